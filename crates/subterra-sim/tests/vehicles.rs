//! Vehicles, metrics and the simulation step loop against analytic answers.

use std::f64::consts::PI;

use glam::DVec3;
use subterra::{Isometry3, PinholeCamera};
use subterra_sim::metrics::MetricsRecorder;
use subterra_sim::noise::{DepthNoiseModel, LidarNoise, LidarNoiseModel};
use subterra_sim::sensors::{DepthCameraConfig, LidarConfig};
use subterra_sim::simulation::{Goal, RunStatus, Simulation, Vehicle};
use subterra_sim::spec::{BoxSpec, CylinderSpec, HeightFieldSpec, PlaneSpec, RegionSpec, WorldSpec};
use subterra_sim::vehicles::{
    BodyVelocityCommand, Failure, GroundRobot, GroundRobotConfig, GroundRobotState, OdometryNoise, Quadrotor, QuadrotorConfig, QuadrotorState,
};
use subterra_sim::world::World;
use subterra_sim::SimError;

const TAU: f64 = 0.2;

fn quad_at(position: DVec3, yaw: f64) -> Quadrotor {
    Quadrotor::new(QuadrotorConfig::default(), QuadrotorState::at_rest(position, yaw)).unwrap()
}

fn instant_quad_config() -> QuadrotorConfig {
    QuadrotorConfig { time_constant_s: 0.0, ..QuadrotorConfig::default() }
}

fn floor() -> PlaneSpec {
    PlaneSpec { point: [0.0, 0.0, 0.0], normal: [0.0, 0.0, 1.0], tag: "floor".into(), dark: false }
}

fn box_spec(centre: [f64; 3], size: [f64; 3]) -> BoxSpec {
    BoxSpec { centre, size, yaw: 0.0, tag: "box".into(), dark: false }
}

fn pole(x: f64, y: f64, radius: f64) -> CylinderSpec {
    CylinderSpec { a: [x, y, 0.0], b: [x, y, 3.0], radius, tag: "pole".into(), dark: false }
}

/// A height field over x in [x0, x0 + (cols-1)·res], y in [y0, ...] with heights `f(x, y)`.
fn terrain(x0: f64, y0: f64, res: f64, cols: usize, rows: usize, f: impl Fn(f64, f64) -> f64) -> HeightFieldSpec {
    let heights = (0..rows).map(|r| (0..cols).map(|c| f(x0 + c as f64 * res, y0 + r as f64 * res)).collect()).collect();
    HeightFieldSpec { origin: [x0, y0], resolution: res, heights, hole_value: Some(-1000.0), dark: false }
}

fn world_with(spec: WorldSpec) -> World {
    World::from_spec(spec).unwrap()
}

fn flat_world() -> World {
    world_with(WorldSpec { planes: vec![floor()], ..WorldSpec::default() })
}

fn husky_at(x: f64, y: f64, yaw: f64) -> GroundRobot {
    GroundRobot::new(GroundRobotConfig::default(), GroundRobotState::at_rest(x, y, yaw)).unwrap()
}

/// Drives straight at `v` until a failure or `max_x`; returns the failure and the x where it happened.
fn drive_straight(robot: &mut GroundRobot, world: &World, v: f64, max_x: f64) -> (Option<Failure>, f64) {
    assert_eq!(robot.place(world), None);
    for _ in 0..10_000 {
        if let Some(f) = robot.step(v, 0.0, 0.1, world) {
            return (Some(f), robot.state().x_m);
        }
        if robot.state().x_m >= max_x {
            break;
        }
    }
    (None, robot.state().x_m)
}

// ---------------------------------------------------------------------------------------
// Quadrotor
// ---------------------------------------------------------------------------------------

#[test]
fn quadrotor_step_response_reaches_63_percent_at_tau() {
    let mut q = quad_at(DVec3::ZERO, 0.0);
    let cmd = BodyVelocityCommand::new(0.5, -0.3, 0.4, 0.8);
    for _ in 0..20 {
        q.step(&cmd, 0.01);
    }
    // After t = τ = 0.2 s: 1 - e^-1 = 63.2 % of each commanded component.
    let frac = 1.0 - (-1.0_f64).exp();
    let s = q.state();
    assert!((s.yaw_rate_rad_s - 0.8 * frac).abs() < 1e-12, "yaw rate {}", s.yaw_rate_rad_s);
    assert!((s.velocity_world.z - 0.4 * frac).abs() < 1e-12);
    // (Horizontally the world-frame velocity lags toward a command that turns with the
    // body, so with a yaw rate the body-frame components are not exactly 63 %.)

    // Straight, no yaw: exact per axis.
    let mut q = quad_at(DVec3::ZERO, 0.0);
    for _ in 0..20 {
        q.step(&BodyVelocityCommand::new(0.5, -0.3, 0.4, 0.0), 0.01);
    }
    let v = q.state().velocity_world;
    assert!((v - DVec3::new(0.5, -0.3, 0.4) * frac).length() < 1e-12, "v = {v}");
}

