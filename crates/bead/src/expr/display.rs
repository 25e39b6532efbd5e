//! Printing expressions for people: the infix printer ([`Expr::display_with`]), the same
//! printer with a length limit ([`Expr::display_bounded`]), and a normalization that collects
//! numeric factors before printing ([`Expr::for_display`]). Display only: the tape compiles
//! the expressions exactly as the constructors built them.
//!
//! Derivatives are DAGs that share their subexpressions: the gradient of a product of n
//! factors has O(n) nodes (the partial products are shared), but written out it is a tree of
//! O(n^2) characters, and the acceleration bias one of O(n^3). The bounded printer walks the
//! tree only as far as it prints and measures the rest on the DAG, each shared node once, so
//! it takes time and memory linear in the DAG plus what it prints.
use std::fmt::{self, Write as _};
use std::sync::Arc;

use super::ast::{topo, FastMap, Node};
use super::{Expr, Func};

impl Expr {
    /// Infix form with slot names given by `name`, with the fewest parentheses that keep the
    /// structure: `x^2 + 100*y`, `-(a + b)`, `sin(q)`. Numbers use Rust's shortest round-trip
    /// formatting (`{}`, switching to `{:e}` below 1e-5 and from 1e16 on in magnitude), so the
    /// output parses back to the same tree.
    ///
    /// The whole tree is written out: an expression that shares subexpressions prints each
    /// use in full, which can be far longer than the DAG (see [`Expr::display_bounded`]).
    pub fn display_with<'a>(&'a self, name: &'a dyn Fn(usize) -> String) -> impl fmt::Display + 'a {
        Printer {
            expr: self,
            name,
            limit: None,
            loose: false,
        }
    }

    /// Infix form for reading, stopping once `max_chars` characters are written (at the end
    /// of the token that reaches the limit) with ` ... (N more characters)`, N being what the
    /// whole tree would take. Time and memory are linear in the DAG and in what is printed,
    /// however long the written-out tree would be.
    ///
    /// Unlike [`Expr::display_with`] it leaves out the parentheses that only group a product
    /// (`a*(b*c)` and `a*(b/c)` print as `a*b*c` and `a*b/c`): the text parses back to an
    /// expression of the same value, not necessarily to the same tree.
    ///
    /// ```
    /// use bead::expr::Expr;
    /// // x*(x + 1) nested 40 times shares every level: 81 nodes, 2^40 terms written out.
    /// let mut e = Expr::var(0);
    /// for _ in 0..40 {
    ///     e = &e * &(&e + 1.0);
    /// }
    /// let shown = e.display_bounded(&|_| "x".to_string(), 60).to_string();
    /// assert!(shown.len() < 120, "{shown}");
    /// assert!(shown.ends_with(" more characters)"), "{shown}");
    /// ```
    pub fn display_bounded<'a>(
        &'a self,
        name: &'a dyn Fn(usize) -> String,
        max_chars: usize,
    ) -> impl fmt::Display + 'a {
        Printer {
            expr: self,
            name,
            limit: Some(max_chars),
            loose: true,
        }
    }

    /// An expression of the same value, arranged for reading: the numeric factors of every
    /// product and quotient collected into one coefficient (`2*x/2` is `x`, `-(2*q/100)` is
    /// `-0.02*q`, `2*x/(2*sqrt(u))` is `x/sqrt(u)`), a negative coefficient turned into a
    /// subtraction (`a + -2*b` is `a - 2*b`), `x^-n` written `1/x^n`, and equal
    /// subexpressions merged (so `2*v*v` is `2*v^2`).
    ///
    /// The rewrites are identities of real arithmetic; the value may differ from `self` in
    /// the last bits, where a folded coefficient rounds differently. Nothing is dropped: `x/x`
    /// and `0*x` keep their meaning where the operand is 0 or not finite. Linear in the number
    /// of distinct nodes; the result shares subexpressions as `self` does. For printing
    /// (`bead check`), not for evaluation.
    pub fn for_display(&self) -> Expr {
        Tidy::new(self).run()
    }
}

