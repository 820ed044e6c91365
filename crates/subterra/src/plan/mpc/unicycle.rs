//! The unicycle: exact discrete dynamics and their Jacobians.
//!
//! State `[x, y, θ, v]` (world position \[m\], heading from world x \[rad\], forward speed
//! [m/s]); input `[a, ω]` (acceleration [m/s²], yaw rate [rad/s]) held constant over a step
//! of `T` seconds. Over the step `v(t) = v + a·t`, `θ(t) = θ + ω·t`, and the position moves
//! by `∫₀ᵀ v(t)·(cos θ(t), sin θ(t)) dt`. With `h = ω·T` that integral is exactly
//!
//! ```text
//! Δp = R(θ) · T · ( v·C0(h) + a·T·C1(h),  v·S0(h) + a·T·S1(h) )
//! Ck(h) = ∫₀¹ τᵏ cos(hτ) dτ,   Sk(h) = ∫₀¹ τᵏ sin(hτ) dτ
//! ```
//!
//! `Ck`, `Sk` are summed from their power series for `|h| <= 1` (ten terms: the first
//! dropped term is below 2e-16 relative) and from their closed forms (`C0 = sin h / h`, ...)
//! beyond, so small yaw rates lose no digits to cancellation. `θ` is not wrapped.

use glam::DVec2;

/// Largest `|h| = |ω·T|` summed by the power series; the closed forms are used beyond.
const SERIES_MAX_H: f64 = 1.0;
/// Terms of the power series (the first dropped one is `< 1/18! < 2e-16` for `|h| <= 1`).
const SERIES_TERMS: usize = 10;

/// The state of a unicycle in the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UnicycleState {
    /// World x \[m\].
    pub x_m: f64,
    /// World y \[m\].
    pub y_m: f64,
    /// Heading, counter-clockwise from world x \[rad\] (not wrapped).
    pub heading_rad: f64,
    /// Forward speed [m/s]; negative when backing up.
    pub speed_m_s: f64,
}

impl UnicycleState {
    /// The state from `[x, y, θ, v]`.
    pub fn from_array(s: [f64; 4]) -> Self {
        Self { x_m: s[0], y_m: s[1], heading_rad: s[2], speed_m_s: s[3] }
    }

    /// `[x, y, θ, v]`.
    pub fn to_array(self) -> [f64; 4] {
        [self.x_m, self.y_m, self.heading_rad, self.speed_m_s]
    }

    /// World position \[m\].
    pub fn position(&self) -> DVec2 {
        DVec2::new(self.x_m, self.y_m)
    }

    /// Whether every component is finite.
    pub fn is_finite(&self) -> bool {
        self.to_array().iter().all(|v| v.is_finite())
    }
}

/// An input of a unicycle, held constant over one step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UnicycleInput {
    /// Forward acceleration [m/s²].
    pub accel_m_s2: f64,
    /// Yaw rate, counter-clockwise [rad/s].
    pub yaw_rate_rad_s: f64,
}

/// `∂x⁺/∂x` (4x4) and `∂x⁺/∂u` (4x2) of one step, rows and columns in `[x, y, θ, v]`,
/// `[a, ω]` order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StepJacobians {
    /// `∂x⁺/∂x`.
    pub a: [[f64; 4]; 4],
    /// `∂x⁺/∂u`.
    pub b: [[f64; 2]; 4],
}