#[test]
fn quadrotor_final_velocity_equals_command_and_position_is_analytic() {
    let mut q = quad_at(DVec3::new(1.0, 2.0, 3.0), 0.0);
    let cmd = BodyVelocityCommand::new(0.4, 0.2, -0.3, 0.0);
    for _ in 0..100 {
        q.step(&cmd, 0.1);
    }
    let t: f64 = 10.0;
    let s = q.state();
    assert!((s.velocity_world - DVec3::new(0.4, 0.2, -0.3)).length() < 1e-12);
    // x(t) = x0 + v (t - τ (1 - e^{-t/τ})).
    let lagged = t - TAU * (1.0 - (-t / TAU).exp());
    let expected = DVec3::new(1.0, 2.0, 3.0) + DVec3::new(0.4, 0.2, -0.3) * lagged;
    assert!((s.position - expected).length() < 1e-12, "{} vs {}", s.position, expected);
    // Step size does not matter for a constant command (exact discretisation).
    let mut coarse = quad_at(DVec3::new(1.0, 2.0, 3.0), 0.0);
    for _ in 0..4 {
        coarse.step(&cmd, 2.5);
    }
    assert!((coarse.state().position - expected).length() < 1e-12);
}

#[test]
fn quadrotor_limits_clip_each_axis() {
    let q = quad_at(DVec3::ZERO, 0.0);
    assert_eq!(q.limited(&BodyVelocityCommand::new(2.0, -3.0, 5.0, -4.0)), BodyVelocityCommand::new(0.6, -0.6, 0.6, -1.0));
    let mut q = quad_at(DVec3::ZERO, 0.0);
    let mut qz = quad_at(DVec3::ZERO, 0.0);
    let mut qr = quad_at(DVec3::ZERO, 0.0);
    for _ in 0..100 {
        q.step(&BodyVelocityCommand::new(2.0, -3.0, 5.0, 0.0), 0.05);
        qz.step(&BodyVelocityCommand::new(-2.0, 0.1, -9.0, 0.0), 0.05);
        qr.step(&BodyVelocityCommand::new(0.0, 0.0, 0.0, -4.0), 0.05);
    }
    assert!((qr.state().yaw_rate_rad_s + 1.0).abs() < 1e-9);
    // Velocity settles on the per-axis limits.
    let v = q.state().velocity_world;
    assert!((v - DVec3::new(0.6, -0.6, 0.6)).length() < 1e-9, "v = {v}");
    let v = qz.state().velocity_world;
    assert!((v - DVec3::new(-0.6, 0.1, -0.6)).length() < 1e-9, "v = {v}");
}

#[test]
fn quadrotor_yaw_integrates_with_the_lag_and_wraps() {
    let mut q = quad_at(DVec3::ZERO, 0.0);
    for _ in 0..40 {
        q.step(&BodyVelocityCommand::new(0.0, 0.0, 0.0, 0.5), 0.05);
    }
    // ψ(t) = r (t - τ (1 - e^{-t/τ})) at t = 2 s.
    let expected = 0.5 * (2.0 - TAU * (1.0 - (-10.0_f64).exp()));
    assert!((q.state().yaw_rad - expected).abs() < 1e-12, "yaw {}", q.state().yaw_rad);
    // Wrap: 1 rad/s for 10 s from 0 -> 10 - 0.2 (1 - e^-50), wrapped to (-π, π].
    let mut q = quad_at(DVec3::ZERO, 0.0);
    for _ in 0..100 {
        q.step(&BodyVelocityCommand::new(0.0, 0.0, 0.0, 1.0), 0.1);
    }
    let raw = 10.0 - TAU * (1.0 - (-50.0_f64).exp());
    let wrapped = raw - 2.0 * PI * ((raw + PI) / (2.0 * PI)).floor();
    assert!((q.state().yaw_rad - wrapped).abs() < 1e-9);
    // A forward command at heading 90° moves along world +y.
    let mut q = quad_at(DVec3::ZERO, 0.5 * PI);
    for _ in 0..50 {
        q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.1);
    }
    let v = q.state().velocity_world;
    assert!((v - DVec3::new(0.0, 0.5, 0.0)).length() < 1e-9, "v = {v}");
    // The body frame's x axis is world +y.
    assert!((q.world_from_body().transform_vector(DVec3::X) - DVec3::Y).length() < 1e-12);
    // No lag, constant turn: 100 steps of 0.1 s at 2π/10 rad/s close the circle exactly
    // (mid-step heading: the 100 displacements are equally spaced directions).
    let mut q = Quadrotor::new(instant_quad_config(), QuadrotorState::at_rest(DVec3::ZERO, 0.0)).unwrap();
    for _ in 0..100 {
        q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.2 * PI), 0.1);
    }
    assert!(q.state().position.length() < 1e-12, "p = {}", q.state().position);
    assert!(q.state().yaw_rad.abs() < 1e-9 || (q.state().yaw_rad.abs() - 2.0 * PI).abs() < 1e-9);
}

