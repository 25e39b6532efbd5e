//! Numbers on the command line. Every numeric flag (`--dt`, `--duration`, `--rtol`, `--atol`,
//! `--stabilize KS,KD`, `--set NAME=VALUE`, `--dts`) takes an expression of numbers, `pi`, `e`
//! and the functions of scene numbers (`1/60`, `2*pi`, `sqrt(2)/10`), parsed by the library's
//! expression parser. Names other than `pi` and `e` are errors: a flag is read before the
//! scene, so it cannot use the scene's parameters (see [`Context::Set`]).
//!
//! An error is the message followed by the flag's value with a caret under the offending
//! text, for clap to print after `invalid value '...' for '--flag'`.

use bead::expr::{parse, ExprError, Resolved, Span};

/// What a number must be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bound {
    /// Finite.
    Finite,
    /// Finite and > 0.
    Positive,
    /// Finite and >= 0.
    NonNegative,
}

/// Where a number comes from, for the message about names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Context {
    /// An ordinary numeric flag.
    Flag,
    /// A `--set` value. It is evaluated when the command line is read, before the scene, so
    /// that every flag error is a usage error found before any file is touched, and so that
    /// its value does not depend on the order of the scene's `[params]`: it may not use the
    /// scene's parameters.
    Set,
}

/// A number that could not be read: the message and the byte span in the flag's value.
#[derive(Clone, Debug, PartialEq)]
pub struct NumberError {
    pub message: String,
    pub span: Span,
}

impl NumberError {
    pub fn new(message: impl Into<String>, start: usize, end: usize) -> Self {
        NumberError {
            message: message.into(),
            span: Span { start, end },
        }
    }

    /// `message` then the value, indented by two spaces, with a caret under the span (the same
    /// layout as a scene error's snippet).
    pub fn render(&self, value: &str) -> String {
        let caret = ExprError {
            message: String::new(),
            span: self.span,
        }
        .caret(value);
        let mut out = self.message.clone();
        for line in caret.lines() {
            out.push('\n');
            out.push_str(format!("  {line}").trim_end());
        }
        out
    }
}

/// The number written at `value[start..end]`: an expression of numbers, `pi`, `e` and
/// functions, checked against `bound`. Spans in the error are in bytes of `value`.
pub fn number(
    value: &str,
    start: usize,
    end: usize,
    bound: Bound,
    context: Context,
) -> Result<f64, NumberError> {
    let text = &value[start..end];
    let resolve = |name: &str| -> Result<Resolved, String> {
        Err(match name.to_ascii_lowercase().as_str() {
            "inf" | "infinity" | "nan" => {
                format!("`{name}` is not allowed here: numbers must be finite")
            }
            _ => match context {
                Context::Flag => format!(
                    "`{name}` is not a number; a number here may use pi, e and functions like sqrt(2)"
                ),
                Context::Set => format!(
                    "`{name}` is not a number; a --set value may use pi, e and functions like sqrt(2), not the scene's parameters"
                ),
            },
        })
    };
    let expr = parse(text, &resolve)
        .map_err(|e| NumberError::new(e.message, start + e.span.start, start + e.span.end))?;
    let x = expr.as_constant().unwrap_or_else(|| expr.eval(&[]));
    // Point at the expression without the spaces around it.
    let trimmed_start = start + (text.len() - text.trim_start().len());
    let trimmed_end = start + text.trim_end().len();
    let out_of_range = |message: String| NumberError::new(message, trimmed_start, trimmed_end);
    if !x.is_finite() {
        return Err(out_of_range(format!(
            "must be finite, got {}",
            bead::readable(x)
        )));
    }
    match bound {
        Bound::Positive if x <= 0.0 => Err(out_of_range(format!(
            "must be positive, got {}",
            bead::readable(x)
        ))),
        Bound::NonNegative if x < 0.0 => Err(out_of_range(format!(
            "must not be negative, got {}",
            bead::readable(x)
        ))),
        _ => Ok(x),
    }
}

/// The whole of `value` as one number.
pub fn whole(value: &str, bound: Bound) -> Result<f64, String> {
    number(value, 0, value.len(), bound, Context::Flag).map_err(|e| e.render(value))
}

/// The parts of a comma-separated list, as byte ranges of `value`; commas inside parentheses
/// (function arguments, `atan2(1, 2)`) do not separate.
pub fn split_list(value: &str) -> Vec<(usize, usize)> {
    let mut parts = Vec::new();
    let mut depth = 0usize;
    let mut start = 0;
    for (i, c) in value.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => depth = depth.saturating_sub(1),
            ',' if depth == 0 => {
                parts.push((start, i));
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push((start, value.len()));
    parts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expressions_of_numbers_pi_e_and_functions() {
        assert_eq!(whole("1/60", Bound::Positive), Ok(1.0 / 60.0));
        assert_eq!(
            whole(" 2*pi ", Bound::Finite),
            Ok(2.0 * std::f64::consts::PI)
        );
        assert_eq!(
            whole("sqrt(4) - e", Bound::Finite),
            Ok(2.0 - std::f64::consts::E)
        );
        assert_eq!(whole("1e-3", Bound::NonNegative), Ok(1e-3));
        assert_eq!(whole("0", Bound::NonNegative), Ok(0.0));
    }

    #[test]
    fn errors_carry_a_caret_under_the_offending_text() {
        assert_eq!(
            whole("1/", Bound::Positive).unwrap_err(),
            "unexpected end of expression, expected a number, name or `(`\n  1/\n    ^"
        );
        assert_eq!(
            whole("2*g", Bound::Positive).unwrap_err(),
            "`g` is not a number; a number here may use pi, e and functions like sqrt(2)\n  2*g\n    ^"
        );
        assert_eq!(
            whole(" 1 - 2 ", Bound::Positive).unwrap_err(),
            "must be positive, got -1\n   1 - 2\n   ^^^^^"
        );
        assert_eq!(
            whole("1/0", Bound::Finite).unwrap_err(),
            "must be finite, got inf\n  1/0\n  ^^^"
        );
        assert_eq!(
            whole("-1e-3", Bound::NonNegative).unwrap_err(),
            "must not be negative, got -0.001\n  -1e-3\n  ^^^^^"
        );
        assert!(whole("inf", Bound::Finite)
            .unwrap_err()
            .starts_with("`inf` is not allowed here: numbers must be finite"));
    }

    #[test]
    fn lists_split_at_commas_outside_parentheses() {
        assert_eq!(split_list("1/30,1/60"), vec![(0, 4), (5, 9)]);
        assert_eq!(split_list("atan2(1, 2),3"), vec![(0, 11), (12, 13)]);
        assert_eq!(split_list(""), vec![(0, 0)]);
        assert_eq!(split_list("1,"), vec![(0, 1), (2, 2)]);
    }
}
