//! QMDP action selection over the particle belief (the APF-PF authors' follow-up; their
//! code's `output_qmdp` mode): instead of the belief-weighted repulsive *force*, a discrete
//! set of evasive velocities is scored by its expected reward under the belief, and the
//! best one takes the force's place beside the goal's attraction.
//!
//! Documented on [`Qmdp`].

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::depth::{DepthPerception, PerceptionOutput};
use crate::error::{Error, Result};

/// Most actions per axis.
pub(super) const MAX_ACTIONS_PER_AXIS: usize = 101;
/// Most actions in all.
pub(super) const MAX_ACTIONS: usize = 4096;
/// Most look-ahead steps.
pub(super) const MAX_LOOKAHEAD_STEPS: usize = 100;
/// Most entries of the reward table (states x actions; 8 bytes each).
pub(super) const MAX_TABLE_ENTRIES: usize = 1 << 24;

/// The QMDP controller's settings. The defaults are the authors' (`qmdp_ral.yaml`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QmdpConfig {
    /// Lowest action per axis `(v_x, v_y, v_z)` [m/s]. Authors: `[-0.8, -0.8, -0.8]`.
    pub action_min_m_s: [f64; 3],
    /// Highest action per axis [m/s]. Authors: `[0.0, 0.8, 0.8]`.
    pub action_max_m_s: [f64; 3],
    /// Spacing of the actions per axis [m/s]. Authors: `[0.2, 0.2, 0.2]`.
    pub action_step_m_s: [f64; 3],
    /// `q_i`: cost of each axis' speed squared [1/(m/s)²]. Authors' `reward_Q`: `[0.7, 0.7, 0.7]`.
    pub action_cost: [f64; 3],
    /// `g`: the potential's gain. Authors' `repulsive_potential_gain`: 2.
    pub potential_gain: f64,
    /// `ρ`: the potential's range \[m\]. Authors' `repulsive_potential_max_distance`: 1.4.
    pub potential_range_m: f64,
    /// `|x|` is clamped below at this in the potential \[m\]. Authors' `min_distance`: 0.1.
    pub min_distance_m: f64,
    /// Look-ahead over which an action's reward is summed \[s\]. Authors: 0.5.
    pub lookahead_s: f64,
    /// `Δt` between the look-ahead's samples \[s\]. Authors' `sampling_time`: 0.1.
    pub step_s: f64,
}

impl Default for QmdpConfig {
    fn default() -> Self {
        Self {
            action_min_m_s: [-0.8, -0.8, -0.8],
            action_max_m_s: [0.0, 0.8, 0.8],
            action_step_m_s: [0.2, 0.2, 0.2],
            action_cost: [0.7, 0.7, 0.7],
            potential_gain: 2.0,
            potential_range_m: 1.4,
            min_distance_m: 0.1,
            lookahead_s: 0.5,
            step_s: 0.1,
        }
    }
}

fn axis_name(i: usize) -> &'static str {
    ["v_x", "v_y", "v_z"][i]
}

impl QmdpConfig {
    /// Checks every field; errors name it (`action_step_m_s`, ...).
    pub fn validate(&self) -> Result<()> {
        for i in 0..3 {
            let (lo, hi, step, q) = (self.action_min_m_s[i], self.action_max_m_s[i], self.action_step_m_s[i], self.action_cost[i]);
            if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo.abs() <= 100.0 && hi.abs() <= 100.0) {
                return Err(Error::config(
                    "action_min_m_s",
                    format!("{} must be finite, within ±100 m/s, and at most action_max_m_s = {hi}", axis_name(i)),
                    lo,
                ));
            }
            if !(step.is_finite() && step > 0.0) {
                return Err(Error::config("action_step_m_s", format!("{} must be finite and > 0", axis_name(i)), step));
            }
            if axis_count(lo, hi, step) > MAX_ACTIONS_PER_AXIS {
                return Err(Error::config(
                    "action_step_m_s",
                    format!("{} gives more than {MAX_ACTIONS_PER_AXIS} actions over [{lo}, {hi}] m/s", axis_name(i)),
                    step,
                ));
            }
            if !(q.is_finite() && (0.0..=1e6).contains(&q)) {
                return Err(Error::config("action_cost", format!("{} must be in [0, 1e6]", axis_name(i)), q));
            }
        }
        let total: usize = (0..3).map(|i| axis_count(self.action_min_m_s[i], self.action_max_m_s[i], self.action_step_m_s[i])).product();
        if total > MAX_ACTIONS {
            return Err(Error::config("action_step_m_s", format!("gives {total} actions; at most {MAX_ACTIONS}"), self.action_step_m_s[0]));
        }
        if !(self.potential_gain.is_finite() && self.potential_gain > 0.0 && self.potential_gain <= 1e6) {
            return Err(Error::config("potential_gain", "must be in (0, 1e6]", self.potential_gain));
        }
        if !(self.potential_range_m.is_finite() && self.potential_range_m > 0.0 && self.potential_range_m <= 100.0) {
            return Err(Error::config("potential_range_m", "must be in (0, 100] m", self.potential_range_m));
        }
        if !(self.min_distance_m.is_finite() && self.min_distance_m > 0.0 && self.min_distance_m < self.potential_range_m) {
            return Err(Error::config("min_distance_m", format!("must be in (0, potential_range_m = {}) m", self.potential_range_m), self.min_distance_m));
        }
        if !(self.step_s.is_finite() && self.step_s > 0.0 && self.step_s <= 10.0) {
            return Err(Error::config("step_s", "must be in (0, 10] s", self.step_s));
        }
        if !(self.lookahead_s.is_finite() && self.lookahead_s >= 0.0 && self.lookahead_s / self.step_s <= MAX_LOOKAHEAD_STEPS as f64) {
            return Err(Error::config("lookahead_s", format!("must be in [0, {MAX_LOOKAHEAD_STEPS}·step_s] s"), self.lookahead_s));
        }
        Ok(())
    }
}