#[test]
fn quadrotor_collision_against_a_pole_and_not_at_safe_distance() {
    let world = world_with(WorldSpec { cylinders: vec![pole(2.0, 0.0, 0.1)], ..WorldSpec::default() });
    // Centre 0.2 m from the pole's surface: inside the 0.27 m sphere.
    let q = quad_at(DVec3::new(1.7, 0.0, 1.0), 0.0);
    assert!(q.collided(&world));
    assert!((q.clearance_m(&world) + 0.07).abs() < 1e-5);
    // 0.4 m from the surface: clear by 0.13 m.
    let q = quad_at(DVec3::new(1.5, 0.0, 1.0), 0.0);
    assert!(!q.collided(&world));
    assert!((q.clearance_m(&world) - 0.13).abs() < 1e-5);
    // Flying at it: the run fails with a collision at the first step past x = 2 - 0.1 - 0.27.
    let vehicle = Vehicle::quadrotor(instant_quad_config(), QuadrotorState::at_rest(DVec3::new(0.0, 0.0, 1.0), 0.0)).unwrap();
    let mut sim = Simulation::new(world.clone(), vehicle, 1).unwrap();
    let mut last_x = 0.0;
    loop {
        let out = sim.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.1, 0.0).unwrap();
        let x = sim.vehicle().position().x;
        if !out.status.is_running() {
            assert_eq!(out.status, RunStatus::Failed(Failure::Collision));
            assert!(out.collided && out.clearance_m < 0.0);
            assert!(x > 1.63 - 1e-5 && last_x <= 1.63 + 1e-5, "collision at x = {x}, previous {last_x}");
            break;
        }
        last_x = x;
        assert!(x < 2.0);
    }
    let m = sim.metrics();
    assert!(!m.success);
    assert_eq!(m.failure.as_deref(), Some("collision"));
    assert_eq!(m.collisions, 1);
    // Passing beside the pole at 0.5 m from its axis: never a collision; min clearance
    // 0.5 - 0.1 - 0.27 = 0.13 m, reached abreast of the pole (x = 2.0 is a sample point).
    let vehicle = Vehicle::quadrotor(instant_quad_config(), QuadrotorState::at_rest(DVec3::new(0.0, 0.5, 1.0), 0.0)).unwrap();
    let mut sim = Simulation::new(world, vehicle, 1).unwrap();
    for _ in 0..80 {
        let out = sim.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.1, 0.0).unwrap();
        assert!(!out.collided);
    }
    let m = sim.metrics();
    assert_eq!(m.collisions, 0);
    assert!((m.min_clearance_m - 0.13).abs() < 1e-5, "min clearance {}", m.min_clearance_m);
}

// ---------------------------------------------------------------------------------------
// Ground robot: settle
// ---------------------------------------------------------------------------------------

#[test]
fn ground_robot_on_a_flat_plane_is_level_at_zero() {
    let world = flat_world();
    let mut robot = husky_at(1.0, -2.0, 0.7);
    assert_eq!(robot.place(&world), None);
    let s = robot.settle(&world);
    assert_eq!(s.z_m, 0.0);
    assert_eq!(s.roll_rad, 0.0);
    assert_eq!(s.pitch_rad, 0.0);
    assert_eq!(s.max_gap_m, 0.0);
    assert_eq!(s.samples_on_ground, 15);
    let pose = robot.world_from_body();
    assert!((pose.translation - DVec3::new(1.0, -2.0, 0.0)).length() < 1e-15);
    assert!((pose.rotation.z_axis - DVec3::Z).length() < 1e-15);
    // A flat height field at 0.3 m: z = 0.3.
    let world = world_with(WorldSpec { heightfield: Some(terrain(-5.0, -5.0, 0.1, 101, 101, |_, _| 0.3)), ..WorldSpec::default() });
    let robot = husky_at(0.2, 0.1, -2.0);
    let s = robot.settle(&world);
    assert!((s.z_m - 0.3).abs() < 1e-12 && s.roll_rad.abs() < 1e-12 && s.pitch_rad.abs() < 1e-12);
}

#[test]
fn ground_robot_settles_on_a_ten_degree_incline() {
    let slope = 10f64.to_radians();
    let world = world_with(WorldSpec { heightfield: Some(terrain(-5.0, -5.0, 0.1, 101, 101, |x, _| x * slope.tan())), ..WorldSpec::default() });
    // Heading uphill (+x): nose up = negative pitch (REP 103), no roll.
    let up = husky_at(1.0, 0.5, 0.0).settle(&world);
    assert!((up.pitch_rad + slope).abs() < 0.5f64.to_radians(), "pitch {}", up.pitch_rad.to_degrees());
    assert!((up.pitch_rad + slope).abs() < 1e-9);
    assert!(up.roll_rad.abs() < 1e-9);
    assert!((up.z_m - slope.tan()).abs() < 1e-9);
    // Downhill: nose down, positive pitch.
    let down = husky_at(1.0, 0.5, PI).settle(&world);
    assert!((down.pitch_rad - slope).abs() < 1e-9 && down.roll_rad.abs() < 1e-9);
    // Across (+y heading): the uphill side is on the right (-y body) -> left side down: roll = -10°.
    let across = husky_at(-1.0, 0.0, 0.5 * PI).settle(&world);
    assert!((across.roll_rad.abs() - slope).abs() < 0.5f64.to_radians());
    assert!((across.roll_rad + slope).abs() < 1e-9, "roll {}", across.roll_rad.to_degrees());
    assert!(across.pitch_rad.abs() < 1e-9);
    // Heading 45°: pitch = -atan(tan 10° cos 45°), and the body z axis is the plane normal.
    let mut diag = husky_at(0.0, 0.0, 0.25 * PI);
    let s = diag.settle(&world);
    assert!((s.pitch_rad + (slope.tan() * (0.25 * PI).cos()).atan()).abs() < 1e-9);
    assert_eq!(diag.place(&world), None);
    let n = DVec3::new(-slope.sin(), 0.0, slope.cos());
    assert!((diag.world_from_body().rotation.z_axis - n).length() < 1e-9);
    // Driving up the incline: no failure, the pitch stays -10°.
    let mut robot = husky_at(-3.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &world, 1.0, 3.0);
    assert_eq!(failure, None);
    assert!(x >= 3.0);
    assert!((robot.last_settle().unwrap().pitch_rad + slope).abs() < 1e-9);
}

