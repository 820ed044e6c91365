//! Escape from local minima of the potential field by boundary following (subterra; the
//! paper's controller has none).
//!
//! Documented on [`Escape`].

use glam::DVec3;

use crate::config::{ApfConfig, EscapeConfig};
use crate::error::{Error, Result};
use crate::frames::Isometry3;

/// How far ahead of the robot the boundary target is put \[m\]: beyond the attraction's
/// `ρ_r` = 0.5 m, so that the pull has its full (conic) strength.
const TARGET_DISTANCE_M: f64 = 1.0;

/// How far ahead a clear way keeps clear of the known points (step 5) \[m\]: a little under
/// a second of flight at the 0.6 m/s speed limit.
const LOOKAHEAD_M: f64 = 0.5;
/// Longest gap between two steps that counts toward a stall \[s\]: a longer one (the pilot
/// was not stepped, a hover without depth or odometry) moves the progress reference on.
const MAX_STEP_GAP_S: f64 = 0.5;
/// Points along it where the clearance is checked (every 0.1 m).
const LOOKAHEAD_SAMPLES: u32 = 5;
/// When the nearest point jumps to another obstacle, a new tangent pointing back by more
/// than 120° (cos 120°) is a reversal (the far wall of a tube): the side flips to keep the
/// direction of travel. One within 60° of square to it (a wall ahead) is a turn: the side
/// whose tangent points toward the goal is taken if that way keeps clear.
const REVERSAL_COS: f64 = -0.5;

/// Horizontal lengths below this are treated as zero \[m\].
const TINY_M: f64 = 1e-9;
/// A dot product of unit vectors this close to 0 is a tie.
const TIE: f64 = 1e-9;

/// What the escape is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EscapeMode {
    /// Flying to the goal; watching the progress.
    Goal,
    /// Following the boundary of a known obstacle with it on the robot's left:
    /// counter-clockwise round it, seen from above.
    FollowLeft,
    /// Following it on the robot's right: clockwise round it.
    FollowRight,
}

/// What one [`Escape::step`] gives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EscapeOutput {
    /// The goal the attraction should pull toward, in the body frame \[m\].
    pub goal_body: DVec3,
    /// The mode after this step.
    pub mode: EscapeMode,
    /// The boundary point followed, in the world frame \[m\] (while following).
    pub boundary_world: Option<DVec3>,
    /// The repulsion the command should use, body frame \[N\]: the one given, or while
    /// following, that one capped ([`Escape`], step 4).
    pub repulsive_body: DVec3,
    /// How many times following has engaged so far.
    pub engagements: u32,
}

