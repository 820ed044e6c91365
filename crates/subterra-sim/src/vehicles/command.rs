//! The velocity command both vehicles take: body-frame velocity (FLU) and a yaw rate.

use serde::{Deserialize, Serialize};

use crate::error::{SimError, SimResult};

/// A velocity command in the body frame (FLU) with a yaw rate about the world z axis.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BodyVelocityCommand {
    /// Forward velocity [m/s].
    pub v_x_m_s: f64,
    /// Leftward velocity [m/s] (holonomic mode; a ground robot ignores it).
    pub v_y_m_s: f64,
    /// Upward velocity [m/s] (a ground robot ignores it).
    pub v_z_m_s: f64,
    /// Yaw rate, counter-clockwise seen from above [rad/s].
    pub yaw_rate_rad_s: f64,
}

impl BodyVelocityCommand {
    /// Zero velocity: hover / stand still.
    pub const ZERO: Self = Self { v_x_m_s: 0.0, v_y_m_s: 0.0, v_z_m_s: 0.0, yaw_rate_rad_s: 0.0 };

    /// A command from its four components [m/s, m/s, m/s, rad/s].
    pub fn new(v_x_m_s: f64, v_y_m_s: f64, v_z_m_s: f64, yaw_rate_rad_s: f64) -> Self {
        Self { v_x_m_s, v_y_m_s, v_z_m_s, yaw_rate_rad_s }
    }

    /// Checks that every component is finite; the error names `argument.component`.
    pub fn validate(&self, argument: &str) -> SimResult<()> {
        for (name, value) in self.components() {
            if !value.is_finite() {
                return Err(SimError::input(format!("{argument}.{name}"), format!("must be finite, got {value}")));
            }
        }
        Ok(())
    }

    /// The components with their field names.
    fn components(&self) -> [(&'static str, f64); 4] {
        [
            ("v_x_m_s", self.v_x_m_s),
            ("v_y_m_s", self.v_y_m_s),
            ("v_z_m_s", self.v_z_m_s),
            ("yaw_rate_rad_s", self.yaw_rate_rad_s),
        ]
    }

    /// Non-finite components replaced by zero (a vehicle never integrates a NaN).
    pub(super) fn sanitised(&self) -> Self {
        let f = |x: f64| if x.is_finite() { x } else { 0.0 };
        Self::new(f(self.v_x_m_s), f(self.v_y_m_s), f(self.v_z_m_s), f(self.yaw_rate_rad_s))
    }
}