#[test]
fn ground_robot_rolls_over_on_a_forty_degree_slope() {
    let steep = 40f64.to_radians();
    let world = world_with(WorldSpec { heightfield: Some(terrain(-5.0, -5.0, 0.1, 101, 101, |x, _| x * steep.tan())), ..WorldSpec::default() });
    assert_eq!(husky_at(0.0, 0.0, 0.0).place(&world), Some(Failure::Rollover));
    assert_eq!(husky_at(0.0, 0.0, 0.5 * PI).place(&world), Some(Failure::Rollover));
    let s = husky_at(0.0, 0.0, 0.0).settle(&world);
    assert!((s.pitch_rad + steep).abs() < 1e-9);
    // The simulation refuses to start there.
    let vehicle = Vehicle::ground(GroundRobotConfig::default(), GroundRobotState::at_rest(0.0, 0.0, 0.0)).unwrap();
    assert!(matches!(Simulation::new(world, vehicle, 0), Err(SimError::InvalidInput { argument, reason }) if argument == "vehicle" && reason.contains("rollover")));
    // 30° is within the limit.
    let world = world_with(WorldSpec {
        heightfield: Some(terrain(-5.0, -5.0, 0.1, 101, 101, |x, _| x * 30f64.to_radians().tan())),
        ..WorldSpec::default()
    });
    assert_eq!(husky_at(0.0, 0.0, 0.0).place(&world), None);
    // Driving from flat ground onto a 40° ramp starting at x = 2: rollover on the ramp,
    // not a ledge collision (the ramp rises 4 cm per 5 cm sub-step).
    let world = world_with(WorldSpec {
        heightfield: Some(terrain(-5.0, -5.0, 0.1, 121, 101, |x, _| (x - 2.0).max(0.0) * steep.tan())),
        ..WorldSpec::default()
    });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &world, 0.5, 6.0);
    assert_eq!(failure, Some(Failure::Rollover));
    assert!(x > 1.5 && x < 3.0, "rolled over at x = {x}");
}

#[test]
fn ground_robot_falls_at_a_hole_and_a_drop_but_not_at_a_small_dip() {
    // A hole: samples at 3.0 <= x <= 4.0 are holes; cells touching them (2.9..4.1) are gone.
    let hole = world_with(WorldSpec {
        heightfield: Some(terrain(-2.0, -3.0, 0.1, 101, 61, |x, _| if (2.95..=4.05).contains(&x) { -1000.0 } else { 0.0 })),
        ..WorldSpec::default()
    });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &hole, 0.5, 6.0);
    assert_eq!(failure, Some(Failure::Fall));
    // The front edge (x + 0.495) reaches 2.9 at x = 2.405; sub-steps are 5 cm.
    assert!(x > 2.405 - 1e-9 && x < 2.405 + 0.05 + 1e-9, "fell at x = {x}");
    let s = robot.last_settle().unwrap();
    assert!(s.samples_over_hole > 0);

    // A 0.5 m drop: ground at 0 up to x = 2.9, -0.5 from x = 3.0.
    let drop = world_with(WorldSpec { heightfield: Some(terrain(-2.0, -3.0, 0.1, 101, 61, |x, _| if x < 2.95 { 0.0 } else { -0.5 })), ..WorldSpec::default() });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &drop, 0.5, 6.0);
    assert_eq!(failure, Some(Failure::Fall));
    // The front samples sink 5 m per metre on the 2.9..3.0 ramp: 0.13 below at front = 2.926.
    assert!(x > 2.926 - 0.495 - 1e-9 && x < 2.926 - 0.495 + 0.05 + 1e-9, "fell at x = {x}");
    assert!(robot.last_settle().unwrap().max_gap_m > 0.13);

    // A 5 cm dip from x = 3.0 to 4.0: drives through.
    let dip = world_with(WorldSpec {
        heightfield: Some(terrain(-2.0, -3.0, 0.1, 101, 61, |x, _| if (2.95..=4.05).contains(&x) { -0.05 } else { 0.0 })),
        ..WorldSpec::default()
    });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &dip, 0.5, 6.0);
    assert_eq!(failure, None);
    assert!(x >= 6.0);
    let mut inside = husky_at(3.5, 0.0, 0.0);
    assert_eq!(inside.place(&dip), None);
    assert!((inside.last_settle().unwrap().z_m + 0.05).abs() < 1e-9);

    // Off the terrain altogether: out of the world; half off: a fall (the edge is a drop).
    assert_eq!(husky_at(50.0, 0.0, 0.0).place(&dip), Some(Failure::OutOfWorld));
    assert_eq!(husky_at(8.0, 0.0, 0.0).place(&dip), Some(Failure::Fall));
}

