//! Tests of the vehicle models: angle wrapping, unicycle arcs and ramps, the resting plane
//! and hull, the quadrotor's lag, odometry drift, config checks and the collision probes.

use std::f64::consts::PI;

use glam::{DVec2, DVec3};
use rand::{Rng, SeedableRng};

use super::*;
use super::collision::CollisionProbes;
use super::dynamics::ramp;
use super::settle::{convex_hull, hull_contains, resting_plane};
use crate::error::SimError;

#[test]
fn wrap_angle_maps_into_half_open_interval() {
    assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
    assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
    assert!((wrap_angle(0.5) - 0.5).abs() < 1e-15);
    assert!((wrap_angle(2.0 * PI + 0.25) - 0.25).abs() < 1e-12);
    assert!((wrap_angle(-0.75 * PI) + 0.75 * PI).abs() < 1e-12);
}

#[test]
fn unicycle_arc_quarter_circle() {
    // v = 1, ω = π/2 for 1 s: a quarter circle of radius 2/π, from heading 0 turning left.
    let (x, y, yaw) = unicycle_arc(0.0, 0.0, 0.0, 1.0, 0.5 * PI, 1.0);
    let r = 2.0 / PI;
    assert!((x - r).abs() < 1e-12, "x = {x}");
    assert!((y - r).abs() < 1e-12, "y = {y}");
    assert!((yaw - 0.5 * PI).abs() < 1e-12);
    // Two half steps compose exactly to the same arc.
    let (x1, y1, yaw1) = unicycle_arc(0.0, 0.0, 0.0, 1.0, 0.5 * PI, 0.5);
    let (x2, y2, yaw2) = unicycle_arc(x1, y1, yaw1, 1.0, 0.5 * PI, 0.5);
    assert!((x2 - x).abs() < 1e-12 && (y2 - y).abs() < 1e-12 && (yaw2 - yaw).abs() < 1e-12);
    // Straight line.
    let (x, y, _) = unicycle_arc(1.0, 2.0, 0.5 * PI, 0.5, 0.0, 2.0);
    assert!((x - 1.0).abs() < 1e-12 && (y - 3.0).abs() < 1e-12);
}

#[test]
fn ramp_means_are_exact() {
    assert_eq!(ramp(0.0, 1.0, None, 0.1), (1.0, 1.0));
    // 0.5 m/s² over 0.1 s from 0: 0.05 at the end, mean 0.025.
    let (end, mean) = ramp(0.0, 1.0, Some(0.5), 0.1);
    assert!((end - 0.05).abs() < 1e-15 && (mean - 0.025).abs() < 1e-15);
    // Reaches 0.2 from 0 at 4 m/s² after 0.05 s of 0.1: distance 0.005 + 0.01 -> mean 0.15.
    let (end, mean) = ramp(0.0, 0.2, Some(4.0), 0.1);
    assert_eq!(end, 0.2);
    assert!((mean - 0.15).abs() < 1e-15);
    // Braking: from 1 toward -1 at 2 m/s² for 0.1 s: 0.8, mean 0.9.
    let (end, mean) = ramp(1.0, -1.0, Some(2.0), 0.1);
    assert!((end - 0.8).abs() < 1e-15 && (mean - 0.9).abs() < 1e-15);
}

#[test]
fn resting_plane_on_a_plane_is_the_plane() {
    // z = 1 + 0.2 x - 0.1 y sampled on a 3 x 3 grid: every triple is coplanar.
    let pts: Vec<DVec3> =
        (-1..=1).flat_map(|i| (-1..=1).map(move |j| DVec3::new(i as f64, j as f64, 1.0 + 0.2 * i as f64 - 0.1 * j as f64))).collect();
    let (a, g) = resting_plane(&pts).unwrap();
    assert!((a - 1.0).abs() < 1e-12);
    assert!((g.x - 0.2).abs() < 1e-12 && (g.y + 0.1).abs() < 1e-12);
}