/// Actions on one axis: `min + i·step` for `i = 0, 1, ...` up to `max` (a hair of rounding
/// allowed, so that `(0 - -0.8) / 0.2` counts 5, not 4).
fn axis_count(lo: f64, hi: f64, step: f64) -> usize {
    let n = ((hi - lo) / step + 1e-9).floor();
    if n.is_finite() && n < (MAX_ACTIONS_PER_AXIS * 2) as f64 { n as usize + 1 } else { usize::MAX }
}

/// The action set in the order the choice breaks ties: `v_x` slowest-varying, `v_z`
/// fastest, then `0` when the grid misses it. Values within 1e-9 of 0 are 0.
pub(super) fn actions(config: &QmdpConfig) -> Vec<DVec3> {
    let axis = |i: usize| -> Vec<f64> {
        let (lo, step) = (config.action_min_m_s[i], config.action_step_m_s[i]);
        (0..axis_count(lo, config.action_max_m_s[i], step))
            .map(|k| {
                let v = lo + k as f64 * step;
                if v.abs() < 1e-9 { 0.0 } else { v }
            })
            .collect()
    };
    let (xs, ys, zs) = (axis(0), axis(1), axis(2));
    let mut out = Vec::with_capacity(xs.len() * ys.len() * zs.len() + 1);
    for &x in &xs {
        for &y in &ys {
            for &z in &zs {
                out.push(DVec3::new(x, y, z));
            }
        }
    }
    if !out.contains(&DVec3::ZERO) {
        out.push(DVec3::ZERO);
    }
    out
}

/// `U(x) = ½·g·(1/|x| - 1/ρ)²` within `ρ`, 0 beyond; `|x|` clamped below at `min_distance_m`.
pub(super) fn potential(config: &QmdpConfig, x_body: DVec3) -> f64 {
    let d = x_body.length().max(config.min_distance_m);
    if d >= config.potential_range_m {
        return 0.0;
    }
    let k = 1.0 / d - 1.0 / config.potential_range_m;
    0.5 * config.potential_gain * k * k
}

/// What one [`Qmdp::act`] gives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QmdpAction {
    /// The chosen evasive velocity in the body frame [m/s].
    pub velocity_body: DVec3,
    /// Its index in [`Qmdp::actions`].
    pub index: usize,
    /// Its expected reward `Σ_s b(s)·R(s, a*)`.
    pub value: f64,
}