#[test]
fn ground_robot_climbs_the_foot_of_a_ramp_at_an_angle_without_a_fall() {
    // A sharp-footed 19.5° ramp from x = 2 (0.5 m up): crossing its foot at 45°, one front
    // corner climbs first and the opposite corner lifts off the floor by more than the
    // clearance. That is a tilt, not a drop: the floor under the lifted corner is as high as
    // the lowest support.
    let slope = 19.5f64.to_radians().tan();
    let ramp = world_with(WorldSpec {
        heightfield: Some(terrain(-2.0, -6.0, 0.05, 241, 241, |x, _| ((x - 2.0).max(0.0) * slope).min(0.5))),
        ..WorldSpec::default()
    });
    let mut deepest_lift = 0.0_f64;
    for i in 0..=60 {
        let x = 1.0 + 0.025 * i as f64;
        for yaw in [std::f64::consts::FRAC_PI_4, -std::f64::consts::FRAC_PI_4, 0.3] {
            let mut robot = husky_at(x, 0.0, yaw);
            assert_eq!(robot.place(&ramp), None, "x = {x}, yaw = {yaw}");
            let s = robot.last_settle().unwrap();
            assert_eq!(s.overhang_gap_m, 0.0, "x = {x}, yaw = {yaw}");
            deepest_lift = deepest_lift.max(s.max_gap_m);
        }
    }
    // The case is a real one: some wheel hangs higher above the floor than the clearance.
    assert!(deepest_lift > GroundRobotConfig::default().max_drop_m, "deepest lift {deepest_lift}");
    // Driving across the foot at 45° climbs onto the ramp.
    let mut robot = husky_at(0.5, -1.5, std::f64::consts::FRAC_PI_4);
    let (failure, x) = drive_straight(&mut robot, &ramp, 0.5, 3.0);
    assert_eq!(failure, None, "failed at x = {x}");
    assert!(robot.last_settle().unwrap().z_m > 0.2);
    // Off the crest's far side there is still a drop: the plateau ends in a 0.5 m cliff.
    let mesa = world_with(WorldSpec {
        heightfield: Some(terrain(-2.0, -6.0, 0.05, 241, 241, |x, _| if x < 5.0 { ((x - 2.0).max(0.0) * slope).min(0.5) } else { 0.0 })),
        ..WorldSpec::default()
    });
    let mut robot = husky_at(4.7, 0.0, std::f64::consts::FRAC_PI_4);
    assert_eq!(robot.place(&mesa), Some(Failure::Fall));
}

#[test]
fn ground_robot_collides_with_a_box_above_its_clearance_not_with_a_bump() {
    let world_with_box = |height: f64| {
        world_with(WorldSpec { planes: vec![floor()], boxes: vec![box_spec([3.0, 0.0, 0.5 * height], [0.2, 2.0, height])], ..WorldSpec::default() })
    };
    // A 0.3 m box with its face at x = 2.9: collision once the front edge passes it.
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &world_with_box(0.3), 0.5, 6.0);
    assert_eq!(failure, Some(Failure::Collision));
    assert!(x > 2.405 - 1e-9 && x < 2.405 + 0.05 + 1e-9, "collided at x = {x}");
    // 0.16 m (3 cm above the clearance): still a collision.
    let mut robot = husky_at(0.0, 0.0, 0.0);
    assert_eq!(drive_straight(&mut robot, &world_with_box(0.16), 0.5, 6.0).0, Some(Failure::Collision));
    // 5 cm and 12 cm bumps pass under the body.
    for height in [0.05, 0.12] {
        let mut robot = husky_at(0.0, 0.0, 0.0);
        let (failure, x) = drive_straight(&mut robot, &world_with_box(height), 0.5, 6.0);
        assert_eq!(failure, None, "bump of {height} m");
        assert!(x >= 6.0);
    }
    // A 22 mm pole in the path, off the centre line.
    let poles = world_with(WorldSpec { planes: vec![floor()], cylinders: vec![pole(3.0, 0.2, 0.011)], ..WorldSpec::default() });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &poles, 0.5, 6.0);
    assert_eq!(failure, Some(Failure::Collision));
    assert!(x < 3.0 - 0.495 + 0.1, "pole hit at x = {x}");
    // The same pole 0.5 m to the side of the body (y = 0.335 + 0.5): no collision.
    let beside = world_with(WorldSpec { planes: vec![floor()], cylinders: vec![pole(3.0, 0.835, 0.011)], ..WorldSpec::default() });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    assert_eq!(drive_straight(&mut robot, &beside, 0.5, 6.0).0, None);
}

#[test]
fn ground_robot_runs_into_a_ledge_as_a_collision() {
    // A 0.5 m step up at x = 2.9..3.0: the terrain rises into the body (not a fall).
    let ledge = world_with(WorldSpec { heightfield: Some(terrain(-2.0, -3.0, 0.1, 101, 61, |x, _| if x < 2.95 { 0.0 } else { 0.5 })), ..WorldSpec::default() });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    let (failure, x) = drive_straight(&mut robot, &ledge, 0.5, 6.0);
    assert_eq!(failure, Some(Failure::Collision));
    // The 10 cm ramp rises 25 cm per 5 cm sub-step: caught while the front edge is on it.
    assert!(x > 2.405 - 1e-9 && x < 2.505 + 1e-9, "ledge at x = {x}");
    // A 5 cm step up is climbed.
    let kerb = world_with(WorldSpec { heightfield: Some(terrain(-2.0, -3.0, 0.1, 101, 61, |x, _| if x < 2.95 { 0.0 } else { 0.05 })), ..WorldSpec::default() });
    let mut robot = husky_at(0.0, 0.0, 0.0);
    assert_eq!(drive_straight(&mut robot, &kerb, 0.5, 6.0).0, None);
    assert!((robot.last_settle().unwrap().z_m - 0.05).abs() < 1e-9);
}

