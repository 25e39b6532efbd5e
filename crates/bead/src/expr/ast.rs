//! The expression DAG: nodes, simplifying constructors, evaluation and substitution (printing
//! is in `display.rs`).
//!
//! Every algorithm here walks the DAG iteratively (see [`topo`]) and visits each shared node
//! once, so neither very long expressions (`x + x + ... + x`, a left-deep chain thousands of
//! nodes deep) nor heavy sharing (repeated squaring) can overflow the stack or blow up
//! exponentially. Dropping a deep expression is iterative too (see `Drop for Node`).
use std::collections::HashMap;
use std::fmt;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::{Arc, LazyLock};

/// Built-in functions of one or two arguments.
///
/// Each variant's documentation gives its derivative rule as used by
/// [`Expr::derivative`], written for an argument `u` with derivative `u'`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Func {
    /// sin(u); derivative `cos(u) u'`.
    Sin,
    /// cos(u); derivative `-sin(u) u'`.
    Cos,
    /// tan(u); derivative `(1 + tan(u)^2) u'` (reusing the `tan(u)` node).
    Tan,
    /// asin(u); derivative `u' / sqrt(1 - u^2)`.
    Asin,
    /// acos(u); derivative `-u' / sqrt(1 - u^2)`.
    Acos,
    /// atan(u); derivative `u' / (1 + u^2)`.
    Atan,
    /// sinh(u); derivative `cosh(u) u'`.
    Sinh,
    /// cosh(u); derivative `sinh(u) u'`.
    Cosh,
    /// tanh(u); derivative `(1 - tanh(u)^2) u'` (reusing the `tanh(u)` node).
    Tanh,
    /// exp(u); derivative `exp(u) u'` (reusing the `exp(u)` node).
    Exp,
    /// Natural logarithm ln(u); derivative `u' / u`.
    Ln,
    /// Decimal logarithm log10(u); derivative `u' / (ln(10) u)`.
    Log10,
    /// sqrt(u); derivative `u' / (2 sqrt(u))` (reusing the `sqrt(u)` node).
    Sqrt,
    /// |u|; derivative `sign(u) u'` (taking sign(0) = 0 at the kink).
    Abs,
    /// sign(x) in {-1, 0, 1}: the derivative of abs.
    /// Its own derivative is taken as 0 (exact everywhere except at 0). sign(NaN) = NaN.
    Sign,
    /// atan2(y, x)
    ///
    /// Derivative `(x y' - y x') / (x^2 + y^2)`.
    Atan2,
    /// pow(a, b) = a^b
    ///
    /// Derivative `b a^(b-1) a'` when `b` does not depend on the variable (in particular when
    /// it is a constant), `a^b ln(a) b'` when `a` does not, and
    /// `a^b (b' ln(a) + b a'/a)` in general.
    Pow,
}

impl Func {
    /// Every function, in declaration order.
    pub const ALL: [Func; 17] = [
        Func::Sin,
        Func::Cos,
        Func::Tan,
        Func::Asin,
        Func::Acos,
        Func::Atan,
        Func::Sinh,
        Func::Cosh,
        Func::Tanh,
        Func::Exp,
        Func::Ln,
        Func::Log10,
        Func::Sqrt,
        Func::Abs,
        Func::Sign,
        Func::Atan2,
        Func::Pow,
    ];

    /// The name used in expression source, e.g. `"atan2"`.
    pub fn name(self) -> &'static str {
        match self {
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tan => "tan",
            Func::Asin => "asin",
            Func::Acos => "acos",
            Func::Atan => "atan",
            Func::Sinh => "sinh",
            Func::Cosh => "cosh",
            Func::Tanh => "tanh",
            Func::Exp => "exp",
            Func::Ln => "ln",
            Func::Log10 => "log10",
            Func::Sqrt => "sqrt",
            Func::Abs => "abs",
            Func::Sign => "sign",
            Func::Atan2 => "atan2",
            Func::Pow => "pow",
        }
    }

    /// Number of arguments: 2 for `atan2` and `pow`, 1 otherwise.
    pub fn arity(self) -> usize {
        match self {
            Func::Atan2 | Func::Pow => 2,
            _ => 1,
        }
    }

    /// The function called `name` in expression source (exact, case-sensitive), if any.
    pub fn from_name(name: &str) -> Option<Func> {
        Func::ALL.into_iter().find(|f| f.name() == name)
    }
}

impl fmt::Display for Func {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
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
    /// `a^b`. A small integer constant exponent evaluates by multiplication / `powi`
    /// (see [`int_exponent`]), another constant by `powf`, a variable one by `powf`/`powd`.
    Pow(Expr, Expr),
    /// A one-argument function (never `Atan2` or `Pow`).
    Unary(Func, Expr),
    /// atan2(y, x)
    Atan2(Expr, Expr),
}

impl Node {
    /// The children in order (first, second), `None` where absent.
    pub(crate) fn children(&self) -> [Option<&Expr>; 2] {
        match self {
            Node::Const(_) | Node::Var(_) => [None, None],
            Node::Neg(a) | Node::Unary(_, a) => [Some(a), None],
            Node::Add(a, b)
            | Node::Sub(a, b)
            | Node::Mul(a, b)
            | Node::Div(a, b)
            | Node::Pow(a, b)
            | Node::Atan2(a, b) => [Some(a), Some(b)],
        }
    }

    fn children_mut(&mut self) -> [Option<&mut Expr>; 2] {
        match self {
            Node::Const(_) | Node::Var(_) => [None, None],
            Node::Neg(a) | Node::Unary(_, a) => [Some(a), None],
            Node::Add(a, b)
            | Node::Sub(a, b)
            | Node::Mul(a, b)
            | Node::Div(a, b)
            | Node::Pow(a, b)
            | Node::Atan2(a, b) => [Some(a), Some(b)],
        }
    }

    fn is_leaf(&self) -> bool {
        matches!(self, Node::Const(_) | Node::Var(_))
    }
}

/// A shared leaf swapped in for children that are being dropped.
static PLACEHOLDER: LazyLock<Expr> = LazyLock::new(|| Expr(Arc::new(Node::Const(0.0))));

/// Move the non-leaf children of `node` onto `stack`, leaving shared leaves behind.
fn detach_children(node: &mut Node, stack: &mut Vec<Expr>) {
    for child in node.children_mut().into_iter().flatten() {
        if !child.0.is_leaf() {
            stack.push(std::mem::replace(child, PLACEHOLDER.clone()));
        }
    }
}

