//! numpy → Rust conversion with shape and dtype checks that raise `InputError`: shapes are
//! checked on the view, before anything is copied (a broadcast view costs no memory in Python
//! but would be copied whole).

use numpy::{PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyList, PyTuple, PyType};

use crate::errors::InputError;

/// One axis of an expected shape.
#[derive(Debug, Clone, Copy)]
pub enum Dim {
    /// Exactly this size.
    Exact(usize),
    /// Any size up to this bound (the caller's library check names the real limit).
    AtMost(usize),
}

/// A float64 or float32 array viewed, not yet copied.
pub enum Floats<'py> {
    /// float64.
    F64(PyReadonlyArrayDyn<'py, f64>),
    /// float32.
    F32(PyReadonlyArrayDyn<'py, f32>),
}

impl Floats<'_> {
    /// The array's shape.
    pub fn shape(&self) -> &[usize] {
        match self {
            Self::F64(a) => a.shape(),
            Self::F32(a) => a.shape(),
        }
    }

    /// The values, row-major, as f64 (any strides).
    pub fn to_vec(&self) -> Vec<f64> {
        match self {
            Self::F64(a) => a.as_array().iter().copied().collect(),
            Self::F32(a) => a.as_array().iter().map(|&v| f64::from(v)).collect(),
        }
    }
}

/// `numpy.ma.MaskedArray`.
fn masked_array_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    static MASKED: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    MASKED.import(py, "numpy.ma", "MaskedArray")
}

fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.getattr("dtype").map_or_else(
        |_| {
            obj.get_type()
                .name()
                .map_or_else(|_| "?".to_owned(), |n| n.to_string())
        },
        |d| d.to_string(),
    )
}

/// Views `obj` as a float64 or float32 array: a numpy array of either dtype (any strides), or
/// a (nested) list or tuple of numbers, converted to float64. Other dtypes, masked arrays
/// (their mask would be ignored) and other objects raise `InputError` naming `what`.
pub fn floats<'py>(what: &str, obj: &Bound<'py, PyAny>) -> PyResult<Floats<'py>> {
    let py = obj.py();
    if obj.is_instance(masked_array_type(py)?)? {
        return Err(InputError::new_err(format!(
            "{what}: masked arrays are not supported (the mask would be ignored); pass \
             `a.filled(...)` or drop the masked rows"
        )));
    }
    if let Ok(a) = obj.extract::<PyReadonlyArrayDyn<'py, f64>>() {
        return Ok(Floats::F64(a));
    }
    if let Ok(a) = obj.extract::<PyReadonlyArrayDyn<'py, f32>>() {
        return Ok(Floats::F32(a));
    }
    let expected = || {
        InputError::new_err(format!(
            "{what}: expected a float64 (or float32) numpy array or a nested list of numbers, \
             got {}",
            type_name(obj)
        ))
    };
    if !(obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>()) {
        return Err(expected());
    }
    // A (nested) sequence: numpy decides whether it is a rectangular array of real numbers.
    let np = py.import("numpy")?;
    let arr = np.call_method1("asarray", (obj,)).map_err(|_| expected())?;
    let kind: String = arr.getattr("dtype")?.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(expected());
    }
    let arr = arr.call_method1("astype", ("float64",))?;
    arr.cast_into::<PyArrayDyn<f64>>()
        .map(|a| Floats::F64(a.readonly()))
        .map_err(|_| expected())
}

/// Raises `InputError` unless `shape` matches `expected`.
pub fn check_shape(what: &str, shape: &[usize], expected: &[Dim]) -> PyResult<()> {
    let ok = shape.len() == expected.len()
        && shape.iter().zip(expected).all(|(s, e)| match e {
            Dim::Exact(n) => s == n,
            Dim::AtMost(n) => s <= n,
        });
    if ok {
        return Ok(());
    }
    let want: Vec<String> = expected
        .iter()
        .map(|e| match e {
            Dim::Exact(n) => n.to_string(),
            Dim::AtMost(n) => format!("≤{n}"),
        })
        .collect();
    Err(InputError::new_err(format!(
        "{what}: expected shape [{}], got {shape:?}",
        want.join(", ")
    )))
}

/// [`floats`] checked against `expected` (before copying), copied row-major; with its shape.
pub fn to_f64(
    what: &str,
    obj: &Bound<'_, PyAny>,
    expected: &[Dim],
) -> PyResult<(Vec<f64>, Vec<usize>)> {
    let a = floats(what, obj)?;
    let shape = a.shape().to_vec();
    check_shape(what, &shape, expected)?;
    Ok((a.to_vec(), shape))
}