/// `[C0, C1, C2, S0, S1, S2]` at `h` (see `MpcTracker`'s docs).
fn moments(h: f64) -> [f64; 6] {
    if h.abs() <= SERIES_MAX_H {
        // Ck = Σ_j (-1)^j h^{2j} / ((2j)! (2j+k+1)),  Sk = Σ_j (-1)^j h^{2j+1} / ((2j+1)! (2j+k+2)).
        let mut c = [0.0; 3];
        let mut s = [0.0; 3];
        let mut even = 1.0; // (-1)^j h^{2j} / (2j)!
        for j in 0..SERIES_TERMS {
            let odd = even * h / (2 * j + 1) as f64; // (-1)^j h^{2j+1} / (2j+1)!
            for k in 0..3 {
                c[k] += even / (2 * j + k + 1) as f64;
                s[k] += odd / (2 * j + k + 2) as f64;
            }
            even = -odd * h / (2 * j + 2) as f64;
        }
        [c[0], c[1], c[2], s[0], s[1], s[2]]
    } else {
        let (sin, cos) = h.sin_cos();
        let (h2, h3) = (h * h, h * h * h);
        [
            sin / h,
            (h * sin + cos - 1.0) / h2,
            (h2 * sin + 2.0 * h * cos - 2.0 * sin) / h3,
            (1.0 - cos) / h,
            (sin - h * cos) / h2,
            (-h2 * cos + 2.0 * h * sin + 2.0 * cos - 2.0) / h3,
        ]
    }
}

/// One exact step of `dt_s` seconds.
pub fn step(state: &UnicycleState, input: &UnicycleInput, dt_s: f64) -> UnicycleState {
    step_with_jacobians(state, input, dt_s).0
}

