//! bead: constrained particle dynamics.
// Unsafe code is denied everywhere but in `expr::jit`, which calls the machine code it
// generates (each use allowed there, with its argument).
#![deny(unsafe_code)]
pub mod convergence;
pub mod describe;
pub mod expr;
pub mod formulation;
pub mod integrate;
pub mod linalg;
pub mod model;
pub mod output;
pub mod plan;
pub mod scene;
pub mod simulate;
pub mod sweep;

/// A number type the engine can differentiate through: `f64`, num-dual's dual numbers, and
/// the crate's own number that records operations to trace a constraint into an expression.
/// Constraints written as Rust types are generic over it (see [`model::Holonomic`]).
pub trait Scalar: num_dual::DualNum<Primitive = f64> + Copy {}
impl<T: num_dual::DualNum<Primitive = f64> + Copy> Scalar for T {}

/// Whether two slices hold the same values bit for bit (the same length, `to_bits` equal:
/// -0.0 differs from 0.0, a NaN equals only a NaN with its payload), the test of every
/// "same bits" claim and cache in the crate.
pub(crate) fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// The shipped scene files (`scenes/*.toml`), sorted: what the unit tests that walk every
/// scene load.
#[cfg(test)]
pub(crate) fn shipped_scene_paths() -> Vec<std::path::PathBuf> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .expect("the scenes")
        .map(|e| e.expect("an entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    paths.sort();
    paths
}

/// `value` for messages: plain notation, or exponent notation when it is very large or very
/// small, so that no message prints a 300-digit number.
///
/// ```
/// assert_eq!(bead::readable(0.25), "0.25");
/// assert_eq!(bead::readable(1e300), "1e300");
/// assert_eq!(bead::readable(-5e-7), "-5e-7");
/// ```
pub fn readable(value: f64) -> String {
    let magnitude = value.abs();
    if magnitude != 0.0 && magnitude.is_finite() && !(1e-4..1e16).contains(&magnitude) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

/// `x` with `digits` significant digits, in the shorter of fixed and exponent notation (like
/// C's `%g`), signed: the formatter of measured values (residuals, errors, energies) in
/// messages, reports and the CLI, so that every front end prints a number the same way.
///
/// ```
/// assert_eq!(bead::significant(-50.0, 6), "-50");
/// assert_eq!(bead::significant(1.0 / 60.0, 6), "0.0166667");
/// assert_eq!(bead::significant(1.234e-8, 4), "1.234e-8");
/// assert_eq!(bead::significant(f64::INFINITY, 4), "inf");
/// ```
pub fn significant(x: f64, digits: usize) -> String {
    if !x.is_finite() {
        return format!("{x}");
    }
    if x == 0.0 {
        return "0".into();
    }
    let digits = digits.max(1);
    let rounded: f64 = format!("{:.*e}", digits - 1, x).parse().unwrap_or(x);
    let exponent = rounded.abs().log10().floor() as i32;
    let trim = |s: &str| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s.to_string()
        }
    };
    if exponent < -4 || exponent >= digits as i32 {
        let s = format!("{:.*e}", digits - 1, rounded);
        match s.split_once('e') {
            Some((mantissa, exp)) => format!("{}e{exp}", trim(mantissa)),
            None => s,
        }
    } else {
        let decimals = (digits as i32 - 1 - exponent).max(0) as usize;
        trim(&format!("{:.*}", decimals, rounded))
    }
}

/// A size in bytes for a message, in decimal units with 3 significant digits.
///
/// ```
/// assert_eq!(bead::byte_size(950), "950 bytes");
/// assert_eq!(bead::byte_size(12_900_000_000), "12.9 GB");
/// assert_eq!(bead::byte_size(u64::MAX), "18.4 EB");
/// ```
pub fn byte_size(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["kB", "MB", "GB", "TB", "PB", "EB"];
    if bytes < 1000 {
        return format!("{bytes} bytes");
    }
    let mut value = bytes as f64;
    let mut unit = "bytes";
    for u in UNITS {
        if value < 999.5 {
            break;
        }
        value /= 1000.0;
        unit = u;
    }
    format!("{} {unit}", significant(value, 3))
}

