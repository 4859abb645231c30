//! `nudge._native.PlannerSettings` and `nudge._native.SimConfig`: the planner's and the
//! closed loop's settings, round-tripping with Python dicts and JSON text.
//!
//! Both go through serde (`serde_json::Value`): every key must be a known field (unknown keys
//! raise `SettingsError` naming the key), each value must have its default's type (integers
//! stay integers, floats must be finite, names must be one of the field's names; a group of
//! the planner settings is a dict of its fields, `PlannerSettings(cost={"w_y": 20})`), and the
//! result is validated by the Rust `validate()`.

use nudge_planner::PlannerSettings;
use nudge_planner::describe::{Described, FieldDoc};
use nudge_sim::SimConfig;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString};
use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::{Map, Number, Value};

use crate::errors::{SettingsError, settings_err, sim_config_err};

/// A settings struct with serde (de)serialisation, defaults and validation.
pub trait Settings: Serialize + DeserializeOwned + Default + Clone {
    /// What the struct is called in messages.
    const WHAT: &'static str;
    /// What one field is called in messages.
    const FIELD: &'static str;
    /// Validates every field; the error as a Python exception.
    fn check(&self) -> PyResult<()>;
    /// Parses and validates JSON text.
    fn parse_json(text: &str) -> PyResult<Self>;
    /// The error for a top-level key of an earlier version (moved or removed), if `key` is one.
    fn old_key(_key: &str) -> Option<PyErr> {
        None
    }
}

impl Settings for PlannerSettings {
    const WHAT: &'static str = "planner settings";
    const FIELD: &'static str = "planner setting";
    fn check(&self) -> PyResult<()> {
        self.validate().map_err(settings_err)
    }
    fn parse_json(text: &str) -> PyResult<Self> {
        Self::from_json(text).map_err(settings_err)
    }
    fn old_key(key: &str) -> Option<PyErr> {
        nudge_planner::settings::check_key(key)
            .err()
            .map(settings_err)
    }
}

impl Settings for SimConfig {
    const WHAT: &'static str = "closed-loop settings";
    const FIELD: &'static str = "closed-loop setting";
    fn check(&self) -> PyResult<()> {
        self.validate().map_err(sim_config_err)
    }
    fn parse_json(text: &str) -> PyResult<Self> {
        Self::from_json(text).map_err(sim_config_err)
    }
}

/// The settings as a JSON object (field name → value).
fn as_object<T: Settings>(s: &T) -> PyResult<Map<String, Value>> {
    match serde_json::to_value(s) {
        Ok(Value::Object(m)) => Ok(m),
        Ok(other) => Err(SettingsError::new_err(format!(
            "{} serialised to {other}, expected an object",
            T::WHAT
        ))),
        Err(e) => Err(SettingsError::new_err(format!(
            "cannot serialise {}: {e}",
            T::WHAT
        ))),
    }
}

/// A JSON value as a Python object (settings hold bools, numbers and names).
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
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Object(m) => {
            let d = PyDict::new(py);
            for (k, v) in m {
                d.set_item(k, value_to_py(py, v)?)?;
            }
            d.into_any()
        }
        other => other.to_string().into_pyobject(py)?.into_any(),
    })
}

