//! Seeded property tests of the risk-aware A* (proptest): its optimal cost equals a plain
//! Dijkstra's over the same graph, its paths never enter an untraversable cell nor cut a
//! forbidden corner, zero-risk grids give octile-length paths, and the budget check is exact.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::DVec2;
use proptest::prelude::*;
use subterra::plan::{CostModel, PlanStatus, RiskAStar, RiskAStarConfig, RiskGrid};
use subterra::terrain::CellIndex;

/// The effective risk of a cell: NaN is unknown.
fn effective(config: &RiskAStarConfig, r: f32) -> f64 {
    if r.is_nan() {
        config.unknown_risk
    } else {
        r as f64
    }
}

fn traversable(config: &RiskAStarConfig, r: f32) -> bool {
    effective(config, r) < config.r_inst
}

/// Optimal cost from `start` to every cell by textbook Dijkstra (no heuristic, no stamps),
/// written from the cost model of the module docs: cost `λ - ln(1 - r)`, move `d·(c_a + c_b)/2`,
/// no diagonal past an untraversable corner unless corner cutting is allowed.
fn dijkstra(config: &RiskAStarConfig, risk: &[f32], nx: usize, ny: usize, res: f64, start: usize) -> Vec<f64> {
    let cost = |i: usize| match config.cost_model {
        CostModel::Risk => config.lam - (1.0 - effective(config, risk[i]).min(1.0 - 1.0 / 16_777_216.0)).ln(),
        // The baseline: 1 + k·r per metre.
        CostModel::Additive => 1.0 + config.additive_weight * effective(config, risk[i]),
    };
    let mut dist = vec![f64::INFINITY; nx * ny];
    let mut done = vec![false; nx * ny];
    let mut heap = BinaryHeap::new();
    if !traversable(config, risk[start]) {
        return dist;
    }
    dist[start] = 0.0;
    heap.push(Reverse((0u64, start)));
    while let Some(Reverse((_, a))) = heap.pop() {
        if done[a] {
            continue;
        }
        done[a] = true;
        let (ax, ay) = ((a % nx) as i64, (a / nx) as i64);
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let (bx, by) = (ax + dx, ay + dy);
                if (dx, dy) == (0, 0) || bx < 0 || by < 0 || bx >= nx as i64 || by >= ny as i64 {
                    continue;
                }
                let b = by as usize * nx + bx as usize;
                if !traversable(config, risk[b]) {
                    continue;
                }
                let diagonal = dx != 0 && dy != 0;
                if diagonal && !config.allow_corner_cutting {
                    let side1 = ay as usize * nx + bx as usize;
                    let side2 = by as usize * nx + ax as usize;
                    if !(traversable(config, risk[side1]) && traversable(config, risk[side2])) {
                        continue;
                    }
                }
                let d = if diagonal { res * 2f64.sqrt() } else { res };
                let g = dist[a] + d * (cost(a) + cost(b)) / 2.0;
                if g < dist[b] {
                    dist[b] = g;
                    heap.push(Reverse((g.to_bits(), b)));
                }
            }
        }
    }
    dist
}

/// A grid of risks: mostly smooth values, some lethal cells, some unknown.
fn grid_strategy() -> impl Strategy<Value = (usize, usize, Vec<f32>)> {
    (1usize..24, 1usize..24).prop_flat_map(|(nx, ny)| {
        let value = prop_oneof![4 => Just(0.0f32), 6 => 0.0f32..0.95, 3 => Just(1.0f32), 1 => Just(f32::NAN), 1 => 0.5f32..1.0];
        (Just(nx), Just(ny), prop::collection::vec(value, nx * ny))
    })
}

