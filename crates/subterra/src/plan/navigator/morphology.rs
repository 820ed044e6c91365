//! Morphology on the planner's grid: which lethal cells form a patch ([`clustered`]), the
//! patch grown into the unobserved cells of its own shadow ([`grow_into_unseen`]), and
//! lethal cells inflated by the robot's inscribed radius for the A*, which plans the robot's
//! centre ([`inflate_lethal`]).

use std::cmp::Ordering;

use glam::DVec2;

use crate::terrain::GridGeometry;

/// The growth into the unseen (step 2 of the navigator), its settings.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Growth {
    /// The lethal level.
    pub lethal: f32,
    /// Lethal neighbours a lethal cell needs to spread (a patch, not a speckle).
    pub min_neighbours: u32,
    /// How far a patch spreads \[m\].
    pub radius_m: f64,
    /// The robot [m, world].
    pub robot: DVec2,
    /// No cell whose centre is nearer the robot than this takes a rating \[m\].
    pub min_range_m: f64,
}

/// The growth into the unseen (step 2): every unobserved (NaN) cell of `risk` within
/// `radius_m` of a lethal cell (at or above `lethal`, with `min_neighbours` lethal
/// neighbours), and at least `min_range_m` from the robot, takes the highest such rating.
/// Only cells lethal before the growth spread it. `scratch`: a buffer for the grid as it was.
pub(crate) fn grow_into_unseen(risk: &mut [f32], scratch: &mut Vec<f32>, g: &GridGeometry, growth: &Growth) {
    let Growth { lethal, min_neighbours, radius_m, robot, min_range_m } = *growth;
    // The robot in cell units, relative to cell centres.
    let rc = (robot - g.origin_m()) / g.resolution_m - 0.5;
    let near2 = (min_range_m / g.resolution_m).powi(2);
    scratch.clear();
    scratch.extend_from_slice(risk);
    let src = &scratch[..];
    let (nx, ny) = (g.nx as i64, g.ny as i64);
    // In cells, a hair wide: 0.3 m / 0.1 m is 2.9999999999999996.
    let cells = radius_m / g.resolution_m * (1.0 + 1e-9);
    let reach = cells.floor() as i64;
    let disc: Vec<(i64, i64)> = (-reach..=reach).flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy))).filter(|&(dx, dy)| (dx * dx + dy * dy) as f64 <= cells * cells).collect();
    for iy in 0..ny {
        for ix in 0..nx {
            let c = (iy * nx + ix) as usize;
            let r = src[c];
            if r.partial_cmp(&lethal).is_none_or(Ordering::is_lt) || !clustered(src, g.nx, g.ny, c, lethal, min_neighbours) {
                continue;
            }
            for &(dx, dy) in &disc {
                let (jx, jy) = (ix + dx, iy + dy);
                if jx < 0 || jy < 0 || jx >= nx || jy >= ny {
                    continue;
                }
                let j = (jy * nx + jx) as usize;
                if src[j].is_nan() && risk[j].partial_cmp(&r).is_none_or(Ordering::is_lt) && DVec2::new(jx as f64, jy as f64).distance_squared(rc) >= near2 {
                    risk[j] = r;
                }
            }
        }
    }
}

/// Whether cell `c` of the `nx x ny` grid `risk` has at least `min` of its 8 neighbours at or
/// above `lethal` (cells off the grid do not count).
pub(crate) fn clustered(risk: &[f32], nx: usize, ny: usize, c: usize, lethal: f32, min: u32) -> bool {
    if min == 0 {
        return true;
    }
    let (ix, iy) = ((c % nx) as i64, (c / nx) as i64);
    let mut n = 0;
    for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
        let (jx, jy) = (ix + dx, iy + dy);
        if jx >= 0 && jy >= 0 && jx < nx as i64 && jy < ny as i64 && risk[jy as usize * nx + jx as usize] >= lethal {
            n += 1;
        }
    }
    n >= min
}

