//! Behaviour of the risk-aware A*: optimal costs, the corner rule, determinism, the
//! budget, entry prices, the search toward a target off the grid and input errors.

use super::*;

fn planner(f: impl FnOnce(&mut RiskAStarConfig)) -> RiskAStar {
    let mut c = RiskAStarConfig::default();
    f(&mut c);
    RiskAStar::new(c).unwrap()
}

fn cell(ix: u32, iy: u32) -> CellIndex {
    CellIndex { ix, iy }
}

#[test]
fn toward_a_target_off_the_grid_the_path_leaves_where_the_whole_way_is_cheapest() {
    // 20 x 10 cells of 1 m; a lethal wall across the whole grid at column 15. The target
    // lies beyond the east border at (30, 8): the way on leaves by the north or the south
    // border before the wall, where a stand-in on the segment toward the target is walled
    // off.
    let mut risk = vec![0.0f32; 200];
    for y in 0..10 {
        risk[y * 20 + 15] = 1.0;
    }
    let grid = RiskGrid::new(&risk, 20, 10, 1.0, DVec2::ZERO).unwrap();
    let mut p = planner(|c| c.r_total = 1.0);
    let (start, target) = (DVec2::new(2.5, 2.5), DVec2::new(30.5, 8.5));
    let out = p.plan_toward(&grid, start, target, None).unwrap();
    assert_eq!(out.status, PlanStatus::Found);
    let exit = out.goal_cell;
    assert!(exit.ix < 15 && (exit.iy == 0 || exit.iy == 9), "a border cell before the wall: {exit:?}");
    let path = out.path.as_ref().unwrap();
    assert_eq!(*path.cells.last().unwrap(), exit);
    let on_segment = p.plan(&grid, start, DVec2::new(19.5, 8.5)).unwrap();
    assert_eq!(on_segment.status, PlanStatus::NoPath);
    // A target on the grid is planned to as usual.
    let inside = p.plan_toward(&grid, start, DVec2::new(10.5, 5.5), None).unwrap();
    assert_eq!(inside.goal_cell, cell(10, 5));
    assert!(p.plan_toward(&grid, start, DVec2::new(f64::NAN, 0.0), None).unwrap_err().to_string().contains("`target`"));
    assert!(p.plan_toward(&grid, start, DVec2::new(1e300, 0.0), None).unwrap_err().to_string().contains("`target`"));
}

#[test]
fn the_way_out_is_the_least_over_every_border_cell() {
    // Random risks (some untraversable) on 13 x 9 cells of 0.5 m; targets round the grid.
    // The search's cost to its exit plus λ·|exit - target| equals the least, over every
    // border cell reachable, of a plain search's cost plus the same leg.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (nx, ny, res) = (13usize, 9usize, 0.5);
    for case in 0..12 {
        let risk: Vec<f32> = (0..nx * ny).map(|_| { let u = next(); if u < 0.15 { 1.0 } else { (u * 0.6) as f32 } }).collect();
        let grid = RiskGrid::new(&risk, nx, ny, res, DVec2::new(-1.0, 2.0)).unwrap();
        let mut p = planner(|c| c.r_total = 1.0);
        let lam = p.config().min_cell_cost();
        let start_cell = cell(6, 4);
        if risk[4 * nx + 6] >= 0.8 {
            continue;
        }
        let start = grid.centre_of(start_cell);
        let angle = case as f64 * 0.53;
        let target = start + 9.0 * DVec2::new(angle.cos(), angle.sin());
        let out = p.plan_toward(&grid, start, target, None).unwrap();
        let mut best = f64::INFINITY;
        for iy in 0..ny as u32 {
            for ix in 0..nx as u32 {
                if ix != 0 && iy != 0 && ix + 1 != nx as u32 && iy + 1 != ny as u32 {
                    continue;
                }
                if let Some(path) = p.plan_cells(&grid, start_cell, cell(ix, iy)).unwrap().path {
                    best = best.min(path.cost + lam * grid.centre_of(cell(ix, iy)).distance(target));
                }
            }
        }
        match out.path {
            Some(path) => {
                let got = path.cost + lam * grid.centre_of(out.goal_cell).distance(target);
                assert!((got - best).abs() < 1e-9, "case {case}: {got} vs {best}");
                let (cost, _) = p.config().polyline_cost(&grid, &path.points_world).unwrap();
                assert!((cost - path.cost).abs() < 1e-9);
            }
            None => assert!(best.is_infinite(), "case {case}: no way out found, but {best}"),
        }
    }
}

