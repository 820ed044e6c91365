//! Every configuration's Python class, and the one way a binding takes a config argument.
//!
//! Each core [`Config`] has a class of the same name (`TerrainConfig`, `MpcConfig`, ...)
//! with the same methods, and every constructor that takes a config accepts the same four
//! forms through [`resolve`]:
//!
//! - `None`: the defaults (for some stages, defaults that depend on another argument: the
//!   navigator's follow the robot, the perception's the preset);
//! - a dict: a partial, nested dict laid over those defaults (`{"coarse": {"resolution_m": 0.2}}`);
//! - a config object of the class;
//! - a `str` or `os.PathLike`: a TOML file laid out like `configs/<name>.toml`, read whole.
//!
//! Every failure is a `subterra.errors.ConfigError` naming the dotted field.

use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use pyo3::PyClass;
use serde_json::Value;
use subterra::apf::QmdpConfig;
use subterra::config::{PerceptionConfig, PRESET_NAMES};
use subterra::hero::HeroConfig;
use subterra::plan::{MpcConfig, NavigatorConfig, RiskAStarConfig};
use subterra::{Config, RobotConfig, TerrainConfig};

use crate::convert::{arg, type_name};
use crate::errors::{config_error, input_error, IntoPyResult};

/// Deepest nesting of a config dict accepted (the deepest config has 3 levels).
const MAX_CONFIG_DEPTH: usize = 16;

// ---------------------------------------------------------------- the four forms

/// A Python class wrapping one core config.
pub(crate) trait ConfigClass: PyClass<Frozen = pyo3::pyclass::boolean_struct::True> + Sync {
    /// The core config.
    type Core: Config;
    /// The wrapped config.
    fn core(&self) -> &Self::Core;
}

/// The config given as argument `argument`: `None` gives `base()`; a dict is laid over
/// `base()`; an object of class `P` is taken as it is; a path is read as TOML.
pub(crate) fn resolve<P: ConfigClass>(
    py: Python<'_>,
    argument: &str,
    value: Option<&Bound<'_, PyAny>>,
    base: impl FnOnce() -> PyResult<P::Core>,
) -> PyResult<P::Core> {
    let Some(value) = value.filter(|v| !v.is_none()) else { return base() };
    if let Ok(object) = value.cast::<P>() {
        return Ok(object.get().core().clone());
    }
    if value.cast::<PyDict>().is_ok() {
        return overlay(py, argument, &base()?, value);
    }
    if let Some(path) = as_path(py, value)? {
        return load(py, &path);
    }
    let name = <P::Core as Config>::NAME;
    Err(config_error(py, format!("argument `{argument}` must be None, a dict, a {name} or a TOML path, got {}", type_name(value))))
}

/// `base` with the (partial, nested) dict `d` laid over it, checked; unknown keys are
/// errors naming them.
pub(crate) fn overlay<C: Config>(py: Python<'_>, argument: &str, base: &C, d: &Bound<'_, PyAny>) -> PyResult<C> {
    let value = merged(py, argument, C::FIELD_PREFIX, serde_json::to_value(base), d)?;
    let config: C = from_json_value(py, argument, value)?;
    config.validate().py_err(py)?;
    Ok(config)
}

/// A TOML config file, read like every other file (regular files only, bounded, UTF-8) and
/// checked; errors end with the path.
pub(crate) fn load<C: Config>(py: Python<'_>, path: &str) -> PyResult<C> {
    let text = read_config_text(py, path)?;
    C::from_toml_str(&text).map_err(|e| config_error(py, format!("{e}: {path}")))
}

