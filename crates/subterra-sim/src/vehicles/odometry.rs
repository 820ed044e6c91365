//! Drifting odometry: the random-walk noise model, the drift state of one vehicle and the
//! standard normal draws it takes.

use std::f64::consts::PI;

use glam::{DMat3, DVec3};
use rand::Rng;
use serde::{Deserialize, Serialize};
use subterra::Isometry3;

use super::dynamics::require_non_negative;
use crate::error::SimResult;

/// Odometry drift: a random-walk bias added to the true position (each axis) and yaw.
/// After `t` seconds the bias has standard deviation `walk·√t` per axis.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OdometryNoise {
    /// Position random-walk intensity [m/√s] (per axis).
    pub position_walk_m_per_sqrt_s: f64,
    /// Yaw random-walk intensity [rad/√s].
    pub yaw_walk_rad_per_sqrt_s: f64,
}

impl OdometryNoise {
    /// Checks both intensities are finite and >= 0; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> SimResult<()> {
        require_non_negative(&format!("{prefix}.position_walk_m_per_sqrt_s"), self.position_walk_m_per_sqrt_s)?;
        require_non_negative(&format!("{prefix}.yaw_walk_rad_per_sqrt_s"), self.yaw_walk_rad_per_sqrt_s)
    }
}

/// The drifting odometry of one vehicle: the bias of [`OdometryNoise`] and the time not
/// yet folded into it. Odometry = truth with `bias_position_m` added to the position,
/// the body rotated by `bias_yaw_rad` about world z and the velocity rotated likewise.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdometryDrift {
    /// The noise intensities; `None`: odometry equals the truth and draws nothing.
    pub noise: Option<OdometryNoise>,
    /// Current position bias [m].
    pub bias_position_m: DVec3,
    /// Current yaw bias [rad].
    pub bias_yaw_rad: f64,
    /// Time elapsed since the bias was last drawn [s].
    pending_s: f64,
}

impl OdometryDrift {
    /// A drift with zero bias.
    pub fn new(noise: Option<OdometryNoise>) -> Self {
        Self { noise, ..Self::default() }
    }

    /// Lets `dt_s` seconds pass (the bias walks over them at the next [`Self::advance`]).
    pub fn elapse(&mut self, dt_s: f64) {
        if dt_s.is_finite() && dt_s > 0.0 {
            self.pending_s += dt_s;
        }
    }

    /// Draws the random walk over the elapsed time: each bias component gets a Gaussian
    /// increment of standard deviation `walk·√elapsed`. Draws nothing without noise or
    /// when no time has passed.
    pub fn advance<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let Some(noise) = self.noise else { return };
        if self.pending_s <= 0.0 {
            return;
        }
        let scale = self.pending_s.sqrt();
        self.pending_s = 0.0;
        let sp = noise.position_walk_m_per_sqrt_s * scale;
        self.bias_position_m += DVec3::new(standard_normal(rng), standard_normal(rng), standard_normal(rng)) * sp;
        self.bias_yaw_rad += standard_normal(rng) * noise.yaw_walk_rad_per_sqrt_s * scale;
    }

    /// The odometry `(world_from_body, velocity_world)` of a true pose and velocity.
    pub fn apply(&self, world_from_body: &Isometry3, velocity_world: DVec3) -> (Isometry3, DVec3) {
        let r = DMat3::from_rotation_z(self.bias_yaw_rad);
        let pose = Isometry3 { rotation: r * world_from_body.rotation, translation: world_from_body.translation + self.bias_position_m };
        (pose, r * velocity_world)
    }
}

/// A standard normal draw (Box-Muller, one of the pair; 53-bit uniforms).
pub(crate) fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    // u1 in (0, 1], u2 in [0, 1).
    let u1 = ((rng.next_u64() >> 11) as f64 + 1.0) * (1.0 / (1u64 << 53) as f64);
    let u2 = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}
