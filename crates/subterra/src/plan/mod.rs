//! Planning and control for the ground robot (STEP, Fan et al. 2021): a risk map in, a command out.
//!
//! - [`RiskGrid`]: the one grid every planner reads (risks in [0, 1], NaN unknown,
//!   validated once) and the one definition of a lethal cell.
//! - [`RiskAStar`]: the risk-aware A*. In: a risk grid (the terrain
//!   [`RiskMap`](crate::terrain::RiskMap)'s `risk` layer, or any row-major `(ny, nx)` array
//!   of per-metre risks), a start and a goal. Out: the least-cost path with its accumulated
//!   risk, length and carrot point, or the reason there is none.
//! - [`SensorCoverage`]: perception-aware planning: which unknown cells a path would enter
//!   before the robot's sensor has seen them ([`EntryPrices`]).
//! - [`MpcTracker`]: tracks a reference path with a kinodynamic MPC: risk-limited speed,
//!   obstacle half-planes from the lethal cells, a backup stop when no safe plan exists.
//! - [`Navigator`]: all of it wired for a robot's control loop: terrain mapper, planner,
//!   tracker and recovery, one step per tick.
//! - [`RecoveryMachine`]: adaptive thresholds and recovery behaviours, a state machine that
//!   decides what to do when no path exists or the robot stops making progress.

mod astar;
mod coverage;
mod grid;
mod mpc;
mod navigator;
mod recovery;

pub use astar::{CostModel, EntryPrices, PlanOutcome, PlanStatus, PlannedPath, RiskAStar, RiskAStarConfig};
pub use coverage::SensorCoverage;
pub use grid::RiskGrid;
pub use mpc::{step as unicycle_step, ConvexPolygon, MpcCommand, MpcConfig, MpcFootprint, MpcLimits, MpcObstacles, MpcOutput, MpcRisk, MpcSolver, MpcStatus, MpcQp, MpcQpSolution, MpcTracker, MpcTracking, MpcWeights, QpSolverKind, QpStatus, UnicycleInput, UnicycleState};
pub use navigator::{Navigator, NavigatorConfig, NavigatorInput, NavigatorOutput, NavigatorSettings, NavigatorTimings, UNSEEN_RISK_PER_M};
pub use recovery::{Behaviour, Directive, PlanFeedback, RecoveryConfig, RecoveryInput, RecoveryMachine, Target, Transition};
