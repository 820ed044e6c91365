//! The APF-PF perception pipeline of one camera: depth image -> voxel counts -> Bayes
//! filter -> belief. The belief's forces are `apf`'s (`apf::forces`): this module knows
//! nothing of potentials.

use std::time::Instant;

use glam::DVec3;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::filter::{HistogramFilter, ParticleFilter};
use super::grid::{DepthImage, DepthVoxelGrid, StateId, VoxelCounts, VoxelIndex};
use super::observation::ObservationModel;
use super::transition::TransitionModel;
use crate::camera::PinholeCamera;
use crate::config::{FilterMode, PerceptionConfig};
use crate::error::Result;
use crate::frames::Isometry3;

/// The most probable voxel of the belief (the free state is reported separately).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MostProbableVoxel {
    /// The voxel.
    pub voxel: VoxelIndex,
    /// Its flat state id.
    pub state: StateId,
    /// Its belief.
    pub probability: f64,
    /// Its centre in the camera optical frame \[m\].
    pub centre_camera: DVec3,
    /// Its centre in the body frame \[m\].
    pub centre_body: DVec3,
}

/// Wall-clock time of each stage of one update \[s\].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageTimings {
    /// Counting the image into voxels.
    pub count_s: f64,
    /// Propagation (particles) or prediction (histogram).
    pub predict_s: f64,
    /// Observation log-likelihoods, weighting and resampling or Bayes update.
    pub update_s: f64,
    /// Belief extraction (the sparse view and the most probable voxel).
    pub belief_s: f64,
    /// The whole update.
    pub total_s: f64,
}

/// What one frame gives.
#[derive(Debug, Clone, PartialEq)]
pub struct PerceptionOutput {
    /// States with belief above zero (particle mode) or above the sparse threshold
    /// (histogram mode), ascending; the free state may be among them.
    pub belief_states: Vec<StateId>,
    /// Their probabilities.
    pub belief_probabilities: Vec<f64>,
    /// Belief of the free state.
    pub p_free: f64,
    /// The most probable voxel, if any voxel has belief.
    pub most_probable: Option<MostProbableVoxel>,
    /// Smallest valid raw depth of the frame, any range \[m\] (for comparison).
    pub closest_depth_m: Option<f64>,
    /// Pixels with valid depth, and those inside the horizon.
    pub valid_pixels: u64,
    /// Pixels with valid depth inside `[d_min, d_max)`.
    pub in_range_pixels: u64,
    /// Largest per-voxel count.
    pub max_count: u32,
    /// Stage timings.
    pub timings: StageTimings,
    /// [`DepthPerception::fingerprint`] of the perception that made this output: its
    /// states mean voxels of that camera, grid and mounting only.
    pub fingerprint: u64,
}

/// Histogram-mode beliefs below this are left out of the sparse view (the dense belief
/// stays available through [`DepthPerception::belief`]).
pub(super) const SPARSE_BELIEF_THRESHOLD: f64 = 1e-12;

#[derive(Debug, Clone)]
enum Filter {
    Particle(ParticleFilter),
    Histogram(HistogramFilter),
    /// No filter: the belief is the frame's empirical histogram of in-range points.
    Raw,
}

/// APF-PF perception for one depth camera.
#[derive(Debug, Clone)]
pub struct DepthPerception {
    config: PerceptionConfig,
    body_from_camera: Isometry3,
    grid: DepthVoxelGrid,
    /// `None` in raw mode (no filter, nothing to propagate).
    transition: Option<TransitionModel>,
    observation: ObservationModel,
    filter: Filter,
    log_likelihood: Vec<f64>,
    belief: Vec<f64>,
    last_counts: Option<VoxelCounts>,
    transition_build_s: f64,
    frames: u64,
    fingerprint: u64,
}

