//! Step 2 of `Navigator`'s docs: the navigator's grid from a new map, through the near, hazard
//! and driven memories, the growth into the unseen, the unseen-near rule and the void rims.

use glam::DVec2;

use super::memory::{mark_unseen_near, mark_void_rims, HazardRules, UnseenNear, WorldCell};
use super::morphology::{clustered, grow_into_unseen, Growth};
use super::Navigator;
use crate::error::Result;
use crate::terrain::RiskMap;

impl Navigator {
    /// Step 2: the navigator's grid from a new map, through the memories.
    pub(super) fn grids(&mut self, map: RiskMap, position: DVec2) -> Result<()> {
        let nav = self.config.navigator;
        // Risk (or its CVaR) where observed, NaN elsewhere so that the planner's own
        // `unknown_risk` prices the unseen.
        let risk = match nav.cvar_alpha {
            Some(alpha) => map.cvar(alpha)?,
            None => map.layer("risk")?.to_vec(),
        };
        let observed = map.layer("observed")?;
        self.grid.clear();
        self.grid.extend(risk.iter().zip(observed).map(|(&r, &o)| if o > 0.0 { r } else { f32::NAN }));
        let g = *map.geometry();
        let lethal = map.lethal_risk;
        if nav.near_memory_m > 0.0 {
            self.near.record(&self.grid, map.layer("count")?, &g, position, nav.near_memory_m, nav.coverage.min_range_m, nav.near_memory_highest);
        }
        if nav.hazard_memory {
            let rules = HazardRules {
                lethal,
                min_neighbours: nav.lethal_min_neighbours,
                forget_points: nav.hazard_memory_forget_points as f32,
                record_m: nav.hazard_memory_record_m,
                range_m: nav.hazard_memory_range_m,
            };
            self.hazards.update(&mut self.grid, map.layer("ground_count")?, map.layer("negative")?, &g, position, &rules);
        }
        let s = &mut self.scratch;
        s.grown.clone_from(&self.grid);
        if nav.unseen_growth_m > 0.0 {
            let growth = Growth { lethal, min_neighbours: nav.lethal_min_neighbours, radius_m: nav.unseen_growth_m, robot: position, min_range_m: nav.unseen_growth_min_range_m };
            grow_into_unseen(&mut s.grown, &mut s.astar, &g, &growth);
        }
        if nav.near_memory_m > 0.0 {
            let above = self.config.planner.unknown_risk as f32;
            self.near.recall(&mut self.grid, &g, position, nav.near_memory_m, above, lethal);
            self.near.recall(&mut s.grown, &g, position, nav.near_memory_m, above, lethal);
        }
        let start = *self.start.get_or_insert(position);
        if nav.unseen_near_lethal {
            let rule = UnseenNear { robot: position, start, blind_m: nav.coverage.min_range_m, lethal };
            mark_unseen_near(&mut self.grid, &mut s.grown, &g, &self.near, &self.driven, &rule);
        }
        if nav.void_rim_m > 0.0 {
            // The voids of this map (patches, as the hazard memory keeps them) the memory does
            // not already hold, and the remembered ones, which the blind ring hides once the
            // robot is beside them.
            let negative = map.layer("negative")?;
            let on_map: Vec<WorldCell> = (0..g.cells())
                .filter(|&c| negative[c] >= lethal && clustered(&self.grid, g.nx, g.ny, c, lethal, nav.lethal_min_neighbours))
                .map(|c| WorldCell::of_flat(&g, c))
                .filter(|&cell| !self.hazards.is_void(cell))
                .collect();
            let remembered = self.hazards.voids().collect::<Vec<_>>();
            mark_void_rims(&mut self.grid, &mut s.grown, &g, on_map.into_iter().chain(remembered), &self.driven, nav.void_rim_m, lethal);
        }
        self.map = Some(map);
        Ok(())
    }
}
