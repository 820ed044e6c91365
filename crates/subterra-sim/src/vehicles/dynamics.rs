//! Motion helpers shared by the vehicles: the step-length limit, angle wrapping, the exact
//! first-order lag, rate ramps, exact unicycle arcs, and the range checks of their configs.

use std::f64::consts::PI;

use crate::error::{SimError, SimResult};

/// Longest step accepted by the vehicles [s]; longer (or non-positive) steps are ignored.
pub const MAX_STEP_S: f64 = 60.0;

/// Wraps an angle to (-π, π] [rad].
pub fn wrap_angle(angle_rad: f64) -> f64 {
    let a = (angle_rad + PI).rem_euclid(2.0 * PI) - PI;
    if a <= -PI {
        a + 2.0 * PI
    } else {
        a
    }
}

pub(super) fn require_positive(field: &str, value: f64) -> SimResult<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SimError::config(field, "must be finite and > 0", value))
    }
}

pub(super) fn require_non_negative(field: &str, value: f64) -> SimResult<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimError::config(field, "must be finite and >= 0", value))
    }
}

pub(super) fn step_is_valid(dt_s: f64) -> bool {
    dt_s.is_finite() && dt_s > 0.0 && dt_s <= MAX_STEP_S
}

/// `∫_0^t e^{-s/τ} ds = τ·(1 - e^{-t/τ})` [s]; `0` lag (τ = 0) gives 0.
pub(super) fn lag_integral(t_s: f64, tau_s: f64) -> f64 {
    if tau_s > 0.0 {
        -tau_s * (-t_s / tau_s).exp_m1()
    } else {
        0.0
    }
}

/// `e^{-t/τ}`; 0 for τ = 0 (no lag).
pub(super) fn lag_decay(t_s: f64, tau_s: f64) -> f64 {
    if tau_s > 0.0 {
        (-t_s / tau_s).exp()
    } else {
        0.0
    }
}

/// A rate moving from `from` toward `to` at most `max_rate` per second (`None`: jumps to
/// `to` at once) over `h` seconds: `(value at the end, mean value over the interval)`.
/// The mean is exact for the linear ramp, also when it reaches `to` within the interval.
pub(super) fn ramp(from: f64, to: f64, max_rate: Option<f64>, h: f64) -> (f64, f64) {
    let Some(rate) = max_rate else { return (to, to) };
    let change = to - from;
    let t_reach = change.abs() / rate;
    if t_reach >= h {
        let end = from + rate * h * change.signum();
        (end, 0.5 * (from + end))
    } else {
        // Ramp for t_reach, then hold `to`.
        let mean = (0.5 * (from + to) * t_reach + to * (h - t_reach)) / h;
        (to, mean)
    }
}

/// Exact unicycle motion for constant `(v, ω)` over `dt`: a straight segment for ω = 0,
/// else a circular arc. Returns `(x, y, yaw)` with the yaw wrapped to (-π, π].
pub fn unicycle_arc(x_m: f64, y_m: f64, yaw_rad: f64, v_m_s: f64, omega_rad_s: f64, dt_s: f64) -> (f64, f64, f64) {
    let dyaw = omega_rad_s * dt_s;
    // Chord of the arc: length v·dt·sinc(dψ/2) along the mid heading.
    let half = 0.5 * dyaw;
    let sinc = if half.abs() < 1e-6 { 1.0 - half * half / 6.0 } else { half.sin() / half };
    let chord = v_m_s * dt_s * sinc;
    let mid = yaw_rad + half;
    (x_m + chord * mid.cos(), y_m + chord * mid.sin(), wrap_angle(yaw_rad + dyaw))
}