/// The QMDP controller of one perception: the reward table and the choice.
///
/// In: the voxel points of one [`DepthPerception`] (the points its forces come from,
/// `apf.voxel_position`, in the body frame) and each frame's [`PerceptionOutput`]. Out: a
/// [`QmdpAction`], an evasive velocity in the body frame [m/s] that
/// [`ApfController::command`](super::ApfController::command) adds to the attraction in place
/// of the repulsive force (the authors' `goal_to_vel` node adds the two the same way).
///
/// # The model, exactly
/// - **Actions** `a = (v_x, v_y, v_z)`: every point of the grid `min + i·step <= max` per
///   axis (the authors: `v_x` in [-0.8, 0], `v_y`, `v_z` in [-0.8, 0.8], steps of 0.2; a
///   robot can back off, not charge), plus `a = 0` when the grid misses it: 5 x 9 x 9 = 405.
/// - **Motion**: holonomic, for the look-ahead only: after `t` seconds an obstacle at the
///   body-frame point `p` is at `p - a·t` (the authors' `apply_action`, holonomic case).
/// - **Reward** of action `a` when the obstacle is in state `s` (a voxel at `p_s`):
///   `R(s, a) = -Σ_i q_i·a_i² - Σ_{k=0..K} U(p_s - a·k·Δt)`, `K = lookahead_s / step_s`,
///   with the potential `U(x) = ½·g·(1/|x| - 1/ρ)²` within `ρ`, zero beyond (`|x|`
///   clamped below at `min_distance_m`, so that it stays finite). The free state repels
///   nothing: `R(s_free, a) = -Σ_i q_i·a_i²`.
/// - **Choice**: `a* = argmax_a Σ_s b(s)·R(s, a)`, the first of equals in the order above.
///
/// Why the expected *reward* is the QMDP choice here: QMDP picks `argmax_a Σ_s b(s)·Q(s, a)`
/// with `Q` the fully observed MDP's action values, which the authors compute by value
/// iteration, `Q ← R + γ·T·max_a Q`. The belief's transition `T` (the obstacle's motion
/// model) does not depend on the action, so every iteration adds the same vector
/// `γ·T·max_a Q` to every action's column: `Q(·, a) - Q(·, a') = R(·, a) - R(·, a')` after
/// any number of iterations, and the choice is the reward's. (A test checks it against 20
/// iterations of the authors' recursion.) The table `R` is computed once, when the
/// controller is made; a frame costs one pass over the belief's states.
///
/// [`DepthPerception`]: crate::depth::DepthPerception
/// [`PerceptionOutput`]: crate::depth::PerceptionOutput
#[derive(Debug, Clone)]
pub struct Qmdp {
    config: QmdpConfig,
    actions: Vec<DVec3>,
    /// `R(s, a)` at `reward[s·A + a]`, states as the perception numbers them (free last).
    reward: Vec<f64>,
    states: usize,
    fingerprint: u64,
    scratch: Vec<f64>,
}

impl Qmdp {
    /// The controller for `perception`'s states, their points taken as its forces take
    /// them (`apf.voxel_position`, body frame).
    pub fn new(perception: &DepthPerception, config: QmdpConfig) -> Result<Self> {
        let grid = perception.grid();
        let body_from_camera = perception.body_from_camera();
        let position = perception.config().apf.voxel_position;
        let points: Vec<DVec3> = (0..grid.voxel_count() as u32)
            .map(|s| {
                let v = grid.voxel_of(crate::depth::StateId(s)).expect("every id below voxel_count is a voxel");
                body_from_camera.transform_point(grid.voxel_point_camera(v, position))
            })
            .collect();
        Self::from_points(&points, config, perception.fingerprint())
    }

    /// The controller over the voxel states at `points_body` (state `i` at `points_body[i]`)
    /// and one free state after them; `fingerprint` is that of the perception whose
    /// outputs [`act`](Self::act) takes.
    pub fn from_points(points_body: &[DVec3], config: QmdpConfig, fingerprint: u64) -> Result<Self> {
        config.validate()?;
        if let Some(i) = points_body.iter().position(|p| !p.is_finite()) {
            return Err(Error::input("points_body", format!("point {i} is not finite")));
        }
        let actions = actions(&config);
        let states = points_body.len() + 1;
        let entries = states.checked_mul(actions.len()).filter(|&n| n <= MAX_TABLE_ENTRIES).ok_or_else(|| {
            Error::config(
                "action_step_m_s",
                format!("{states} states x {} actions pass the reward table's {MAX_TABLE_ENTRIES} entries", actions.len()),
                config.action_step_m_s[0],
            )
        })?;
        let steps = (config.lookahead_s / config.step_s + 1e-9).floor() as usize;
        let q = DVec3::from_array(config.action_cost);
        let cost: Vec<f64> = actions.iter().map(|a| -(q * *a * *a).element_sum()).collect();
        let mut reward = Vec::with_capacity(entries);
        for p in points_body {
            for (a, c) in actions.iter().zip(&cost) {
                let mut r = *c;
                for k in 0..=steps {
                    r -= potential(&config, *p - *a * (k as f64 * config.step_s));
                }
                reward.push(r);
            }
        }
        reward.extend_from_slice(&cost); // the free state
        Ok(Self { config, actions, reward, states, fingerprint, scratch: Vec::new() })
    }

