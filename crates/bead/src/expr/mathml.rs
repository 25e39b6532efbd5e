//! Expressions as MathML (Core), for typeset equations that a browser renders itself (the
//! viewer's "equations"): fractions as fractions, powers as superscripts, square roots
//! under a radical, with the same parentheses rules as the infix printer.
use std::fmt::Write as _;

use super::ast::Node;
use super::{Expr, Func};

/// How far into a tree the MathML printer goes before writing "…": deeper levels are not
/// worth typesetting and would only stress the recursion.
const MAX_DEPTH: usize = 60;

/// 1: sum, 2: product (not a fraction), 3: negation, 4: power, 5: atom (incl. a fraction).
fn class(n: &Node) -> u8 {
    match n {
        Node::Add(..) | Node::Sub(..) => 1,
        Node::Mul(..) => 2,
        Node::Neg(_) => 3,
        Node::Const(c) if c.is_sign_negative() => 3,
        Node::Pow(..) => 4,
        _ => 5,
    }
}

/// Where a subexpression goes, to decide on parentheses.
#[derive(Clone, Copy)]
enum Pos {
    Top,
    AddR,
    MulL,
    MulR,
    NegArg,
    PowBase,
}

fn needs_parens(n: &Node, pos: Pos) -> bool {
    let c = class(n);
    match pos {
        Pos::Top => false,
        Pos::AddR => c == 1 || c == 3,
        Pos::MulL => c <= 1,
        Pos::MulR | Pos::NegArg => c <= 3,
        Pos::PowBase => c <= 4,
    }
}

/// `text` with `<`, `>` and `&` escaped, for MathML text content.
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// A number as MathML: `<mn>2.5</mn>`, `1.5 × 10^-7` for exponent forms.
fn number(c: f64) -> String {
    let m = c.abs();
    let text = if c.is_finite() && m != 0.0 && !(1e-5..1e16).contains(&m) {
        format!("{m:e}")
    } else {
        format!("{m}")
    };
    let body = match text.split_once('e') {
        Some((mantissa, exponent)) => {
            format!("<mn>{mantissa}</mn><mo>×</mo><msup><mn>10</mn><mn>{exponent}</mn></msup>")
        }
        None => format!("<mn>{text}</mn>"),
    };
    if c.is_sign_negative() {
        format!("<mrow><mo>−</mo>{body}</mrow>")
    } else {
        body
    }
}

struct Printer<'a> {
    name: &'a dyn Fn(usize) -> String,
    /// Nodes left to write before "…".
    budget: usize,
    out: String,
}

impl Printer<'_> {
    fn write(&mut self, e: &Expr, pos: Pos, depth: usize) {
        if self.budget == 0 || depth > MAX_DEPTH {
            if !self.out.ends_with("<mi>…</mi>") {
                self.out.push_str("<mi>…</mi>");
            }
            self.budget = 0;
            return;
        }
        self.budget -= 1;
        let parens = needs_parens(&e.0, pos);
        self.out.push_str("<mrow>");
        if parens {
            self.out.push_str("<mo>(</mo>");
        }
        let d = depth + 1;
        match &*e.0 {
            Node::Const(c) => self.out.push_str(&number(*c)),
            Node::Var(k) => {
                let name = (self.name)(*k);
                self.out.push_str(&name);
            }
            Node::Neg(a) => {
                self.out.push_str("<mo>−</mo>");
                self.write(a, Pos::NegArg, d);
            }
            Node::Add(a, b) | Node::Sub(a, b) => {
                self.write(a, Pos::Top, d);
                let op = if matches!(&*e.0, Node::Add(..)) {
                    "+"
                } else {
                    "−"
                };
                let _ = write!(self.out, "<mo>{op}</mo>");
                self.write(b, Pos::AddR, d);
            }
            Node::Mul(a, b) => {
                self.write(a, Pos::MulL, d);
                // A visible dot between two numbers (or before one), none elsewhere.
                let number_next = matches!(&*b.0, Node::Const(_));
                self.out.push_str(if number_next {
                    "<mo>·</mo>"
                } else {
                    "<mo>\u{2062}</mo>"
                });
                self.write(b, Pos::MulR, d);
            }
            Node::Div(a, b) => {
                self.out.push_str("<mfrac>");
                self.write(a, Pos::Top, d);
                self.write(b, Pos::Top, d);
                self.out.push_str("</mfrac>");
            }
            Node::Pow(a, b) => {
                self.out.push_str("<msup>");
                self.write(a, Pos::PowBase, d);
                self.write(b, Pos::Top, d);
                self.out.push_str("</msup>");
            }
            Node::Unary(Func::Sqrt, a) => {
                self.out.push_str("<msqrt>");
                self.write(a, Pos::Top, d);
                self.out.push_str("</msqrt>");
            }
            Node::Unary(Func::Abs, a) => {
                self.out.push_str("<mo>|</mo>");
                self.write(a, Pos::Top, d);
                self.out.push_str("<mo>|</mo>");
            }
            Node::Unary(f, a) => {
                let _ = write!(self.out, "<mi>{}</mi><mo>\u{2061}</mo><mo>(</mo>", f.name());
                self.write(a, Pos::Top, d);
                self.out.push_str("<mo>)</mo>");
            }
            Node::Atan2(y, x) => {
                self.out
                    .push_str("<mi>atan2</mi><mo>\u{2061}</mo><mo>(</mo>");
                self.write(y, Pos::Top, d);
                self.out.push_str("<mo>,</mo>");
                self.write(x, Pos::Top, d);
                self.out.push_str("<mo>)</mo>");
            }
        }
        if parens {
            self.out.push_str("<mo>)</mo>");
        }
        self.out.push_str("</mrow>");
    }
}

