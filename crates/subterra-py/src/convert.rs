//! NumPy and Python values in, core types out, with errors that name the argument.

use std::borrow::Cow;

use glam::DVec3;
use numpy::{PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use subterra::depth::DepthImage;
use subterra::Isometry3;

use crate::errors::input_error;

/// A 3-vector from any sequence or array of three finite numbers.
pub fn vec3(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<DVec3> {
    let v: Vec<f64> = value
        .extract()
        .or_else(|_| {
            let np = py.import("numpy")?;
            np.call_method1("asarray", (value, "float64"))?.call_method0("ravel")?.call_method0("tolist")?.extract()
        })
        .map_err(|_| input_error(py, format!("argument `{argument}` must be 3 numbers, got {}", type_name(value))))?;
    if v.len() != 3 {
        return Err(input_error(py, format!("argument `{argument}` must have 3 elements, got {}", v.len())));
    }
    let out = DVec3::new(v[0], v[1], v[2]);
    if !out.is_finite() {
        return Err(input_error(py, format!("argument `{argument}` must be finite, got {v:?}")));
    }
    Ok(out)
}

/// A rigid transform from a 4x4 homogeneous matrix (array or nested sequence).
pub fn isometry(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<Isometry3> {
    let np = py.import("numpy")?;
    let array = np
        .call_method1("asarray", (value, "float64"))
        .map_err(|_| input_error(py, format!("argument `{argument}` must be a 4x4 matrix of numbers, got {}", type_name(value))))?;
    let array = array
        .cast::<PyArray2<f64>>()
        .map_err(|_| input_error(py, format!("argument `{argument}` must be a 4x4 matrix")))?;
    if array.shape() != [4, 4] {
        return Err(input_error(py, format!("argument `{argument}` must have shape (4, 4), got {:?}", array.shape())));
    }
    let view = array.readonly();
    let a = view.as_array();
    let mut rows = [[0.0; 4]; 4];
    for (r, row) in rows.iter_mut().enumerate() {
        for (c, x) in row.iter_mut().enumerate() {
            *x = a[[r, c]];
        }
    }
    Isometry3::from_matrix_rows(argument, &rows).map_err(|e| crate::errors::to_py(py, e))
}

/// The type of a Python value, for messages (`ndarray[float64, 3-D]`, `list`).
pub fn type_name(value: &Bound<'_, PyAny>) -> String {
    if let Ok(array) = value.cast::<numpy::PyUntypedArray>() {
        let dtype = array.dtype().str().map(|s| s.to_string()).unwrap_or_default();
        return format!("ndarray of dtype {dtype} and shape {:?}", array.shape());
    }
    value.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into())
}

/// Pixels of a depth image held for the duration of one call.
pub enum DepthPixels<'a> {
    /// Raw units with their scale [m/unit].
    U16(Cow<'a, [u16]>, f64),
    /// Metres.
    F32(Cow<'a, [f32]>),
}

impl DepthPixels<'_> {
    /// The core's view.
    pub fn image(&self) -> DepthImage<'_> {
        match self {
            Self::U16(p, scale) => DepthImage::U16 { pixels: p, scale_m_per_unit: *scale },
            Self::F32(p) => DepthImage::F32 { pixels: p },
        }
    }
}

/// Calls `f` with the pixels of a `(H, W)` `uint16` or `float32` array and its width and height.
/// `scale` [m/unit] applies to `uint16` (default 0.001); a float image must not be given one.
pub fn with_depth<T>(
    py: Python<'_>,
    depth: &Bound<'_, PyAny>,
    scale: Option<f64>,
    f: impl FnOnce(&DepthPixels<'_>, u32, u32) -> T,
) -> PyResult<T> {
    if let Ok(array) = depth.cast::<PyArray2<u16>>() {
        let view = array.readonly();
        let (h, w) = (view.shape()[0], view.shape()[1]);
        // Borrow only a C-ordered buffer; anything else (Fortran order, transposed, strided)
        // is copied in logical row-major order.
        let pixels = match view.as_array().to_slice() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(view.as_array().iter().copied().collect()),
        };
        let scale = scale.unwrap_or(0.001);
        return Ok(f(&DepthPixels::U16(pixels, scale), dim(py, w)?, dim(py, h)?));
    }
    if let Ok(array) = depth.cast::<PyArray2<f32>>() {
        if scale.is_some_and(|s| s != 1.0) {
            return Err(input_error(py, "argument `scale` applies to uint16 depth only; a float32 depth image is already in metres"));
        }
        let view = array.readonly();
        let (h, w) = (view.shape()[0], view.shape()[1]);
        // Borrow only a C-ordered buffer; anything else (Fortran order, transposed, strided)
        // is copied in logical row-major order.
        let pixels = match view.as_array().to_slice() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(view.as_array().iter().copied().collect()),
        };
        return Ok(f(&DepthPixels::F32(pixels), dim(py, w)?, dim(py, h)?));
    }
    Err(input_error(
        py,
        format!(
            "argument `depth` must be a 2-D numpy array of dtype uint16 (raw units) or float32 (metres), got {}",
            type_name(depth)
        ),
    ))
}

fn dim(py: Python<'_>, n: usize) -> PyResult<u32> {
    u32::try_from(n).map_err(|_| input_error(py, format!("argument `depth` is too large ({n} pixels on a side)")))
}