#[test]
fn resting_plane_rests_on_the_highest_supports() {
    // Square corners at z = 0 and a bump of 0.1 at the centre: the body rests on the
    // bump and tips onto two corners; the centre height is the bump's 0.1.
    let mut pts = vec![
        DVec3::new(-1.0, -1.0, 0.0),
        DVec3::new(1.0, -1.0, 0.0),
        DVec3::new(1.0, 1.0, 0.0),
        DVec3::new(-1.0, 1.0, 0.0),
        DVec3::new(0.0, 0.0, 0.1),
    ];
    let (a, _) = resting_plane(&pts).unwrap();
    assert!((a - 0.1).abs() < 1e-12);
    // A raised corner (0.2 at (1, 1)): every plane on or above the samples that is
    // lowest at the centre passes 0.1 there (the centre lies on the hull ridge from
    // (-1, -1, 0) through the bump to (1, 1, 0.2)); the planes through three samples
    // on that ridge's sides all tilt by 0.1 (e.g. z = 0.1 + 0.1 y through (1, 1),
    // (1, -1), (-1, -1)), and every sample stays on or below the chosen plane.
    pts[2].z = 0.2;
    let (a, g) = resting_plane(&pts).unwrap();
    assert!((a - 0.1).abs() < 1e-12, "a = {a}");
    assert!((g.length() - 0.1).abs() < 1e-12, "g = {g}");
    assert!(pts.iter().all(|p| p.z <= a + g.x * p.x + g.y * p.y + 1e-12));
    // Collinear points give no plane.
    assert!(resting_plane(&[DVec3::ZERO, DVec3::X, DVec3::new(2.0, 0.0, 1.0)]).is_none());
}

#[test]
fn hull_of_a_grid_and_containment() {
    // 3 x 3 grid: hull is the 4 corners; the centre and edge midpoints are inside/on it.
    let pts: Vec<DVec2> = (0..3).flat_map(|i| (0..3).map(move |j| DVec2::new(i as f64, j as f64))).collect();
    let hull = convex_hull(&pts);
    assert_eq!(hull, vec![DVec2::new(0.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(2.0, 2.0), DVec2::new(0.0, 2.0)]);
    assert!(hull_contains(&hull, DVec2::new(1.0, 1.0)));
    assert!(hull_contains(&hull, DVec2::new(2.0, 1.0)));
    assert!(!hull_contains(&hull, DVec2::new(2.0 + 1e-6, 1.0)));
    // Rear and front rows only (a valley under the middle): the middle row is bridged.
    let rows: Vec<DVec2> = pts.iter().copied().filter(|p| p.x != 1.0).collect();
    let hull = convex_hull(&rows);
    assert!(hull_contains(&hull, DVec2::new(1.0, 0.0)) && hull_contains(&hull, DVec2::new(1.0, 2.0)));
    // Rear and middle rows only (a cliff ahead): the front row overhangs.
    let back: Vec<DVec2> = pts.iter().copied().filter(|p| p.x != 2.0).collect();
    assert!(!hull_contains(&convex_hull(&back), DVec2::new(2.0, 1.0)));
    // Degenerate support (collinear) contains nothing.
    assert!(!hull_contains(&convex_hull(&[DVec2::ZERO, DVec2::X, DVec2::new(2.0, 0.0)]), DVec2::X));
}

#[test]
fn quadrotor_step_is_exact_first_order_lag() {
    let mut q = Quadrotor::new(QuadrotorConfig::default(), QuadrotorState::at_rest(DVec3::ZERO, 0.0)).unwrap();
    q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.2);
    // One step of τ: v = 0.5 (1 - e^-1), x = 0.5 (τ - τ (1 - e^-1)) = 0.5·0.2·e^-1.
    let e = (-1.0_f64).exp();
    assert!((q.state().velocity_world.x - 0.5 * (1.0 - e)).abs() < 1e-15);
    assert!((q.state().position.x - 0.5 * 0.2 * e).abs() < 1e-15);
    // Invalid steps do nothing.
    let before = *q.state();
    q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), f64::NAN);
    q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), -0.1);
    assert_eq!(*q.state(), before);
    // NaN commands count as zero.
    let limited = q.limited(&BodyVelocityCommand::new(f64::NAN, 2.0, -2.0, f64::INFINITY));
    assert_eq!(limited, BodyVelocityCommand::new(0.0, 0.6, -0.6, 0.0));
}