impl Drop for Node {
    /// Iterative drop: the default recursive drop would overflow the stack on a chain of a
    /// few hundred thousand nodes (e.g. a long sum read from a file).
    fn drop(&mut self) {
        let mut stack = Vec::new();
        detach_children(self, &mut stack);
        while let Some(mut e) = stack.pop() {
            if let Some(node) = Arc::get_mut(&mut e.0) {
                detach_children(node, &mut stack);
            }
            // `e` is dropped here; its node (if this was the last reference) now has only
            // leaf children, so its own `drop` does not recurse.
        }
    }
}

// ---------------------------------------------------------------------------------------
// Hashing and traversal helpers shared by the expression modules.

/// A fast non-cryptographic hasher for pointer and small integer keys (FxHash-style mixing
/// with a final fold so that aligned pointers spread over the low bits).
#[derive(Default, Clone, Copy)]
pub(crate) struct FastHasher(u64);

impl FastHasher {
    #[inline]
    fn add(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

impl Hasher for FastHasher {
    #[inline]
    fn finish(&self) -> u64 {
        self.0 ^ (self.0 >> 32)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.add(u64::from(b));
        }
    }
    #[inline]
    fn write_u8(&mut self, x: u8) {
        self.add(u64::from(x));
    }
    #[inline]
    fn write_u32(&mut self, x: u32) {
        self.add(u64::from(x));
    }
    #[inline]
    fn write_u64(&mut self, x: u64) {
        self.add(x);
    }
    #[inline]
    fn write_usize(&mut self, x: usize) {
        self.add(x as u64);
    }
}

/// A `HashMap` with [`FastHasher`].
pub(crate) type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<FastHasher>>;

/// "No child" marker in [`Topo::kids`].
pub(crate) const NO_CHILD: u32 = u32::MAX;

/// The distinct nodes reachable from some roots, children before parents.
pub(crate) struct Topo<'a> {
    /// Distinct nodes (by `Arc` identity) in dependency order.
    pub(crate) nodes: Vec<&'a Expr>,
    /// For each node, the indices (into `nodes`) of its children; [`NO_CHILD`] where absent.
    pub(crate) kids: Vec<[u32; 2]>,
    /// For each root, its index in `nodes`.
    pub(crate) roots: Vec<u32>,
}

/// Topologically sort the DAG below `roots` without recursion, each shared node once.
pub(crate) fn topo<'a>(roots: impl IntoIterator<Item = &'a Expr>) -> Topo<'a> {
    let mut index: FastMap<*const Node, u32> = FastMap::default();
    let mut nodes: Vec<&'a Expr> = Vec::new();
    let mut kids: Vec<[u32; 2]> = Vec::new();
    let mut root_idx = Vec::new();
    let mut stack: Vec<(&'a Expr, bool)> = Vec::new();
    for root in roots {
        stack.push((root, false));
        while let Some((e, expanded)) = stack.pop() {
            let p = Arc::as_ptr(&e.0);
            if index.contains_key(&p) {
                continue;
            }
            let children = e.0.children();
            if expanded {
                // All children were finished before this entry surfaced again.
                let mut k = [NO_CHILD; 2];
                for (slot, c) in k.iter_mut().zip(children) {
                    if let Some(c) = c {
                        *slot = index[&Arc::as_ptr(&c.0)];
                    }
                }
                index.insert(p, nodes.len() as u32);
                nodes.push(e);
                kids.push(k);
            } else {
                stack.push((e, true));
                for c in children.into_iter().rev().flatten() {
                    if !index.contains_key(&Arc::as_ptr(&c.0)) {
                        stack.push((c, false));
                    }
                }
            }
        }
        root_idx.push(index[&Arc::as_ptr(&root.0)]);
    }
    Topo {
        nodes,
        kids,
        roots: root_idx,
    }
}

/// Whether two lists of expressions are the same computation: DAGs of the same shape (the
/// same operations on the same children, constants by bit pattern, variables by slot, in the
/// same sharing). A DAG equal in value but shared differently reads as different: the
/// answer errs only towards "different", never towards "same".
pub(crate) fn same_structure(a: &[&Expr], b: &[&Expr]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let (ta, tb) = (topo(a.iter().copied()), topo(b.iter().copied()));
    if ta.nodes.len() != tb.nodes.len() || ta.kids != tb.kids || ta.roots != tb.roots {
        return false;
    }
    ta.nodes
        .iter()
        .zip(&tb.nodes)
        .all(|(x, y)| match (&*x.0, &*y.0) {
            (Node::Const(p), Node::Const(q)) => p.to_bits() == q.to_bits(),
            (Node::Var(p), Node::Var(q)) => p == q,
            (Node::Unary(f, _), Node::Unary(g, _)) => f == g,
            (Node::Neg(_), Node::Neg(_))
            | (Node::Add(..), Node::Add(..))
            | (Node::Sub(..), Node::Sub(..))
            | (Node::Mul(..), Node::Mul(..))
            | (Node::Div(..), Node::Div(..))
            | (Node::Pow(..), Node::Pow(..))
            | (Node::Atan2(..), Node::Atan2(..)) => true,
            _ => false,
        })
}

