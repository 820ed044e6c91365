//! Behaviour of the MPC tracker: convergence, risk-limited speed, obstacle margins, the
//! backup stop, limits, determinism, input errors.

use glam::DVec2;
use proptest::prelude::*;

use super::*;

/// Solver tolerance for bounds on the exact rollout [m/s, m].
const TOL: f64 = 1e-3;

fn straight_path() -> Vec<DVec2> {
    vec![DVec2::new(-1.0, 0.0), DVec2::new(30.0, 0.0)]
}

/// A `(ny, nx)` grid of `value` at 0.1 m with its lower-left corner at `origin`.
fn grid_of(nx: usize, ny: usize, value: f32) -> Vec<f32> {
    vec![value; nx * ny]
}

/// Sets the cells whose centres fall in `[x0, x1] x [y0, y1]` to `value`.
fn paint(risk: &mut [f32], nx: usize, origin: DVec2, res: f64, (x0, x1, y0, y1): (f64, f64, f64, f64), value: f32) {
    let ny = risk.len() / nx;
    for iy in 0..ny {
        for ix in 0..nx {
            let c = origin + res * DVec2::new(ix as f64 + 0.5, iy as f64 + 0.5);
            if c.x >= x0 && c.x <= x1 && c.y >= y0 && c.y <= y1 {
                risk[iy * nx + ix] = value;
            }
        }
    }
}

/// Runs the closed loop for `steps`, the plant being the exact model driven by the first
/// planned input; calls `check` on every output and returns the final state.
fn closed_loop(
    tracker: &mut MpcTracker,
    mut state: UnicycleState,
    path: &[DVec2],
    risk: Option<&RiskGrid<'_>>,
    steps: usize,
    mut check: impl FnMut(&UnicycleState, &MpcOutput),
) -> UnicycleState {
    for _ in 0..steps {
        let out = tracker.solve(&state, path, risk, None).unwrap();
        check(&state, &out);
        state = step(&state, &out.inputs[0], tracker.config().dt_s);
    }
    state
}

#[test]
fn converges_to_a_straight_path_and_the_desired_speed() {
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    let start = UnicycleState { x_m: 0.0, y_m: 0.6, heading_rad: 0.4, speed_m_s: 0.0 };
    let end = closed_loop(&mut tracker, start, &straight_path(), None, 100, |_, out| {
        assert_eq!(out.status, MpcStatus::Solved, "{out:?}");
        assert!(out.sqp_iterations >= 1);
    });
    assert!(end.y_m.abs() < 0.01, "cross-track error {end:?}");
    assert!(end.heading_rad.abs() < 0.01, "heading {end:?}");
    assert!((end.speed_m_s - 0.8).abs() < 0.01, "speed {end:?}");
}

#[test]
fn stops_at_the_end_of_the_path() {
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    let path = [DVec2::new(0.0, 0.0), DVec2::new(3.0, 0.0)];
    let start = UnicycleState { speed_m_s: 0.5, ..Default::default() };
    let end = closed_loop(&mut tracker, start, &path, None, 120, |_, _| {});
    assert!((end.x_m - 3.0).abs() < 0.05 && end.y_m.abs() < 0.02 && end.speed_m_s.abs() < 0.02, "{end:?}");
}

#[test]
fn risk_limits_the_speed_of_every_predicted_state() {
    // A band of risk 0.6 across the path for 2 <= x <= 3.5: v <= 0.4 m/s inside.
    let (nx, ny, res, origin) = (200, 60, 0.1, DVec2::new(-2.0, -3.0));
    let mut risk = grid_of(nx, ny, 0.0);
    paint(&mut risk, nx, origin, res, (2.0, 3.5, -10.0, 10.0), 0.6);
    let grid = RiskGrid::new(&risk, nx, ny, res, origin).unwrap();
    let mut config = MpcConfig::default();
    config.tracking.desired_speed_m_s = 1.0;
    let mut tracker = MpcTracker::new(config).unwrap();
    let start = UnicycleState { speed_m_s: 1.0, ..Default::default() };
    let mut slowest_in_band = f64::INFINITY;
    let end = closed_loop(&mut tracker, start, &straight_path(), Some(&grid), 80, |state, out| {
        assert!(!out.status.is_backup(), "{out:?}");
        for (k, s) in out.predicted.iter().enumerate().skip(1) {
            let r = grid.risk_at(s.position()).unwrap();
            assert!(s.speed_m_s <= 1.0 * (1.0 - r) + TOL, "k={k}: v={} at risk {r}", s.speed_m_s);
            assert!(s.speed_m_s <= out.speed_limits_m_s[k - 1] + out.max_speed_slack_m_s + 1e-12);
        }
        if grid.risk_at(state.position()) == Some(0.6) {
            slowest_in_band = slowest_in_band.min(state.speed_m_s);
            assert!(state.speed_m_s <= 0.4 + TOL, "{state:?}");
        }
    });
    assert!(slowest_in_band > 0.3, "the robot crawls through the band: {slowest_in_band}");
    assert!(end.x_m > 4.0 && end.speed_m_s > 0.9, "it speeds up again after the band: {end:?}");
}