impl Expr {
    /// MathML (Core) presentation markup of `self`, an `<mrow>`: slots written by `name` (which
    /// returns MathML, e.g. `<mi>x</mi>`), at most `max_nodes` nodes of the written-out tree
    /// (then "…"). Arrange the expression for reading first with [`Expr::for_display`].
    ///
    /// ```
    /// use bead::expr::Expr;
    /// let x = Expr::var(0);
    /// let e = (&x * &x) / 100.0;
    /// let m = e.mathml(&|_| "<mi>x</mi>".into(), 100);
    /// assert!(m.contains("<mfrac>") && m.contains("<mn>100</mn>"), "{m}");
    /// ```
    pub fn mathml(&self, name: &dyn Fn(usize) -> String, max_nodes: usize) -> String {
        let mut printer = Printer {
            name,
            budget: max_nodes.max(1),
            out: String::new(),
        };
        printer.write(self, Pos::Top, 0);
        printer.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn show(e: &Expr) -> String {
        e.mathml(&|k| format!("<mi>v{k}</mi>"), 1000)
            .replace("<mrow>", "")
            .replace("</mrow>", "")
    }

    #[test]
    fn parentheses_follow_precedence() {
        let (a, b, c) = (Expr::var(0), Expr::var(1), Expr::var(2));
        // (a + b) * c needs them, a + b * c does not.
        let m = show(&(&(&a + &b) * &c));
        assert!(m.starts_with("<mo>(</mo><mi>v0</mi><mo>+</mo>"), "{m}");
        let m = show(&(&a + &(&b * &c)));
        assert!(!m.contains("<mo>(</mo>"), "{m}");
        // a - (b - c): the right operand of a difference keeps its parentheses.
        let m = show(&(&a - &(&b - &c)));
        assert!(m.contains("<mo>−</mo><mo>(</mo><mi>v1</mi>"), "{m}");
        // (a + b)^2 and a fraction's parts without parentheses.
        let m = show(&(&a + &b).powi(2));
        assert!(m.starts_with("<msup><mo>(</mo>"), "{m}");
        let m = show(&(&(&a + &b) / &(&b + &c)));
        assert!(!m.contains("<mo>(</mo>"), "{m}");
        assert!(m.starts_with("<mfrac>"), "{m}");
    }

    #[test]
    fn numbers_functions_and_limits() {
        let x = Expr::var(0);
        assert_eq!(show(&Expr::constant(-2.5)), "<mo>−</mo><mn>2.5</mn>");
        assert!(show(&Expr::constant(1.5e-7)).contains("<msup><mn>10</mn><mn>-7</mn></msup>"));
        assert!(show(&x.sqrt()).starts_with("<msqrt>"));
        assert!(show(&x.sin()).starts_with("<mi>sin</mi>"));
        // A long sum is cut with "…", the markup still well nested.
        let mut e = x.clone();
        for k in 1..200 {
            e = &e + &Expr::var(k);
        }
        let m = e.mathml(&|k| format!("<mi>v{k}</mi>"), 50);
        assert!(m.contains("<mi>…</mi>"), "{m}");
        assert_eq!(m.matches("<mrow>").count(), m.matches("</mrow>").count());
    }
}
