//! HeRO, heterogeneous redundant odometry: several odometry sources, health checks on each,
//! and the most trusted healthy one passed on as one continuous pose with a confidence
//! (the JPL SubT stack's odometry multiplexer; Santamaria-Navarro et al. 2020, "Towards
//! resilient autonomous navigation of drones", and the STEP draft's §VI-B).
//!
//! In: samples `(stamp, world_from_body, covariance, twist)` per named source, in any order
//! across sources ([`OdometryMux::push`]); every source reports the pose of the same body
//! frame, each in a world frame of its own (a visual-inertial estimator and a lidar
//! odometry start where they start). Out, per [`OdometryMux::update`]: the chosen source,
//! the pose in the mux's own world frame, a confidence in [0, 1], and the events since the
//! last call.
//!
//! # The checks, per source
//! - **Stale**: no sample for `stale_periods` of the source's nominal period.
//! - **Jump**: between two consecutive samples the translation differs from the one the
//!   twist predicts (the previous sample's body-frame velocity times the interval) by more
//!   than `jump_m`, or the yaw by more than `jump_yaw_rad`; without a twist (or after a
//!   stale gap) the bound is `max_speed_m_s`·dt + `jump_m` and `max_yaw_rate_rad_s`·dt +
//!   `jump_yaw_rad`. An estimator that resets or relocalises jumps so.
//! - **Covariance**: the position standard deviation (the largest of the x, y, z
//!   variances) above `max_position_std_m`, or the yaw's above `max_yaw_std_rad`.
//! - **Consistency**: over the last `consistency_window_s`, each pair of sources that both
//!   cover it is compared on its relative motion, `pose(t₁)⁻¹·pose(t₂)` (in the body frame
//!   at `t₁`, so that the sources' world frames do not matter): the translations may differ
//!   by `consistency_m` plus `consistency_ratio` of the distance moved, the yaws by
//!   `consistency_yaw_rad`. A source that agrees with fewer than half of at least two
//!   others is inconsistent (a drift, a frozen estimator while the robot moves). Two sources
//!   alone that disagree cannot tell which is wrong: both stay usable, the disagreement is
//!   an event and halves the confidence.
//!
//! A source that fails a check is not used until it has passed every check for
//! `recover_s` (a jumped source also waits that long after its jump).
//!
//! # The choice and the pose
//! The first usable source in the order the sources were given (most trusted first) is
//! chosen. The output is `anchor · pose` of the chosen source; when the choice changes the
//! new source's anchor is set so that its pose at the last output's stamp (interpolated in
//! its history, else its newest) maps onto the last output pose: the output does not jump
//! when the source does. A jumped source's own anchor absorbs its jump (the motion its twist
//! predicts is kept), so re-choosing it later is continuous too. One exception: leaving a
//! source the vote found inconsistent, the output is taken back to where it was at the start
//! of the consistency window (the outputs of the last two windows are kept; before them, no
//! correction) and the new source's motion since then is put on it — the
//! drift that the vote measured is taken out of the pose instead of carried on (the switch
//! event's `corrected_m` says by how much). A map kept in the output frame then lines up
//! with the world again; without it, a ground robot whose pose had drifted 0.6 m sideways
//! drove into a hole it had mapped before the drift. With no usable source the
//! last pose is held with confidence 0: the stack should stop (or hover) until one recovers.
//!
//! The confidence is `1 - (σ / max_position_std_m)²` of the chosen source's position
//! standard deviation σ (1 without a covariance), halved while it is disputed, 0 with none.

use std::collections::VecDeque;

use glam::{DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{require_positive, Error, Result};
use crate::frames::{Isometry3, MAX_TRANSLATION_M};

/// Most sources one mux takes.
pub const MAX_SOURCES: usize = 64;
/// Highest nominal rate of a source \[Hz\].
pub const MAX_RATE_HZ: f64 = 10_000.0;
/// Most samples kept per source for the consistency window.
const MAX_HISTORY: usize = 8192;

/// The checks' settings (module docs). Defaults for a ground robot or a drone moving at up
/// to a few metres per second.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HeroConfig {
    /// A source is stale after this many of its nominal periods without a sample.
    pub stale_periods: f64,
    /// Speed bound of the jump check without a twist [m/s].
    pub max_speed_m_s: f64,
    /// Yaw-rate bound of the jump check without a twist [rad/s].
    pub max_yaw_rate_rad_s: f64,
    /// Translation one step may differ from the predicted one \[m\].
    pub jump_m: f64,
    /// Yaw one step may differ from the predicted one \[rad\].
    pub jump_yaw_rad: f64,
    /// Largest position standard deviation a usable source reports \[m\].
    pub max_position_std_m: f64,
    /// Largest yaw standard deviation a usable source reports \[rad\].
    pub max_yaw_std_rad: f64,
    /// Window over which the sources' relative motions are compared \[s\].
    pub consistency_window_s: f64,
    /// Translation two sources' relative motions may differ by \[m\] ...
    pub consistency_m: f64,
    /// ... plus this fraction of the distance moved.
    pub consistency_ratio: f64,
    /// Yaw two sources' relative motions may differ by \[rad\].
    pub consistency_yaw_rad: f64,
    /// A source that failed a check is used again after passing them all this long \[s\].
    pub recover_s: f64,
}

