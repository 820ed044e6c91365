//! What the navigator remembers in the world frame, beyond the mapper's fusion window: the
//! **hazard memory** (lethal patches, kept until ground is seen there), the **near memory**
//! (the last rating of every cell observed near the robot) and the **driven memory** (the
//! cells the robot's own footprint has stood on). All three are keyed by [`WorldCell`], the
//! global cell index at the map's resolution, so they survive the robot-centred map moving.
//!
//! Distances are measured from a cell's centre to the robot in cell units, as
//! `|(x, y) - (p/res - 0.5)|`: the same arithmetic for every memory.

use std::collections::{HashMap, HashSet};
use std::cmp::Ordering;

use glam::DVec2;

use super::morphology::clustered;
use crate::terrain::GridGeometry;

/// A cell of the world's grid at the map's resolution `res`: it covers
/// `[x·res, (x+1)·res) x [y·res, (y+1)·res)` (the terrain map's global cells).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct WorldCell {
    /// Global column (along world x).
    pub x: i64,
    /// Global row (along world y).
    pub y: i64,
}

impl WorldCell {
    /// The world cell of flat index `flat` of a map of geometry `g`.
    pub(crate) fn of_flat(g: &GridGeometry, flat: usize) -> Self {
        Self { x: g.origin_cell.0 + (flat % g.nx) as i64, y: g.origin_cell.1 + (flat / g.nx) as i64 }
    }

    /// The world cell holding the world position `p` at resolution `res`.
    pub(crate) fn containing(p: DVec2, res: f64) -> Self {
        Self { x: (p.x / res).floor() as i64, y: (p.y / res).floor() as i64 }
    }

    /// Its flat index on a map of geometry `g`, if the map holds it.
    pub(crate) fn flat_on(self, g: &GridGeometry) -> Option<usize> {
        let (ix, iy) = (self.x - g.origin_cell.0, self.y - g.origin_cell.1);
        (ix >= 0 && iy >= 0 && ix < g.nx as i64 && iy < g.ny as i64).then(|| iy as usize * g.nx + ix as usize)
    }

    /// Squared distance of its centre from `here` (a position in cell units less 0.5) [cells²].
    fn distance2(self, here: DVec2) -> f64 {
        DVec2::new(self.x as f64, self.y as f64).distance_squared(here)
    }
}

/// A position in the cell units the memories measure in: `p/res - 0.5`.
fn in_cells(p: DVec2, res: f64) -> DVec2 {
    p / res - 0.5
}

/// The cells of geometry `g` whose centres lie within `radius_m` of `position`: `f(world
/// cell, flat index)` for each.
pub(crate) fn for_cells_within(g: &GridGeometry, position: DVec2, radius_m: f64, mut f: impl FnMut(WorldCell, usize)) {
    let (ox, oy) = g.origin_cell;
    let radius = radius_m / g.resolution_m;
    let here = in_cells(position, g.resolution_m);
    let (lo_x, hi_x) = ((here.x - radius).floor() as i64, (here.x + radius).ceil() as i64);
    let (lo_y, hi_y) = ((here.y - radius).floor() as i64, (here.y + radius).ceil() as i64);
    for wy in lo_y.max(oy)..=hi_y.min(oy + g.ny as i64 - 1) {
        for wx in lo_x.max(ox)..=hi_x.min(ox + g.nx as i64 - 1) {
            let cell = WorldCell { x: wx, y: wy };
            if cell.distance2(here) <= radius * radius {
                f(cell, (wy - oy) as usize * g.nx + (wx - ox) as usize);
            }
        }
    }
}

/// Settings of the hazard memory (from the navigator's settings).
#[derive(Debug, Clone, Copy)]
pub(crate) struct HazardRules {
    /// The lethal level (the map's `risk.lethal_risk`).
    pub lethal: f32,
    /// Lethal neighbours a lethal cell needs to be remembered (a patch, not a speckle).
    pub min_neighbours: u32,
    /// A cell is forgotten once the map holds this many ground points in it and rates it
    /// below lethal.
    pub forget_points: f32,
    /// Only cells this near the robot are remembered \[m\].
    pub record_m: f64,
    /// Remembered cells farther than this are forgotten \[m\].
    pub range_m: f64,
}

/// A remembered hazard: its newest lethal rating and whether the map ever rated it a void
/// (missing ground, its `negative` layer at the lethal level).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Hazard {
    risk: f32,
    void: bool,
}

/// Lethal patches, by world cell, with their newest rating.
#[derive(Debug, Clone, Default)]
pub(crate) struct HazardMemory {
    cells: HashMap<WorldCell, Hazard>,
}