/// The same expressions with structurally equal subexpressions merged into one node: same
/// operation, same (merged) children, constants by bit pattern, variables by slot. Nothing is
/// rewritten or reordered, so every value and every printed form stays the same; only sharing
/// grows. What was written out several times (`sin(q1) + sin(q2)` in one position and
/// `sin(q1) + sin(q2) + sin(q3)` in the next) is then differentiated once.
pub(crate) fn share(roots: &[Expr]) -> Vec<Expr> {
    let t = topo(roots);
    // Key: (operation, function or constant bits or slot, merged child ids).
    let mut canonical: FastMap<(u8, u64, u32, u32), u32> = FastMap::default();
    let mut merged: Vec<Expr> = Vec::with_capacity(t.nodes.len());
    let mut id: Vec<u32> = Vec::with_capacity(t.nodes.len());
    for (e, &[ia, ib]) in t.nodes.iter().zip(&t.kids) {
        let kid = |c: u32| {
            if c == NO_CHILD {
                NO_CHILD
            } else {
                id[c as usize]
            }
        };
        let (ka, kb) = (kid(ia), kid(ib));
        let (op, extra) = match &*e.0 {
            Node::Const(c) => (0, c.to_bits()),
            Node::Var(k) => (1, *k as u64),
            Node::Neg(_) => (2, 0),
            Node::Add(..) => (3, 0),
            Node::Sub(..) => (4, 0),
            Node::Mul(..) => (5, 0),
            Node::Div(..) => (6, 0),
            Node::Pow(..) => (7, 0),
            Node::Unary(f, _) => (8, *f as u64),
            Node::Atan2(..) => (9, 0),
        };
        let next = merged.len() as u32;
        let slot = *canonical.entry((op, extra, ka, kb)).or_insert(next);
        if slot != next {
            id.push(id[slot as usize]);
            merged.push(merged[slot as usize].clone());
            continue;
        }
        let same = |c: u32, k: u32, child: Option<&Expr>| {
            c == NO_CHILD || child.is_some_and(|x| x.ptr_eq(&merged[k as usize]))
        };
        let [ca, cb] = e.0.children();
        let node = if same(ia, ka, ca) && same(ib, kb, cb) {
            (*e).clone()
        } else {
            let a = || merged[ka as usize].clone();
            let b = || merged[kb as usize].clone();
            make(match &*e.0 {
                Node::Neg(_) => Node::Neg(a()),
                Node::Add(..) => Node::Add(a(), b()),
                Node::Sub(..) => Node::Sub(a(), b()),
                Node::Mul(..) => Node::Mul(a(), b()),
                Node::Div(..) => Node::Div(a(), b()),
                Node::Pow(..) => Node::Pow(a(), b()),
                Node::Unary(f, _) => Node::Unary(*f, a()),
                Node::Atan2(..) => Node::Atan2(a(), b()),
                Node::Const(_) | Node::Var(_) => unreachable!("leaves have no children"),
            })
        };
        id.push(next);
        merged.push(node);
    }
    t.roots
        .iter()
        .map(|&r| merged[r as usize].clone())
        .collect()
}

/// Whether some variable slot for which `pred` holds occurs in any of `roots` (one walk over
/// their shared DAG).
pub(crate) fn reads_any(roots: &[Expr], pred: &dyn Fn(usize) -> bool) -> bool {
    topo(roots)
        .nodes
        .iter()
        .any(|e| matches!(*e.0, Node::Var(k) if pred(k)))
}

// ---------------------------------------------------------------------------------------
// Numeric semantics shared by `eval`, constant folding and the tape.

/// sign(x): -1, 0 or 1 (0 for both zeros), NaN for NaN.
#[inline]
pub(crate) fn sign_f64(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        x * 0.0 // 0 for ±0 (sign kept), NaN for NaN
    }
}

/// Largest `|n|` for which a constant integer exponent is evaluated with `powi`.
pub(crate) const MAX_POWI: i32 = 16;

/// `Some(n)` if the constant exponent `c` is an integer with `|n| <= MAX_POWI`: such powers
/// are evaluated as `x*x` (n = 2) or with `powi`, faster than `powf`.
#[inline]
pub(crate) fn int_exponent(c: f64) -> Option<i32> {
    if c.fract() == 0.0 && c.abs() <= f64::from(MAX_POWI) {
        Some(c as i32)
    } else {
        None
    }
}

/// `x^c` for a constant exponent, exactly as the tape computes it.
#[inline]
pub(crate) fn pow_const_f64(x: f64, c: f64) -> f64 {
    match int_exponent(c) {
        Some(2) => x * x,
        Some(n) => x.powi(n),
        None => x.powf(c),
    }
}

/// A one-argument function on `f64`, exactly as the tape computes it.
pub(crate) fn unary_f64(f: Func, x: f64) -> f64 {
    match f {
        Func::Sin => x.sin(),
        Func::Cos => x.cos(),
        Func::Tan => x.tan(),
        Func::Asin => x.asin(),
        Func::Acos => x.acos(),
        Func::Atan => x.atan(),
        Func::Sinh => x.sinh(),
        Func::Cosh => x.cosh(),
        Func::Tanh => x.tanh(),
        Func::Exp => x.exp(),
        Func::Ln => x.ln(),
        Func::Log10 => x.log10(),
        Func::Sqrt => x.sqrt(),
        Func::Abs => x.abs(),
        Func::Sign => sign_f64(x),
        Func::Atan2 | Func::Pow => f64::NAN, // not unary; never stored in `Node::Unary`
    }
}

/// The operations an evaluator needs; one implementation for `f64` (matching the tape bit
/// for bit) and one for num-dual numbers.
trait Backend {
    type T: Copy;
    fn konst(c: f64) -> Self::T;
    fn neg(a: Self::T) -> Self::T;
    fn add(a: Self::T, b: Self::T) -> Self::T;
    fn sub(a: Self::T, b: Self::T) -> Self::T;
    fn mul(a: Self::T, b: Self::T) -> Self::T;
    fn div(a: Self::T, b: Self::T) -> Self::T;
    fn pow_const(a: Self::T, c: f64) -> Self::T;
    fn pow(a: Self::T, b: Self::T) -> Self::T;
    fn unary(f: Func, a: Self::T) -> Self::T;
    fn atan2(y: Self::T, x: Self::T) -> Self::T;
}

struct F64Backend;

impl Backend for F64Backend {
    type T = f64;
    fn konst(c: f64) -> f64 {
        c
    }
    fn neg(a: f64) -> f64 {
        -a
    }
    fn add(a: f64, b: f64) -> f64 {
        a + b
    }
    fn sub(a: f64, b: f64) -> f64 {
        a - b
    }
    fn mul(a: f64, b: f64) -> f64 {
        a * b
    }
    fn div(a: f64, b: f64) -> f64 {
        a / b
    }
    fn pow_const(a: f64, c: f64) -> f64 {
        pow_const_f64(a, c)
    }
    fn pow(a: f64, b: f64) -> f64 {
        a.powf(b)
    }
    fn unary(f: Func, a: f64) -> f64 {
        unary_f64(f, a)
    }
    fn atan2(y: f64, x: f64) -> f64 {
        y.atan2(x)
    }
}

struct DualBackend<D>(std::marker::PhantomData<D>);