/// One Python value for field `key`, type-checked against the default's JSON type.
fn py_to_value<T: Settings>(key: &str, default: &Value, v: &Bound<'_, PyAny>) -> PyResult<Value> {
    let bad = |want: &str| {
        SettingsError::new_err(format!(
            "{} `{key}`: expected {want}, got {} ({})",
            T::FIELD,
            v.repr().map_or_else(|_| "?".to_string(), |r| r.to_string()),
            v.get_type()
                .name()
                .map_or_else(|_| "?".to_string(), |n| n.to_string()),
        ))
    };
    let is_bool = v.is_instance_of::<PyBool>();
    match default {
        Value::Bool(_) if is_bool => Ok(Value::Bool(v.extract::<bool>()?)),
        Value::Bool(_) => Err(bad("a bool")),
        Value::Number(n) if n.is_u64() || n.is_i64() => {
            let integer = v.is_instance_of::<PyInt>() || v.hasattr("__index__").unwrap_or(false);
            match v.extract::<u64>() {
                Ok(u) if integer && !is_bool => Ok(Value::Number(u.into())),
                _ => Err(bad("a non-negative integer")),
            }
        }
        Value::Number(_) => {
            let number = v.is_instance_of::<PyFloat>()
                || v.is_instance_of::<PyInt>()
                || v.hasattr("__float__").unwrap_or(false);
            if is_bool || !number {
                return Err(bad("a number"));
            }
            let x: f64 = v.extract().map_err(|_| bad("a number"))?;
            Number::from_f64(x)
                .map(Value::Number)
                .ok_or_else(|| bad("a finite number"))
        }
        Value::String(_) if v.is_instance_of::<PyString>() => Ok(Value::String(v.extract()?)),
        Value::String(_) => Err(bad("a str")),
        Value::Object(fields) => {
            let dict = v
                .cast::<PyDict>()
                .map_err(|_| bad("a dict of the group's fields"))?;
            let mut out = fields.clone();
            for (k, item) in dict.iter() {
                let name: String = k.extract().map_err(|_| bad("a dict with str keys"))?;
                let path = format!("{key}.{name}");
                let Some(default) = fields.get(&name) else {
                    let mut known: Vec<&str> = fields.keys().map(String::as_str).collect();
                    known.sort_unstable();
                    return Err(SettingsError::new_err(format!(
                        "unknown {} `{path}` (known in `{key}`: {})",
                        T::FIELD,
                        known.join(", ")
                    )));
                };
                out.insert(name, py_to_value::<T>(&path, default, &item)?);
            }
            Ok(Value::Object(out))
        }
        _ => Err(bad("a supported value")),
    }
}

/// `base` with the fields of the Python mapping `d` replaced, validated.
pub fn with_overrides<T: Settings>(base: &T, d: &Bound<'_, PyAny>) -> PyResult<T> {
    let dict = d.cast::<PyDict>().map_err(|_| {
        SettingsError::new_err(format!(
            "{}: expected a dict, got {}",
            T::WHAT,
            d.get_type()
                .name()
                .map_or_else(|_| "?".to_string(), |n| n.to_string())
        ))
    })?;
    let mut obj = as_object(base)?;
    for (k, v) in dict.iter() {
        let key: String = k.extract().map_err(|_| {
            SettingsError::new_err(format!(
                "{}: keys must be str, got {}",
                T::WHAT,
                k.repr().map_or_else(|_| "?".to_string(), |r| r.to_string())
            ))
        })?;
        if let Some(e) = T::old_key(&key) {
            return Err(e);
        }
        // A dotted key (`"cost.w_y"`, as `describe()` names fields) sets one field of a group.
        let (top, v) = match key.split_once('.') {
            Some((group, leaf)) => {
                let py = v.py();
                let one = PyDict::new(py);
                one.set_item(leaf, &v)?;
                (group.to_owned(), one.into_any())
            }
            None => (key.clone(), v),
        };
        let key = top;
        let Some(default) = obj.get(&key) else {
            let mut known: Vec<&str> = obj.keys().map(String::as_str).collect();
            known.sort_unstable();
            return Err(SettingsError::new_err(format!(
                "unknown {} `{key}` (known: {})",
                T::FIELD,
                known.join(", ")
            )));
        };
        let value = py_to_value::<T>(&key, default, &v)?;
        // A name must be one the field knows: deserialise with only this field replaced.
        let mut one = obj.clone();
        one.insert(key.clone(), value.clone());
        serde_json::from_value::<T>(Value::Object(one))
            .map_err(|e| SettingsError::new_err(format!("{} `{key}`: {e}", T::FIELD)))?;
        obj.insert(key, value);
    }
    let out: T = serde_json::from_value(Value::Object(obj))
        .map_err(|e| SettingsError::new_err(format!("{}: {e}", T::WHAT)))?;
    out.check()?;
    Ok(out)
}

