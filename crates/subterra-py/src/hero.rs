//! `subterra.OdometryMux`: the HeRO odometry multiplexer (`subterra::hero`).

use glam::DVec3;
use numpy::{IntoPyArray, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use subterra::hero::{Fault, HeroConfig, MuxEvent, MuxOutput, OdometryMux, OdometrySample, SourceSpec, Twist};
use subterra::Isometry3;

use crate::convert::{isometry, real, real_vector, text, type_name};
use crate::errors::{input_error, IntoPyResult};
use crate::shared::Shared;
use crate::config::{resolve, PyHeroConfig};

fn matrix<'py>(py: Python<'py>, p: &Isometry3) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let r = p.rotation;
    let t = p.translation;
    let rows = vec![
        r.x_axis.x, r.y_axis.x, r.z_axis.x, t.x, //
        r.x_axis.y, r.y_axis.y, r.z_axis.y, t.y, //
        r.x_axis.z, r.y_axis.z, r.z_axis.z, t.z, //
        0.0, 0.0, 0.0, 1.0,
    ];
    rows.into_pyarray(py).reshape([4, 4])
}

/// What one `OdometryMux.update` gives.
#[pyclass(name = "OdometryMuxOutput", module = "subterra._core", frozen)]
struct PyMuxOutput {
    inner: MuxOutput,
    names: Vec<String>,
}

impl PyMuxOutput {
    fn name(&self, k: Option<usize>) -> Option<String> {
        k.map(|k| self.names[k].clone())
    }
}

#[pymethods]
impl PyMuxOutput {
    /// The stamp of the pose [s]: the chosen source's newest sample, or the held pose's.
    #[getter]
    fn stamp(&self) -> f64 {
        self.inner.stamp_s
    }
    /// The body's pose in the mux's world frame, 4x4; None before any source was chosen.
    #[getter]
    fn world_from_body<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
        self.inner.world_from_body.as_ref().map(|p| matrix(py, p)).transpose()
    }
    /// The chosen source's name, None when no source is usable (the pose is held).
    #[getter]
    fn source(&self) -> Option<String> {
        self.name(self.inner.source)
    }
    /// How far the pose can be trusted, in [0, 1].
    #[getter]
    fn confidence(&self) -> f64 {
        self.inner.confidence
    }
    /// Per source name: why it is not used (one line), or None when it is usable.
    #[getter]
    fn faults<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, fault) in self.names.iter().zip(&self.inner.faults) {
            d.set_item(name, fault.as_ref().map(Fault::describe))?;
        }
        Ok(d)
    }
    /// The events since the last update: dicts with `time_s`, `event` (`unhealthy`,
    /// `recovered`, `switch`, `dispute`, `agreement`), `source`, `reason` and
    /// `corrected_m` (how far a switch took the pose back: the drift of a source the vote
    /// found inconsistent; 0 otherwise).
    #[getter]
    fn events<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for e in &self.inner.events {
            let d = PyDict::new(py);
            let corrected = if let MuxEvent::Switch { corrected_m, .. } = e { *corrected_m } else { 0.0 };
            let (t, kind, source, reason) = match e {
                MuxEvent::Unhealthy { stamp_s, source, fault } => (*stamp_s, "unhealthy", self.name(Some(*source)), fault.describe()),
                MuxEvent::Recovered { stamp_s, source } => (*stamp_s, "recovered", self.name(Some(*source)), "passed every check for recover_s".to_string()),
                MuxEvent::Switch { stamp_s, from, to, corrected_m } => {
                    let from_name = self.name(*from).unwrap_or_else(|| "none".into());
                    let reason = match to {
                        Some(_) if *corrected_m > 0.0 => {
                            format!("from {from_name}, the pose taken back {corrected_m:.3} m to the window's start (the drift it had put in)")
                        }
                        Some(_) => format!("from {from_name}"),
                        None => format!("from {from_name}: no usable source, pose held"),
                    };
                    (*stamp_s, "switch", self.name(*to), reason)
                }
                MuxEvent::Dispute { stamp_s, disputed, error_m } => {
                    if *disputed {
                        (*stamp_s, "dispute", None, format!("the two sources disagree by {error_m:.3} m"))
                    } else {
                        (*stamp_s, "agreement", None, "the two sources agree again".to_string())
                    }
                }
            };
            d.set_item("time_s", t)?;
            d.set_item("event", kind)?;
            d.set_item("source", source)?;
            d.set_item("reason", reason)?;
            d.set_item("corrected_m", corrected)?;
            list.append(d)?;
        }
        Ok(list)
    }
    fn __repr__(&self) -> String {
        format!(
            "OdometryMuxOutput(stamp={:.3}, source={:?}, confidence={:.3}, events={})",
            self.inner.stamp_s,
            self.name(self.inner.source),
            self.inner.confidence,
            self.inner.events.len()
        )
    }
}

/// HeRO, the odometry multiplexer: several odometry sources, health checks on each (stale,
/// jump, covariance, consistency), the most trusted usable one passed on as one continuous
/// pose with a confidence (docs/hero.md).
///
/// `sources`: `[(name, rate_hz), ...]` most trusted first (or a dict `{name: rate_hz}` in
/// that order). `config`: a dict over `OdometryMux.default_config()`.
#[pyclass(name = "OdometryMux", module = "subterra._core", frozen)]
struct PyOdometryMux {
    inner: Shared<OdometryMux>,
    names: Vec<String>,
}

