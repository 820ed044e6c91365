//! Temporal fusion: the window of recent scans with their poses (pipeline step 2).
//!
//! Each scan is kept as it was labelled: its points relative to its sensor, in world-aligned
//! axes, and each point's height above its own ground line. Re-expressing a scan in the
//! current robot-centred frame is then a translation by `t_k + s_k - t_now` (scan body
//! position plus its sensor offset, minus the current body position), exact for rigid poses
//! because every scan is already in world-aligned axes. Since the coarse map's cells are
//! aligned to the world, each scan is also binned once on arrival into global cells
//! ([`BinnedCell`]); fusing is then merging those cell sums, shifted by the difference of the
//! body heights, instead of re-binning every point of every scan.
//!
//! The window holds scans at most `window_s` older than the newest (and at most
//! `max_scans`). At odometry confidence `c` in [0, 1], only scans at most `c·window_s` older
//! than the newest are fused: confidence 0 fuses the newest scan alone.

use std::collections::VecDeque;

use glam::{DMat3, DVec3};

use super::config::FusionConfig;
use super::risk::BinnedCell;
use crate::error::{Error, Result};
use crate::frames::Isometry3;

/// Tolerance on `|RᵀR - I|` and `|det R - 1|` of a pose from the caller (f32 quaternions
/// converted to matrices stay within ~1e-7).
pub(super) const RIGID_TOLERANCE: f64 = 1e-5;

/// Checks that a pose is finite and rigid (a proper rotation), naming `argument` if not.
pub(super) fn check_rigid(argument: &str, pose: &Isometry3) -> Result<()> {
    let r = pose.rotation;
    if !(r.is_finite() && pose.translation.is_finite()) {
        return Err(Error::input(argument, "contains NaN or infinity"));
    }
    let off = (r.transpose() * r - DMat3::IDENTITY).abs().to_cols_array().iter().fold(0.0f64, |a, &b| a.max(b));
    let det = r.determinant();
    if off > RIGID_TOLERANCE || (det - 1.0).abs() > RIGID_TOLERANCE {
        return Err(Error::input(argument, format!("is not rigid: its rotation has |RᵀR - I| = {off:.2e} and det = {det:.6} (tolerance {RIGID_TOLERANCE:.0e})")));
    }
    Ok(())
}

/// One labelled scan of the window.
#[derive(Debug, Clone, Default)]
pub(super) struct StoredScan {
    /// Time of the scan \[s\].
    pub stamp_s: f64,
    /// Body position in the world at the scan \[m\].
    pub body_world: DVec3,
    /// Sensor position relative to the body origin, world axes \[m\].
    pub sensor_level: DVec3,
    /// Points relative to the sensor, world axes \[m\].
    pub points: Vec<[f32; 3]>,
    /// Each point's height above its ground line \[m\] (NaN: no line).
    pub heights: Vec<f32>,
    /// The points binned once into the coarse map's global cells.
    pub binned: Vec<BinnedCell>,
}

impl StoredScan {
    /// Where the scan's point frame (its sensor, world axes) is relative to `body_world_now`.
    pub(super) fn offset_from(&self, body_world_now: DVec3) -> DVec3 {
        self.body_world + self.sensor_level - body_world_now
    }
}

/// The window of recent scans, newest first.
#[derive(Debug, Clone)]
pub(super) struct ScanWindow {
    config: FusionConfig,
    scans: VecDeque<StoredScan>,
    spare: Vec<StoredScan>,
}

impl ScanWindow {
    /// An empty window; `config` is trusted (validated by the caller).
    pub(super) fn new(config: FusionConfig) -> Self {
        Self { config, scans: VecDeque::new(), spare: Vec::new() }
    }

    /// A scan record to fill, reusing the buffers of an evicted one.
    pub(super) fn blank(&mut self) -> StoredScan {
        self.spare.pop().unwrap_or_default()
    }

    /// Adds the newest scan and evicts what the window no longer holds.
    pub(super) fn push(&mut self, scan: StoredScan) {
        let newest = scan.stamp_s;
        self.scans.push_front(scan);
        while self.scans.len() > self.config.max_scans || self.scans.back().is_some_and(|s| newest - s.stamp_s > self.config.window_s) {
            if let Some(old) = self.scans.pop_back() {
                self.spare.push(old);
            }
        }
    }

    /// Drops every scan.
    pub(super) fn clear(&mut self) {
        self.spare.extend(self.scans.drain(..));
    }

    /// The newest scan.
    pub(super) fn newest(&self) -> Option<&StoredScan> {
        self.scans.front()
    }

    /// Stamp of the newest scan.
    pub(super) fn newest_stamp(&self) -> Option<f64> {
        self.scans.front().map(|s| s.stamp_s)
    }

    /// The scans fused at odometry `confidence` in [0, 1], newest first.
    pub(super) fn fused(&self, confidence: f64) -> impl Iterator<Item = &StoredScan> {
        let newest = self.newest_stamp().unwrap_or(0.0);
        let span = confidence.clamp(0.0, 1.0) * self.config.window_s;
        self.scans.iter().enumerate().filter(move |(i, s)| *i == 0 || newest - s.stamp_s <= span).map(|(_, s)| s)
    }

    /// Scans held.
    pub(super) fn len(&self) -> usize {
        self.scans.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(stamp_s: f64) -> StoredScan {
        StoredScan { stamp_s, ..Default::default() }
    }

    #[test]
    fn window_evicts_by_age_and_count_and_shrinks_with_confidence() {
        let mut w = ScanWindow::new(FusionConfig { window_s: 2.0, max_scans: 5 });
        for k in 0..30 {
            w.push(scan(k as f64 * 0.1));
        }
        // 2.9 s newest; max 5 scans: 2.5 ..= 2.9.
        assert_eq!(w.len(), 5);
        assert_eq!(w.fused(1.0).count(), 5);
        // Confidence 0.1: 0.2 s -> 2.7, 2.8, 2.9 (within float slack).
        assert!((2..=3).contains(&w.fused(0.1).count()));
        assert_eq!(w.fused(0.0).count(), 1);
        assert_eq!(w.fused(0.0).next().unwrap().stamp_s, 29.0 * 0.1);
        let mut w = ScanWindow::new(FusionConfig { window_s: 1.0, max_scans: 100 });
        for k in 0..30 {
            w.push(scan(k as f64 * 0.25));
        }
        assert_eq!(w.len(), 5);
    }

    #[test]
    fn poses_must_be_finite_and_rigid() {
        check_rigid("world_from_body", &Isometry3::IDENTITY).unwrap();
        let mut p = Isometry3::IDENTITY;
        p.translation.x = f64::NAN;
        assert!(check_rigid("world_from_body", &p).unwrap_err().to_string().contains("world_from_body"));
        let mut p = Isometry3::IDENTITY;
        p.rotation.x_axis.x = 1.5;
        assert!(check_rigid("body_from_sensor", &p).unwrap_err().to_string().contains("body_from_sensor"));
    }
}
