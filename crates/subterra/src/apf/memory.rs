//! A short memory of where the belief put obstacles, kept in the odometry (world) frame,
//! so that an obstacle still repels after it has left the camera's view (subterra; the
//! paper's filter has none).
//!
//! Documented on [`ObstacleMemory`].

use std::collections::BTreeMap;
use std::cmp::Ordering;

use glam::DVec3;

use super::repulsive_force;
use crate::camera::PinholeCamera;
use crate::config::{ApfConfig, GridConfig, MemoryConfig};
use crate::depth::{DepthPerception, PerceptionOutput, StateId, VoxelCounts};
use crate::error::{Error, Result};
use crate::frames::Isometry3;

/// One remembered cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RememberedObstacle {
    /// The newest voxel centre recorded in the cell [m, world].
    pub point_world: DVec3,
    /// Its weight: the largest belief recorded in the cell on its newest frame.
    pub weight: f64,
    /// When an obstacle was last recorded in the cell (by the belief or the guard) \[s\].
    pub seen_s: f64,
    /// The frame that did (the update counter).
    frame: u64,
}

/// What one [`ObstacleMemory::update`] gives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MemoryOutput {
    /// The memory's repulsive force in the body frame \[N\] (step 3).
    pub repulsive_body: DVec3,
    /// Cells remembered after the update.
    pub cells: usize,
    /// Distance from the body origin to the nearest remembered point \[m\], if any.
    pub nearest_m: Option<f64>,
}

/// The memory of one camera's belief.
///
/// In: each frame's [`PerceptionOutput`] (its belief), the odometry pose `world_from_body`
/// and the time stamp. Out: a repulsive force in the body frame, added to the belief's.
///
/// # One update, exactly
/// 1. **Record.** Every voxel whose belief is at least `min_belief` (the free state never)
///    puts its point (the one its repulsion comes from, `apf.voxel_position`), in the
///    world frame, into the cell of side `cell_m` that holds it; the cell keeps the newest
///    point, the largest belief of this frame, and the time.
/// 2. **Guard** (with `guard_sigmas > 0` and the frame's counts given). Every voxel whose
///    point lies within `rho_0_m` and whose count is at least `guard_sigmas · σ_n` is
///    recorded as in step 1 with weight 1, whatever the belief holds. The free hypothesis
///    explains the largest count as `N(0, σ_n)` (the observation model), so at 3 σ_n such a
///    count is an object, not speckle; the belief over *one* obstacle, though, can stay on
///    a full wall voxel 1 m behind a 14 mm cable while the cable closes to contact (tunnel
///    seeds 25 and 35, docs/flight.md). The guard acts only where the memory's own short
///    cut-off acts, so it adds no long-range push.
/// 3. **Forget.** A cell is forgotten `timeout_s` after an obstacle was last recorded in
///    it, or `in_view_timeout_s` after, when its point lies in the camera's view now
///    (inside the image and between `grid.depth_min_m` and `grid.depth_max_m` along the
///    optical axis): there the filter sees the place, and its belief is the better word
///    (occlusion is not modelled, and a belief that moved to another obstacle in view also
///    lets a cell go after that second). Past `max_cells` the oldest cells go first. Both
///    timeouts are multiplied by the odometry confidence in [0, 1]
///    ([`ObstacleMemory::set_confidence`], 1 by default): at 0 only this frame's cells stay.
/// 4. **Repel.** `F = Σ_c w_c·F_rep(p_c) / max(1, Σ_{c: |p_c| < ρ_m} w_c)`: the potential
///    of [`repulsive_force`] with the memory's own cut-off `ρ_m = rho_0_m` (the belief's
///    `η` and `min_distance_m`), over the cells' points `p_c` in the body frame, weighted
///    by their beliefs and normalised like a belief once the weights within `ρ_m` sum past 1
///    (a guarded cell counts 1 there: the force is the mean over what is near, as the
///    belief's is an expectation, not a sum that grows with a wall's area).
///    Cells the belief holds now count too: an obstacle in view within `ρ_m` is pushed
///    against by the belief and by the memory, up to twice as hard.
///
/// Why: the simulated D435's 80° x 64° view (fx = 385 px on 640 x 480) is narrow. A
/// robot that turns away from a thin pole until the pole leaves the view flies on past it
/// blind, and grazes it (highbay seeds 13, 15, 17, docs/flight.md); and a belief over one
/// obstacle can jump to a fuller voxel beyond `ρ_0` and drop a thin pole close ahead
/// (seeds 10, 14): the memory keeps the pole for `in_view_timeout_s` more, and the
/// `flight-memory` preset's σ_o = 300 has the pole believed from farther away, in time to
/// turn. The cut-off `ρ_m` is short (0.6 m, against the belief's 1.4 m) so that
/// what is remembered only acts near contact: a long-range memory holds the robot in front
/// of every large obstacle it has turned away from.
///
/// Cells are kept in a `BTreeMap`, so the sums run in one order: the same calls give
/// bit-identical forces.
#[derive(Debug, Clone)]
pub struct ObstacleMemory {
    config: MemoryConfig,
    apf: ApfConfig,
    grid: GridConfig,
    camera: PinholeCamera,
    camera_from_body: Isometry3,
    /// Voxel points (`apf.voxel_position`) in the body frame, by state id (the free state has none).
    centres_body: Vec<DVec3>,
    free: StateId,
    /// The guard's count threshold `guard_sigmas · σ_n` (infinite when off).
    guard_points: f64,
    cells: BTreeMap<(i64, i64, i64), RememberedObstacle>,
    last_stamp_s: Option<f64>,
    frames: u64,
    /// The perception whose outputs it takes.
    fingerprint: u64,
    /// Odometry confidence in [0, 1] that scales the timeouts (step 3).
    confidence: f64,
}