    /// The config.
    pub fn config(&self) -> &QmdpConfig {
        &self.config
    }

    /// The action set, in the order of [`QmdpAction::index`].
    pub fn actions(&self) -> &[DVec3] {
        &self.actions
    }

    /// States (voxels and the free state).
    pub fn state_count(&self) -> usize {
        self.states
    }

    /// `R(s, a)` for every action of state `s`.
    pub fn rewards(&self, state: usize) -> Option<&[f64]> {
        let n = self.actions.len();
        (state < self.states).then(|| &self.reward[state * n..(state + 1) * n])
    }

    /// The best action under `output`'s belief (an output of the perception this
    /// controller was made for).
    pub fn act(&mut self, output: &PerceptionOutput) -> Result<QmdpAction> {
        if output.fingerprint != self.fingerprint {
            return Err(Error::input(
                "output",
                "comes from a different perception (camera, mounting or grid): a QMDP controller takes the outputs of the perception it was made for",
            ));
        }
        self.act_on(output.belief_states.iter().map(|s| s.0 as usize), &output.belief_probabilities)
    }

    /// The best action under the belief `probabilities[j]` of `states[j]`.
    pub fn act_on(&mut self, states: impl ExactSizeIterator<Item = usize>, probabilities: &[f64]) -> Result<QmdpAction> {
        if states.len() != probabilities.len() {
            return Err(Error::input("probabilities", format!("has {} values for {} states", probabilities.len(), states.len())));
        }
        let n = self.actions.len();
        self.scratch.clear();
        self.scratch.resize(n, 0.0);
        let mut total = 0.0;
        for (s, &b) in states.zip(probabilities) {
            if s >= self.states {
                return Err(Error::input("states", format!("state {s} is not below the state count {}", self.states)));
            }
            if !(b.is_finite() && b >= 0.0) {
                return Err(Error::input("probabilities", format!("must be finite and >= 0, got {b} for state {s}")));
            }
            if b == 0.0 {
                continue;
            }
            total += b;
            for (v, r) in self.scratch.iter_mut().zip(&self.reward[s * n..(s + 1) * n]) {
                *v += b * r;
            }
        }
        if total == 0.0 {
            // No belief at all: nothing is known to be there, as with the free state.
            let free = self.states - 1;
            self.scratch.copy_from_slice(&self.reward[free * n..]);
        }
        let (index, value) = self.scratch.iter().copied().enumerate().fold((0, f64::NEG_INFINITY), |best, (i, v)| if v > best.1 { (i, v) } else { best });
        Ok(QmdpAction { velocity_body: self.actions[index], index, value })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pole_ahead() -> Vec<DVec3> {
        // Three voxels: straight ahead 0.5 m, to the left 0.5 m, far ahead 5 m.
        vec![DVec3::new(0.5, 0.0, 0.0), DVec3::new(0.0, 0.5, 0.0), DVec3::new(5.0, 0.0, 0.0)]
    }

    #[test]
    fn the_authors_action_set_has_405_actions_with_zero_among_them() {
        let a = actions(&QmdpConfig::default());
        assert_eq!(a.len(), 5 * 9 * 9);
        assert!(a.contains(&DVec3::ZERO));
        assert!(a.iter().all(|v| v.x <= 0.0 && v.y.abs() <= 0.8 + 1e-12 && v.z.abs() <= 0.8 + 1e-12));
        // A grid that misses 0 gets it appended.
        let c = QmdpConfig { action_min_m_s: [0.1, 0.1, 0.1], action_max_m_s: [0.3, 0.1, 0.1], ..QmdpConfig::default() };
        assert_eq!(actions(&c), vec![DVec3::new(0.1, 0.1, 0.1), DVec3::new(0.1 + 0.2, 0.1, 0.1), DVec3::ZERO]);
    }

    #[test]
    fn free_belief_stands_still_and_an_obstacle_ahead_backs_off() {
        let mut q = Qmdp::from_points(&pole_ahead(), QmdpConfig::default(), 7).unwrap();
        let free = q.state_count() - 1;
        let a = q.act_on([free].into_iter(), &[1.0]).unwrap();
        assert_eq!(a.velocity_body, DVec3::ZERO);
        assert_eq!(a.value, 0.0);
        let ahead = q.act_on([0].into_iter(), &[1.0]).unwrap();
        assert!(ahead.velocity_body.x < 0.0, "{ahead:?}");
        assert_eq!(ahead.velocity_body.y, 0.0); // symmetric: no side is better
        let left = q.act_on([1].into_iter(), &[1.0]).unwrap();
        assert!(left.velocity_body.y < 0.0 && left.velocity_body.x == 0.0, "{left:?}");
        // Out of range: the action cost alone, so stand still.
        assert_eq!(q.act_on([2].into_iter(), &[1.0]).unwrap().velocity_body, DVec3::ZERO);
        // The surer the belief that the pole is ahead, the harder it backs off.
        let backs: Vec<f64> = [0.002, 0.01, 0.05, 0.3, 1.0].iter().map(|&p| q.act_on([0, free].into_iter(), &[p, 1.0 - p]).unwrap().velocity_body.x).collect();
        assert!(backs.windows(2).all(|w| w[1] <= w[0]) && backs[0] > backs[4], "{backs:?}");
    }

    #[test]
    fn the_choice_is_that_of_the_authors_value_iteration_for_any_transition() {
        // Q <- R + 0.95·T·max_a Q, 20 times, with a random stochastic T: the argmax of
        // b·Q(·, a) is the argmax of b·R(·, a) (the docs of `Qmdp`).
        let points: Vec<DVec3> = (0..12).map(|i| DVec3::new(0.3 + 0.1 * i as f64, 0.2 * ((i % 5) as f64 - 2.0), 0.1 * ((i % 3) as f64 - 1.0))).collect();
        let mut q = Qmdp::from_points(&points, QmdpConfig::default(), 1).unwrap();
        let (s, n) = (q.state_count(), q.actions().len());
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut t = vec![0.0; s * s];
        for i in 0..s {
            let row: Vec<f64> = (0..s).map(|_| rnd()).collect();
            let sum: f64 = row.iter().sum();
            for j in 0..s {
                t[i * s + j] = row[j] / sum;
            }
        }
        let r: Vec<f64> = (0..s).flat_map(|i| q.rewards(i).unwrap().to_vec()).collect();
        let mut alpha = vec![0.0; s * n];
        for _ in 0..20 {
            let best: Vec<f64> = (0..s).map(|i| alpha[i * n..(i + 1) * n].iter().copied().fold(f64::NEG_INFINITY, f64::max)).collect();
            let carried: Vec<f64> = (0..s).map(|i| (0..s).map(|j| t[i * s + j] * best[j]).sum::<f64>()).collect();
            for i in 0..s {
                for a in 0..n {
                    alpha[i * n + a] = r[i * n + a] + 0.95 * carried[i];
                }
            }
        }
        for trial in 0..50 {
            let mut b: Vec<f64> = (0..s).map(|_| rnd().powi(3)).collect();
            let sum: f64 = b.iter().sum();
            b.iter_mut().for_each(|v| *v /= sum);
            let values: Vec<f64> = (0..n).map(|a| (0..s).map(|i| b[i] * alpha[i * n + a]).sum()).collect();
            let best = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let chosen = q.act_on(0..s, &b).unwrap();
            assert!(values[chosen.index] >= best - 1e-9 * best.abs().max(1.0), "trial {trial}: {} vs {best}", values[chosen.index]);
        }
    }

    #[test]
    fn bad_settings_and_beliefs_are_named() {
        let bad = |c: QmdpConfig| Qmdp::from_points(&pole_ahead(), c, 0).unwrap_err().to_string();
        let d = QmdpConfig::default();
        assert!(bad(QmdpConfig { action_step_m_s: [0.0, 0.2, 0.2], ..d }).contains("action_step_m_s"));
        assert!(bad(QmdpConfig { action_step_m_s: [1e-6, 0.2, 0.2], ..d }).contains("more than 101 actions"));
        assert!(bad(QmdpConfig { action_min_m_s: [1.0, 0.0, 0.0], ..d }).contains("action_min_m_s"));
        assert!(bad(QmdpConfig { lookahead_s: 1e9, ..d }).contains("lookahead_s"));
        assert!(bad(QmdpConfig { min_distance_m: 2.0, ..d }).contains("min_distance_m"));
        assert!(bad(QmdpConfig { potential_gain: f64::NAN, ..d }).contains("potential_gain"));
        let mut q = Qmdp::from_points(&pole_ahead(), d, 0).unwrap();
        assert!(q.act_on([9].into_iter(), &[1.0]).unwrap_err().to_string().contains("states"));
        assert!(q.act_on([0].into_iter(), &[f64::NAN]).unwrap_err().to_string().contains("probabilities"));
        assert!(q.act_on([0, 1].into_iter(), &[1.0]).unwrap_err().to_string().contains("probabilities"));
    }
}