#[test]
fn keeps_the_margin_from_a_lethal_block_beside_the_path() {
    // A 0.6 x 0.6 m block whose near edge is 0.2 m left of the path: the 0.67 m wide robot
    // with a 0.1 m margin must swerve right by about 0.25 m.
    let (nx, ny, res, origin) = (120, 60, 0.1, DVec2::new(-2.0, -3.0));
    let mut risk = grid_of(nx, ny, 0.0);
    paint(&mut risk, nx, origin, res, (4.0, 4.6, 0.2, 0.8), 1.0);
    let grid = RiskGrid::new(&risk, nx, ny, res, origin).unwrap();
    let config = MpcConfig::default();
    let margin = config.obstacles.margin_m;
    let mut tracker = MpcTracker::new(config).unwrap();
    let start = UnicycleState { speed_m_s: 0.8, ..Default::default() };
    let mut smallest = f64::INFINITY;
    let mut widest = 0.0f64;
    let end = closed_loop(&mut tracker, start, &straight_path(), Some(&grid), 120, |state, out| {
        assert_eq!(out.status, MpcStatus::Solved, "{state:?}");
        assert!(out.min_clearance_m >= margin - 0.02, "predicted clearance {} at {state:?}", out.min_clearance_m);
        smallest = smallest.min(clearance(&config, &out.polygons, state));
        widest = widest.max(-state.y_m);
    });
    assert!(smallest >= margin - 0.02 && smallest.is_finite(), "closed-loop clearance {smallest}");
    assert!(widest > 0.15, "the robot swerved {widest} m");
    assert!(end.x_m > 7.0 && end.y_m.abs() < 0.05, "back on the path after the block: {end:?}");
}

#[test]
fn a_wall_too_close_to_stop_before_gives_the_backup_stop() {
    // Full speed toward a wide wall whose face is 0.3 m ahead of the robot's front: braking
    // at 1 m/s² needs 0.5 m and turning away needs more.
    let (nx, ny, res, origin) = (60, 100, 0.1, DVec2::new(-2.0, -5.0));
    let mut risk = grid_of(nx, ny, 0.0);
    paint(&mut risk, nx, origin, res, (0.8, 1.5, -10.0, 10.0), 1.0);
    let grid = RiskGrid::new(&risk, nx, ny, res, origin).unwrap();
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    let start = UnicycleState { speed_m_s: 1.0, ..Default::default() };
    let out = tracker.solve(&start, &straight_path(), Some(&grid), None).unwrap();
    assert_eq!(out.status, MpcStatus::InfeasibleBackup, "{out:?}");
    assert_eq!(out.command, MpcCommand { speed_m_s: 0.9, yaw_rate_rad_s: 0.0 });
    for (k, u) in out.inputs.iter().enumerate() {
        assert_eq!(u.yaw_rate_rad_s, 0.0);
        let expected = if k < 10 { -1.0 } else { 0.0 };
        assert!((u.accel_m_s2 - expected).abs() < 1e-9, "k={k}: {u:?}");
    }
    let last = out.predicted[20];
    assert!(last.speed_m_s.abs() < 1e-9 && last.y_m == 0.0 && last.heading_rad == 0.0);
    assert!((last.x_m - 0.5).abs() < 1e-9, "braked over v²/2a = 0.5 m: {last:?}");
    assert!(out.max_obstacle_slack_m > 0.0);
}