/// Every field as a Python dict.
fn to_dict<'py, T: Settings>(py: Python<'py>, s: &T) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    for (k, v) in as_object(s)? {
        out.set_item(k, value_to_py(py, &v)?)?;
    }
    Ok(out)
}

/// Field `name` as a Python value.
fn field<'py, T: Settings>(
    py: Python<'py>,
    s: &T,
    class: &str,
    name: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let obj = as_object(s)?;
    let found = match name.split_once('.') {
        Some((group, leaf)) => obj.get(group).and_then(|g| g.get(leaf)),
        None => obj.get(name),
    };
    match found {
        Some(v) => value_to_py(py, v),
        None => Err(pyo3::exceptions::PyAttributeError::new_err(format!(
            "{class} has no field `{name}`"
        ))),
    }
}

/// One described field as a Python dict (`field`, `unit`, `default`, `range`, `doc`).
fn field_dict<'py>(py: Python<'py>, f: &FieldDoc) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("field", &f.field)?;
    d.set_item("unit", f.unit)?;
    d.set_item("default", value_to_py(py, &f.default)?)?;
    d.set_item("range", &f.range)?;
    d.set_item("doc", &f.doc)?;
    Ok(d)
}

/// Every field of `T` as a list of dicts ([`describe`]).
fn describe_list<T: Settings + Described>(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
    let rows = T::rows()
        .iter()
        .map(|f| field_dict(py, f))
        .collect::<PyResult<Vec<_>>>()?;
    PyList::new(py, rows)
}

/// The class docstring of `T`: its own text, then every field with its type, unit, default,
/// valid values and meaning (numpy style), from the same rows as `describe()`.
fn class_doc<T: Settings + Described>(intro: &str) -> String {
    let mut doc = format!("{intro}\n\nFields\n------\n");
    for f in T::rows() {
        let kind = match &f.default {
            serde_json::Value::Bool(_) => "bool",
            serde_json::Value::Number(n) if n.is_f64() => "float",
            serde_json::Value::Number(_) => "int",
            _ => "str",
        };
        let unit = if f.unit.is_empty() {
            String::new()
        } else {
            format!(" ({})", f.unit)
        };
        doc.push_str(&format!(
            "{} : {kind}{unit}, default {}, valid values {}\n    {}\n",
            f.field, f.default, f.range, f.doc
        ));
    }
    doc
}

/// Sets the docstrings of the settings classes of module `m` to list every field
/// ([`class_doc`]); called once when the module is made.
pub fn document_fields(m: &Bound<'_, PyModule>) -> PyResult<()> {
    for (name, doc) in [
        ("PlannerSettings", class_doc::<PlannerSettings>(PLANNER_DOC)),
        ("SimConfig", class_doc::<SimConfig>(SIM_DOC)),
    ] {
        m.getattr(name)?.setattr("__doc__", doc)?;
    }
    Ok(())
}

/// The settings as JSON text.
fn to_json<T: Settings>(s: &T) -> PyResult<String> {
    serde_json::to_string_pretty(s)
        .map_err(|e| SettingsError::new_err(format!("cannot serialise {}: {e}", T::WHAT)))
}

