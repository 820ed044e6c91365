//! Planning and control for a ground robot (DESIGN §3).
//!
//! In: a risk grid (a [`RiskMap`](crate::terrain::RiskMap) layer or any row-major `(ny, nx)`
//! risk array), the robot's state and a reference path. Out: commands.
//!
//! [`mpc`] tracks a reference path with a kinodynamic MPC: risk-limited speed, obstacle
//! half-planes from the lethal cells, a backup stop when no safe plan exists.

pub mod mpc;

pub use mpc::{ConvexPolygon, MpcCommand, MpcConfig, MpcOutput, MpcStatus, MpcTracker, RiskGrid, UnicycleInput, UnicycleState};
