//! `subterra.Qmdp`: QMDP action selection over a perception's belief (`subterra::apf::Qmdp`).

use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use subterra::apf::{Qmdp, QmdpAction, QmdpConfig};

use crate::convert::arg;
use crate::errors::IntoPyResult;
use crate::shared::Shared;
use crate::config::{resolve, PyQmdpConfig};
use crate::{array3, PyDepthPerception, PyPerceptionOutput};

/// The QMDP config of argument `config` (any of the four forms).
pub(crate) fn resolve_config(py: Python<'_>, config: Option<&Bound<'_, PyAny>>) -> PyResult<QmdpConfig> {
    resolve::<PyQmdpConfig>(py, "config", config, || Ok(QmdpConfig::default()))
}

/// What one `Qmdp.act` gives.
#[pyclass(name = "QmdpAction", module = "subterra._core", frozen)]
struct PyQmdpAction {
    inner: QmdpAction,
}

#[pymethods]
impl PyQmdpAction {
    /// The chosen evasive velocity in the body frame [m/s]: it takes the repulsive
    /// force's place in `ApfController.command`.
    #[getter]
    fn velocity_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.velocity_body)
    }
    /// Its index in `Qmdp.actions()`.
    #[getter]
    fn index(&self) -> usize {
        self.inner.index
    }
    /// Its expected reward under the belief.
    #[getter]
    fn value(&self) -> f64 {
        self.inner.value
    }
    fn __repr__(&self) -> String {
        let v = self.inner.velocity_body;
        format!("QmdpAction(velocity_body=[{:.2}, {:.2}, {:.2}], index={}, value={:.4})", v.x, v.y, v.z, self.inner.index, self.inner.value)
    }
}

/// QMDP action selection (the APF-PF authors' follow-up): a discrete set of evasive
/// velocities scored by their expected reward over `perception`'s belief, built once from
/// its states; `act(output)` per frame. `config`: a dict over `Qmdp.default_config()`.
#[pyclass(name = "Qmdp", module = "subterra._core", frozen)]
struct PyQmdp {
    inner: Shared<Qmdp>,
}

#[pymethods]
impl PyQmdp {
    #[new]
    #[pyo3(signature = (perception, config = None))]
    fn new(py: Python<'_>, #[pyo3(from_py_with = arg::perception)] perception: Bound<'_, PyDepthPerception>, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let config = resolve_config(py, config)?;
        let p = perception.get().inner.lock();
        Ok(Self { inner: Shared::new(py.detach(|| Qmdp::new(&p, config)).py_err(py)?) })
    }

    /// The settings in use.
    #[getter]
    fn config(&self) -> PyQmdpConfig {
        PyQmdpConfig::from_core(*self.inner.lock().config())
    }

    /// The best action under `output`'s belief (a `PerceptionOutput` of the perception
    /// this controller was made for).
    fn act(&self, py: Python<'_>, #[pyo3(from_py_with = arg::output)] output: Bound<'_, PyPerceptionOutput>) -> PyResult<PyQmdpAction> {
        let mut this = self.inner.lock();
        let (inner, out) = (&mut *this, &output.get().inner);
        Ok(PyQmdpAction { inner: py.detach(|| inner.act(out)).py_err(py)? })
    }

    /// The action set, shape `(A, 3)` [m/s, body frame], in the order of `QmdpAction.index`.
    fn actions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let this = self.inner.lock();
        let flat: Vec<f64> = this.actions().iter().flat_map(|a| [a.x, a.y, a.z]).collect();
        flat.into_pyarray(py).reshape([this.actions().len(), 3])
    }

    /// The reward table `R(s, a)`, shape `(S, A)` (states as the perception numbers them,
    /// the free state last).
    fn rewards<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let this = self.inner.lock();
        let (s, a) = (this.state_count(), this.actions().len());
        let flat: Vec<f64> = (0..s).flat_map(|i| this.rewards(i).unwrap_or(&[]).to_vec()).collect();
        flat.into_pyarray(py).reshape([s, a])
    }

    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        format!("Qmdp(states={}, actions={}, lookahead_s={})", this.state_count(), this.actions().len(), this.config().lookahead_s)
    }
}

/// Adds the QMDP classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyQmdp>()?;
    m.add_class::<PyQmdpAction>()?;
    Ok(())
}