#[test]
fn ground_robot_unicycle_limits_and_turning() {
    let world = flat_world();
    let mut robot = husky_at(0.0, 0.0, 0.0);
    robot.place(&world);
    // v beyond the 1 m/s limit, ω = π/4 rad/s for 2 s: a quarter circle of radius 1/(π/4).
    for _ in 0..20 {
        assert_eq!(robot.step(3.0, 0.25 * PI, 0.1, &world), None);
    }
    let s = *robot.state();
    let r = 1.0 / (0.25 * PI);
    assert!((s.x_m - r).abs() < 1e-12 && (s.y_m - r).abs() < 1e-12, "({}, {})", s.x_m, s.y_m);
    assert!((s.yaw_rad - 0.5 * PI).abs() < 1e-12);
    assert_eq!(s.v_m_s, 1.0);
    // Acceleration limit 0.5 m/s²: from rest, 1 s at a commanded 1 m/s -> v = 0.5, x = 0.25.
    let config = GroundRobotConfig { accel_max_m_s2: Some(0.5), ..GroundRobotConfig::default() };
    let mut robot = GroundRobot::new(config, GroundRobotState::at_rest(0.0, 0.0, 0.0)).unwrap();
    robot.place(&world);
    for _ in 0..10 {
        robot.step(1.0, 0.0, 0.1, &world);
    }
    assert!((robot.state().v_m_s - 0.5).abs() < 1e-12);
    assert!((robot.state().x_m - 0.25).abs() < 1e-12);
    // Invalid dt: nothing happens.
    let before = *robot.state();
    assert_eq!(robot.step(1.0, 0.0, f64::NAN, &world), None);
    assert_eq!(*robot.state(), before);
}

// ---------------------------------------------------------------------------------------
// Metrics
// ---------------------------------------------------------------------------------------

#[test]
fn metrics_of_a_straight_run() {
    // A wall (plane x = 10, solid beyond) ahead; the quadrotor (no lag) flies 1 m along x.
    let wall = PlaneSpec { point: [10.0, 0.0, 0.0], normal: [-1.0, 0.0, 0.0], tag: "wall".into(), dark: false };
    let world = world_with(WorldSpec { planes: vec![wall], ..WorldSpec::default() });
    let vehicle = Vehicle::quadrotor(instant_quad_config(), QuadrotorState::at_rest(DVec3::new(0.0, 0.0, 1.0), 0.0)).unwrap();
    let mut sim = Simulation::new(world, vehicle, 3).unwrap();
    for k in 0..20 {
        sim.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.1, 0.001 * f64::from(k + 1)).unwrap();
    }
    let m = sim.metrics();
    assert!((m.path_length_m - 1.0).abs() < 1e-12, "path {} end {}", m.path_length_m, sim.vehicle().position());
    assert!((m.time_s - 2.0).abs() < 1e-12);
    // Nearest the wall at x = 1: 9 m from the centre, 8.73 m from the sphere.
    assert!((m.min_clearance_m - 8.73).abs() < 1e-9, "clearance {}", m.min_clearance_m);
    // Compute times 1..20 ms: median 10.5 ms, p99 = 19 + 0.81 = 19.81 ms.
    assert!((m.compute_ms_median - 10.5).abs() < 1e-9);
    assert!((m.compute_ms_p99 - 19.81).abs() < 1e-9);
    assert_eq!(m.steps, 20);
    assert!(!m.success && m.failure.is_none() && m.collisions == 0);

    // The ground robot: 1 m straight on a floor, a 0.2 m thick wall box with its face at
    // x = 4.9: clearance from the body front at x = 1 + 0.495 is 3.405 m.
    let world = world_with(WorldSpec { planes: vec![floor()], boxes: vec![box_spec([5.0, 0.0, 1.0], [0.2, 6.0, 2.0])], ..WorldSpec::default() });
    let vehicle = Vehicle::ground(GroundRobotConfig::default(), GroundRobotState::at_rest(0.0, 0.0, 0.0)).unwrap();
    let mut sim = Simulation::new(world, vehicle, 3).unwrap();
    for _ in 0..10 {
        let out = sim.step(&BodyVelocityCommand::new(1.0, 0.0, 0.0, 0.0), 0.1, 0.0).unwrap();
        assert!(out.status.is_running());
    }
    let m = sim.metrics();
    assert!((m.path_length_m - 1.0).abs() < 1e-12);
    assert!((m.min_clearance_m - 3.405).abs() < 1e-9, "clearance {}", m.min_clearance_m);
    // Recorder alone: an L-shaped path.
    let mut rec = MetricsRecorder::new(0.0, DVec3::ZERO, 1.0, false);
    rec.record(1.0, DVec3::new(0.0, 2.0, 0.0), 0.5, false, Some(0.0));
    rec.record(2.0, DVec3::new(1.5, 2.0, 0.0), 0.75, false, Some(0.0));
    let m = rec.finish(true, None);
    assert_eq!(m.path_length_m, 3.5);
    assert_eq!(m.min_clearance_m, 0.5);
}

// ---------------------------------------------------------------------------------------
// Simulation
// ---------------------------------------------------------------------------------------