impl<D: crate::Scalar> Backend for DualBackend<D> {
    type T = D;
    fn konst(c: f64) -> D {
        D::from(c)
    }
    fn neg(a: D) -> D {
        -a
    }
    fn add(a: D, b: D) -> D {
        a + b
    }
    fn sub(a: D, b: D) -> D {
        a - b
    }
    fn mul(a: D, b: D) -> D {
        a * b
    }
    fn div(a: D, b: D) -> D {
        a / b
    }
    fn pow_const(a: D, c: f64) -> D {
        match int_exponent(c) {
            Some(2) => a * a,
            Some(n) => a.powi(n),
            None => a.powf(c),
        }
    }
    fn pow(a: D, b: D) -> D {
        a.powd(b)
    }
    fn unary(f: Func, a: D) -> D {
        match f {
            Func::Sin => a.sin(),
            Func::Cos => a.cos(),
            Func::Tan => a.tan(),
            Func::Asin => a.asin(),
            Func::Acos => a.acos(),
            Func::Atan => a.atan(),
            Func::Sinh => a.sinh(),
            Func::Cosh => a.cosh(),
            Func::Tanh => a.tanh(),
            Func::Exp => a.exp(),
            Func::Ln => a.ln(),
            Func::Log10 => a.log10(),
            Func::Sqrt => a.sqrt(),
            Func::Abs => {
                if a.re() < 0.0 {
                    -a
                } else {
                    a
                }
            }
            Func::Sign => D::from(sign_f64(a.re())),
            Func::Atan2 | Func::Pow => D::from(f64::NAN),
        }
    }
    fn atan2(y: D, x: D) -> D {
        y.atan2(x)
    }
}

fn eval_with<B: Backend>(root: &Expr, vars: &[B::T]) -> B::T {
    match &*root.0 {
        Node::Const(c) => return B::konst(*c),
        Node::Var(k) => return vars[*k],
        _ => {}
    }
    let t = topo([root]);
    let mut vals: Vec<B::T> = Vec::with_capacity(t.nodes.len());
    for (e, &[ia, ib]) in t.nodes.iter().zip(&t.kids) {
        let a = || vals[ia as usize];
        let b = || vals[ib as usize];
        let v = match &*e.0 {
            Node::Const(c) => B::konst(*c),
            Node::Var(k) => vars[*k],
            Node::Neg(_) => B::neg(a()),
            Node::Add(..) => B::add(a(), b()),
            Node::Sub(..) => B::sub(a(), b()),
            Node::Mul(..) => B::mul(a(), b()),
            Node::Div(..) => B::div(a(), b()),
            Node::Pow(_, exp) => match exp.as_constant() {
                Some(c) => B::pow_const(a(), c),
                None => B::pow(a(), b()),
            },
            Node::Unary(f, _) => B::unary(*f, a()),
            Node::Atan2(..) => B::atan2(a(), b()),
        };
        vals.push(v);
    }
    vals[t.roots[0] as usize]
}

// ---------------------------------------------------------------------------------------
// Simplifying constructors.

fn konst(e: &Expr) -> Option<f64> {
    match *e.0 {
        Node::Const(c) => Some(c),
        _ => None,
    }
}

/// `Some(constant)` when `v` is finite: folding never hides an inf or NaN.
fn fold(v: f64) -> Option<Expr> {
    v.is_finite().then(|| Expr::constant(v))
}

fn make(n: Node) -> Expr {
    Expr(Arc::new(n))
}

/// `a + b`: folds constants; `x + 0 = 0 + x = x`; `a + (-b) = a - b`; `(-a) + b = b - a`;
/// a negative constant is moved into a subtraction (all exact).
pub(crate) fn add(a: Expr, b: Expr) -> Expr {
    let (ca, cb) = (konst(&a), konst(&b));
    if let (Some(x), Some(y)) = (ca, cb) {
        if let Some(e) = fold(x + y) {
            return e;
        }
    }
    if ca == Some(0.0) {
        return b;
    }
    if cb == Some(0.0) {
        return a;
    }
    if let Node::Neg(nb) = &*b.0 {
        return sub(a, nb.clone());
    }
    if let Some(y) = cb {
        if y < 0.0 {
            return sub(a, Expr::constant(-y));
        }
    }
    if let Node::Neg(na) = &*a.0 {
        return sub(b, na.clone());
    }
    if let Some(x) = ca {
        if x < 0.0 {
            return sub(b, Expr::constant(-x));
        }
    }
    make(Node::Add(a, b))
}

/// `a - b`: folds constants; `x - 0 = x`; `0 - x = -x`; `a - (-b) = a + b`;
/// `(-a) - b = -(a + b)` (all exact).
pub(crate) fn sub(a: Expr, b: Expr) -> Expr {
    let (ca, cb) = (konst(&a), konst(&b));
    if let (Some(x), Some(y)) = (ca, cb) {
        if let Some(e) = fold(x - y) {
            return e;
        }
    }
    if cb == Some(0.0) {
        return a;
    }
    if ca == Some(0.0) {
        return neg(b);
    }
    if let Node::Neg(nb) = &*b.0 {
        return add(a, nb.clone());
    }
    if let Some(y) = cb {
        if y < 0.0 {
            return add(a, Expr::constant(-y));
        }
    }
    if let Node::Neg(na) = &*a.0 {
        return neg(add(na.clone(), b));
    }
    make(Node::Sub(a, b))
}

/// `-a`: folds constants; `--x = x`; `-(c*x) = (-c)*x`; `-(c/x) = (-c)/x`.
pub(crate) fn neg(a: Expr) -> Expr {
    match &*a.0 {
        Node::Const(c) => return Expr::constant(-c),
        Node::Neg(x) => return x.clone(),
        Node::Mul(c, x) => {
            if let Some(c) = konst(c) {
                return mul(Expr::constant(-c), x.clone());
            }
        }
        Node::Div(c, x) => {
            if let Some(c) = konst(c) {
                return div(Expr::constant(-c), x.clone());
            }
        }
        _ => {}
    }
    make(Node::Neg(a))
}

