//! # subterra
//!
//! Onboard perception and planning for robots in cluttered, GPS-denied places.
//!
//! - [`depth`]: APF-PF, a particle filter over a 2.5D voxel grid of a depth image
//!   (Ahmad, Sunberg, Humbert, ACC 2021), and [`apf`], the potential fields it weights.
//! - [`terrain`]: multi-layer terrain risk maps from lidar scans for a ground robot
//!   (STEP, Fan et al. 2021).
//! - [`plan`]: planning and control for the ground robot (STEP, Fan et al. 2021).
//! - [`hero`]: the odometry multiplexer (HeRO): several odometry sources, health checks,
//!   one continuous pose with a confidence.
//! - [`config`]: the APF-PF configuration and its presets; [`settings`]: the [`Config`]
//!   trait every configuration implements (TOML in and out, checks naming the field).
//! - [`camera`], [`frames`]: the shared vocabulary (pinhole intrinsics, rigid transforms).
//!
//! No I/O, no printing, no global state: every stage takes arrays and returns values,
//! and every random stream is seeded by the caller.

#![warn(missing_docs)]
// `pub` is the public API: an item the crate's users cannot reach is `pub(crate)` or narrower,
// and every type reachable through the API can be named (re-exported at its module's root).
#![warn(unreachable_pub, unnameable_types)]

pub mod apf;
pub mod camera;
pub mod config;
pub mod depth;
pub mod error;
pub mod frames;
pub mod hero;
pub mod plan;
pub mod settings;
pub mod terrain;

pub use apf::{ApfController, Command};
pub use camera::PinholeCamera;
pub use config::PerceptionConfig;
pub use depth::{DepthImage, DepthPerception, PerceptionOutput};
pub use error::{Error, Result};
pub use frames::Isometry3;
pub use settings::Config;
pub use terrain::{RobotConfig, TerrainConfig};