#[test]
fn one_diagonal_and_one_straight_move_by_hand() {
    // 3 x 2 grid, res 0.5, λ = 0.1: path (0,0) -> (1,1) -> (2,1) with risks 0.2, 0.5, 0.
    // Costs c = 0.1 - ln(0.8) = 0.3231435513, 0.1 - ln(0.5) = 0.7931471806, 0.1.
    // Diagonal: 0.5·√2·(0.3231435513 + 0.7931471806)/2 = 0.3946683731;
    // straight: 0.5·(0.7931471806 + 0.1)/2 = 0.2232867951; total 0.6179551683.
    let risk = [0.2, 0.9, 0.9, 0.9, 0.5, 0.0];
    let grid = RiskGrid::new(&risk, 3, 2, 0.5, DVec2::new(-1.0, 2.0)).unwrap();
    let mut p = planner(|c| {
        c.lam = 0.1;
        c.r_total = 1.0;
        c.allow_corner_cutting = true;
    });
    let out = p.plan_cells(&grid, cell(0, 0), cell(2, 1)).unwrap();
    assert_eq!(out.status, PlanStatus::Found);
    let path = out.path.unwrap();
    assert_eq!(path.cells, vec![cell(0, 0), cell(1, 1), cell(2, 1)]);
    assert!((path.cost - 0.617_955_168_3).abs() < 1e-8, "{}", path.cost);
    assert!((path.length_m - (0.5 * 2f64.sqrt() + 0.5)).abs() < 1e-12);
    // S = cost - λ·L = 0.6179551683 - 0.1·1.2071067812 = 0.4972444902; R = 1 - e^-S.
    // (Risks are f32: 0.2f32 = 0.2000000030, hence the 1e-8 tolerances.)
    assert!((path.risk_integral - 0.497_244_490_2).abs() < 1e-8);
    assert!((path.accumulated_risk - (1.0 - (-0.497_244_490_2f64).exp())).abs() < 1e-8);
    assert_eq!(path.points_world[0], DVec2::new(-0.75, 2.25));
    assert_eq!(path.points_world[2], DVec2::new(0.25, 2.75));
    // The same polyline priced outside the search: the same cost and risk integral.
    let (cost, integral) = p.config().polyline_cost(&grid, &path.points_world).unwrap();
    assert!((cost - path.cost).abs() < 1e-12 && (integral - path.risk_integral).abs() < 1e-12);
    // Through an untraversable cell (0.9 >= r_inst 0.8), off the grid, or over budget: none.
    assert_eq!(p.config().polyline_cost(&grid, &[DVec2::new(-0.75, 2.25), DVec2::new(-0.25, 2.25)]), None);
    assert_eq!(p.config().polyline_cost(&grid, &[DVec2::new(-0.75, 2.25), DVec2::new(-5.0, 2.25)]), None);
    let tight = RiskAStarConfig { r_total: 0.1, ..*p.config() };
    assert_eq!(tight.polyline_cost(&grid, &path.points_world), None);
    // With entry prices: the move into the last cell (E, from (1, 1) to (2, 1)) entered
    // unseen pays the search's extra, as the search would.
    let mut unseen = vec![0u8; 6];
    unseen[5] = 1 << 0;
    let entry = EntryPrices { unseen: &unseen, unseen_risk: 0.5, clearance: &[] };
    let (priced, _) = p.price_polyline(&grid, &path.points_world, Some(&entry)).unwrap().unwrap();
    let extra = p.config().cell_cost(0.5) - p.config().cell_cost(f32::NAN);
    assert!((priced - (path.cost + 0.5 * extra)).abs() < 1e-9, "{priced} vs {}", path.cost + 0.5 * extra);
    let searched = p.plan_cells_with(&grid, cell(0, 0), cell(2, 1), Some(&entry)).unwrap();
    if searched.path.as_ref().map(|q| &q.cells) == Some(&path.cells) {
        assert!((searched.path.unwrap().cost - priced).abs() < 1e-9);
    }
}