/// The Python class of a [`Settings`] struct: construction with overrides, `default()`,
/// dict and JSON round trips, `replace()`, attribute access to every field.
macro_rules! settings_class {
    ($py:ident, $rust:ty, $name:literal, $doc:literal) => {
        #[doc = $doc]
        #[pyclass(name = $name, module = "nudge._native", frozen, eq)]
        #[derive(Debug, Clone, PartialEq)]
        pub struct $py {
            /// The validated Rust settings.
            pub inner: $rust,
        }

        #[pymethods]
        impl $py {
            /// The defaults with the given fields replaced.
            #[new]
            #[pyo3(signature = (**overrides))]
            fn new(py: Python<'_>, overrides: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
                crate::args::guard(|| {
                    let empty = PyDict::new(py);
                    let d = overrides.unwrap_or(&empty);
                    with_overrides(&<$rust>::default(), d.as_any()).map(|inner| Self { inner })
                })
            }

            /// The defaults.
            #[staticmethod]
            fn default() -> Self {
                Self {
                    inner: <$rust>::default(),
                }
            }

            /// Settings from a dict; missing keys default, unknown keys or bad values raise
            /// `SettingsError` naming the key.
            #[staticmethod]
            fn from_dict(d: &Bound<'_, PyAny>) -> PyResult<Self> {
                crate::args::guard(|| {
                    with_overrides(&<$rust>::default(), d).map(|inner| Self { inner })
                })
            }

            /// Every field as a dict.
            fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
                to_dict(py, &self.inner)
            }

            /// Settings from JSON text (the format of the CLI's settings files).
            #[staticmethod]
            fn from_json(text: &str) -> PyResult<Self> {
                crate::args::guard(|| {
                    <$rust as Settings>::parse_json(text).map(|inner| Self { inner })
                })
            }

            /// The settings as JSON text.
            fn to_json(&self) -> PyResult<String> {
                to_json(&self.inner)
            }

            /// A copy with some fields replaced (same checks as `from_dict`).
            #[pyo3(signature = (**overrides))]
            fn replace(
                &self,
                py: Python<'_>,
                overrides: Option<&Bound<'_, PyDict>>,
            ) -> PyResult<Self> {
                crate::args::guard(|| {
                    let empty = PyDict::new(py);
                    let d = overrides.unwrap_or(&empty);
                    with_overrides(&self.inner, d.as_any()).map(|inner| Self { inner })
                })
            }

            /// Every field: a list of dicts with `field` (name), `unit`, `default`, `range` (the
            /// values validation accepts) and `doc` (meaning), from the Rust settings' doc
            /// comments, defaults and validation ranges (the page docs/reference/settings.md).
            #[staticmethod]
            fn describe(py: Python<'_>) -> PyResult<Bound<'_, PyList>> {
                describe_list::<$rust>(py)
            }

            /// Attribute access to every field.
            fn __getattr__<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyAny>> {
                field(py, &self.inner, $name, name)
            }

            fn __repr__(&self) -> PyResult<String> {
                let fields: Vec<String> = as_object(&self.inner)?
                    .iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect();
                Ok(format!("{}({})", $name, fields.join(", ")))
            }
        }
    };
}

/// The opening of `PlannerSettings`'s docstring (the fields follow, [`document_fields`]).
const PLANNER_DOC: &str = "Planner settings: every weight, bound, tolerance and limit of the ADMM MPC \
     (units: m, s, rad, m/s, m/s²), in groups by phase (model, cost, bounds, safety, admm, \
     repair, budget, lane_ends). Construct with group overrides \
     (`PlannerSettings(admm={\"max_iter\": 50})`) or dotted keys \
     (`PlannerSettings(**{\"admm.max_iter\": 50})`); a group reads as a dict (`s.admm`); \
     `describe()` lists every field, as does docs/reference/settings.md.";

/// The opening of `SimConfig`'s docstring (the fields follow, [`document_fields`]).
const SIM_DOC: &str = "Closed-loop settings (units: m, rad, 0.3 s steps). Construct with overrides \
     (`SimConfig(world=\"idm\")`); `describe()` lists every field, as does \
     docs/reference/settings.md.";

settings_class!(
    PySettings,
    PlannerSettings,
    "PlannerSettings",
    "Planner settings (every field, unit, default and range: `describe()`)."
);
settings_class!(
    PySimConfig,
    SimConfig,
    "SimConfig",
    "Closed-loop settings (every field, unit, default and range: `describe()`)."
);
