//! Parser. (Skeleton.)
use super::Expr;

/// A byte range in the expression source.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Span { pub start: usize, pub end: usize }

/// What a name means: a variable slot or a known number (a scene parameter, pi, e).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Resolved { Var(usize), Value(f64) }

/// A parse or name error at `span` of the expression source.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ExprError { pub message: String, pub span: Span }

impl ExprError {
    /// The source line with a caret line under `span`, e.g.
    /// ```text
    /// bead.x^2 + 100*bead.w
    ///                ^^^^^^
    /// ```
    pub fn caret(&self, source: &str) -> String { let _ = source; todo!() }
}

/// Parse `source`. Names other than the built-in functions and the constants `pi` and `e`
/// are passed to `resolve`; its `Err(message)` becomes an [`ExprError`] at the name's span.
pub fn parse(source: &str, resolve: &dyn Fn(&str) -> Result<Resolved, String>) -> Result<Expr, ExprError> {
    let _ = (source, resolve);
    todo!()
}