impl HazardMemory {
    /// Cells remembered.
    pub(super) fn len(&self) -> usize {
        self.cells.len()
    }

    /// The remembered rating of `cell`.
    pub(super) fn get(&self, cell: WorldCell) -> Option<f32> {
        self.cells.get(&cell).map(|h| h.risk)
    }

    /// Whether `cell` is remembered as a void.
    pub(super) fn is_void(&self, cell: WorldCell) -> bool {
        self.cells.get(&cell).is_some_and(|h| h.void)
    }

    /// The remembered cells the map rated a void at least once.
    pub(super) fn voids(&self) -> impl Iterator<Item = WorldCell> + '_ {
        self.cells.iter().filter(|(_, h)| h.void).map(|(&cell, _)| cell)
    }

    /// One map's pass over the planner's grid `risk` (NaN: unobserved) of geometry `g`, with
    /// `ground_points` its ground-point counts and `negative` its `negative` layer: forgets
    /// remembered cells beyond `range_m` of `position` and those the map now holds
    /// `forget_points` ground points in and rates below lethal; remembers every clustered
    /// lethal cell within `record_m` (its newest rating, and whether `negative` is lethal
    /// there: a void); then raises each remembered cell on the grid to its rating (unobserved
    /// ones set to it).
    pub(super) fn update(&mut self, risk: &mut [f32], ground_points: &[f32], negative: &[f32], g: &GridGeometry, position: DVec2, rules: &HazardRules) {
        let here = in_cells(position, g.resolution_m);
        let range = rules.range_m / g.resolution_m;
        self.cells.retain(|&cell, _| {
            cell.distance2(here) <= range * range
                && cell.flat_on(g).is_none_or(|c| !(ground_points[c] >= rules.forget_points && risk[c] < rules.lethal))
        });
        let record = rules.record_m / g.resolution_m;
        for (c, &r) in risk.iter().enumerate() {
            let cell = WorldCell::of_flat(g, c);
            // NaN (unobserved) compares false.
            if r >= rules.lethal && cell.distance2(here) <= record * record && clustered(risk, g.nx, g.ny, c, rules.lethal, rules.min_neighbours) {
                let void = negative[c] >= rules.lethal;
                let hazard = self.cells.entry(cell).or_insert(Hazard { risk: r, void });
                *hazard = Hazard { risk: r, void: hazard.void || void };
            }
        }
        for (&cell, hazard) in &self.cells {
            if let Some(c) = cell.flat_on(g) {
                risk[c] = if risk[c].is_nan() { hazard.risk } else { risk[c].max(hazard.risk) };
            }
        }
    }

    /// Forgets the cells whose centres are farther than `keep_m` from `position`.
    pub(super) fn forget_beyond(&mut self, position: DVec2, resolution_m: f64, keep_m: f64) {
        forget_beyond(&mut self.cells, position, resolution_m, keep_m);
    }
}

/// The last (or highest) rating of every cell observed near the robot, by world cell, and
/// whether it was ever shown to be ground while near (a return from it, or a rating from
/// outside the sensor's blind ring).
#[derive(Debug, Clone, Default)]
pub(crate) struct NearMemory {
    cells: HashMap<WorldCell, (f32, bool)>,
}

impl NearMemory {
    /// The remembered rating of `cell`.
    pub(super) fn get(&self, cell: WorldCell) -> Option<f32> {
        self.cells.get(&cell).map(|&(r, _)| r)
    }