fn cluttered_world() -> World {
    world_with(WorldSpec {
        planes: vec![floor()],
        cylinders: vec![pole(4.0, 0.3, 0.1), pole(5.0, -0.8, 0.045)],
        boxes: vec![box_spec([7.0, 0.0, 1.0], [0.5, 4.0, 2.0])],
        regions: vec![RegionSpec { name: "B".into(), centre: [3.0, -2.025, 1.0], radius: 0.5 }],
        ..WorldSpec::default()
    })
}

fn small_camera() -> DepthCameraConfig {
    DepthCameraConfig { camera: PinholeCamera { fx: 40.0, fy: 40.0, cx: 31.5, cy: 23.5, width: 64, height: 48 }, min_range_m: 0.1, max_range_m: 10.0 }
}

fn small_lidar() -> LidarConfig {
    LidarConfig { azimuth_steps: 180, ..LidarConfig::vlp16() }
}

fn equipped_sim(seed: u64) -> Simulation {
    let config = QuadrotorConfig {
        odometry_noise: Some(OdometryNoise { position_walk_m_per_sqrt_s: 0.05, yaw_walk_rad_per_sqrt_s: 0.01 }),
        ..QuadrotorConfig::default()
    };
    let vehicle = Vehicle::quadrotor(config, QuadrotorState::at_rest(DVec3::new(0.0, 0.0, 1.0), 0.0)).unwrap();
    let mut sim = Simulation::new(cluttered_world(), vehicle, seed).unwrap();
    sim.add_depth_camera("front", small_camera(), Isometry3::body_from_forward_optical(), DepthNoiseModel::preset("d435-phantom").unwrap()).unwrap();
    let lidar_noise = LidarNoiseModel::new(vec![LidarNoise::Range { sigma_m: 0.02 }, LidarNoise::Dropout { probability: 0.1 }]).unwrap();
    sim.add_lidar("top", small_lidar(), Isometry3 { translation: DVec3::new(0.0, 0.0, 0.1), ..Isometry3::IDENTITY }, lidar_noise).unwrap();
    sim
}

fn observation_bits(sim: &mut Simulation) -> Vec<u64> {
    let obs = sim.observe();
    let mut bits: Vec<u64> = Vec::new();
    for d in &obs.depth {
        bits.extend(d.depth_m.iter().map(|v| u64::from(v.to_bits())));
    }
    for s in &obs.scans {
        bits.extend(s.scan.points_sensor.iter().flat_map(|p| p.iter().map(|v| u64::from(v.to_bits()))));
    }
    bits.extend(obs.odometry.world_from_body.to_matrix_rows().iter().flatten().map(|v| v.to_bits()));
    bits.push(obs.time_s.to_bits());
    bits
}

#[test]
fn simulation_is_deterministic_for_a_seed() {
    let run = |seed: u64| {
        let mut sim = equipped_sim(seed);
        let mut bits = observation_bits(&mut sim);
        for _ in 0..5 {
            sim.step(&BodyVelocityCommand::new(0.5, 0.1, 0.0, 0.3), 0.1, 0.0).unwrap();
            bits.extend(observation_bits(&mut sim));
        }
        bits
    };
    let a = run(42);
    let b = run(42);
    assert_eq!(a, b, "same seed, same bits");
    let c = run(43);
    assert_ne!(a, c, "another seed, other noise");
    // The observation carries the truth: a noise-free render and scan with returns.
    let mut sim = equipped_sim(42);
    let obs = sim.observe();
    assert_eq!(obs.depth.len(), 1);
    assert_eq!(obs.depth[0].name, "front");
    assert_eq!(obs.depth[0].depth_m.len(), 64 * 48);
    assert!(obs.depth[0].truth.depth_m.iter().any(|&d| d > 0.0));
    assert!(!obs.scans[0].truth.points_sensor.is_empty());
    assert!(obs.scans[0].scan.points_sensor.len() < obs.scans[0].truth.points_sensor.len());
    assert_eq!(obs.world_from_body.translation, DVec3::new(0.0, 0.0, 1.0));
    // The camera sees the pole at x = 4 (surface at 3.9 m) at the image centre row... the
    // centre pixel's ray hits the box at x = 6.75 (pole is off-axis by 0.3 m).
    let c = 24 * 64 + 32;
    let d = obs.depth[0].truth.depth_m[c];
    assert!(d > 6.0 && d < 7.0, "centre depth {d}");
}

