//! The drone's loop, wired once: depth frames, odometry and a goal in the world become a
//! velocity command. `subterra fly`, `perceive`, `replay` and a live node all call this.
//!
//! Documented on [`Pilot`].

use std::time::Instant;

use glam::DVec3;

use super::carrot::PathFollower;
use super::escape::{Escape, EscapeOutput};
use super::forces::BeliefForces;
use super::memory::ObstacleMemory;
use super::qmdp::{Qmdp, QmdpConfig};
use super::{ApfController, Command};
use crate::camera::PinholeCamera;
use crate::config::{FilterMode, PerceptionConfig};
use crate::depth::{DepthImage, DepthPerception, PerceptionOutput};
use crate::error::{Error, Result};
use crate::frames::Isometry3;

/// At most this many cameras on one pilot (each holds a filter and a transition model).
pub const MAX_CAMERAS: usize = 8;

/// The controllers a pilot runs, by name: each picks a filter mode and how the belief
/// pushes. `raw-apf` is the baseline the APF-PF paper argues against (the same voxels and
/// potentials over each frame's raw histogram: no filter).
pub const CONTROLLER_NAMES: [&str; 4] = ["apf-pf", "apf-pf-histogram", "apf-pf-qmdp", "raw-apf"];

/// The filter mode and controller of a name of [`CONTROLLER_NAMES`].
pub fn controller_named(name: &str) -> Result<(FilterMode, PilotController)> {
    match name {
        "apf-pf" => Ok((FilterMode::Particle, PilotController::Apf)),
        "apf-pf-histogram" => Ok((FilterMode::Histogram, PilotController::Apf)),
        "apf-pf-qmdp" => Ok((FilterMode::Particle, PilotController::Qmdp)),
        "raw-apf" => Ok((FilterMode::Raw, PilotController::Apf)),
        _ => Err(Error::input("controller", format!("must be one of {}, got {name:?}", CONTROLLER_NAMES.join(", ")))),
    }
}

/// How the belief pushes the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PilotController {
    /// The belief-weighted repulsive force (APF-PF paper §IV).
    #[default]
    Apf,
    /// The QMDP action over the belief in the force's place (the authors' follow-up).
    Qmdp,
}

/// One camera of the pilot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PilotCamera {
    /// Intrinsics and image size.
    pub camera: PinholeCamera,
    /// Its mounting.
    pub body_from_camera: Isometry3,
}

/// Wall-clock time of one [`Pilot::step`] \[s\].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PilotTimings {
    /// The cameras' filters (step 2).
    pub perception_s: f64,
    /// Steps 3-6: forces or QMDP, memory, escape and the command.
    pub control_s: f64,
    /// The whole step.
    pub total_s: f64,
}

/// What one [`Pilot::step`] gives.
#[derive(Debug, Clone, PartialEq)]
pub struct PilotOutput {
    /// The command.
    pub command: Command,
    /// Each camera's perception output, in camera order.
    pub perceptions: Vec<PerceptionOutput>,
    /// Each camera's belief-weighted repulsion, body frame \[N\] (computed with QMDP too).
    pub belief_repulsive_body: Vec<DVec3>,
    /// The point the attraction pulled toward before the escape (goal or carrot), world \[m\].
    pub target_world: DVec3,
    /// Distance still to go (straight, or along the path) \[m\].
    pub remaining_m: f64,
    /// The belief's push, body frame: summed repulsion \[N\], or the QMDP velocity [m/s].
    pub belief_push_body: DVec3,
    /// The memories' summed repulsion, body frame \[N\] (zero without a memory).
    pub memory_repulsive_body: DVec3,
    /// Cells the memories hold after the step (0 without a memory).
    pub memory_cells: usize,
    /// The escape's output (None when the config leaves the escape off).
    pub escape: Option<EscapeOutput>,
    /// The goal the command pulled toward, body frame \[m\].
    pub goal_body: DVec3,
    /// The repulsion the command used, body frame \[N\].
    pub repulsive_body: DVec3,
    /// Step timings.
    pub timings: PilotTimings,
}

#[derive(Debug, Clone)]
struct CameraChain {
    perception: DepthPerception,
    forces: BeliefForces,
    memory: Option<ObstacleMemory>,
}