impl ObstacleMemory {
    /// A memory for `perception`'s camera, grid and mounting, with the settings of its
    /// config's `memory` section (used whether or not `memory.enabled` is set: the flag
    /// tells callers such as `subterra fly` whether to build one).
    pub fn new(perception: &DepthPerception) -> Result<Self> {
        let config = perception.config();
        config.memory.validate()?;
        let grid = perception.grid();
        let body_from_camera = *perception.body_from_camera();
        let centres_body = (0..grid.voxel_count() as u32)
            .map(|s| {
                grid.voxel_of(StateId(s))
                    .map_or(DVec3::ZERO, |v| body_from_camera.transform_point(grid.voxel_point_camera(v, config.apf.voxel_position)))
            })
            .collect();
        Ok(Self {
            config: config.memory,
            apf: config.apf,
            grid: config.grid,
            camera: *grid.camera(),
            camera_from_body: body_from_camera.inverse(),
            centres_body,
            free: grid.free_state(),
            guard_points: if config.memory.guard_sigmas > 0.0 { config.memory.guard_sigmas * config.observation.sigma_n_points } else { f64::INFINITY },
            cells: BTreeMap::new(),
            last_stamp_s: None,
            frames: 0,
            fingerprint: perception.fingerprint(),
            confidence: 1.0,
        })
    }

    /// Sets the odometry confidence `c` in [0, 1] (an [`crate::hero::OdometryMux`]'s) that
    /// the next updates forget with: both timeouts of step 3 are multiplied by `c`, so at 0
    /// only what the newest frame recorded is kept (a memory kept in a frame the odometry no
    /// longer vouches for drags obstacles across the world). 1 (the default) leaves them.
    pub fn set_confidence(&mut self, confidence: f64) -> Result<()> {
        if !(confidence.is_finite() && (0.0..=1.0).contains(&confidence)) {
            return Err(Error::input("confidence", format!("must be in [0, 1], got {confidence}")));
        }
        self.confidence = confidence;
        Ok(())
    }

    /// The settings.
    pub fn config(&self) -> &MemoryConfig {
        &self.config
    }

    /// The remembered cells, in key order.
    pub fn obstacles(&self) -> impl Iterator<Item = &RememberedObstacle> {
        self.cells.values()
    }