#[test]
fn simulation_reaches_a_goal_region() {
    let vehicle = Vehicle::quadrotor(instant_quad_config(), QuadrotorState::at_rest(DVec3::new(3.0, 0.0, 1.0), -0.5 * PI)).unwrap();
    let mut sim = Simulation::new(cluttered_world(), vehicle, 0).unwrap();
    sim.set_goal(Goal::Region("B".into())).unwrap();
    // Heading -y at 0.5 m/s: the region (radius 0.5 around y = -2.025) is entered at y = -1.55.
    let mut steps = 0;
    while sim.status().is_running() {
        sim.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.1, 0.0).unwrap();
        steps += 1;
        assert!(steps < 100);
    }
    assert_eq!(*sim.status(), RunStatus::GoalReached);
    assert_eq!(steps, 31);
    let m = sim.metrics();
    assert!(m.success && m.failure.is_none());
    assert!((m.time_s - 3.1).abs() < 1e-12);
    // A ground robot reaches a point goal on flat ground and the run is over.
    let vehicle = Vehicle::ground(GroundRobotConfig::default(), GroundRobotState::at_rest(0.0, 0.0, 0.0)).unwrap();
    let mut sim = Simulation::new(flat_world(), vehicle, 0).unwrap();
    sim.set_goal(Goal::Point { centre: DVec3::new(2.025, 0.0, 0.0), radius_m: 0.25 }).unwrap();
    sim.set_time_limit(Some(10.0)).unwrap();
    while sim.status().is_running() {
        // v_y and v_z are ignored by the ground robot.
        sim.step(&BodyVelocityCommand::new(0.5, 3.0, 1.0, 0.0), 0.1, 0.0).unwrap();
    }
    assert_eq!(*sim.status(), RunStatus::GoalReached);
    assert!((sim.vehicle().position() - DVec3::new(1.8, 0.0, 0.0)).length() < 1e-9);
    assert!(sim.step(&BodyVelocityCommand::ZERO, 0.1, 0.0).is_err());
    // A time limit ends a run with a timeout.
    let vehicle = Vehicle::ground(GroundRobotConfig::default(), GroundRobotState::at_rest(0.0, 0.0, 0.0)).unwrap();
    let mut sim = Simulation::new(flat_world(), vehicle, 0).unwrap();
    sim.set_time_limit(Some(0.95)).unwrap();
    for _ in 0..10 {
        sim.step(&BodyVelocityCommand::ZERO, 0.1, 0.0).unwrap();
    }
    assert_eq!(*sim.status(), RunStatus::TimedOut);
    assert_eq!(sim.metrics().failure.as_deref(), Some("timeout"));
}

/// The argument an input error names.
fn arg<T: std::fmt::Debug>(r: Result<T, SimError>) -> String {
    match r {
        Err(SimError::InvalidInput { argument, .. }) => argument,
        other => panic!("expected an input error, got {other:?}"),
    }
}

#[test]
fn simulation_validates_its_inputs() {
    let mut sim = equipped_sim(1);
    let cmd = BodyVelocityCommand::new(0.1, 0.0, 0.0, 0.0);
    assert_eq!(arg(sim.step(&cmd, 0.0, 0.0)), "dt_s");
    assert_eq!(arg(sim.step(&cmd, -0.1, 0.0)), "dt_s");
    assert_eq!(arg(sim.step(&cmd, f64::NAN, 0.0)), "dt_s");
    assert_eq!(arg(sim.step(&cmd, f64::INFINITY, 0.0)), "dt_s");
    assert_eq!(arg(sim.step(&BodyVelocityCommand::new(f64::NAN, 0.0, 0.0, 0.0), 0.1, 0.0)), "cmd.v_x_m_s");
    assert_eq!(arg(sim.step(&BodyVelocityCommand::new(0.0, 0.0, 0.0, f64::INFINITY), 0.1, 0.0)), "cmd.yaw_rate_rad_s");
    assert_eq!(arg(sim.step(&cmd, 0.1, -1.0)), "compute_time_s");
    assert_eq!(arg(sim.step(&cmd, 0.1, f64::NAN)), "compute_time_s");
    // Nothing moved.
    assert_eq!(sim.time_s(), 0.0);
    assert_eq!(arg(sim.add_depth_camera("front", small_camera(), Isometry3::IDENTITY, DepthNoiseModel::default())), "name");
    assert_eq!(arg(sim.add_lidar("", small_lidar(), Isometry3::IDENTITY, LidarNoiseModel::default())), "name");
    let mut skew = Isometry3::IDENTITY;
    skew.rotation.x_axis.y = 0.5;
    assert_eq!(arg(sim.add_lidar("l2", small_lidar(), skew, LidarNoiseModel::default())), "body_from_sensor");
    assert!(matches!(sim.set_goal(Goal::Region("Z".into())), Err(SimError::Unknown { known, .. }) if known == "B"));
    assert_eq!(arg(sim.set_goal(Goal::Point { centre: DVec3::ZERO, radius_m: 0.0 })), "goal.radius_m");
    assert_eq!(arg(sim.set_time_limit(Some(f64::NAN))), "limit_s");
    // A quadrotor starting inside the pole's reach is refused.
    let vehicle = Vehicle::quadrotor(QuadrotorConfig::default(), QuadrotorState::at_rest(DVec3::new(4.0, 0.0, 1.0), 0.0)).unwrap();
    assert_eq!(arg(Simulation::new(cluttered_world(), vehicle, 0).map(|_| ())), "vehicle");
    // Collisions counted without ending the run when asked.
    let vehicle = Vehicle::quadrotor(instant_quad_config(), QuadrotorState::at_rest(DVec3::new(3.0, 0.3, 1.0), 0.0)).unwrap();
    let mut sim = Simulation::new(cluttered_world(), vehicle, 0).unwrap();
    sim.set_stop_on_collision(false);
    for _ in 0..70 {
        sim.step(&BodyVelocityCommand::new(0.6, 0.0, 0.0, 0.0), 0.1, 0.0).unwrap();
    }
    // Through the pole at x = 4 (once), then into the box at x = 6.75 (the run goes on).
    let m = sim.metrics();
    assert_eq!(m.collisions, 2);
    assert!(m.min_clearance_m < 0.0);
    assert!(sim.status().is_running());
    sim.abort("local_minimum");
    assert_eq!(sim.metrics().failure.as_deref(), Some("local_minimum"));
}
