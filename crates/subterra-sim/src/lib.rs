//! # subterra-sim
//!
//! The closed-loop test harness of subterra (never a dependency of the onboard stack):
//! worlds written by hand or generated, ray-cast depth cameras and spinning lidars with
//! realistic noise, a quadrotor and a ground robot, and per-run metrics.
//!
//! [`spec`] is the world description (TOML), [`world`] its geometry and queries (ray
//! casts through a bounding-volume hierarchy, clearance, ground height), [`scenarios`]
//! the seeded generators of the built-in worlds, [`sensors`] and [`noise`] what the robot
//! sees, [`vehicles`] how it moves, [`metrics`] how a run went, [`simulation`] the step loop.

#![warn(missing_docs)]
// Units are written in brackets (`[m]`, `[rad]`) as in the core crate, not as doc links.
#![allow(rustdoc::broken_intra_doc_links)]

pub mod error;
pub mod metrics;
pub mod noise;
pub mod scenarios;
pub mod sensors;
pub mod simulation;
pub mod spec;
pub mod vehicles;
pub mod world;

pub use error::{SimError, SimResult};
