//! Where to plan to: a target off the map or on a cell the robot may not enter is replaced by
//! a **stand-in**, a cell where the robot fits and that the A* reaches from the robot
//! ([`nearest_traversable`], [`nearest_traversable_to`], [`reachable_from`]); and how far the
//! robot still has to go along its path ([`path_length_from`]).

use glam::DVec2;

use crate::plan::grid::RiskGrid;

/// `target` if it is on the grid (one cell inside its edge), else the point of the segment
/// `from -> target` nearest to `target` that is; and the straight distance left from there.
pub(crate) fn on_map(grid: &RiskGrid<'_>, from: DVec2, target: DVec2) -> (DVec2, f64) {
    let res = grid.resolution_m();
    let lo = grid.origin_m() + DVec2::splat(1.5 * res);
    let hi = grid.origin_m() + DVec2::new(grid.nx() as f64, grid.ny() as f64) * res - DVec2::splat(1.5 * res);
    let inside = |p: DVec2| p.x >= lo.x && p.y >= lo.y && p.x <= hi.x && p.y <= hi.y;
    if inside(target) {
        return (target, 0.0);
    }
    // Largest t in [0, 1] with from + t·(target - from) inside the shrunk box (slab clipping).
    let d = target - from;
    let mut t_max: f64 = 1.0;
    for (o, dd, l, h) in [(from.x, d.x, lo.x, hi.x), (from.y, d.y, lo.y, hi.y)] {
        if dd > 0.0 {
            t_max = t_max.min((h - o) / dd);
        } else if dd < 0.0 {
            t_max = t_max.min((l - o) / dd);
        }
    }
    let p = from + d * t_max.clamp(0.0, 1.0);
    let p = p.clamp(lo, hi);
    (p, p.distance(target))
}

/// What a stand-in must satisfy (step 3): the robot fits there (every cell within
/// `fit_radius_m` of it, itself included, has a risk (NaN: `unknown`) below `r_inst`) and the
/// planner reaches it from the robot (`reachable`, by cell; empty: not checked). A lone
/// traversable cell in a lethal patch, or a pocket walled in by one, would do as a target
/// for the planner, but no path reaches it.
pub(crate) struct Search<'a> {
    pub r_inst: f64,
    pub unknown: f64,
    pub fit_radius_m: f64,
    pub reachable: &'a [bool],
}

impl Search<'_> {
    fn accepts(&self, grid: &RiskGrid<'_>, ix: i64, iy: i64) -> bool {
        let (nx, ny) = (grid.nx() as i64, grid.ny() as i64);
        let res = grid.resolution_m();
        let blocked = |ix: i64, iy: i64| {
            let inside = ix >= 0 && iy >= 0 && ix < nx && iy < ny;
            !inside || {
                let r = grid.risk()[(iy * nx + ix) as usize];
                (if r.is_nan() { self.unknown } else { f64::from(r) }) >= self.r_inst
            }
        };
        let fit = (self.fit_radius_m / res).floor() as i64;
        let r2 = self.fit_radius_m * self.fit_radius_m;
        let inside = ix >= 0 && iy >= 0 && ix < nx && iy < ny;
        inside
            && (self.reachable.is_empty() || self.reachable[(iy * nx + ix) as usize])
            && (-fit..=fit).all(|dy| (-fit..=fit).all(|dx| ((dx * dx + dy * dy) as f64 * res * res > r2) || !blocked(ix + dx, iy + dy)))
    }
}

/// The centre of the cell nearest `p` (within `radius_m`) that `search` accepts.
pub(crate) fn nearest_traversable(grid: &RiskGrid<'_>, p: DVec2, radius_m: f64, search: &Search<'_>) -> Option<DVec2> {
    let centre = grid.cell_of(p)?;
    let res = grid.resolution_m();
    let reach = (radius_m / res).ceil() as i64;
    let mut best: Option<(f64, DVec2)> = None;
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            let (ix, iy) = (centre.ix as i64 + dx, centre.iy as i64 + dy);
            let q = grid.origin_m() + (DVec2::new(ix as f64, iy as f64) + 0.5) * res;
            let d = q.distance_squared(p);
            if d <= radius_m * radius_m && best.is_none_or(|(bd, _)| d < bd) && search.accepts(grid, ix, iy) {
                best = Some((d, q));
            }
        }
    }
    best.map(|(_, q)| q)
}

