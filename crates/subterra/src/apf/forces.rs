//! The belief-weighted repulsion of one camera: `F = Σ_s b(s)·F_rep(p_s)` (APF-PF paper
//! §IV), with `p_s` the point of voxel `s` in the body frame and `F_rep` the potential of
//! [`repulsive_force`].
//!
//! In: a perception (its grid, mounting and `apf` settings fix every voxel's force once) and
//! each frame's dense belief. Out: the summed force in the body frame. The free state
//! repels nothing.

use glam::DVec3;

use super::repulsive_force;
use crate::depth::{DepthPerception, StateId};

/// Per-state repulsive forces of one perception, computed once.
#[derive(Debug, Clone)]
pub struct BeliefForces {
    /// Force of an obstacle at each state's point, body frame \[N\]; the free state last (zero).
    forces_body: Vec<DVec3>,
    fingerprint: u64,
}

impl BeliefForces {
    /// The table for `perception`: each voxel's point is taken where its config's
    /// `apf.voxel_position` puts it (the authors' corner pixel and near bin edge, or the
    /// centre), moved into the body frame by the perception's mounting.
    pub fn new(perception: &DepthPerception) -> Self {
        let grid = perception.grid();
        let config = perception.config();
        let body_from_camera = perception.body_from_camera();
        let mut forces_body = Vec::with_capacity(grid.state_count());
        for s in 0..grid.voxel_count() as u32 {
            let point = grid.voxel_of(StateId(s)).map_or(DVec3::ZERO, |v| grid.voxel_point_camera(v, config.apf.voxel_position));
            forces_body.push(repulsive_force(&config.apf, body_from_camera.transform_point(point)));
        }
        forces_body.push(DVec3::ZERO); // s_free repels nothing
        Self { forces_body, fingerprint: perception.fingerprint() }
    }

    /// Per-state forces, body frame \[N\] (voxels, then the free state).
    pub fn forces_body(&self) -> &[DVec3] {
        &self.forces_body
    }

    /// [`DepthPerception::fingerprint`] of the perception the table was made for.
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    /// `Σ_s b(s)·F_rep(s)` over the dense `belief` (one value per state, as
    /// [`DepthPerception::belief`] gives it), in state order: the same belief gives the
    /// same bits. A belief of another length sums over the states both have.
    pub fn repulsive(&self, belief: &[f64]) -> DVec3 {
        let mut sum = DVec3::ZERO;
        for (&b, f) in belief.iter().zip(&self.forces_body) {
            if b > 0.0 {
                sum += b * *f;
            }
        }
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeCamera;
    use crate::config::{PerceptionConfig, VoxelPosition};
    use crate::depth::DepthImage;
    use crate::frames::Isometry3;

    fn perception(position: VoxelPosition) -> DepthPerception {
        let mut config = PerceptionConfig::flight();
        config.filter.particles = 2000;
        config.apf.voxel_position = position;
        DepthPerception::new(PinholeCamera::d435(), Isometry3::body_from_forward_optical(), config, 7).unwrap()
    }

    #[test]
    fn the_force_is_the_belief_weighted_sum_of_the_voxels_forces() {
        let mut p = perception(VoxelPosition::NearCorner);
        let forces = BeliefForces::new(&p);
        let mut depth = vec![0u16; 640 * 480];
        for v in 200..280 {
            for u in 300..350 {
                depth[v * 640 + u] = 700;
            }
        }
        for _ in 0..3 {
            p.update(DepthImage::U16 { pixels: &depth, scale_m_per_unit: 0.001 }, 640, 480).unwrap();
        }
        let mut expected = DVec3::ZERO;
        for (s, &b) in p.belief().iter().enumerate() {
            expected += b * forces.forces_body()[s];
        }
        let got = forces.repulsive(p.belief());
        assert!(got.x < 0.0, "an obstacle ahead pushes back: {got}");
        assert!((got - expected).length() < 1e-12, "{got} vs {expected}");
        assert_eq!(*forces.forces_body().last().unwrap(), DVec3::ZERO, "the free state repels nothing");
    }

    #[test]
    fn forces_come_from_the_configured_voxel_point() {
        // Voxel (6, 4, 9): block pixels 300..349 x 200..249, bin [1.0, 1.1) m.
        let camera = PinholeCamera::d435();
        let v = crate::depth::VoxelIndex { i: 6, j: 4, k: 9 };
        let body_from_camera = Isometry3::body_from_forward_optical();
        let table = |config: PerceptionConfig| {
            let mut config = config;
            config.filter.particles = 10;
            BeliefForces::new(&DepthPerception::new(camera, body_from_camera, config, 0).unwrap())
        };
        for (config, pixel, depth) in [(PerceptionConfig::acc2021(), (300.0, 200.0), 1.0), (PerceptionConfig::flight(), (324.5, 224.5), 1.05)] {
            let forces = table(config);
            let s = DepthPerception::new(camera, body_from_camera, PerceptionConfig { filter: crate::config::FilterConfig { particles: 10, ..config.filter }, ..config }, 0)
                .unwrap()
                .grid()
                .state_of(v)
                .0 as usize;
            let point = body_from_camera.transform_point(camera.back_project(pixel.0, pixel.1, depth));
            let expected = repulsive_force(&config.apf, point);
            assert!((forces.forces_body()[s] - expected).length() < 1e-12, "{:?}: {} vs {expected}", config.apf.voxel_position, forces.forces_body()[s]);
        }
        // The near corner is the conservative distance: ~30-40% more repulsion 1 m ahead.
        let (near, centre) = (table(PerceptionConfig::acc2021()), table(PerceptionConfig::flight()));
        let grid = crate::depth::DepthVoxelGrid::new(camera, PerceptionConfig::flight().grid).unwrap();
        let s = grid.state_of(v).0 as usize;
        let ratio = near.forces_body()[s].length() / centre.forces_body()[s].length();
        assert!(ratio > 1.25 && ratio < 1.45, "{ratio}");
    }
}