// ---------------------------------------------------------------------------------------
// The printer.

struct Printer<'a> {
    expr: &'a Expr,
    name: &'a dyn Fn(usize) -> String,
    limit: Option<usize>,
    /// Leave out the parentheses that only group a product (`a*(b*c)`).
    loose: bool,
}

/// Where a subexpression is printed, to decide on parentheses.
#[derive(Clone, Copy)]
enum Pos {
    Top,
    AddL,
    AddR,
    MulL,
    /// Right of `*`
    MulR,
    /// Right of `/`
    DivR,
    NegArg,
    PowBase,
    PowExp,
}

/// 1: sum, 2: product, 3: negation (incl. negative constants), 4: power, 5: atom.
fn class(n: &Node) -> u8 {
    match n {
        Node::Add(..) | Node::Sub(..) => 1,
        Node::Mul(..) | Node::Div(..) => 2,
        Node::Neg(_) => 3,
        Node::Const(c) if c.is_sign_negative() => 3,
        Node::Pow(..) => 4,
        _ => 5,
    }
}

/// Whether `n` printed at `pos` needs parentheses; `loose`: not around a product right of
/// `*`, which only groups it.
fn needs_parens(n: &Node, pos: Pos, loose: bool) -> bool {
    let c = class(n);
    match pos {
        Pos::Top | Pos::AddL => false,
        Pos::AddR => c <= 1 || c == 3,
        Pos::MulL => c <= 1,
        Pos::MulR if loose && c == 2 => false,
        Pos::MulR | Pos::DivR | Pos::NegArg | Pos::PowExp => c <= 3,
        Pos::PowBase => c <= 4,
    }
}

/// Shortest round-trip formatting, in exponent form for very large or small magnitudes.
fn number_text(c: f64) -> String {
    let m = c.abs();
    if c.is_finite() && m != 0.0 && !(1e-5..1e16).contains(&m) {
        format!("{c:e}")
    } else {
        format!("{c}")
    }
}

/// The operator between the children of a binary node, with the children's positions.
fn binary(n: &Node) -> Option<(&'static str, Pos, Pos)> {
    Some(match n {
        Node::Add(..) => (" + ", Pos::AddL, Pos::AddR),
        Node::Sub(..) => (" - ", Pos::AddL, Pos::AddR),
        Node::Mul(..) => ("*", Pos::MulL, Pos::MulR),
        Node::Div(..) => ("/", Pos::MulL, Pos::DivR),
        Node::Pow(..) => ("^", Pos::PowBase, Pos::PowExp),
        _ => return None,
    })
}

/// The number of characters `root` prints as, written out in full: computed on the DAG (each
/// shared node once), saturating at `u64::MAX`.
fn printed_length(root: &Expr, name: &dyn Fn(usize) -> String, loose: bool) -> u64 {
    let t = topo([root]);
    let mut length: Vec<u64> = Vec::with_capacity(t.nodes.len());
    for (e, &[ia, ib]) in t.nodes.iter().zip(&t.kids) {
        let child = |i: u32, pos: Pos| {
            let parens = if needs_parens(&t.nodes[i as usize].0, pos, loose) {
                2
            } else {
                0
            };
            length[i as usize].saturating_add(parens)
        };
        let n = match &*e.0 {
            Node::Const(c) => number_text(*c).len() as u64,
            Node::Var(k) => name(*k).chars().count() as u64,
            Node::Neg(_) => child(ia, Pos::NegArg).saturating_add(1),
            // name(...)
            Node::Unary(f, _) => child(ia, Pos::Top).saturating_add(f.name().len() as u64 + 2),
            // atan2(y, x)
            Node::Atan2(..) => child(ia, Pos::Top)
                .saturating_add(child(ib, Pos::Top))
                .saturating_add(9),
            n => {
                let (op, pa, pb) = binary(n).expect("every other node is binary");
                child(ia, pa)
                    .saturating_add(child(ib, pb))
                    .saturating_add(op.len() as u64)
            }
        };
        length.push(n);
    }
    length[t.roots[0] as usize]
}