    /// Number of remembered cells.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether nothing is remembered.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Forgets everything (a new flight, or odometry that jumped).
    pub fn reset(&mut self) {
        self.cells.clear();
        self.last_stamp_s = None;
    }

    /// Steps 1-4 for one frame of `output` (from the perception this memory was built for)
    /// taken at `stamp_s` \[s\] with the odometry pose `world_from_body`; `counts`, the same
    /// frame's voxel counts ([`DepthPerception::last_counts`]), feed the near-field guard
    /// (see [`ObstacleMemory`]; without them, or with `guard_sigmas = 0`, there is no guard).
    pub fn update(&mut self, output: &PerceptionOutput, counts: Option<&VoxelCounts>, stamp_s: f64, world_from_body: &Isometry3) -> Result<MemoryOutput> {
        crate::frames::check_stamp("stamp", stamp_s)?;
        if let Some(last) = self.last_stamp_s {
            if stamp_s < last {
                return Err(Error::input("stamp", format!("must not go back in time: {stamp_s} s after {last} s (call reset() first)")));
            }
        }
        if !(world_from_body.translation.is_finite() && world_from_body.rotation.is_finite()) {
            return Err(Error::input("world_from_body", "must be finite"));
        }
        if output.fingerprint != self.fingerprint {
            return Err(Error::input(
                "output",
                "comes from a different perception (camera, mounting or grid): a memory takes the outputs of the perception it was made for",
            ));
        }
        if output.belief_states.len() != output.belief_probabilities.len() {
            return Err(Error::input("output", "belief states and probabilities differ in length"));
        }
        if let Some(counts) = counts {
            if counts.counts.len() != self.centres_body.len() {
                return Err(Error::input("counts", format!("must hold one count per voxel of this memory's grid ({}), got {}", self.centres_body.len(), counts.counts.len())));
            }
        }
        self.last_stamp_s = Some(stamp_s);
        self.frames += 1;
        let c = self.config;

        // 1. Record.
        for (&state, &belief) in output.belief_states.iter().zip(&output.belief_probabilities) {
            if state == self.free || belief.partial_cmp(&c.min_belief).is_none_or(Ordering::is_lt) {
                continue;
            }
            let Some(&centre) = self.centres_body.get(state.0 as usize) else {
                return Err(Error::input("output", format!("state {} is not a voxel of this memory's grid", state.0)));
            };
            self.record(world_from_body.transform_point(centre), belief, stamp_s);
        }
        // 2. The near-field guard.
        if let Some(counts) = counts.filter(|_| self.guard_points.is_finite()) {
            for (s, &n) in counts.counts.iter().enumerate() {
                let centre = self.centres_body[s];
                if f64::from(n) >= self.guard_points && centre.length() < c.rho_0_m {
                    self.record(world_from_body.transform_point(centre), 1.0, stamp_s);
                }
            }
        }

        // 3. Forget.
        let body_from_world = world_from_body.inverse();
        let camera_from_world = self.camera_from_body.compose(&body_from_world);
        let (camera, grid) = (self.camera, self.grid);
        let (timeout_s, in_view_timeout_s) = (self.confidence * c.timeout_s, self.confidence * c.in_view_timeout_s);
        self.cells.retain(|_, cell| {
            let age = stamp_s - cell.seen_s;
            age <= timeout_s && !(age > in_view_timeout_s && in_view(&camera, &grid, camera_from_world.transform_point(cell.point_world)))
        });
        if self.cells.len() > c.max_cells as usize {
            let mut by_age: Vec<((i64, i64, i64), f64)> = self.cells.iter().map(|(k, v)| (*k, v.seen_s)).collect();
            by_age.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            let excess = self.cells.len() - c.max_cells as usize;
            for (key, _) in by_age.into_iter().take(excess) {
                self.cells.remove(&key);
            }
        }

        // 4. Repel.
        let field = ApfConfig { rho_0_m: c.rho_0_m, ..self.apf };
        let mut sum = DVec3::ZERO;
        let mut weight_near = 0.0;
        let mut nearest: Option<f64> = None;
        for cell in self.cells.values() {
            let p_body = body_from_world.transform_point(cell.point_world);
            let d = p_body.length();
            nearest = Some(nearest.map_or(d, |n| n.min(d)));
            if d < c.rho_0_m {
                sum += cell.weight * repulsive_force(&field, p_body);
                weight_near += cell.weight;
            }
        }
        Ok(MemoryOutput { repulsive_body: sum / weight_near.max(1.0), cells: self.cells.len(), nearest_m: nearest })
    }
}