impl Default for HeroConfig {
    fn default() -> Self {
        Self {
            stale_periods: 3.0,
            max_speed_m_s: 5.0,
            max_yaw_rate_rad_s: 3.0,
            jump_m: 0.25,
            jump_yaw_rad: 0.15,
            max_position_std_m: 0.5,
            max_yaw_std_rad: 0.3,
            consistency_window_s: 2.0,
            consistency_m: 0.15,
            consistency_ratio: 0.1,
            consistency_yaw_rad: 0.1,
            recover_s: 2.0,
        }
    }
}

impl HeroConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        if !(self.stale_periods.is_finite() && self.stale_periods >= 1.0 && self.stale_periods <= 1000.0) {
            return Err(Error::config("hero.stale_periods", "must be in [1, 1000]", self.stale_periods));
        }
        require_positive("hero.max_speed_m_s", self.max_speed_m_s)?;
        require_positive("hero.max_yaw_rate_rad_s", self.max_yaw_rate_rad_s)?;
        require_positive("hero.jump_m", self.jump_m)?;
        require_positive("hero.jump_yaw_rad", self.jump_yaw_rad)?;
        require_positive("hero.max_position_std_m", self.max_position_std_m)?;
        require_positive("hero.max_yaw_std_rad", self.max_yaw_std_rad)?;
        if !(self.consistency_window_s.is_finite() && self.consistency_window_s > 0.0 && self.consistency_window_s <= 60.0) {
            return Err(Error::config("hero.consistency_window_s", "must be in (0, 60] s", self.consistency_window_s));
        }
        require_positive("hero.consistency_m", self.consistency_m)?;
        if !(self.consistency_ratio.is_finite() && (0.0..=1.0).contains(&self.consistency_ratio)) {
            return Err(Error::config("hero.consistency_ratio", "must be in [0, 1]", self.consistency_ratio));
        }
        require_positive("hero.consistency_yaw_rad", self.consistency_yaw_rad)?;
        if !(self.recover_s.is_finite() && self.recover_s >= 0.0 && self.recover_s <= 3600.0) {
            return Err(Error::config("hero.recover_s", "must be in [0, 3600] s", self.recover_s));
        }
        Ok(())
    }
}

/// A source: its name and the rate it publishes at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceSpec {
    /// Its name, unique in the mux (`"vio"`, `"lidar"`, `"wheels"`).
    pub name: String,
    /// Its nominal rate \[Hz\]: the stale check counts its periods.
    pub rate_hz: f64,
}

/// A body-frame velocity (`nav_msgs/Odometry`'s twist, in the child frame).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Twist {
    /// Linear velocity [m/s].
    pub linear: DVec3,
    /// Angular velocity [rad/s].
    pub angular: DVec3,
}

/// One odometry sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometrySample {
    /// Its time \[s\].
    pub stamp_s: f64,
    /// The body's pose in the source's world frame.
    pub world_from_body: Isometry3,
    /// Row-major 6x6 covariance over (x, y, z, roll, pitch, yaw), `nav_msgs/Odometry`'s
    /// layout [m², rad²]; None: unknown (the covariance check passes).
    pub covariance: Option<[f64; 36]>,
    /// The body-frame velocity, if the source gives one.
    pub twist: Option<Twist>,
}

/// Why a source is not used.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// No sample for this long \[s\].
    Stale {
        /// Seconds since its newest sample.
        age_s: f64,
    },
    /// A step off the predicted one.
    Jump {
        /// Translation off the twist's prediction, or the step itself without a twist \[m\].
        translation_m: f64,
        /// Yaw off the twist's prediction, or the step's yaw without a twist \[rad\].
        yaw_rad: f64,
        /// The step's interval \[s\].
        dt_s: f64,
        /// Whether a twist predicted the step.
        predicted: bool,
    },
    /// A covariance above the bounds.
    Covariance {
        /// Position standard deviation \[m\].
        position_std_m: f64,
        /// Yaw standard deviation \[rad\].
        yaw_std_rad: f64,
    },
    /// Its relative motion disagrees with most of the others'.
    Inconsistent {
        /// The others it was compared with.
        compared: usize,
        /// Those it agreed with.
        agreed: usize,
        /// Its largest translation disagreement \[m\].
        error_m: f64,
    },
}

impl Fault {
    /// A short name: `stale`, `jump`, `covariance`, `inconsistent`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Stale { .. } => "stale",
            Self::Jump { .. } => "jump",
            Self::Covariance { .. } => "covariance",
            Self::Inconsistent { .. } => "inconsistent",
        }
    }

    /// One line saying what failed, with the values.
    pub fn describe(&self) -> String {
        match *self {
            Self::Stale { age_s } => format!("stale: no sample for {age_s:.3} s"),
            Self::Jump { translation_m, yaw_rad, dt_s, predicted: true } => {
                format!("jump: {translation_m:.3} m and {:.1}° off the step its twist predicts over {dt_s:.3} s", yaw_rad.to_degrees())
            }
            Self::Jump { translation_m, yaw_rad, dt_s, predicted: false } => {
                format!("jump: a step of {translation_m:.3} m and {:.1}° in {dt_s:.3} s", yaw_rad.to_degrees())
            }
            Self::Covariance { position_std_m, yaw_std_rad } => {
                format!("covariance: position std {position_std_m:.3} m, yaw std {:.1}°", yaw_std_rad.to_degrees())
            }
            Self::Inconsistent { compared, agreed, error_m } => {
                format!("inconsistent: agrees with {agreed} of {compared} other sources (off by up to {error_m:.3} m)")
            }
        }
    }
}