#[derive(Debug, Clone)]
enum Goal {
    Point(DVec3),
    Path(PathFollower),
}

/// The drone's perception and control.
///
/// In: one depth frame per camera, the time stamp and the odometry pose `world_from_body`.
/// Out: a [`Command`] with everything that made it ([`PilotOutput`]).
///
/// # One step, exactly
/// 1. **Goal.** The point the attraction pulls toward: the goal, or with a path the carrot
///    `lookahead_m` ahead along it ([`PathFollower`]); and the distance still to go.
/// 2. **Perceive.** Each camera's filter takes its frame ([`DepthPerception::update`]).
/// 3. **Belief's push.** Per camera, the belief-weighted repulsion ([`BeliefForces`]), or
///    with the QMDP controller the chosen evasive velocity in its place ([`Qmdp`]); summed
///    over the cameras in their order.
/// 4. **Memory.** With `memory.enabled`, each camera's [`ObstacleMemory`] records its belief
///    (and, with `memory.guard_sigmas`, the frame's near-field counts) at the pose and adds
///    its repulsion.
/// 5. **Escape.** With `escape.enabled`, [`Escape`] watches the progress and, in a local
///    minimum, follows the remembered obstacles' boundary: it may replace the goal and cap
///    the repulsion.
/// 6. **Command.** [`ApfController::command`] (eq. 10) toward the goal in the body frame.
///
/// Several cameras each keep their own filter and memory; their forces add in the body
/// frame (the authors flew a forward and an upward camera). The QMDP controller scores one
/// camera's belief: it takes exactly one camera.
#[derive(Debug, Clone)]
pub struct Pilot {
    config: PerceptionConfig,
    cameras: Vec<CameraChain>,
    qmdp: Option<Qmdp>,
    escape: Option<Escape>,
    controller: ApfController,
    goal: Option<Goal>,
    steps: u64,
}

impl Pilot {
    /// A pilot over `cameras` (1 to [`MAX_CAMERAS`]) with `config` (validated here; its
    /// `filter.mode` picks particle, histogram or raw, its `memory.enabled` and
    /// `escape.enabled` switch those parts on). Camera `n`'s filter is seeded with
    /// `seed + n`. `qmdp` is used by [`PilotController::Qmdp`] only.
    pub fn new(config: PerceptionConfig, cameras: &[PilotCamera], controller: PilotController, qmdp: QmdpConfig, seed: u64) -> Result<Self> {
        if cameras.is_empty() || cameras.len() > MAX_CAMERAS {
            return Err(Error::input("cameras", format!("must hold 1 to {MAX_CAMERAS} cameras, got {}", cameras.len())));
        }
        if controller == PilotController::Qmdp && cameras.len() != 1 {
            return Err(Error::input("cameras", format!("the QMDP controller scores one camera's belief: give exactly one camera, got {}", cameras.len())));
        }
        config.validate()?;
        let mut chains = Vec::with_capacity(cameras.len());
        for (n, c) in cameras.iter().enumerate() {
            let perception = DepthPerception::new(c.camera, c.body_from_camera, config, seed.wrapping_add(n as u64))?;
            let forces = BeliefForces::new(&perception);
            let memory = if config.memory.enabled { Some(ObstacleMemory::new(&perception)?) } else { None };
            chains.push(CameraChain { perception, forces, memory });
        }
        let qmdp = match controller {
            PilotController::Qmdp => Some(Qmdp::new(&chains[0].perception, qmdp)?),
            PilotController::Apf => None,
        };
        let escape = if config.escape.enabled { Some(Escape::new(config.escape, &config.apf)?) } else { None };
        Ok(Self { config, cameras: chains, qmdp, escape, controller: ApfController::new(config.apf), goal: None, steps: 0 })
    }

    /// The config.
    pub fn config(&self) -> &PerceptionConfig {
        &self.config
    }

    /// The cameras' perceptions, in camera order.
    pub fn perceptions(&self) -> impl ExactSizeIterator<Item = &DepthPerception> {
        self.cameras.iter().map(|c| &c.perception)
    }