/// The escape state machine.
///
/// A potential field stops where the goal's pull and the obstacles' push cancel: a pole
/// straight ahead of the goal, a wall across the way, the inside of a U. [`Escape`] watches
/// the progress toward the goal and, once it has stalled near a known obstacle, replaces
/// the goal by a target on the obstacle's boundary, so that the robot goes round it; it
/// lets go as soon as the robot is clearly closer to the goal than where it got stuck.
/// This is the leave rule of the Bug family of planners (Lumelsky and Stepanov 1987,
/// "Path-planning strategies for a point mobile automaton moving amidst unknown obstacles
/// of arbitrary shape"): follow the boundary from the hit point until the distance to the
/// goal is below the hit point's.
///
/// In, per control step: the time, the odometry pose `world_from_body`, the goal (or a
/// path's carrot) in the world frame, the remaining distance to the goal along the way,
/// the obstacle points the robot remembers in the world frame (the obstacle memory's
/// cells) and the repulsive force in the body frame. Out: the goal to attract toward, in
/// the body frame — the real goal, or the boundary target while escaping — the repulsion
/// the command should use, and the mode.
///
/// # One step, exactly
/// 1. **Progress.** When the remaining distance falls `progress_m` below its reference,
///    the reference becomes the remaining distance and its time the step's time. A gap of
///    more than 0.5 s since the last step (the robot was not stepped: it hovered without
///    depth or odometry) moves the reference's time on by the gap: time not flown is not a
///    stall.
/// 2. **Engage** (following off): when the reference is `stall_s` old and an obstacle is
///    known — a remembered point within `follow_range_m` horizontally and `z_band_m`
///    vertically, or a repulsive force — following starts: the hit distance is the
///    remaining distance, the standoff is the horizontal distance to the nearest point
///    clamped to `[min_standoff_m, max_standoff_m]`, and the side is the one whose tangent
///    points more along the sum of the unit vectors toward the goal and along the robot's
///    heading (the boundary on the robot's left, i.e. counter-clockwise round it, on a tie,
///    as in front of a pole straight ahead). Facing the goal, that is the side toward the
///    goal; turned away by the field, as a robot usually is after `stall_s` in front of an
///    obstacle, it is the way round the robot faces: a forward-only robot that turns about
///    first spends seconds while the field pushes it around (tunnel seed 1, a cable).
/// 3. **Release** (following on): when the remaining distance is `release_m` below the
///    hit distance; the progress reference restarts from there. The side flips when it
///    leads away — the remaining distance `max_detour_m` above where this side began (a
///    tunnel wall followed back up the tunnel, a long wall's far end) — or after
///    `side_timeout_s` on it; after `max_flips` flips following stops and the stall must
///    be detected afresh.
/// 4. **Follow.** With `n` the horizontal unit vector from the nearest known point to
///    the robot (the last one kept when none is in range; else the repulsion's direction;
///    else away from the goal) at distance `d`, and `t = side·(ẑ × n)` the tangent, the
///    target lies 1 m along `t + clamp(gain·(standoff - d), -1, 1)·n` (normalised), at the
///    goal's height difference capped to that metre: the robot circles the boundary at the
///    standoff. When the nearest point jumps to another obstacle (a tube's far wall) the
///    tangent that keeps the direction of travel is taken, and the side with it. The repulsion still acts, capped at `follow_repulsion_ratio` times the
///    attraction's full strength `ρ_r·ξ`: near an obstacle the field's push is what held
///    the robot in the minimum (0.3-0.7 N against a 0.2 N pull, so the forward speed of
///    eq. 10 is 0), and the boundary term keeps the distance instead. A jump counts as a
///    reversal only when the new tangent points back by more than 120°; when it is within
///    60° of square to the heading — a wall ahead, in a concave corner or beyond the pole
///    followed — the way round turns along it toward the goal when that way keeps clear
///    (step 5; the side may change), else along it on the same side (out of a U).
/// 5. **A clear way** (for step 4's turn toward the goal): along the next 0.5 m the
///    direction keeps every known point within the z band at least `min(d₀,
///    lookahead_keep_m)` away, `d₀` being the nearest one's distance now — a collision
///    margin, not the standoff (between the poles of a hall, 1.2 m apart, no direction
///    keeps 0.55 m from both). The followed direction itself is not turned by this check:
///    turning it away from every point it would close in on makes it turn the robot about
///    wherever points stand on both sides (a tunnel's tight places), and the wall ahead in
///    a concave corner that such a turn was meant for is already avoided by not turning
///    toward the goal into it (step 4). docs/flight.md has the measured comparison.
#[derive(Debug, Clone)]
pub struct Escape {
    config: EscapeConfig,
    /// Full strength of the attraction, `ρ_r·ξ` \[N\].
    attraction_n: f64,
    /// Progress reference: remaining distance and its time.
    reference: Option<(f64, f64)>,
    mode: EscapeMode,
    hit_remaining_m: f64,
    standoff_m: f64,
    side_since_s: f64,
    /// Remaining distance when the current side began.
    side_remaining_m: f64,
    flips: u32,
    last_boundary: Option<DVec3>,
    /// The tangent followed on the last step (horizontal, unit).
    heading: Option<DVec3>,
    engagements: u32,
    last_stamp_s: Option<f64>,
}

fn horizontal(v: DVec3) -> DVec3 {
    DVec3::new(v.x, v.y, 0.0)
}

/// The known points near the robot, relative to it, for a clear way ([`Escape`], step 5).
struct Lookahead {
    /// Horizontal offsets from the robot of the points within the z band and reach.
    near: Vec<DVec3>,
    /// The clearance a direction must keep: `min(d₀, lookahead_keep_m)` \[m\].
    keep_m: f64,
}

impl Lookahead {
    fn new(config: &EscapeConfig, position: DVec3, obstacles_world: &[DVec3]) -> Self {
        let reach = config.follow_range_m.max(config.min_standoff_m) + LOOKAHEAD_M;
        let near: Vec<DVec3> = obstacles_world
            .iter()
            .filter(|p| (p.z - position.z).abs() <= config.z_band_m)
            .map(|&p| horizontal(p - position))
            .filter(|p| p.length() <= reach)
            .collect();
        let now = near.iter().map(|p| p.length()).fold(f64::INFINITY, f64::min);
        Self { near, keep_m: now.min(config.lookahead_keep_m) }
    }