impl ObstacleMemory {
    /// Step 1 for one point: its cell keeps the newest point and this frame's largest weight.
    fn record(&mut self, point_world: DVec3, weight: f64, stamp_s: f64) {
        let key = cell_key(point_world, self.config.cell_m);
        let frame = self.frames;
        let cell = self.cells.entry(key).or_insert(RememberedObstacle { point_world, weight, seen_s: stamp_s, frame });
        let weight = if cell.frame == frame { cell.weight.max(weight) } else { weight };
        *cell = RememberedObstacle { point_world, weight, seen_s: stamp_s, frame };
    }
}

/// The cell of side `cell_m` holding `p`.
fn cell_key(p: DVec3, cell_m: f64) -> (i64, i64, i64) {
    let q = (p / cell_m).floor();
    (q.x as i64, q.y as i64, q.z as i64)
}

/// Whether `p_camera` is inside the image and the filter's depth range.
fn in_view(camera: &PinholeCamera, grid: &GridConfig, p_camera: DVec3) -> bool {
    if !(p_camera.z >= grid.depth_min_m && p_camera.z < grid.depth_max_m) {
        return false;
    }
    camera.project(p_camera).is_some_and(|(u, v)| u >= 0.0 && v >= 0.0 && u < f64::from(camera.width) && v < f64::from(camera.height))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::PerceptionConfig;
    use crate::depth::MostProbableVoxel;
    use crate::depth::StageTimings;
    use glam::DMat3;

    fn perception() -> DepthPerception {
        let mut config = PerceptionConfig::flight_memory();
        config.filter.particles = 100;
        DepthPerception::new(PinholeCamera::d435(), Isometry3::body_from_forward_optical(), config, 0).unwrap()
    }

    /// An output whose belief is `b` on voxel `(i, j, k)` and `1 - b` on free.
    fn output(p: &DepthPerception, voxel: (u32, u32, u32), b: f64) -> PerceptionOutput {
        let g = p.grid();
        let s = g.state_of(crate::depth::VoxelIndex { i: voxel.0, j: voxel.1, k: voxel.2 });
        let most_probable: Option<MostProbableVoxel> = None;
        PerceptionOutput {
            belief_states: vec![s, g.free_state()],
            belief_probabilities: vec![b, 1.0 - b],
            p_free: 1.0 - b,
            most_probable,
            closest_depth_m: None,
            valid_pixels: 0,
            in_range_pixels: 0,
            max_count: 0,
            timings: StageTimings::default(),
            fingerprint: p.fingerprint(),
        }
    }

    fn free(p: &DepthPerception) -> PerceptionOutput {
        let mut o = output(p, (0, 0, 0), 0.0);
        o.belief_states.remove(0);
        o.belief_probabilities.remove(0);
        o
    }

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3 {
        Isometry3 { rotation: DMat3::from_rotation_z(yaw), translation: DVec3::new(x, y, 0.0) }
    }

    #[test]
    fn an_output_of_another_perception_is_refused() {
        let p = perception();
        let mut other_config = PerceptionConfig::flight_memory();
        other_config.filter.particles = 100;
        let camera = PinholeCamera::new(200.0, 200.0, 99.5, 99.5, 200, 200).unwrap();
        let other = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), other_config, 0).unwrap();
        let mut memory = ObstacleMemory::new(&p).unwrap();
        let foreign = output(&other, (0, 0, 0), 0.9);
        let err = memory.update(&foreign, None, 0.0, &pose(0.0, 0.0, 0.0)).unwrap_err().to_string();
        assert!(err.contains("output") && err.contains("different perception"), "{err}");
        assert!(memory.update(&output(&p, (0, 0, 0), 0.9), None, 0.0, &pose(0.0, 0.0, 0.0)).is_ok());
    }

    #[test]
    fn a_remembered_obstacle_repels_with_the_memory_cut_off_after_it_left_the_view() {
        let p = perception();
        let mut m = ObstacleMemory::new(&p).unwrap();
        // The centre column's voxel at bin 3 (0.45 m ahead): seen once with belief 0.8.
        let (n_w, n_h, _) = p.grid().shape();
        let v = ((n_w / 2) as u32, (n_h / 2) as u32, 3);
        let centre = m.centres_body[p.grid().state_of(crate::depth::VoxelIndex { i: v.0, j: v.1, k: v.2 }).0 as usize];
        let out = m.update(&output(&p, v, 0.8), None, 0.0, &pose(0.0, 0.0, 0.0)).unwrap();
        assert_eq!(out.cells, 1);
        // Weight 0.8 < 1: not normalised. The belief's η, the memory's ρ = 0.6 m.
        let field = ApfConfig { rho_0_m: 0.6, ..p.config().apf };
        let expected = 0.8 * repulsive_force(&field, centre);
        assert!((out.repulsive_body - expected).length() < 1e-12, "{} vs {expected}", out.repulsive_body);
        // Turned 90° left: the point is now on the right, out of view, still remembered
        // 5 s later, and pushes left (+y in the body frame).
        let out = m.update(&free(&p), None, 5.0, &pose(0.0, 0.0, std::f64::consts::FRAC_PI_2)).unwrap();
        assert_eq!(out.cells, 1);
        // The same force, turned with the body: body_from_world takes (x, y) to (y, -x).
        let turned = DVec3::new(expected.y, -expected.x, expected.z);
        assert!(out.repulsive_body.y > 0.0 && (out.repulsive_body - turned).length() < 1e-9, "{} vs {turned}", out.repulsive_body);
        // Past timeout_s it is gone.
        let out = m.update(&free(&p), None, 10.5, &pose(0.0, 0.0, std::f64::consts::FRAC_PI_2)).unwrap();
        assert_eq!((out.cells, out.repulsive_body), (0, DVec3::ZERO));
    }

    #[test]
    fn in_view_and_no_longer_believed_it_is_forgotten_after_the_view_timeout() {
        let p = perception();
        let mut m = ObstacleMemory::new(&p).unwrap();
        let v = (6, 4, 3);
        m.update(&output(&p, v, 0.9), None, 0.0, &pose(0.0, 0.0, 0.0)).unwrap();
        let t = m.config().in_view_timeout_s;
        // Still in view, belief free: kept up to the view timeout, then forgotten.
        assert_eq!(m.update(&free(&p), None, t, &pose(0.0, 0.0, 0.0)).unwrap().cells, 1);
        assert_eq!(m.update(&free(&p), None, t + 0.01, &pose(0.0, 0.0, 0.0)).unwrap().cells, 0);
        // Believed again every frame: never forgotten in view.
        for n in 0..40 {
            let out = m.update(&output(&p, v, 0.9), None, 2.0 + 0.1 * f64::from(n), &pose(0.0, 0.0, 0.0)).unwrap();
            assert_eq!(out.cells, 1, "frame {n}");
        }
    }

    #[test]
    fn odometry_confidence_shortens_the_memory_and_at_zero_keeps_only_the_newest_frame() {
        let p = perception();
        let mut m = ObstacleMemory::new(&p).unwrap();
        let (n_w, n_h, _) = p.grid().shape();
        let v = ((n_w / 2) as u32, (n_h / 2) as u32, 3);
        m.update(&output(&p, v, 0.9), None, 0.0, &pose(0.0, 0.0, 0.0)).unwrap();
        let half = 0.5 * m.config().timeout_s;
        let out_of_view = pose(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        // At confidence 1 a cell out of view is kept for timeout_s; at 0.5 for half of it.
        assert_eq!(m.update(&free(&p), None, half - 0.01, &out_of_view).unwrap().cells, 1);
        m.set_confidence(0.5).unwrap();
        assert_eq!(m.update(&free(&p), None, half + 0.01, &out_of_view).unwrap().cells, 0);
        // At 0 a cell recorded now is kept, the one before is not.
        m.set_confidence(1.0).unwrap();
        m.update(&output(&p, v, 0.9), None, 6.0, &pose(0.0, 0.0, 0.0)).unwrap();
        let other = output(&p, ((n_w / 2) as u32 + 1, (n_h / 2) as u32, 5), 0.9);
        let mut trusting = m.clone();
        assert_eq!(trusting.update(&other, None, 6.1, &pose(0.0, 0.0, 0.0)).unwrap().cells, 2);
        m.set_confidence(0.0).unwrap();
        assert_eq!(m.update(&other, None, 6.1, &pose(0.0, 0.0, 0.0)).unwrap().cells, 1);
        assert!(m.set_confidence(1.5).unwrap_err().to_string().contains("confidence"));
        assert!(m.set_confidence(f64::NAN).is_err());
    }

    #[test]
    fn weights_past_one_are_normalised_like_a_belief() {
        let p = perception();
        let mut m = ObstacleMemory::new(&p).unwrap();
        // Two voxels of one frame, belief 0.9 each, 0.35 m and 0.45 m ahead (bins 2, 3) in
        // the centre column: the force is their weighted mean, not their sum.
        let (n_w, n_h, _) = p.grid().shape();
        let (i, j) = ((n_w / 2) as u32, (n_h / 2) as u32);
        let mut o = output(&p, (i, j, 2), 0.9);
        let s3 = p.grid().state_of(crate::depth::VoxelIndex { i, j, k: 3 });
        o.belief_states.insert(1, s3);
        o.belief_probabilities.insert(1, 0.9);
        let out = m.update(&o, None, 0.0, &pose(0.0, 0.0, 0.0)).unwrap();
        let field = ApfConfig { rho_0_m: 0.6, ..p.config().apf };
        let s2 = o.belief_states[0];
        let expected = (0.9 * repulsive_force(&field, m.centres_body[s2.0 as usize]) + 0.9 * repulsive_force(&field, m.centres_body[s3.0 as usize])) / 1.8;
        assert!((out.repulsive_body - expected).length() < 1e-12);
        assert!((out.nearest_m.unwrap() - m.centres_body[s2.0 as usize].length()).abs() < 1e-12);
    }

    #[test]
    fn bad_stamps_and_poses_are_refused() {
        let p = perception();
        let mut m = ObstacleMemory::new(&p).unwrap();
        m.update(&free(&p), None, 1.0, &pose(0.0, 0.0, 0.0)).unwrap();
        let back = m.update(&free(&p), None, 0.5, &pose(0.0, 0.0, 0.0)).unwrap_err().to_string();
        assert!(back.contains("stamp") && back.contains("back in time"), "{back}");
        assert!(m.update(&free(&p), None, f64::NAN, &pose(0.0, 0.0, 0.0)).unwrap_err().to_string().contains("stamp"));
        assert!(m.update(&free(&p), None, 2.0, &pose(f64::NAN, 0.0, 0.0)).unwrap_err().to_string().contains("world_from_body"));
        m.reset();
        assert!(m.update(&free(&p), None, 0.0, &pose(0.0, 0.0, 0.0)).is_ok(), "reset forgets the clock");
    }

    /// Counts with `n` points in voxel `(i, j, k)` and nothing else.
    fn counts(p: &DepthPerception, voxel: (u32, u32, u32), n: u32) -> VoxelCounts {
        let g = p.grid();
        let mut counts = vec![0; g.voxel_count()];
        counts[g.state_of(crate::depth::VoxelIndex { i: voxel.0, j: voxel.1, k: voxel.2 }).0 as usize] = n;
        VoxelCounts { counts, max_count: n, in_range: u64::from(n), valid: u64::from(n), closest_depth_m: None }
    }

    fn guarded() -> DepthPerception {
        let mut config = PerceptionConfig::flight_escape();
        config.filter.particles = 100;
        assert_eq!(config.memory.guard_sigmas, 3.0);
        DepthPerception::new(PinholeCamera::d435(), Isometry3::body_from_forward_optical(), config, 0).unwrap()
    }

    #[test]
    fn the_guard_remembers_a_near_voxel_the_belief_left_on_free() {
        let p = guarded();
        let sigma_n = p.config().observation.sigma_n_points;
        let (n_w, n_h, _) = p.grid().shape();
        let (i, j) = ((n_w / 2) as u32, (n_h / 2) as u32);
        // Bin 3: 0.4-0.5 m ahead, inside ρ_m = 0.6 m. The belief says free.
        let mut m = ObstacleMemory::new(&p).unwrap();
        let at = (3.0 * sigma_n) as u32;
        let out = m.update(&free(&p), Some(&counts(&p, (i, j, 3), at)), 0.0, &pose(0.0, 0.0, 0.0)).unwrap();
        assert_eq!(out.cells, 1, "3 σ_n points within ρ_m are an obstacle");
        assert_eq!(m.obstacles().next().unwrap().weight, 1.0);
        let field = ApfConfig { rho_0_m: 0.6, ..p.config().apf };
        let centre = m.centres_body[p.grid().state_of(crate::depth::VoxelIndex { i, j, k: 3 }).0 as usize];
        assert!((out.repulsive_body - repulsive_force(&field, centre)).length() < 1e-12);
        assert!(out.repulsive_body.x < 0.0, "it pushes back");
        // One point fewer is what the free hypothesis allows: nothing.
        let mut m = ObstacleMemory::new(&p).unwrap();
        assert_eq!(m.update(&free(&p), Some(&counts(&p, (i, j, 3), at - 1)), 0.0, &pose(0.0, 0.0, 0.0)).unwrap().cells, 0);
        // Beyond ρ_m (bin 8, ~0.95 m), however full: the belief's business, not the guard's.
        assert_eq!(m.update(&free(&p), Some(&counts(&p, (i, j, 8), 2500)), 0.1, &pose(0.0, 0.0, 0.0)).unwrap().cells, 0);
        // Without counts, or with the guard off, nothing either.
        assert_eq!(m.update(&free(&p), None, 0.2, &pose(0.0, 0.0, 0.0)).unwrap().cells, 0);
        let off = perception();
        assert_eq!(off.config().memory.guard_sigmas, 0.0);
        let mut m = ObstacleMemory::new(&off).unwrap();
        assert_eq!(m.update(&free(&off), Some(&counts(&off, (i, j, 3), 2500)), 0.0, &pose(0.0, 0.0, 0.0)).unwrap().cells, 0);
    }

    #[test]
    fn counts_of_another_grid_are_refused() {
        let p = guarded();
        let mut m = ObstacleMemory::new(&p).unwrap();
        let mut c = counts(&p, (0, 0, 0), 0);
        c.counts.pop();
        let err = m.update(&free(&p), Some(&c), 0.0, &pose(0.0, 0.0, 0.0)).unwrap_err().to_string();
        assert!(err.contains("counts"), "{err}");
    }

    #[test]
    fn the_cap_drops_the_oldest_cells() {
        let mut config = PerceptionConfig::flight_memory();
        config.filter.particles = 100;
        config.memory.max_cells = 2;
        let p = DepthPerception::new(PinholeCamera::d435(), Isometry3::body_from_forward_optical(), config, 0).unwrap();
        let mut m = ObstacleMemory::new(&p).unwrap();
        // Three frames, each seeing a voxel in another cell, turning so the old ones leave the view.
        for (n, yaw) in [0.0, 2.0, 4.0].into_iter().enumerate() {
            m.update(&output(&p, (6, 4, 5), 0.5), None, n as f64, &pose(0.0, 0.0, yaw)).unwrap();
        }
        assert_eq!(m.len(), 2);
        assert!(m.obstacles().all(|c| c.seen_s >= 1.0), "the oldest (t = 0) went first");
    }
}