/// What happened, on an [`OdometryMux::update`].
#[derive(Debug, Clone, PartialEq)]
pub enum MuxEvent {
    /// A source failed a check.
    Unhealthy {
        /// When \[s\].
        stamp_s: f64,
        /// Its index.
        source: usize,
        /// What failed.
        fault: Fault,
    },
    /// A source passed every check for `recover_s` and can be used again.
    Recovered {
        /// When \[s\].
        stamp_s: f64,
        /// Its index.
        source: usize,
    },
    /// The choice changed (`to` None: no usable source, the pose is held).
    Switch {
        /// When \[s\].
        stamp_s: f64,
        /// The source before, if any.
        from: Option<usize>,
        /// The source now, if any.
        to: Option<usize>,
        /// How far the pose was moved back \[m\]: 0, except when leaving a source the vote
        /// found inconsistent (module docs, "The choice and the pose").
        corrected_m: f64,
    },
    /// The only two comparable sources disagree (`disputed` true) or agree again.
    Dispute {
        /// When \[s\].
        stamp_s: f64,
        /// Whether they disagree now.
        disputed: bool,
        /// The error of the disagreement \[m\].
        error_m: f64,
    },
}

/// What one [`OdometryMux::update`] gives.
#[derive(Debug, Clone, PartialEq)]
pub struct MuxOutput {
    /// The stamp of the pose: the chosen source's newest sample, or the held pose's \[s\].
    pub stamp_s: f64,
    /// The body's pose in the mux's world frame (the first chosen source's, carried on
    /// across switches); None before any source has been chosen.
    pub world_from_body: Option<Isometry3>,
    /// The chosen source's index, None when none is usable.
    pub source: Option<usize>,
    /// How far the pose can be trusted, in [0, 1] (module docs).
    pub confidence: f64,
    /// Per source: the fault that keeps it from being used, None when usable.
    pub faults: Vec<Option<Fault>>,
    /// The events since the last update, in order.
    pub events: Vec<MuxEvent>,
}

#[derive(Debug, Clone)]
struct Source {
    spec: SourceSpec,
    /// Samples `(stamp, pose)` back to about twice the consistency window.
    history: VecDeque<(f64, Isometry3)>,
    last: Option<OdometrySample>,
    /// The output frame from this source's frame.
    anchor: Isometry3,
    /// The fault found on the last update, or latched by a jump.
    fault: Option<Fault>,
    /// When a check last failed \[s\].
    failed_at: Option<f64>,
    /// A jump found by `push`, reported on the next update.
    jump: Option<(f64, Fault)>,
    usable: bool,
}

/// The odometry multiplexer (module docs).
#[derive(Debug, Clone)]
pub struct OdometryMux {
    config: HeroConfig,
    sources: Vec<Source>,
    chosen: Option<usize>,
    /// The last output pose and its stamp.
    held: Option<(f64, Isometry3)>,
    /// The output poses `(stamp, pose)` back to about twice the consistency window.
    outputs: VecDeque<(f64, Isometry3)>,
    disputed: bool,
    last_update_s: Option<f64>,
}

fn yaw_of(r: &DMat3) -> f64 {
    r.x_axis.y.atan2(r.x_axis.x)
}

