//! Planning for a ground robot (DESIGN §3).
//!
//! In: a risk grid (the terrain [`RiskMap`](crate::terrain::RiskMap)'s `risk` layer, or any
//! row-major `(ny, nx)` array of per-metre risks), a start and a goal. Out: a plan outcome —
//! the least-cost path with its accumulated risk, length and carrot point, or the reason there
//! is none.
//!
//! [`astar`] is the risk-aware A* ([`RiskAStar`]).

pub mod astar;

pub use astar::{PlanOutcome, PlanStatus, PlannedPath, RiskAStar, RiskAStarConfig, RiskGrid};
