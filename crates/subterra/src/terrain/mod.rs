//! Terrain risk for a ground robot (STEP, Fan et al. 2021).
//!
//! In: a point cloud in the sensor frame, `body_from_sensor`, the odometry pose
//! `world_from_body` and its confidence. Out: robot-centred, world-axis-aligned grid maps
//! with named layers — geometry (counts, heights, slope, roughness), risk layers in [0, 1]
//! and the combined risk with its uncertainty — a fine one from the newest scan and a
//! coarse one from the fused window.
//!
//! [`cloud`] prefilters, [`ground`] labels ground by line fits, [`fusion`] keeps the window
//! of scans, [`grid`] is the map geometry and its layers, [`risk`] computes the layers, and
//! [`mapper`] wires them into [`TerrainMapper`].

pub mod cloud;
pub mod config;
pub mod fusion;
pub mod grid;
pub mod ground;
pub mod mapper;
pub mod risk;

pub use cloud::{Prefilter, PrefilterStats};
pub use config::{FusionConfig, GroundConfig, LayerConfig, MapConfig, PrefilterConfig, Ramp, RiskConfig, RobotConfig, TerrainConfig, UncertaintyConfig};
pub use fusion::{check_rigid, ScanWindow, StoredScan};
pub use grid::{cvar_factor, CellIndex, GridGeometry, Layer, RiskMap, DEFAULT_LETHAL_RISK};
pub use ground::{segment_ground, GroundLine, GroundSegmenter, PolarBin};
pub use mapper::{TerrainMapper, TerrainOutput, TerrainStats, TerrainTimings};
pub use risk::MissionItem;