fn wrap(a: f64) -> f64 {
    let t = (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if t <= -std::f64::consts::PI {
        t + std::f64::consts::TAU
    } else {
        t
    }
}

fn compose(a: &Isometry3, b: &Isometry3) -> Isometry3 {
    Isometry3 { rotation: a.rotation * b.rotation, translation: a.rotation * b.translation + a.translation }
}

/// The pose at `t` in `history` (sorted by stamp), interpolated between its neighbours
/// (translation linearly, rotation by slerp); None outside the history's span.
fn pose_at(history: &VecDeque<(f64, Isometry3)>, t: f64) -> Option<Isometry3> {
    let (first, last) = (history.front()?, history.back()?);
    if t < first.0 || t > last.0 {
        return None;
    }
    let i = history.partition_point(|(s, _)| *s < t);
    let (t1, p1) = history[i];
    if i == 0 || t1 == t {
        return Some(p1);
    }
    let (t0, p0) = history[i - 1];
    let f = (t - t0) / (t1 - t0);
    let q0 = DQuat::from_mat3(&p0.rotation).normalize();
    let q1 = DQuat::from_mat3(&p1.rotation).normalize();
    Some(Isometry3 { rotation: DMat3::from_quat(q0.slerp(q1, f)), translation: p0.translation.lerp(p1.translation, f) })
}

impl OdometryMux {
    /// A mux over `sources`, most trusted first.
    pub fn new(config: HeroConfig, sources: &[SourceSpec]) -> Result<Self> {
        config.validate()?;
        if sources.is_empty() || sources.len() > MAX_SOURCES {
            return Err(Error::input("sources", format!("must name 1 to {MAX_SOURCES} sources, got {}", sources.len())));
        }
        for (k, s) in sources.iter().enumerate() {
            if s.name.is_empty() || s.name.len() > 64 || s.name.chars().any(char::is_control) {
                return Err(Error::input("sources", format!("source {k}: a name must be 1 to 64 printable characters, got {:?}", s.name)));
            }
            if sources[..k].iter().any(|o| o.name == s.name) {
                return Err(Error::input("sources", format!("source name {:?} is given twice", s.name)));
            }
            if !(s.rate_hz.is_finite() && s.rate_hz > 0.0 && s.rate_hz <= MAX_RATE_HZ) {
                return Err(Error::input("sources", format!("source {:?}: rate_hz must be in (0, {MAX_RATE_HZ}] Hz, got {}", s.name, s.rate_hz)));
            }
        }
        let sources = sources
            .iter()
            .map(|spec| Source {
                spec: spec.clone(),
                history: VecDeque::new(),
                last: None,
                anchor: Isometry3::IDENTITY,
                fault: None,
                failed_at: None,
                jump: None,
                usable: false,
            })
            .collect();
        Ok(Self { config, sources, chosen: None, held: None, outputs: VecDeque::new(), disputed: false, last_update_s: None })
    }

    /// The settings.
    pub fn config(&self) -> &HeroConfig {
        &self.config
    }

    /// The sources, most trusted first.
    pub fn sources(&self) -> Vec<&SourceSpec> {
        self.sources.iter().map(|s| &s.spec).collect()
    }

    /// The index of the source called `name`.
    pub fn index_of(&self, name: &str) -> Result<usize> {
        self.sources.iter().position(|s| s.spec.name == name).ok_or_else(|| {
            let known: Vec<&str> = self.sources.iter().map(|s| s.spec.name.as_str()).collect();
            Error::input("source", format!("no source {name:?}; the sources are {}", known.join(", ")))
        })
    }

    /// Takes one sample of source `source` (its index). Stamps must increase per source.
    pub fn push(&mut self, source: usize, sample: OdometrySample) -> Result<()> {
        let Some(s) = self.sources.get(source) else {
            return Err(Error::input("source", format!("index {source} is out of range: {} sources", self.sources.len())));
        };
        crate::frames::check_stamp("stamp", sample.stamp_s)?;
        if let Some(last) = &s.last {
            if sample.stamp_s <= last.stamp_s {
                return Err(Error::input(
                    "stamp",
                    format!("must increase per source: {} s after {} s from {:?}", sample.stamp_s, last.stamp_s, s.spec.name),
                ));
            }
        }
        let pose = sample.world_from_body;
        if !(pose.translation.is_finite() && pose.rotation.is_finite()) {
            return Err(Error::input("world_from_body", "must be finite"));
        }
        if pose.translation.abs().max_element() > MAX_TRANSLATION_M {
            return Err(Error::input("world_from_body", format!("translation {} is beyond {MAX_TRANSLATION_M} m", pose.translation)));
        }
        let r = pose.rotation;
        let off = (r.transpose() * r - DMat3::IDENTITY).abs().to_cols_array().iter().fold(0.0_f64, |a, &b| a.max(b));
        if off > 1e-6 || (r.determinant() - 1.0).abs() > 1e-6 {
            return Err(Error::input("world_from_body", "rotation is not a proper rotation"));
        }
        if let Some(c) = &sample.covariance {
            if c.iter().any(|v| !v.is_finite()) {
                return Err(Error::input("covariance", "must be finite"));
            }
            if (0..6).any(|k| c[k * 7] < 0.0) {
                return Err(Error::input("covariance", "its diagonal must be >= 0"));
            }
        }
        if let Some(t) = &sample.twist {
            if !(t.linear.is_finite() && t.angular.is_finite()) {
                return Err(Error::input("twist", "must be finite"));
            }
        }
        let config = self.config;
        let s = &mut self.sources[source];
        if let Some(prev) = s.last {
            let dt = sample.stamp_s - prev.stamp_s;
            let stale_gap = dt > config.stale_periods / s.spec.rate_hz;
            let delta = pose.translation - prev.world_from_body.translation;
            let dyaw = wrap(yaw_of(&pose.rotation) - yaw_of(&prev.world_from_body.rotation));
            // (translation, yaw) of the step or off its prediction, their bounds, the prediction.
            let (off_m, off_yaw, bound_m, bound_yaw, predicted) = match prev.twist {
                Some(t) if !stale_gap => {
                    let step = prev.world_from_body.rotation * (t.linear * dt);
                    let turn = t.angular.z * dt;
                    ((delta - step).length(), wrap(dyaw - turn).abs(), config.jump_m, config.jump_yaw_rad, Some((step, turn)))
                }
                _ => (
                    delta.length(),
                    dyaw.abs(),
                    config.max_speed_m_s * dt + config.jump_m,
                    config.max_yaw_rate_rad_s * dt + config.jump_yaw_rad,
                    None,
                ),
            };
            if off_m > bound_m || off_yaw > bound_yaw {
                let fault = Fault::Jump { translation_m: off_m, yaw_rad: off_yaw, dt_s: dt, predicted: predicted.is_some() };
                s.jump = Some((sample.stamp_s, fault));
                // The source's own stream stays continuous across its jump: the anchor
                // takes the jump (the predicted step is kept).
                let (step, turn) = predicted.unwrap_or((DVec3::ZERO, 0.0));
                let before = compose(&s.anchor, &prev.world_from_body);
                let expected = Isometry3 {
                    rotation: DMat3::from_rotation_z(turn) * before.rotation,
                    translation: before.translation + s.anchor.rotation * step,
                };
                let after = compose(&s.anchor, &pose);
                s.anchor = compose(&compose(&expected, &after.inverse()), &s.anchor);
                // Relative motions across the jump mean nothing.
                s.history.clear();
            }
        }
        s.history.push_back((sample.stamp_s, pose));
        let keep_from = sample.stamp_s - 2.0 * config.consistency_window_s - config.stale_periods / s.spec.rate_hz;
        while s.history.len() > MAX_HISTORY || s.history.front().is_some_and(|(t, _)| *t < keep_from) {
            s.history.pop_front();
        }
        s.last = Some(sample);
        Ok(())
    }

    /// Runs the checks at time `now_s`, chooses, and gives the pose (module docs).
    pub fn update(&mut self, now_s: f64) -> Result<MuxOutput> {
        if !now_s.is_finite() {
            return Err(Error::input("now", format!("must be finite, got {now_s}")));
        }
        if let Some(last) = self.last_update_s {
            if now_s < last {
                return Err(Error::input("now", format!("must not go back in time: {now_s} s after {last} s")));
            }
        }
        self.last_update_s = Some(now_s);
        let c = self.config;
        let mut events = Vec::new();
        let n = self.sources.len();

        // Per-source checks.
        let mut found: Vec<Option<Fault>> = vec![None; n];
        for (k, s) in self.sources.iter_mut().enumerate() {
            let Some(last) = s.last else {
                found[k] = Some(Fault::Stale { age_s: f64::INFINITY });
                continue;
            };
            let age = now_s - last.stamp_s;
            if age > c.stale_periods / s.spec.rate_hz {
                found[k] = Some(Fault::Stale { age_s: age });
            } else if let Some((at, fault)) = s.jump.take() {
                found[k] = Some(fault);
                s.failed_at = Some(s.failed_at.map_or(at, |f| f.max(at)));
            } else if let Some(cov) = &last.covariance {
                let position_std = cov[0].max(cov[7]).max(cov[14]).sqrt();
                let yaw_std = cov[35].sqrt();
                if position_std > c.max_position_std_m || yaw_std > c.max_yaw_std_rad {
                    found[k] = Some(Fault::Covariance { position_std_m: position_std, yaw_std_rad: yaw_std });
                }
            }
        }

        // Consistency between the fresh sources.
        let window = c.consistency_window_s;
        let mut compared = vec![0usize; n];
        let mut agreed = vec![0usize; n];
        let mut worst = vec![0.0f64; n];
        let mut pair_error = 0.0f64;
        for a in 0..n {
            for b in a + 1..n {
                if matches!(found[a], Some(Fault::Stale { .. })) || matches!(found[b], Some(Fault::Stale { .. })) {
                    continue;
                }
                let (ha, hb) = (&self.sources[a].history, &self.sources[b].history);
                let (Some(&(ta, _)), Some(&(tb, _))) = (ha.back(), hb.back()) else { continue };
                let t2 = ta.min(tb);
                let t1 = t2 - window;
                let (Some(a1), Some(a2), Some(b1), Some(b2)) = (pose_at(ha, t1), pose_at(ha, t2), pose_at(hb, t1), pose_at(hb, t2)) else {
                    continue;
                };
                let da = compose(&a1.inverse(), &a2);
                let db = compose(&b1.inverse(), &b2);
                let error = (da.translation - db.translation).length();
                let moved = da.translation.length().max(db.translation.length());
                let yaw_error = wrap(yaw_of(&da.rotation) - yaw_of(&db.rotation)).abs();
                let agree = error <= c.consistency_m + c.consistency_ratio * moved && yaw_error <= c.consistency_yaw_rad;
                for k in [a, b] {
                    compared[k] += 1;
                    agreed[k] += usize::from(agree);
                    if !agree {
                        worst[k] = worst[k].max(error);
                    }
                }
                pair_error = pair_error.max(if agree { 0.0 } else { error });
            }
        }
        let mut disputed_pair = false;
        for k in 0..n {
            if compared[k] >= 2 && 2 * agreed[k] < compared[k] && found[k].is_none() {
                found[k] = Some(Fault::Inconsistent { compared: compared[k], agreed: agreed[k], error_m: worst[k] });
            }
        }
        let comparable: usize = compared.iter().filter(|&&m| m > 0).count();
        if comparable == 2 && compared.iter().all(|&m| m <= 1) && agreed.iter().all(|&m| m == 0) {
            disputed_pair = true;
        }
        if disputed_pair != self.disputed {
            events.push(MuxEvent::Dispute { stamp_s: now_s, disputed: disputed_pair, error_m: pair_error });
            self.disputed = disputed_pair;
        }

        // Usability with the recovery time.
        for (k, s) in self.sources.iter_mut().enumerate() {
            match found[k] {
                Some(fault) => {
                    let newly = s.fault.is_none_or(|f| f.name() != fault.name());
                    if newly {
                        events.push(MuxEvent::Unhealthy { stamp_s: now_s, source: k, fault });
                    }
                    s.fault = Some(fault);
                    s.failed_at = Some(s.failed_at.map_or(now_s, |f| f.max(now_s)));
                    s.usable = false;
                }
                None => {
                    let rested = s.failed_at.is_none_or(|f| now_s - f >= c.recover_s);
                    if rested && !s.usable {
                        if s.failed_at.is_some() {
                            events.push(MuxEvent::Recovered { stamp_s: now_s, source: k });
                        }
                        s.usable = true;
                        s.fault = None;
                    }
                }
            }
        }

        // The choice, and the pose.
        let choice = self.sources.iter().position(|s| s.usable);
        if choice != self.chosen {
            let mut corrected_m = 0.0;
            if let Some(k) = choice {
                // Leaving a source the vote found inconsistent: its motion over the window was
                // wrong, so the output is taken back to where it was at the window's start and
                // the new source's motion since then is put on it.
                let rebase = self.chosen.filter(|&j| matches!(found[j], Some(Fault::Inconsistent { .. }))).and_then(|j| {
                    let last = self.sources[j].last?;
                    let t1 = last.stamp_s - window;
                    Some((t1, pose_at(&self.outputs, t1)?, last.stamp_s, compose(&self.sources[j].anchor, &last.world_from_body)))
                });
                let s = &mut self.sources[k];
                if let (Some((t_ref, reference)), Some(last)) = (rebase.map(|(t, p, _, _)| (t, p)).or(self.held), s.last) {
                    let pose = pose_at(&s.history, t_ref).unwrap_or(last.world_from_body);
                    s.anchor = compose(&reference, &pose.inverse());
                    if let Some((_, _, t_now, old_now)) = rebase {
                        // The old source's output now against the new one at the same stamp.
                        let new_now = compose(&s.anchor, &pose_at(&s.history, t_now).unwrap_or(last.world_from_body));
                        corrected_m = (new_now.translation - old_now.translation).length();
                    }
                }
            }
            events.push(MuxEvent::Switch { stamp_s: now_s, from: self.chosen, to: choice, corrected_m });
            self.chosen = choice;
        }
        let faults: Vec<Option<Fault>> = self.sources.iter().map(|s| if s.usable { None } else { s.fault.or(Some(Fault::Stale { age_s: f64::INFINITY })) }).collect();
        let Some(k) = self.chosen else {
            let (stamp_s, pose) = self.held.map_or((now_s, None), |(t, p)| (t, Some(p)));
            return Ok(MuxOutput { stamp_s, world_from_body: pose, source: None, confidence: 0.0, faults, events });
        };
        let s = &self.sources[k];
        let Some(last) = s.last else {
            return Err(Error::input("now", "internal: a usable source without a sample"));
        };
        let pose = compose(&s.anchor, &last.world_from_body);
        self.held = Some((last.stamp_s, pose));
        if self.outputs.back().is_none_or(|(t, _)| last.stamp_s > *t) {
            self.outputs.push_back((last.stamp_s, pose));
        }
        let keep_from = last.stamp_s - 2.0 * c.consistency_window_s;
        while self.outputs.len() > MAX_HISTORY || self.outputs.front().is_some_and(|(t, _)| *t < keep_from) {
            self.outputs.pop_front();
        }
        let sigma = last.covariance.map_or(0.0, |cov| cov[0].max(cov[7]).max(cov[14]).sqrt());
        let mut confidence = (1.0 - (sigma / c.max_position_std_m).powi(2)).clamp(0.0, 1.0);
        if self.disputed {
            confidence *= 0.5;
        }
        Ok(MuxOutput { stamp_s: last.stamp_s, world_from_body: Some(pose), source: Some(k), confidence, faults, events })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn specs(names: &[(&str, f64)]) -> Vec<SourceSpec> {
        names.iter().map(|&(n, r)| SourceSpec { name: n.into(), rate_hz: r }).collect()
    }

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3 {
        Isometry3 { rotation: DMat3::from_rotation_z(yaw), translation: DVec3::new(x, y, 0.0) }
    }

    fn sample(t: f64, p: Isometry3, twist: Option<Twist>) -> OdometrySample {
        OdometrySample { stamp_s: t, world_from_body: p, covariance: None, twist }
    }

    fn forward(v: f64) -> Option<Twist> {
        Some(Twist { linear: DVec3::new(v, 0.0, 0.0), angular: DVec3::ZERO })
    }

    /// The robot drives along +x at 1 m/s; three sources at 20 Hz see it, each in its own
    /// world frame (offset and turned); `tweak(source, t, pose)` bends one.
    fn drive(mux: &mut OdometryMux, from_s: f64, to_s: f64, tweak: &dyn Fn(usize, f64, Isometry3) -> Option<Isometry3>) -> Vec<MuxOutput> {
        let frames = [pose(0.0, 0.0, 0.0), pose(5.0, -2.0, 0.7), pose(-3.0, 1.0, -1.2)];
        let mut out = Vec::new();
        let steps = ((to_s - from_s) / 0.05).round() as u32;
        for i in 0..steps {
            // Stamps a little after the 50 ms grid, so that `t >= 2.0` is the step at 2 s.
            let t = from_s + f64::from(i) * 0.05 + 1e-6;
            for (k, frame) in frames.iter().enumerate().take(mux.sources.len()) {
                let truth = pose(t, 0.0, 0.0);
                if let Some(p) = tweak(k, t, compose(frame, &truth)) {
                    mux.push(k, sample(t, p, forward(1.0))).unwrap();
                }
            }
            out.push(mux.update(t).unwrap());
        }
        out
    }

    /// The largest distance of an output from the truth at its stamp (the output's world
    /// frame is the first source's, where the truth is `pose(t, 0, 0)`): a pose that jumps
    /// when the choice switches is off by the jump.
    fn max_error(outputs: &[MuxOutput]) -> f64 {
        outputs
            .iter()
            .filter_map(|o| Some((o.world_from_body?.translation - DVec3::new(o.stamp_s, 0.0, 0.0)).length()))
            .fold(0.0, f64::max)
    }

    fn three() -> OdometryMux {
        OdometryMux::new(HeroConfig::default(), &specs(&[("vio", 20.0), ("lidar", 20.0), ("wheels", 20.0)])).unwrap()
    }

    #[test]
    fn healthy_sources_give_the_first_and_its_pose() {
        let mut mux = three();
        let out = drive(&mut mux, 0.0, 3.0, &|_, _, p| Some(p));
        let last = out.last().unwrap();
        assert_eq!(last.source, Some(0));
        assert!((last.confidence - 1.0).abs() < 1e-12);
        assert!((last.world_from_body.unwrap().translation - DVec3::new(2.95, 0.0, 0.0)).length() < 1e-5);
        assert!(last.faults.iter().all(Option::is_none));
        assert!(max_error(&out) < 1e-6);
    }

    #[test]
    fn a_jump_switches_with_a_continuous_pose_and_recovers_later() {
        let mut mux = three();
        // vio relocalises at t = 2 s: its pose jumps 1.5 m sideways from then on.
        let out = drive(&mut mux, 0.0, 6.0, &|k, t, p| Some(if k == 0 && t >= 2.0 { compose(&pose(0.0, 1.5, 0.0), &p) } else { p }));
        let at = |t: f64| &out[(t / 0.05).round() as usize];
        assert_eq!(at(1.9).source, Some(0));
        assert_eq!(at(2.0).source, Some(1), "switched to lidar on the jump");
        assert!(at(2.0).events.iter().any(|e| matches!(e, MuxEvent::Unhealthy { source: 0, fault: Fault::Jump { .. }, .. })));
        assert!(at(2.0).events.iter().any(|e| matches!(e, MuxEvent::Switch { from: Some(0), to: Some(1), .. })));
        // The output follows the truth through the switch and back.
        assert!(max_error(&out) < 1e-6, "{}", max_error(&out));
        // vio is used again recover_s after its jump, re-anchored: still no jump.
        assert_eq!(at(4.1).source, Some(0));
        let end = out.last().unwrap().world_from_body.unwrap().translation;
        assert!((end - DVec3::new(5.95, 0.0, 0.0)).length() < 0.06, "{end}");
    }

    #[test]
    fn a_stale_source_is_left_and_taken_back() {
        let mut mux = three();
        let out = drive(&mut mux, 0.0, 6.0, &|k, t, p| if k == 0 && (2.0..3.0).contains(&t) { None } else { Some(p) });
        let at = |t: f64| &out[(t / 0.05).round() as usize];
        // Stale after 3 periods (0.15 s) without a sample.
        assert_eq!(at(2.05).source, Some(0));
        assert_eq!(at(2.25).source, Some(1));
        assert!(matches!(at(2.5).faults[0], Some(Fault::Stale { .. })));
        assert_eq!(at(4.9).source, Some(1), "not before recover_s of health");
        assert_eq!(at(5.1).source, Some(0));
        assert!(max_error(&out) < 1e-6);
    }

    #[test]
    fn a_drifting_source_is_outvoted() {
        let mut mux = three();
        // vio drifts sideways at 0.3 m/s from t = 3 s: no single step jumps.
        let out = drive(&mut mux, 0.0, 8.0, &|k, t, p| Some(if k == 0 && t > 3.0 { compose(&pose(0.0, 0.3 * (t - 3.0), 0.0), &p) } else { p }));
        let flagged = out.iter().position(|o| matches!(o.faults[0], Some(Fault::Inconsistent { .. }))).unwrap();
        let t = flagged as f64 * 0.05;
        assert!(t > 3.0 && t < 5.0, "flagged at {t} s");
        assert_eq!(out[flagged].source, Some(1));
        assert!(out[flagged].faults[1].is_none() && out[flagged].faults[2].is_none());
        // The switch takes the output back to the window's start (before the drift began)
        // and puts lidar's motion on it: the drift is taken out, not carried on.
        let switch = out[flagged].events.iter().find_map(|e| match e {
            MuxEvent::Switch { to: Some(1), corrected_m, .. } => Some(*corrected_m),
            _ => None,
        });
        let drifted = 0.3 * (t - 0.05 - 3.0);
        assert!(switch.is_some_and(|c| (c - drifted).abs() < 0.05), "{switch:?} against {drifted}");
        assert!(max_error(&out[flagged..]) < 1e-6, "{}", max_error(&out[flagged..]));
    }

    #[test]
    fn two_sources_that_disagree_are_a_dispute_not_a_verdict() {
        let mut mux = OdometryMux::new(HeroConfig::default(), &specs(&[("vio", 20.0), ("wheels", 20.0)])).unwrap();
        let out = drive(&mut mux, 0.0, 6.0, &|k, t, p| Some(if k == 1 && t > 2.0 { compose(&pose(0.0, 0.4 * (t - 2.0), 0.0), &p) } else { p }));
        let last = out.last().unwrap();
        assert_eq!(last.source, Some(0));
        assert!((last.confidence - 0.5).abs() < 1e-12);
        assert!(out.iter().flat_map(|o| &o.events).any(|e| matches!(e, MuxEvent::Dispute { disputed: true, .. })));
    }

    #[test]
    fn with_every_source_lost_the_pose_is_held_at_confidence_zero() {
        let mut mux = three();
        let out = drive(&mut mux, 0.0, 6.0, &|_, t, p| if (2.0..3.0).contains(&t) { None } else { Some(p) });
        let at = |t: f64| &out[(t / 0.05).round() as usize];
        assert_eq!(at(2.5).source, None);
        assert_eq!(at(2.5).confidence, 0.0);
        assert_eq!(at(2.5).world_from_body, at(1.95).world_from_body);
        assert_eq!(out[40..50].iter().flat_map(|o| &o.events).filter(|e| matches!(e, MuxEvent::Switch { to: None, .. })).count(), 1);
        // Back after recover_s: re-anchored where the held pose was (its history spans
        // the gap), so on the truth again.
        assert_eq!(at(5.1).source, Some(0));
        assert!(max_error(&out) < 1e-6);
    }

    #[test]
    fn a_covariance_beyond_the_bound_is_not_used() {
        let mut mux = OdometryMux::new(HeroConfig::default(), &specs(&[("vio", 10.0), ("wheels", 10.0)])).unwrap();
        let mut cov = [0.0; 36];
        cov[0] = 0.36;
        cov[7] = 0.01;
        mux.push(0, OdometrySample { stamp_s: 0.0, world_from_body: pose(0.0, 0.0, 0.0), covariance: Some(cov), twist: None }).unwrap();
        mux.push(1, sample(0.0, pose(0.0, 0.0, 0.0), None)).unwrap();
        let out = mux.update(0.0).unwrap();
        assert_eq!(out.source, Some(1));
        assert!(matches!(out.faults[0], Some(Fault::Covariance { position_std_m, .. }) if (position_std_m - 0.6).abs() < 1e-12));
        // Within the bound, the confidence falls with the variance.
        let mut mux = OdometryMux::new(HeroConfig::default(), &specs(&[("vio", 10.0)])).unwrap();
        cov[0] = 0.0625;
        mux.push(0, OdometrySample { stamp_s: 0.0, world_from_body: pose(0.0, 0.0, 0.0), covariance: Some(cov), twist: None }).unwrap();
        assert!((mux.update(0.0).unwrap().confidence - 0.75).abs() < 1e-12);
    }

    #[test]
    fn bad_input_names_its_argument() {
        let bad = |s: &[SourceSpec]| OdometryMux::new(HeroConfig::default(), s).unwrap_err().to_string();
        assert!(bad(&[]).contains("sources"));
        assert!(bad(&specs(&[("a", 10.0), ("a", 10.0)])).contains("twice"));
        assert!(bad(&specs(&[("a", 0.0)])).contains("rate_hz"));
        let mut mux = three();
        mux.push(0, sample(1.0, pose(0.0, 0.0, 0.0), None)).unwrap();
        assert!(mux.push(0, sample(1.0, pose(0.0, 0.0, 0.0), None)).unwrap_err().to_string().contains("stamp"));
        assert!(mux.push(7, sample(2.0, pose(0.0, 0.0, 0.0), None)).unwrap_err().to_string().contains("source"));
        assert!(mux.push(1, sample(f64::NAN, pose(0.0, 0.0, 0.0), None)).unwrap_err().to_string().contains("stamp"));
        let mut skew = pose(0.0, 0.0, 0.0);
        skew.rotation.x_axis.x = 2.0;
        assert!(mux.push(1, sample(1.0, skew, None)).unwrap_err().to_string().contains("world_from_body"));
        let far = pose(1e7, 0.0, 0.0);
        assert!(mux.push(1, sample(1.0, far, None)).unwrap_err().to_string().contains("world_from_body"));
        let cov = Some([f64::NAN; 36]);
        assert!(mux.push(1, OdometrySample { stamp_s: 1.0, world_from_body: pose(0.0, 0.0, 0.0), covariance: cov, twist: None }).unwrap_err().to_string().contains("covariance"));
        assert!(mux.update(f64::INFINITY).unwrap_err().to_string().contains("now"));
        mux.update(5.0).unwrap();
        assert!(mux.update(4.0).unwrap_err().to_string().contains("now"));
        assert!(mux.index_of("gps").unwrap_err().to_string().contains("vio, lidar, wheels"));
        let c = HeroConfig { consistency_ratio: 2.0, ..HeroConfig::default() };
        assert!(c.validate().unwrap_err().to_string().contains("hero.consistency_ratio"));
    }
}