#[test]
fn clearance_prices_move_a_path_off_a_wall_without_adding_risk() {
    // A 30 x 8 grid of 0.1 m cells, row 0 a wall, the start and goal next to it (row 1):
    // without prices the path runs straight along row 1; with a price of 4
    // on rows 1-2 and 2 on row 3 it moves to row 4 and back (a detour of a few cells is
    // cheaper than 2.5 m at up to 5x the cost), its risk unchanged (0), its cost the
    // prices' search cost, and `price_polyline` prices it alike.
    let (nx, ny) = (30, 8);
    let risk: Vec<f32> = (0..nx * ny).map(|i| if i < nx { 1.0 } else { 0.0 }).collect();
    let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
    for model in [CostModel::Risk, CostModel::Additive] {
        let mut p = planner(|c| c.cost_model = model);
        let plain = p.plan_cells(&grid, cell(1, 1), cell(28, 1)).unwrap().path.unwrap();
        assert!(plain.cells.iter().all(|c| c.iy == 1), "{model:?}");
        let clearance: Vec<f32> = (0..nx * ny).map(|i| match i / nx { 1 | 2 => 4.0, 3 => 2.0, _ => 0.0 }).collect();
        let entry = EntryPrices { clearance: &clearance, ..EntryPrices::NONE };
        let priced = p.plan_cells_with(&grid, cell(1, 1), cell(28, 1), Some(&entry)).unwrap().path.unwrap();
        assert!(priced.cells.iter().any(|c| c.iy >= 4), "{model:?}: {:?}", priced.cells);
        assert_eq!(priced.risk_integral, 0.0);
        assert!(priced.length_m > plain.length_m);
        let (again, _) = p.price_polyline(&grid, &priced.points_world, Some(&entry)).unwrap().unwrap();
        assert!((again - priced.cost).abs() < 1e-9, "{model:?}: {again} vs {}", priced.cost);
        // A price that is not finite and >= 0, or of the wrong length, is refused by name.
        for bad in [vec![-1.0f32; nx * ny], vec![f32::NAN; nx * ny], vec![0.0f32; 3]] {
            let e = EntryPrices { clearance: &bad, ..EntryPrices::NONE };
            let err = p.plan_cells_with(&grid, cell(1, 1), cell(28, 1), Some(&e)).unwrap_err().to_string();
            assert!(err.contains("clearance"), "{err}");
        }
    }
}

#[test]
fn corner_cutting_rule() {
    // Row 1:  . .   Start S = (0, 0), goal (1, 1), lethal X at (1, 0): without corner
    // Row 0:  S X   cutting the diagonal is refused and the path goes round by (0, 1).
    let risk = [0.0, 1.0, 0.0, 0.0];
    let grid = RiskGrid::new(&risk, 2, 2, 1.0, DVec2::ZERO).unwrap();
    let out = planner(|_| {}).plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap();
    assert_eq!(out.path.unwrap().cells, vec![cell(0, 0), cell(0, 1), cell(1, 1)]);
    let out = planner(|c| c.allow_corner_cutting = true).plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap();
    assert_eq!(out.path.unwrap().cells, vec![cell(0, 0), cell(1, 1)]);
    // Both corner cells lethal: no path without corner cutting.
    let risk = [0.0, 1.0, 1.0, 0.0];
    let grid = RiskGrid::new(&risk, 2, 2, 1.0, DVec2::ZERO).unwrap();
    assert_eq!(planner(|_| {}).plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap().status, PlanStatus::NoPath);
}

#[test]
fn blocked_and_unreachable_are_told_apart() {
    let risk = [0.0, 0.9, 0.0, 0.0, 0.9, 0.0];
    let grid = RiskGrid::new(&risk, 3, 2, 1.0, DVec2::ZERO).unwrap();
    let mut p = planner(|_| {});
    assert_eq!(p.plan_cells(&grid, cell(1, 0), cell(2, 0)).unwrap().status, PlanStatus::StartBlocked);
    assert_eq!(p.plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap().status, PlanStatus::GoalBlocked);
    let out = p.plan_cells(&grid, cell(0, 0), cell(2, 1)).unwrap();
    assert_eq!((out.status, out.path, out.carrot_world, out.expanded), (PlanStatus::NoPath, None, None, 2));
    // Unknown cells take `unknown_risk`: untraversable when it reaches r_inst.
    let risk = [0.0, f32::NAN, 0.0];
    let grid = RiskGrid::new(&risk, 3, 1, 1.0, DVec2::ZERO).unwrap();
    assert_eq!(p.plan_cells(&grid, cell(0, 0), cell(2, 0)).unwrap().status, PlanStatus::Found);
    let mut q = planner(|c| c.unknown_risk = 0.8);
    assert_eq!(q.plan_cells(&grid, cell(0, 0), cell(2, 0)).unwrap().status, PlanStatus::NoPath);
}

