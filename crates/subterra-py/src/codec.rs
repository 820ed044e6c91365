//! Byte codecs the Python readers use: LZF (liblzf's format, PCL's `binary_compressed`),
//! through the `lzf` crate, a Rust port of liblzf. The GIL is released while they run.

use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::errors::input_error;

/// The largest output either function produces [bytes] (the PCD reader's own limit is lower).
const MAX_OUTPUT_BYTES: usize = 1 << 32;

/// LZF-decompresses `data` into exactly `expected_size` bytes, or returns None when the
/// stream is corrupt or decompresses to another size (the caller then explains why).
#[pyfunction]
fn lzf_decompress<'py>(py: Python<'py>, data: &Bound<'py, PyAny>, expected_size: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, PyBytes>>> {
    let data = bytes_of(py, "data", data)?;
    let data = data.as_slice();
    let expected_size = size_of(py, expected_size)?;
    if expected_size > MAX_OUTPUT_BYTES {
        return Err(input_error(py, format!("argument `expected_size` must be at most {MAX_OUTPUT_BYTES} bytes, got {expected_size}")));
    }
    if expected_size == 0 || data.is_empty() {
        return Ok((expected_size == 0 && data.is_empty()).then(|| PyBytes::new(py, b"")));
    }
    let out = py.detach(|| lzf::decompress(data, expected_size));
    Ok(match out {
        Ok(bytes) if bytes.len() == expected_size => Some(PyBytes::new(py, &bytes)),
        _ => None,
    })
}

/// LZF-compresses `data`; None when it would not get smaller (the caller stores it raw).
#[pyfunction]
fn lzf_compress<'py>(py: Python<'py>, data: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, PyBytes>>> {
    let data = bytes_of(py, "data", data)?;
    let data = data.as_slice();
    if data.len() > MAX_OUTPUT_BYTES {
        return Err(input_error(py, format!("argument `data` must be at most {MAX_OUTPUT_BYTES} bytes, got {}", data.len())));
    }
    if data.is_empty() {
        return Ok(None);
    }
    let out = py.detach(|| lzf::compress(data));
    Ok(out.ok().map(|bytes| PyBytes::new(py, &bytes)))
}

/// The bytes of a `bytes` object (anything else is an InputError naming `argument`).
fn bytes_of(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<Vec<u8>> {
    match value.cast::<PyBytes>() {
        Ok(b) => Ok(b.as_bytes().to_vec()),
        Err(_) => Err(input_error(py, format!("argument `{argument}` must be bytes, got {}", crate::convert::type_name(value)))),
    }
}

/// A byte count: an int in [0, MAX_OUTPUT_BYTES] (not a bool, not a float).
fn size_of(py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<usize> {
    let bad = || input_error(py, format!("argument `expected_size` must be an integer in [0, {MAX_OUTPUT_BYTES}], got {}", crate::convert::type_name(value)));
    if value.is_instance_of::<pyo3::types::PyBool>() || !value.is_instance_of::<pyo3::types::PyInt>() {
        return Err(bad());
    }
    let n: i128 = value.extract().map_err(|_| bad())?;
    usize::try_from(n).ok().filter(|&n| n <= MAX_OUTPUT_BYTES).ok_or_else(bad)
}

pub fn register(parent: &Bound<'_, PyModule>) -> PyResult<()> {
    parent.add_function(wrap_pyfunction!(lzf_decompress, parent)?)?;
    parent.add_function(wrap_pyfunction!(lzf_compress, parent)?)?;
    Ok(())
}