/// The path of a `str` or `os.PathLike`, else `None`.
pub(crate) fn as_path(py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<Option<String>> {
    if value.is_instance_of::<PyString>() || value.hasattr("__fspath__")? {
        let p = py.import("os")?.call_method1("fspath", (value,))?;
        return Ok(Some(p.extract()?));
    }
    Ok(None)
}

/// The text of a config file, read by `subterra._files` like every other file: regular files
/// only (a FIFO or a device is a FileFormatError, never a hang), bounded, UTF-8.
pub(crate) fn read_config_text(py: Python<'_>, path: &str) -> PyResult<String> {
    py.import("subterra._files")?.call_method1("read_regular_text", (path, "config file"))?.extract()
}

// ---------------------------------------------------------------- dict <-> JSON

/// A config value (dict, list, tuple, str, bool, int, float, None, or a NumPy bool, integer
/// or real scalar, taken as its Python equivalent) as JSON: every float finite (JSON has no
/// NaN), dicts and lists nested at most [`MAX_CONFIG_DEPTH`] deep, and anything else (complex,
/// bytes, arrays) an error naming the field.
pub(crate) fn config_json(py: Python<'_>, argument: &str, field: &str, value: &Bound<'_, PyAny>, depth: usize) -> PyResult<Value> {
    let name = |f: &str| if f.is_empty() { format!("argument `{argument}`") } else { format!("config field `{f}`") };
    if depth > MAX_CONFIG_DEPTH {
        return Err(config_error(py, format!("{} is nested deeper than {MAX_CONFIG_DEPTH} levels", name(field))));
    }
    let finite = |x: f64| -> PyResult<Value> {
        match serde_json::Number::from_f64(x) {
            Some(n) => Ok(Value::Number(n)),
            None => Err(config_error(py, format!("{} is invalid: must be finite (got {x})", name(field)))),
        }
    };
    let integer = |v: &Bound<'_, PyAny>| -> PyResult<Value> {
        if let Ok(i) = v.extract::<i64>() {
            return Ok(Value::from(i));
        }
        if let Ok(u) = v.extract::<u64>() {
            return Ok(Value::from(u));
        }
        // Beyond 64 bits: a float, as JSON would read it; the field's type then refuses it.
        finite(v.call_method0("__float__")?.extract::<f64>()?)
    };
    if let Ok(dict) = value.cast::<PyDict>() {
        let mut object = serde_json::Map::new();
        for (key, v) in dict.iter() {
            let key = key.str()?.to_string();
            let sub = if field.is_empty() { key.clone() } else { format!("{field}.{key}") };
            object.insert(key, config_json(py, argument, &sub, &v, depth + 1)?);
        }
        return Ok(Value::Object(object));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let mut array = Vec::new();
        for (i, v) in value.try_iter()?.enumerate() {
            array.push(config_json(py, argument, &format!("{field}[{i}]"), &v?, depth + 1)?);
        }
        return Ok(Value::Array(array));
    }
    if value.is_none() {
        return Ok(Value::Null);
    }
    if value.is_instance_of::<PyString>() {
        return Ok(Value::String(value.extract()?));
    }
    if value.is_instance_of::<PyBool>() {
        return Ok(Value::Bool(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        return integer(value);
    }
    if value.is_instance_of::<PyFloat>() {
        return finite(value.extract()?);
    }
    // NumPy scalars, as their Python equivalents (np.float32(2.0) is 2.0).
    let np = py.import("numpy")?;
    if value.is_instance(&np.getattr("bool_")?)? {
        return Ok(Value::Bool(value.is_truthy()?));
    }
    if value.is_instance(&np.getattr("integer")?)? {
        return integer(&value.call_method0("__int__")?);
    }
    if value.is_instance(&np.getattr("floating")?)? {
        return finite(value.call_method0("__float__")?.extract()?);
    }
    Err(config_error(py, format!("{} must be a number, a bool, a string, a list or a dict, got {}", name(field), type_name(value))))
}

/// Deserialises a config from JSON, naming the field of an error (`planner.lam`).
pub(crate) fn from_json_value<T: serde::de::DeserializeOwned>(py: Python<'_>, argument: &str, value: Value) -> PyResult<T> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        let at = if path.is_empty() || path == "." { String::new() } else { format!(" field `{path}`") };
        config_error(py, format!("argument `{argument}`{at}: config could not be parsed: {}", e.inner()))
    })
}

/// A Python value as JSON ([`config_json`]); `section` prefixes the fields an error names
/// (`robot` for `robot.length_m`), as the core's validation names them.
fn to_json_value(py: Python<'_>, argument: &str, section: &str, value: &Bound<'_, PyAny>) -> PyResult<Value> {
    config_json(py, argument, section, value, 0)
}

