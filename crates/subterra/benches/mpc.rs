//! MPC tracker benchmarks (Project target: one solve, horizon 20, <= 2 ms on one core).
//!
//! The typical case: a 200 x 200 risk grid at 0.1 m (a coarse terrain map) with a risky band
//! across a curved reference path and four lethal blocks beside it, one reaching into the
//! path; the tracker runs the closed loop along the path (each solve warm-started from the
//! previous one, as on the robot), restarting from the beginning every 60 steps.
//!
//! `cargo bench -p subterra --bench mpc`

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec2;
use std::hint::black_box;
use std::time::Instant;
use subterra::plan::{unicycle_step, MpcConfig, MpcTracker, QpSolverKind, RiskGrid, UnicycleState};

const NX: usize = 200;
const RES: f64 = 0.1;
const ORIGIN: DVec2 = DVec2::new(-5.0, -10.0);
/// Closed-loop steps before the run starts again from the beginning.
const RUN_STEPS: usize = 60;
/// Runs of the closed loop for the per-solve fastest times.
const REPEATS: usize = 30;

/// An arc of radius 6 m turning left from the origin along +x, 1.3 rad long, points 0.1 m apart.
fn reference() -> Vec<DVec2> {
    let radius = 6.0;
    (0..=78).map(|i| i as f64 * 0.1 / radius).map(|phi| DVec2::new(radius * phi.sin(), radius * (1.0 - phi.cos()))).collect()
}

/// Background 0.05-0.2, a band of risk 0.5 across the path near 3 m along it, four blocks.
fn risk() -> Vec<f32> {
    let mut risk = vec![0.0f32; NX * NX];
    let blocks = [(2.0, 2.5, -1.3, -0.7), (4.0, 4.5, 1.6, 2.1), (5.0, 5.6, 0.6, 1.1), (1.5, 2.0, 0.8, 1.3)];
    for iy in 0..NX {
        for ix in 0..NX {
            let c = ORIGIN + RES * DVec2::new(ix as f64 + 0.5, iy as f64 + 0.5);
            let mut r = 0.125 + 0.075 * (1.3 * c.x).sin() * (0.7 * c.y).cos();
            if (2.8..3.3).contains(&c.x) {
                r = 0.5;
            }
            if blocks.iter().any(|&(x0, x1, y0, y1)| (x0..x1).contains(&c.x) && (y0..y1).contains(&c.y)) {
                r = 1.0;
            }
            risk[iy * NX + ix] = r as f32;
        }
    }
    risk
}

fn bench_mpc(c: &mut Criterion) {
    let path = reference();
    let risk = risk();
    let grid = RiskGrid::new(&risk, NX, NX, RES, ORIGIN).unwrap();
    let config = MpcConfig::default();
    let start = UnicycleState { x_m: 0.0, y_m: -0.2, heading_rad: 0.0, speed_m_s: 0.5 };

    // One pass over the run, for orientation: per-solve wall times, iterations, polygons; and
    // how much a third QP per solve (a tracker with `sqp_iterations = 3` solving at the same
    // states) would change the first input.
    let mut tracker = MpcTracker::new(config).unwrap();
    let mut three = MpcConfig::default();
    three.solver.sqp_iterations = 3;
    let mut tracker3 = MpcTracker::new(three).unwrap();
    let mut state = start;
    let (mut times, mut sqp, mut qp, mut polygons, mut changes) = (Vec::new(), 0, 0, 0, Vec::new());
    for _ in 0..RUN_STEPS {
        let out = tracker.solve(&state, &path, Some(&grid), None).unwrap();
        assert!(!out.status.is_backup(), "{:?} at {state:?}", out.status);
        times.push(out.solve_time_s * 1e3);
        sqp += out.sqp_iterations;
        qp += out.qp_iterations;
        polygons = polygons.max(out.polygons.len());
        let u3 = tracker3.solve(&state, &path, Some(&grid), None).unwrap().inputs[0];
        changes.push((u3.accel_m_s2 - out.inputs[0].accel_m_s2).abs().max((u3.yaw_rate_rad_s - out.inputs[0].yaw_rate_rad_s).abs()));
        state = unicycle_step(&state, &out.inputs[0], config.dt_s);
    }
    times.sort_by(f64::total_cmp);
    changes.sort_by(f64::total_cmp);
    let (change_median, change_max) = (changes[changes.len() / 2], changes[changes.len() - 1]);
    println!(
        "closed loop, {RUN_STEPS} solves: wall median {:.3} ms, p90 {:.3} ms, max {:.3} ms; {:.2} QPs and {:.1} interior-point iterations per solve; up to {polygons} polygons; a third QP would change the first input by {change_median:.3} (median), {change_max:.3} (max) (m/s² or rad/s)",
        times[times.len() / 2],
        times[times.len() * 9 / 10],
        times[times.len() - 1],
        sqp as f64 / RUN_STEPS as f64,
        qp as f64 / RUN_STEPS as f64
    );

    // Per solve, robust to a shared machine: the closed loop is deterministic, so run it
    // `REPEATS` times and take each step's fastest time, then the median over the steps.
    for (kind, name) in [(QpSolverKind::Banded, "banded"), (QpSolverKind::Clarabel, "clarabel")] {
        let mut config = config;
        config.solver.qp_solver = kind;
        let mut best = vec![f64::INFINITY; RUN_STEPS];
        for _ in 0..REPEATS {
            let mut tracker = MpcTracker::new(config).unwrap();
            let mut state = start;
            for t in &mut best {
                let t0 = Instant::now();
                let out = tracker.solve(&state, &path, Some(&grid), None).unwrap();
                *t = t.min(t0.elapsed().as_secs_f64() * 1e3);
                state = unicycle_step(&state, &out.inputs[0], config.dt_s);
            }
        }
        best.sort_by(f64::total_cmp);
        println!("{name}: per solve, fastest of {REPEATS} runs: median {:.3} ms, p90 {:.3} ms, max {:.3} ms", best[RUN_STEPS / 2], best[RUN_STEPS * 9 / 10], best[RUN_STEPS - 1]);
    }

    // The same closed loop with each QP solver, in the same run.
    for (kind, name) in [(QpSolverKind::Banded, "mpc_solve_closed_loop_h20_200x200"), (QpSolverKind::Clarabel, "mpc_solve_closed_loop_h20_200x200_clarabel")] {
        let mut config = config;
        config.solver.qp_solver = kind;
        let mut tracker = MpcTracker::new(config).unwrap();
        let mut state = start;
        let mut steps = 0;
        c.bench_function(name, |b| {
            b.iter(|| {
                if steps == RUN_STEPS {
                    tracker.reset();
                    state = start;
                    steps = 0;
                }
                let out = tracker.solve(black_box(&state), &path, Some(&grid), None).unwrap();
                state = unicycle_step(&state, &out.inputs[0], config.dt_s);
                steps += 1;
                out.command
            });
        });
    }

    let mut tracker = MpcTracker::new(config).unwrap();
    let state = UnicycleState { x_m: 1.0, y_m: 0.0, heading_rad: 0.1, speed_m_s: 0.8 };
    c.bench_function("mpc_solve_cold_h20_200x200", |b| {
        b.iter(|| {
            tracker.reset();
            tracker.solve(black_box(&state), &path, Some(&grid), None).unwrap().command
        });
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(4));
    targets = bench_mpc
}
criterion_main!(benches);
