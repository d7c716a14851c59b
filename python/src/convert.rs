//! Python values ↔ the library's: keyword options → typed configuration values, errors →
//! Python exceptions, JSON records → Python objects.

use pyo3::exceptions::{PyOSError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use trainer::config::TrainConfig;

/// A library error as a Python exception: `OSError` when a file is missing or unreadable (an I/O
/// error, a dataset file or image not found), else `ValueError`; the message is the whole chain.
pub fn to_py_err(error: trainer::Error) -> PyErr {
    use datasets::DatasetError;
    use trainer::Error;
    let message = error.chain();
    let file_missing = matches!(
        error.root(),
        Error::Io(_) | Error::Dataset(DatasetError::Io { .. } | DatasetError::NotFound { .. } | DatasetError::MissingImage { .. })
    );
    if file_missing { PyOSError::new_err(message) } else { PyValueError::new_err(message) }
}

/// `data__masks` (a Python keyword) → `data.masks` (the configuration's key); dotted keys
/// (`**{"data.masks": False}`) pass unchanged.
pub fn config_key(keyword: &str) -> String {
    keyword.replace("__", ".")
}

/// A Python value as a TOML value of the configuration: bool, int, float, str, list/tuple,
/// dict (a section), and numpy scalars (by `__index__` / `__float__`). `key` names the option
/// in errors.
pub fn toml_value(key: &str, value: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        let v: i64 = value.extract().map_err(|_| PyValueError::new_err(format!("{key}: {value} does not fit a 64-bit integer")))?;
        return Ok(toml::Value::Integer(v));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if let Ok(text) = value.cast::<PyString>() {
        return Ok(toml::Value::String(text.to_cow()?.into_owned()));
    }
    if let Ok(dict) = value.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in dict.iter() {
            let k: String = k.extract().map_err(|_| PyTypeError::new_err(format!("{key}: section keys must be str")))?;
            let inner = toml_value(&format!("{key}.{k}"), &v)?;
            table.insert(k, inner);
        }
        return Ok(toml::Value::Table(table));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items = value.try_iter()?.map(|item| toml_value(key, &item?)).collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(items));
    }
    // numpy scalars and other numbers.
    if value.hasattr("__index__")? {
        return Ok(toml::Value::Integer(value.extract()?));
    }
    if value.hasattr("__float__")? {
        return Ok(toml::Value::Float(value.extract()?));
    }
    Err(PyTypeError::new_err(format!(
        "{key}: a value of type {} is not a configuration value (bool, int, float, str, list, dict)",
        value.get_type().name()?
    )))
}

/// The typed overrides of keyword options, with `prefix` (e.g. `guide.`) before each key.
pub fn overrides(options: Option<&Bound<'_, PyDict>>, prefix: &str) -> PyResult<Vec<(String, toml::Value)>> {
    let Some(options) = options else { return Ok(Vec::new()) };
    options
        .iter()
        .map(|(k, v)| {
            let key = format!("{prefix}{}", config_key(&k.extract::<String>()?));
            let value = toml_value(&key, &v)?;
            Ok((key, value))
        })
        .collect()
}

/// The default configuration with `overrides` (and a TOML file), validated; errors name the key.
pub fn config(file: Option<&std::path::Path>, overrides: &[(String, toml::Value)]) -> PyResult<TrainConfig> {
    TrainConfig::load_values(file, overrides).map_err(to_py_err)
}

/// A JSON value as a Python object (None, bool, int, float, str, list, dict).
pub fn json_to_py<'py>(py: Python<'py>, value: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    use serde_json::Value;
    Ok(match value {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => PyBool::new(py, *b).to_owned().into_any(),
        Value::Number(n) => match (n.as_i64(), n.as_u64()) {
            (Some(i), _) => i.into_pyobject(py)?.into_any(),
            (None, Some(u)) => u.into_pyobject(py)?.into_any(),
            _ => n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any(),
        },
        Value::String(s) => PyString::new(py, s).into_any(),
        Value::Array(items) => PyList::new(py, items.iter().map(|v| json_to_py(py, v)).collect::<PyResult<Vec<_>>>()?)?.into_any(),
        Value::Object(map) => {
            let dict = PyDict::new(py);
            for (k, v) in map {
                dict.set_item(k, json_to_py(py, v)?)?;
            }
            dict.into_any()
        }
    })
}
