//! Risk-aware A* benchmarks: seeded random risk grids of 200x200 and 1000x1000 cells (0.1 m),
//! start and goal in opposite corners, the default config with `r_total = 1` (the search is the
//! same whatever the budget). Project target: <= 2 ms on 200x200; subterra: <= 100 ms on
//! 1000x1000.
//!
//! `cargo bench -p subterra --bench astar`

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec2;
use subterra::plan::{PlanStatus, RiskAStar, RiskAStarConfig, RiskGrid};
use subterra::terrain::CellIndex;

/// Cell side of the benchmark grids [m].
const RESOLUTION_M: f64 = 0.1;
/// Smooth risk blobs per grid.
const BLOBS: usize = 40;
/// Lethal rectangles per grid.
const OBSTACLES: usize = 30;

/// SplitMix64 (Steele, Lea, Flood 2014): the few random numbers of [`random_risk_grid`], drawn
/// identically by `subterra.bench.plan.SplitMix64`, so both benchmarks plan on the same grids.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi): the top 53 bits as a fraction.
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next() >> 11) as f64 * (-53f64).exp2())
    }
}

/// An `n x n` risk grid, the same as `subterra.bench.plan.random_risk_grid` makes (same draws
/// in the same order; values equal up to the last bit of `exp`): the hazard
/// `s = Σ a·exp(-|p - c|²/2σ²)` of `BLOBS` Gaussian blobs (centre uniform over the grid, σ in
/// [0.02n, 0.08n] cells, a in [0.1, 1.5] per metre, cut at 4σ; cell centres at `i + 0.5`), risk
/// `1 - exp(-s)`; then `OBSTACLES` lethal rectangles (risk 1; lower corner
/// `floor(uniform(0, n))`, sides `floor(uniform(max(1, 0.01n), max(2, 0.06n)))` cells); then the
/// `max(2, floor(0.02n))`-cell squares at the start (0, 0) and goal (n-1, n-1) corners cleared to 0.
fn random_risk_grid(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = SplitMix64(seed);
    let nf = n as f64;
    let mut hazard = vec![0.0f64; n * n];
    for _ in 0..BLOBS {
        let (cx, cy) = (rng.uniform(0.0, nf), rng.uniform(0.0, nf));
        let sigma = rng.uniform(0.02 * nf, 0.08 * nf);
        let a = rng.uniform(0.1, 1.5);
        let lo = |c: f64| (c - 4.0 * sigma).floor().max(0.0) as usize;
        let hi = |c: f64| (c + 4.0 * sigma).ceil().min(nf - 1.0) as usize;
        for iy in lo(cy)..=hi(cy) {
            let y = iy as f64 + 0.5 - cy;
            for ix in lo(cx)..=hi(cx) {
                let x = ix as f64 + 0.5 - cx;
                hazard[iy * n + ix] += a * (-(x * x + y * y) / (2.0 * sigma * sigma)).exp();
            }
        }
    }
    let mut risk: Vec<f32> = hazard.iter().map(|s| -(-s).exp_m1() as f32).collect();
    let (lo, hi) = ((0.01 * nf).max(1.0), (0.06 * nf).max(2.0));
    for _ in 0..OBSTACLES {
        let (x0, y0) = (rng.uniform(0.0, nf).floor() as usize, rng.uniform(0.0, nf).floor() as usize);
        let (w, h) = (rng.uniform(lo, hi).floor() as usize, rng.uniform(lo, hi).floor() as usize);
        for iy in y0..(y0 + h).min(n) {
            risk[iy * n + x0..iy * n + (x0 + w).min(n)].fill(1.0);
        }
    }
    let clear = ((0.02 * nf).floor() as usize).max(2).min(n);
    for iy in 0..clear {
        risk[iy * n..iy * n + clear].fill(0.0);
        let top = n - 1 - iy;
        risk[top * n + n - clear..top * n + n].fill(0.0);
    }
    risk
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
            "{n}x{n}: risk sum {:.4} (subterra.bench.plan.random_risk_grid({n}, 0).sum() is the same), {:.1}% cells untraversable; path {} cells, {:.2} m, cost {:.4}, accumulated risk {:.4}; expanded {} cells ({:.1}%)",
            risk.iter().map(|&r| r as f64).sum::<f64>(),
            100.0 * lethal as f64 / (n * n) as f64,
            path.cells.len(),
            path.length_m,
            path.cost,
            path.accumulated_risk,
            out.expanded,
            100.0 * out.expanded as f64 / (n * n) as f64
        );
        // Per-plan wall time: on a loaded machine the minimum is the run that kept its core.
        let runs = if n <= 200 { 300 } else { 20 };
        let mut ms: Vec<f64> = (0..runs)
            .map(|_| {
                let t0 = Instant::now();
                black_box(planner.plan_cells(&grid, start, goal).unwrap());
                t0.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        println!("{n}x{n}: wall per plan: min {:.3} ms, median {:.3} ms ({runs} plans)", ms[0], ms[runs / 2]);
        c.bench_function(&format!("astar_{n}x{n}"), |b| b.iter(|| planner.plan_cells(black_box(&grid), start, goal).unwrap()));
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(4));
    targets = bench_astar
}
criterion_main!(benches);