#[test]
fn start_equals_goal() {
    let risk = [0.3; 4];
    let grid = RiskGrid::new(&risk, 2, 2, 1.0, DVec2::new(1.0, 1.0)).unwrap();
    let out = planner(|_| {}).plan(&grid, DVec2::new(1.2, 1.7), DVec2::new(1.9, 1.1)).unwrap();
    let path = out.path.as_ref().unwrap();
    assert_eq!((out.status, path.cells.len(), path.cost, path.length_m, path.accumulated_risk), (PlanStatus::Found, 1, 0.0, 0.0, 0.0));
    assert_eq!(out.carrot_world, Some(DVec2::new(1.5, 1.5)));
}

#[test]
fn carrot_by_hand() {
    let pts = [DVec2::new(0.0, 0.0), DVec2::new(0.5, 0.0), DVec2::new(1.0, 0.5)];
    // 0.5 along the first segment, then 0.5 of the 0.7071 diagonal.
    let c = carrot(&pts, 1.0);
    let t = 0.5 / 0.5f64.hypot(0.5);
    assert!((c - DVec2::new(0.5 + 0.5 * t, 0.5 * t)).length() < 1e-12);
    assert_eq!(carrot(&pts, 5.0), DVec2::new(1.0, 0.5));
    assert_eq!(carrot(&pts[..1], 1.0), DVec2::ZERO);
}

#[test]
fn budget_boundary_is_inclusive() {
    let risk = [0.1f32; 10];
    let grid = RiskGrid::new(&risk, 10, 1, 0.5, DVec2::ZERO).unwrap();
    let probe = planner(|c| c.r_total = 1.0).plan_cells(&grid, cell(0, 0), cell(9, 0)).unwrap();
    let r = probe.path.unwrap().accumulated_risk;
    // 4.5 m at -ln(0.9)/m: R = 1 - 0.9^4.5.
    assert!((r - (1.0 - (1.0 - 0.1f32 as f64).powf(4.5))).abs() < 1e-12, "{r}");
    let at = planner(|c| c.r_total = r).plan_cells(&grid, cell(0, 0), cell(9, 0)).unwrap();
    assert_eq!(at.status, PlanStatus::Found);
    let below = planner(|c| c.r_total = f64::from_bits(r.to_bits() - 1)).plan_cells(&grid, cell(0, 0), cell(9, 0)).unwrap();
    assert_eq!(below.status, PlanStatus::BudgetExceeded);
    assert_eq!(below.path.unwrap().accumulated_risk, r);
    assert_eq!(below.carrot_world, None);
}

