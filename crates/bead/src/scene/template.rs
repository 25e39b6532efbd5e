//! Generated tables: the loop variables of a `for` key and the `{...}` in the strings of
//! `[[particle]]`, `[[constraint]]` and `[[force]]` tables.
//!
//! `{EXPR}` is replaced by the value of EXPR, which must be a whole number, 0 or more (its
//! digits become part of a name: `p{i-1}` is `p2` when i = 3). The replacement is textual and
//! happens before the string is read, so it works alike in names (`name = "p{i}"`), in
//! references to particles (`between = ["p{i-1}", "p{i}"]`) and inside expressions
//! (`expr = "p{i}.x - p{i-1}.x - L"`). [`Expanded::original`] maps a byte range of the
//! expanded text back to the string as written, so that errors point at the file's text.

use std::borrow::Cow;
use std::ops::Range;

use crate::expr::{name_spans, ExprError};

/// The largest value a `{...}` may have: every integer up to it is exact in an f64.
const LARGEST: f64 = 9_007_199_254_740_992.0;

/// The loop variables of one repetition of a generated table and their values, outermost
/// first; empty for a table without `for`.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct Scope {
    pub vars: Vec<(String, i64)>,
}

impl Scope {
    /// The value of loop variable `name`.
    pub fn value(&self, name: &str) -> Option<f64> {
        self.vars
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| *v as f64)
    }

    /// `i = 3, j = 4`.
    pub fn describe(&self) -> String {
        self.vars
            .iter()
            .map(|(n, v)| format!("{n} = {v}"))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// `source` (an expression that parses) with every loop variable replaced by its value,
    /// so that the text stands alone: it is what the system keeps as the constraint's source,
    /// shows in `bead check` and parses again on edits, where there are no loop variables.
    pub fn substitute(&self, source: &str) -> String {
        if self.vars.is_empty() {
            return source.to_string();
        }
        let Ok(names) = name_spans(source) else {
            return source.to_string();
        };
        let mut out = String::with_capacity(source.len());
        let mut done = 0;
        for span in names {
            let name = &source[span.start..span.end];
            if let Some((_, v)) = self.vars.iter().find(|(n, _)| n == name) {
                out.push_str(&source[done..span.start]);
                if *v < 0 {
                    out.push_str(&format!("({v})"));
                } else {
                    out.push_str(&v.to_string());
                }
                done = span.end;
            }
        }
        out.push_str(&source[done..]);
        out
    }
}

/// An error in a string of the scene: where in the string's value, and what (without the
/// table's context).
#[derive(Debug)]
pub(super) struct StringError {
    pub span: Range<usize>,
    pub message: String,
}

/// One `{...}` and the digits that replaced it.
#[derive(Clone, Debug)]
struct Piece {
    original: Range<usize>,
    expanded: Range<usize>,
}

/// A string with its `{...}` replaced.
#[derive(Debug)]
pub(super) struct Expanded<'s> {
    /// The string as written.
    pub original: &'s str,
    /// The string with every `{...}` replaced by its value.
    pub text: Cow<'s, str>,
    pieces: Vec<Piece>,
}