/// Writes through to a formatter, counting characters.
struct Counted<'a, 'b> {
    out: &'a mut fmt::Formatter<'b>,
    chars: u64,
}

impl fmt::Write for Counted<'_, '_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.chars += s.chars().count() as u64;
        self.out.write_str(s)
    }
}

impl fmt::Display for Printer<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        enum Task<'b> {
            E(&'b Expr, Pos),
            S(&'static str),
        }
        // (limit, full length) when the expression is longer than the limit.
        let cut = self.limit.and_then(|limit| {
            let full = printed_length(self.expr, self.name, self.loose);
            (full > limit as u64).then_some((limit as u64, full))
        });
        let mut out = Counted { out: f, chars: 0 };
        let mut stack = vec![Task::E(self.expr, Pos::Top)];
        while let Some(task) = stack.pop() {
            if let Some((limit, full)) = cut {
                if out.chars >= limit {
                    return if full == u64::MAX {
                        out.write_str(" ... (more than 10^19 characters in all)")
                    } else {
                        write!(out, " ... ({} more characters)", full - out.chars)
                    };
                }
            }
            let (e, pos) = match task {
                Task::S(s) => {
                    out.write_str(s)?;
                    continue;
                }
                Task::E(e, pos) => (e, pos),
            };
            if needs_parens(&e.0, pos, self.loose) {
                out.write_str("(")?;
                stack.push(Task::S(")"));
            }
            match &*e.0 {
                Node::Const(c) => out.write_str(&number_text(*c))?,
                Node::Var(k) => out.write_str(&(self.name)(*k))?,
                Node::Neg(a) => {
                    out.write_str("-")?;
                    stack.push(Task::E(a, Pos::NegArg));
                }
                Node::Unary(func, a) => {
                    out.write_str(func.name())?;
                    out.write_str("(")?;
                    stack.push(Task::S(")"));
                    stack.push(Task::E(a, Pos::Top));
                }
                Node::Atan2(y, x) => {
                    out.write_str("atan2(")?;
                    stack.push(Task::S(")"));
                    stack.push(Task::E(x, Pos::Top));
                    stack.push(Task::S(", "));
                    stack.push(Task::E(y, Pos::Top));
                }
                Node::Add(a, b)
                | Node::Sub(a, b)
                | Node::Mul(a, b)
                | Node::Div(a, b)
                | Node::Pow(a, b) => {
                    let (op, pa, pb) = binary(&e.0).expect("binary node");
                    stack.push(Task::E(b, pb));
                    stack.push(Task::S(op));
                    stack.push(Task::E(a, pa));
                }
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// Collecting numeric factors.

/// `num / den * n / d`: a product or quotient with its numeric factors collected (`num`, `den`
/// normal numbers, `den > 0`) and the rest (`None` for 1).
#[derive(Clone)]
struct Frac {
    num: f64,
    den: f64,
    n: Option<Expr>,
    d: Option<Expr>,
}

impl Frac {
    /// An expression whose factors are not looked into.
    fn opaque(e: Expr) -> Frac {
        Frac {
            num: 1.0,
            den: 1.0,
            n: Some(e),
            d: None,
        }
    }

    fn negated(&self) -> Frac {
        Frac {
            num: -self.num,
            ..self.clone()
        }
    }

    /// The same value with `den > 0`.
    fn with_positive_den(mut self) -> Frac {
        if self.den < 0.0 {
            self.num = -self.num;
            self.den = -self.den;
        }
        self
    }
}

/// `num/den` in lowest terms when both are integers (exactly, below 2^53).
fn reduced(num: f64, den: f64) -> (f64, f64) {
    const EXACT: f64 = 9_007_199_254_740_992.0;
    let integer = |x: f64| x.fract() == 0.0 && x.abs() < EXACT;
    if !(integer(num) && integer(den)) {
        return (num, den);
    }
    let (mut a, mut b) = (num.abs() as u64, den.abs() as u64);
    while b != 0 {
        (a, b) = (b, a % b);
    }
    let g = a as f64;
    (num / g, den / g)
}

/// A node of the result, by its operator and its children's identities (the result is
/// hash-consed, so identity is structure).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
enum Key {
    Const(u64),
    Var(usize),
    Neg(usize),
    /// 0 add, 1 sub, 2 mul, 3 div, 4 pow, 5 atan2
    Binary(u8, usize, usize),
    Unary(Func, usize),
}

struct Tidy<'a> {
    t: super::ast::Topo<'a>,
    /// Per node of the input (topological index): its collected form.
    fracs: Vec<Frac>,
    /// Per node of the input: its collected form as an expression, once asked for.
    built: Vec<Option<Expr>>,
    nodes: FastMap<Key, Expr>,
}

impl<'a> Tidy<'a> {
    fn new(root: &'a Expr) -> Tidy<'a> {
        let t = topo([root]);
        let n = t.nodes.len();
        Tidy {
            t,
            fracs: Vec::with_capacity(n),
            built: vec![None; n],
            nodes: FastMap::default(),
        }
    }

    /// The node `n`, shared with an equal one built before.
    fn node(&mut self, n: Node) -> Expr {
        let id = |e: &Expr| Arc::as_ptr(&e.0) as usize;
        let key = match &n {
            Node::Const(c) => Key::Const(c.to_bits()),
            Node::Var(k) => Key::Var(*k),
            Node::Neg(a) => Key::Neg(id(a)),
            Node::Add(a, b) => Key::Binary(0, id(a), id(b)),
            Node::Sub(a, b) => Key::Binary(1, id(a), id(b)),
            Node::Mul(a, b) => Key::Binary(2, id(a), id(b)),
            Node::Div(a, b) => Key::Binary(3, id(a), id(b)),
            Node::Pow(a, b) => Key::Binary(4, id(a), id(b)),
            Node::Atan2(a, b) => Key::Binary(5, id(a), id(b)),
            Node::Unary(f, a) => Key::Unary(*f, id(a)),
        };
        self.nodes
            .entry(key)
            .or_insert_with(|| Expr(Arc::new(n)))
            .clone()
    }

    fn constant(&mut self, c: f64) -> Expr {
        self.node(Node::Const(c))
    }

    /// `a * b` of two optional factors (`None` is 1); `a * a` is `a^2`.
    fn times(&mut self, a: Option<Expr>, b: Option<Expr>) -> Option<Expr> {
        match (a, b) {
            (None, x) | (x, None) => x,
            (Some(a), Some(b)) if a.ptr_eq(&b) => {
                let two = self.constant(2.0);
                Some(self.node(Node::Pow(a, two)))
            }
            (Some(a), Some(b)) => Some(self.node(Node::Mul(a, b))),
        }
    }

    /// `f` as an expression, with its coefficient written the shortest exact way.
    fn build(&mut self, f: &Frac) -> Expr {
        let (num, den) = (f.num, f.den);
        let c = num / den;
        let short =
            |c: f64| number_text(c).len() <= number_text(num).len() + number_text(den).len();
        let (top, bottom) = if den == 1.0 || c.abs() == 1.0 {
            (c, 1.0)
        } else if num.abs() == 1.0 {
            // x/2 rather than 0.5*x, z/0.2 as written rather than 5*z
            (num, den)
        } else if c.is_normal() && short(c) {
            // 0.02*q rather than 2*q/100, 2*x/y rather than 4*x/(2*y)
            (c, 1.0)
        } else {
            // 2*x/3 rather than 0.6666666666666666*x, x/2 rather than 2*x/4
            reduced(num, den)
        };
        let numerator = match (top, f.n.clone()) {
            (t, None) => self.constant(t),
            (1.0, Some(n)) => n,
            (-1.0, Some(n)) => self.node(Node::Neg(n)),
            (t, Some(n)) => {
                let t = self.constant(t);
                self.node(Node::Mul(t, n))
            }
        };
        let denominator = match (bottom, f.d.clone()) {
            (1.0, None) => return numerator,
            (b, None) => self.constant(b),
            (1.0, Some(d)) => d,
            (b, Some(d)) => {
                let b = self.constant(b);
                self.node(Node::Mul(b, d))
            }
        };
        self.node(Node::Div(numerator, denominator))
    }

    /// Input node `i` in its collected form, as an expression.
    fn built(&mut self, i: u32) -> Expr {
        let i = i as usize;
        if let Some(e) = &self.built[i] {
            return e.clone();
        }
        let f = self.fracs[i].clone();
        let e = self.build(&f);
        self.built[i] = Some(e.clone());
        e
    }

    /// Input node `i` as a term of a sum: (whether it is subtracted, its magnitude).
    fn term(&mut self, i: u32) -> (bool, Expr) {
        let f = &self.fracs[i as usize];
        if f.num < 0.0 {
            let positive = f.negated();
            (true, self.build(&positive))
        } else {
            (false, self.built(i))
        }
    }

    /// The collected form of input node `i`, its children's being known.
    fn collect(&mut self, i: usize) -> Frac {
        let e = self.t.nodes[i];
        let [ia, ib] = self.t.kids[i];
        let frac = |s: &Self, k: u32| s.fracs[k as usize].clone();
        match &*e.0 {
            Node::Const(c) if c.is_normal() => Frac {
                num: *c,
                den: 1.0,
                n: None,
                d: None,
            },
            Node::Const(c) => Frac::opaque(self.constant(*c)),
            Node::Var(k) => Frac::opaque(self.node(Node::Var(*k))),
            Node::Neg(_) => frac(self, ia).negated(),
            Node::Mul(..) => {
                let (a, b) = (frac(self, ia), frac(self, ib));
                let (num, den) = (a.num * b.num, a.den * b.den);
                if num.is_normal() && den.is_normal() {
                    Frac {
                        num,
                        den,
                        n: self.times(a.n, b.n),
                        d: self.times(a.d, b.d),
                    }
                } else {
                    let (a, b) = (self.built(ia), self.built(ib));
                    Frac::opaque(self.node(Node::Mul(a, b)))
                }
            }
            Node::Div(..) => {
                let (a, b) = (frac(self, ia), frac(self, ib));
                let (num, den) = (a.num * b.den, a.den * b.num);
                if num.is_normal() && den.is_normal() {
                    Frac {
                        num,
                        den,
                        n: self.times(a.n, b.d),
                        d: self.times(a.d, b.n),
                    }
                    .with_positive_den()
                } else {
                    let (a, b) = (self.built(ia), self.built(ib));
                    Frac::opaque(self.node(Node::Div(a, b)))
                }
            }
            Node::Pow(_, exponent) => match exponent.as_constant() {
                // a^-1 = 1/a, with a's coefficient inverted
                Some(-1.0) => {
                    let a = frac(self, ia);
                    Frac {
                        num: a.den,
                        den: a.num,
                        n: a.d,
                        d: a.n,
                    }
                    .with_positive_den()
                }
                // a^-c = 1/a^c
                Some(c) if c < 0.0 && c.is_finite() => {
                    let a = self.built(ia);
                    let c = self.constant(-c);
                    Frac {
                        num: 1.0,
                        den: 1.0,
                        n: None,
                        d: Some(self.node(Node::Pow(a, c))),
                    }
                }
                _ => {
                    let (a, b) = (self.built(ia), self.built(ib));
                    Frac::opaque(self.node(Node::Pow(a, b)))
                }
            },
            Node::Unary(f, _) => {
                let a = self.built(ia);
                Frac::opaque(self.node(Node::Unary(*f, a)))
            }
            Node::Atan2(..) => {
                let (y, x) = (self.built(ia), self.built(ib));
                Frac::opaque(self.node(Node::Atan2(y, x)))
            }
            Node::Add(..) | Node::Sub(..) => {
                let a = self.built(ia);
                let (minus, b) = self.term(ib);
                let subtract = minus != matches!(*e.0, Node::Sub(..));
                Frac::opaque(self.node(if subtract {
                    Node::Sub(a, b)
                } else {
                    Node::Add(a, b)
                }))
            }
        }
    }

    fn run(mut self) -> Expr {
        for i in 0..self.t.nodes.len() {
            let f = self.collect(i);
            self.fracs.push(f);
        }
        let root = self.t.roots[0];
        self.built(root)
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

    fn name(k: usize) -> String {
        NAMES[k].to_string()
    }

    fn show(e: &Expr) -> String {
        e.display_with(&name).to_string()
    }

    /// For reading, without a limit.
    fn read(e: &Expr) -> String {
        e.display_bounded(&name, usize::MAX).to_string()
    }

    /// `src` parsed, collected and printed.
    fn tidy(src: &str) -> String {
        show(&p(src).for_display())
    }

    #[test]
    fn constant_factors_fold() {
        assert_eq!(tidy("2*a/2"), "a");
        assert_eq!(tidy("-(2*x/100)"), "-0.02*x");
        assert_eq!(tidy("2*x/(2*sqrt(y))"), "x/sqrt(y)");
        assert_eq!(tidy("x/2"), "x/2");
        assert_eq!(tidy("(x + y)/2"), "(x + y)/2");
        assert_eq!(tidy("3*x/2"), "3*x/2");
        assert_eq!(tidy("x/0.2"), "x/0.2");
        assert_eq!(tidy("2*x/4"), "x/2");
        assert_eq!(tidy("2*x/3"), "2*x/3");
        assert_eq!(tidy("2*x/(3*y)"), "2*x/(3*y)");
        assert_eq!(tidy("4*x/(2*y)"), "2*x/y");
        assert_eq!(tidy("1/(2*sqrt(x))"), "1/(2*sqrt(x))");
        assert_eq!(tidy("-2*x/2*y"), "-(x*y)");
        assert_eq!(tidy("-x/y"), "-x/y");
        assert_eq!(tidy("x/(1/y)"), "x*y");
        assert_eq!(tidy("x^-1"), "1/x");
        assert_eq!(tidy("(2*x)^-1"), "1/(2*x)");
        assert_eq!(tidy("3*x^-2"), "3/x^2");
    }

    #[test]
    fn signs_become_subtractions() {
        assert_eq!(tidy("a + -2*b"), "a - 2*b");
        assert_eq!(
            tidy("2*(a - b)/2*x + -2*(a - b)/2*y"),
            "(a - b)*x - (a - b)*y"
        );
        assert_eq!(tidy("a - -2*b/4"), "a + b/2");
        assert_eq!(tidy("-(a + b)"), "-(a + b)");
        assert_eq!(tidy("-2*a + b"), "-2*a + b");
    }

    #[test]
    fn equal_subexpressions_merge() {
        assert_eq!(tidy("2*x*x"), "2*x^2");
        assert_eq!(tidy("sin(x)*sin(x)"), "sin(x)^2");
    }

    #[test]
    fn value_changing_rewrites_are_not_done() {
        assert_eq!(tidy("x/x"), "x/x");
        assert_eq!(tidy("x - x"), "x - x");
        assert_eq!(tidy("1/0"), "1/0");
        assert_eq!(tidy("0/0"), "0/0");
        // A coefficient that would overflow is not folded.
        assert_eq!(tidy("x*1e300*1e300"), "1e300*(1e300*x)");
    }

    /// Collected, printed and parsed back, random expressions keep their value.
    #[test]
    fn collected_forms_keep_the_value() {
        let mut rng = Rng::new(17);
        for _ in 0..400 {
            let mut pool = Vec::new();
            let e = random_expr(&mut rng, 4, 5, &mut pool);
            let tidy = e.for_display();
            let back = p(&show(&tidy));
            let v = [
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
            ];
            let want = e.eval(&v);
            for got in [tidy.eval(&v), back.eval(&v)] {
                assert!(
                    got == want || (got - want).abs() <= 1e-9 * (1.0 + want.abs()),
                    "{} -> {}: {got} vs {want}",
                    show(&e),
                    show(&tidy)
                );
            }
        }
    }

    #[test]
    fn printed_length_matches_the_printer() {
        let mut rng = Rng::new(23);
        for _ in 0..300 {
            let mut pool = Vec::new();
            let e = random_expr(&mut rng, 4, 6, &mut pool);
            for e in [e.clone(), e.for_display(), e.derivative(0)] {
                let (exact, loose) = (show(&e), read(&e));
                let count = |s: &str| s.chars().count() as u64;
                assert_eq!(printed_length(&e, &name, false), count(&exact), "{exact}");
                assert_eq!(printed_length(&e, &name, true), count(&loose), "{loose}");
                // Up to the limit the bounded printer prints everything.
                assert_eq!(e.display_bounded(&name, loose.len()).to_string(), loose);
                // The loose form has the same value.
                let v = [0.3, -1.1, 0.7, 1.9];
                let (a, b) = (e.eval(&v), p(&loose).eval(&v));
                assert!(
                    a == b || (a - b).abs() <= 1e-12 * (1.0 + a.abs()),
                    "{loose}"
                );
            }
        }
    }

    #[test]
    fn reading_drops_only_the_grouping_of_products() {
        for (src, want) in [
            ("a*(b*x)", "a*b*x"),
            ("a*(b/x)", "a*b/x"),
            ("a/(b*x)", "a/(b*x)"),
            ("a/(b/x)", "a/(b/x)"),
            ("a - (b + x)", "a - (b + x)"),
            ("a*(-b)", "-(a*b)"),
            ("x*(y + 1)", "x*(y + 1)"),
        ] {
            assert_eq!(read(&p(src)), want, "{src}");
        }
    }

    #[test]
    fn bounded_printing_stops_and_counts_the_rest() {
        let e = p("x + y*sin(a) + b^2 + x*y");
        let full = show(&e);
        assert_eq!(full, "x + y*sin(a) + b^2 + x*y");
        let cut = e.display_bounded(&name, 10).to_string();
        // Stops once 10 characters are out, after a whole token.
        assert_eq!(cut, "x + y*sin( ... (14 more characters)");
        let cut = e.display_bounded(&name, 8).to_string();
        assert_eq!(cut, "x + y*sin( ... (14 more characters)");
        assert_eq!(
            e.display_bounded(&name, 0).to_string(),
            " ... (24 more characters)"
        );
    }

    #[test]
    fn shared_dags_print_in_bounded_time() {
        // Each level used twice: 2^60 leaves written out, 61 distinct nodes.
        let mut s = Expr::var(0);
        for _ in 0..60 {
            s = &s * &(&s + &Expr::var(1));
        }
        assert!(s.node_count() < 200);
        let shown = s.display_bounded(&name, 100).to_string();
        assert!(shown.len() < 150, "{shown}");
        assert!(shown.contains(" ... ("), "{shown}");
        // More than u64 can count.
        for _ in 0..10 {
            s = &s * &(&s + &Expr::var(1));
        }
        let shown = s.display_bounded(&name, 100).to_string();
        assert!(
            shown.ends_with("(more than 10^19 characters in all)"),
            "{shown}"
        );
        // The collected form stays as small.
        assert!(s.for_display().node_count() <= 2 * s.node_count());
    }
}