#[test]
fn odometry_drift_variance_grows_with_time() {
    let noise = OdometryNoise { position_walk_m_per_sqrt_s: 0.1, yaw_walk_rad_per_sqrt_s: 0.02 };
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
    let n = 4000;
    let (mut sum_x2, mut sum_yaw2) = (0.0, 0.0);
    for _ in 0..n {
        let mut drift = OdometryDrift::new(Some(noise));
        for _ in 0..4 {
            drift.elapse(1.0);
            drift.advance(&mut rng);
        }
        sum_x2 += drift.bias_position_m.x.powi(2);
        sum_yaw2 += drift.bias_yaw_rad.powi(2);
    }
    // After 4 s: variance 0.1² · 4 = 0.04 and 0.02² · 4 = 0.0016 (5 % tolerance at n = 4000 ~ 2.2 σ).
    let var_x = sum_x2 / n as f64;
    let var_yaw = sum_yaw2 / n as f64;
    assert!((var_x / 0.04 - 1.0).abs() < 0.05, "var_x = {var_x}");
    assert!((var_yaw / 0.0016 - 1.0).abs() < 0.05, "var_yaw = {var_yaw}");
    // Without noise nothing is drawn and odometry is the truth.
    let mut drift = OdometryDrift::new(None);
    drift.elapse(1.0);
    let mut a = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
    drift.advance(&mut a);
    let mut b = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
    assert_eq!(a.next_u64(), b.next_u64());
    assert_eq!(drift.bias_position_m, DVec3::ZERO);
}

#[test]
fn configs_reject_bad_values() {
    let c = QuadrotorConfig { radius_m: 0.0, ..QuadrotorConfig::default() };
    assert!(matches!(c.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "quadrotor.radius_m"));
    let g = GroundRobotConfig { ground_clearance_m: 0.5, ..GroundRobotConfig::default() };
    assert!(matches!(g.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "ground_robot.ground_clearance_m"));
    let g = GroundRobotConfig { rollover_pitch_rad: 2.0, ..GroundRobotConfig::default() };
    assert!(matches!(g.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "ground_robot.rollover_pitch_rad"));
    assert!(matches!(
        Quadrotor::new(QuadrotorConfig::default(), QuadrotorState::at_rest(DVec3::new(f64::NAN, 0.0, 0.0), 0.0)),
        Err(SimError::InvalidInput { argument, .. }) if argument == "initial.position"
    ));
}

#[test]
fn collision_probes_cover_the_husky_box() {
    let probes = CollisionProbes::new(&GroundRobotConfig::default());
    // 4 x 3 coarse cells of 0.2475 x 0.2233 x 0.27 m.
    assert_eq!(probes.cells.len(), 12);
    let hd = DVec3::new(0.12375, 0.67 / 6.0, 0.135).length();
    assert!((probes.cells[0].half_diagonal_m - hd).abs() < 1e-12);
    // The half diagonal stays below the cell centre's height above the contact plane
    // (0.265 m), so level ground never blocks the coarse test.
    assert!(hd < 0.265);
    // Fine balls: r = 0.27 / 4, spacing √2·r = 0.0955: along x ceil(0.855 / 0.0955) + 1 = 10,
    // along y ceil(0.535 / 0.0955) + 1 = 7, along z ceil(0.135 / 0.0955) + 1 = 3; all inside the box.
    let r = probes.fine_radius_m;
    assert!((r - 0.0675).abs() < 1e-12);
    let all: Vec<DVec3> = probes.cells.iter().flat_map(|c| c.fine_body.iter().copied()).collect();
    assert_eq!(all.len(), 10 * 7 * 3);
    for p in &all {
        assert!(p.x.abs() + r <= 0.495 + 1e-12 && p.y.abs() + r <= 0.335 + 1e-12);
        assert!(p.z - r >= 0.13 - 1e-12 && p.z + r <= 0.4 + 1e-12);
    }
}