impl<'s> Expanded<'s> {
    /// `text` as it is, where `{...}` is not expanded.
    pub fn verbatim(text: &'s str) -> Expanded<'s> {
        Expanded {
            original: text,
            text: Cow::Borrowed(text),
            pieces: Vec::new(),
        }
    }

    /// The byte range of the string as written that bytes `span` of [`Self::text`] come
    /// from; a range that touches a replacement covers its whole `{...}`.
    pub fn original(&self, span: Range<usize>) -> Range<usize> {
        if self.pieces.is_empty() {
            return span;
        }
        let map = |p: usize, end: bool| -> usize {
            // Bytes added (or removed) by the replacements before p.
            let mut delta = 0isize;
            for piece in &self.pieces {
                let inside = if end {
                    piece.expanded.start < p && p <= piece.expanded.end
                } else {
                    piece.expanded.start <= p && p < piece.expanded.end
                };
                if inside {
                    return if end {
                        piece.original.end
                    } else {
                        piece.original.start
                    };
                }
                if p < piece.expanded.end {
                    break;
                }
                delta += piece.original.len() as isize - piece.expanded.len() as isize;
            }
            (p as isize + delta).max(0) as usize
        };
        let start = map(span.start, false);
        let end = map(span.end, true).max(start);
        start..end
    }

    /// An expression error in [`Self::text`], moved to the string as written: its span, and
    /// the column a message names (`opened at column 9`), which counts in the text parsed.
    pub fn error(&self, error: &ExprError) -> StringError {
        let span = self.original(error.span.start..error.span.end);
        let mut message = error.message.clone();
        const MARK: &str = "opened at column ";
        if let (Some(at), false) = (message.find(MARK), self.pieces.is_empty()) {
            let digits_start = at + MARK.len();
            let digits_end = message[digits_start..]
                .find(|c: char| !c.is_ascii_digit())
                .map_or(message.len(), |k| digits_start + k);
            let single_line = !self.text.contains('\n');
            if let (Ok(column), true) = (
                message[digits_start..digits_end].parse::<usize>(),
                single_line,
            ) {
                let byte = self
                    .text
                    .char_indices()
                    .nth(column.saturating_sub(1))
                    .map_or(self.text.len(), |(i, _)| i);
                let written = self.original(byte..byte + 1).start.min(self.original.len());
                let written_column = self.original[..written].chars().count() + 1;
                message.replace_range(digits_start..digits_end, &written_column.to_string());
            }
        }
        StringError { span, message }
    }
}

/// `text` with every `{EXPR}` replaced by the value of EXPR, given by `evaluate` (which
/// parses and evaluates an expression of the parameters and loop variables).
pub(super) fn expand<'s>(
    text: &'s str,
    evaluate: &dyn Fn(&str) -> Result<f64, ExprError>,
) -> Result<Expanded<'s>, StringError> {
    let braces = ['{', '}'];
    if !text.contains(braces) {
        return Ok(Expanded::verbatim(text));
    }
    let error = |span: Range<usize>, message: String| Err(StringError { span, message });
    let mut out = String::with_capacity(text.len());
    let mut pieces = Vec::new();
    let mut done = 0;
    while let Some(k) = text[done..].find(braces) {
        let open = done + k;
        if text.as_bytes()[open] == b'}' {
            return error(open..open + 1, "`}` without a `{` before it".into());
        }
        let after = open + 1;
        let close = match text[after..].find(braces) {
            None => {
                return error(
                    open..text.len(),
                    "`{` is not closed: expected `}` after the expression".into(),
                )
            }
            Some(k) if text.as_bytes()[after + k] == b'{' => {
                return error(
                    after + k..after + k + 1,
                    "`{` inside `{...}`: braces do not nest".into(),
                )
            }
            Some(k) => after + k,
        };
        let inner = &text[after..close];
        let whole = &text[open..close + 1];
        if inner.trim().is_empty() {
            return error(
                open..close + 1,
                "empty `{}`: write an integer expression in it, e.g. `{i}`".into(),
            );
        }
        let value = evaluate(inner).map_err(|e| StringError {
            span: after + e.span.start..after + e.span.end,
            message: e.message,
        })?;
        if !(value.is_finite() && value.fract() == 0.0) {
            return error(
                open..close + 1,
                format!(
                    "`{whole}` is {}, not a whole number",
                    crate::readable(value)
                ),
            );
        }
        if value < 0.0 {
            return error(
                open..close + 1,
                format!(
                    "`{whole}` is {}: a `{{...}}` must not be negative (its digits become part of a name)",
                    crate::readable(value)
                ),
            );
        }
        if value > LARGEST {
            return error(
                open..close + 1,
                format!(
                    "`{whole}` is {}: a `{{...}}` must be at most 2^53",
                    crate::readable(value)
                ),
            );
        }
        out.push_str(&text[done..open]);
        let digits = (value as u64).to_string();
        pieces.push(Piece {
            original: open..close + 1,
            expanded: out.len()..out.len() + digits.len(),
        });
        out.push_str(&digits);
        done = close + 1;
    }
    out.push_str(&text[done..]);
    Ok(Expanded {
        original: text,
        text: Cow::Owned(out),
        pieces,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expr::{parse, Resolved};

    fn evaluate(source: &str) -> Result<f64, ExprError> {
        let e = parse(source, &|name| match name {
            "i" => Ok(Resolved::Value(3.0)),
            "N" => Ok(Resolved::Value(10.0)),
            _ => Err(format!("unknown name `{name}`")),
        })?;
        Ok(e.eval(&[]))
    }

    #[test]
    fn braces_are_replaced_and_spans_map_back() {
        let x = expand("p{i}.x - p{i-1}.x - {N*10}", &evaluate).unwrap();
        assert_eq!(x.text, "p3.x - p2.x - 100");
        // `p3.x` is bytes 0..4 of the text: `p{i}.x`, 0..6 of the original.
        assert_eq!(x.original(0..4), 0..6);
        // `p2` (7..9) comes from `p{i-1}` (9..15).
        assert_eq!(x.original(7..9), 9..15);
        assert_eq!(x.original(9..11), 15..17);
        assert_eq!(x.original(14..17), 20..26);
        assert_eq!(x.original(17..17), 26..26);
        let plain = expand("p.x", &evaluate).unwrap();
        assert!(matches!(plain.text, Cow::Borrowed("p.x")));
    }

    #[test]
    fn bad_braces_are_located() {
        let e = |text: &str| {
            let e = expand(text, &evaluate).unwrap_err();
            (e.span, e.message)
        };
        assert_eq!(
            e("p{i"),
            (
                1..3,
                "`{` is not closed: expected `}` after the expression".into()
            )
        );
        assert_eq!(e("p}"), (1..2, "`}` without a `{` before it".into()));
        assert_eq!(
            e("p{{i}}"),
            (2..3, "`{` inside `{...}`: braces do not nest".into())
        );
        assert_eq!(
            e("p{ }"),
            (
                1..4,
                "empty `{}`: write an integer expression in it, e.g. `{i}`".into()
            )
        );
        assert_eq!(
            e("p{i/2}"),
            (1..6, "`{i/2}` is 1.5, not a whole number".into())
        );
        assert_eq!(e("p{k}"), (2..3, "unknown name `k`".into()));
        assert_eq!(
            e("p{i-4}"),
            (
                1..6,
                "`{i-4}` is -1: a `{...}` must not be negative (its digits become part of a name)"
                    .into()
            )
        );
    }

    #[test]
    fn loop_variables_are_substituted_by_name_only() {
        let scope = Scope {
            vars: vec![("i".into(), 3), ("j".into(), -2)],
        };
        assert_eq!(
            scope.substitute("p3.x*i - sin(j)^i + i.x + 1e2"),
            "p3.x*3 - sin((-2))^3 + i.x + 1e2"
        );
        assert_eq!(scope.describe(), "i = 3, j = -2");
    }
}
