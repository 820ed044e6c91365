//! Terrain risk for a ground robot (STEP, Fan et al. 2021).
//!
//! In: a point cloud in the sensor frame, `body_from_sensor`, the odometry pose
//! `world_from_body` and its confidence. Out: robot-centred, world-axis-aligned grid maps
//! with named layers — geometry (counts, heights, slope, roughness), risk layers in [0, 1]
//! and the combined risk with its uncertainty — a fine one from the newest scan and a
//! coarse one from the fused window.
//!
//! [`TerrainMapper`] prefilters the cloud ([`PrefilterConfig`]), labels ground by line fits
//! ([`GroundConfig`]; alone: [`segment_ground`]), keeps the window of scans
//! ([`FusionConfig`]) and computes the layers ([`RiskConfig`]) of each [`RiskMap`] (its
//! geometry a [`GridGeometry`], its layers named by [`Layer`]).

mod cloud;
mod config;
mod fusion;
mod grid;
mod ground;
mod mapper;
mod risk;

pub use cloud::PrefilterStats;
pub use config::{FusionConfig, GroundConfig, LayerConfig, MapConfig, PrefilterConfig, Ramp, RiskConfig, RobotConfig, TerrainConfig, UncertaintyConfig};
pub use grid::{CellIndex, GridGeometry, Layer, RiskMap, DEFAULT_LETHAL_RISK};
pub use ground::{segment_ground, MAX_SENSOR_HEIGHT_M, MIN_SENSOR_HEIGHT_M};
pub use mapper::{TerrainMapper, MAX_MISSION_ITEMS, TerrainOutput, TerrainStats, TerrainTimings};
pub use risk::MissionItem;