/// `a * b`: folds constants; `x*0 = 0*x = 0`; `x*1 = 1*x = x`; `x*(-1) = -x`; `x*x = x^2`
/// (same node); constants move to the left and merge (`c1*(c2*x) = (c1 c2)*x`, unless the
/// product underflows to zero or a subnormal); signs move out (`(-a)*b = -(a*b)`).
pub(crate) fn mul(a: Expr, b: Expr) -> Expr {
    let (mut a, mut b) = (a, b);
    let (ca, cb) = (konst(&a), konst(&b));
    if let (Some(x), Some(y)) = (ca, cb) {
        if let Some(e) = fold(x * y) {
            return e;
        }
    }
    for (c, other) in [(ca, &b), (cb, &a)] {
        match c {
            Some(0.0) => return Expr::constant(0.0),
            Some(1.0) => return other.clone(),
            Some(-1.0) => return neg(other.clone()),
            _ => {}
        }
    }
    if Arc::ptr_eq(&a.0, &b.0) {
        return pow(a, Expr::constant(2.0));
    }
    if cb.is_some() && ca.is_none() {
        std::mem::swap(&mut a, &mut b);
    }
    if let Some(c) = konst(&a) {
        match &*b.0 {
            Node::Mul(c2, x) => {
                // Merged only where the product is a normal number: one that underflows
                // would drop x (`x*1e-170*1e-170` is 1e-320 at x = 1e20, not 0).
                if let Some(c2) = konst(c2).filter(|c2| (c * c2).is_normal()) {
                    if let Some(p) = fold(c * c2) {
                        return mul(p, x.clone());
                    }
                }
            }
            Node::Neg(x) => return mul(Expr::constant(-c), x.clone()),
            _ => {}
        }
    }
    if let Node::Neg(x) = &*a.0 {
        return neg(mul(x.clone(), b));
    }
    if let Node::Neg(y) = &*b.0 {
        return neg(mul(a, y.clone()));
    }
    make(Node::Mul(a, b))
}

/// `a / b`: folds constants; `0/x = 0` for non-constant `x`; `x/1 = x`; `x/(-1) = -x`;
/// signs move out (`(-a)/b = a/(-b) = -(a/b)`). `x/x` is *not* simplified.
pub(crate) fn div(a: Expr, b: Expr) -> Expr {
    let (ca, cb) = (konst(&a), konst(&b));
    if let (Some(x), Some(y)) = (ca, cb) {
        if let Some(e) = fold(x / y) {
            return e;
        }
    }
    if ca == Some(0.0) && cb.is_none() {
        return Expr::constant(0.0);
    }
    match cb {
        Some(1.0) => return a,
        Some(-1.0) => return neg(a),
        _ => {}
    }
    if let Node::Neg(x) = &*a.0 {
        return neg(div(x.clone(), b));
    }
    if let Node::Neg(y) = &*b.0 {
        return neg(div(a, y.clone()));
    }
    make(Node::Div(a, b))
}

/// `a ^ b`: folds constants; `x^1 = x`; `x^0 = 1`; `1^x = 1`.
pub(crate) fn pow(a: Expr, b: Expr) -> Expr {
    let (ca, cb) = (konst(&a), konst(&b));
    if let (Some(x), Some(y)) = (ca, cb) {
        if let Some(e) = fold(pow_const_f64(x, y)) {
            return e;
        }
    }
    match cb {
        Some(1.0) => return a,
        Some(0.0) => return Expr::constant(1.0),
        _ => {}
    }
    if ca == Some(1.0) {
        return Expr::constant(1.0);
    }
    make(Node::Pow(a, b))
}

/// `f(a)` for a one-argument function, constant-folded.
pub(crate) fn unary(f: Func, a: Expr) -> Expr {
    if let Some(x) = konst(&a) {
        if let Some(e) = fold(unary_f64(f, x)) {
            return e;
        }
    }
    make(Node::Unary(f, a))
}

/// `atan2(y, x)`, constant-folded.
pub(crate) fn atan2(y: Expr, x: Expr) -> Expr {
    if let (Some(cy), Some(cx)) = (konst(&y), konst(&x)) {
        if let Some(e) = fold(cy.atan2(cx)) {
            return e;
        }
    }
    make(Node::Atan2(y, x))
}

impl Expr {
    /// The constant `value`.
    pub fn constant(value: f64) -> Expr {
        make(Node::Const(value))
    }

    /// Variable slot `k`.
    pub fn var(k: usize) -> Expr {
        make(Node::Var(k))
    }

    /// `f(args)`, simplified (constant-folded) as it is built. `Func::Pow` is the same as
    /// [`Expr::powf`].
    ///
    /// # Panics
    /// If `args.len()` is not `f.arity()`.
    pub fn call(f: Func, args: Vec<Expr>) -> Expr {
        assert_eq!(
            args.len(),
            f.arity(),
            "function `{}` takes {} argument(s), got {}",
            f.name(),
            f.arity(),
            args.len()
        );
        let mut it = args.into_iter();
        let (Some(a), b) = (it.next(), it.next()) else {
            unreachable!("arity checked above")
        };
        match (f, b) {
            (Func::Pow, Some(b)) => pow(a, b),
            (Func::Atan2, Some(b)) => atan2(a, b),
            (_, _) => unary(f, a),
        }
    }

    /// `self^exponent`, simplified.
    ///
    /// A small integer constant exponent (`|n| <= 16`) is evaluated by multiplication
    /// (`x^2` as one `x*x`) or `powi`, much faster than `powf`; other constant exponents use
    /// `powf`, and a non-constant exponent `powf` (`powd` for dual numbers). `x*x` with both
    /// factors the same node is built as `x^2`, and the tape squares `x*x` in any case.
    pub fn powf(&self, exponent: &Expr) -> Expr {
        pow(self.clone(), exponent.clone())
    }

    /// `self^n`, simplified (see [`Expr::powf`]).
    pub fn powi(&self, n: i32) -> Expr {
        pow(self.clone(), Expr::constant(f64::from(n)))
    }

    /// `sqrt(self)`.
    pub fn sqrt(&self) -> Expr {
        unary(Func::Sqrt, self.clone())
    }

    /// `sin(self)`.
    pub fn sin(&self) -> Expr {
        unary(Func::Sin, self.clone())
    }

    /// `cos(self)`.
    pub fn cos(&self) -> Expr {
        unary(Func::Cos, self.clone())
    }

    /// `Some(value)` when the expression is a constant.
    pub fn as_constant(&self) -> Option<f64> {
        konst(self)
    }

