//! Artificial potential fields: the belief-weighted repulsion and the goal's attraction
//! become a velocity command (APF-PF paper §IV, eq. 10).
//!
//! In: the goal relative to the robot in the body frame, and the repulsive forces of one
//! or more cameras' perception (already belief-weighted, in the body frame). Out: a
//! [`Command`]. [`ObstacleMemory`] keeps where the belief put obstacles, so that they still
//! repel out of view, [`Escape`] gets the robot out of the field's local minima by following
//! the remembered obstacles' boundary, and [`PathFollower`] leads it along a path of
//! waypoints (all three subterra). [`BeliefForces`] weighs each camera's belief into a
//! repulsion, [`Qmdp`] picks actions over the belief instead of the field, and [`Pilot`]
//! wires it all into the drone's loop, once.
//!
//! `apf` reads `depth` (a perception's grid, mounting and belief); `depth` knows nothing of
//! potentials.

mod carrot;
mod escape;
mod forces;
mod memory;
mod pilot;
mod qmdp;

pub use carrot::{CarrotOutput, PathFollower, DEFAULT_LOOKAHEAD_M};
pub use escape::{Escape, EscapeMode, EscapeOutput};
pub use forces::BeliefForces;
pub use memory::{MemoryOutput, ObstacleMemory, RememberedObstacle};
pub use pilot::{controller_named, Pilot, PilotCamera, PilotController, PilotOutput, PilotTimings, CONTROLLER_NAMES, MAX_CAMERAS};
pub use qmdp::{Qmdp, QmdpAction, QmdpConfig};

use std::f64::consts::PI;

use glam::DVec3;

use crate::config::{ApfConfig, CommandMode};
use crate::error::{Error, Result};

/// Attractive force toward `goal_body` \[m\]: parabolic (`ξ·x`) within `ρ_r`, conic
/// (`ρ_r·ξ·x/|x|`, constant magnitude) beyond.
pub fn attractive_force(config: &ApfConfig, goal_body: DVec3) -> DVec3 {
    let d = goal_body.length();
    if d <= config.rho_r_m {
        config.xi * goal_body
    } else {
        config.rho_r_m * config.xi * goal_body / d
    }
}

/// Repulsive force of an obstacle at `x_body`: `η(1/|x| - 1/ρ_0)/|x|² · (-x/|x|)` inside
/// `ρ_0`, zero beyond; `|x|` clamped below at `min_distance_m` in the magnitude.
pub fn repulsive_force(config: &ApfConfig, x_body: DVec3) -> DVec3 {
    let d = x_body.length();
    let r = d.max(config.min_distance_m);
    if r >= config.rho_0_m || d == 0.0 {
        return DVec3::ZERO;
    }
    let magnitude = config.eta * (1.0 / r - 1.0 / config.rho_0_m) / (r * r);
    -magnitude * x_body / d
}

/// A velocity command in the body frame (FLU).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Command {
    /// Forward speed [m/s].
    pub v_x_m_s: f64,
    /// Lateral speed [m/s] (holonomic mode only; 0 otherwise).
    pub v_y_m_s: f64,
    /// Vertical speed [m/s].
    pub v_z_m_s: f64,
    /// Yaw rate [rad/s], positive counter-clockwise seen from above.
    pub yaw_rate_rad_s: f64,
    /// The goal is within the success radius: the command is zero.
    pub reached: bool,
    /// The attractive force used \[N\].
    pub attractive_body: DVec3,
    /// The summed repulsive force used \[N\].
    pub repulsive_body: DVec3,
}

/// Turns forces into commands with the configured limits and mapping.
#[derive(Debug, Clone)]
pub struct ApfController {
    config: ApfConfig,
}

impl ApfController {
    /// A controller; the config must be valid (see `PerceptionConfig::validate`).
    pub fn new(config: ApfConfig) -> Self {
        Self { config }
    }

    /// The config.
    pub fn config(&self) -> &ApfConfig {
        &self.config
    }