    /// Camera `n`'s belief forces.
    pub fn forces(&self, n: usize) -> Option<&BeliefForces> {
        self.cameras.get(n).map(|c| &c.forces)
    }

    /// Every remembered obstacle point, world frame \[m\], camera by camera.
    pub fn memory_points_world(&self) -> Vec<DVec3> {
        self.cameras.iter().filter_map(|c| c.memory.as_ref()).flat_map(|m| m.obstacles().map(|o| o.point_world)).collect()
    }

    /// Whether the config runs an obstacle memory.
    pub fn has_memory(&self) -> bool {
        self.config.memory.enabled
    }

    /// Steps taken since the pilot was built.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Flies to `goal_world` \[m\] (drops a path).
    pub fn set_goal(&mut self, goal_world: DVec3) -> Result<()> {
        crate::frames::check_position("goal_world", &goal_world.to_array())?;
        self.goal = Some(Goal::Point(goal_world));
        Ok(())
    }

    /// Follows `points_world` (at least two, the last the goal) with a carrot
    /// `lookahead_m` ahead.
    pub fn set_path(&mut self, points_world: &[DVec3], lookahead_m: f64) -> Result<()> {
        self.goal = Some(Goal::Path(PathFollower::new(points_world, lookahead_m)?));
        Ok(())
    }

    /// Length of the way to go when set: the path's length, or `None` for a point goal.
    pub fn path_length_m(&self) -> Option<f64> {
        match &self.goal {
            Some(Goal::Path(f)) => Some(f.length_m()),
            _ => None,
        }
    }

    /// Forgets the memories and the escape's progress (odometry that jumped, a new flight);
    /// the filters keep their belief.
    pub fn reset(&mut self) {
        for c in &mut self.cameras {
            if let Some(m) = c.memory.as_mut() {
                m.reset();
            }
        }
        if let Some(e) = self.escape.as_mut() {
            e.reset();
        }
    }

    /// Sets the odometry confidence in [0, 1] the obstacle memories forget with from the
    /// next step on ([`ObstacleMemory::set_confidence`]; 1 by default).
    pub fn set_odometry_confidence(&mut self, confidence: f64) -> Result<()> {
        if !(confidence.is_finite() && (0.0..=1.0).contains(&confidence)) {
            return Err(Error::input("confidence", format!("must be in [0, 1], got {confidence}")));
        }
        for c in &mut self.cameras {
            if let Some(m) = c.memory.as_mut() {
                m.set_confidence(confidence)?;
            }
        }
        Ok(())
    }

