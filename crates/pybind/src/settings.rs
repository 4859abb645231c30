//! `nudge._native.PlannerSettings`: the planner's settings, round-tripping with a Python dict.
//!
//! Conversion goes through serde (`serde_json::Value`): every key must be a known setting
//! (unknown keys raise `SettingsError` naming the key), integers stay integers, floats must be
//! finite, and the result is validated by `PlannerSettings::validate`.

use nudge_planner::PlannerSettings;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt};
use serde_json::{Map, Number, Value};

use crate::errors::{SettingsError, settings_err};

/// Planner settings (see `crates/planner/src/settings.rs` for every field, unit and default).
#[pyclass(name = "PlannerSettings", module = "nudge._native", frozen, eq)]
#[derive(Debug, Clone, PartialEq)]
pub struct PySettings {
    /// The validated Rust settings.
    pub inner: PlannerSettings,
}

/// The settings as a JSON object (field name → value).
fn as_object(s: &PlannerSettings) -> PyResult<Map<String, Value>> {
    match serde_json::to_value(s) {
        Ok(Value::Object(m)) => Ok(m),
        Ok(other) => Err(SettingsError::new_err(format!(
            "planner settings serialised to {other}, expected an object"
        ))),
        Err(e) => Err(SettingsError::new_err(format!(
            "cannot serialise planner settings: {e}"
        ))),
    }
}

/// A JSON value as a Python object (settings hold only bools and numbers).
fn value_to_py<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        Value::Bool(b) => PyBool::new(py, *b).to_owned().into_any(),
        Value::Number(n) => {
            if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any()
            } else if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any()
            } else {
                n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any()
            }
        }
        other => other.to_string().into_pyobject(py)?.into_any(),
    })
}

/// One Python value for setting `key`, type-checked against the default's JSON type.
fn py_to_value(key: &str, default: &Value, v: &Bound<'_, PyAny>) -> PyResult<Value> {
    let bad = |want: &str| {
        SettingsError::new_err(format!(
            "planner setting `{key}`: expected {want}, got {} ({})",
            v.repr().map_or_else(|_| "?".to_string(), |r| r.to_string()),
            v.get_type()
                .name()
                .map_or_else(|_| "?".to_string(), |n| n.to_string()),
        ))
    };
    match default {
        Value::Bool(_) => {
            if v.is_instance_of::<PyBool>() {
                Ok(Value::Bool(v.extract::<bool>()?))
            } else {
                Err(bad("a bool"))
            }
        }
        Value::Number(n) if n.is_u64() || n.is_i64() => {
            if v.is_instance_of::<PyBool>() {
                return Err(bad("a non-negative integer"));
            }
            if v.is_instance_of::<PyInt>() || v.hasattr("__index__").unwrap_or(false) {
                v.extract::<u64>()
                    .map(|u| Value::Number(u.into()))
                    .map_err(|_| bad("a non-negative integer"))
            } else {
                Err(bad("a non-negative integer"))
            }
        }
        Value::Number(_) => {
            if v.is_instance_of::<PyBool>() {
                return Err(bad("a number"));
            }
            if !(v.is_instance_of::<PyFloat>()
                || v.is_instance_of::<PyInt>()
                || v.hasattr("__float__").unwrap_or(false))
            {
                return Err(bad("a number"));
            }
            let x: f64 = v.extract().map_err(|_| bad("a number"))?;
            Number::from_f64(x)
                .map(Value::Number)
                .ok_or_else(|| bad("a finite number"))
        }
        _ => Err(bad("a supported value")),
    }
}

impl PySettings {
    /// Settings from a Python mapping of overrides (missing keys keep their defaults).
    pub fn from_mapping(d: &Bound<'_, PyAny>) -> PyResult<Self> {
        let dict = d.cast::<PyDict>().map_err(|_| {
            SettingsError::new_err(format!(
                "planner settings: expected a dict, got {}",
                d.get_type()
                    .name()
                    .map_or_else(|_| "?".to_string(), |n| n.to_string())
            ))
        })?;
        let mut obj = as_object(&PlannerSettings::default())?;
        for (k, v) in dict.iter() {
            let key: String = k.extract().map_err(|_| {
                SettingsError::new_err(format!(
                    "planner settings: keys must be str, got {}",
                    k.repr().map_or_else(|_| "?".to_string(), |r| r.to_string())
                ))
            })?;
            let Some(default) = obj.get(&key) else {
                let mut known: Vec<&String> = obj.keys().collect();
                known.sort();
                let known: Vec<&str> = known.iter().map(|s| s.as_str()).collect();
                return Err(SettingsError::new_err(format!(
                    "unknown planner setting `{key}` (known: {})",
                    known.join(", ")
                )));
            };
            let value = py_to_value(&key, default, &v)?;
            obj.insert(key, value);
        }
        let inner: PlannerSettings = serde_json::from_value(Value::Object(obj))
            .map_err(|e| SettingsError::new_err(format!("planner settings: {e}")))?;
        inner.validate().map_err(settings_err)?;
        Ok(Self { inner })
    }
}

#[pymethods]
impl PySettings {
    /// `PlannerSettings(**overrides)`: the defaults with the given fields replaced.
    #[new]
    #[pyo3(signature = (**overrides))]
    fn new(py: Python<'_>, overrides: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        match overrides {
            Some(d) => Self::from_mapping(d.as_any()),
            None => Self::from_mapping(PyDict::new(py).as_any()),
        }
    }

    /// The defaults (the paper's values).
    #[staticmethod]
    fn default() -> Self {
        Self {
            inner: PlannerSettings::default(),
        }
    }

    /// Settings from a dict; missing keys default, unknown keys or bad values raise
    /// `SettingsError` naming the key.
    #[staticmethod]
    fn from_dict(d: &Bound<'_, PyAny>) -> PyResult<Self> {
        Self::from_mapping(d)
    }

    /// Every field as a dict (ints, floats, bools).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for (k, v) in as_object(&self.inner)? {
            out.set_item(k, value_to_py(py, &v)?)?;
        }
        Ok(out)
    }

    /// Settings from JSON text (the format of the Rust CLI's `--settings` files).
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        PlannerSettings::from_json(text)
            .map(|inner| Self { inner })
            .map_err(settings_err)
    }

    /// The settings as JSON text.
    fn to_json(&self) -> PyResult<String> {
        serde_json::to_string_pretty(&self.inner)
            .map_err(|e| SettingsError::new_err(format!("cannot serialise planner settings: {e}")))
    }

    /// A copy with some fields replaced (same checks as `from_dict`).
    #[pyo3(signature = (**overrides))]
    fn replace(&self, py: Python<'_>, overrides: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let d = self.to_dict(py)?;
        if let Some(o) = overrides {
            d.update(o.as_mapping())?;
        }
        Self::from_mapping(d.as_any())
    }

    /// Attribute access to every field (`settings.horizon`).
    fn __getattr__<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
        let obj = as_object(&self.inner)?;
        match obj.get(name) {
            Some(v) => value_to_py(py, v),
            None => Err(pyo3::exceptions::PyAttributeError::new_err(format!(
                "PlannerSettings has no field `{name}`"
            ))),
        }
    }

    fn __repr__(&self) -> String {
        let s = &self.inner;
        format!(
            "PlannerSettings(horizon={}, dt={}, rho={}, max_iter={}, ...)",
            s.horizon, s.dt, s.rho, s.max_iter
        )
    }
}