    /// Forgets remembered cells farther than `radius_m` from `position`, and remembers for
    /// each cell within it that the map observed (`risk` not NaN; the map's own ratings,
    /// before the hazard memory) its newest rating, or with `highest` the highest it got
    /// while near, and whether it was ever *shown*: it held a point (`count` > 0), or it lay
    /// at least `blind_m` from `position`. Inside the sensor's blind ring a rating without a
    /// point of its own is a ground line drawn on into ground the sensor cannot see.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record(&mut self, risk: &[f32], count: &[f32], g: &GridGeometry, position: DVec2, radius_m: f64, blind_m: f64, highest: bool) {
        let radius = radius_m / g.resolution_m;
        let blind2 = (blind_m / g.resolution_m).powi(2);
        let here = in_cells(position, g.resolution_m);
        self.cells.retain(|&cell, _| cell.distance2(here) <= radius * radius);
        for_cells_within(g, position, radius_m, |cell, c| {
            if !risk[c].is_nan() {
                let (r, shown) = self.cells.entry(cell).or_insert((risk[c], false));
                *r = if highest { r.max(risk[c]) } else { risk[c] };
                *shown |= count[c] > 0.0 || cell.distance2(here) >= blind2;
            }
        });
    }

    /// Whether `cell` is held below `lethal` and was shown to be ground ([`Self::record`]).
    pub(super) fn shown_below_lethal(&self, cell: WorldCell, lethal: f32) -> bool {
        self.cells.get(&cell).is_some_and(|&(r, shown)| shown && r < lethal)
    }

    /// The remembered rating of `cell` if it is below `lethal`: lethal cells are remembered by
    /// the hazard memory, which keeps only patches (a lone cell rated lethal once, a noise
    /// speckle, would otherwise stay an obstacle beside the robot for as long as it is in the
    /// blind ring).
    pub(super) fn below_lethal(&self, cell: WorldCell, lethal: f32) -> Option<f32> {
        self.get(cell).filter(|&r| r < lethal)
    }

    /// Each cell of `risk` still unobserved (NaN) within `radius_m` of `position` whose
    /// remembered rating is above `above` (the planner's price of the unseen) and below
    /// `lethal` takes it ([`NearMemory::below_lethal`]).
    pub(super) fn recall(&self, risk: &mut [f32], g: &GridGeometry, position: DVec2, radius_m: f64, above: f32, lethal: f32) {
        for_cells_within(g, position, radius_m, |cell, c| {
            if risk[c].is_nan() {
                if let Some(r) = self.below_lethal(cell, lethal).filter(|&r| r > above) {
                    risk[c] = r;
                }
            }
        });
    }

    /// Forgets the cells whose centres are farther than `keep_m` from `position`.
    pub(super) fn forget_beyond(&mut self, position: DVec2, resolution_m: f64, keep_m: f64) {
        forget_beyond(&mut self.cells, position, resolution_m, keep_m);
    }
}

/// The cells the robot's footprint has stood on: ground that carried the robot, known
/// traversable whatever the sensor could see of it since.
#[derive(Debug, Clone, Default)]
pub(crate) struct DrivenMemory {
    cells: HashSet<WorldCell>,
}

impl DrivenMemory {
    /// Whether the robot has stood on `cell`.
    pub(super) fn contains(&self, cell: WorldCell) -> bool {
        self.cells.contains(&cell)
    }

    /// Cells remembered.
    pub(super) fn len(&self) -> usize {
        self.cells.len()
    }

    /// Adds the cells under the `length_m x width_m` footprint centred on `position` with its
    /// length along `heading_rad` (those whose centres lie inside it shrunk by half a cell on
    /// every side: cells wholly under it, not a rim cell half over a drop), and forgets those
    /// farther than `range_m` from `position`.
    pub(super) fn stamp(&mut self, position: DVec2, heading_rad: f64, length_m: f64, width_m: f64, resolution_m: f64, range_m: f64) {
        let here = in_cells(position, resolution_m);
        let range = range_m / resolution_m;
        self.cells.retain(|&cell| cell.distance2(here) <= range * range);
        let (length, width) = ((length_m - resolution_m).max(0.0), (width_m - resolution_m).max(0.0));
        for_footprint_cells(position, heading_rad, length, width, resolution_m, |cell| {
            self.cells.insert(cell);
        });
    }
}

/// The unseen-near rule's situation ([`mark_unseen_near`]).
pub(crate) struct UnseenNear {
    /// Where the robot is [m, world].
    pub robot: DVec2,
    /// Where it stood at its first map [m, world]: its blind ring there was never in view.
    pub start: DVec2,
    /// The sensor's blind ring: the nearest ground it sees \[m\].
    pub blind_m: f64,
    /// The lethal level written \[1\].
    pub lethal: f32,
}

/// The unseen-near rule (`NavigatorSettings::unseen_near_lethal`): marks lethal, in `grid` and
/// `grown` (both of geometry `g`), each cell within `rule.blind_m` of the robot that is unseen
/// (NaN in `grid`, never held by the near memory below the lethal level as shown ground, never
/// stood on), farther than `rule.blind_m` from the start, and whose 8 neighbours are unseen
/// too or off the map. Returns how many.
///
/// Inside the blind ring a ground line drawn across a cell rates it without a return from it:
/// around a corner, the line from a bump to the ground beyond spanned a hole whose angular
/// gap was too small for the void test (cave seed 126: four lidar rings missing, 2.2°), so
/// such a rating does not show ground ([`NearMemory::record`]).
///
/// The neighbourhood keeps a lone cell between two lidar rings from turning into an obstacle:
/// a patch three cells across that the sensor never returned from is a hole, not a gap.
pub(crate) fn mark_unseen_near(grid: &mut [f32], grown: &mut [f32], g: &GridGeometry, near: &NearMemory, driven: &DrivenMemory, rule: &UnseenNear) -> usize {
    let res = g.resolution_m;
    let start = in_cells(rule.start, res);
    let start_r2 = (rule.blind_m / res).powi(2);
    let unseen = |cell: WorldCell, grid: &[f32]| match cell.flat_on(g) {
        Some(c) => grid[c].is_nan() && !near.shown_below_lethal(cell, rule.lethal) && !driven.contains(cell),
        None => true,
    };
    let mut marked = Vec::new();
    for_cells_within(g, rule.robot, rule.blind_m, |cell, c| {
        if cell.distance2(start) > start_r2 && unseen(cell, grid) && (-1..=1).all(|dy| (-1..=1).all(|dx| unseen(WorldCell { x: cell.x + dx, y: cell.y + dy }, grid))) {
            marked.push(c);
        }
    });
    for &c in &marked {
        grid[c] = rule.lethal;
        grown[c] = rule.lethal;
    }
    marked.len()
}