/// The A*'s grid (step 3): `risk` with every cell whose centre lies within `radius_m` of a
/// cell at or above `lethal` with at least `min_neighbours` such neighbours ([`clustered`])
/// raised to at least `lethal` (the robot's centre there
/// would put its footprint on it; `radius_m` is half its width, the inscribed radius), except
/// cells within `radius_m` of `robot`: a robot already that close must be able to plan its
/// way out.
pub(crate) fn inflate_lethal(risk: &[f32], out: &mut Vec<f32>, g: &GridGeometry, lethal: f32, min_neighbours: u32, radius_m: f64, robot: DVec2) {
    out.clear();
    out.extend_from_slice(risk);
    let res = g.resolution_m;
    let (nx, ny) = (g.nx as i64, g.ny as i64);
    let reach = (radius_m / res).floor() as i64;
    let r2 = (radius_m / res) * (radius_m / res);
    let disc: Vec<(i64, i64)> =
        (-reach..=reach).flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy))).filter(|&(dx, dy)| (dx * dx + dy * dy) as f64 <= r2).collect();
    // The robot in cell units, relative to cell centres.
    let rc = (robot - g.origin_m()) / res - 0.5;
    for_each_patch_edge(risk, g, lethal, min_neighbours, |ix, iy, r| {
        for &(dx, dy) in &disc {
            let (jx, jy) = (ix + dx, iy + dy);
            if jx < 0 || jy < 0 || jx >= nx || jy >= ny || DVec2::new(jx as f64, jy as f64).distance_squared(rc) <= r2 {
                continue;
            }
            let v = &mut out[(jy * nx + jx) as usize];
            if (*v).partial_cmp(&r).is_none_or(Ordering::is_lt) {
                *v = r;
            }
        }
    });
}

/// Calls `f(ix, iy, risk)` for every cell at or above `lethal` with at least `min_neighbours`
/// such neighbours ([`clustered`]) that is not interior to its patch. An interior cell (its
/// four neighbours lethal or off the grid) is skipped: a disc stamped round it is covered by
/// its neighbours' (a cell within reach of it is nearer one of its four neighbours), and with
/// `min_neighbours` <= 2 those neighbours are clustered themselves. NaN is never lethal.
fn for_each_patch_edge(risk: &[f32], g: &GridGeometry, lethal: f32, min_neighbours: u32, mut f: impl FnMut(i64, i64, f32)) {
    let (nx, ny) = (g.nx as i64, g.ny as i64);
    let is_lethal = |ix: i64, iy: i64| ix < 0 || iy < 0 || ix >= nx || iy >= ny || risk[(iy * nx + ix) as usize] >= lethal;
    for iy in 0..ny {
        for ix in 0..nx {
            let r = risk[(iy * nx + ix) as usize];
            let interior = is_lethal(ix - 1, iy) && is_lethal(ix + 1, iy) && is_lethal(ix, iy - 1) && is_lethal(ix, iy + 1);
            if r >= lethal && !interior && clustered(risk, g.nx, g.ny, (iy * nx + ix) as usize, lethal, min_neighbours) {
                f(ix, iy, r);
            }
        }
    }
}

