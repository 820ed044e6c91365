//! Planning and control for the ground robot (DESIGN §3): a risk map in, a command out.
//!
//! - [`recovery`]: adaptive thresholds and recovery behaviours, a state machine that
//!   decides what to do when no path exists or the robot stops making progress.

pub mod recovery;

pub use recovery::{Behaviour, Directive, PlanFeedback, RecoveryConfig, RecoveryInput, RecoveryMachine, Target, Transition};