/// The void-rim rule (`NavigatorSettings::void_rim_m`): marks lethal, in `grid` and `grown`
/// (both of geometry `g`), every cell whose centre lies within `rim_m` of the centre of a
/// void cell (`voids`: cells the map rated as missing ground) and that the robot never stood
/// on. Returns how many cells it raised.
///
/// The map finds a void where a ray's ground returns stop short of where the ground should
/// go on; the last returns come from the rim, so the cells they fall in are rated ground
/// although their far part overhangs the drop. Where ground ends is therefore known only to
/// the ground segmentation's radial bin; the rim takes that uncertainty as part of the void.
pub(crate) fn mark_void_rims(grid: &mut [f32], grown: &mut [f32], g: &GridGeometry, voids: impl IntoIterator<Item = WorldCell>, driven: &DrivenMemory, rim_m: f64, lethal: f32) -> usize {
    let res = g.resolution_m;
    let mut raised = 0;
    for void in voids {
        let centre = (DVec2::new(void.x as f64, void.y as f64) + 0.5) * res;
        for_cells_within(g, centre, rim_m, |cell, c| {
            if (grid[c] >= lethal && grown[c] >= lethal) || driven.contains(cell) {
                return;
            }
            if grid[c].partial_cmp(&lethal).is_none_or(Ordering::is_lt) {
                grid[c] = lethal;
                raised += 1;
            }
            grown[c] = grown[c].max(lethal);
        });
    }
    raised
}

/// `f(cell)` for every world cell at `resolution_m` whose centre lies inside the
/// `length_m x width_m` rectangle centred on `position`, its length along `heading_rad`.
pub(crate) fn for_footprint_cells(position: DVec2, heading_rad: f64, length_m: f64, width_m: f64, resolution_m: f64, mut f: impl FnMut(WorldCell)) {
    let axis = DVec2::from_angle(heading_rad);
    let (hl, hw) = (0.5 * length_m, 0.5 * width_m);
    let reach = hl.hypot(hw);
    let lo = WorldCell::containing(position - reach, resolution_m);
    let hi = WorldCell::containing(position + reach, resolution_m);
    for y in lo.y..=hi.y {
        for x in lo.x..=hi.x {
            let centre = (DVec2::new(x as f64, y as f64) + 0.5) * resolution_m - position;
            let (along, across) = (centre.dot(axis), centre.perp_dot(axis));
            if along.abs() <= hl && across.abs() <= hw {
                f(WorldCell { x, y });
            }
        }
    }
}