/// The A*'s clearance prices (step 3): per cell, `price·(outer - d)/(outer - inner)` clamped to
/// `[0, price]`, `d` the distance from the cell's centre to the nearest cell at or above
/// `lethal` with at least `min_neighbours` such neighbours (those [`inflate_lethal`]
/// inflates); 0 beyond `outer_m`. With `inner_m` the inscribed radius and `outer_m` the
/// circumscribed one, it prices the ground where the robot fits but could not turn in place.
#[allow(clippy::too_many_arguments)]
pub(crate) fn turn_room_prices(risk: &[f32], out: &mut Vec<f32>, g: &GridGeometry, lethal: f32, min_neighbours: u32, inner_m: f64, outer_m: f64, price: f32) {
    out.clear();
    out.resize(risk.len(), 0.0);
    if !(price > 0.0 && outer_m > inner_m) {
        return;
    }
    let res = g.resolution_m;
    let (nx, ny) = (g.nx as i64, g.ny as i64);
    let reach = (outer_m / res).floor() as i64;
    let (inner, outer) = (inner_m / res, outer_m / res);
    let disc: Vec<(i64, i64, f32)> = (-reach..=reach)
        .flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy)))
        .filter_map(|(dx, dy)| {
            let d = ((dx * dx + dy * dy) as f64).sqrt();
            let p = (f64::from(price) * (outer - d) / (outer - inner)).clamp(0.0, f64::from(price)) as f32;
            (p > 0.0).then_some((dx, dy, p))
        })
        .collect();
    for_each_patch_edge(risk, g, lethal, min_neighbours, |ix, iy, _| {
        for &(dx, dy, p) in &disc {
            let (jx, jy) = (ix + dx, iy + dy);
            if jx < 0 || jy < 0 || jx >= nx || jy >= ny {
                continue;
            }
            let v = &mut out[(jy * nx + jx) as usize];
            *v = v.max(p);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turn_room_falls_from_the_inscribed_to_the_circumscribed_radius() {
        // One 3x3 lethal patch in the middle of a 41x41 grid of 0.1 m cells.
        let g = GridGeometry { resolution_m: 0.1, nx: 41, ny: 41, origin_cell: (0, 0) };
        let mut risk = vec![0.0f32; 41 * 41];
        for iy in 19..=21 {
            for ix in 19..=21 {
                risk[iy * 41 + ix] = 1.0;
            }
        }
        let mut out = Vec::new();
        turn_room_prices(&risk, &mut out, &g, 0.9, 2, 0.3, 0.6, 2.0);
        let at = |ix: usize, iy: usize| out[iy * 41 + ix];
        // Along +x from the patch's edge cell (21, 20): 0.3 m away the full price, halfway
        // between the radii half of it, at 0.6 m and beyond nothing; the lethal cells and
        // those nearer than the inscribed radius carry the full price too (the A* has them
        // untraversable anyway).
        assert_eq!(at(24, 20), 2.0);
        assert!((at(25, 20) - 4.0 / 3.0).abs() < 1e-6, "{}", at(25, 20));
        assert!((at(26, 20) - 2.0 / 3.0).abs() < 1e-6, "{}", at(26, 20));
        assert_eq!(at(27, 20), 0.0);
        assert_eq!(at(35, 20), 0.0);
        assert_eq!(at(22, 20), 2.0);
        // Symmetric round the patch, and the same prices with a lone lethal cell ignored.
        assert_eq!(at(15, 20), at(25, 20));
        assert_eq!(at(20, 16), at(20, 24));
        risk[5 * 41 + 5] = 1.0;
        let mut lone = Vec::new();
        turn_room_prices(&risk, &mut lone, &g, 0.9, 2, 0.3, 0.6, 2.0);
        assert_eq!(lone, out);
        // Off: all zero.
        turn_room_prices(&risk, &mut lone, &g, 0.9, 2, 0.3, 0.6, 0.0);
        assert!(lone.iter().all(|&p| p == 0.0));
    }

    /// `inflate_lethal` without its shortcut: every lethal cell stamps its disc.
    fn inflate_naive(risk: &[f32], g: &GridGeometry, lethal: f32, min: u32, radius_m: f64, robot: DVec2) -> Vec<f32> {
        let mut out = risk.to_vec();
        let centre = |i: usize| g.origin_m() + (DVec2::new((i % g.nx) as f64, (i / g.nx) as f64) + 0.5) * g.resolution_m;
        for (i, &r) in risk.iter().enumerate() {
            for (j, slot) in out.iter_mut().enumerate() {
                let near = |a: DVec2, b: DVec2| a.distance_squared(b) <= radius_m * radius_m * (1.0 + 1e-12);
                if r >= lethal && clustered(risk, g.nx, g.ny, i, lethal, min) && near(centre(i), centre(j)) && !near(centre(j), robot) && (*slot).partial_cmp(&r).is_none_or(Ordering::is_lt) {
                    *slot = r;
                }
            }
        }
        out
    }

    #[test]
    fn a_lethal_cell_is_inflated_by_the_inscribed_radius_except_around_the_robot() {
        let g = GridGeometry { resolution_m: 0.1, nx: 21, ny: 21, origin_cell: (0, 0) };
        let mut risk = vec![0.1f32; 21 * 21];
        risk[10 * 21 + 10] = 1.0;
        risk[10 * 21 + 12] = f32::NAN;
        let mut out = Vec::new();
        // 0.25 m = 2.5 cells: 21 cells within, the unobserved one among them raised too.
        inflate_lethal(&risk, &mut out, &g, 0.9, 0, 0.25, DVec2::ZERO);
        assert_eq!(out.iter().filter(|&&v| v >= 0.9).count(), 21);
        assert_eq!(out[10 * 21 + 12], 1.0);
        assert_eq!((out[12 * 21 + 12], out[10 * 21 + 13]), (0.1, 0.1));
        // The robot at cell (12, 10): cells within 0.25 m of it keep their risk.
        inflate_lethal(&risk, &mut out, &g, 0.9, 0, 0.25, DVec2::new(1.25, 1.05));
        assert!(out[10 * 21 + 12].is_nan());
        assert_eq!((out[10 * 21 + 10], out[10 * 21 + 9]), (1.0, 1.0));
    }

    #[test]
    fn lethal_inflation_equals_stamping_every_lethal_cell() {
        // Seeded random grids: blobs of lethal cells (values 0.9-1), NaN and safe cells.
        let g = GridGeometry { resolution_m: 0.1, nx: 23, ny: 17, origin_cell: (-5, 3) };
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut out = Vec::new();
        for case in 0..20 {
            let risk: Vec<f32> = (0..g.cells())
                .map(|_| match next() {
                    u if u < 0.15 => 0.9 + 0.1 * next() as f32,
                    u if u < 0.25 => f32::NAN,
                    _ => 0.8 * next() as f32,
                })
                .collect();
            let robot = g.origin_m() + DVec2::new(next() * 2.3, next() * 1.7);
            let radius = 0.05 + 0.3 * next();
            let min = (case % 3) as u32;
            inflate_lethal(&risk, &mut out, &g, 0.9, min, radius, robot);
            let want = inflate_naive(&risk, &g, 0.9, min, radius, robot);
            for (c, (a, b)) in out.iter().zip(&want).enumerate() {
                // Lethal values may come from a different lethal neighbour; both block.
                let same = a.to_bits() == b.to_bits() || (*a >= 0.9 && *b >= 0.9);
                assert!(same, "case {case} cell {c}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn lethal_patches_grow_into_unobserved_cells_only() {
        // 12 x 12 cells of 0.1 m: a lethal 3 x 3 patch at cells 2..=4, unobserved cells to
        // its right (columns 5..=11 of rows 2..=4), observed ground elsewhere.
        let g = GridGeometry { resolution_m: 0.1, nx: 12, ny: 12, origin_cell: (0, 0) };
        let mut risk = vec![0.1f32; 144];
        for iy in 2..=4 {
            for ix in 2..=4 {
                risk[iy * 12 + ix] = 1.0;
            }
            for ix in 5..12 {
                risk[iy * 12 + ix] = f32::NAN;
            }
        }
        risk[8 * 12 + 8] = 0.95; // a lone lethal speckle: no patch, no growth
        risk[8 * 12 + 9] = f32::NAN;
        let mut scratch = Vec::new();
        // The robot far off the grid: nothing is too near it to grow into.
        let growth = Growth { lethal: 0.9, min_neighbours: 2, radius_m: 0.3, robot: DVec2::new(-50.0, -50.0), min_range_m: 2.5 };
        grow_into_unseen(&mut risk, &mut scratch, &g, &growth);
        for iy in 2..=4 {
            // 0.3 m = 3 cells: columns 5..=7 taken, not 8 and beyond (no chain reaction).
            assert_eq!(&risk[iy * 12 + 5..iy * 12 + 8], &[1.0, 1.0, 1.0], "row {iy}");
            assert!(risk[iy * 12 + 8..iy * 12 + 12].iter().all(|v| v.is_nan()), "row {iy}");
        }
        // Observed cells keep their rating; the speckle spreads nothing.
        assert_eq!((risk[12 + 3], risk[5 * 12 + 3]), (0.1, 0.1));
        assert!(risk[8 * 12 + 9].is_nan());
    }

    #[test]
    fn no_growth_next_to_the_robot() {
        // A lethal band at x = 0.1-0.3 m, unobserved cells right of it; the robot at
        // (0.78, 0.64) m. Within 0.5 m of it nothing grows, beyond it the growth stays.
        let g = GridGeometry { resolution_m: 0.1, nx: 12, ny: 12, origin_cell: (0, 0) };
        let mut risk = vec![f32::NAN; 144];
        for iy in 0..12 {
            risk[iy * 12 + 1] = 1.0;
            risk[iy * 12 + 2] = 1.0;
        }
        let growth = Growth { lethal: 0.9, min_neighbours: 2, radius_m: 0.3, robot: DVec2::new(0.78, 0.64), min_range_m: 0.5 };
        grow_into_unseen(&mut risk, &mut Vec::new(), &g, &growth);
        for iy in 0..12usize {
            for ix in 3..=5usize {
                let centre = DVec2::new(ix as f64 + 0.5, iy as f64 + 0.5) * 0.1;
                let grown = risk[iy * 12 + ix] == 1.0;
                assert_eq!(grown, centre.distance(growth.robot) >= 0.5, "cell ({ix}, {iy})");
            }
        }
    }
}