    /// Whether the two handles share the same node (not structural equality).
    pub fn ptr_eq(&self, other: &Expr) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }

    /// Whether variable slot `k` occurs in the expression.
    pub fn depends_on(&self, k: usize) -> bool {
        // Iterative depth-first search with early exit.
        let mut seen: FastMap<*const Node, ()> = FastMap::default();
        let mut stack = vec![self];
        while let Some(e) = stack.pop() {
            match &*e.0 {
                Node::Var(j) if *j == k => return true,
                _ => {}
            }
            for c in e.0.children().into_iter().flatten() {
                if !matches!(*c.0, Node::Const(_)) && seen.insert(Arc::as_ptr(&c.0), ()).is_none() {
                    stack.push(c);
                }
            }
        }
        false
    }

    /// All variable slots that occur, ascending, without duplicates.
    pub fn vars(&self) -> Vec<usize> {
        let mut v: Vec<usize> = topo([self])
            .nodes
            .iter()
            .filter_map(|e| match *e.0 {
                Node::Var(k) => Some(k),
                _ => None,
            })
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    /// Reference evaluator (slow: it allocates; for tests, load-time checks and constants).
    /// Each shared node is evaluated once; the arithmetic is exactly that of
    /// [`Tape::eval`](super::Tape::eval).
    ///
    /// # Panics
    /// If a variable slot is out of range of `vars`.
    pub fn eval(&self, vars: &[f64]) -> f64 {
        eval_with::<F64Backend>(self, vars)
    }

    /// Evaluate with any number type (num-dual's dual numbers in tests).
    ///
    /// `abs` is `-x` when the real part is negative and `x` otherwise; `sign` is a constant;
    /// a constant exponent uses `powi`/`powf`, a variable one `powd`.
    ///
    /// # Panics
    /// If a variable slot is out of range of `vars`.
    pub fn eval_generic<D: crate::Scalar>(&self, vars: &[D]) -> D {
        eval_with::<DualBackend<D>>(self, vars)
    }

    /// Replace variable slots: slot k becomes `map(k)`. The result is simplified; subtrees
    /// without variables are shared with `self`.
    pub fn substitute(&self, map: &dyn Fn(usize) -> Expr) -> Expr {
        let t = topo([self]);
        let mut new: Vec<Expr> = Vec::with_capacity(t.nodes.len());
        for (e, &[ia, ib]) in t.nodes.iter().zip(&t.kids) {
            let a = || new[ia as usize].clone();
            let b = || new[ib as usize].clone();
            let unchanged =
                e.0.children()
                    .into_iter()
                    .zip([ia, ib])
                    .all(|(c, i)| match c {
                        Some(c) => Arc::ptr_eq(&c.0, &new[i as usize].0),
                        None => true,
                    });
            let v = match &*e.0 {
                Node::Var(k) => {
                    let m = map(*k);
                    match *m.0 {
                        Node::Var(j) if j == *k => (*e).clone(),
                        _ => m,
                    }
                }
                _ if unchanged => (*e).clone(),
                Node::Const(_) => (*e).clone(),
                Node::Neg(_) => neg(a()),
                Node::Add(..) => add(a(), b()),
                Node::Sub(..) => sub(a(), b()),
                Node::Mul(..) => mul(a(), b()),
                Node::Div(..) => div(a(), b()),
                Node::Pow(..) => pow(a(), b()),
                Node::Unary(f, _) => unary(*f, a()),
                Node::Atan2(..) => atan2(a(), b()),
            };
            new.push(v);
        }
        new.swap_remove(t.roots[0] as usize)
    }

    /// Exact partial derivative with respect to slot `k`, simplified.
    ///
    /// Rules: `(a ± b)' = a' ± b'`, `(a b)' = a' b + a b'`, `(a/b)' = (a' - (a/b) b')/b`
    /// (reusing the quotient node), and those listed on [`Func`] for the functions and
    /// powers. Shared subexpressions are differentiated once (memoized on node identity),
    /// and subexpressions that do not contain slot `k` are not visited for differentiation.
    pub fn derivative(&self, k: usize) -> Expr {
        super::diff::derivative(self, k)
    }

    /// [`Self::derivative`] with respect to each slot of `ks`, in order: the same
    /// expressions, for the cost of one traversal of the DAG plus the derivatives.
    pub fn derivatives(&self, ks: &[usize]) -> Vec<Expr> {
        super::diff::derivatives(self, ks)
    }

    /// Number of distinct nodes in the DAG.
    pub fn node_count(&self) -> usize {
        topo([self]).nodes.len()
    }
}

impl fmt::Debug for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

macro_rules! binop {
    ($tr:ident, $m:ident, $f:ident) => {
        impl std::ops::$tr<Expr> for Expr {
            type Output = Expr;
            fn $m(self, rhs: Expr) -> Expr {
                $f(self, rhs)
            }
        }
        impl std::ops::$tr<&Expr> for &Expr {
            type Output = Expr;
            fn $m(self, rhs: &Expr) -> Expr {
                $f(self.clone(), rhs.clone())
            }
        }
        impl std::ops::$tr<f64> for Expr {
            type Output = Expr;
            fn $m(self, rhs: f64) -> Expr {
                $f(self, Expr::constant(rhs))
            }
        }
        impl std::ops::$tr<&Expr> for Expr {
            type Output = Expr;
            fn $m(self, rhs: &Expr) -> Expr {
                $f(self, rhs.clone())
            }
        }
        impl std::ops::$tr<Expr> for &Expr {
            type Output = Expr;
            fn $m(self, rhs: Expr) -> Expr {
                $f(self.clone(), rhs)
            }
        }
        impl std::ops::$tr<f64> for &Expr {
            type Output = Expr;
            fn $m(self, rhs: f64) -> Expr {
                $f(self.clone(), Expr::constant(rhs))
            }
        }
        impl std::ops::$tr<Expr> for f64 {
            type Output = Expr;
            fn $m(self, rhs: Expr) -> Expr {
                $f(Expr::constant(self), rhs)
            }
        }
    };
}
binop!(Add, add, add);
binop!(Sub, sub, sub);
binop!(Mul, mul, mul);
binop!(Div, div, div);

impl std::ops::Neg for Expr {
    type Output = Expr;
    fn neg(self) -> Expr {
        neg(self)
    }
}

