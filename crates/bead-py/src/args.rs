//! Python arguments to Rust numbers. Every error names the argument, shows the value given
//! and says what the argument accepts: a `TypeError` for a value of the wrong type (a bool,
//! a string, a float where an integer is needed), a `ValueError` for one out of range (an
//! integer beyond a Rust integer's range, or beyond a float's, included), never a bare
//! `OverflowError`.

use pyo3::exceptions::{PyOverflowError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyBool;

/// Largest number of steps (and of steps between two recorded states): beyond 2^53,
/// t = step * dt is no longer exact.
pub const MAX_STEPS: u64 = 1 << 53;

/// The most threads a sweep may be asked for: more would only make the system refuse to
/// start them.
pub const MAX_THREADS: u64 = 1024;

/// `value` as Python writes it, cut short when long (a huge integer).
pub fn shown(value: &Bound<'_, PyAny>) -> String {
    let text = value
        .repr()
        .map(|r| r.to_string())
        .unwrap_or_else(|_| "<unprintable>".to_string());
    let length = text.chars().count();
    if length <= 40 {
        text
    } else {
        let start: String = text.chars().take(20).collect();
        format!("{start}... ({length} characters)")
    }
}

/// `bool`, `str`, ...: the name of `value`'s type.
fn type_name(value: &Bound<'_, PyAny>) -> String {
    value
        .get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".to_string())
}

/// A real number (a Python int or float, or a numpy scalar) for argument `name`, which
/// accepts `accepts` (e.g. "a finite number > 0"); None stays None. The range itself is
/// checked by the caller; a value beyond a float's range is refused here.
pub fn real(name: &str, value: Option<&Bound<'_, PyAny>>, accepts: &str) -> PyResult<Option<f64>> {
    match value.filter(|v| !v.is_none()) {
        None => Ok(None),
        Some(value) => real_value(name, value, accepts).map(Some),
    }
}

/// [`real`] for a value that must be given.
pub fn real_value(name: &str, value: &Bound<'_, PyAny>, accepts: &str) -> PyResult<f64> {
    let wrong_type = || {
        PyTypeError::new_err(format!(
            "{name}={}: must be {accepts}, not a {}",
            shown(value),
            type_name(value)
        ))
    };
    if value.is_instance_of::<PyBool>() {
        return Err(wrong_type());
    }
    match value.extract::<f64>() {
        Ok(x) => Ok(x),
        Err(e) if e.is_instance_of::<PyOverflowError>(value.py()) => {
            Err(PyValueError::new_err(format!(
                "{name}={}: must be {accepts}; this is beyond the range of a float (about 1.8e308)",
                shown(value)
            )))
        }
        Err(_) => Err(wrong_type()),
    }
}

/// `low..=high` as messages say it: `an integer from 1 to 2^53`.
pub fn integer_range(low: u64, high: u64) -> String {
    format!("an integer from {low} to {}", power_of_two(high))
}

/// 2^k, 2^k - 1, or the number.
fn power_of_two(n: u64) -> String {
    if n >= 1 << 16 && n.is_power_of_two() {
        format!("2^{}", n.trailing_zeros())
    } else if n >= (1 << 16) - 1 && n & n.wrapping_add(1) == 0 {
        format!("2^{} - 1", n.count_ones())
    } else {
        n.to_string()
    }
}

/// An integer (a Python int or a numpy integer; not a bool or a float) from `low` to `high`
/// for argument `name`; None stays None. `note` follows the range in errors (e.g. what 0
/// means).
pub fn integer(
    name: &str,
    value: Option<&Bound<'_, PyAny>>,
    low: u64,
    high: u64,
    note: &str,
) -> PyResult<Option<u64>> {
    match value.filter(|v| !v.is_none()) {
        None => Ok(None),
        Some(value) => integer_value(name, value, low, high, note).map(Some),
    }
}

/// [`integer`] for a value that must be given.
pub fn integer_value(
    name: &str,
    value: &Bound<'_, PyAny>,
    low: u64,
    high: u64,
    note: &str,
) -> PyResult<u64> {
    let accepts = format!("{}{note}", integer_range(low, high));
    if value.is_instance_of::<PyBool>() {
        return Err(PyTypeError::new_err(format!(
            "{name}={}: must be {accepts}, not a bool",
            shown(value)
        )));
    }
    let out_of_range =
        || PyValueError::new_err(format!("{name}={}: must be {accepts}", shown(value)));
    match value.extract::<u64>() {
        Ok(n) if (low..=high).contains(&n) => Ok(n),
        Ok(_) => Err(out_of_range()),
        // Negative, or beyond 2^64 - 1.
        Err(e) if e.is_instance_of::<PyOverflowError>(value.py()) => Err(out_of_range()),
        Err(_) => Err(PyTypeError::new_err(format!(
            "{name}={}: must be {accepts}, not a {}",
            shown(value),
            type_name(value)
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::power_of_two;

    #[test]
    fn ranges_are_written_as_powers_of_two_when_large() {
        assert_eq!(power_of_two(1 << 53), "2^53");
        assert_eq!(power_of_two(u32::MAX as u64), "2^32 - 1");
        assert_eq!(power_of_two(u64::MAX), "2^64 - 1");
        assert_eq!(power_of_two(1024), "1024");
        assert_eq!(power_of_two(7), "7");
    }
}