    /// The command toward `goal_body` under the summed `repulsive_body` force.
    pub fn command(&self, goal_body: DVec3, repulsive_body: DVec3) -> Result<Command> {
        crate::frames::check_position("goal_body", &goal_body.to_array())?;
        if !repulsive_body.is_finite() {
            return Err(Error::input("repulsive_body", format!("must be finite, got {repulsive_body}")));
        }
        let c = &self.config;
        let attractive_body = attractive_force(c, goal_body);
        let mut command = Command { attractive_body, repulsive_body, ..Command::default() };
        if goal_body.length() < c.success_radius_m {
            command.reached = true;
            return Ok(command);
        }
        let net = attractive_body + repulsive_body;
        let norm = net.length();
        if norm == 0.0 {
            return Ok(command);
        }
        let nu = net / norm;
        match c.mode {
            CommandMode::Nonholonomic => {
                let heading = nu.y.atan2(nu.x);
                command.yaw_rate_rad_s = c.yaw_rate_max_rad_s / PI * heading;
                command.v_x_m_s = (c.v_x_max_m_s * heading.cos()).max(0.0);
                command.v_z_m_s = c.v_z_max_m_s * nu.z;
            }
            CommandMode::Holonomic => {
                command.v_x_m_s = c.v_x_max_m_s * nu.x;
                command.v_y_m_s = c.v_x_max_m_s * nu.y;
                command.v_z_m_s = c.v_z_max_m_s * nu.z;
            }
        }
        Ok(command)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::PerceptionConfig;

    fn apf() -> ApfConfig {
        PerceptionConfig::flight().apf
    }

    #[test]
    fn attraction_parabolic_then_conic() {
        let c = apf();
        // Within ρ_r = 0.5 m: ξ·x.
        assert!((attractive_force(&c, DVec3::new(0.4, 0.0, 0.0)) - DVec3::new(0.16, 0.0, 0.0)).length() < 1e-15);
        // Beyond: magnitude ρ_r·ξ = 0.2 along the goal.
        assert!((attractive_force(&c, DVec3::new(0.0, 5.0, 0.0)) - DVec3::new(0.0, 0.2, 0.0)).length() < 1e-15);
    }

    #[test]
    fn repulsion_by_hand_with_cutoff() {
        let c = apf();
        // At 0.5 m ahead: 1.1·(2 - 1/1.4)/0.25 = 5.6571... pointing backward.
        let f = repulsive_force(&c, DVec3::new(0.5, 0.0, 0.0));
        let expected = 1.1 * (1.0 / 0.5 - 1.0 / 1.4) / 0.25;
        assert!((f - DVec3::new(-expected, 0.0, 0.0)).length() < 1e-12, "{f}");
        // Beyond ρ_0 nothing (the authors' code forgets this cut-off).
        assert_eq!(repulsive_force(&c, DVec3::new(1.5, 0.0, 0.0)), DVec3::ZERO);
        // Clamped below at min_distance: finite and directed away.
        let f = repulsive_force(&c, DVec3::new(0.0, 0.001, 0.0));
        let at_min = 1.1 * (1.0 / 0.05 - 1.0 / 1.4) / 0.0025;
        assert!((f - DVec3::new(0.0, -at_min, 0.0)).length() < 1e-9);
    }

    #[test]
    fn command_mapping_eq_10() {
        let ctl = ApfController::new(apf());
        // Goal straight ahead, no obstacle: full forward speed, no yaw.
        let cmd = ctl.command(DVec3::new(5.0, 0.0, 0.0), DVec3::ZERO).unwrap();
        assert!((cmd.v_x_m_s - 0.6).abs() < 1e-15 && cmd.yaw_rate_rad_s == 0.0 && cmd.v_z_m_s == 0.0);
        // Goal 90° left: yaw rate ψ̇_max/π·π/2 = 0.5, no forward speed (cos = 0).
        let cmd = ctl.command(DVec3::new(0.0, 5.0, 0.0), DVec3::ZERO).unwrap();
        assert!((cmd.yaw_rate_rad_s - 0.5).abs() < 1e-15 && cmd.v_x_m_s.abs() < 1e-15);
        // Goal behind: never a negative forward speed.
        let cmd = ctl.command(DVec3::new(-5.0, 0.1, 0.0), DVec3::ZERO).unwrap();
        assert_eq!(cmd.v_x_m_s, 0.0);
        // Goal above and ahead at 45°: v_z = 0.6·sin 45°.
        let cmd = ctl.command(DVec3::new(3.0, 0.0, 3.0), DVec3::ZERO).unwrap();
        assert!((cmd.v_z_m_s - 0.6 / 2f64.sqrt()).abs() < 1e-12);
        // An obstacle pushing back harder than the goal pulls: stop forward motion.
        let cmd = ctl.command(DVec3::new(5.0, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0)).unwrap();
        assert_eq!(cmd.v_x_m_s, 0.0);
        // Inside the success radius: zero and reached.
        let cmd = ctl.command(DVec3::new(0.1, 0.0, 0.0), DVec3::ZERO).unwrap();
        assert!(cmd.reached && cmd.v_x_m_s == 0.0);
        assert!(ctl.command(DVec3::new(f64::NAN, 0.0, 0.0), DVec3::ZERO).is_err());
    }

    #[test]
    fn holonomic_mode_follows_the_force() {
        let mut c = apf();
        c.mode = CommandMode::Holonomic;
        let cmd = ApfController::new(c).command(DVec3::new(0.0, 3.0, 4.0), DVec3::ZERO).unwrap();
        assert!((cmd.v_y_m_s - 0.6 * 0.6).abs() < 1e-12 && (cmd.v_z_m_s - 0.6 * 0.8).abs() < 1e-12);
        assert_eq!(cmd.yaw_rate_rad_s, 0.0);
    }
}