impl std::ops::Neg for &Expr {
    type Output = Expr;
    fn neg(self) -> Expr {
        neg(self.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::{random_expr, Rng};
    use crate::expr::{parse, Resolved};

    const NAMES: [&str; 4] = ["x", "y", "a", "b"];

    fn p(src: &str) -> Expr {
        let r = |n: &str| match NAMES.iter().position(|&m| m == n) {
            Some(k) => Ok(Resolved::Var(k)),
            None => Err(format!("unknown name `{n}`")),
        };
        parse(src, &r).unwrap_or_else(|e| panic!("{src}: {e}"))
    }

    fn show(e: &Expr) -> String {
        e.display_with(&|k| NAMES[k].to_string()).to_string()
    }

    fn x() -> Expr {
        Expr::var(0)
    }

    fn y() -> Expr {
        Expr::var(1)
    }

    fn c(v: f64) -> Expr {
        Expr::constant(v)
    }

    #[test]
    fn share_merges_equal_subexpressions_and_changes_nothing_else() {
        // Two sums written out separately, the second extending the first.
        let a = p("sin(x) + cos(y*b) + a");
        let b = p("sin(x) + cos(y*b) + a + exp(x)");
        let shared = share(&[a.clone(), b.clone()]);
        assert_eq!(show(&shared[0]), show(&a));
        assert_eq!(show(&shared[1]), show(&b));
        let Node::Add(prefix, _) = &*shared[1].0 else {
            panic!("a sum")
        };
        assert!(prefix.ptr_eq(&shared[0]));
        assert!(topo(&shared).nodes.len() < topo([&a, &b]).nodes.len());
        let v = [0.3, -1.1, 0.7, 2.0];
        assert_eq!(shared[1].eval(&v).to_bits(), b.eval(&v).to_bits());
        // Already shared expressions come back as they are; constants merge by bit pattern.
        let again = share(&shared);
        assert!(again[0].ptr_eq(&shared[0]) && again[1].ptr_eq(&shared[1]));
        let twice = share(&[p("x + 0.5"), p("x + 0.5"), p("x + 0.25")]);
        assert!(twice[0].ptr_eq(&twice[1]) && !twice[0].ptr_eq(&twice[2]));
        // Random expressions keep their values and printed forms.
        let mut rng = Rng::new(4);
        for _ in 0..50 {
            let mut pool = Vec::new();
            let roots: Vec<Expr> = (0..4)
                .map(|_| random_expr(&mut rng, 4, 5, &mut pool))
                .collect();
            let shared = share(&roots);
            for (r, s) in roots.iter().zip(&shared) {
                assert_eq!(show(r), show(s));
                let got = s.eval(&v);
                let want = r.eval(&v);
                assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()));
            }
        }
    }

    /// Constants merge only where their product is a normal number: one that underflows
    /// would drop the variable or lose its digits.
    #[test]
    fn constants_merge_unless_their_product_underflows() {
        assert_eq!(show(&p("2*(3*x)")), "6*x");
        for src in ["x*1e-170*1e-170", "1e-160*(1e-160*x)"] {
            let e = p(src);
            assert!(e.depends_on(0), "{src}: {}", show(&e));
            let v = [1e20, 0.0, 0.0, 0.0];
            let want: f64 = if src.starts_with('x') {
                1e20 * 1e-170 * 1e-170
            } else {
                1e-160 * (1e-160 * 1e20)
            };
            assert_eq!(e.eval(&v).to_bits(), want.to_bits(), "{src}");
            assert!(want != 0.0);
        }
    }

    #[test]
    fn reads_any_looks_at_every_root() {
        let roots = [p("x + 1"), p("sin(y)*2")];
        assert!(reads_any(&roots, &|k| k == 1));
        assert!(!reads_any(&roots, &|k| k >= 2));
        assert!(!reads_any(&[], &|_| true));
    }

    #[test]
    fn send_sync_and_small() {
        fn assert_send_sync<T: Send + Sync>() {}
        assert_send_sync::<Expr>();
        assert_eq!(std::mem::size_of::<Expr>(), 8);
    }

    #[test]
    fn simplifications() {
        let x = x();
        assert!((x.clone() + 0.0).ptr_eq(&x));
        assert!((c(0.0) + x.clone()).ptr_eq(&x));
        assert!((x.clone() - 0.0).ptr_eq(&x));
        assert_eq!(show(&(c(0.0) - x.clone())), "-x");
        assert_eq!((x.clone() * 0.0).as_constant(), Some(0.0));
        assert_eq!((c(0.0) * x.clone()).as_constant(), Some(0.0));
        assert!((x.clone() * 1.0).ptr_eq(&x));
        assert!((c(1.0) * x.clone()).ptr_eq(&x));
        assert!((x.clone() / 1.0).ptr_eq(&x));
        assert_eq!((c(0.0) / x.clone()).as_constant(), Some(0.0));
        assert!((-(-x.clone())).ptr_eq(&x));
        assert!(x.powi(1).ptr_eq(&x));
        assert_eq!(x.powi(0).as_constant(), Some(1.0));
        assert_eq!(c(1.0).powf(&x).as_constant(), Some(1.0));
        assert_eq!(show(&(x.clone() * -1.0)), "-x");
        assert_eq!(show(&(x.clone() / -1.0)), "-x");
        // Constant folding, but only to finite values.
        assert_eq!((c(2.0) * c(3.0) + c(1.0)).as_constant(), Some(7.0));
        assert_eq!(c(2.0).powi(10).as_constant(), Some(1024.0));
        assert_eq!((c(1.0) / c(0.0)).as_constant(), None);
        assert_eq!((c(1.0) / c(0.0)).eval(&[]), f64::INFINITY);
        assert!((c(0.0) / c(0.0)).eval(&[]).is_nan());
        assert_eq!(Expr::call(Func::Ln, vec![c(0.0)]).as_constant(), None);
        assert_eq!(
            Expr::call(Func::Sign, vec![c(-3.0)]).as_constant(),
            Some(-1.0)
        );
        // Value-changing rewrites are not done.
        assert_eq!(show(&(x.clone() / x.clone())), "x/x");
        assert_eq!(show(&(x.clone() - x.clone())), "x - x");
        // Constants merge and move left; signs move out.
        assert_eq!(show(&(c(2.0) * (c(3.0) * x.clone()))), "6*x");
        assert_eq!(show(&(x.clone() * 2.0 * 3.0)), "6*x");
        assert_eq!(show(&(-(x.clone() * 2.0))), "-2*x");
        assert_eq!(show(&(-x.clone() * y())), "-(x*y)");
        assert_eq!(show(&(-x.clone() * -y())), "x*y");
        assert_eq!(show(&(x.clone() + -y())), "x - y");
        assert_eq!(show(&(x.clone() - -y())), "x + y");
        assert_eq!(show(&(-x.clone() + y())), "y - x");
        assert_eq!(show(&(-x.clone() - y())), "-(x + y)");
        assert_eq!(show(&(x.clone() + -2.0)), "x - 2");
        assert_eq!(show(&(x.clone() - -2.0)), "x + 2");
        assert_eq!(show(&(x.clone() * x.clone())), "x^2");
        assert_eq!(show(&(-x.clone() / y())), "-(x/y)");
    }