/// [`DepthPerception::fingerprint`]: SipHash with fixed keys, the same on every run.
fn fingerprint_of(camera: &PinholeCamera, body_from_camera: &Isometry3, config: &PerceptionConfig) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for x in [camera.fx, camera.fy, camera.cx, camera.cy] {
        x.to_bits().hash(&mut h);
    }
    (camera.width, camera.height).hash(&mut h);
    for x in body_from_camera.to_matrix_rows().iter().flatten() {
        x.to_bits().hash(&mut h);
    }
    format!("{:?} {:?}", config.grid, config.apf.voxel_position).hash(&mut h);
    h.finish()
}

impl DepthPerception {
    /// Builds the pipeline: validates, precomputes the transition model and the forces.
    /// The filter's random stream is seeded with `seed`.
    pub fn new(camera: PinholeCamera, body_from_camera: Isometry3, config: PerceptionConfig, seed: u64) -> Result<Self> {
        camera.validate()?;
        config.validate_for_image(camera.width, camera.height)?;
        let grid = DepthVoxelGrid::new(camera, config.grid)?;
        let started = Instant::now();
        let transition = match config.filter.mode {
            FilterMode::Raw => None,
            FilterMode::Particle | FilterMode::Histogram => Some(TransitionModel::new(&grid, &config.transition)?),
        };
        let transition_build_s = started.elapsed().as_secs_f64();
        let observation = ObservationModel::new(&grid, &config.observation);
        let states = grid.state_count();
        let filter = match (config.filter.mode, &transition) {
            (FilterMode::Particle, Some(transition)) => Filter::Particle(ParticleFilter::new(
                transition,
                config.filter.particles,
                config.filter.resampling,
                config.filter.free_proposal_min,
                Pcg64Mcg::seed_from_u64(seed),
            )),
            (FilterMode::Histogram, _) => Filter::Histogram(HistogramFilter::new(states)),
            _ => Filter::Raw,
        };
        let fingerprint = fingerprint_of(&camera, &body_from_camera, &config);
        let mut perception = Self {
            config,
            body_from_camera,
            grid,
            transition,
            observation,
            filter,
            log_likelihood: vec![0.0; states],
            belief: vec![0.0; states],
            last_counts: None,
            transition_build_s,
            frames: 0,
            fingerprint,
        };
        perception.refresh_belief();
        Ok(perception)
    }

    /// The config.
    pub fn config(&self) -> &PerceptionConfig {
        &self.config
    }

    /// The grid (shape, ids, voxel centres).
    pub fn grid(&self) -> &DepthVoxelGrid {
        &self.grid
    }

    /// The transition model (`None` in raw mode).
    pub fn transition(&self) -> Option<&TransitionModel> {
        self.transition.as_ref()
    }

    /// `body_from_camera`.
    pub fn body_from_camera(&self) -> &Isometry3 {
        &self.body_from_camera
    }

    /// A hash of what gives a state its meaning: the camera, its mounting, the grid and the
    /// voxel position. Two perceptions whose states mean the same voxels share it.
    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    /// Seconds spent building the transition model.
    pub fn transition_build_s(&self) -> f64 {
        self.transition_build_s
    }

    /// Frames processed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The dense belief over all states (voxels, then `s_free`).
    pub fn belief(&self) -> &[f64] {
        &self.belief
    }

    /// Per-voxel counts of the last frame.
    pub fn last_counts(&self) -> Option<&VoxelCounts> {
        self.last_counts.as_ref()
    }

    fn refresh_belief(&mut self) {
        match &self.filter {
            Filter::Particle(f) => f.belief(&mut self.belief),
            Filter::Histogram(f) => self.belief.copy_from_slice(f.belief()),
            Filter::Raw => {
                // Before the first frame (and on frames with no point in range): free.
                let free = self.grid.free_state().0 as usize;
                self.belief.fill(0.0);
                match &self.last_counts {
                    Some(c) if c.in_range > 0 => {
                        let total = c.in_range as f64;
                        for (b, &n) in self.belief.iter_mut().zip(&c.counts) {
                            *b = f64::from(n) / total;
                        }
                    }
                    _ => self.belief[free] = 1.0,
                }
            }
        }
    }