#[test]
fn bad_config_and_input_name_the_field() {
    let err = |f: fn(&mut RiskAStarConfig)| {
        let mut c = RiskAStarConfig::default();
        f(&mut c);
        RiskAStar::new(c).unwrap_err().to_string()
    };
    assert!(err(|c| c.lam = 0.0).contains("astar.lam"));
    assert!(err(|c| c.lam = f64::NAN).contains("astar.lam"));
    assert!(err(|c| c.r_inst = 1.5).contains("astar.r_inst"));
    assert!(err(|c| c.r_total = 0.0).contains("astar.r_total"));
    assert!(err(|c| c.carrot_m = -1.0).contains("astar.carrot_m"));
    assert!(err(|c| c.unknown_risk = f64::NAN).contains("astar.unknown_risk"));
    let risk = [0.0f32; 6];
    assert!(RiskGrid::new(&risk, 3, 3, 1.0, DVec2::ZERO).unwrap_err().to_string().contains("`risk`"));
    assert!(RiskGrid::new(&risk[..0], 0, 3, 1.0, DVec2::ZERO).unwrap_err().to_string().contains("empty"));
    assert!(RiskGrid::new(&risk, 3, 2, 0.0, DVec2::ZERO).unwrap_err().to_string().contains("`resolution`"));
    assert!(RiskGrid::new(&risk, 3, 2, 1.0, DVec2::new(f64::NAN, 0.0)).unwrap_err().to_string().contains("`origin`"));
    let negative = [0.0, 0.0, 0.0, 0.0, -0.5, 0.0];
    assert!(RiskGrid::new(&negative, 3, 2, 1.0, DVec2::ZERO).unwrap_err().to_string().contains("row 1, column 1"));
    let grid = RiskGrid::new(&risk, 3, 2, 1.0, DVec2::ZERO).unwrap();
    let mut p = planner(|_| {});
    assert!(p.plan(&grid, DVec2::new(f64::NAN, 0.0), DVec2::ZERO).unwrap_err().to_string().contains("`start`"));
    assert!(p.plan(&grid, DVec2::ZERO, DVec2::new(3.0, 0.5)).unwrap_err().to_string().contains("`goal`"));
    assert!(p.plan(&grid, DVec2::new(-1e-9, 0.5), DVec2::ZERO).unwrap_err().to_string().contains("`start`"));
    assert!(p.plan_cells(&grid, cell(0, 2), cell(0, 0)).unwrap_err().to_string().contains("`start`"));
}

#[test]
fn a_terrain_map_is_planned_on_its_own_cells() {
    use crate::terrain::{GridGeometry, Layer, MapConfig, RiskMap};
    let config = MapConfig { resolution_m: 0.1, size_x_m: 2.0, size_y_m: 1.0 };
    let mut map = RiskMap::zeros(GridGeometry::centred_on(&config, 0.37, -0.21), 0.0);
    let geometry = *map.geometry();
    // A lethal column through the map but for its top row.
    for iy in 0..geometry.ny - 1 {
        map.get_mut(Layer::Risk)[geometry.flat(CellIndex { ix: 12, iy: iy as u32 })] = 1.0;
    }
    let grid = RiskGrid::from_map(&map).unwrap();
    let (start, goal) = (DVec2::new(-0.3, -0.5), DVec2::new(1.05, -0.55));
    let out = planner(|c| c.r_total = 1.0).plan(&grid, start, goal).unwrap();
    assert_eq!(out.status, PlanStatus::Found);
    assert_eq!(Some(out.start_cell), geometry.cell_of(start.x, start.y));
    assert_eq!(Some(out.goal_cell), geometry.cell_of(goal.x, goal.y));
    let path = out.path.unwrap();
    assert!(path.cells.iter().all(|&c| map.get(Layer::Risk)[geometry.flat(c)] < 0.8));
    assert!(path.cells.iter().any(|c| c.iy as usize == geometry.ny - 1), "goes over the wall's top");
    for (c, p) in path.cells.iter().zip(&path.points_world) {
        assert_eq!(*p, geometry.centre_of(*c));
    }
}

#[test]
fn stamps_reuse_the_buffers_across_grids() {
    // A big grid, then a small one, then the big one again: same answers as fresh planners.
    let big: Vec<f32> = (0..400).map(|i| ((i * 37) % 100) as f32 / 120.0).collect();
    let small = [0.0f32, 0.5, 0.2, 0.0];
    let gb = RiskGrid::new(&big, 20, 20, 0.1, DVec2::ZERO).unwrap();
    let gs = RiskGrid::new(&small, 2, 2, 0.1, DVec2::ZERO).unwrap();
    let mut p = planner(|c| c.r_total = 1.0);
    let first = p.plan_cells(&gb, cell(0, 0), cell(19, 19)).unwrap();
    let s = p.plan_cells(&gs, cell(0, 0), cell(1, 1)).unwrap();
    let again = p.plan_cells(&gb, cell(0, 0), cell(19, 19)).unwrap();
    assert_eq!((&first.path, first.expanded), (&again.path, again.expanded));
    let fresh = planner(|c| c.r_total = 1.0).plan_cells(&gs, cell(0, 0), cell(1, 1)).unwrap();
    assert_eq!(s.path, fresh.path);
    // Force the stamp to wrap.
    p.stamp = u32::MAX;
    let wrapped = p.plan_cells(&gb, cell(0, 0), cell(19, 19)).unwrap();
    assert_eq!(wrapped.path, again.path);
}