    #[test]
    fn display() {
        for src in [
            "x^2 + 100*y",
            "-(a + b)",
            "sin(x)",
            "a - (b - x)",
            "a - (b + x)",
            "a + (b + x)",
            "a + b + x",
            "(a + b)*x",
            "a*b*x",
            "a*(b*x)",
            "a/(b*x)",
            "a/b/x",
            "a*b/x",
            "(-x)^2",
            "-x^2",
            "x^y^a",
            "(x^y)^a",
            "2^(-x)",
            "x^(-1)",
            "x^(a*b)",
            "x^(a + b)",
            "(a*b)^x",
            "atan2(y, x)",
            "pow(x, 0.5)",
            "-sin(x)*y",
            "x*(-3)",
            "-3*x",
            "(-3)^x",
            "-(x*sin(y))",
            "x*0.1",
            "1e-7*x",
            "6.02e23*x",
            "abs(x) + sign(y) + sqrt(exp(ln(log10(a))))",
            "-(a/b)",
        ] {
            let e = p(src);
            let shown = show(&e);
            // Round trip: the printed form parses to an expression printed the same.
            assert_eq!(show(&p(&shown)), shown, "{src}");
            let want = match src {
                "a*(b*x)" => "a*(b*x)",
                "pow(x, 0.5)" => "x^0.5",
                "x*(-3)" | "-3*x" => "-3*x",
                "-sin(x)*y" => "-(sin(x)*y)",
                "x*0.1" => "0.1*x",
                _ => src,
            };
            assert_eq!(shown, want, "{src}");
        }
        assert_eq!(show(&c(f64::NAN)), "NaN");
        assert_eq!(show(&c(0.5)), "0.5");
        assert_eq!(show(&c(1e16)), "1e16");
        assert_eq!(show(&c(1234.5)), "1234.5");
    }

    #[test]
    fn display_round_trips_random_expressions() {
        let mut rng = Rng::new(11);
        for _ in 0..300 {
            let mut pool = Vec::new();
            let e = random_expr(&mut rng, 4, 5, &mut pool);
            let shown = show(&e);
            let back = p(&shown);
            let v = [0.3, -1.1, 0.7, 1.9];
            let (a, b) = (e.eval(&v), back.eval(&v));
            assert!(
                a == b || (a - b).abs() <= 1e-12 * a.abs(),
                "{shown}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn vars_depends_on_node_count_substitute() {
        let e = p("sin(x)*b + x^2 - b");
        assert_eq!(e.vars(), vec![0, 3]);
        assert!(e.depends_on(0) && e.depends_on(3));
        assert!(!e.depends_on(1) && !e.depends_on(2));
        assert_eq!(c(1.0).vars(), Vec::<usize>::new());
        // Sharing: s = x*y used three times is one node.
        let s = x() * y();
        let f = &(&s + &s.sin()) * &s.cos();
        // x, y, s, sin s, cos s, +, *
        assert_eq!(f.node_count(), 7);
        // Substitution: x -> a + 1, y -> 2 (constant); b stays.
        let g = e.substitute(&|k| match k {
            0 => Expr::var(2) + 1.0,
            1 => c(2.0),
            k => Expr::var(k),
        });
        assert_eq!(show(&g), "sin(a + 1)*b + (a + 1)^2 - b");
        let v = [0.0, 0.0, 0.4, -1.5];
        assert_eq!(g.eval(&v), e.eval(&[1.4, 0.0, 0.0, -1.5]));
        // Substituting constants folds.
        assert_eq!(
            p("x*y + 1")
                .substitute(&|k| c(k as f64 + 2.0))
                .as_constant(),
            Some(7.0)
        );
        // Unchanged subtrees keep their identity.
        let h = f.substitute(&Expr::var);
        assert!(h.ptr_eq(&f));
    }

    #[test]
    fn eval_matches_eval_generic() {
        let mut rng = Rng::new(3);
        for _ in 0..200 {
            let mut pool = Vec::new();
            let e = random_expr(&mut rng, 3, 6, &mut pool);
            let v = [
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
            ];
            let a = e.eval(&v);
            let b = e.eval_generic(&v);
            let d = e.eval_generic(&v.map(num_dual::Dual64::from)).re;
            assert!(a == b || (a - b).abs() <= 1e-14 * a.abs(), "{a} vs {b}");
            assert!(
                a == d || (a - d).abs() <= 1e-13 * a.abs(),
                "{a} vs {d}: {}",
                e.display_with(&|k| NAMES[k].to_string())
            );
        }
    }

    #[test]
    fn integer_powers() {
        let v = [1.3];
        for n in -17..=17 {
            let e = x().powi(n);
            let want = if n.abs() <= MAX_POWI {
                1.3f64.powi(n)
            } else {
                1.3f64.powf(f64::from(n))
            };
            assert_eq!(e.eval(&v), if n == 2 { 1.3 * 1.3 } else { want }, "{n}");
        }
        assert_eq!(x().powf(&c(2.5)).eval(&v), 1.3f64.powf(2.5));
        assert_eq!(x().powf(&y()).eval(&[1.3, 0.5]), 1.3f64.powf(0.5));
    }

    #[test]
    fn heavy_sharing_and_deep_chains() {
        // Repeated squaring: 40 levels, 41 nodes; evaluation visits each node once.
        let mut e = x();
        for _ in 0..40 {
            e = &e * &(&e + &c(0.0)); // x*x: becomes e^2
        }
        assert_eq!(e.node_count(), 81); // x, 40 squares, 40 constants 2
        assert_eq!(e.eval(&[1.0]), 1.0);
        // A sum of shared terms: x + x with the same node, nested 60 times.
        let mut s = x();
        for _ in 0..60 {
            s = &s + &s;
        }
        assert_eq!(s.node_count(), 61);
        assert_eq!(s.eval(&[1.0]), 2f64.powi(60));
        assert_eq!(s.vars(), vec![0]);
        // A million-node chain builds, evaluates and drops without recursion.
        let mut chain = x();
        for i in 0..1_000_000 {
            chain = if i % 2 == 0 { chain.sin() } else { -chain };
        }
        assert!(chain.eval(&[0.5]).abs() < 0.1);
        assert!(chain.depends_on(0));
        drop(chain);
    }

    #[test]
    #[should_panic(expected = "takes 2 argument(s), got 1")]
    fn call_checks_arity() {
        let _ = Expr::call(Func::Atan2, vec![x()]);
    }

    #[test]
    fn func_names() {
        for f in Func::ALL {
            assert_eq!(Func::from_name(f.name()), Some(f));
            assert_eq!(f.to_string(), f.name());
        }
        assert_eq!(Func::from_name("log"), None);
    }
}