/// Overlays `patch` on `base`: objects merge key by key (recursively), anything else replaces.
/// A section (an object in `base`) given as a list is an error naming it: serde would fill
/// the section's fields by position. `field` is the dotted name of `base` in errors.
fn merge(py: Python<'_>, field: &str, base: &mut Value, patch: Value) -> PyResult<()> {
    match (base, patch) {
        (Value::Object(b), Value::Object(p)) => {
            for (k, v) in p {
                match b.get_mut(&k) {
                    Some(slot) => {
                        let sub = if field.is_empty() { k } else { format!("{field}.{k}") };
                        merge(py, &sub, slot, v)?;
                    }
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (Value::Object(_), Value::Array(_)) => {
            return Err(config_error(py, format!("config section `{field}` must be a dict (a table), got a list")));
        }
        (slot, v) => *slot = v,
    }
    Ok(())
}

/// `base` (a config as JSON) with the (partial, nested) dict `d` laid over it; the caller
/// deserialises the result, so unknown keys are a `ConfigError` naming them. `prefix` starts
/// the field names of errors, as the core's checks name them (`robot` for `robot.length_m`).
fn merged(py: Python<'_>, argument: &str, prefix: &str, base: serde_json::Result<Value>, d: &Bound<'_, PyAny>) -> PyResult<Value> {
    let mut base = base.map_err(|e| config_error(py, e.to_string()))?;
    let patch = to_json_value(py, argument, prefix, d)?;
    if !patch.is_object() {
        return Err(config_error(py, format!("argument `{argument}` must be a dict, got {}", type_name(d))));
    }
    merge(py, prefix, &mut base, patch)?;
    Ok(base)
}

/// A serialisable value as Python objects (through JSON).
pub(crate) fn to_py_dict<'py>(py: Python<'py>, json: serde_json::Result<String>) -> PyResult<Bound<'py, PyAny>> {
    let text = json.map_err(|e| config_error(py, e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

// ---------------------------------------------------------------- the classes

/// Defines the Python class `$name` around the core config `$core`, with the methods every
/// config class has and the class's own (`$extra`).
macro_rules! config_class {
    ($py_ty:ident, $name:literal, $core:ty, $doc:literal, { $($extra:tt)* }) => {
        #[doc = $doc]
        #[pyclass(name = $name, module = "subterra._core", frozen, eq)]
        #[derive(Clone, PartialEq)]
        pub(crate) struct $py_ty {
            pub(crate) inner: $core,
        }

        impl ConfigClass for $py_ty {
            type Core = $core;
            fn core(&self) -> &$core {
                &self.inner
            }
        }

        impl $py_ty {
            /// A Python config around a core one.
            pub(crate) fn from_core(inner: $core) -> Self {
                Self { inner }
            }
        }

        #[pymethods]
        impl $py_ty {
            /// The defaults, or `config`: a (partial, nested) dict laid over the defaults, a
            /// config of this class, or the path of a TOML file.
            #[new]
            #[pyo3(signature = (config = None))]
            fn new(py: Python<'_>, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
                Ok(Self { inner: resolve::<Self>(py, "config", config, || Ok(<$core>::default()))? })
            }

            /// A (partial, nested) dict laid over the defaults, checked.
            #[staticmethod]
            fn from_dict(py: Python<'_>, d: &Bound<'_, PyAny>) -> PyResult<Self> {
                if d.cast::<PyDict>().is_err() {
                    return Err(config_error(py, format!("argument `d` must be a dict, got {}", type_name(d))));
                }
                Ok(Self { inner: overlay(py, "d", &<$core>::default(), d)? })
            }

            /// Parses and checks a TOML document laid out like the committed defaults.
            #[staticmethod]
            fn from_toml(py: Python<'_>, #[pyo3(from_py_with = arg::s_text)] text: String) -> PyResult<Self> {
                Ok(Self { inner: <$core as Config>::from_toml_str(&text).py_err(py)? })
            }

            /// Reads and checks a TOML file; errors end with the path.
            #[staticmethod]
            fn load(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<Self> {
                let path = as_path(py, path)?
                    .ok_or_else(|| input_error(py, format!("argument `path` must be a str or os.PathLike, got {}", type_name(path))))?;
                Ok(Self { inner: load(py, &path)? })
            }

            /// The config as a nested dict laid out like the TOML file.
            fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
                to_py_dict(py, serde_json::to_string(&self.inner))
            }

            /// The config as TOML text (every field).
            fn to_toml(&self) -> String {
                self.inner.to_toml_string()
            }

            fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
                Ok(format!("{}({})", $name, self.to_dict(py)?.repr()?))
            }

            /// Pickles as its TOML text (for worker processes and Ray).
            fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (String,))> {
                Ok((slf.get_type().getattr("from_toml")?, (slf.get().inner.to_toml_string(),)))
            }

            $($extra)*
        }
    };
}

config_class!(PyPerceptionConfig, "PerceptionConfig", PerceptionConfig,
    "The APF-PF configuration: grid, transition, observation, filter and APF settings (defaults: the `flight` preset).", {
    /// A named preset (`flight`, `cable`, `flight-memory`, `acc2021`, `flight-escape`).
    #[staticmethod]
    fn preset(py: Python<'_>, #[pyo3(from_py_with = arg::s_name)] name: String) -> PyResult<Self> {
        Ok(Self { inner: PerceptionConfig::preset(&name).py_err(py)? })
    }

    /// Parses and checks a JSON document with the TOML file's layout.
    #[staticmethod]
    fn from_json(py: Python<'_>, #[pyo3(from_py_with = arg::s_text)] text: String) -> PyResult<Self> {
        let mut de = serde_json::Deserializer::from_str(&text);
        let inner: PerceptionConfig = serde_path_to_error::deserialize(&mut de).map_err(|e| {
            let path = e.path().to_string();
            let at = if path.is_empty() || path == "." { String::new() } else { format!("field `{path}`: ") };
            let hint = if e.inner().is_syntax() && (text.contains("NaN") || text.contains("Infinity")) { " (JSON has no NaN or Infinity: a value must be a finite number)" } else { "" };
            config_error(py, format!("config could not be parsed: {at}{}{hint}", e.inner()))
        })?;
        inner.validate().py_err(py)?;
        Ok(Self { inner })
    }

    /// The config as JSON text.
    fn to_json(&self) -> String {
        serde_json::to_string(&self.inner).unwrap_or_default()
    }

    /// Number of depth bins N_d.
    #[getter]
    fn depth_bins(&self) -> usize {
        self.inner.depth_bins()
    }
});

config_class!(PyRobotConfig, "RobotConfig", RobotConfig,
    "The ground robot: footprint, height, clearance, speed, tilt limits (Husky-like by default).", {
    /// The Clearpath Husky A200-like robot (0.99 x 0.67 x 0.4 m, clearance 0.13 m): the default.
    #[staticmethod]
    fn husky() -> Self {
        Self { inner: RobotConfig::husky() }
    }
});

config_class!(PyTerrainConfig, "TerrainConfig", TerrainConfig,
    "Settings of the terrain pipeline (layout of `configs/terrain.toml`).", {});

config_class!(PyRiskAStarConfig, "RiskAStarConfig", RiskAStarConfig,
    "Settings of the risk-aware A* (layout of `configs/astar.toml`).", {});

config_class!(PyMpcConfig, "MpcConfig", MpcConfig,
    "Settings of the MPC tracker (layout of `configs/mpc.toml`).", {});

config_class!(PyNavigatorConfig, "NavigatorConfig", NavigatorConfig,
    "Settings of the ground navigation stack: sections `planner`, `tracker`, `recovery`, `navigator` (layout of `configs/navigator.toml`; defaults for the Husky-like robot).", {});

config_class!(PyHeroConfig, "HeroConfig", HeroConfig,
    "Health checks of the HeRO odometry multiplexer (layout of `configs/hero.toml`).", {});

config_class!(PyQmdpConfig, "QmdpConfig", QmdpConfig,
    "Settings of the QMDP controller (defaults: the authors').", {});

/// Names of the built-in perception presets, the default first.
#[pyfunction]
fn preset_names() -> Vec<&'static str> {
    PRESET_NAMES.to_vec()
}

/// Adds every config class to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyPerceptionConfig>()?;
    m.add_class::<PyRobotConfig>()?;
    m.add_class::<PyTerrainConfig>()?;
    m.add_class::<PyRiskAStarConfig>()?;
    m.add_class::<PyMpcConfig>()?;
    m.add_class::<PyNavigatorConfig>()?;
    m.add_class::<PyHeroConfig>()?;
    m.add_class::<PyQmdpConfig>()?;
    m.add_function(wrap_pyfunction!(preset_names, m)?)?;
    Ok(())
}