#[test]
fn a_start_inside_the_margin_backs_out_without_a_backup() {
    // Standing still 0.05 m from a wall ahead (inside the 0.1 m margin): a plan that does not
    // go deeper exists, so no backup; the slack is reported.
    let (nx, ny, res, origin) = (60, 100, 0.1, DVec2::new(-2.0, -5.0));
    let mut risk = grid_of(nx, ny, 0.0);
    paint(&mut risk, nx, origin, res, (0.6, 1.5, -10.0, 10.0), 1.0);
    let grid = RiskGrid::new(&risk, nx, ny, res, origin).unwrap();
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    let out = tracker.solve(&UnicycleState::default(), &straight_path(), Some(&grid), None).unwrap();
    assert!(!out.status.is_backup(), "{out:?}");
    assert!(out.command.speed_m_s <= 1e-6, "it does not move toward the wall: {:?}", out.command);
    assert!(out.min_clearance_m >= 0.05 - 0.02);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn limits_always_hold(
        x in -1.0f64..1.0, y in -1.0f64..1.0, heading in -3.2f64..3.2, speed in -0.5f64..1.5,
        bx in 1.0f64..4.0, by in -1.5f64..1.5, band in 0.0f32..0.95,
    ) {
        let (nx, ny, res, origin) = (100, 80, 0.1, DVec2::new(-3.0, -4.0));
        let mut risk = grid_of(nx, ny, 0.0);
        paint(&mut risk, nx, origin, res, (1.0, 2.0, -10.0, 10.0), band);
        paint(&mut risk, nx, origin, res, (bx, bx + 0.5, by, by + 0.5), 1.0);
        let grid = RiskGrid::new(&risk, nx, ny, res, origin).unwrap();
        let config = MpcConfig::default();
        let mut tracker = MpcTracker::new(config).unwrap();
        let path = [DVec2::new(-2.0, 0.0), DVec2::new(2.0, 0.5), DVec2::new(5.0, -1.0)];
        let state = UnicycleState { x_m: x, y_m: y, heading_rad: heading, speed_m_s: speed };
        let out = tracker.solve(&state, &path, Some(&grid), None).unwrap();
        let l = &config.limits;
        prop_assert_eq!(out.predicted.len(), 21);
        prop_assert_eq!(out.inputs.len(), 20);
        for u in &out.inputs {
            prop_assert!(u.accel_m_s2.abs() <= l.max_accel_m_s2 + 1e-9 && u.yaw_rate_rad_s.abs() <= l.max_yaw_rate_rad_s + 1e-9, "{:?}", u);
        }
        for (k, s) in out.predicted.iter().enumerate().skip(1) {
            let hi = out.speed_limits_m_s[k - 1];
            prop_assert!(s.speed_m_s <= hi + out.max_speed_slack_m_s + 1e-12 && s.speed_m_s >= l.min_speed_m_s.max(-hi) - out.max_speed_slack_m_s - 1e-12);
        }
        // The speed slack is only what braking at a_max cannot avoid, or a trade against a
        // start inside an obstacle's margin: none when the start is within the limits and
        // braking takes the footprint (half-diagonal 0.6 m) nowhere near the block's margin.
        let to_block = DVec2::new((bx - x).max(x - bx - 0.5).max(0.0), (by - y).max(y - by - 0.5).max(0.0)).length();
        let braking = speed * speed / (2.0 * l.max_accel_m_s2) + 0.6 + config.obstacles.margin_m;
        if speed >= l.min_speed_m_s && speed <= l.max_speed_m_s * (1.0 - band as f64) && to_block > braking && !out.status.is_backup() {
            prop_assert!(out.max_speed_slack_m_s <= TOL, "{}", out.max_speed_slack_m_s);
        }
        prop_assert!(out.command.speed_m_s == out.predicted[1].speed_m_s && out.command.yaw_rate_rad_s == out.inputs[0].yaw_rate_rad_s);
    }
}