fn specs(py: Python<'_>, sources: &Bound<'_, PyAny>) -> PyResult<Vec<SourceSpec>> {
    let pairs: Vec<Bound<'_, PyAny>> = if let Ok(d) = sources.cast::<PyDict>() {
        d.items().iter().collect()
    } else if sources.is_instance_of::<pyo3::types::PyString>() {
        return Err(input_error(py, "argument `sources` must be a list of (name, rate_hz) pairs or a dict, got str"));
    } else {
        let iter = sources
            .try_iter()
            .map_err(|_| input_error(py, format!("argument `sources` must be a list of (name, rate_hz) pairs or a dict, got {}", type_name(sources))))?;
        let mut out = Vec::new();
        for item in iter {
            out.push(item?);
            if out.len() > subterra::hero::MAX_SOURCES {
                return Err(input_error(py, format!("argument `sources` must name at most {} sources", subterra::hero::MAX_SOURCES)));
            }
        }
        out
    };
    let mut specs = Vec::with_capacity(pairs.len());
    for (k, pair) in pairs.iter().enumerate() {
        let len = pair.len().unwrap_or(0);
        if pair.is_instance_of::<pyo3::types::PyString>() || len != 2 {
            return Err(input_error(py, format!("argument `sources`: item {k} must be a (name, rate_hz) pair, got {}", type_name(pair))));
        }
        let name = text(py, "sources", &pair.get_item(0)?)?;
        let rate_hz = real(py, "sources", &pair.get_item(1)?)?;
        specs.push(SourceSpec { name, rate_hz });
    }
    Ok(specs)
}

#[pymethods]
impl PyOdometryMux {
    #[new]
    #[pyo3(signature = (sources, config = None))]
    fn new(py: Python<'_>, sources: &Bound<'_, PyAny>, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let config = resolve::<PyHeroConfig>(py, "config", config, || Ok(HeroConfig::default()))?;
        let specs = specs(py, sources)?;
        let mux = OdometryMux::new(config, &specs).py_err(py)?;
        Ok(Self { inner: Shared::new(mux), names: specs.into_iter().map(|s| s.name).collect() })
    }

    /// The settings in use.
    #[getter]
    fn config(&self) -> PyHeroConfig {
        PyHeroConfig::from_core(*self.inner.lock().config())
    }

    /// The source names, most trusted first.
    #[getter]
    fn sources(&self) -> Vec<String> {
        self.names.clone()
    }

    /// Takes one sample of `source` (its name): `stamp` [s] (increasing per source),
    /// `world_from_body` 4x4 in that source's world frame, `covariance` the 6x6 over
    /// (x, y, z, roll, pitch, yaw) as in `nav_msgs/Odometry` (None: unknown), `twist` the
    /// body-frame `(vx, vy, vz, wx, wy, wz)` (None: not given).
    #[pyo3(signature = (source, stamp, world_from_body, covariance = None, twist = None))]
    fn push(
        &self,
        py: Python<'_>,
        source: &Bound<'_, PyAny>,
        stamp: &Bound<'_, PyAny>,
        world_from_body: &Bound<'_, PyAny>,
        covariance: Option<&Bound<'_, PyAny>>,
        twist: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let name = text(py, "source", source)?;
        let stamp_s = real(py, "stamp", stamp)?;
        let pose = isometry(py, "world_from_body", world_from_body)?;
        let covariance = match covariance {
            None => None,
            Some(c) if c.is_none() => None,
            Some(c) => {
                let v = real_vector(py, "covariance", c, 36, "a 6x6 covariance (36 numbers)")?;
                let mut a = [0.0; 36];
                a.copy_from_slice(&v);
                Some(a)
            }
        };
        let twist = match twist {
            None => None,
            Some(t) if t.is_none() => None,
            Some(t) => {
                let v = real_vector(py, "twist", t, 6, "6 numbers (vx, vy, vz, wx, wy, wz)")?;
                Some(Twist { linear: DVec3::new(v[0], v[1], v[2]), angular: DVec3::new(v[3], v[4], v[5]) })
            }
        };
        let mut mux = self.inner.lock();
        let k = mux.index_of(&name).py_err(py)?;
        mux.push(k, OdometrySample { stamp_s, world_from_body: pose, covariance, twist }).py_err(py)
    }

    /// Runs the checks at time `now` [s] (not going back), chooses, and gives the pose.
    fn update(&self, py: Python<'_>, now: &Bound<'_, PyAny>) -> PyResult<PyMuxOutput> {
        let now_s = real(py, "now", now)?;
        let inner = self.inner.lock().update(now_s).py_err(py)?;
        Ok(PyMuxOutput { inner, names: self.names.clone() })
    }

    fn __repr__(&self) -> String {
        format!("OdometryMux(sources={:?})", self.names)
    }
}

/// Adds the HeRO classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyOdometryMux>()?;
    m.add_class::<PyMuxOutput>()?;
    Ok(())
}
