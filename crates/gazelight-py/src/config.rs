//! Configuration from Python: a TOML string (the CLI's `[filter]` table's
//! contents, or the whole configuration file for `render`) or a dict of the
//! same keys. A dict is converted to a TOML value as it is (NaN stays NaN)
//! and handed to the application core (`gazelight_app::config`), whose
//! loader reads, deserialises and checks it and says what is wrong, in the
//! CLI's words; nothing here knows the schema.

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use gazelight_tracker::filter::FilterConfig;

/// Converts a Python value (dict, list, str, bool, int, float) to TOML.
pub(crate) fn to_toml(value: &Bound<'_, PyAny>, key: &str) -> PyResult<toml::Value> {
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        return Ok(toml::Value::Integer(value.extract()?));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if value.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(value.extract()?));
    }
    if let Ok(d) = value.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in d.iter() {
            let k: String = k
                .extract()
                .map_err(|_| PyTypeError::new_err(format!("{key}: keys must be strings")))?;
            let path = if key.is_empty() {
                k.clone()
            } else {
                format!("{key}.{k}")
            };
            table.insert(k, to_toml(&v, &path)?);
        }
        return Ok(toml::Value::Table(table));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let mut out = Vec::new();
        for v in value.try_iter()? {
            out.push(to_toml(&v?, key)?);
        }
        return Ok(toml::Value::Array(out));
    }
    Err(PyTypeError::new_err(format!(
        "{}: expected a dict, list, str, bool, int or float, not {}",
        if key.is_empty() { "config" } else { key },
        value.get_type().name()?
    )))
}

/// The filter configuration from `None` (the defaults), a TOML string or
/// a dict; read and checked by the application core
/// (`gazelight_app::config::filter_from_str` / `filter_from_value`).
pub(crate) fn filter_config(config: Option<&Bound<'_, PyAny>>) -> PyResult<FilterConfig> {
    match config {
        None => Ok(FilterConfig::default()),
        Some(c) if c.is_none() => Ok(FilterConfig::default()),
        Some(c) if c.is_instance_of::<PyString>() => {
            let text: String = c.extract()?;
            gazelight_app::config::filter_from_str(&text).map_err(crate::err)
        }
        Some(c) if c.is_instance_of::<PyDict>() => {
            gazelight_app::config::filter_from_value(to_toml(c, "")?).map_err(crate::err)
        }
        Some(c) => Err(PyTypeError::new_err(format!(
            "config: expected a dict or a TOML string, not {}",
            c.get_type().name()?
        ))),
    }
}
