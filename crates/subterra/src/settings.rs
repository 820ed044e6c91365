//! The one configuration path: every configurable stage has a [`Config`] type that reads
//! TOML, checks every field naming it on error, and writes itself back as TOML.
//!
//! Each type's defaults are committed as text under `configs/` ([`Config::FILE`]); a test
//! in this module parses every committed file and requires it to equal the defaults in the
//! code, so a default never changes silently. The Python bindings build the same types from
//! `None`, a dict laid over the defaults, a config object or a TOML path, with one error
//! format (`ConfigError` naming the dotted field).

use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::apf::QmdpConfig;
use crate::error::Result;
use crate::hero::HeroConfig;
use crate::plan::RiskAStarConfig;
use crate::plan::MpcConfig;
use crate::plan::NavigatorConfig;
use crate::{PerceptionConfig, RobotConfig, TerrainConfig};

/// A validated configuration with TOML in and out.
///
/// Unknown fields are errors; which missing fields keep their defaults is the type's
/// `#[serde(default)]` (documented on each).
pub trait Config: Sized + Clone + PartialEq + std::fmt::Debug + Default + Serialize + DeserializeOwned {
    /// The type's name, the same in Rust and Python (`"TerrainConfig"`).
    const NAME: &'static str;
    /// The committed file of the defaults under `configs/` (`"terrain.toml"`), if there is one.
    const FILE: Option<&'static str>;
    /// The prefix of the field names in this type's errors (`"robot"` for `robot.length_m`),
    /// or `""` when they are named from the top of the document (`coarse.resolution_m`).
    const FIELD_PREFIX: &'static str = "";

    /// Checks every field; an error names the field (`coarse.resolution_m`).
    fn validate(&self) -> Result<()>;

    /// Parses and checks a TOML document of this type's layout.
    fn from_toml_str(text: &str) -> Result<Self> {
        let config: Self = crate::error::parse_toml(text)?;
        config.validate()?;
        Ok(config)
    }

    /// The configuration as a TOML document (every field).
    fn to_toml_string(&self) -> String {
        // The configs are plain structs of numbers, strings, enums and arrays: serialising
        // them cannot fail.
        toml::to_string(self).unwrap_or_default()
    }
}

/// Implements [`Config`] for a type whose inherent `validate` checks it.
macro_rules! config {
    ($ty:ty, $name:literal, $file:expr) => {
        config!($ty, $name, $file, "");
    };
    ($ty:ty, $name:literal, $file:expr, $prefix:literal) => {
        impl Config for $ty {
            const NAME: &'static str = $name;
            const FILE: Option<&'static str> = $file;
            const FIELD_PREFIX: &'static str = $prefix;
            fn validate(&self) -> Result<()> {
                <$ty>::validate(self)
            }
        }
    };
}

config!(PerceptionConfig, "PerceptionConfig", Some("flight.toml"));
config!(TerrainConfig, "TerrainConfig", Some("terrain.toml"));
config!(RobotConfig, "RobotConfig", None, "robot");
config!(RiskAStarConfig, "RiskAStarConfig", Some("astar.toml"), "astar");
config!(MpcConfig, "MpcConfig", Some("mpc.toml"));
config!(NavigatorConfig, "NavigatorConfig", Some("navigator.toml"));
config!(HeroConfig, "HeroConfig", Some("hero.toml"), "hero");
config!(QmdpConfig, "QmdpConfig", None);

#[cfg(test)]
mod tests {
    use super::*;

    fn committed(file: &str) -> String {
        let path = format!("{}/../../configs/{file}", env!("CARGO_MANIFEST_DIR"));
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
    }

    /// The committed file equals the defaults, the defaults pass their checks, and TOML
    /// round-trips; a misspelt field is an error naming it.
    fn holds<C: Config>() {
        let defaults = C::default();
        Config::validate(&defaults).unwrap_or_else(|e| panic!("{}: defaults fail their checks: {e}", C::NAME));
        if let Some(file) = C::FILE {
            assert_eq!(C::from_toml_str(&committed(file)).unwrap(), defaults, "configs/{file} drifted from {}::default()", C::NAME);
        }
        assert_eq!(C::from_toml_str(&defaults.to_toml_string()).unwrap(), defaults, "{} does not round-trip", C::NAME);
        let err = C::from_toml_str("no_such_field_xyz = 1\n").unwrap_err().to_string();
        assert!(err.contains("no_such_field_xyz"), "{}: {err}", C::NAME);
    }

    #[test]
    fn every_config_reads_its_committed_defaults_and_round_trips() {
        holds::<PerceptionConfig>();
        holds::<TerrainConfig>();
        holds::<RobotConfig>();
        holds::<RiskAStarConfig>();
        holds::<MpcConfig>();
        holds::<NavigatorConfig>();
        holds::<HeroConfig>();
        holds::<QmdpConfig>();
    }
}