    /// Processes one depth frame of the camera's size.
    pub fn update(&mut self, image: DepthImage<'_>, width: u32, height: u32) -> Result<PerceptionOutput> {
        let started = Instant::now();
        let counts = self.grid.count(image, width, height)?;
        let counted = Instant::now();
        match (&mut self.filter, &self.transition) {
            (Filter::Particle(f), Some(t)) => f.propagate(t),
            (Filter::Histogram(f), Some(t)) => f.predict(t),
            _ => {}
        }
        let predicted = Instant::now();
        if !matches!(self.filter, Filter::Raw) {
            self.observation.log_likelihood(&counts, &mut self.log_likelihood);
        }
        match &mut self.filter {
            Filter::Particle(f) => f.weight_and_resample(&self.log_likelihood),
            Filter::Histogram(f) => f.update(&self.log_likelihood),
            Filter::Raw => {}
        }
        let updated = Instant::now();
        let (closest_depth_m, valid_pixels, in_range_pixels, max_count) = (counts.closest_depth_m, counts.valid, counts.in_range, counts.max_count);
        self.last_counts = Some(counts);
        self.refresh_belief();
        let threshold = match self.filter {
            Filter::Particle(_) | Filter::Raw => 0.0,
            Filter::Histogram(_) => SPARSE_BELIEF_THRESHOLD,
        };
        let free = self.grid.free_state().0 as usize;
        let mut belief_states = Vec::new();
        let mut belief_probabilities = Vec::new();
        let mut best: Option<(usize, f64)> = None;
        for (s, &b) in self.belief.iter().enumerate() {
            if b > threshold {
                belief_states.push(StateId(s as u32));
                belief_probabilities.push(b);
            }
            if b > 0.0 && s != free && best.is_none_or(|(_, p)| b > p) {
                best = Some((s, b));
            }
        }
        let most_probable = best.and_then(|(s, probability)| {
            let voxel = self.grid.voxel_of(StateId(s as u32))?;
            let centre_camera = self.grid.voxel_centre_camera(voxel);
            Some(MostProbableVoxel {
                voxel,
                state: StateId(s as u32),
                probability,
                centre_camera,
                centre_body: self.body_from_camera.transform_point(centre_camera),
            })
        });
        let done = Instant::now();
        self.frames += 1;
        let output = PerceptionOutput {
            belief_states,
            belief_probabilities,
            p_free: self.belief[free],
            most_probable,
            closest_depth_m,
            valid_pixels,
            in_range_pixels,
            max_count,
            timings: StageTimings {
                count_s: (counted - started).as_secs_f64(),
                predict_s: (predicted - counted).as_secs_f64(),
                update_s: (updated - predicted).as_secs_f64(),
                belief_s: (done - updated).as_secs_f64(),
                total_s: (done - started).as_secs_f64(),
            },
            fingerprint: self.fingerprint,
        };
        Ok(output)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw_perception() -> DepthPerception {
        let mut config = PerceptionConfig::flight();
        config.filter.mode = FilterMode::Raw;
        DepthPerception::new(PinholeCamera::d435(), Isometry3::body_from_forward_optical(), config, 0).unwrap()
    }

    #[test]
    fn raw_mode_belief_is_the_frame_histogram() {
        let mut p = raw_perception();
        assert!(p.transition().is_none(), "raw mode builds no transition model");
        let (w, h) = (640usize, 480usize);
        // 100 pixels at 0.55 m in the top-left block, 300 at 0.95 m in the centre, the
        // rest beyond the horizon (valid but out of range).
        let mut image = vec![5000u16; w * h];
        for r in 0..10 {
            for c in 0..10 {
                image[r * w + c] = 550;
            }
        }
        for r in 230..245 {
            for c in 310..330 {
                image[r * w + c] = 950;
            }
        }
        let out = p.update(DepthImage::U16 { pixels: &image, scale_m_per_unit: 0.001 }, 640, 480).unwrap();
        assert_eq!(out.in_range_pixels, 400);
        assert_eq!(out.p_free, 0.0);
        let total: f64 = out.belief_probabilities.iter().sum();
        assert!((total - 1.0).abs() < 1e-12);
        let counts = p.last_counts().unwrap();
        for (s, &n) in counts.counts.iter().enumerate() {
            assert_eq!(p.belief()[s], f64::from(n) / 400.0, "state {s}");
        }
        let best = out.most_probable.unwrap();
        assert!((best.centre_camera.z - 0.95).abs() <= 0.05 + 1e-9, "the 300-pixel patch wins: {best:?}");
        // Memoryless: an empty frame next is free at once (a filter would remember).
        let empty = vec![0u16; w * h];
        let out = p.update(DepthImage::U16 { pixels: &empty, scale_m_per_unit: 0.001 }, 640, 480).unwrap();
        assert_eq!(out.p_free, 1.0);
        assert!(out.most_probable.is_none());
    }

    /// `frames` of 640x480 D435 images: a wall patch at 0.6 m over blocks 5-7 x 4-5 (whole
    /// 50 px blocks, 15 000 pixels), or no return anywhere; `P(free)` after each.
    fn p_free_trace(config: PerceptionConfig, seed: u64, frames: &[bool]) -> Vec<f64> {
        let mut p = DepthPerception::new(PinholeCamera::d435(), Isometry3::body_from_forward_optical(), config, seed).unwrap();
        let (w, h) = (640usize, 480usize);
        let mut wall = vec![0u16; w * h];
        for r in 200..300 {
            for c in 250..400 {
                wall[r * w + c] = 600;
            }
        }
        let empty = vec![0u16; w * h];
        frames
            .iter()
            .map(|&obstacle| {
                let pixels = if obstacle { &wall } else { &empty };
                p.update(DepthImage::U16 { pixels, scale_m_per_unit: 0.001 }, 640, 480).unwrap().p_free
            })
            .collect()
    }

    /// 20 frames with the wall, 40 empty, 20 with the wall.
    fn wall_empty_wall() -> Vec<bool> {
        [vec![true; 20], vec![false; 40], vec![true; 20]].concat()
    }

    #[test]
    fn paper_filter_with_free_state_at_depth_zero_believes_empty_frames_free() {
        // The paper's filter (no extra proposal, multinomial) with the authors' free state
        // at depth 0: about 90 of 20 000 particles reach s_free per frame, so P(free) is 1 on
        // every empty frame, the first included, and 0 once the wall is back.
        let config = PerceptionConfig::acc2021();
        assert_eq!((config.filter.free_proposal_min, config.filter.resampling), (0.0, crate::config::Resampling::Multinomial));
        for seed in 0..3 {
            let trace = p_free_trace(config, seed, &wall_empty_wall());
            assert!(trace[1..20].iter().all(|&f| f < 1e-9), "seed {seed}: wall frames {:?}", &trace[..20]);
            assert!(trace[20..60].iter().all(|&f| f > 0.99), "seed {seed}: empty frames {:?}", &trace[20..60]);
            assert!(trace[61..].iter().all(|&f| f < 1e-9), "seed {seed}: wall again {:?}", &trace[60..]);
        }
    }

    #[test]
    fn paper_filter_with_free_state_at_the_horizon_flips_on_empty_frames() {
        // The same filter with s_free at d_max (factor e^-4.5): ~1 particle reaches it per
        // frame, so on empty frames P(free) jumps between 0 and 1 (the regression the
        // `free_proposal_min` proposal of `flight` hides).
        let mut config = PerceptionConfig::acc2021();
        config.transition.free_state_depth = crate::config::FreeStateDepth::Horizon;
        let trace = p_free_trace(config, 0, &wall_empty_wall());
        let empty = &trace[20..60];
        let free = empty.iter().filter(|&&f| f > 0.5).count();
        assert!((5..=35).contains(&free), "{free} of 40 empty frames believed free: {empty:?}");
        assert!(trace[61..].iter().all(|&f| f < 1e-9));
        // With subterra's defensive proposal (the `flight` preset) it holds 1 again.
        let mut config = PerceptionConfig::flight();
        config.filter.resampling = crate::config::Resampling::Multinomial;
        let trace = p_free_trace(config, 0, &wall_empty_wall());
        assert!(trace[20..60].iter().all(|&f| f > 0.99), "{:?}", &trace[20..60]);
    }
}