/// The centre of the cell of the whole grid nearest `p` that `search` accepts: for a target
/// off the map whose stand-in on the edge has none near it, the way on goes through the
/// reachable cell nearest the target (the map grows as the robot gets there).
pub(crate) fn nearest_traversable_to(grid: &RiskGrid<'_>, p: DVec2, search: &Search<'_>) -> Option<DVec2> {
    let res = grid.resolution_m();
    let mut best: Option<(f64, DVec2)> = None;
    for iy in 0..grid.ny() as i64 {
        for ix in 0..grid.nx() as i64 {
            if !search.reachable.is_empty() && !search.reachable[iy as usize * grid.nx() + ix as usize] {
                continue;
            }
            let q = grid.origin_m() + (DVec2::new(ix as f64, iy as f64) + 0.5) * res;
            let d = q.distance_squared(p);
            if best.is_none_or(|(bd, _)| d < bd) && search.accepts(grid, ix, iy) {
                best = Some((d, q));
            }
        }
    }
    best.map(|(_, q)| q)
}

/// Marks in `out` (one flag per cell) the cells the A* can reach from `start`'s cell: its
/// moves (8-connected; a diagonal needs both cells at its corner traversable unless
/// `allow_corner_cutting`) over cells with a risk (NaN: `unknown`) below `r_inst`. The start
/// cell counts as reached even when blocked (the A* then reports it). `out` is left empty
/// when `start` is off the grid (nothing is checked then). `stack`: scratch.
pub(crate) fn reachable_from(grid: &RiskGrid<'_>, start: DVec2, r_inst: f64, unknown: f64, allow_corner_cutting: bool, out: &mut Vec<bool>, stack: &mut Vec<usize>) {
    out.clear();
    let Some(c) = grid.cell_of(start) else { return };
    let (nx, ny) = (grid.nx(), grid.ny());
    out.resize(nx * ny, false);
    let risk = grid.risk();
    let free = |i: usize| {
        let r = risk[i];
        (if r.is_nan() { unknown } else { f64::from(r) }) < r_inst
    };
    stack.clear();
    let s = c.iy as usize * nx + c.ix as usize;
    out[s] = true;
    stack.push(s);
    while let Some(i) = stack.pop() {
        let (x, y) = ((i % nx) as i64, (i / nx) as i64);
        for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)] {
            let (jx, jy) = (x + dx, y + dy);
            if jx < 0 || jy < 0 || jx >= nx as i64 || jy >= ny as i64 {
                continue;
            }
            let j = jy as usize * nx + jx as usize;
            if out[j] || !free(j) {
                continue;
            }
            if dx != 0 && dy != 0 && !allow_corner_cutting && !(free(y as usize * nx + jx as usize) && free(jy as usize * nx + x as usize)) {
                continue;
            }
            out[j] = true;
            stack.push(j);
        }
    }
}

