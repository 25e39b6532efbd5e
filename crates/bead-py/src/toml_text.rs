//! TOML written from Python: the values of `Scene.with_force`'s table and of the scene text
//! `bead.Builder` writes, formatted by the `toml` crate (quoting and escaping included) in
//! the order the caller gives, so that a scene built in Python is a TOML scene, loaded by
//! the same loader with the same located errors.

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyString};

/// A Python value as TOML: a bool, an integer, a float, a string (an expression where a
/// number goes), a sequence or array of these, a dict of these (an inline table).
pub(crate) fn toml_value(value: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        let i: i64 = value
            .extract()
            .map_err(|_| PyValueError::new_err(format!("{value} is too large an integer")))?;
        return Ok(toml::Value::Integer(i));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if let Ok(s) = value.cast::<PyString>() {
        return Ok(toml::Value::String(s.extract::<String>()?));
    }
    if let Ok(dict) = value.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in dict.iter() {
            table.insert(k.extract::<String>()?, toml_value(&v)?);
        }
        return Ok(toml::Value::Table(table));
    }
    // numpy arrays and scalars: as Python numbers and lists.
    if value.hasattr("tolist")? {
        let plain = value.call_method0("tolist")?;
        if !plain.is(value) {
            return toml_value(&plain);
        }
    }
    if let Ok(items) = value.try_iter() {
        let values = items
            .map(|item| toml_value(&item?))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(values));
    }
    Err(PyTypeError::new_err(format!(
        "{}: cannot be written in a scene (numbers, strings, lists and dicts can)",
        crate::args::shown(value)
    )))
}

/// The value as inline TOML text, e.g. `[0.0, "g"]` (used by `bead.Builder`).
#[pyfunction]
pub(crate) fn _toml_value(value: &Bound<'_, PyAny>) -> PyResult<String> {
    let value = toml_value(value)?;
    if let toml::Value::Float(f) = value {
        if !f.is_finite() {
            return Err(PyValueError::new_err(format!(
                "{f}: numbers in a scene must be finite"
            )));
        }
    }
    Ok(value.to_string())
}

/// A `[[NAME]]` table with `keys` in their order (`key = value` lines).
pub(crate) fn array_table(name: &str, keys: &[(String, Bound<'_, PyAny>)]) -> PyResult<String> {
    let mut text = format!("[[{name}]]\n");
    for (key, value) in keys {
        let bare = !key.is_empty()
            && key
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        let key = if bare {
            key.clone()
        } else {
            toml::Value::String(key.clone()).to_string()
        };
        text.push_str(&format!("{key} = {}\n", _toml_value(value)?));
    }
    Ok(text)
}