fn forget_beyond<V>(cells: &mut HashMap<WorldCell, V>, position: DVec2, resolution_m: f64, keep_m: f64) {
    let here = in_cells(position, resolution_m);
    let keep = keep_m / resolution_m;
    cells.retain(|&cell, _| cell.distance2(here) <= keep * keep);
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: usize = 10;

    fn geometry(origin_cell: (i64, i64)) -> GridGeometry {
        GridGeometry { resolution_m: 0.1, nx: N, ny: N, origin_cell }
    }

    fn rules(min_neighbours: u32) -> HazardRules {
        HazardRules { lethal: 0.9, min_neighbours, forget_points: 5.0, record_m: 6.0, range_m: 15.0 }
    }

    /// One memory step on a 10x10 grid at `origin_cell`: `cells` lists (ix, iy, risk,
    /// ground points), every other cell unobserved. Returns the grid after the step.
    fn step_with(memory: &mut HazardMemory, origin_cell: (i64, i64), cells: &[(usize, usize, f32, f32)], position: DVec2, min_neighbours: u32) -> Vec<f32> {
        let mut risk = vec![f32::NAN; N * N];
        let mut ground = vec![0.0; N * N];
        for &(ix, iy, r, n) in cells {
            risk[iy * N + ix] = r;
            ground[iy * N + ix] = n;
        }
        let negative = vec![0.0; N * N];
        memory.update(&mut risk, &ground, &negative, &geometry(origin_cell), position, &rules(min_neighbours));
        risk
    }

    fn step(memory: &mut HazardMemory, origin_cell: (i64, i64), cells: &[(usize, usize, f32, f32)], position: DVec2) -> Vec<f32> {
        step_with(memory, origin_cell, cells, position, 0)
    }

    #[test]
    fn world_cells_map_to_and_from_flat_indices() {
        let g = geometry((-3, 7));
        for flat in [0, 9, 10, 55, 99] {
            let cell = WorldCell::of_flat(&g, flat);
            assert_eq!(cell.flat_on(&g), Some(flat));
        }
        assert_eq!(WorldCell { x: -4, y: 7 }.flat_on(&g), None);
        assert_eq!(WorldCell::containing(DVec2::new(-0.05, 0.71), 0.1), WorldCell { x: -1, y: 7 });
    }

    #[test]
    fn near_memory_keeps_what_was_seen_near_the_robot_in_the_world_frame() {
        let mut memory = NearMemory::default();
        let near = |memory: &mut NearMemory, origin_cell: (i64, i64), cells: &[(usize, usize, f32)], position: DVec2| {
            let mut risk = vec![f32::NAN; N * N];
            for &(ix, iy, r) in cells {
                risk[iy * N + ix] = r;
            }
            memory.record(&risk, &risk, &geometry(origin_cell), position, 0.3, 0.0, true);
            memory.recall(&mut risk, &geometry(origin_cell), position, 0.3, 0.05, 0.9);
            risk
        };
        // Grid at origin cell (0, 0): cell (5, 5) is at (0.55, 0.55) m. The robot at its centre.
        let robot = DVec2::new(0.55, 0.55);
        let risk = near(&mut memory, (0, 0), &[(5, 5, 0.6), (6, 5, 0.2), (9, 9, 0.7)], robot);
        assert_eq!((risk[5 * N + 5], risk[5 * N + 6]), (0.6, 0.2));
        // (9, 9) is 0.57 m away, beyond 0.3 m: not remembered.
        assert_eq!(memory.cells.len(), 2);
        // Next map, shifted by one cell (origin (1, 0)): nothing observed; the same world
        // cells get their ratings back at their new indices, the rest stay unobserved.
        let risk = near(&mut memory, (1, 0), &[], robot);
        assert_eq!((risk[5 * N + 4], risk[5 * N + 5]), (0.6, 0.2));
        assert_eq!(risk.iter().filter(|v| !v.is_nan()).count(), 2);
        // A lethal rating does not come back (the hazard memory keeps lethal patches).
        let risk = near(&mut memory, (0, 0), &[(4, 5, 1.0)], robot);
        assert_eq!(risk[5 * N + 4], 1.0, "observed now: as the map says");
        let risk = near(&mut memory, (0, 0), &[], robot);
        assert!(risk[5 * N + 4].is_nan(), "{}", risk[5 * N + 4]);
        // A lower rating seen later: the highest stays (with `highest`).
        near(&mut memory, (0, 0), &[(5, 5, 0.3)], robot);
        assert_eq!(memory.get(WorldCell { x: 5, y: 5 }), Some(0.6));
        // The robot moves away: forgotten.
        memory.cells.remove(&WorldCell { x: 4, y: 5 });
        near(&mut memory, (0, 0), &[], DVec2::new(5.0, 5.0));
        assert_eq!(memory.cells.len(), 0);
    }

    #[test]
    fn a_hazard_stays_on_the_grid_until_ground_is_seen_there() {
        let mut memory = HazardMemory::default();
        let p = DVec2::new(0.5, 0.5);
        // Seen lethal (a hole's void), with a safe neighbour.
        let r = step(&mut memory, (0, 0), &[(4, 4, 1.0, 0.0), (5, 4, 0.1, 20.0)], p);
        assert_eq!((r[44], r[45]), (1.0, 0.1));
        // Out of view (the blind ring): still lethal; the unobserved rest stays NaN.
        let r = step(&mut memory, (0, 0), &[], p);
        assert_eq!(r[44], 1.0);
        assert!(r.iter().enumerate().all(|(c, v)| c == 44 || v.is_nan()));
        // Rated safe on too few ground points: the memory wins.
        let r = step(&mut memory, (0, 0), &[(4, 4, 0.2, 4.0)], p);
        assert_eq!(r[44], 1.0);
        // Rated safe on enough ground points: forgotten, now and later.
        let r = step(&mut memory, (0, 0), &[(4, 4, 0.2, 5.0)], p);
        assert_eq!(r[44], 0.2);
        assert!(step(&mut memory, (0, 0), &[], p)[44].is_nan());
        assert_eq!(memory.len(), 0);
    }

    #[test]
    fn only_clustered_lethal_cells_and_near_ones_are_remembered() {
        let mut memory = HazardMemory::default();
        // A lone lethal cell (noise) and an L of three (each with two lethal neighbours).
        step_with(&mut memory, (0, 0), &[(1, 1, 1.0, 0.0), (5, 5, 1.0, 0.0), (6, 5, 1.0, 0.0), (5, 6, 1.0, 0.0)], DVec2::ZERO, 2);
        let mut kept: Vec<_> = memory.cells.keys().copied().collect();
        kept.sort_unstable();
        assert_eq!(kept, vec![WorldCell { x: 5, y: 5 }, WorldCell { x: 5, y: 6 }, WorldCell { x: 6, y: 5 }]);
        // Beyond the record range (6 m = 60 cells), nothing new is remembered.
        let mut memory = HazardMemory::default();
        step_with(&mut memory, (0, 0), &[(5, 5, 1.0, 0.0)], DVec2::new(-6.0, 0.0), 0);
        assert_eq!(memory.len(), 0);
    }

    #[test]
    fn a_hazard_is_kept_in_the_world_frame_as_the_map_moves() {
        let mut memory = HazardMemory::default();
        // World cell (7, 2): on the first map at (7, 2), on a map whose origin moved by
        // (3, -1) cells at (4, 3); a cell below the lethal level is not remembered.
        step(&mut memory, (0, 0), &[(7, 2, 0.95, 30.0), (1, 1, 0.89, 0.0)], DVec2::ZERO);
        let r = step(&mut memory, (3, -1), &[], DVec2::ZERO);
        assert_eq!(r[3 * N + 4], 0.95);
        assert_eq!(r.iter().filter(|v| !v.is_nan()).count(), 1);
        // Off this map it is kept; beyond the range it is forgotten.
        step(&mut memory, (100, 100), &[], DVec2::ZERO);
        assert_eq!(memory.len(), 1);
        step(&mut memory, (200, 0), &[], DVec2::new(20.0, 0.0));
        assert_eq!(memory.len(), 0);
    }

    #[test]
    fn clear_map_keeps_the_hazards_the_lidar_cannot_see_again() {
        let mut memory = HazardMemory::default();
        memory.cells.insert(WorldCell { x: 10, y: 0 }, Hazard { risk: 1.0, void: false });
        memory.cells.insert(WorldCell { x: 40, y: 0 }, Hazard { risk: 1.0, void: false });
        memory.forget_beyond(DVec2::ZERO, 0.1, 3.0);
        assert_eq!(memory.cells.keys().copied().collect::<Vec<_>>(), vec![WorldCell { x: 10, y: 0 }]);
    }

    #[test]
    fn the_driven_memory_holds_the_footprints_cells_and_forgets_far_ones() {
        let mut driven = DrivenMemory::default();
        // A 1.0 x 0.6 m footprint on the centre of cell (0, 0), facing +x: cell centres
        // within 0.45 m along x and 0.25 m along y (half a cell inside its edges): 9 x 5.
        driven.stamp(DVec2::new(0.05, 0.05), 0.0, 1.0, 0.6, 0.1, 20.0);
        assert_eq!(driven.len(), 9 * 5);
        assert!(driven.contains(WorldCell { x: 4, y: 2 }) && driven.contains(WorldCell { x: -4, y: -2 }));
        assert!(!driven.contains(WorldCell { x: 5, y: 0 }) && !driven.contains(WorldCell { x: 0, y: 3 }));
        // Turned by 90°: the long side along y.
        let mut turned = DrivenMemory::default();
        turned.stamp(DVec2::new(0.05, 0.05), std::f64::consts::FRAC_PI_2, 1.0, 0.6, 0.1, 20.0);
        assert!(turned.contains(WorldCell { x: 0, y: 4 }) && !turned.contains(WorldCell { x: 4, y: 0 }));
        // 30 m on: the first stamp is forgotten.
        driven.stamp(DVec2::new(30.0, 0.0), 0.0, 1.0, 0.6, 0.1, 20.0);
        assert!(!driven.contains(WorldCell { x: 0, y: 0 }) && driven.contains(WorldCell { x: 300, y: 0 }));
    }

    /// The unseen-near rule on a 20 x 20 grid of 0.1 m cells, robot at its centre (1, 1),
    /// blind within 0.5 m: `seen` lists the observed cells (rated 0.1), the rest unseen.
    fn unseen_near(seen: impl Fn(usize, usize) -> bool, near: &NearMemory, driven: &DrivenMemory, start: DVec2) -> (Vec<f32>, usize) {
        let g = GridGeometry { resolution_m: 0.1, nx: 20, ny: 20, origin_cell: (0, 0) };
        let mut grid: Vec<f32> = (0..400).map(|c| if seen(c % 20, c / 20) { 0.1 } else { f32::NAN }).collect();
        let mut grown = grid.clone();
        let rule = UnseenNear { robot: DVec2::new(1.0, 1.0), start, blind_m: 0.5, lethal: 0.9 };
        let n = mark_unseen_near(&mut grid, &mut grown, &g, near, driven, &rule);
        assert_eq!(grid.iter().map(|r| r.to_bits()).collect::<Vec<_>>(), grown.iter().map(|r| r.to_bits()).collect::<Vec<_>>(), "both grids get the same marks");
        (grid, n)
    }

    #[test]
    fn ground_never_seen_on_its_way_into_the_blind_ring_is_lethal() {
        let (empty_near, empty_driven) = (NearMemory::default(), DrivenMemory::default());
        let far = DVec2::new(-50.0, -50.0);
        // Nothing ever seen: every cell within the blind ring is a hole's mouth (centres
        // within 0.5 m of (1, 1): the disc of radius 5 cells about (9.5, 9.5)).
        let (grid, n) = unseen_near(|_, _| false, &empty_near, &empty_driven, far);
        let inside = (0..400).filter(|&c| ((c % 20) as f64 - 9.5).hypot((c / 20) as f64 - 9.5) <= 5.0).count();
        assert_eq!(n, inside);
        assert!(grid[10 * 20 + 10] == 0.9 && grid[10 * 20 + 16].is_nan(), "inside marked, outside the ring left unknown");
        // A hole 3 x 3 cells beside the robot, the rest seen: its centre cell only (the rim
        // cells have seen neighbours).
        let hole = |x: usize, y: usize| (12..=14).contains(&x) && (9..=11).contains(&y);
        let (grid, n) = unseen_near(|x, y| !hole(x, y), &empty_near, &empty_driven, far);
        assert_eq!(n, 1);
        assert_eq!(grid[10 * 20 + 13], 0.9);
        // A lone unseen cell between lidar rings stays unknown.
        let (_, n) = unseen_near(|x, y| (x, y) != (10, 10), &empty_near, &empty_driven, far);
        assert_eq!(n, 0);
        // Held by the near memory (seen on its way in): not marked.
        let mut near = NearMemory::default();
        let g = GridGeometry { resolution_m: 0.1, nx: 20, ny: 20, origin_cell: (0, 0) };
        let mut seen_once = vec![f32::NAN; 400];
        for y in 9..=11 {
            for x in 12..=14 {
                seen_once[y * 20 + x] = 0.1;
            }
        }
        let (points, none) = (vec![1.0f32; 400], vec![0.0f32; 400]);
        let robot = DVec2::new(1.0, 1.0);
        near.record(&seen_once, &points, &g, robot, 3.0, 0.5, false);
        let (_, n) = unseen_near(|x, y| !hole(x, y), &near, &empty_driven, far);
        assert_eq!(n, 0);
        // Rated only by a ground line drawn across it, inside the blind ring (no point of its
        // own): still a hole.
        let mut near_line = NearMemory::default();
        near_line.record(&seen_once, &none, &g, robot, 3.0, 0.5, false);
        let (_, n) = unseen_near(|x, y| !hole(x, y), &near_line, &empty_driven, far);
        assert_eq!(n, 1);
        // ... but a line's rating from outside the blind ring (the robot 1 m off) shows it.
        let mut near_far = NearMemory::default();
        near_far.record(&seen_once, &none, &g, DVec2::new(0.3, 1.0), 3.0, 0.5, false);
        let (_, n) = unseen_near(|x, y| !hole(x, y), &near_far, &empty_driven, far);
        assert_eq!(n, 0);
        // A point once is enough, even if later rated by the line alone.
        near_line.record(&seen_once, &points, &g, robot, 3.0, 0.5, false);
        near_line.record(&seen_once, &none, &g, robot, 3.0, 0.5, false);
        let (_, n) = unseen_near(|x, y| !hole(x, y), &near_line, &empty_driven, far);
        assert_eq!(n, 0);
        // Held as lethal (a drop rated from afar, then out of view): still a hole.
        let mut near_lethal = NearMemory::default();
        near_lethal.record(&seen_once.iter().map(|r| if r.is_nan() { *r } else { 1.0 }).collect::<Vec<_>>(), &points, &g, robot, 3.0, 0.5, false);
        let (_, n) = unseen_near(|x, y| !hole(x, y), &near_lethal, &empty_driven, far);
        assert_eq!(n, 1);
        // Stood on: not marked.
        let mut driven = DrivenMemory::default();
        driven.stamp(DVec2::new(1.35, 1.05), 0.0, 0.3, 0.3, 0.1, 20.0);
        let (_, n) = unseen_near(|x, y| !hole(x, y), &empty_near, &driven, far);
        assert_eq!(n, 0);
        // Within the blind ring of the start: never in view, not marked.
        let (_, n) = unseen_near(|_, _| false, &empty_near, &empty_driven, DVec2::new(1.0, 1.0));
        assert_eq!(n, 0);
    }

    #[test]
    fn the_rim_of_a_remembered_void_is_lethal_except_where_the_robot_stood() {
        let g = GridGeometry { resolution_m: 0.1, nx: 20, ny: 20, origin_cell: (0, 0) };
        // A 3 x 3 void at cells (8..=10, 8..=10), rated lethal by the negative layer, beside a
        // 3 x 3 step (lethal, not a void) at (15..=17, 8..=10); the rest rated ground.
        let void = |x: usize, y: usize| (8..=10).contains(&x) && (8..=10).contains(&y);
        let step = |x: usize, y: usize| (15..=17).contains(&x) && (8..=10).contains(&y);
        let mut risk: Vec<f32> = (0..400).map(|c| if void(c % 20, c / 20) || step(c % 20, c / 20) { 1.0 } else { 0.0 }).collect();
        let negative: Vec<f32> = (0..400).map(|c| if void(c % 20, c / 20) { 1.0 } else { 0.0 }).collect();
        let ground = vec![10.0; 400];
        let mut memory = HazardMemory::default();
        memory.update(&mut risk, &ground, &negative, &g, DVec2::new(1.0, 0.3), &HazardRules { lethal: 0.9, min_neighbours: 2, forget_points: 5.0, record_m: 6.0, range_m: 15.0 });
        let mut voids: Vec<WorldCell> = memory.voids().collect();
        voids.sort();
        assert_eq!(voids.len(), 9, "the void's cells are remembered as a void, the step's are not");
        assert!(voids.iter().all(|c| void(c.x as usize, c.y as usize)));
        assert_eq!(memory.len(), 18);

        // Out of view (the blind ring): the grid holds only what the memory raises.
        let mut grid = vec![f32::NAN; 400];
        let mut grown = vec![f32::NAN; 400];
        let mut driven = DrivenMemory::default();
        let n = mark_void_rims(&mut grid, &mut grown, &g, memory.voids(), &driven, 0.2, 0.9);
        // Centres within two cells of a void centre: the 7 x 7 square less its 12 far
        // corner cells (distance sqrt(5) and sqrt(8) > 2).
        assert_eq!(n, 49 - 12);
        assert_eq!(grid[9 * 20 + 12], 0.9, "two cells beyond the void's edge: rim");
        assert!(grid[9 * 20 + 13].is_nan(), "three cells beyond: not rim");
        assert!(grid[9 * 20 + 14].is_nan() && grid[11 * 20 + 16].is_nan(), "a step gets no rim");
        assert_eq!(grown[9 * 20 + 12], 0.9);
        // Ground rated safe beside it is raised too: its far part overhangs the drop.
        let mut seen = vec![0.0f32; 400];
        let mut seen_grown = seen.clone();
        mark_void_rims(&mut seen, &mut seen_grown, &g, memory.voids(), &driven, 0.2, 0.9);
        assert_eq!(seen[9 * 20 + 7], 0.9);
        assert_eq!(seen[9 * 20 + 5], 0.0);
        // Cells the robot stood on carried it: not rim.
        driven.stamp(DVec2::new(0.75, 0.95), 0.0, 0.3, 0.3, 0.1, 20.0);
        assert!(driven.contains(WorldCell { x: 7, y: 9 }));
        let mut grid = vec![0.0f32; 400];
        let mut grown = grid.clone();
        mark_void_rims(&mut grid, &mut grown, &g, memory.voids(), &driven, 0.2, 0.9);
        assert_eq!(grid[9 * 20 + 7], 0.0);
        assert_eq!(grid[9 * 20 + 12], 0.9);
        // 0 m: the void itself only, already lethal; nothing raised.
        let mut grid = vec![0.0f32; 400];
        let mut grown = grid.clone();
        for c in voids {
            grid[c.y as usize * 20 + c.x as usize] = 0.9;
        }
        assert_eq!(mark_void_rims(&mut grid, &mut grown, &g, memory.voids(), &DrivenMemory::default(), 0.0, 0.9), 0);
    }
}
