//! Parser: a recursive-descent parser over an on-the-fly tokenizer, with byte spans.
//!
//! Grammar (whitespace between tokens is ignored):
//!
//! ```text
//! sum     := product (("+" | "-") product)*            left-associative
//! product := unary (("*" | "/") unary)*                left-associative
//! unary   := ("-" | "+") unary | power
//! power   := primary ("^" unary)?                      right-associative, binds tighter
//!                                                      than unary minus: -x^2 = -(x^2)
//! primary := number | name | function "(" sum ("," sum)* ")" | "(" sum ")"
//! number  := digits ["." digits?] [exponent] | "." digits [exponent]
//! exponent:= ("e" | "E") ["+" | "-"] digits
//! name    := ident ("." ident)*          ident := (XID_Start | "_") XID_Continue*
//! ```
//!
//! Identifiers follow Unicode's UAX #31, as Rust's do: a letter of any script or `_`, then
//! letters, digits, `_` and combining marks: `α`, `bead_2`, `θ_1`, but not `x²` or `θ₁`
//! (superscripts and subscripts are not digits). Particle, parameter and coordinate names follow the same rule
//! ([`is_identifier`]), so that every name a scene accepts can be written in an expression.
//!
//! Nesting (parentheses, calls, prefix signs, exponents) is limited to [`MAX_DEPTH`] levels so
//! hostile input cannot overflow the stack; everything else is linear in the input length.
use super::ast::{self, Func};
use super::Expr;

/// Maximum nesting depth of parentheses, function calls, prefix signs and exponents.
pub const MAX_DEPTH: usize = 256;

/// A byte range in the expression source.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Span {
    /// First byte.
    pub start: usize,
    /// One past the last byte (equal to `start` for an empty span, e.g. at end of input).
    pub end: usize,
}

impl Span {
    fn new(start: usize, end: usize) -> Span {
        Span { start, end }
    }
}

/// What a name means: a variable slot or a known number (a scene parameter, pi, e).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Resolved {
    /// Variable slot `k`.
    Var(usize),
    /// A constant.
    Value(f64),
}

/// A parse or name error at `span` of the expression source.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ExprError {
    /// What went wrong and what was expected.
    pub message: String,
    /// Where, in bytes of the source (always on `char` boundaries of the parsed source).
    pub span: Span,
}

