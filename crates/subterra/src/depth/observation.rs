//! The observation model, in log space (the weights underflow otherwise: with σ_n = 1,
//! `exp(-300²/2)` is 0 in f64).
//!
//! - voxel `s` whose image block has `B` pixels (`k_w·k_h` inside, fewer at the edges):
//!   `log N(n_s; B, σ_o·B/(k_w·k_h))` with σ_o's normalising constant, i.e. the occupied
//!   *fraction* is compared, so that an edge voxel can be full and an empty one is not
//!   mistaken for occupied;
//! - `s_free`: `log N(max_i n_i; 0, σ_n)`.

use super::grid::{DepthVoxelGrid, StateId, VoxelCounts};
use crate::config::ObservationConfig;

/// `0.5·ln(2π)`.
const HALF_LN_TWO_PI: f64 = 0.918_938_533_204_672_7;

/// Precomputed per-voxel constants of the observation model.
#[derive(Debug, Clone)]
pub(super) struct ObservationModel {
    /// Per voxel: the expected count of a full voxel, `B`.
    full_count: Vec<f64>,
    /// Per voxel: `1 / (σ_o·B/(k_w·k_h))`.
    inv_spread: Vec<f64>,
    /// `-ln σ_o - ½ ln 2π`.
    voxel_log_norm: f64,
    /// `1 / σ_n`.
    inv_sigma_n: f64,
    /// `-ln σ_n - ½ ln 2π`.
    free_log_norm: f64,
}

impl ObservationModel {
    /// Precomputes the model for `grid`.
    pub(super) fn new(grid: &DepthVoxelGrid, config: &ObservationConfig) -> Self {
        let full_block = (grid.config().block_width_px * grid.config().block_height_px) as f64;
        let voxels = grid.voxel_count();
        let mut full_count = Vec::with_capacity(voxels);
        let mut inv_spread = Vec::with_capacity(voxels);
        for s in 0..voxels as u32 {
            let b = grid.voxel_of(StateId(s)).map_or(full_block, |v| grid.block_pixel_count(v) as f64);
            full_count.push(b);
            inv_spread.push(full_block / (config.sigma_o_points * b));
        }
        Self {
            full_count,
            inv_spread,
            voxel_log_norm: -config.sigma_o_points.ln() - HALF_LN_TWO_PI,
            inv_sigma_n: 1.0 / config.sigma_n_points,
            free_log_norm: -config.sigma_n_points.ln() - HALF_LN_TWO_PI,
        }
    }

    /// Log-likelihood of the observation for every state (voxels, then `s_free`).
    pub(super) fn log_likelihood(&self, counts: &VoxelCounts, out: &mut [f64]) {
        let voxels = self.full_count.len();
        for (((o, &n), &b), &inv) in out[..voxels].iter_mut().zip(&counts.counts).zip(&self.full_count).zip(&self.inv_spread) {
            let r = (n as f64 - b) * inv;
            *o = -0.5 * r * r + self.voxel_log_norm;
        }
        let r = counts.max_count as f64 * self.inv_sigma_n;
        out[voxels] = -0.5 * r * r + self.free_log_norm;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeCamera;
    use crate::config::PerceptionConfig;
    use crate::depth::grid::VoxelIndex;

    #[test]
    fn log_weights_by_hand() {
        let config = PerceptionConfig::flight();
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), config.grid).unwrap();
        let model = ObservationModel::new(&grid, &config.observation);
        let mut counts = VoxelCounts { counts: vec![0; grid.voxel_count()], max_count: 0, in_range: 0, valid: 0, closest_depth_m: None };
        let full = grid.state_of(VoxelIndex { i: 3, j: 3, k: 4 }).0 as usize;
        let edge = grid.state_of(VoxelIndex { i: 12, j: 3, k: 4 }).0 as usize;
        counts.counts[full] = 2500;
        counts.counts[edge] = 1000; // half of the 40x50 edge block
        counts.max_count = 2500;
        let mut lw = vec![0.0; grid.state_count()];
        model.log_likelihood(&counts, &mut lw);
        let norm = -(170.0f64).ln() - 0.5 * (2.0 * std::f64::consts::PI).ln();
        assert!((lw[full] - norm).abs() < 1e-12);
        // Edge block: mean 2000, spread 170·2000/2500 = 136.
        assert!((lw[edge] - (-0.5 * (1000.0f64 / 136.0).powi(2) + norm)).abs() < 1e-12);
        // An empty interior voxel: 2500/170 standard deviations away.
        assert!((lw[0] - (-0.5 * (2500.0f64 / 170.0).powi(2) + norm)).abs() < 1e-12);
        let free_norm = -(60.0f64).ln() - 0.5 * (2.0 * std::f64::consts::PI).ln();
        assert!((lw[grid.voxel_count()] - (-0.5 * (2500.0f64 / 60.0).powi(2) + free_norm)).abs() < 1e-9);
    }

    #[test]
    fn an_empty_edge_voxel_is_not_taken_for_occupied() {
        // Regression: mean B with spread σ_o made an empty 40x30 corner block look full.
        let config = PerceptionConfig::flight();
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), config.grid).unwrap();
        let model = ObservationModel::new(&grid, &config.observation);
        let counts = VoxelCounts { counts: vec![0; grid.voxel_count()], max_count: 0, in_range: 0, valid: 0, closest_depth_m: None };
        let mut lw = vec![0.0; grid.state_count()];
        model.log_likelihood(&counts, &mut lw);
        let corner = grid.state_of(VoxelIndex { i: 12, j: 9, k: 0 }).0 as usize;
        assert!(lw[grid.voxel_count()] - lw[corner] > 50.0, "free must beat an empty corner voxel by far");
    }
}