#[test]
fn same_calls_give_the_same_bits() {
    let (nx, ny, res, origin) = (120, 60, 0.1, DVec2::new(-2.0, -3.0));
    let mut risk = grid_of(nx, ny, 0.05);
    paint(&mut risk, nx, origin, res, (2.0, 2.5, -0.2, 0.6), 1.0);
    paint(&mut risk, nx, origin, res, (1.0, 1.5, -3.0, 3.0), 0.5);
    let grid = RiskGrid::new(&risk, nx, ny, res, origin).unwrap();
    let path = [DVec2::new(0.0, 0.0), DVec2::new(3.0, 0.5), DVec2::new(6.0, -0.5)];
    let run = || {
        let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
        let mut outs = Vec::new();
        closed_loop(&mut tracker, UnicycleState { speed_m_s: 0.3, ..Default::default() }, &path, Some(&grid), 15, |_, out| {
            let mut out = out.clone();
            out.solve_time_s = 0.0;
            outs.push(out);
        });
        outs
    };
    let (a, b) = (run(), run());
    assert_eq!(a, b);
    // And reset() is a fresh tracker.
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    let state = UnicycleState { speed_m_s: 0.3, ..Default::default() };
    let mut first = tracker.solve(&state, &path, Some(&grid), None).unwrap();
    tracker.solve(&state, &path, Some(&grid), None).unwrap();
    tracker.reset();
    let mut again = tracker.solve(&state, &path, Some(&grid), None).unwrap();
    first.solve_time_s = 0.0;
    again.solve_time_s = 0.0;
    assert_eq!(first, again);
}

#[test]
fn bad_inputs_name_the_argument_and_leave_the_tracker_alone() {
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    let path = straight_path();
    let nan = UnicycleState { x_m: f64::NAN, ..Default::default() };
    assert!(tracker.solve(&nan, &path, None, None).unwrap_err().to_string().contains("`state`"));
    let absurd = UnicycleState { speed_m_s: 1e9, ..Default::default() };
    assert!(tracker.solve(&absurd, &path, None, None).unwrap_err().to_string().contains("`state`"));
    let ok = UnicycleState::default();
    assert!(tracker.solve(&ok, &path[..1], None, None).unwrap_err().to_string().contains("`reference_path`"));
    assert!(tracker.solve(&ok, &path, None, Some(5.0)).unwrap_err().to_string().contains("`desired_speed`"));
    assert!(tracker.solve(&ok, &path, None, Some(f64::NAN)).unwrap_err().to_string().contains("`desired_speed`"));
    let bad = MpcConfig { horizon: 0, ..MpcConfig::default() };
    assert!(MpcTracker::new(bad).unwrap_err().to_string().contains("`horizon`"));
    // The failed calls did not count: the next solve is a first solve.
    let mut fresh = MpcTracker::new(MpcConfig::default()).unwrap();
    let mut a = tracker.solve(&ok, &path, None, None).unwrap();
    let mut b = fresh.solve(&ok, &path, None, None).unwrap();
    a.solve_time_s = 0.0;
    b.solve_time_s = 0.0;
    assert_eq!(a, b);
}


/// The benchmark's world in small: a curved path, a risky band and lethal blocks beside it,
/// one reaching into the path.
fn blocks_world() -> (Vec<DVec2>, Vec<f32>, usize, DVec2) {
    let path: Vec<DVec2> = (0..=78).map(|i| i as f64 * 0.1 / 6.0).map(|phi| DVec2::new(6.0 * phi.sin(), 6.0 * (1.0 - phi.cos()))).collect();
    let (nx, origin) = (120, DVec2::new(-2.0, -4.0));
    let mut risk = grid_of(nx, nx, 0.1);
    paint(&mut risk, nx, origin, 0.1, (2.8, 3.3, -4.0, 8.0), 0.5);
    for block in [(2.0, 2.5, -1.3, -0.4), (4.0, 4.5, 1.6, 2.1), (5.0, 5.6, 0.6, 1.1), (1.5, 2.0, 0.8, 1.3)] {
        paint(&mut risk, nx, origin, 0.1, block, 1.0);
    }
    (path, risk, nx, origin)
}