/// Names joined by `, ` for a message, at most [`LISTED_NAMES`] of them: a longer list shows
/// its first names, `...`, its last name and how many there are, so that an error in a scene
/// of 10^4 particles stays one readable line.
///
/// ```
/// assert_eq!(bead::name_list(["a", "b"]), "a, b");
/// let many: Vec<String> = (0..1000).map(|i| format!("p{i}")).collect();
/// assert_eq!(bead::name_list(&many), "p0, p1, p2, p3, p4, p5, p6, p7, ..., p999 (1000 in all)");
/// ```
pub fn name_list<I>(names: I) -> String
where
    I: IntoIterator,
    I::IntoIter: ExactSizeIterator,
    I::Item: AsRef<str>,
{
    let names = names.into_iter();
    let count = names.len();
    if count <= LISTED_NAMES {
        return names
            .map(|n| n.as_ref().to_string())
            .collect::<Vec<_>>()
            .join(", ");
    }
    let mut out = String::new();
    for (i, name) in names.enumerate() {
        if i < LISTED_NAMES - 2 {
            out.push_str(name.as_ref());
            out.push_str(", ");
        } else if i + 1 == count {
            out.push_str("..., ");
            out.push_str(name.as_ref());
        }
    }
    format!("{out} ({count} in all)")
}

/// The longest list [`name_list`] writes out in full.
pub const LISTED_NAMES: usize = 10;

/// `text` with every control character escaped, so that it can be shown on a terminal or
/// quoted in a message on one line: `\n`, `\r`, `\t`, other ASCII controls as `\x1b`, the C1
/// controls (U+0080 to U+009F) as `\u{9b}`. Everything else, Unicode included, is kept.
///
/// ```
/// assert_eq!(bead::printable("a\u{1b}[31mb\n"), "a\\x1b[31mb\\n");
/// assert_eq!(bead::printable("α.x"), "α.x");
/// ```
pub fn printable(text: &str) -> std::borrow::Cow<'_, str> {
    if !text.chars().any(char::is_control) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for c in text.chars() {
        push_printable(&mut out, c);
    }
    std::borrow::Cow::Owned(out)
}

/// Push `c`, escaped as [`printable`] does when it is a control character.
pub(crate) fn push_printable(out: &mut String, c: char) {
    match c {
        '\n' => out.push_str("\\n"),
        '\r' => out.push_str("\\r"),
        '\t' => out.push_str("\\t"),
        c if c.is_control() && (c as u32) < 0x80 => {
            out.push_str(&format!("\\x{:02x}", c as u32));
        }
        c if c.is_control() => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
        c => out.push(c),
    }
}

/// `line` and, under it, a caret line marking bytes `start..end` of it (at least one caret):
/// the snippet of located errors. Control characters are escaped as [`printable`] does, and
/// the carets follow the escaped text; tabs are kept, and repeated in the caret line's
/// padding, so that the carets line up whatever the tab width.
pub(crate) fn caret_snippet(line: &str, start: usize, end: usize) -> String {
    let width = |c: char| {
        let mut escaped = String::new();
        push_printable(&mut escaped, c);
        escaped.chars().count()
    };
    let mut shown = String::with_capacity(line.len() + 8);
    let mut pad = String::new();
    let mut carets = 0;
    for (i, c) in line.char_indices() {
        if c == '\t' {
            shown.push('\t');
        } else {
            push_printable(&mut shown, c);
        }
        if i < start {
            if c == '\t' {
                pad.push('\t');
            } else {
                pad.extend(std::iter::repeat_n(' ', width(c)));
            }
        } else if i < end {
            carets += width(c);
        }
    }
    format!("{shown}\n{pad}{}", "^".repeat(carets.max(1)))
}

/// The README's Rust examples, compiled and run as doctests.
#[doc = include_str!("../../../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
