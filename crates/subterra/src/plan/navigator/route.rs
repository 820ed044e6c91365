//! Plan hysteresis (step 3 of `Navigator`'s docs): whether a new plan replaces the path being
//! followed, keeps it, or is the same route refreshed.

use glam::DVec2;

/// What step 3 does with a new plan while a path is being followed.
#[derive(Debug, PartialEq)]
pub(super) enum Route {
    /// No path was being followed: the plan is the path.
    New,
    /// The plan runs along the path being followed (within the robot's width): it replaces
    /// it, as a refreshed copy of the same route.
    Same,
    /// The plan takes another route, and the rest of the path being followed is still
    /// traversable, within the budget, passable for the footprint and at most
    /// `1 + plan_hysteresis` times the plan's price: the rest is kept.
    Kept(Vec<DVec2>),
    /// The plan takes another route, clearly better or the only one left: it replaces the path.
    Switched,
}

/// Step 3's choice between `rest`, the rest of the path being followed (if any), and `new`,
/// the plan just found: the same route if every vertex of `rest` lies within `width_m` of
/// `new`; else `rest` is kept if `price` prices both, `rest` at most `1 + hysteresis` times
/// `new`, and the footprint can follow it (`passable`).
pub(super) fn choose_route(
    rest: Option<Vec<DVec2>>,
    new: &[DVec2],
    width_m: f64,
    hysteresis: f64,
    price: impl Fn(&[DVec2]) -> Option<f64>,
    passable: impl Fn(&[DVec2]) -> bool,
) -> Route {
    let Some(rest) = rest else { return Route::New };
    if max_deviation(&rest, new) <= width_m {
        return Route::Same;
    }
    let cheap_enough = matches!((price(&rest), price(new)), (Some(old), Some(new)) if old <= (1.0 + hysteresis) * new);
    if hysteresis > 0.0 && cheap_enough && passable(&rest) { Route::Kept(rest) } else { Route::Switched }
}

/// The rest of `path` from the robot at `position`: the robot, then the path from its vertex
/// nearest the robot; `None` if that vertex is farther than `within_m` (the robot is not
/// following the path) or is the path's end.
pub(super) fn rest_of_path(path: &[DVec2], position: DVec2, within_m: f64) -> Option<Vec<DVec2>> {
    let (nearest, d2) = path.iter().enumerate().map(|(i, p)| (i, p.distance_squared(position))).min_by(|a, b| a.1.total_cmp(&b.1))?;
    if d2 > within_m * within_m || nearest + 1 >= path.len() {
        return None;
    }
    let mut rest = Vec::with_capacity(path.len() - nearest + 1);
    rest.push(position);
    rest.extend_from_slice(&path[nearest..]);
    Some(rest)
}

/// The largest distance from a vertex of `a` to the nearest vertex of `b` \[m\].
fn max_deviation(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter().map(|p| b.iter().map(|q| p.distance_squared(*q)).fold(f64::INFINITY, f64::min)).fold(0.0, f64::max).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::astar::{RiskAStar, RiskAStarConfig};
    use crate::plan::grid::RiskGrid;

    /// 30 x 15 cells of 0.2 m with a block across the middle (x 10-19, y 4-10): two routes
    /// round it, over (rows 11-14) and under (rows 0-3); `top_risk` on the upper band.
    fn two_routes(top_risk: f32) -> Vec<f32> {
        let mut risk = vec![0.0f32; 30 * 15];
        for y in 0..15 {
            for x in 0..30 {
                if (10..20).contains(&x) && (4..11).contains(&y) {
                    risk[y * 30 + x] = 0.95;
                } else if y >= 11 && (8..22).contains(&x) {
                    risk[y * 30 + x] = top_risk;
                }
            }
        }
        risk
    }

    fn plan(risk: &[f32]) -> (RiskAStarConfig, Vec<DVec2>) {
        let grid = RiskGrid::new(risk, 30, 15, 0.2, DVec2::ZERO).unwrap();
        let config = RiskAStarConfig { r_total: 1.0, ..RiskAStarConfig::default() };
        let out = RiskAStar::new(config).unwrap().plan(&grid, DVec2::new(0.5, 1.5), DVec2::new(5.7, 1.5)).unwrap();
        (config, out.found().expect("a path").points_world.clone())
    }

    #[test]
    fn a_route_is_kept_unless_the_new_one_is_clearly_better() {
        // The robot follows the route over the block (planned when the under route was risky).
        let mut under_risky = two_routes(0.0);
        for y in 0..4 {
            for x in 8..22 {
                under_risky[y * 30 + x] = 0.3;
            }
        }
        let (config, over) = plan(&under_risky);
        assert!(over.iter().any(|p| p.y > 2.2), "the first plan goes over the block");
        let rest = rest_of_path(&over, over[3], 0.3).unwrap();
        let judge = |risk: &[f32], hysteresis: f64| {
            let (_, new) = plan(risk);
            let grid = RiskGrid::new(risk, 30, 15, 0.2, DVec2::ZERO).unwrap();
            let price = |points: &[DVec2]| config.polyline_cost(&grid, points).map(|(c, _)| c);
            (choose_route(Some(rest.clone()), &new, 0.67, hysteresis, price, |_| true), new)
        };
        // Now the under route is clear and the over one slightly risky: the new plan goes
        // under, a little cheaper; the route over is kept.
        let (route, new) = judge(&two_routes(0.02), 0.2);
        assert!(new.iter().all(|p| p.y < 2.2), "the new plan goes under");
        assert!(matches!(route, Route::Kept(_)), "{route:?}");
        // Without hysteresis, or when the route over became clearly worse, it switches.
        assert_eq!(judge(&two_routes(0.02), 0.0).0, Route::Switched);
        assert_eq!(judge(&two_routes(0.4), 0.2).0, Route::Switched);
        // A route the footprint cannot follow any more is not kept.
        let grid = RiskGrid::new(&under_risky, 30, 15, 0.2, DVec2::ZERO).unwrap();
        let price = |points: &[DVec2]| config.polyline_cost(&grid, points).map(|(c, _)| c);
        assert_eq!(choose_route(Some(rest.clone()), &plan(&two_routes(0.02)).1, 0.67, 0.2, price, |_| false), Route::Switched);
        // The same route found again replaces the old path; no path followed: the plan.
        assert_eq!(choose_route(Some(rest.clone()), &over, 0.67, 0.2, price, |_| true), Route::Same);
        assert_eq!(choose_route(None, &over, 0.67, 0.2, price, |_| true), Route::New);
    }

    #[test]
    fn the_rest_of_a_path_starts_at_the_robot_and_needs_it_near() {
        let path = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 0.0), DVec2::new(2.0, 0.0)];
        assert_eq!(rest_of_path(&path, DVec2::new(1.1, 0.1), 0.3).unwrap(), vec![DVec2::new(1.1, 0.1), DVec2::new(1.0, 0.0), DVec2::new(2.0, 0.0)]);
        assert_eq!(rest_of_path(&path, DVec2::new(1.0, 1.0), 0.3), None, "off the path");
        assert_eq!(rest_of_path(&path, DVec2::new(2.0, 0.0), 0.3), None, "at its end");
        assert!((max_deviation(&path, &[DVec2::new(0.0, 0.5), DVec2::new(2.0, 0.5)]) - 1.0f64.hypot(0.5)).abs() < 1e-12);
    }
}