#[test]
fn the_banded_solver_finds_clarabels_solution_of_every_qp_of_a_run() {
    let (path, risk, nx, origin) = blocks_world();
    let grid = RiskGrid::new(&risk, nx, nx, 0.1, origin).unwrap();
    let mut config = MpcConfig::default();
    config.solver.qp_solver = QpSolverKind::Clarabel;
    let mut tracker = MpcTracker::new(config).unwrap();
    let (mut clarabel, mut banded) = (QpSolver::new(50, QpSolverKind::Clarabel), ipm::BandedIpm::default());
    let (mut z_clarabel, mut z_banded) = (Vec::new(), Vec::new());
    let start = UnicycleState { x_m: 0.0, y_m: -0.3, heading_rad: 0.0, speed_m_s: 0.5 };
    let (mut qps, mut obstacle_qps, mut iterations) = (0, 0, 0);
    let mut state = start;
    for _ in 0..60 {
        let out = tracker.solve(&state, &path, Some(&grid), None).unwrap();
        let qp = &tracker.ws.qp;
        let (a, _) = clarabel.solve(qp, &mut z_clarabel);
        let (b, it) = banded.solve(qp, 50, &mut z_banded);
        assert_eq!(a, QpStatus::Solved);
        assert_eq!(b, QpStatus::Solved, "iterations {it}");
        // The stage-by-stage layout keeps the band about one stage wide (7 variables and 4
        // dynamics rows per stage).
        assert!(banded.half_bandwidth() <= 14, "half bandwidth {}", banded.half_bandwidth());
        let objective = |z: &[f64]| -> f64 {
            let mut value: f64 = qp.q.iter().zip(z).map(|(q, z)| q * z).sum();
            for c in 0..z.len() {
                for k in qp.p.colptr[c]..qp.p.colptr[c + 1] {
                    let r = qp.p.rowval[k];
                    value += qp.p.nzval[k] * z[r] * z[c] * if r == c { 0.5 } else { 1.0 };
                }
            }
            value
        };
        let (fa, fb) = (objective(&z_clarabel), objective(&z_banded));
        assert!((fa - fb).abs() <= 1e-5 * fa.abs().max(1.0), "objectives {fa} and {fb}");
        let gap = z_clarabel.iter().zip(&z_banded).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(gap < 1e-3, "solutions differ by {gap}");
        qps += 1;
        obstacle_qps += usize::from(qp.a.rows > qp.equalities + 6 * config.horizon);
        iterations += it;
        state = step(&state, &out.inputs[0], config.dt_s);
    }
    assert!(obstacle_qps >= 10, "only {obstacle_qps} of {qps} QPs had obstacle rows");
    assert!(iterations <= 25 * qps, "{iterations} iterations over {qps} QPs");
}

#[test]
fn the_last_qp_solves_alike_with_either_solver_and_bad_parts_are_named() {
    let (path, risk, nx, origin) = blocks_world();
    let grid = RiskGrid::new(&risk, nx, nx, 0.1, origin).unwrap();
    let mut tracker = MpcTracker::new(MpcConfig::default()).unwrap();
    assert!(tracker.last_qp().is_none());
    let state = UnicycleState { x_m: 1.2, y_m: -0.1, heading_rad: 0.05, speed_m_s: 0.8 };
    tracker.solve(&state, &path, Some(&grid), None).unwrap();
    let qp = tracker.last_qp().unwrap();
    assert_eq!(qp.q.len(), 7 * tracker.config().horizon);
    let banded = qp.solve(QpSolverKind::Banded, 50).unwrap();
    let clarabel = qp.solve(QpSolverKind::Clarabel, 50).unwrap();
    assert_eq!((banded.status, clarabel.status), (QpStatus::Solved, QpStatus::Solved));
    let gap = banded.z.iter().zip(&clarabel.z).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(gap < 1e-3, "{gap}");
    assert_eq!(qp.solve(QpSolverKind::Banded, 50).unwrap().z, banded.z, "same QP, same bits");

    let field = |bad: MpcQp| match bad.solve(QpSolverKind::Banded, 50) {
        Err(Error::InvalidInput { argument, .. }) => argument,
        other => panic!("{other:?}"),
    };
    let mut bad = qp.clone();
    bad.p_colptr.pop();
    assert_eq!(field(bad), "P");
    let mut bad = qp.clone();
    // Column 1's diagonal entry moved below the diagonal.
    let k = bad.p_colptr[2] - 1;
    bad.p_rowval[k] = bad.q.len() - 1;
    assert_eq!(field(bad), "P");
    let mut bad = qp.clone();
    bad.a_rowval[0] = bad.b.len();
    assert_eq!(field(bad), "A");
    let mut bad = qp.clone();
    bad.b[3] = f64::NAN;
    assert_eq!(field(bad), "b");
    let mut bad = qp.clone();
    bad.equalities = bad.b.len() + 1;
    assert_eq!(field(bad), "equalities");
    assert!(qp.solve(QpSolverKind::Banded, 0).is_err());
    tracker.reset();
    assert!(tracker.last_qp().is_none(), "reset forgets the last QP");
}