/// Length of `path` from its point nearest `p` to its end, plus the gap to that point \[m\].
pub(crate) fn path_length_from(path: &[DVec2], p: DVec2) -> f64 {
    let nearest = path
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.distance_squared(p).total_cmp(&b.1.distance_squared(p)))
        .map_or(0, |(i, _)| i);
    let rest: f64 = path[nearest..].windows(2).map(|w| w[0].distance(w[1])).sum();
    rest + path.get(nearest).map_or(0.0, |q| q.distance(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stand_in_is_where_the_robot_fits_not_a_lone_cell_in_a_lethal_patch() {
        // 20 x 20 cells of 0.1 m: a lethal 9 x 9 patch at cells 6..=14 with one safe cell
        // (10, 10) in it.
        let mut risk = vec![0.0f32; 400];
        for iy in 6..=14 {
            for ix in 6..=14 {
                risk[iy * 20 + ix] = 1.0;
            }
        }
        risk[10 * 20 + 10] = 0.0;
        let grid = RiskGrid::new(&risk, 20, 20, 0.1, DVec2::ZERO).unwrap();
        let p = DVec2::new(1.05, 1.05);
        let search = |fit_radius_m: f64| Search { r_inst: 0.6, unknown: 0.03, fit_radius_m, reachable: &[] };
        // Without room to fit, the lone cell itself.
        assert_eq!(nearest_traversable(&grid, p, 1.0, &search(0.0)), Some(p));
        // A robot 0.2 m wide: the nearest cell at least 0.1 m clear of the patch, 5 cells
        // away along an axis (cell 4 or 16).
        let q = nearest_traversable(&grid, p, 1.0, &search(0.1)).unwrap();
        assert!((q.distance(p) - 0.6).abs() < 1e-9, "{q}");
        // None within reach.
        assert_eq!(nearest_traversable(&grid, p, 0.4, &search(0.1)), None);
    }

    #[test]
    fn a_stand_in_is_one_the_planner_reaches_not_a_walled_in_pocket() {
        // Regression (mine seed 4): the stand-in on the map's edge was a pocket of free cells
        // walled in by lethal ones, and the A* reported "no path" although the robot could
        // drive to the edge elsewhere. 40 x 20 cells of 0.1 m; the robot at (0.5, 1.0); a
        // lethal ring around the pocket centred on (3.5, 1.0) (cells 30..=40 x 5..=15, its
        // inside 32..=38 x 7..=13 free).
        let (nx, ny) = (40usize, 20usize);
        let mut risk = vec![0.0f32; nx * ny];
        for iy in 5..=15 {
            for ix in 30..nx {
                let inner = (32..=38).contains(&ix) && (7..=13).contains(&iy);
                if !inner {
                    risk[iy * nx + ix] = 1.0;
                }
            }
        }
        let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
        let (mut reachable, mut stack) = (Vec::new(), Vec::new());
        reachable_from(&grid, DVec2::new(0.5, 1.0), 0.6, 0.03, false, &mut reachable, &mut stack);
        assert!(!reachable[10 * nx + 35] && reachable[10 * nx + 10] && reachable[2 * nx + 35], "pocket walled in, the rest reached");
        let target = DVec2::new(3.55, 1.05);
        let blind = Search { r_inst: 0.6, unknown: 0.03, fit_radius_m: 0.15, reachable: &[] };
        assert!(nearest_traversable(&grid, target, 1.0, &blind).is_some_and(|q| q.distance(target) < 0.2), "without reachability: the pocket");
        let seeing = Search { reachable: &reachable, ..blind };
        // Within 0.5 m of the target, nothing reachable fits; over the whole grid, the
        // reachable cells nearest the target with room for the robot are 0.7 m from it,
        // beside the ring (left of it or below it).
        assert_eq!(nearest_traversable(&grid, target, 0.5, &seeing), None);
        let q = nearest_traversable_to(&grid, target, &seeing).unwrap();
        assert!((q.distance(target) - 0.7).abs() < 1e-9 && (q.x < 2.9 || q.y < 0.4), "{q}");
        // A diagonal gap between two blocked cells is no way in without corner cutting.
        let mut diag = vec![0.0f32; 9];
        diag[1] = 1.0;
        diag[3] = 1.0;
        let g3 = RiskGrid::new(&diag, 3, 3, 0.1, DVec2::ZERO).unwrap();
        reachable_from(&g3, DVec2::new(0.05, 0.05), 0.6, 0.03, false, &mut reachable, &mut stack);
        assert_eq!(reachable.iter().filter(|&&r| r).count(), 1);
        reachable_from(&g3, DVec2::new(0.05, 0.05), 0.6, 0.03, true, &mut reachable, &mut stack);
        assert_eq!(reachable.iter().filter(|&&r| r).count(), 7);
    }
}