/// Largest byte index `<= i` that is a char boundary of `s` (and `<= s.len()`).
fn floor_boundary(s: &str, i: usize) -> usize {
    let mut i = i.min(s.len());
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// 1-based column (in chars) of byte `pos` within its line.
fn column(source: &str, pos: usize) -> usize {
    let pos = floor_boundary(source, pos);
    let line_start = source[..pos].rfind('\n').map_or(0, |i| i + 1);
    source[line_start..pos].chars().count() + 1
}

impl ExprError {
    fn new(message: impl Into<String>, span: Span) -> ExprError {
        ExprError {
            message: message.into(),
            span,
        }
    }

    /// The source line with a caret line under `span`, e.g.
    /// ```text
    /// bead.x^2 + 100*bead.w
    ///                ^^^^^^
    /// ```
    /// There is always at least one caret; for an error at the end of input it sits just
    /// after the last character. Tabs in the line are repeated in the caret line so the
    /// carets line up. Never panics, even for a span that does not fit `source`.
    pub fn caret(&self, source: &str) -> String {
        let start = floor_boundary(source, self.span.start);
        let end = floor_boundary(source, self.span.end.max(start));
        let line_start = source[..start].rfind('\n').map_or(0, |i| i + 1);
        let line_end = source[start..]
            .find('\n')
            .map_or(source.len(), |i| start + i);
        let line = source[line_start..line_end].trim_end_matches('\r');
        let marked_end = end.min(line_start + line.len()).max(start);
        crate::caret_snippet(line, start - line_start, marked_end - line_start)
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Tok {
    Num(f64),
    Name,
    Plus,
    Minus,
    Star,
    Slash,
    Caret,
    LParen,
    RParen,
    Comma,
    End,
}

#[derive(Clone, Copy, Debug)]
struct Token {
    tok: Tok,
    span: Span,
}

fn is_ident_start(c: char) -> bool {
    c == '_' || unicode_ident::is_xid_start(c)
}

fn is_ident_char(c: char) -> bool {
    unicode_ident::is_xid_continue(c)
}

/// Whether `name` is one identifier of an expression (no dots): a letter of any script or
/// `_`, then letters, digits, `_` or combining marks (Unicode XID, as in Rust: `bead`, `α`,
/// `_q2`, `θ_1`). Names of particles, parameters and coordinates must be identifiers.
///
/// ```
/// use bead::expr::is_identifier;
/// assert!(is_identifier("α") && is_identifier("bead_2") && is_identifier("_q"));
/// assert!(!is_identifier("2a") && !is_identifier("a.b") && !is_identifier("x²") && !is_identifier(""));
/// ```
pub fn is_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(is_ident_start) && chars.all(is_ident_char)
}

struct Parser<'s, 'r> {
    src: &'s str,
    pos: usize,
    peeked: Option<Token>,
    depth: usize,
    resolve: &'r dyn Fn(&str) -> Result<Resolved, String>,
}

impl<'s> Parser<'s, '_> {
    fn text(&self, span: Span) -> &'s str {
        &self.src[span.start..span.end]
    }

    fn err<T>(&self, message: impl Into<String>, span: Span) -> Result<T, ExprError> {
        Err(ExprError::new(message, span))
    }

    /// Scan the next token starting at `self.pos`.
    fn lex(&mut self) -> Result<Token, ExprError> {
        let bytes = self.src.as_bytes();
        let mut i = self.pos;
        while i < bytes.len() && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        let start = i;
        let single = |tok| (tok, start + 1);
        let (tok, end) = match bytes.get(i) {
            None => (Tok::End, start),
            Some(b'+') => single(Tok::Plus),
            Some(b'-') => single(Tok::Minus),
            Some(b'*') => single(Tok::Star),
            Some(b'/') => single(Tok::Slash),
            Some(b'^') => single(Tok::Caret),
            Some(b'(') => single(Tok::LParen),
            Some(b')') => single(Tok::RParen),
            Some(b',') => single(Tok::Comma),
            Some(&b)
                if b.is_ascii_digit()
                    || (b == b'.' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit)) =>
            {
                return self.lex_number(start);
            }
            Some(_) if self.src[i..].chars().next().is_some_and(is_ident_start) => {
                let mut j = i;
                loop {
                    j += self.src[j..]
                        .chars()
                        .take_while(|&c| is_ident_char(c))
                        .map(char::len_utf8)
                        .sum::<usize>();
                    if bytes.get(j) == Some(&b'.') {
                        if self.src[j + 1..].chars().next().is_some_and(is_ident_start) {
                            j += 1;
                            continue;
                        }
                        let bad_end = floor_boundary(self.src, j + 1);
                        let bad_end = self.src[bad_end..]
                            .chars()
                            .next()
                            .map_or(bad_end, |c| bad_end + c.len_utf8());
                        return self.err(
                            format!("expected a name after `.` in `{}`", &self.src[start..j + 1]),
                            Span::new(j, bad_end),
                        );
                    }
                    break;
                }
                (Tok::Name, j)
            }
            Some(_) => {
                let ch = self.src[start..].chars().next().unwrap_or('?');
                return self.err(
                    format!(
                        "unexpected character `{}`",
                        crate::printable(ch.encode_utf8(&mut [0; 4]))
                    ),
                    Span::new(start, start + ch.len_utf8()),
                );
            }
        };
        self.pos = end;
        Ok(Token {
            tok,
            span: Span::new(start, end),
        })
    }

    fn lex_number(&mut self, start: usize) -> Result<Token, ExprError> {
        let bytes = self.src.as_bytes();
        let digits = |mut j: usize| {
            while j < bytes.len() && bytes[j].is_ascii_digit() {
                j += 1;
            }
            j
        };
        let mut j = digits(start);
        if bytes.get(j) == Some(&b'.') {
            j = digits(j + 1);
        }
        if matches!(bytes.get(j), Some(b'e' | b'E')) {
            let mut k = j + 1;
            if matches!(bytes.get(k), Some(b'+' | b'-')) {
                k += 1;
            }
            if bytes.get(k).is_some_and(u8::is_ascii_digit) {
                j = digits(k);
            } else {
                return self.err(
                    format!(
                        "malformed number `{}`: expected digits after the exponent `{}`",
                        &self.src[start..k],
                        &self.src[j..j + 1]
                    ),
                    Span::new(start, k),
                );
            }
        }
        let span = Span::new(start, j);
        let text = self.text(span);
        let value: f64 = match text.parse() {
            Ok(v) => v,
            Err(_) => return self.err(format!("malformed number `{text}`"), span),
        };
        if !value.is_finite() {
            return self.err(format!("number `{text}` is out of range"), span);
        }
        self.pos = j;
        Ok(Token {
            tok: Tok::Num(value),
            span,
        })
    }

    fn peek(&mut self) -> Result<Token, ExprError> {
        if let Some(t) = self.peeked {
            return Ok(t);
        }
        let t = self.lex()?;
        self.peeked = Some(t);
        Ok(t)
    }

    fn next(&mut self) -> Result<Token, ExprError> {
        let t = self.peek()?;
        self.peeked = None;
        Ok(t)
    }

    fn enter(&mut self, span: Span) -> Result<(), ExprError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return self.err(
                format!("expression is nested too deeply (more than {MAX_DEPTH} levels)"),
                span,
            );
        }
        Ok(())
    }

    fn leave(&mut self) {
        self.depth -= 1;
    }

    /// `found `x`` for an error message.
    fn describe(&self, t: Token) -> String {
        match t.tok {
            Tok::End => "the end of the expression".to_string(),
            _ => format!("`{}`", self.text(t.span)),
        }
    }

    fn sum(&mut self) -> Result<Expr, ExprError> {
        let mut lhs = self.product()?;
        loop {
            let t = self.peek()?;
            let op = match t.tok {
                Tok::Plus => ast::add,
                Tok::Minus => ast::sub,
                _ => return Ok(lhs),
            };
            self.next()?;
            let rhs = self.product()?;
            lhs = op(lhs, rhs);
        }
    }

    fn product(&mut self) -> Result<Expr, ExprError> {
        let mut lhs = self.unary()?;
        loop {
            let t = self.peek()?;
            let op = match t.tok {
                Tok::Star => ast::mul,
                Tok::Slash => ast::div,
                _ => return Ok(lhs),
            };
            self.next()?;
            let rhs = self.unary()?;
            lhs = op(lhs, rhs);
        }
    }

    fn unary(&mut self) -> Result<Expr, ExprError> {
        let t = self.peek()?;
        match t.tok {
            Tok::Minus | Tok::Plus => {
                self.next()?;
                self.enter(t.span)?;
                let v = self.unary()?;
                self.leave();
                Ok(if t.tok == Tok::Minus { ast::neg(v) } else { v })
            }
            _ => self.power(),
        }
    }

    fn power(&mut self) -> Result<Expr, ExprError> {
        let base = self.primary()?;
        let t = self.peek()?;
        if t.tok != Tok::Caret {
            return Ok(base);
        }
        self.next()?;
        self.enter(t.span)?;
        let exponent = self.unary()?;
        self.leave();
        Ok(ast::pow(base, exponent))
    }

    fn primary(&mut self) -> Result<Expr, ExprError> {
        let t = self.next()?;
        match t.tok {
            Tok::Num(v) => Ok(Expr::constant(v)),
            Tok::Name => self.name(t),
            Tok::LParen => {
                self.enter(t.span)?;
                let inner = self.sum()?;
                self.leave();
                self.close(t, "`)`")?;
                Ok(inner)
            }
            Tok::End => self.err(
                "unexpected end of expression, expected a number, name or `(`",
                t.span,
            ),
            _ => self.err(
                format!("expected a number, name or `(`, found {}", self.describe(t)),
                t.span,
            ),
        }
    }

    /// Expect the `)` closing `open`; `what` is the expected token list for the message.
    fn close(&mut self, open: Token, what: &str) -> Result<Token, ExprError> {
        let t = self.next()?;
        if t.tok == Tok::RParen {
            return Ok(t);
        }
        let col = column(self.src, open.span.start);
        let mut msg = format!("expected {what} to close `(` opened at column {col}");
        if t.tok != Tok::End {
            msg.push_str(&format!(", found {}", self.describe(t)));
        }
        self.err(msg, t.span)
    }

    fn name(&mut self, t: Token) -> Result<Expr, ExprError> {
        let name = self.text(t.span);
        let is_call = self.peek()?.tok == Tok::LParen;
        let func = Func::from_name(name);
        match (func, is_call) {
            (Some(f), true) => self.call(f, t),
            (Some(f), false) => {
                let at = self.peek()?.span;
                self.err(format!("expected `(` after function `{f}`"), at)
            }
            (None, true) if name == "log" => {
                self.err("unknown function `log`; use ln or log10", t.span)
            }
            (None, true) => self.err(format!("unknown function `{name}`"), t.span),
            (None, false) => match name {
                "pi" => Ok(Expr::constant(std::f64::consts::PI)),
                "e" => Ok(Expr::constant(std::f64::consts::E)),
                _ => match (self.resolve)(name) {
                    Ok(Resolved::Var(k)) => Ok(Expr::var(k)),
                    Ok(Resolved::Value(v)) => Ok(Expr::constant(v)),
                    Err(msg) => self.err(msg, t.span),
                },
            },
        }
    }

    fn call(&mut self, f: Func, name: Token) -> Result<Expr, ExprError> {
        let open = self.next()?;
        self.enter(open.span)?;
        let mut args = Vec::with_capacity(f.arity());
        let close = if self.peek()?.tok == Tok::RParen {
            self.next()?
        } else {
            loop {
                args.push(self.sum()?);
                if self.peek()?.tok == Tok::Comma {
                    self.next()?;
                    continue;
                }
                let what = if args.len() < f.arity() {
                    "`,` or `)`"
                } else {
                    "`)`"
                };
                break self.close(open, what)?;
            }
        };
        self.leave();
        if args.len() != f.arity() {
            let plural = if f.arity() == 1 { "" } else { "s" };
            return self.err(
                format!(
                    "function `{f}` takes {} argument{plural}, found {}",
                    f.arity(),
                    args.len()
                ),
                Span::new(name.span.start, close.span.end),
            );
        }
        Ok(Expr::call(f, args))
    }
}

