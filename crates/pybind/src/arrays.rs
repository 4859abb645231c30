//! numpy → Rust conversion with shape and dtype checks that raise `InputError`.

use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::errors::InputError;

/// Copies a float64 or float32 numpy array of any strides into a row-major `Vec<f64>` and
/// returns it with its shape. Other dtypes, or objects that are not arrays, raise `InputError`.
pub fn to_f64(what: &str, obj: &Bound<'_, PyAny>) -> PyResult<(Vec<f64>, Vec<usize>)> {
    if let Ok(a) = obj.extract::<PyReadonlyArrayDyn<'_, f64>>() {
        let shape = a.shape().to_vec();
        return Ok((a.as_array().iter().copied().collect(), shape));
    }
    if let Ok(a) = obj.extract::<PyReadonlyArrayDyn<'_, f32>>() {
        let shape = a.shape().to_vec();
        return Ok((a.as_array().iter().map(|&v| f64::from(v)).collect(), shape));
    }
    let dtype = obj
        .getattr("dtype")
        .map_or_else(|_| format!("{}", obj.get_type()), |d| d.to_string());
    Err(InputError::new_err(format!(
        "{what}: expected a float64 (or float32) numpy array, got {dtype}"
    )))
}

/// Raises `InputError` unless `shape` matches `expected` (`None` = any size on that axis).
pub fn check_shape(what: &str, shape: &[usize], expected: &[Option<usize>]) -> PyResult<()> {
    let ok = shape.len() == expected.len()
        && shape
            .iter()
            .zip(expected)
            .all(|(s, e)| e.is_none_or(|e| e == *s));
    if ok {
        Ok(())
    } else {
        let want: Vec<String> = expected
            .iter()
            .map(|e| e.map_or_else(|| "*".to_string(), |v| v.to_string()))
            .collect();
        Err(InputError::new_err(format!(
            "{what}: expected shape [{}], got {shape:?}",
            want.join(", ")
        )))
    }
}
