//! Step 3 of `Navigator`'s docs: the A*'s grid (inflated, grown into the unseen), the stand-in
//! for a target off the map or on a blocked cell, the entry prices, the plan with its
//! footprint replans, and whether it replaces the path being followed.

use std::cmp::Ordering;

use glam::DVec2;

use super::memory::WorldCell;
use super::morphology::{inflate_lethal, turn_room_prices};
use super::reactive::{self, FootprintReplan};
use super::route::{choose_route, rest_of_path, Route};
use super::target::{nearest_traversable, nearest_traversable_to, on_map, reachable_from, Search};
use super::{safety_view, Navigator};
use crate::error::{Error, Result};
use crate::plan::astar::{EntryPrices, PlanOutcome, PlanStatus, RiskAStar, RiskAStarConfig};
use crate::plan::coverage::unseen_entries;
use crate::plan::grid::RiskGrid;
use crate::plan::recovery::Target;

impl Navigator {
    /// Step 3: the A*'s grid, the stand-in, the entry prices and the plan; keeps the path.
    pub(super) fn plan(&mut self, grid: &RiskGrid<'_>, lethal: f32, pose: (DVec2, f64), target_point: DVec2, key: (f64, f64, Target)) -> Result<PlanOutcome> {
        let position = pose.0;
        let nav = self.config.navigator;
        let g = *grid.map_geometry().ok_or_else(|| Error::input("grid", "must lie on a map geometry"))?;
        let fit_radius = 0.5 * self.robot.width_m + nav.inflation_margin_m;
        let unknown = self.config.planner.unknown_risk;
        let s = &mut self.scratch;
        if nav.inflate_lethal {
            // The lethal cells of the map and the memories are inflated by the inscribed
            // radius; the cells grown into the unseen, a guess, only block where they are.
            inflate_lethal(grid.risk(), &mut s.astar, &g, lethal, nav.lethal_min_neighbours, fit_radius, position);
            for (a, &grown) in s.astar.iter_mut().zip(&s.grown) {
                if grown >= lethal && (*a).partial_cmp(&grown).is_none_or(Ordering::is_lt) {
                    *a = grown;
                }
            }
        } else {
            s.astar.clone_from(&s.grown);
        }
        let astar_grid = RiskGrid::on_geometry(&s.astar, &g)?;
        let (mut goal_on_map, mut remainder) = on_map(grid, position, target_point);
        let off_map = remainder > 0.0;
        let exit_search = off_map && nav.leave_by_any_border;
        if self.planner.config().r_inst != key.0 || self.planner.config().r_total != key.1 {
            self.planner = RiskAStar::new(RiskAStarConfig { r_inst: key.0, r_total: key.1, ..self.config.planner })?;
        }
        if nav.perception_aware {
            s.known.clear();
            s.known.extend((0..g.cells()).map(|c| {
                let cell = WorldCell::of_flat(&g, c);
                !s.astar[c].is_nan() || self.near.get(cell).is_some() || self.driven.contains(cell)
            }));
            unseen_entries(&astar_grid, &s.known, position, &nav.coverage, lethal, &mut s.unseen, &mut s.run);
        } else {
            s.unseen.clear();
        }
        let turn_room = nav.inflate_lethal && nav.turn_room_price > 0.0;
        if turn_room {
            // Room to turn: the ground between the inscribed and the circumscribed radius of
            // the same lethal cells the inflation grows, priced (it stays traversable).
            let circumscribed = (0.5 * self.robot.length_m).hypot(0.5 * self.robot.width_m) + nav.inflation_margin_m;
            turn_room_prices(grid.risk(), &mut s.turn_room, &g, lethal, nav.lethal_min_neighbours, fit_radius, circumscribed, nav.turn_room_price as f32);
        } else {
            s.turn_room.clear();
        }
        let entry = (nav.perception_aware || turn_room).then(|| EntryPrices { unseen: &s.unseen, unseen_risk: self.unseen_risk, clearance: &s.turn_room });
        // Toward a target beyond the map: leave by whichever border cell makes the whole way
        // cheapest (the A*'s "toward a target off the grid"); when no way out within the
        // thresholds exists (the border walled off or over them), the stand-in still gets
        // the robot as near as the map allows.
        let toward = if exit_search { Some(self.planner.plan_toward(&astar_grid, position, target_point, entry.as_ref())?) } else { None };
        let mut outcome = match toward {
            Some(out) if out.status == PlanStatus::Found => {
                goal_on_map = astar_grid.centre_of(out.goal_cell);
                remainder = goal_on_map.distance(target_point);
                out
            }
            _ => {
                // A stand-in for a target off the map, or on a cell the robot may not enter,
                // must be a cell where it fits and that the planner can reach.
                let blocking = key.0.min(f64::from(lethal));
                reachable_from(&astar_grid, position, blocking, unknown, self.config.planner.allow_corner_cutting, &mut s.reachable, &mut s.flood);
                let search = Search { r_inst: blocking, unknown, fit_radius_m: fit_radius, reachable: &s.reachable };
                let standin = nearest_traversable(grid, goal_on_map, nav.standin_search_m, &search)
                    .or_else(|| off_map.then(|| nearest_traversable_to(grid, target_point, &search)).flatten());
                if let Some(p) = standin {
                    goal_on_map = p;
                    remainder = p.distance(target_point);
                }
                self.planner.plan_with(&astar_grid, position, goal_on_map, entry.as_ref())?
            }
        };
        if nav.footprint_replans > 0 && outcome.found().is_some() {
            // The path checked with the tracker's own footprint test (the rectangle along the
            // path's tangent, lethal cells and the unknown next to them): where it fails, a
            // disc around that point of the path is closed and the A* plans again.
            let view = safety_view(&nav, self.robot, (&self.hazards, &self.near, &self.driven), *grid, lethal, lethal, false);
            let replan = FootprintReplan {
                view: &view,
                from: pose,
                goal: goal_on_map,
                replans: nav.footprint_replans,
                half_window_m: self.config.tracker.tracking.tangent_half_window_m,
            };
            outcome = reactive::footprint_checked(&mut self.planner, &s.astar, &g, lethal, entry.as_ref(), &replan, outcome)?;
        }
        let followed = self.last_plan_ok && self.planned_for == Some(key) && self.path.len() >= 2;
        if let Some(path) = outcome.found() {
            let view = safety_view(&nav, self.robot, (&self.hazards, &self.near, &self.driven), *grid, lethal, lethal, false);
            let check = FootprintReplan { view: &view, from: pose, goal: goal_on_map, replans: 0, half_window_m: self.config.tracker.tracking.tangent_half_window_m };
            let rest = if followed { rest_of_path(&self.path, position, 0.5 * self.robot.width_m) } else { None };
            let planner = &self.planner;
            // Both priced alike, as the A* prices a path (its perception-aware entry prices
            // included: a path kept through ground the sensor will not have seen costs what
            // the search would charge for it), then λ per metre of straight line on to the
            // target (the heuristic's price of the unmapped remainder).
            let price = |points: &[DVec2]| {
                let end = *points.last()?;
                let (cost, _) = planner.price_polyline(&astar_grid, points, entry.as_ref()).ok()??;
                Some(cost + planner.config().min_cell_cost() * end.distance(target_point))
            };
            // Only over ground the map has rated: a path kept through unknown ground would
            // take the robot where the planner no longer goes (a pit whose floor its rim
            // hides), on the strength of an old guess.
            let passable = |rest: &[DVec2]| {
                let check = FootprintReplan { goal: *rest.last().unwrap_or(&goal_on_map), ..check };
                rest.iter().skip(1).all(|p| astar_grid.value_at(*p).is_some_and(|v| !v.is_nan()))
                    && reactive::first_blocked_along(&check, rest, g.resolution_m).is_none()
            };
            let decision = choose_route(rest, &path.points_world, self.robot.width_m, nav.plan_hysteresis, price, passable);
            match decision {
                Route::Kept(rest) => {
                    self.remainder_m = rest.last().map_or(0.0, |e| e.distance(target_point));
                    self.path = rest;
                }
                _ => {
                    self.path.clone_from(&path.points_world);
                    self.remainder_m = remainder;
                }
            }
        } else {
            self.path.clear();
        }
        Ok(outcome)
    }
}