/// Parse `source`. Names other than the built-in functions and the constants `pi` and `e`
/// are passed to `resolve`; its `Err(message)` becomes an [`ExprError`] at the name's span.
///
/// Syntax: numbers (`1.5`, `1e-3`, `.5`, `2.`), `+ - * / ^`, unary `-` and `+`,
/// parentheses, the functions of [`Func`] (`sin(x)`, `atan2(y, x)`, `pow(a, b)`, ...),
/// `pi`, `e`, and names, [`is_identifier`]s optionally dotted (`bead.x` and `α.x` are one name).
/// `^` is right-associative and binds tighter than unary minus (`-x^2 = -(x^2)`,
/// `2^3^2 = 2^9`), then `*` `/`, then `+` `-`, both left-associative.
///
/// Never panics (unless `resolve` does); nesting deeper than [`MAX_DEPTH`] is an error.
pub fn parse(
    source: &str,
    resolve: &dyn Fn(&str) -> Result<Resolved, String>,
) -> Result<Expr, ExprError> {
    let mut p = Parser {
        src: source,
        pos: 0,
        peeked: None,
        depth: 0,
        resolve,
    };
    let first = p.peek()?;
    if first.tok == Tok::End {
        return Err(ExprError::new("empty expression", first.span));
    }
    let e = p.sum()?;
    let t = p.next()?;
    match t.tok {
        Tok::End => Ok(e),
        Tok::RParen => p.err("unexpected `)`", t.span),
        // `2x`, `2(x)`, `x y`: point out that juxtaposition does not multiply.
        Tok::Num(_) | Tok::Name | Tok::LParen => p.err(
            format!(
                "unexpected {}, expected an operator (implicit multiplication is not \
                 supported; write `*`)",
                p.describe(t)
            ),
            t.span,
        ),
        _ => p.err(
            format!("unexpected {}, expected an operator", p.describe(t)),
            t.span,
        ),
    }
}

