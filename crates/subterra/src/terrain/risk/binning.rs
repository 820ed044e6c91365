//! Binning points into map cells: a scan's points into the global cells once when it
//! arrives, a fine map's scans point by point, and pre-binned scans merged into the map;
//! with the libm-free `floor` the cell index needs.

use glam::{DVec2, DVec3};

use crate::terrain::grid::GridGeometry;
#[cfg(doc)]
use crate::terrain::ground::GroundSegmenter;
use super::{BinnedCell, BinnedSource, CellAccumulator, MapBuilder, ScanSource};

impl MapBuilder {
    /// Bins one scan's points once, into the global cells around `origin_world` (the scan's
    /// sensor, world frame): `out` gets the non-empty cells. `sensor_above_body_m` lifts the
    /// sensor-centred heights to the scan's body origin. `voids`: the scan's void samples
    /// (sensor-centred `(x, y)`, [`GroundSegmenter::void_samples`]), counted per cell.
    pub(crate) fn bin_scan(&mut self, points: &[[f32; 3]], heights: &[f32], voids: &[[f32; 2]], origin_world: DVec3, sensor_above_body_m: f64, out: &mut Vec<BinnedCell>) {
        let g = GridGeometry::centred_on(&self.scratch_map, origin_world.x, origin_world.y);
        let n = g.cells();
        if self.scratch.len() != n {
            self.scratch.clear();
            self.scratch.resize(n, CellAccumulator::EMPTY);
        }
        let res = g.resolution_m;
        let (nx, ny) = (g.nx as i64, g.ny as i64);
        let thr = self.ground_threshold;
        let lo = (self.robot.ground_clearance_m - self.layers.clearance_margin_m) as f32;
        let hi = (self.robot.height_m + self.layers.head_margin_m) as f32;
        let dz = sensor_above_body_m as f32;
        // Each point writes its cell to `touched[hits]` and counts it only if the cell was
        // empty: no branch on "first hit", which real scans mispredict often. At most
        // min(points + voids, cells) distinct cells, plus the slot the last write may use.
        let room = (points.len() + voids.len()).min(n) + 1;
        if self.touched.len() < room {
            self.touched.resize(room, 0);
        }
        let touched = &mut self.touched[..room];
        let mut hits = 0;
        // The cells are [origin, origin + n) along each axis: floor(q) - origin is in [0, n)
        // iff q is in [origin, origin + n) (integer bounds), tested on q itself; then
        // floor_small gives floor(q) exactly. Points are finite (prefiltered), so q is too.
        let (x_lo, y_lo) = (g.origin_cell.0 as f64, g.origin_cell.1 as f64);
        let (x_hi, y_hi) = ((g.origin_cell.0 + nx) as f64, (g.origin_cell.1 + ny) as f64);
        let small = [x_lo, x_hi, y_lo, y_hi].iter().all(|b| b.abs() < FLOOR_SMALL_LIMIT);
        // A local slice: its pointer and length stay in registers (the writes to `touched`
        // could otherwise alias `self.scratch`).
        let scratch = &mut self.scratch[..n];
        for (p, &h) in points.iter().zip(heights) {
            // The same formula as GridGeometry::cell_of, so every scan agrees on the cells.
            let qx = (p[0] as f64 + origin_world.x) / res;
            let qy = (p[1] as f64 + origin_world.y) / res;
            let (ix, iy) = if small {
                if !(qx >= x_lo && qx < x_hi && qy >= y_lo && qy < y_hi) {
                    continue;
                }
                (floor_small(qx) - g.origin_cell.0, floor_small(qy) - g.origin_cell.1)
            } else {
                let (ix, iy) = (floor_i64(qx) - g.origin_cell.0, floor_i64(qy) - g.origin_cell.1);
                if ix < 0 || iy < 0 || ix >= nx || iy >= ny {
                    continue;
                }
                (ix, iy)
            };
            let c = (iy * nx + ix) as usize;
            let cell = &mut scratch[c];
            touched[hits] = c as u32;
            hits += (cell.count == 0) as usize;
            cell.add(p[2] + dz, h, thr, lo, hi);
        }
        for v in voids {
            let (ix, iy) = (floor_i64((v[0] as f64 + origin_world.x) / res) - g.origin_cell.0, floor_i64((v[1] as f64 + origin_world.y) / res) - g.origin_cell.1);
            if ix < 0 || iy < 0 || ix >= nx || iy >= ny {
                continue;
            }
            let c = (iy * nx + ix) as usize;
            let cell = &mut scratch[c];
            touched[hits] = c as u32;
            hits += (cell.count == 0 && cell.void_n == 0) as usize;
            cell.void_n += 1;
        }
        // The non-empty cells in the order they were first hit (each global cell once, so
        // the order does not change any sum the map makes of them).
        out.clear();
        let touched = &touched[..hits];
        out.reserve(touched.len());
        let scratch = &mut self.scratch[..n];
        for &c in touched {
            let c = c as usize;
            let cell = std::mem::replace(&mut scratch[c], CellAccumulator::EMPTY);
            let (ix, iy) = ((c % g.nx) as i64, (c / g.nx) as i64);
            out.push(BinnedCell { gx: g.origin_cell.0 + ix, gy: g.origin_cell.1 + iy, acc: cell });
        }
    }

