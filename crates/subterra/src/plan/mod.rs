//! Planning and control for the ground robot (STEP, Fan et al. 2021): a risk map in, a command out.
//!
//! - [`grid`]: the one [`RiskGrid`] every planner reads (risks in [0, 1], NaN unknown,
//!   validated once) and the one definition of a lethal cell.
//! - [`astar`]: the risk-aware A* ([`RiskAStar`]). In: a risk grid (the terrain
//!   [`RiskMap`](crate::terrain::RiskMap)'s `risk` layer, or any row-major `(ny, nx)` array
//!   of per-metre risks), a start and a goal. Out: the least-cost path with its accumulated
//!   risk, length and carrot point, or the reason there is none.
//! - [`coverage`]: perception-aware planning: which unknown cells a path would enter before
//!   the robot's sensor has seen them ([`SensorCoverage`]).
//! - [`mpc`]: tracks a reference path with a kinodynamic MPC ([`MpcTracker`]): risk-limited
//!   speed, obstacle half-planes from the lethal cells, a backup stop when no safe plan
//!   exists.
//! - [`navigator`]: all of it wired for a robot's control loop ([`Navigator`]): terrain
//!   mapper, planner, tracker and recovery, one step per tick.
//! - [`recovery`]: adaptive thresholds and recovery behaviours, a state machine that
//!   decides what to do when no path exists or the robot stops making progress.

pub mod astar;
pub mod coverage;
pub mod grid;
pub mod mpc;
pub mod navigator;
pub mod recovery;

pub use astar::{CostModel, EntryPrices, PlanOutcome, PlanStatus, PlannedPath, RiskAStar, RiskAStarConfig};
pub use coverage::SensorCoverage;
pub use grid::RiskGrid;
pub use mpc::{ConvexPolygon, MpcCommand, MpcConfig, MpcOutput, MpcStatus, MpcTracker, UnicycleInput, UnicycleState};
pub use navigator::{Navigator, NavigatorConfig, NavigatorInput, NavigatorOutput, NavigatorSettings};
pub use recovery::{Behaviour, Directive, PlanFeedback, RecoveryConfig, RecoveryInput, RecoveryMachine, Target, Transition};
