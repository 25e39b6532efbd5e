//! The expression DAG. (Skeleton: bodies to be filled in.)
use std::fmt;
use std::sync::Arc;

/// Built-in functions of one or two arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Func {
    Sin, Cos, Tan, Asin, Acos, Atan, Sinh, Cosh, Tanh, Exp, Ln, Log10, Sqrt, Abs,
    /// sign(x) in {-1, 0, 1}: the derivative of abs.
    Sign,
    /// atan2(y, x)
    Atan2,
    /// pow(a, b) = a^b
    Pow,
}

/// An immutable expression DAG node, shared by reference counting (`Send + Sync`).
#[derive(Clone)]
pub struct Expr(pub(crate) Arc<Node>);

#[derive(Debug)]
pub(crate) enum Node {
    Const(f64),
    Var(usize),
    Neg(Expr),
    Add(Expr, Expr),
    Sub(Expr, Expr),
    Mul(Expr, Expr),
    Div(Expr, Expr),
    Call(Func, Vec<Expr>),
}

impl Expr {
    /// The constant `value`.
    pub fn constant(value: f64) -> Expr { let _ = value; todo!() }
    /// Variable slot `k`.
    pub fn var(k: usize) -> Expr { let _ = k; todo!() }
    /// `f(args)`, simplified (constant-folded) as it is built.
    pub fn call(f: Func, args: Vec<Expr>) -> Expr { let _ = (f, args); todo!() }
    /// `self^exponent`, simplified.
    pub fn powf(&self, exponent: &Expr) -> Expr { let _ = exponent; todo!() }
    /// `Some(value)` when the expression is a constant.
    pub fn as_constant(&self) -> Option<f64> { todo!() }
    /// Whether variable slot `k` occurs in the expression.
    pub fn depends_on(&self, k: usize) -> bool { let _ = k; todo!() }
    /// All variable slots that occur, ascending, without duplicates.
    pub fn vars(&self) -> Vec<usize> { todo!() }
    /// Reference tree-walking evaluator (slow; for tests, load-time checks and constants).
    pub fn eval(&self, vars: &[f64]) -> f64 { let _ = vars; todo!() }
    /// Evaluate with any number type (num-dual's dual numbers in tests).
    pub fn eval_generic<D: crate::Scalar>(&self, vars: &[D]) -> D { let _ = vars; todo!() }
    /// Replace variable slots: slot k becomes `map(k)`.
    pub fn substitute(&self, map: &dyn Fn(usize) -> Expr) -> Expr { let _ = map; todo!() }
    /// Exact partial derivative with respect to slot `k`, simplified.
    pub fn derivative(&self, k: usize) -> Expr { let _ = k; todo!() }
    /// Infix form with slot names given by `name` (for `bead check`).
    pub fn display_with<'a>(&'a self, name: &'a dyn Fn(usize) -> String) -> impl fmt::Display + 'a { let _ = name; DisplayStub }
    /// Number of distinct nodes in the DAG.
    pub fn node_count(&self) -> usize { todo!() }
}

struct DisplayStub;
impl fmt::Display for DisplayStub { fn fmt(&self, _: &mut fmt::Formatter<'_>) -> fmt::Result { todo!() } }

impl fmt::Debug for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result { self.0.fmt(f) }
}

macro_rules! binop {
    ($tr:ident, $m:ident) => {
        impl std::ops::$tr<Expr> for Expr { type Output = Expr; fn $m(self, rhs: Expr) -> Expr { let _ = rhs; todo!() } }
        impl std::ops::$tr<&Expr> for &Expr { type Output = Expr; fn $m(self, rhs: &Expr) -> Expr { let _ = rhs; todo!() } }
        impl std::ops::$tr<f64> for Expr { type Output = Expr; fn $m(self, rhs: f64) -> Expr { let _ = rhs; todo!() } }
    };
}
binop!(Add, add);
binop!(Sub, sub);
binop!(Mul, mul);
binop!(Div, div);
impl std::ops::Neg for Expr { type Output = Expr; fn neg(self) -> Expr { todo!() } }
impl std::ops::Neg for &Expr { type Output = Expr; fn neg(self) -> Expr { todo!() } }