/// The spans of the names in `source` (every name token, dotted names whole, functions and
/// constants included), in order, as [`parse`] reads them; an error where the text does not
/// tokenize. For rewriting a parsed expression's names, e.g. a scene's loop variables by
/// their values.
///
/// ```
/// use bead::expr::name_spans;
/// let source = "p3.x - 2e1*i + sin(i)";
/// let names: Vec<&str> = name_spans(source).unwrap().iter().map(|s| &source[s.start..s.end]).collect();
/// assert_eq!(names, ["p3.x", "i", "sin", "i"]);
/// ```
pub fn name_spans(source: &str) -> Result<Vec<Span>, ExprError> {
    let mut p = Parser {
        src: source,
        pos: 0,
        peeked: None,
        depth: 0,
        resolve: &|_| Err(String::new()),
    };
    let mut names = Vec::new();
    loop {
        let t = p.next()?;
        match t.tok {
            Tok::End => return Ok(names),
            Tok::Name => names.push(t.span),
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::testutil::Rng;

    fn resolve(name: &str) -> Result<Resolved, String> {
        match name {
            "x" => Ok(Resolved::Var(0)),
            "y" => Ok(Resolved::Var(1)),
            "z" => Ok(Resolved::Var(2)),
            "bead.x" => Ok(Resolved::Var(3)),
            "pérle.x" => Ok(Resolved::Var(0)),
            "a.vx" => Ok(Resolved::Var(4)),
            "k" => Ok(Resolved::Value(2.5)),
            // A resolver cannot override the built-in constants.
            "pi" | "e" => Ok(Resolved::Value(0.0)),
            _ => Err(format!("unknown name `{name}`")),
        }
    }

    fn p(src: &str) -> Result<Expr, ExprError> {
        parse(src, &resolve)
    }

    const VARS: [f64; 5] = [3.0, -2.0, 0.5, 7.0, 11.0];

    fn val(src: &str) -> f64 {
        p(src)
            .unwrap_or_else(|e| panic!("{src}: {e}\n{}", e.caret(src)))
            .eval(&VARS)
    }

    fn err(src: &str) -> ExprError {
        match p(src) {
            Ok(e) => panic!("{src} parsed as {e:?}"),
            Err(e) => e,
        }
    }

    /// Error message, span and caret rendering all at once.
    fn check_err(src: &str, message: &str, start: usize, end: usize, caret: &str) {
        let e = err(src);
        assert_eq!(e.message, message, "message for {src:?}");
        assert_eq!(e.span, Span { start, end }, "span for {src:?}");
        assert_eq!(e.caret(src), caret, "caret for {src:?}");
        assert_eq!(e.to_string(), message);
    }

    #[test]
    fn numbers() {
        for (src, v) in [
            ("1.5", 1.5),
            ("1e-3", 1e-3),
            (".5", 0.5),
            ("2.", 2.0),
            ("1E+2", 100.0),
            ("2.e1", 20.0),
            ("0.25e1", 2.5),
            ("007", 7.0),
            ("  42  ", 42.0),
        ] {
            assert_eq!(p(src).unwrap().as_constant(), Some(v), "{src}");
        }
    }

    #[test]
    fn precedence_and_associativity() {
        let cases = [
            ("-x^2", -9.0),
            ("(-x)^2", 9.0),
            ("-2^2", -4.0),
            ("2^3^2", 512.0),
            ("(2^3)^2", 64.0),
            ("2^-1", 0.5),
            ("2^-x^2", 2f64.powf(-9.0)),
            ("1 - 2 - 3", -4.0),
            ("8 / 4 / 2", 1.0),
            ("2 + 3 * 4", 14.0),
            ("(1 + 2) * 3", 9.0),
            ("x - y*z", 4.0),
            ("--x", 3.0),
            ("+x", 3.0),
            ("-+-x", 3.0),
            ("x*-y", 6.0),
            ("x/y/z", -3.0),
            ("x^y", 1.0 / 9.0),
            ("k*x", 7.5),
            ("bead.x + a.vx", 18.0),
            ("bead.x*a.vx", 77.0),
            ("pi", std::f64::consts::PI),
            ("e", std::f64::consts::E),
            ("2*pi*e", 2.0 * std::f64::consts::PI * std::f64::consts::E),
        ];
        for (src, want) in cases {
            let got = val(src);
            assert!(
                (got - want).abs() <= 1e-15 * want.abs(),
                "{src}: {got} != {want}"
            );
        }
    }

    #[test]
    fn functions() {
        let x = 0.3f64;
        let vars = [x, 1.7];
        let cases: [(&str, f64); 19] = [
            ("sin(x)", x.sin()),
            ("cos(x)", x.cos()),
            ("tan(x)", x.tan()),
            ("asin(x)", x.asin()),
            ("acos(x)", x.acos()),
            ("atan(x)", x.atan()),
            ("atan2(x, y)", x.atan2(1.7)),
            ("sinh(x)", x.sinh()),
            ("cosh(x)", x.cosh()),
            ("tanh(x)", x.tanh()),
            ("exp(x)", x.exp()),
            ("ln(x)", x.ln()),
            ("log10(x)", x.log10()),
            ("sqrt(x)", x.sqrt()),
            ("pow(x, y)", x.powf(1.7)),
            ("abs(-x)", x),
            ("sign(-x)", -1.0),
            ("sign(x - x)", 0.0),
            ("sin(cos(x)) + pow(2, 3)", x.cos().sin() + 8.0),
        ];
        for (src, want) in cases {
            let got = p(src).unwrap().eval(&vars);
            assert_eq!(got, want, "{src}");
        }
        // Constant arguments fold.
        assert_eq!(p("sqrt(4) + atan2(0, 1)").unwrap().as_constant(), Some(2.0));
    }

    #[test]
    fn names_and_resolver() {
        // The resolver is not consulted for pi and e.
        assert_eq!(p("pi").unwrap().as_constant(), Some(std::f64::consts::PI));
        assert_eq!(p("e").unwrap().as_constant(), Some(std::f64::consts::E));
        assert_eq!(p("x").unwrap().vars(), vec![0]);
        assert_eq!(p("bead.x").unwrap().vars(), vec![3]);
        assert_eq!(p("k").unwrap().as_constant(), Some(2.5));
        // Names may contain underscores and digits and be dotted several times.
        let seen = std::cell::RefCell::new(Vec::new());
        let r = |n: &str| {
            seen.borrow_mut().push(n.to_string());
            Ok(Resolved::Var(0))
        };
        parse("_a1 + b_2.c3.d + sinx + e1 + pi2", &r).unwrap();
        assert_eq!(*seen.borrow(), ["_a1", "b_2.c3.d", "sinx", "e1", "pi2"]);
    }

    #[test]
    fn unicode_identifiers() {
        let seen = std::cell::RefCell::new(Vec::new());
        let r = |n: &str| {
            seen.borrow_mut().push(n.to_string());
            Ok(Resolved::Var(0))
        };
        parse("α.x + θ_1*ω + 2*Ψ.z - _é2 + ж", &r).unwrap();
        assert_eq!(*seen.borrow(), ["α.x", "θ_1", "ω", "Ψ.z", "_é2", "ж"]);
        // A combining mark continues a name (e + U+0301), never starts one.
        assert!(is_identifier("e\u{301}"));
        assert!(!is_identifier("\u{301}e"));
        for bad in ["x²", "θ₁", "1a", "a.b", "a b", "", "a-b", "😀"] {
            assert!(!is_identifier(bad), "{bad}");
        }
        check_err("θ₁ + 1", "unexpected character `₁`", 2, 5, "θ₁ + 1\n ^");
        check_err("α.", "expected a name after `.` in `α.`", 2, 3, "α.\n ^");
    }

    #[test]
    fn error_messages_spans_and_carets() {
        check_err("", "empty expression", 0, 0, "\n^");
        check_err("   ", "empty expression", 3, 3, "   \n   ^");
        check_err(
            "1 +",
            "unexpected end of expression, expected a number, name or `(`",
            3,
            3,
            "1 +\n   ^",
        );
        check_err("x $ 2", "unexpected character `$`", 2, 3, "x $ 2\n  ^");
        check_err(
            "1 + (x * 2",
            "expected `)` to close `(` opened at column 5",
            10,
            10,
            "1 + (x * 2\n          ^",
        );
        check_err(
            "(x y)",
            "expected `)` to close `(` opened at column 1, found `y`",
            3,
            4,
            "(x y)\n   ^",
        );
        check_err("foo(1)", "unknown function `foo`", 0, 3, "foo(1)\n^^^");
        check_err(
            "2*log(x)",
            "unknown function `log`; use ln or log10",
            2,
            5,
            "2*log(x)\n  ^^^",
        );
        check_err("x)", "unexpected `)`", 1, 2, "x)\n ^");
        check_err(
            "x + atan2(x)",
            "function `atan2` takes 2 arguments, found 1",
            4,
            12,
            "x + atan2(x)\n    ^^^^^^^^",
        );
        check_err(
            "sin(x, y)",
            "function `sin` takes 1 argument, found 2",
            0,
            9,
            "sin(x, y)\n^^^^^^^^^",
        );
        check_err(
            "sin()",
            "function `sin` takes 1 argument, found 0",
            0,
            5,
            "sin()\n^^^^^",
        );
        check_err(
            "atan2(x y)",
            "expected `,` or `)` to close `(` opened at column 6, found `y`",
            8,
            9,
            "atan2(x y)\n        ^",
        );
        check_err(
            "atan2(x,",
            "unexpected end of expression, expected a number, name or `(`",
            8,
            8,
            "atan2(x,\n        ^",
        );
        check_err(
            "sin x",
            "expected `(` after function `sin`",
            4,
            5,
            "sin x\n    ^",
        );
        check_err(
            "bead.x^2 + 100*bead.w",
            "unknown name `bead.w`",
            15,
            21,
            "bead.x^2 + 100*bead.w\n               ^^^^^^",
        );
        check_err("x²", "unexpected character `²`", 1, 3, "x²\n ^");
        // Control characters are shown escaped, and the carets follow the escape.
        check_err(
            "x \u{1b} 2",
            "unexpected character `\\x1b`",
            2,
            3,
            "x \\x1b 2\n  ^^^^",
        );
        // Identifiers are Unicode (see unicode_identifiers); `é` is a name like any other.
        check_err("é + x", "unknown name `é`", 0, 2, "é + x\n^");
        check_err("€ + x", "unexpected character `€`", 0, 3, "€ + x\n^");
        // Spans stay in bytes, carets in characters.
        check_err(
            "pérle.x + bead.w",
            "unknown name `bead.w`",
            11,
            17,
            "pérle.x + bead.w\n          ^^^^^^",
        );
        check_err(
            "1 + 1e",
            "malformed number `1e`: expected digits after the exponent `e`",
            4,
            6,
            "1 + 1e\n    ^^",
        );
        check_err(
            "1e999",
            "number `1e999` is out of range",
            0,
            5,
            "1e999\n^^^^^",
        );
        check_err("a.", "expected a name after `.` in `a.`", 1, 2, "a.\n ^");
        check_err("a.1", "expected a name after `.` in `a.`", 1, 3, "a.1\n ^^");
        check_err(
            "2 x",
            "unexpected `x`, expected an operator (implicit multiplication is not supported; \
             write `*`)",
            2,
            3,
            "2 x\n  ^",
        );
        check_err(
            "x + * y",
            "expected a number, name or `(`, found `*`",
            4,
            5,
            "x + * y\n    ^",
        );
        check_err(
            "x, y",
            "unexpected `,`, expected an operator",
            1,
            2,
            "x, y\n ^",
        );
        check_err(
            "()",
            "expected a number, name or `(`, found `)`",
            1,
            2,
            "()\n ^",
        );
        check_err("pi(2)", "unknown function `pi`", 0, 2, "pi(2)\n^^");
        // Caret on the right line of a multi-line source, tabs kept for alignment.
        check_err(
            "x +\n\ty $",
            "unexpected character `$`",
            7,
            8,
            "\ty $\n\t  ^",
        );
    }

    #[test]
    fn caret_never_panics_on_foreign_spans() {
        let e = ExprError {
            message: String::new(),
            span: Span { start: 2, end: 100 },
        };
        assert_eq!(e.caret("aé"), "aé\n ^"); // start inside `é` floors to its start
        assert_eq!(e.caret(""), "\n^");
        let e = ExprError {
            message: String::new(),
            span: Span { start: 9, end: 3 },
        };
        assert_eq!(e.caret("abc"), "abc\n   ^");
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_stack_overflow() {
        let n = 100_000;
        let d = MAX_DEPTH;
        for (src, at) in [
            (format!("{}x{}", "(".repeat(n), ")".repeat(n)), d),
            (format!("{}x", "-".repeat(n)), d),
            (format!("{}x", "+".repeat(n)), d),
            (format!("{}x", "x^".repeat(n)), 2 * d + 1),
            (format!("{}x{}", "sin(".repeat(n), ")".repeat(n)), 4 * d + 3),
            (format!("{}x", "(-".repeat(n)), d),
        ] {
            let e = err(&src);
            assert_eq!(
                e.message,
                "expression is nested too deeply (more than 256 levels)"
            );
            assert_eq!(
                e.span,
                Span {
                    start: at,
                    end: at + 1
                }
            );
        }
        // Just inside the limit is fine.
        let ok = format!("{}x{}", "(".repeat(d), ")".repeat(d));
        assert_eq!(val(&ok), 3.0);
        assert_eq!(val(&format!("{}x", "-".repeat(d))), 3.0);
    }

    #[test]
    fn long_flat_input_is_fine() {
        // A left-deep chain 200_000 nodes deep: parse, evaluate, differentiate, compile,
        // display and drop without recursion.
        let n = 200_000;
        let src = format!("x{}", " + x*y".repeat(n));
        let e = p(&src).unwrap();
        assert_eq!(e.eval(&VARS), 3.0 + n as f64 * -6.0);
        let d = e.derivative(1);
        assert_eq!(d.eval(&VARS), n as f64 * 3.0);
        let tape = crate::expr::Tape::compile(&[e.clone(), d]);
        assert!(tape.n_instructions() < 2 * n + 10);
        let shown = e
            .display_with(&|k| ["x", "y", "z", "w", "v"][k].to_string())
            .to_string();
        assert_eq!(shown, src);
        let again = p(&"1 + ".repeat(n)).unwrap_err();
        assert!(again.message.starts_with("unexpected end"));
        assert_eq!(
            p(&format!("{}1", "1 + ".repeat(n))).unwrap().as_constant(),
            Some(n as f64 + 1.0)
        );
    }

    /// Random strings over an adversarial alphabet never panic; errors have sane spans.
    #[test]
    fn fuzz_no_panics() {
        let atoms = [
            "x", "y", "bead.x", "a.", ".", "..", "1", "2.5", ".5", "1e", "1e-3", "e", "pi", "+",
            "-", "*", "/", "^", "(", ")", ",", " ", "\t", "\n", "sin", "atan2", "log", "pow", "é",
            "²", "😀", "\u{0}", "$", "_", "9e999", "sign", "abs(", "foo", "x.y.z", "E",
        ];
        let mut rng = Rng::new(7);
        for _ in 0..20_000 {
            let len = rng.below(12);
            let s: String = (0..len).map(|_| atoms[rng.below(atoms.len())]).collect();
            check_no_panic(&s);
        }
        // Random bytes that form valid UTF-8 (lossy decoding).
        for _ in 0..5_000 {
            let len = rng.below(16);
            let bytes: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
            check_no_panic(&String::from_utf8_lossy(&bytes));
        }
    }

    fn check_no_panic(s: &str) {
        match p(s) {
            Ok(e) => {
                let _ = e.eval(&VARS);
                let _ = e.derivative(0);
                let shown = e.display_with(&|k| format!("v{k}")).to_string();
                assert!(!shown.is_empty());
            }
            Err(e) => {
                let Span { start, end } = e.span;
                assert!(start <= end && end <= s.len(), "{s:?}: {e:?}");
                assert!(
                    s.is_char_boundary(start) && s.is_char_boundary(end),
                    "{s:?}: {e:?}"
                );
                let _ = &s[start..end];
                let c = e.caret(s);
                assert!(c.contains('^'), "{s:?}");
                assert!(!e.message.is_empty());
            }
        }
    }
}