    /// The closest any point comes along the next [`LOOKAHEAD_M`] in the unit direction `u`.
    fn closest(&self, u: DVec3) -> f64 {
        let mut least = f64::INFINITY;
        for k in 1..=LOOKAHEAD_SAMPLES {
            let at = u * (LOOKAHEAD_M * f64::from(k) / f64::from(LOOKAHEAD_SAMPLES));
            for &p in &self.near {
                least = least.min((p - at).length());
            }
        }
        least
    }

    /// Whether `u` keeps the clearance.
    fn clear(&self, u: DVec3) -> bool {
        self.closest(u) >= self.keep_m
    }
}

impl Escape {
    /// An escape with `config` (validated here) for the attraction of `apf`.
    pub fn new(config: EscapeConfig, apf: &ApfConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self::fresh(config, apf.rho_r_m * apf.xi))
    }

    fn fresh(config: EscapeConfig, attraction_n: f64) -> Self {
        Self {
            config,
            attraction_n,
            reference: None,
            mode: EscapeMode::Goal,
            hit_remaining_m: 0.0,
            standoff_m: 0.0,
            side_since_s: 0.0,
            side_remaining_m: 0.0,
            flips: 0,
            last_boundary: None,
            heading: None,
            engagements: 0,
            last_stamp_s: None,
        }
    }

    /// The settings.
    pub fn config(&self) -> &EscapeConfig {
        &self.config
    }

    /// The mode.
    pub fn mode(&self) -> EscapeMode {
        self.mode
    }

    /// Starts afresh (a new flight, or odometry that jumped).
    pub fn reset(&mut self) {
        *self = Self::fresh(self.config, self.attraction_n);
    }

    /// The nearest known point within the follow range: `(point, horizontal distance)`.
    fn nearest(&self, position: DVec3, obstacles_world: &[DVec3]) -> Option<(DVec3, f64)> {
        let c = &self.config;
        let mut best: Option<(DVec3, f64)> = None;
        for &p in obstacles_world {
            if (p.z - position.z).abs() > c.z_band_m {
                continue;
            }
            let d = horizontal(position - p).length();
            if d <= c.follow_range_m && best.is_none_or(|(_, b)| d < b) {
                best = Some((p, d));
            }
        }
        best
    }

    /// Steps 1-4 for one control step.
    ///
    /// `remaining_m`: the distance still to go (straight to the goal, or along a path);
    /// `obstacles_world`: remembered obstacle points; `repulsive_body`: the repulsion the
    /// command will use.
    pub fn step(
        &mut self,
        stamp_s: f64,
        world_from_body: &Isometry3,
        goal_world: DVec3,
        remaining_m: f64,
        obstacles_world: &[DVec3],
        repulsive_body: DVec3,
    ) -> Result<EscapeOutput> {
        crate::frames::check_stamp("stamp", stamp_s)?;
        if let Some(last) = self.last_stamp_s {
            if stamp_s < last {
                return Err(Error::input("stamp", format!("must not go back in time: {stamp_s} s after {last} s (call reset() first)")));
            }
        }
        if !(world_from_body.translation.is_finite() && world_from_body.rotation.is_finite()) {
            return Err(Error::input("world_from_body", "must be finite"));
        }
        crate::frames::check_position("goal_world", &goal_world.to_array())?;
        if !(remaining_m.is_finite() && remaining_m >= 0.0) {
            return Err(Error::input("remaining_m", format!("must be finite and >= 0, got {remaining_m}")));
        }
        if !repulsive_body.is_finite() {
            return Err(Error::input("repulsive_body", format!("must be finite, got {repulsive_body}")));
        }
        if let Some(p) = obstacles_world.iter().find(|p| !p.is_finite()) {
            return Err(Error::input("obstacles_world", format!("must be finite, got {p}")));
        }
        // Time the robot was not stepped (a hover without depth or odometry) is not time it
        // failed to progress: the reference moves on by the gap.
        if let (Some(last), Some((r, t))) = (self.last_stamp_s, self.reference) {
            let gap = stamp_s - last;
            if gap > MAX_STEP_GAP_S {
                self.reference = Some((r, t + gap));
            }
        }
        self.last_stamp_s = Some(stamp_s);
        let c = self.config;
        let position = world_from_body.translation;
        let body_from_world = world_from_body.inverse();
        let repulsive_world = world_from_body.transform_vector(repulsive_body);
        let nearest = self.nearest(position, obstacles_world);

        // 1. Progress.
        match self.reference {
            Some((r, _)) if remaining_m > r - c.progress_m => {}
            _ => self.reference = Some((remaining_m, stamp_s)),
        }

        if c.enabled {
            match self.mode {
                EscapeMode::Goal => {
                    // 2. Engage.
                    let since = self.reference.map_or(0.0, |(_, t)| stamp_s - t);
                    let known = nearest.is_some() || horizontal(repulsive_world).length() > 0.0;
                    if since >= c.stall_s && known {
                        let to_goal = horizontal(goal_world - position);
                        let n = self.normal(position, nearest, repulsive_world, to_goal);
                        let tangent_left = DVec3::Z.cross(n);
                        let heading = horizontal(world_from_body.rotation * DVec3::X).normalize_or_zero();
                        let toward = to_goal.normalize_or_zero() + heading;
                        let side = if tangent_left.dot(toward) < -TIE { EscapeMode::FollowRight } else { EscapeMode::FollowLeft };
                        self.mode = side;
                        self.hit_remaining_m = remaining_m;
                        let d = nearest.map_or(c.max_standoff_m, |(_, d)| d);
                        self.standoff_m = d.clamp(c.min_standoff_m, c.max_standoff_m);
                        self.side_since_s = stamp_s;
                        self.side_remaining_m = remaining_m;
                        self.flips = 0;
                        self.heading = None;
                        self.engagements += 1;
                        if let Some((p, _)) = nearest {
                            self.last_boundary = Some(p);
                        }
                    }
                }
                EscapeMode::FollowLeft | EscapeMode::FollowRight => {
                    // 3. Release.
                    if remaining_m < self.hit_remaining_m - c.release_m {
                        self.release(remaining_m, stamp_s);
                    } else if stamp_s - self.side_since_s > c.side_timeout_s || remaining_m > self.side_remaining_m + c.max_detour_m {
                        if self.flips >= c.max_flips {
                            self.release(remaining_m, stamp_s);
                        } else {
                            self.flips += 1;
                            self.side_since_s = stamp_s;
                            self.side_remaining_m = remaining_m;
                            self.mode = if self.mode == EscapeMode::FollowLeft { EscapeMode::FollowRight } else { EscapeMode::FollowLeft };
                            self.heading = self.heading.map(|h| -h);
                        }
                    }
                }
            }
        }

        // 4. Follow.
        let side = match self.mode {
            EscapeMode::Goal => {
                return Ok(EscapeOutput {
                    goal_body: body_from_world.transform_point(goal_world),
                    mode: self.mode,
                    boundary_world: None,
                    repulsive_body,
                    engagements: self.engagements,
                });
            }
            EscapeMode::FollowLeft => 1.0,
            EscapeMode::FollowRight => -1.0,
        };
        if let Some((p, _)) = nearest {
            self.last_boundary = Some(p);
        }
        let to_goal = horizontal(goal_world - position);
        let n = self.normal(position, nearest.or(self.last_boundary.map(|p| (p, horizontal(position - p).length()))), repulsive_world, to_goal);
        let d = self.last_boundary.map_or(self.standoff_m, |p| horizontal(position - p).length());
        let mut tangent = side * DVec3::Z.cross(n);
        // The way round goes on: when the nearest point jumps to another obstacle (the far
        // wall of a tube), keep the direction of travel, not the side the boundary is on.
        // A wall ahead, square to the heading (a concave corner, or a wall beyond the pole
        // followed), is a turn, not a reversal: toward the goal if that way is clear, else
        // on the same side (out of a U).
        let ahead = Lookahead::new(&c, position, obstacles_world);
        if let Some(heading) = self.heading {
            let along = tangent.dot(heading);
            let toward_goal = if tangent.dot(to_goal) < -TIE { -tangent } else { tangent };
            let flip = if along < REVERSAL_COS {
                true
            } else if along <= -REVERSAL_COS {
                toward_goal != tangent && ahead.clear(toward_goal)
            } else {
                false
            };
            if flip {
                tangent = -tangent;
                self.mode = if self.mode == EscapeMode::FollowLeft { EscapeMode::FollowRight } else { EscapeMode::FollowLeft };
            }
        }
        self.heading = Some(tangent);
        let pull = (c.gain_per_m * (self.standoff_m - d)).clamp(-1.0, 1.0);
        let direction = (tangent + pull * n).normalize_or_zero();
        let climb = (goal_world.z - position.z).clamp(-TARGET_DISTANCE_M, TARGET_DISTANCE_M);
        let target_world = position + TARGET_DISTANCE_M * direction + DVec3::new(0.0, 0.0, climb);
        let cap = c.follow_repulsion_ratio * self.attraction_n;
        let push = repulsive_body.length();
        let repulsive_body = if push > cap { repulsive_body * (cap / push) } else { repulsive_body };
        Ok(EscapeOutput {
            goal_body: body_from_world.transform_point(target_world),
            mode: self.mode,
            boundary_world: self.last_boundary,
            repulsive_body,
            engagements: self.engagements,
        })
    }

    fn release(&mut self, remaining_m: f64, stamp_s: f64) {
        self.mode = EscapeMode::Goal;
        self.reference = Some((remaining_m, stamp_s));
        self.last_boundary = None;
        self.heading = None;
    }

    /// The horizontal unit vector from the boundary to the robot ([`Escape`], step 4).
    fn normal(&self, position: DVec3, nearest: Option<(DVec3, f64)>, repulsive_world: DVec3, to_goal: DVec3) -> DVec3 {
        if let Some((p, d)) = nearest {
            if d > TINY_M {
                return horizontal(position - p) / d;
            }
        }
        let away = horizontal(repulsive_world);
        if away.length() > TINY_M {
            return away.normalize();
        }
        if to_goal.length() > TINY_M {
            return -to_goal.normalize();
        }
        DVec3::NEG_X
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;
    use crate::apf::{repulsive_force, ApfController};
    use crate::config::{ApfConfig, PerceptionConfig};

    /// Points every 0.05 m along the segment `a`-`b` at flight height.
    fn segment(a: (f64, f64), b: (f64, f64)) -> Vec<DVec3> {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let n = ((dx.hypot(dy) / 0.05).ceil() as usize).max(1);
        (0..=n).map(|k| DVec3::new(a.0 + dx * k as f64 / n as f64, a.1 + dy * k as f64 / n as f64, 1.0)).collect()
    }

    /// A pole of radius `r` at `(x, y)`: points round its surface.
    fn pole(x: f64, y: f64, r: f64) -> Vec<DVec3> {
        (0..24).map(|k| f64::from(k) * std::f64::consts::TAU / 24.0).map(|a| DVec3::new(x + r * a.cos(), y + r * a.sin(), 1.0)).collect()
    }

    /// Collision radius of the simulated quadrotor \[m\].
    const ROBOT_RADIUS_M: f64 = 0.27;

    struct Flight {
        reached: bool,
        closest_m: f64,
        engagements: u32,
        time_s: f64,
    }

    /// A unicycle flown by the APF controller (`flight` limits) toward `goal`, repelled by
    /// the points a forward camera sees (80° wide, 1.2 m deep; weights normalised like the
    /// obstacle memory's), with the escape on or off; the escape knows all points, as a
    /// memory would. 10 Hz, at most `limit_s`.
    fn fly(points: &[DVec3], start: (f64, f64), goal: (f64, f64), escape_on: bool, limit_s: f64) -> Flight {
        let apf: ApfConfig = PerceptionConfig::flight().apf;
        let controller = ApfController::new(apf);
        let config = EscapeConfig { enabled: escape_on, ..EscapeConfig::default() };
        let mut escape = Escape::new(config, &apf).unwrap();
        let goal_world = DVec3::new(goal.0, goal.1, 1.0);
        let mut position = DVec3::new(start.0, start.1, 1.0);
        let mut yaw = (goal.1 - start.1).atan2(goal.0 - start.0);
        let dt = 0.1;
        let mut closest = f64::INFINITY;
        let mut t = 0.0;
        while t < limit_s {
            let pose = Isometry3 { rotation: DMat3::from_rotation_z(yaw), translation: position };
            let body_from_world = pose.inverse();
            let mut sum = DVec3::ZERO;
            let mut near = 0.0;
            for &p in points {
                let d = (p - position).length();
                closest = closest.min(d);
                let p_body = body_from_world.transform_point(p);
                // What the forward D435 sees of it: within ±40° of the heading, 0.1-1.2 m deep.
                let seen = p_body.x > 0.1 && p_body.x < 1.2 && p_body.y.abs() < p_body.x * 40f64.to_radians().tan();
                if seen && d < apf.rho_0_m {
                    sum += repulsive_force(&apf, p_body);
                    near += 1.0;
                }
            }
            let repulsive_body = sum / f64::max(near, 1.0);
            let remaining = (goal_world - position).length();
            let out = escape.step(t, &pose, goal_world, remaining, points, repulsive_body).unwrap();
            let cmd = controller.command(out.goal_body, out.repulsive_body).unwrap();
            if cmd.reached {
                return Flight { reached: true, closest_m: closest, engagements: out.engagements, time_s: t };
            }
            yaw += cmd.yaw_rate_rad_s * dt;
            let velocity = DMat3::from_rotation_z(yaw) * DVec3::new(cmd.v_x_m_s, cmd.v_y_m_s, cmd.v_z_m_s);
            position += velocity * dt;
            t += dt;
        }
        Flight { reached: false, closest_m: closest, engagements: escape.engagements, time_s: t }
    }

    fn assert_trap(name: &str, points: &[DVec3], start: (f64, f64), goal: (f64, f64)) {
        let stuck = fly(points, start, goal, false, 120.0);
        assert!(!stuck.reached, "{name}: the plain field should stall");
        let free = fly(points, start, goal, true, 120.0);
        assert!(free.reached, "{name}: the escape should reach the goal");
        assert!(free.engagements >= 1, "{name}: reached without escaping");
        assert!(free.closest_m > ROBOT_RADIUS_M + 0.1, "{name}: came within {:.3} m of the obstacle", free.closest_m);
        assert!(free.time_s < 100.0, "{name}: took {} s", free.time_s);
    }

    #[test]
    fn a_pole_straight_ahead_of_the_goal() {
        assert_trap("pole", &pole(3.0, 0.0, 0.15), (0.0, 0.0), (6.0, 0.0));
    }

    #[test]
    fn a_wall_across_the_way() {
        assert_trap("wall", &segment((3.0, -1.5), (3.0, 1.5)), (0.0, 0.0), (6.0, 0.0));
    }

    #[test]
    fn a_u_open_toward_the_robot() {
        let mut u = segment((3.0, -1.5), (3.0, 1.5));
        u.extend(segment((1.5, 1.5), (3.0, 1.5)));
        u.extend(segment((1.5, -1.5), (3.0, -1.5)));
        assert_trap("U", &u, (0.0, 0.0), (6.0, 0.0));
    }

    #[test]
    fn a_long_wall_on_the_side_toward_the_goal_is_given_up_for_the_short_way() {
        // The goal lies a little left, so the escape first follows the wall left, where it
        // runs on for 8 m; past the detour limit it turns back and goes round the right end.
        let points = segment((3.0, -1.0), (3.0, 8.0));
        let plain = fly(&points, (0.0, 0.3), (6.0, 0.6), false, 150.0);
        assert!(!plain.reached);
        let free = fly(&points, (0.0, 0.3), (6.0, 0.6), true, 150.0);
        assert!(free.reached && free.closest_m > ROBOT_RADIUS_M + 0.1, "reached {} closest {}", free.reached, free.closest_m);
    }

    #[test]
    fn open_space_never_engages_and_off_changes_nothing() {
        // No obstacle: the goal is reached straight, with or without the escape, and the
        // escape passes the goal through unchanged.
        let on = fly(&[], (0.0, 0.0), (5.0, 2.0), true, 60.0);
        let off = fly(&[], (0.0, 0.0), (5.0, 2.0), false, 60.0);
        assert!(on.reached && off.reached && on.engagements == 0);
        assert_eq!(on.time_s, off.time_s);
        // Stalled with nothing known (e.g. turning toward a goal behind): no engagement.
        let config = EscapeConfig { enabled: true, ..EscapeConfig::default() };
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let pose = Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::ZERO };
        for k in 0..100 {
            let out = e.step(f64::from(k) * 0.1, &pose, DVec3::new(-3.0, 0.0, 0.0), 3.0, &[], DVec3::ZERO).unwrap();
            assert_eq!(out.mode, EscapeMode::Goal);
            assert_eq!(out.goal_body, DVec3::new(-3.0, 0.0, 0.0));
        }
    }

    #[test]
    fn time_not_stepped_is_not_a_stall() {
        let config = EscapeConfig { enabled: true, ..EscapeConfig::default() };
        let pose = Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::new(0.0, 0.0, 1.0) };
        let point = [DVec3::new(0.5, 0.0, 1.0)];
        let goal = DVec3::new(5.0, 0.0, 1.0);
        // Stepped every 0.1 s without progress: engages after stall_s.
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let engaged_at = (0..100).map(|k| f64::from(k) * 0.1).find(|&t| e.step(t, &pose, goal, 5.0, &point, DVec3::ZERO).unwrap().mode != EscapeMode::Goal);
        assert!(engaged_at.is_some_and(|t| (t - config.stall_s).abs() < 0.15), "{engaged_at:?}");
        // One step, a 4 s hover without steps, then steps again: the stall counts from the
        // end of the gap, not from before it.
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        e.step(0.0, &pose, goal, 5.0, &point, DVec3::ZERO).unwrap();
        let engaged_at = (40..200).map(|k| f64::from(k) * 0.1).find(|&t| e.step(t, &pose, goal, 5.0, &point, DVec3::ZERO).unwrap().mode != EscapeMode::Goal);
        assert!(engaged_at.is_some_and(|t| (t - 4.0 - config.stall_s).abs() < 0.15), "{engaged_at:?}");
    }

    #[test]
    fn of_two_ways_round_equally_toward_the_goal_it_takes_the_one_it_faces() {
        let config = EscapeConfig { enabled: true, ..EscapeConfig::default() };
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        // The robot faces +y (turned away by the field), an obstacle point 0.5 m on its
        // right-hand side at +x, the goal beyond it along +x: both tangents (±y) are square
        // to the goal; the one along the heading (+y: clockwise, boundary on the right) wins.
        let pose = Isometry3 { rotation: DMat3::from_rotation_z(std::f64::consts::FRAC_PI_2), translation: DVec3::new(0.0, 0.0, 1.0) };
        let point = [DVec3::new(0.5, 0.0, 1.0)];
        let goal = DVec3::new(5.0, 0.0, 1.0);
        let mut out = e.step(0.0, &pose, goal, 5.0, &point, DVec3::ZERO).unwrap();
        let mut t = 0.0;
        while out.mode == EscapeMode::Goal && t < 2.0 * config.stall_s {
            t += 0.1;
            out = e.step(t, &pose, goal, 5.0, &point, DVec3::ZERO).unwrap();
        }
        assert_eq!(out.mode, EscapeMode::FollowRight);
        assert!(out.goal_body.x > 0.9, "the target lies ahead, not behind: {}", out.goal_body);
        // Facing the goal instead, the tie goes to the left (counter-clockwise), as before.
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let facing = Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::new(0.0, 0.0, 1.0) };
        let mut t = 0.0;
        let mut out = e.step(t, &facing, goal, 5.0, &point, DVec3::ZERO).unwrap();
        while out.mode == EscapeMode::Goal && t < 2.0 * config.stall_s {
            t += 0.1;
            out = e.step(t, &facing, goal, 5.0, &point, DVec3::ZERO).unwrap();
        }
        assert_eq!(out.mode, EscapeMode::FollowLeft);
    }

    #[test]
    fn a_wall_ahead_turns_the_way_round_toward_the_goal_where_that_way_is_clear() {
        // A hall's corner: the south wall (y = 0) and the east wall (x = 5). The robot,
        // 0.45 m off the south wall and 0.6 m short of the east one, faces east, stalled;
        // the goal lies back to the north-west, so it follows the south wall eastward with
        // the wall on its right (highbay seed 87, route D-B, touched the east wall so).
        let config = EscapeConfig { enabled: true, ..EscapeConfig::default() };
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let mut walls = segment((0.0, 0.0), (5.0, 0.0));
        walls.extend(segment((5.0, 0.0), (5.0, 4.0)));
        let goal = DVec3::new(3.0, 2.0, 1.0);
        let at = |x: f64, y: f64| Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::new(x, y, 1.0) };
        let mut t = 0.0;
        let mut out = e.step(t, &at(4.4, 0.45), goal, 2.1, &walls, DVec3::ZERO).unwrap();
        while out.mode == EscapeMode::Goal {
            t += 0.1;
            assert!(t < 2.0 * config.stall_s);
            out = e.step(t, &at(4.4, 0.45), goal, 2.1, &walls, DVec3::ZERO).unwrap();
        }
        assert_eq!(out.mode, EscapeMode::FollowRight);
        // Deeper in the corner, the east wall now the nearest (its tangent square to the
        // heading): a turn toward the goal, not back along the south wall, nor south.
        let out = e.step(t + 0.1, &at(4.6, 0.5), goal, 2.1, &walls, DVec3::ZERO).unwrap();
        assert_eq!(out.mode, EscapeMode::FollowRight);
        assert!(horizontal(out.goal_body).normalize().y > 0.9, "{}", out.goal_body);
        // Round a pole with a wall beyond it (tunnel seed 51): going north past the pole,
        // the wall ahead becomes the nearest; the way round turns east, toward the goal,
        // with the wall on the left, not west with it on the right.
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let mut points = pole(0.6, 0.0, 0.1);
        points.extend(segment((-3.0, 1.3), (3.0, 1.3)));
        let goal = DVec3::new(5.0, 0.3, 1.0);
        let north = |x: f64, y: f64| Isometry3 { rotation: DMat3::from_rotation_z(std::f64::consts::FRAC_PI_2), translation: DVec3::new(x, y, 1.0) };
        let mut t = 0.0;
        let mut out = e.step(t, &north(0.0, 0.0), goal, 5.0, &points, DVec3::ZERO).unwrap();
        while out.mode == EscapeMode::Goal {
            t += 0.1;
            out = e.step(t, &north(0.0, 0.0), goal, 5.0, &points, DVec3::ZERO).unwrap();
        }
        assert_eq!(out.mode, EscapeMode::FollowRight, "north round the pole's west side");
        let out = e.step(t + 0.1, &north(0.0, 0.7), goal, 5.0, &points, DVec3::ZERO).unwrap();
        assert_eq!(out.mode, EscapeMode::FollowLeft);
        let world = north(0.0, 0.7).transform_point(out.goal_body) - DVec3::new(0.0, 0.7, 1.0);
        assert!(horizontal(world).normalize().x > 0.8, "{world}");
        // With nothing ahead (a straight wall, no corner) the direction is not turned: the
        // tangent plus the pull back out to the standoff.
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let south = segment((0.0, 0.0), (9.0, 0.0));
        let mut t = 0.0;
        let mut out = e.step(t, &at(4.4, 0.45), goal, 2.1, &south, DVec3::ZERO).unwrap();
        while out.mode == EscapeMode::Goal {
            t += 0.1;
            out = e.step(t, &at(4.4, 0.45), goal, 2.1, &south, DVec3::ZERO).unwrap();
        }
        let pull = config.gain_per_m * (config.min_standoff_m - 0.45);
        let expected = DVec3::new(1.0, pull, 0.0).normalize();
        assert!((horizontal(out.goal_body).normalize() - expected).length() < 1e-9, "{}", out.goal_body);
    }

    #[test]
    fn engages_after_the_stall_time_on_the_side_toward_the_goal_and_releases_on_progress() {
        let config = EscapeConfig { enabled: true, ..EscapeConfig::default() };
        let mut e = Escape::new(config, &PerceptionConfig::flight().apf).unwrap();
        let pose = |x: f64, y: f64| Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::new(x, y, 1.0) };
        // A wall point ahead and a little right of the robot; the goal ahead and left.
        let wall = [DVec3::new(0.7, -0.2, 1.0)];
        let goal = DVec3::new(5.0, 1.0, 1.0);
        let mut t = 0.0;
        while t < config.stall_s - 0.05 {
            assert_eq!(e.step(t, &pose(0.0, 0.0), goal, 5.1, &wall, DVec3::new(-0.2, 0.0, 0.0)).unwrap().mode, EscapeMode::Goal);
            t += 0.1;
        }
        let out = e.step(config.stall_s + 0.01, &pose(0.0, 0.0), goal, 5.1, &wall, DVec3::new(-0.2, 0.0, 0.0)).unwrap();
        // n points from the wall point to the robot (back-left); ẑ × n (counter-clockwise
        // round the point) points back-right, away from the goal, so the robot goes
        // clockwise, forward-left, with the wall on its right.
        assert_eq!(out.mode, EscapeMode::FollowRight);
        assert_eq!(out.boundary_world, Some(wall[0]));
        let n = DVec3::new(-0.7, 0.2, 0.0).normalize();
        let tangent = -DVec3::Z.cross(n);
        assert!(tangent.x > 0.0 && tangent.y > 0.0);
        // Standoff = the distance at the hit (0.728 m, inside the clamp): no pull, pure tangent.
        assert!((out.goal_body - (tangent * TARGET_DISTANCE_M)).length() < 1e-9, "{}", out.goal_body);
        // Not yet released at the hit distance ...
        let out = e.step(5.0, &pose(0.0, 0.0), goal, 5.1 - 0.5 * config.release_m, &wall, DVec3::ZERO).unwrap();
        assert_eq!(out.mode, EscapeMode::FollowRight);
        // ... released once clearly closer.
        let out = e.step(5.1, &pose(1.0, 1.0), goal, 5.1 - 1.5 * config.release_m, &wall, DVec3::ZERO).unwrap();
        assert_eq!(out.mode, EscapeMode::Goal);
        assert_eq!(out.goal_body, goal - DVec3::new(1.0, 1.0, 1.0));
        // Bad input names its argument.
        let err = e.step(4.0, &pose(0.0, 0.0), goal, 1.0, &wall, DVec3::ZERO).unwrap_err().to_string();
        assert!(err.contains("stamp"), "{err}");
        let err = e.step(6.0, &pose(0.0, 0.0), goal, f64::NAN, &wall, DVec3::ZERO).unwrap_err().to_string();
        assert!(err.contains("remaining_m"), "{err}");
        let err = e.step(6.0, &pose(0.0, 0.0), goal, 1.0, &[DVec3::NAN], DVec3::ZERO).unwrap_err().to_string();
        assert!(err.contains("obstacles_world"), "{err}");
    }
}