/// One exact step and its Jacobians at `(state, input)`.
pub(crate) fn step_with_jacobians(state: &UnicycleState, input: &UnicycleInput, dt_s: f64) -> (UnicycleState, StepJacobians) {
    let t = dt_s;
    let (v, a, w) = (state.speed_m_s, input.accel_m_s2, input.yaw_rate_rad_s);
    let [c0, c1, c2, s0, s1, s2] = moments(w * t);
    // Displacement in the frame of the initial heading, and its derivatives.
    let along = t * (v * c0 + a * t * c1);
    let across = t * (v * s0 + a * t * s1);
    let d_dv = (t * c0, t * s0);
    let d_da = (t * t * c1, t * t * s1);
    let d_dw = (t * t * (-v * s1 - a * t * s2), t * t * (v * c1 + a * t * c2));
    let (sin, cos) = state.heading_rad.sin_cos();
    let rotate = |(p, q): (f64, f64)| (cos * p - sin * q, sin * p + cos * q);
    let (dx, dy) = rotate((along, across));
    let next = UnicycleState {
        x_m: state.x_m + dx,
        y_m: state.y_m + dy,
        heading_rad: state.heading_rad + w * t,
        speed_m_s: v + a * t,
    };
    let (dx_dv, dy_dv) = rotate(d_dv);
    let (dx_da, dy_da) = rotate(d_da);
    let (dx_dw, dy_dw) = rotate(d_dw);
    let jac = StepJacobians {
        a: [[1.0, 0.0, -dy, dx_dv], [0.0, 1.0, dx, dy_dv], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
        b: [[dx_da, dx_dw], [dy_da, dy_dw], [0.0, t], [t, 0.0]],
    };
    (next, jac)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `∫₀ᵀ (v + a s)(cos, sin)(θ + ω s) ds` by composite Simpson with `n` panels.
    fn quadrature(s: &UnicycleState, u: &UnicycleInput, t: f64, n: usize) -> (f64, f64) {
        let f = |x: f64| {
            let speed = s.speed_m_s + u.accel_m_s2 * x;
            let heading = s.heading_rad + u.yaw_rate_rad_s * x;
            (speed * heading.cos(), speed * heading.sin())
        };
        let h = t / n as f64;
        let (mut sx, mut sy) = (0.0, 0.0);
        for i in 0..=n {
            let w = if i == 0 || i == n { 1.0 } else if i % 2 == 1 { 4.0 } else { 2.0 };
            let (fx, fy) = f(i as f64 * h);
            sx += w * fx;
            sy += w * fy;
        }
        (sx * h / 3.0, sy * h / 3.0)
    }

    #[test]
    fn straight_line_by_hand() {
        // ω = 0: x moves v·T + a·T²/2 along the heading.
        let s = UnicycleState { x_m: 1.0, y_m: 2.0, heading_rad: 0.0, speed_m_s: 0.5 };
        let n = step(&s, &UnicycleInput { accel_m_s2: 1.0, yaw_rate_rad_s: 0.0 }, 0.1);
        assert!((n.x_m - (1.0 + 0.05 + 0.005)).abs() < 1e-15);
        assert_eq!((n.y_m, n.heading_rad), (2.0, 0.0));
        assert!((n.speed_m_s - 0.6).abs() < 1e-15);
    }

    #[test]
    fn circle_by_hand() {
        // a = 0: an arc of radius v/ω; a quarter turn ends at (r, r) from the start.
        let s = UnicycleState { x_m: 0.0, y_m: 0.0, heading_rad: 0.0, speed_m_s: 2.0 };
        let w = std::f64::consts::FRAC_PI_2;
        let n = step(&s, &UnicycleInput { accel_m_s2: 0.0, yaw_rate_rad_s: w }, 1.0);
        let r = 2.0 / w;
        assert!((n.x_m - r).abs() < 1e-14 && (n.y_m - r).abs() < 1e-14, "{n:?}");
    }

    #[test]
    fn matches_quadrature_on_both_branches() {
        for &(w, t) in &[(0.0, 0.1), (1e-9, 0.1), (0.3, 0.1), (9.9, 0.1), (10.1, 0.1), (-25.0, 0.1), (3.0, 2.0)] {
            let s = UnicycleState { x_m: -0.3, y_m: 0.7, heading_rad: 2.1, speed_m_s: -0.4 };
            let u = UnicycleInput { accel_m_s2: 1.7, yaw_rate_rad_s: w };
            let n = step(&s, &u, t);
            let (qx, qy) = quadrature(&s, &u, t, 2000);
            assert!((n.x_m - s.x_m - qx).abs() < 1e-12 && (n.y_m - s.y_m - qy).abs() < 1e-12, "w={w}: {n:?} vs {qx} {qy}");
        }
    }

    #[test]
    fn jacobians_match_central_differences() {
        for &w in &[0.0, 0.2, -1.4, 12.0] {
            let s = UnicycleState { x_m: 0.5, y_m: -1.0, heading_rad: 0.8, speed_m_s: 0.9 };
            let u = UnicycleInput { accel_m_s2: -0.6, yaw_rate_rad_s: w };
            let (_, jac) = step_with_jacobians(&s, &u, 0.1);
            let e = 1e-6;
            for i in 0..4 {
                let mut p = s.to_array();
                let mut m = s.to_array();
                p[i] += e;
                m[i] -= e;
                let fp = step(&UnicycleState::from_array(p), &u, 0.1).to_array();
                let fm = step(&UnicycleState::from_array(m), &u, 0.1).to_array();
                for r in 0..4 {
                    assert!(((fp[r] - fm[r]) / (2.0 * e) - jac.a[r][i]).abs() < 1e-8, "A[{r}][{i}] at w={w}");
                }
            }
            for c in 0..2 {
                let shift = |d: f64| {
                    let mut v = u;
                    if c == 0 {
                        v.accel_m_s2 += d;
                    } else {
                        v.yaw_rate_rad_s += d;
                    }
                    step(&s, &v, 0.1).to_array()
                };
                let (fp, fm) = (shift(e), shift(-e));
                for r in 0..4 {
                    assert!(((fp[r] - fm[r]) / (2.0 * e) - jac.b[r][c]).abs() < 1e-8, "B[{r}][{c}] at w={w}");
                }
            }
        }
    }

    #[test]
    fn series_and_closed_form_agree_at_the_switch() {
        let below = moments(SERIES_MAX_H);
        let above = moments(SERIES_MAX_H * (1.0 + 1e-12));
        for (b, a) in below.iter().zip(above) {
            assert!((b - a).abs() < 1e-12, "{below:?} vs {above:?}");
        }
    }
}
