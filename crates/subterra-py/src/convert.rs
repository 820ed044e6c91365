//! NumPy and Python values in, core types out, with errors that name the argument.

use std::borrow::Cow;

use glam::DVec3;
use numpy::{PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use subterra::depth::DepthImage;
use subterra::Isometry3;

use crate::errors::input_error;

/// Largest risk grid accepted from an array [cells]: 16.7 M (4096 x 4096, 410 m square at
/// 0.1 m). Checked on the array's shape before anything is copied or converted.
pub const MAX_GRID_CELLS: usize = 1 << 24;
/// Largest point cloud accepted in one call [points] (128 full OS1-128 scans).
pub const MAX_POINTS: usize = 1 << 25;
/// Largest path accepted [points].
pub const MAX_PATH_POINTS: usize = 1 << 20;

/// Errors unless an array of `shape` has at most `max` rows (its first axis: points, poses),
/// naming the whole shape (checked before any copy, as [`check_elements`]).
pub fn check_rows(py: Python<'_>, argument: &str, shape: &[usize], max: usize, unit: &str) -> PyResult<()> {
    match shape.first() {
        Some(&n) if n > max => Err(input_error(py, format!("argument `{argument}` has shape {shape:?}: more than {max} {unit}, the most accepted"))),
        _ => Ok(()),
    }
}

/// Errors unless an array of `shape` has at most `max` elements (checked before any copy, so
/// that a broadcast view of 10^10 elements is refused rather than materialised).
pub fn check_elements(py: Python<'_>, argument: &str, shape: &[usize], max: usize, unit: &str) -> PyResult<()> {
    let n = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
    match n {
        Some(n) if n <= max => Ok(()),
        _ => Err(input_error(py, format!("argument `{argument}` has shape {shape:?}: more than {max} {unit}, the most accepted"))),
    }
}

/// The NumPy view of `value` (no copy for an array) with a real dtype (float, int, uint).
/// Complex, boolean, object and string arrays are errors naming `argument`.
pub fn real_array<'py>(py: Python<'py>, argument: &str, value: &Bound<'py, PyAny>, what: &str) -> PyResult<Bound<'py, PyAny>> {
    let np = py.import("numpy")?;
    let raw = np.call_method1("asarray", (value,)).map_err(|_| input_error(py, format!("argument `{argument}` must be {what}, got {}", type_name(value))))?;
    let kind: String = raw.getattr("dtype")?.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(input_error(py, format!("argument `{argument}` must be {what} of real numbers, got {}", type_name(&raw))));
    }
    Ok(raw)
}

/// Exactly `n` real numbers (NaN and inf included) from a sequence or array of any shape with
/// `n` elements.
pub fn real_vector(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>, n: usize, what: &str) -> PyResult<Vec<f64>> {
    let raw = real_array(py, argument, value, what)?;
    let size: usize = raw.getattr("size")?.extract()?;
    if size != n {
        let shape: Vec<usize> = raw.getattr("shape")?.extract()?;
        return Err(input_error(py, format!("argument `{argument}` must be {what}, got {size} numbers (shape {shape:?})")));
    }
    raw.call_method1("astype", ("float64",))?.call_method0("ravel")?.call_method0("tolist")?.extract()
}

/// Exactly `n` finite real numbers from a sequence or array of any shape with `n` elements.
pub fn small_vector(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>, n: usize, what: &str) -> PyResult<Vec<f64>> {
    let v = real_vector(py, argument, value, n, what)?;
    if v.iter().any(|x| !x.is_finite()) {
        return Err(input_error(py, format!("argument `{argument}` must be finite, got {v:?}")));
    }
    Ok(v)
}

/// A `str`, with an error naming `argument` (not pyo3's bare `TypeError`).
pub fn text(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<String> {
    let s = value.cast::<pyo3::types::PyString>().map_err(|_| input_error(py, format!("argument `{argument}` must be a str, got {}", type_name(value))))?;
    s.to_str().map(str::to_owned).map_err(|_| input_error(py, format!("argument `{argument}` must be valid Unicode text (no lone surrogates), got {}", short_repr(value))))
}

/// A real number, with an error naming `argument` (not the bare conversion error).
pub fn real(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<f64> {
    let not_real = || input_error(py, format!("argument `{argument}` must be a real number, got {}", type_name(value)));
    if value.is_instance_of::<pyo3::types::PyBool>() || value.is_instance_of::<pyo3::types::PyComplex>() {
        return Err(not_real());
    }
    // A NumPy scalar or 0-d array: float() of a complex64 or a bool_ would drop its imaginary part
    // or read True as 1.
    if !value.is_exact_instance_of::<pyo3::types::PyFloat>() && !value.is_exact_instance_of::<pyo3::types::PyInt>() {
        if let Ok(kind) = value.getattr("dtype").and_then(|d| d.getattr("kind")).and_then(|k| k.extract::<String>()) {
            if !matches!(kind.as_str(), "f" | "i" | "u") {
                return Err(not_real());
            }
        }
    }
    value.extract::<f64>().map_err(|_| input_error(py, format!("argument `{argument}` must be a real number, got {}", type_name(value))))
}

/// An integer in `lo..=hi`, with an error naming `argument` and the range (no range when it
/// is all of `i128`: the caller checks the value itself).
pub fn integer(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>, lo: i128, hi: i128) -> PyResult<i128> {
    let range = if lo == i128::MIN && hi == i128::MAX { String::new() } else { format!(" in {lo}..={hi}") };
    let bad = || input_error(py, format!("argument `{argument}` must be an integer{range}, got {}", short_repr(value)));
    if value.is_instance_of::<pyo3::types::PyBool>() {
        return Err(bad());
    }
    let v: i128 = value.call_method0("__index__").and_then(|i| i.extract()).map_err(|_| bad())?;
    if (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(bad())
    }
}

/// An instance of the Python class `T`, with an error naming `argument` and the class (pyo3's
/// own cast is a bare `TypeError` that names no argument).
pub fn instance<'py, T: pyo3::PyTypeInfo>(argument: &str, class: &str, value: &Bound<'py, PyAny>) -> PyResult<Bound<'py, T>> {
    value
        .cast::<T>()
        .cloned()
        .map_err(|_| input_error(value.py(), format!("argument `{argument}` must be a subterra {class}, got {}", type_name(value))))
}

