//! Maps every core and simulator error to a class of `subterra.errors`: the one place
//! where a Rust error becomes a Python exception.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyType;
use subterra::Error;
use subterra_sim::SimError;

/// The `subterra.errors` class for a core error.
fn class_name(err: &Error) -> &'static str {
    match err {
        Error::InvalidConfig { .. } | Error::ConfigParse { .. } | Error::UnknownPreset { .. } => "ConfigError",
        Error::ImageShapeMismatch { .. } | Error::InvalidInput { .. } => "InputError",
        _ => "SubterraError",
    }
}

/// Raises `subterra.errors.<name>(message)`; falls back to `ValueError` if the Python
/// package cannot be imported (it always can when the extension is loaded through it).
pub fn raise(py: Python<'_>, name: &str, message: String) -> PyErr {
    let class = py
        .import("subterra.errors")
        .and_then(|m| m.getattr(name))
        .and_then(|c| c.cast_into::<PyType>().map_err(PyErr::from));
    match class {
        Ok(class) => PyErr::from_type(class, message),
        Err(_) => PyValueError::new_err(message),
    }
}

/// `subterra.errors.InputError(message)`.
pub fn input_error(py: Python<'_>, message: impl Into<String>) -> PyErr {
    raise(py, "InputError", message.into())
}

/// `subterra.errors.ConfigError(message)`.
pub fn config_error(py: Python<'_>, message: impl Into<String>) -> PyErr {
    raise(py, "ConfigError", message.into())
}

/// Converts a core error.
pub fn to_py(py: Python<'_>, err: Error) -> PyErr {
    raise(py, class_name(&err), err.to_string())
}

/// `result.map_err(to_py)` with the GIL token.
pub trait IntoPyResult<T> {
    /// Converts the error, if any.
    fn py_err(self, py: Python<'_>) -> PyResult<T>;
}

impl<T> IntoPyResult<T> for subterra::Result<T> {
    fn py_err(self, py: Python<'_>) -> PyResult<T> {
        self.map_err(|e| to_py(py, e))
    }
}

/// Maps a simulator error to `subterra.errors`.
pub fn sim_err(py: Python<'_>, err: SimError) -> PyErr {
    match err {
        SimError::Core(e) => to_py(py, e),
        SimError::InvalidConfig { .. } | SimError::Unknown { .. } => raise(py, "ConfigError", err.to_string()),
        SimError::InvalidWorld { .. } => raise(py, "FileFormatError", err.to_string()),
        _ => raise(py, "InputError", err.to_string()),
    }
}

/// `result.map_err(sim_err)` with the GIL token.
pub trait SimPyResult<T> {
    /// Converts the error, if any.
    fn sim_err(self, py: Python<'_>) -> PyResult<T>;
}

impl<T> SimPyResult<T> for Result<T, SimError> {
    fn sim_err(self, py: Python<'_>) -> PyResult<T> {
        self.map_err(|e| sim_err(py, e))
    }
}
