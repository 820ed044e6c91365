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
fn lzf_decompress<'py>(py: Python<'py>, data: &[u8], expected_size: usize) -> PyResult<Option<Bound<'py, PyBytes>>> {
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
fn lzf_compress<'py>(py: Python<'py>, data: &[u8]) -> PyResult<Option<Bound<'py, PyBytes>>> {
    if data.len() > MAX_OUTPUT_BYTES {
        return Err(input_error(py, format!("argument `data` must be at most {MAX_OUTPUT_BYTES} bytes, got {}", data.len())));
    }
    if data.is_empty() {
        return Ok(None);
    }
    let out = py.detach(|| lzf::compress(data));
    Ok(out.ok().map(|bytes| PyBytes::new(py, &bytes)))
}

pub fn register(parent: &Bound<'_, PyModule>) -> PyResult<()> {
    parent.add_function(wrap_pyfunction!(lzf_decompress, parent)?)?;
    parent.add_function(wrap_pyfunction!(lzf_compress, parent)?)?;
    Ok(())
}