fn config_strategy() -> impl Strategy<Value = RiskAStarConfig> {
    (0.01f64..2.0, 0.3f64..=1.0, any::<bool>(), 0.0f64..0.6, any::<bool>(), 0.0f64..20.0).prop_map(
        |(lam, r_inst, allow_corner_cutting, unknown_risk, additive, additive_weight)| RiskAStarConfig {
            lam,
            r_inst,
            r_total: 1.0,
            carrot_m: 1.0,
            unknown_risk,
            allow_corner_cutting,
            cost_model: if additive { CostModel::Additive } else { CostModel::Risk },
            additive_weight,
            lethal_risk: 1.0,
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, rng_seed: proptest::test_runner::RngSeed::Fixed(7), ..ProptestConfig::default() })]

    #[test]
    fn cost_equals_dijkstra_and_paths_are_legal(
        (nx, ny, risk) in grid_strategy(),
        config in config_strategy(),
        res in 0.05f64..2.0,
        s in any::<prop::sample::Index>(),
        t in any::<prop::sample::Index>(),
    ) {
        let (start, goal) = (s.index(nx * ny), t.index(nx * ny));
        let grid = RiskGrid::new(&risk, nx, ny, res, DVec2::new(-3.0, 7.0)).unwrap();
        let mut planner = RiskAStar::new(config).unwrap();
        let cell = |i: usize| CellIndex { ix: (i % nx) as u32, iy: (i / nx) as u32 };
        let out = planner.plan_cells(&grid, cell(start), cell(goal)).unwrap();
        let reference = dijkstra(&config, &risk, nx, ny, res, start)[goal];
        match out.status {
            PlanStatus::StartBlocked => prop_assert!(!traversable(&config, risk[start])),
            PlanStatus::GoalBlocked => prop_assert!(traversable(&config, risk[start]) && !traversable(&config, risk[goal])),
            PlanStatus::NoPath => prop_assert!(reference.is_infinite() && traversable(&config, risk[goal]), "A* found none, Dijkstra {}", reference),
            PlanStatus::Found | PlanStatus::BudgetExceeded => {
                let path = out.path.as_ref().unwrap();
                prop_assert!((path.cost - reference).abs() <= 1e-9 * reference.max(1.0), "A* {} vs Dijkstra {}", path.cost, reference);
                prop_assert_eq!(path.cells.first().copied(), Some(cell(start)));
                prop_assert_eq!(path.cells.last().copied(), Some(cell(goal)));
                // Legal moves only, and the cost, length and risk recomputed along the path agree.
                let (mut cost, mut length, mut integral) = (0.0, 0.0, 0.0);
                for c in &path.cells {
                    prop_assert!(traversable(&config, risk[c.iy as usize * nx + c.ix as usize]), "entered {:?}", c);
                }
                for w in path.cells.windows(2) {
                    let (dx, dy) = (w[1].ix as i64 - w[0].ix as i64, w[1].iy as i64 - w[0].iy as i64);
                    prop_assert!(dx.abs() <= 1 && dy.abs() <= 1 && (dx, dy) != (0, 0));
                    let diagonal = dx != 0 && dy != 0;
                    if diagonal && !config.allow_corner_cutting {
                        let side1 = w[0].iy as usize * nx + w[1].ix as usize;
                        let side2 = w[1].iy as usize * nx + w[0].ix as usize;
                        prop_assert!(traversable(&config, risk[side1]) && traversable(&config, risk[side2]), "cut a corner at {:?}", w);
                    }
                    let d = if diagonal { res * 2f64.sqrt() } else { res };
                    let rho = |c: CellIndex| config.hazard(risk[c.iy as usize * nx + c.ix as usize]).unwrap();
                    let c = |c: CellIndex| config.cell_cost(risk[c.iy as usize * nx + c.ix as usize]);
                    cost += d * (c(w[0]) + c(w[1])) / 2.0;
                    length += d;
                    integral += d * (rho(w[0]) + rho(w[1])) / 2.0;
                }
                prop_assert!((cost - path.cost).abs() <= 1e-9 * cost.max(1.0));
                prop_assert!((length - path.length_m).abs() <= 1e-9 * length.max(1.0));
                prop_assert!((integral - path.risk_integral).abs() <= 1e-9 * integral.max(1.0));
                prop_assert!((path.accumulated_risk - (1.0 - (-integral).exp())).abs() <= 1e-12);
                // r_total = 1: every path is within the budget.
                prop_assert_eq!(out.status, PlanStatus::Found);
                prop_assert_eq!(path.points_world.len(), path.cells.len());
                prop_assert!(out.carrot_world.is_some());
            }
            _ => prop_assert!(false, "unexpected status {:?}", out.status),
        }
        // Deterministic: the same planner again gives the same outcome.
        let again = planner.plan_cells(&grid, cell(start), cell(goal)).unwrap();
        prop_assert_eq!((&again.path, again.status, again.expanded), (&out.path, out.status, out.expanded));
    }

    #[test]
    fn zero_risk_paths_have_the_octile_length(
        nx in 1usize..60, ny in 1usize..60, lam in 1e-3f64..10.0, res in 0.01f64..3.0, cut in any::<bool>(),
        s in any::<prop::sample::Index>(), t in any::<prop::sample::Index>(),
    ) {
        let risk = vec![0.0f32; nx * ny];
        let grid = RiskGrid::new(&risk, nx, ny, res, DVec2::ZERO).unwrap();
        let config = RiskAStarConfig { lam, allow_corner_cutting: cut, ..RiskAStarConfig::default() };
        let (a, b) = (s.index(nx * ny), t.index(nx * ny));
        let cell = |i: usize| CellIndex { ix: (i % nx) as u32, iy: (i / nx) as u32 };
        let out = RiskAStar::new(config).unwrap().plan_cells(&grid, cell(a), cell(b)).unwrap();
        let path = out.path.unwrap();
        let (dx, dy) = (((a % nx) as f64 - (b % nx) as f64).abs(), ((a / nx) as f64 - (b / nx) as f64).abs());
        let octile = res * (dx.max(dy) + (2f64.sqrt() - 1.0) * dx.min(dy));
        prop_assert_eq!(out.status, PlanStatus::Found);
        prop_assert!((path.length_m - octile).abs() <= 1e-9 * octile.max(1.0), "{} vs {}", path.length_m, octile);
        prop_assert!((path.cost - lam * octile).abs() <= 1e-9 * (lam * octile).max(1.0));
        prop_assert_eq!(path.accumulated_risk, 0.0);
        // With an exact heuristic only cells on optimal paths are expanded: at most the cells
        // of the start-goal bounding box.
        prop_assert!(out.expanded <= (dx as usize + 1) * (dy as usize + 1), "{} expanded", out.expanded);
    }

    #[test]
    fn budget_rejection_is_exact_at_the_boundary(
        (nx, ny, risk) in grid_strategy(),
        config in config_strategy(),
        s in any::<prop::sample::Index>(),
        t in any::<prop::sample::Index>(),
    ) {
        let (start, goal) = (s.index(nx * ny), t.index(nx * ny));
        let grid = RiskGrid::new(&risk, nx, ny, 0.25, DVec2::ZERO).unwrap();
        let cell = |i: usize| CellIndex { ix: (i % nx) as u32, iy: (i / nx) as u32 };
        let probe = RiskAStar::new(config).unwrap().plan_cells(&grid, cell(start), cell(goal)).unwrap();
        let Some(path) = probe.path else { return Ok(()) };
        let r = path.accumulated_risk;
        prop_assume!(r > 0.0);
        prop_assume!(config.cost_model == CostModel::Risk); // the additive baseline has no budget
        let at = RiskAStar::new(RiskAStarConfig { r_total: r, ..config }).unwrap().plan_cells(&grid, cell(start), cell(goal)).unwrap();
        prop_assert_eq!(at.status, PlanStatus::Found);
        let below = RiskAStarConfig { r_total: f64::from_bits(r.to_bits() - 1), ..config };
        let out = RiskAStar::new(below).unwrap().plan_cells(&grid, cell(start), cell(goal)).unwrap();
        prop_assert_eq!(out.status, PlanStatus::BudgetExceeded);
        prop_assert_eq!(out.path.map(|p| p.cost), Some(path.cost));
        prop_assert_eq!(out.carrot_world, None);
    }
}
