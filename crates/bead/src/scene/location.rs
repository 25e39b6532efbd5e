//! Byte spans of the scene text to line, column and a caret snippet.

use std::ops::Range;

use super::SceneError;
use crate::expr::ExprError;

/// The scene text and its name, for locating errors.
#[derive(Clone, Copy)]
pub(super) struct Source<'a> {
    pub text: &'a str,
    pub file: &'a str,
}

impl<'a> Source<'a> {
    /// An error at byte range `span` of the text, with a caret snippet.
    pub fn error(&self, span: Range<usize>, message: impl Into<String>) -> SceneError {
        let text = self.text;
        let start = floor_boundary(text, span.start);
        let end = floor_boundary(text, span.end.max(start));
        let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
        let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
        let line_text = text[line_start..line_end].trim_end_matches('\r');
        let line = text[..start].matches('\n').count() + 1;
        let prefix = &text[line_start..start];
        let column = prefix.chars().count() + 1;
        let marked_end = end.min(line_start + line_text.len()).max(start);
        SceneError {
            file: self.file.to_string(),
            line,
            column,
            message: one_line(&message.into()),
            snippet: Some(crate::caret_snippet(
                line_text,
                start - line_start,
                marked_end - line_start,
            )),
        }
    }

    /// An error about the file as a whole: located at its start, without a snippet.
    pub fn error_at_start(&self, message: impl Into<String>) -> SceneError {
        SceneError {
            file: self.file.to_string(),
            line: 1,
            column: 1,
            message: one_line(&message.into()),
            snippet: None,
        }
    }

    /// An error with no place in the file (a command-line override, say).
    pub fn error_unplaced(&self, message: impl Into<String>) -> SceneError {
        SceneError {
            file: self.file.to_string(),
            line: 0,
            column: 0,
            message: one_line(&message.into()),
            snippet: None,
        }
    }

    /// A TOML syntax or type error.
    pub fn toml_error(&self, e: &toml::de::Error) -> SceneError {
        let mut message = e.message().replace("unknown field", "unknown key");
        match e.span() {
            Some(span) => {
                if message == "duplicate key" {
                    if let Some(key) = self.text.get(span.clone()) {
                        message = format!("duplicate key `{key}`");
                    }
                }
                self.error(span, message)
            }
            None => self.error_at_start(message),
        }
    }

    /// An error in the expression `source`, written as the TOML string at `string_span`: the
    /// caret goes under `error.span` inside the string (see [`Self::within_string`]).
    pub fn expr_error(
        &self,
        string_span: Range<usize>,
        source: &str,
        error: &ExprError,
        message: String,
    ) -> SceneError {
        self.within_string(
            string_span,
            source,
            error.span.start..error.span.end,
            message,
        )
    }

    /// An error at bytes `inner` of the string value `value`, written as the TOML string at
    /// `string_span`: the caret goes under `inner` when the string's text in the file is its
    /// value (a one-line literal string, or a basic string without escapes), else under the
    /// whole string.
    pub fn within_string(
        &self,
        string_span: Range<usize>,
        value: &str,
        inner: Range<usize>,
        message: String,
    ) -> SceneError {
        let raw = self.text.get(string_span.clone()).unwrap_or("");
        let content = if raw.starts_with("\"\"\"") || raw.starts_with("'''") {
            None
        } else if let Some(quoted) = raw.strip_prefix('"').and_then(|r| r.strip_suffix('"')) {
            (!quoted.contains('\\')).then_some(quoted)
        } else {
            raw.strip_prefix('\'').and_then(|r| r.strip_suffix('\''))
        };
        match content {
            Some(content) if content == value => {
                let start = inner.start.min(value.len());
                let end = inner.end.clamp(start, value.len());
                let base = string_span.start + 1;
                self.error(base + start..base + end, message)
            }
            _ => self.error(string_span, message),
        }
    }

    /// The 1-based line of byte `offset`.
    pub fn line_of(&self, offset: usize) -> usize {
        let offset = floor_boundary(self.text, offset);
        self.text[..offset].matches('\n').count() + 1
    }
}

/// The largest char boundary <= `i` (and <= len).
fn floor_boundary(text: &str, i: usize) -> usize {
    let mut i = i.min(text.len());
    while !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}

fn one_line(message: &str) -> String {
    message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}