/// The points of a path given as a sequence of 3-vectors [m] named `argument` (`path[n]` in
/// errors). Its length is checked before the first point is read, so that a broadcast view
/// of 10^9 points is refused at once rather than walked; a sequence without a length stops
/// at the limit.
pub fn path3(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<Vec<DVec3>> {
    let too_long = |n: usize| input_error(py, format!("argument `{argument}` has {n} points: more than {MAX_PATH_POINTS}, the most accepted"));
    if let Ok(n) = value.len() {
        if n > MAX_PATH_POINTS {
            return Err(too_long(n));
        }
    }
    let items = value.try_iter().map_err(|_| input_error(py, format!("argument `{argument}` must be a sequence of 3-vectors, got {}", type_name(value))))?;
    let mut points = Vec::new();
    for (n, item) in items.enumerate() {
        if n >= MAX_PATH_POINTS {
            return Err(too_long(n + 1));
        }
        points.push(vec3(py, &format!("{argument}[{n}]"), &item?)?);
    }
    Ok(points)
}

/// `repr(value)` cut to 60 characters, for messages.
fn short_repr(value: &Bound<'_, PyAny>) -> String {
    let r = value.repr().map(|r| r.to_string()).unwrap_or_else(|_| type_name(value));
    if r.chars().count() > 60 {
        format!("{}...", r.chars().take(57).collect::<String>())
    } else {
        r
    }
}

/// A 3-vector from any sequence or array of three finite numbers.
pub fn vec3(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<DVec3> {
    let v = small_vector(py, argument, value, 3, "3 numbers")?;
    Ok(DVec3::new(v[0], v[1], v[2]))
}

/// A rigid transform from a 4x4 homogeneous matrix (array or nested sequence).
pub fn isometry(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<Isometry3> {
    // The dtype (a complex or bool matrix is not a pose: a cast would drop the imaginary
    // part with only a warning) and the shape are checked on the view, before any copy.
    let raw = real_array(py, argument, value, "a 4x4 matrix")?;
    let shape: Vec<usize> = raw.getattr("shape")?.extract()?;
    if shape != [4, 4] {
        return Err(input_error(py, format!("argument `{argument}` must have shape (4, 4), got {shape:?}")));
    }
    let array = raw.call_method1("astype", ("float64",))?;
    let array = array
        .cast::<PyArray2<f64>>()
        .map_err(|_| input_error(py, format!("argument `{argument}` must be a 4x4 matrix")))?;
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
/// The shape must be `expected` `(width, height)`; it is checked before any copy.
pub fn with_depth<T>(
    py: Python<'_>,
    depth: &Bound<'_, PyAny>,
    scale: Option<f64>,
    expected: (u32, u32),
    f: impl FnOnce(&DepthPixels<'_>, u32, u32) -> T,
) -> PyResult<T> {
    let check = |shape: &[usize]| -> PyResult<()> {
        let (ew, eh) = (expected.0 as usize, expected.1 as usize);
        if shape != [eh, ew] {
            return Err(input_error(py, format!("argument `depth` has shape {shape:?}; the camera is {ew}x{eh}, so it must be ({eh}, {ew})")));
        }
        Ok(())
    };
    if let Some(s) = scale {
        let (lo, hi) = subterra::depth::DEPTH_SCALE_RANGE_M_PER_UNIT;
        if !(s.is_finite() && (lo..=hi).contains(&s)) {
            return Err(input_error(py, format!("argument `scale` must be in [{lo:e}, {hi}] m/unit (metres per unit), got {s:e}")));
        }
    }
    if let Ok(array) = depth.cast::<PyArray2<u16>>() {
        check(array.shape())?;
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
        check(array.shape())?;
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

/// Extractors for `#[pyo3(from_py_with = ...)]`: one per argument name, so that a value of the
/// wrong type or out of range is an `InputError` naming the argument (pyo3's own conversion
/// raises a bare `TypeError` or `OverflowError`). Defaults and signatures stay as they are.
pub mod arg {
    use pyo3::prelude::*;

    use super::{instance, integer, real, text};
    use crate::sim::{PyDepthCamera, PyLidar, PyWorld};
    use crate::{PyDepthPerception, PyObstacleMemory, PyPerceptionOutput, PyPinholeCamera};

    /// `None` (explicit) or a real number.
    fn opt_real(argument: &str, v: &Bound<'_, PyAny>) -> PyResult<Option<f64>> {
        if v.is_none() {
            Ok(None)
        } else {
            real(v.py(), argument, v).map(Some)
        }
    }

    macro_rules! reals {
        ($($name:ident),* $(,)?) => {$(
            #[allow(dead_code)]
            pub fn $name(v: &Bound<'_, PyAny>) -> PyResult<f64> {
                real(v.py(), stringify!($name), v)
            }
        )*};
    }
    macro_rules! opt_reals {
        ($($fn_name:ident => $name:ident),* $(,)?) => {$(
            #[allow(dead_code)]
            pub fn $fn_name(v: &Bound<'_, PyAny>) -> PyResult<Option<f64>> {
                opt_real(stringify!($name), v)
            }
        )*};
    }
    macro_rules! integers {
        ($($fn_name:ident => $name:ident: $ty:ty),* $(,)?) => {$(
            #[allow(dead_code)]
            pub fn $fn_name(v: &Bound<'_, PyAny>) -> PyResult<$ty> {
                integer(v.py(), stringify!($name), v, <$ty>::MIN as i128, <$ty>::MAX as i128).map(|n| n as $ty)
            }
        )*};
    }

    macro_rules! texts {
        ($($fn_name:ident => $name:ident),* $(,)?) => {$(
            #[allow(dead_code)]
            pub fn $fn_name(v: &Bound<'_, PyAny>) -> PyResult<String> {
                text(v.py(), stringify!($name), v)
            }
        )*};
    }

    macro_rules! instances {
        ($($fn_name:ident => $name:ident: $ty:ty = $class:literal),* $(,)?) => {$(
            #[allow(dead_code)]
            pub fn $fn_name<'py>(v: &Bound<'py, PyAny>) -> PyResult<Bound<'py, $ty>> {
                instance(stringify!($name), $class, v)
            }
        )*};
    }
    macro_rules! opt_instances {
        ($($fn_name:ident => $name:ident: $ty:ty = $class:literal),* $(,)?) => {$(
            #[allow(dead_code)]
            pub fn $fn_name<'py>(v: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, $ty>>> {
                if v.is_none() {
                    Ok(None)
                } else {
                    instance(stringify!($name), $class, v).map(Some)
                }
            }
        )*};
    }

    /// `None` (explicit) or a `str` named `region`.
    pub fn opt_region(v: &Bound<'_, PyAny>) -> PyResult<Option<String>> {
        if v.is_none() {
            Ok(None)
        } else {
            text(v.py(), "region", v).map(Some)
        }
    }

    /// `None` (explicit) or a `str` named `mode`.
    pub fn opt_mode(v: &Bound<'_, PyAny>) -> PyResult<Option<String>> {
        if v.is_none() {
            Ok(None)
        } else {
            text(v.py(), "mode", v).map(Some)
        }
    }

    texts!(s_name => name, s_text => text, s_preset => preset, s_frame => frame, s_noise => noise,
           s_dtype => dtype, s_vehicle => vehicle, s_cause => cause, s_depth_dtype => depth_dtype, s_layer => layer, s_controller => controller);

    reals!(stamp, remaining_m, lookahead_m, confidence, speed, x, y, alpha, min_range_m, max_range_m, yaw, radius_m, dt, compute_time_s, sensor_height);
    opt_reals!(opt_scale => scale, opt_resolution => resolution, opt_desired_speed => desired_speed, opt_stamp => stamp, opt_limit_s => limit_s);
    integers!(state_i64 => state: i64, i_i64 => i: i64, j_i64 => j: i64, k_i64 => k: i64, seed_u64 => seed: u64, id_u32 => id: u32, threads_usize => threads: usize, n_usize => n: usize);

    instances!(camera => camera: PyPinholeCamera = "PinholeCamera", perception => perception: PyDepthPerception = "DepthPerception",
               output => output: PyPerceptionOutput = "PerceptionOutput", world => world: PyWorld = "sim.World",
               depth_camera => camera: PyDepthCamera = "sim.DepthCamera", lidar => lidar: PyLidar = "sim.Lidar");
    opt_instances!(opt_camera => camera: PyPinholeCamera = "PinholeCamera", opt_perception => perception: PyDepthPerception = "DepthPerception",
                   opt_memory => memory: PyObstacleMemory = "ObstacleMemory");
}
