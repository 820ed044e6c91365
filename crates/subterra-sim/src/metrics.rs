//! Per-run metrics: what a run achieved and what it cost.
//!
//! In: per step, the vehicle's position, its clearance to the nearest obstacle, whether it
//! is in collision, and the compute time of the controller under test (measured by the
//! caller). Out: [`RunMetrics`] — success, failure cause, collisions, minimum clearance,
//! path length, time, compute time median and p99.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Summary of one run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunMetrics {
    /// The goal was reached.
    pub success: bool,
    /// Why the run ended without success: `collision`, `rollover`, `fall`, `out_of_world`,
    /// `timeout`, or a cause given by the caller (`local_minimum`, ...); `None` on success
    /// or while running.
    pub failure: Option<String>,
    /// Number of collisions: steps at which the vehicle went from free to in collision
    /// (a collision that lasts several steps counts once).
    pub collisions: u32,
    /// Smallest clearance recorded, start included [m] (vehicle-specific, see
    /// [`crate::simulation::Simulation::step`]); +∞ when nothing was ever in reach.
    pub min_clearance_m: f64,
    /// Length of the polyline through the recorded positions [m].
    pub path_length_m: f64,
    /// Time of the last record [s].
    pub time_s: f64,
    /// Median compute time per step of the controller under test [ms]; 0 with no step.
    pub compute_ms_median: f64,
    /// 99th percentile of the compute time per step [ms] (linear interpolation between
    /// order statistics, as NumPy's default); 0 with no step.
    pub compute_ms_p99: f64,
    /// Number of steps recorded.
    pub steps: u64,
}

/// Accumulates a run's metrics step by step.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsRecorder {
    last_position: DVec3,
    path_length_m: f64,
    min_clearance_m: f64,
    time_s: f64,
    collisions: u32,
    in_collision: bool,
    compute_s: Vec<f64>,
    steps: u64,
}

impl MetricsRecorder {
    /// Starts a run at `time_s` [s] at `position` [m] with clearance `clearance_m` [m];
    /// `in_collision` says whether the start already touches a solid (counted as a collision).
    pub fn new(time_s: f64, position: DVec3, clearance_m: f64, in_collision: bool) -> Self {
        Self {
            last_position: position,
            path_length_m: 0.0,
            min_clearance_m: if clearance_m.is_nan() { f64::INFINITY } else { clearance_m },
            time_s,
            collisions: u32::from(in_collision),
            in_collision,
            compute_s: Vec::new(),
            steps: 0,
        }
    }

    /// Records one step ending at `time_s` [s] at `position` [m], with clearance
    /// `clearance_m` [m], collision state `collided` and the controller's compute time
    /// for this step `compute_time_s` [s] (`None`: not measured; NaN or negative values
    /// are not recorded).
    pub fn record(&mut self, time_s: f64, position: DVec3, clearance_m: f64, collided: bool, compute_time_s: Option<f64>) {
        self.steps += 1;
        let step = (position - self.last_position).length();
        if step.is_finite() {
            self.path_length_m += step;
        }
        self.last_position = position;
        if clearance_m < self.min_clearance_m {
            self.min_clearance_m = clearance_m;
        }
        self.time_s = time_s;
        if collided && !self.in_collision {
            self.collisions = self.collisions.saturating_add(1);
        }
        self.in_collision = collided;
        if let Some(c) = compute_time_s.filter(|c| c.is_finite() && *c >= 0.0) {
            self.compute_s.push(c);
        }
    }

    /// Path length so far [m].
    pub fn path_length_m(&self) -> f64 {
        self.path_length_m
    }

    /// Collisions so far.
    pub fn collisions(&self) -> u32 {
        self.collisions
    }

    /// Whether the last record was in collision.
    pub fn in_collision(&self) -> bool {
        self.in_collision
    }

    /// The summary, with the run's outcome given by the caller.
    pub fn finish(&self, success: bool, failure: Option<String>) -> RunMetrics {
        let mut sorted = self.compute_s.clone();
        sorted.sort_by(f64::total_cmp);
        RunMetrics {
            success,
            failure,
            collisions: self.collisions,
            min_clearance_m: self.min_clearance_m,
            path_length_m: self.path_length_m,
            time_s: self.time_s,
            compute_ms_median: 1e3 * percentile(&sorted, 0.5),
            compute_ms_p99: 1e3 * percentile(&sorted, 0.99),
            steps: self.steps,
        }
    }
}

/// The `q`-quantile (q in [0, 1]) of sorted values, interpolating linearly between the
/// order statistics at rank `q·(n - 1)` (NumPy's default); 0 for no value.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    match sorted.len() {
        0 => 0.0,
        1 => sorted[0],
        n => {
            let rank = q.clamp(0.0, 1.0) * (n - 1) as f64;
            let lo = rank.floor() as usize;
            let hi = (lo + 1).min(n - 1);
            let frac = rank - lo as f64;
            sorted[lo] + (sorted[hi] - sorted[lo]) * frac
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_matches_numpy_linear() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        // numpy.percentile(1..=100, 50) = 50.5, (.., 99) = 99.01.
        assert!((percentile(&v, 0.5) - 50.5).abs() < 1e-12);
        assert!((percentile(&v, 0.99) - 99.01).abs() < 1e-9);
        assert_eq!(percentile(&[], 0.5), 0.0);
        assert_eq!(percentile(&[3.0], 0.99), 3.0);
        assert_eq!(percentile(&[1.0, 2.0, 4.0], 0.5), 2.0);
    }

    #[test]
    fn path_length_clearance_collisions_and_compute() {
        let mut m = MetricsRecorder::new(0.0, DVec3::ZERO, 2.0, false);
        m.record(0.1, DVec3::new(3.0, 0.0, 0.0), 1.5, false, Some(0.002));
        m.record(0.2, DVec3::new(3.0, 4.0, 0.0), -0.1, true, Some(0.004));
        m.record(0.3, DVec3::new(3.0, 4.0, 0.0), -0.05, true, Some(0.001));
        m.record(0.4, DVec3::new(3.0, 4.0, 12.0), 0.5, false, None);
        m.record(0.5, DVec3::new(3.0, 4.0, 12.0), 0.2, true, Some(f64::NAN));
        let r = m.finish(false, Some("collision".into()));
        assert_eq!(r.path_length_m, 3.0 + 4.0 + 12.0);
        assert_eq!(r.min_clearance_m, -0.1);
        // Two entries into collision (steps 2 and 5), the contact at step 3 continues the first.
        assert_eq!(r.collisions, 2);
        assert_eq!(r.time_s, 0.5);
        assert_eq!(r.steps, 5);
        // Compute times 1, 2, 4 ms: median 2, p99 = 2 + 0.98·2 = 3.96.
        assert!((r.compute_ms_median - 2.0).abs() < 1e-12);
        assert!((r.compute_ms_p99 - 3.96).abs() < 1e-12);
        assert_eq!(r.failure.as_deref(), Some("collision"));
    }
}
