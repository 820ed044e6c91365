//! Risk-aware A* benchmarks: seeded random risk grids of 200x200 and 1000x1000 cells (0.1 m),
//! start and goal in opposite corners, the default config with `r_total = 1` (the search is the
//! same whatever the budget). DESIGN §6 target: <= 2 ms on 200x200; subterra: <= 100 ms on
//! 1000x1000.
//!
//! `cargo bench -p subterra --bench astar`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec2;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use subterra::plan::{PlanStatus, RiskAStar, RiskAStarConfig, RiskGrid};
use subterra::terrain::CellIndex;

/// Cell side of the benchmark grids [m].
const RESOLUTION_M: f64 = 0.1;
/// Smooth risk blobs per grid.
const BLOBS: usize = 40;
/// Lethal rectangles per grid.
const OBSTACLES: usize = 30;

/// An `n x n` risk grid: the hazard `s = Σ a·exp(-|p - c|²/2σ²)` of `BLOBS` Gaussian blobs
/// (centre uniform, σ in [0.02n, 0.08n] cells, a in [0.1, 1.5] per metre, cut at 4σ), risk
/// `1 - exp(-s)`; then `OBSTACLES` lethal rectangles (sides in [0.01n, 0.06n] cells, risk 1);
/// then the `0.02n`-cell squares at the start (0, 0) and goal (n-1, n-1) corners cleared to 0.
/// Same recipe as `subterra.bench.plan.random_risk_grid` (not the same random numbers).
fn random_risk_grid(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let nf = n as f64;
    let mut hazard = vec![0.0f64; n * n];
    for _ in 0..BLOBS {
        let (cx, cy) = (rng.random_range(0.0..nf), rng.random_range(0.0..nf));
        let sigma = rng.random_range(0.02 * nf..0.08 * nf);
        let a = rng.random_range(0.1..1.5);
        let lo = |c: f64| ((c - 4.0 * sigma).floor().max(0.0)) as usize;
        let hi = |c: f64| ((c + 4.0 * sigma).ceil().min(nf - 1.0)) as usize;
        for iy in lo(cy)..=hi(cy) {
            for ix in lo(cx)..=hi(cx) {
                let d2 = (ix as f64 + 0.5 - cx).powi(2) + (iy as f64 + 0.5 - cy).powi(2);
                hazard[iy * n + ix] += a * (-d2 / (2.0 * sigma * sigma)).exp();
            }
        }
    }
    let mut risk: Vec<f32> = hazard.iter().map(|s| -(-s).exp_m1() as f32).collect();
    let side = |rng: &mut Xoshiro256PlusPlus| rng.random_range((0.01 * nf).max(1.0)..(0.06 * nf).max(2.0)) as usize;
    for _ in 0..OBSTACLES {
        let (x0, y0) = (rng.random_range(0..n), rng.random_range(0..n));
        let (w, h) = (side(&mut rng), side(&mut rng));
        for iy in y0..(y0 + h).min(n) {
            risk[iy * n + x0..iy * n + (x0 + w).min(n)].fill(1.0);
        }
    }
    let clear = ((0.02 * nf) as usize).max(2).min(n);
    for iy in 0..clear {
        risk[iy * n..iy * n + clear].fill(0.0);
        let top = n - 1 - iy;
        risk[top * n + n - clear..top * n + n].fill(0.0);
    }
    risk
}

/// CPU time this thread has run [ns] (Linux `schedstat`), to see past a loaded machine's
/// wall-clock noise; `None` elsewhere.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

fn bench_astar(c: &mut Criterion) {
    let config = RiskAStarConfig { r_total: 1.0, ..RiskAStarConfig::default() };
    for n in [200usize, 1000] {
        let risk = random_risk_grid(n, 0);
        let grid = RiskGrid::new(&risk, n, n, RESOLUTION_M, DVec2::ZERO).unwrap();
        let mut planner = RiskAStar::new(config).unwrap();
        let (start, goal) = (CellIndex { ix: 0, iy: 0 }, CellIndex { ix: n as u32 - 1, iy: n as u32 - 1 });
        let out = planner.plan_cells(&grid, start, goal).unwrap();
        assert_eq!(out.status, PlanStatus::Found);
        let path = out.path.as_ref().unwrap();
        let lethal = risk.iter().filter(|&&r| r as f64 >= config.r_inst).count();
        println!(
            "{n}x{n}: {:.1}% cells untraversable; path {} cells, {:.2} m, cost {:.4}, accumulated risk {:.4}; expanded {} cells ({:.1}%)",
            100.0 * lethal as f64 / (n * n) as f64,
            path.cells.len(),
            path.length_m,
            path.cost,
            path.accumulated_risk,
            out.expanded,
            100.0 * out.expanded as f64 / (n * n) as f64
        );
        let runs = if n <= 200 { 200 } else { 10 };
        let cpu_start = thread_cpu_ns();
        for _ in 0..runs {
            black_box(planner.plan_cells(&grid, start, goal).unwrap());
        }
        let cpu_ms = cpu_start.zip(thread_cpu_ns()).map(|(a, b)| (b - a) as f64 / runs as f64 / 1e6).unwrap_or(f64::NAN);
        println!("{n}x{n}: {cpu_ms:.3} ms CPU per plan (mean of {runs})");
        c.bench_function(&format!("astar_{n}x{n}"), |b| b.iter(|| planner.plan_cells(black_box(&grid), start, goal).unwrap()));
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(4));
    targets = bench_astar
}
criterion_main!(benches);