    /// One control step (see [`Pilot`]): `frames[n]` is camera `n`'s image of its size,
    /// taken at `stamp_s` \[s\] with the odometry pose `world_from_body`.
    pub fn step(&mut self, frames: &[DepthImage<'_>], stamp_s: f64, world_from_body: &Isometry3) -> Result<PilotOutput> {
        let started = Instant::now();
        if frames.len() != self.cameras.len() {
            return Err(Error::input("frames", format!("must hold one image per camera ({}), got {}", self.cameras.len(), frames.len())));
        }
        crate::frames::check_stamp("stamp", stamp_s)?;
        if !(world_from_body.translation.is_finite() && world_from_body.rotation.is_finite()) {
            return Err(Error::input("world_from_body", "must be finite"));
        }
        let position = world_from_body.translation;
        // 1. Goal.
        let (target_world, remaining_m) = match self.goal.as_mut() {
            None => return Err(Error::input("goal", "no goal: call set_goal or set_path before step")),
            Some(Goal::Point(g)) => (*g, (*g - position).length()),
            Some(Goal::Path(f)) => {
                let c = f.update(position)?;
                (c.carrot_world, c.remaining_m)
            }
        };
        // 2. Perceive.
        let mut perceptions = Vec::with_capacity(frames.len());
        for (chain, image) in self.cameras.iter_mut().zip(frames) {
            let camera = chain.perception.grid().camera();
            let (width, height) = (camera.width, camera.height);
            perceptions.push(chain.perception.update(*image, width, height)?);
        }
        let perceived = Instant::now();
        // 3. Belief's push.
        let belief_repulsive_body: Vec<DVec3> = self.cameras.iter().map(|c| c.forces.repulsive(c.perception.belief())).collect();
        let belief_push_body = match self.qmdp.as_mut() {
            Some(q) => q.act(&perceptions[0])?.velocity_body,
            None => belief_repulsive_body.iter().fold(DVec3::ZERO, |sum, f| sum + *f),
        };
        // 4. Memory.
        let mut memory_repulsive_body = DVec3::ZERO;
        let mut memory_cells = 0;
        for (chain, out) in self.cameras.iter_mut().zip(&perceptions) {
            if let Some(m) = chain.memory.as_mut() {
                let remembered = m.update(out, chain.perception.last_counts(), stamp_s, world_from_body)?;
                memory_repulsive_body += remembered.repulsive_body;
                memory_cells += remembered.cells;
            }
        }
        let mut repulsive_body = if self.config.memory.enabled { belief_push_body + memory_repulsive_body } else { belief_push_body };
        // 5. Escape.
        let mut goal_body = world_from_body.rotation.transpose() * (target_world - position);
        let points = if self.escape.is_some() { self.memory_points_world() } else { Vec::new() };
        let escape = match self.escape.as_mut() {
            None => None,
            Some(e) => {
                let out = e.step(stamp_s, world_from_body, target_world, remaining_m, &points, repulsive_body)?;
                goal_body = out.goal_body;
                repulsive_body = out.repulsive_body;
                Some(out)
            }
        };
        // 6. Command.
        let command = self.controller.command(goal_body, repulsive_body)?;
        self.steps += 1;
        let done = Instant::now();
        Ok(PilotOutput {
            command,
            perceptions,
            belief_repulsive_body,
            target_world,
            remaining_m,
            belief_push_body,
            memory_repulsive_body,
            memory_cells,
            escape,
            goal_body,
            repulsive_body,
            timings: PilotTimings {
                perception_s: (perceived - started).as_secs_f64(),
                control_s: (done - perceived).as_secs_f64(),
                total_s: (done - started).as_secs_f64(),
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PilotCamera {
        PilotCamera { camera: PinholeCamera::d435(), body_from_camera: Isometry3::body_from_forward_optical() }
    }

    fn config(preset: &str) -> PerceptionConfig {
        let mut c = PerceptionConfig::preset(preset).unwrap();
        c.filter.particles = 2000;
        c
    }

    /// A wall patch `depth_mm` ahead, slightly left of the image centre.
    fn frame(depth_mm: u16) -> Vec<u16> {
        let mut depth = vec![0u16; 640 * 480];
        for v in 180..300 {
            for u in 250..330 {
                depth[v * 640 + u] = depth_mm;
            }
        }
        depth
    }

    fn pose(x: f64) -> Isometry3 {
        Isometry3 { translation: DVec3::new(x, 0.0, 1.0), ..Isometry3::default() }
    }

    #[test]
    fn the_pilot_is_the_chain_of_its_parts() {
        // The same steps composed by hand give the same bits.
        let config = config("flight-escape");
        assert!(config.memory.enabled && config.escape.enabled);
        let mut pilot = Pilot::new(config, &[camera()], PilotController::Apf, QmdpConfig::default(), 3).unwrap();
        pilot.set_goal(DVec3::new(8.0, 0.5, 1.0)).unwrap();
        let c = camera();
        let mut perception = DepthPerception::new(c.camera, c.body_from_camera, config, 3).unwrap();
        let forces = BeliefForces::new(&perception);
        let mut memory = ObstacleMemory::new(&perception).unwrap();
        let mut escape = Escape::new(config.escape, &config.apf).unwrap();
        let controller = ApfController::new(config.apf);
        for n in 0..12 {
            let depth = frame(if n < 6 { 900 } else { 0 });
            let image = DepthImage::U16 { pixels: &depth, scale_m_per_unit: 0.001 };
            let (stamp, at) = (n as f64 / 15.0, pose(0.02 * n as f64));
            let got = pilot.step(&[image], stamp, &at).unwrap();
            let out = perception.update(image, 640, 480).unwrap();
            let push = forces.repulsive(perception.belief());
            let remembered = memory.update(&out, perception.last_counts(), stamp, &at).unwrap();
            let points: Vec<DVec3> = memory.obstacles().map(|o| o.point_world).collect();
            let goal = DVec3::new(8.0, 0.5, 1.0);
            let e = escape.step(stamp, &at, goal, (goal - at.translation).length(), &points, push + remembered.repulsive_body).unwrap();
            let command = controller.command(e.goal_body, e.repulsive_body).unwrap();
            assert_eq!(got.perceptions[0].belief_states, out.belief_states);
            assert_eq!(got.belief_push_body, push);
            assert_eq!(got.memory_repulsive_body, remembered.repulsive_body);
            assert_eq!(got.command, command, "step {n}");
            if n < 6 {
                assert!(got.belief_push_body.x < 0.0, "a wall ahead pushes back: {}", got.belief_push_body);
            }
        }
        assert!(!pilot.memory_points_world().is_empty(), "the memory kept the wall");
    }

    #[test]
    fn a_path_is_followed_with_a_carrot_and_the_remaining_distance_runs_along_it() {
        let mut pilot = Pilot::new(config("flight"), &[camera()], PilotController::Apf, QmdpConfig::default(), 0).unwrap();
        let path = [DVec3::new(0.0, 0.0, 1.0), DVec3::new(4.0, 0.0, 1.0), DVec3::new(4.0, 4.0, 1.0)];
        pilot.set_path(&path, 1.5).unwrap();
        assert_eq!(pilot.path_length_m(), Some(8.0));
        let depth = frame(0);
        let out = pilot.step(&[DepthImage::U16 { pixels: &depth, scale_m_per_unit: 0.001 }], 0.0, &pose(0.0)).unwrap();
        assert!((out.target_world - DVec3::new(1.5, 0.0, 1.0)).length() < 1e-9, "{}", out.target_world);
        assert!((out.remaining_m - 8.0).abs() < 1e-9, "{}", out.remaining_m);
        assert!(out.command.v_x_m_s > 0.0 && out.escape.is_none() && out.memory_cells == 0);
    }

    #[test]
    fn two_cameras_add_their_forces_and_qmdp_takes_one() {
        let up = PilotCamera { camera: PinholeCamera::d435(), body_from_camera: Isometry3::body_from_upward_optical() };
        let mut config = config("flight");
        config.filter.mode = FilterMode::Raw;
        let mut pilot = Pilot::new(config, &[camera(), up], PilotController::Apf, QmdpConfig::default(), 0).unwrap();
        pilot.set_goal(DVec3::new(5.0, 0.0, 1.0)).unwrap();
        let (wall, empty) = (frame(800), frame(0));
        fn u16(d: &[u16]) -> DepthImage<'_> {
            DepthImage::U16 { pixels: d, scale_m_per_unit: 0.001 }
        }
        let ahead = pilot.step(&[u16(&wall), u16(&empty)], 0.0, &pose(0.0)).unwrap();
        let above = pilot.step(&[u16(&empty), u16(&wall)], 0.1, &pose(0.0)).unwrap();
        let a = ahead.belief_push_body;
        assert!(a.x < 0.0 && a.z.abs() < 0.1 * a.x.abs(), "a wall ahead pushes back: {a}");
        assert!(above.belief_push_body.z < 0.0, "a ceiling pushes down: {}", above.belief_push_body);
        let err = pilot.step(&[u16(&wall)], 0.2, &pose(0.0)).unwrap_err();
        assert!(err.to_string().contains("frames"), "{err}");
        let err = Pilot::new(config, &[camera(), up], PilotController::Qmdp, QmdpConfig::default(), 0).unwrap_err();
        assert!(err.to_string().contains("cameras"), "{err}");
    }

    #[test]
    fn a_step_without_a_goal_is_an_error_naming_it() {
        let mut pilot = Pilot::new(config("flight"), &[camera()], PilotController::Apf, QmdpConfig::default(), 0).unwrap();
        let depth = frame(0);
        let err = pilot.step(&[DepthImage::U16 { pixels: &depth, scale_m_per_unit: 0.001 }], 0.0, &pose(0.0)).unwrap_err();
        assert!(err.to_string().contains("goal"), "{err}");
    }
}