    #[inline(never)]
    pub(super) fn bin_points(&mut self, g: &GridGeometry, corner: DVec2, sources: &[ScanSource<'_>]) -> usize {
        let inv = (1.0 / g.resolution_m) as f32;
        let (nx, ny) = (g.nx as f32, g.ny as f32);
        let nxu = g.nx;
        let thr = self.ground_threshold;
        let lo = (self.robot.ground_clearance_m - self.layers.clearance_margin_m) as f32;
        let hi = (self.robot.height_m + self.layers.head_margin_m) as f32;
        let mut binned = 0;
        for src in sources {
            // u = (x + offset - corner) / res.
            let ox = (src.offset.x as f64 - corner.x) as f32;
            let oy = (src.offset.y as f64 - corner.y) as f32;
            let oz = src.offset.z;
            let age = src.age_s;
            for (p, &h) in src.points_level.iter().zip(src.heights) {
                let u = (p[0] + ox) * inv;
                let v = (p[1] + oy) * inv;
                if !(u >= 0.0 && u < nx && v >= 0.0 && v < ny) {
                    continue;
                }
                let cell = &mut self.cells[v as usize * nxu + u as usize];
                binned += 1;
                cell.add(p[2] + oz, h, thr, lo, hi);
                cell.min_age = cell.min_age.min(age);
            }
        }
        binned
    }

    #[inline(never)]
    pub(super) fn merge_binned(&mut self, g: &GridGeometry, binned: &[BinnedSource<'_>]) -> usize {
        let (nx, ny) = (g.nx as i64, g.ny as i64);
        let mut points = 0;
        for src in binned {
            let dz = src.dz;
            for b in src.cells {
                let (ix, iy) = (b.gx - g.origin_cell.0, b.gy - g.origin_cell.1);
                if ix < 0 || iy < 0 || ix >= nx || iy >= ny {
                    continue;
                }
                let a = &b.acc;
                let cell = &mut self.cells[(iy * nx + ix) as usize];
                points += a.count as usize;
                cell.count += a.count;
                cell.ground_n += a.ground_n;
                cell.collision_n += a.collision_n;
                cell.ground_sum += a.ground_sum + a.ground_n as f32 * dz;
                cell.min_z = cell.min_z.min(a.min_z + dz);
                cell.max_z = cell.max_z.max(a.max_z + dz);
                cell.min_age = cell.min_age.min(src.age_s);
                cell.void_n += a.void_n;
            }
        }
        points
    }
}

/// Inputs of [`floor_small`] stay below this in magnitude.
pub(super) const FLOOR_SMALL_LIMIT: f64 = (1u64 << 50) as f64;

/// `floor(x)` for `|x| < 2^50`, exactly, without a libm call or saturation code: adding
/// 1.5·2^52 rounds x to the nearest integer, held in the low mantissa bits; one comparison
/// turns the rounding into a floor.
#[inline]
pub(super) fn floor_small(x: f64) -> i64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5·2^52
    let t = x + MAGIC;
    let rounded = (t.to_bits() as i64) - (MAGIC.to_bits() as i64);
    rounded - ((t - MAGIC) > x) as i64
}

/// `floor(x)` as an integer without a libm call (x86-64 without SSE4.1 has no inline
/// floor); saturates like `as` for huge or NaN inputs (NaN gives 0).
#[inline]
pub(super) fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t - 1
    } else {
        t
    }
}
