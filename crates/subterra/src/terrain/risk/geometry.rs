//! The geometric layers from the binned cells: ground height, observation and negative
//! depth (with the newest scan's polar ground), the plane fit's slope and residual over
//! summed-area tables, and the step height.

use std::cmp::Ordering;

use glam::DVec2;

use crate::terrain::grid::{GridGeometry, Layer, RiskMap};
use super::{select_f32, MapBuilder, NewestPolar};

impl MapBuilder {
    #[inline(never)]
    pub(super) fn ground_heights(&mut self, g: &GridGeometry, corner: DVec2, polar: Option<&NewestPolar<'_>>, map: &mut RiskMap) {
        let n = g.cells();
        let res = g.resolution_m;
        self.height.resize(n, f32::NAN);
        let Ok([.., negative_depth, _tilt, observed, _age, _collision, _step, _negative, _tilt_risk, _rough, _unknown, _mission, _risk, _variance]) = <[&mut [f32]; 21]>::try_from(map.layers_mut()) else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        let (depth, observed, height) = (&mut negative_depth[..n], &mut observed[..n], &mut self.height[..n]);
        // Every cell: its own points' ground and observation, no depth unless the floor was
        // found missing and no scan of the window saw ground here (the polar queries below
        // add to that). Selects, not branches: real scans mix empty, ground and obstacle
        // cells unpredictably.
        let thr = self.ground_threshold;
        for (c, cell) in self.cells[..n].iter().enumerate() {
            let mean = cell.ground_sum / cell.ground_n as f32;
            height[c] = select_f32(cell.ground_n > 0, mean, f32::NAN);
            let void = (cell.void_n > 0) & (cell.ground_n == 0);
            observed[c] = select_f32((cell.count > 0) | void, 1.0, 0.0);
            // A cell with ground of its own is as deep as its points reach below that ground,
            // if deeper than the ground band (a rim with the drop's wall or floor in it).
            let drop = mean - cell.min_z;
            let own = select_f32((cell.ground_n > 0) & (drop > thr), drop, 0.0);
            depth[c] = select_f32(void, f32::INFINITY, own);
        }
        if let Some(polar) = polar {
            let s = polar.sensor_level;
            // Cell centres relative to the sensor: x by column, y by row.
            self.xs.clear();
            self.xs.extend((0..g.nx).map(|ix| corner.x + (ix as f64 + 0.5) * res - s.x));
            let cells = &self.cells[..n];
            for iy in 0..g.ny {
                let y = corner.y + (iy as f64 + 0.5) * res - s.y;
                let row = iy * g.nx;
                polar.segmenter.query_row(&self.xs, y, |ix, bin| {
                    let c = row + ix;
                    // Selects again: coverage and evidence vary cell by cell. A void cell
                    // without ground points is observed, infinitely deep, and keeps no line.
                    let cell = &cells[c];
                    let void = (cell.ground_n == 0) & (bin.void | (cell.void_n > 0));
                    observed[c] = select_f32(bin.covered | void, 1.0, observed[c]);
                    let line_height = (bin.ground_z + s.z) as f32;
                    height[c] = select_f32(bin.covered & (cell.ground_n == 0) & !void, line_height, height[c]);
                    let below = (bin.ground_z - bin.floor_bound_z).max(0.0) as f32;
                    let below = select_f32(bin.floor_bound_z.is_finite(), below, depth[c]);
                    // In a drop's shadow the drop may begin anywhere: as deep as it gets.
                    let below = below.max(bin.shadow_depth as f32);
                    let below = select_f32(cell.ground_n > 0, depth[c], below);
                    depth[c] = select_f32(void, f32::INFINITY, below);
                });
            }
        }
    }

    /// Slope and residual of the plane through the ground heights under the window.
    #[inline(never)]
    pub(super) fn plane_fits(&mut self, g: &GridGeometry, map: &mut RiskMap) {
        let (nx, ny) = (g.nx, g.ny);
        let res = g.resolution_m;
        let w = nx + 1;
        let hw = self.plane_half;
        // The summed-area table, row r (0..=ny, row 0 all zeros) in slot r % slots: map row
        // iy reads rows iy - hw and iy + hw + 1 (clipped), so 2·hw + 2 slots hold every row
        // still needed.
        let slots = (2 * hw + 2).min(ny + 1);
        self.integral.clear();
        self.integral.resize(slots * w, [0.0; 10]);
        let min_cells = self.layers.plane_min_cells as f64;
        let Ok([_count, _ground_count, _ground_height, _min, _max, slope, residual, ..]) = <[&mut [f32]; 21]>::try_from(map.layers_mut()) else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        slope.fill(f32::NAN);
        residual.fill(f32::NAN);
        let height = &self.height[..nx * ny];
        let mut built = 0;
        for iy in 0..ny {
            let (y0, y1) = (iy.saturating_sub(hw), (iy + hw + 1).min(ny));
            while built < y1 {
                // Row built + 1 = row built + the running sums along map row `built`.
                let (a, b) = (built % slots, (built + 1) % slots);
                let (above, cur) = if a < b {
                    let (lo, hi) = self.integral.split_at_mut(b * w);
                    (&lo[a * w..(a + 1) * w], &mut hi[..w])
                } else {
                    let (lo, hi) = self.integral.split_at_mut(a * w);
                    (&hi[..w], &mut lo[b * w..(b + 1) * w])
                };
                let mut row = [0.0f64; 10];
                let y = built as f64 * res;
                for (ix, (&z, (cell, above))) in height[built * nx..(built + 1) * nx].iter().zip(cur[1..].iter_mut().zip(&above[1..])).enumerate() {
                    if z.is_finite() {
                        let (x, z) = (ix as f64 * res, z as f64);
                        let m = [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z];
                        for k in 0..10 {
                            row[k] += m[k];
                        }
                    }
                    for k in 0..10 {
                        cell[k] = above[k] + row[k];
                    }
                }
                built += 1;
            }
            let (top, bottom) = (&self.integral[(y0 % slots) * w..][..w], &self.integral[(y1 % slots) * w..][..w]);
            let hrow = &height[iy * nx..(iy + 1) * nx];
            for (ix, h) in hrow.iter().enumerate() {
                if !h.is_finite() {
                    continue;
                }
                let (x0, x1) = (ix.saturating_sub(hw), (ix + hw + 1).min(nx));
                let (a, b, cc, d) = (&bottom[x1], &top[x1], &bottom[x0], &top[x0]);
                let mut s = [0.0f64; 10];
                for k in 0..10 {
                    s[k] = a[k] - b[k] - cc[k] + d[k];
                }
                let n = s[0];
                if n < min_cells {
                    continue;
                }
                if let Some((grad, rms)) = fit_plane(&s, ix as f64 * res, iy as f64 * res) {
                    let c = iy * nx + ix;
                    slope[c] = grad.atan() as f32;
                    residual[c] = rms as f32;
                }
            }
        }
    }

    #[inline(never)]
    pub(super) fn steps(&mut self, g: &GridGeometry, map: &mut RiskMap) {
        let (nx, ny) = (g.nx, g.ny);
        let out = map.get_mut(Layer::StepHeight);
        let height = &self.height[..nx * ny];
        // max |H(n) - H(c)| over the 3x3 block clipped to the map, visited in the same
        // row-major order everywhere (the cell itself adds 0; NaN neighbours never compare
        // greater).
        let block = |ix: usize, iy: usize, h: f32| {
            let mut worst = 0.0f32;
            for jy in iy.saturating_sub(1)..(iy + 2).min(ny) {
                for jx in ix.saturating_sub(1)..(ix + 2).min(nx) {
                    let d = (height[jy * nx + jx] - h).abs();
                    if d > worst {
                        worst = d;
                    }
                }
            }
            worst
        };
        for iy in 0..ny {
            let row = iy * nx;
            if iy == 0 || iy + 1 == ny || nx < 3 {
                for ix in 0..nx {
                    let h = height[row + ix];
                    out[row + ix] = if h.is_finite() { block(ix, iy, h) } else { f32::NAN };
                }
                continue;
            }
            // Inner row: the three rows as slices, no clipping between the edge columns.
            let (above, mid, below) = (&height[row - nx..row], &height[row..row + nx], &height[row + nx..row + 2 * nx]);
            let out = &mut out[row..row + nx];
            for ix in [0, nx - 1] {
                let h = mid[ix];
                out[ix] = if h.is_finite() { block(ix, iy, h) } else { f32::NAN };
            }
            // Branch-free over the inner cells, so that the loop vectorises: every candidate
            // `|v - h|` is +0 or positive (abs), NaN ones never win, so the largest does
            // whatever the order, the same as the block order above; the cell itself (0) is
            // left out, and a cell without ground gives NaN.
            let m = nx - 2;
            let (a0, a1, a2) = (&above[..m], &above[1..m + 1], &above[2..m + 2]);
            let (m0, m1, m2) = (&mid[..m], &mid[1..m + 1], &mid[2..m + 2]);
            let (b0, b1, b2) = (&below[..m], &below[1..m + 1], &below[2..m + 2]);
            let out_inner = &mut out[1..m + 1];
            for i in 0..m {
                let h = m1[i];
                let mut worst = 0.0f32;
                for v in [a0[i], a1[i], a2[i], m0[i], m2[i], b0[i], b1[i], b2[i]] {
                    let d = (v - h).abs();
                    worst = if d > worst { d } else { worst };
                }
                out_inner[i] = if h.is_finite() { worst } else { f32::NAN };
            }
        }
    }
}

/// Below this eigenvalue ratio of the cells' spread, a window's cells count as collinear.
const COLLINEAR_RATIO: f64 = 1e-6;

/// Least-squares plane through window sums `s = [n, Σx, Σy, Σz, Σxx, Σxy, Σyy, Σxz, Σyz, Σzz]`,
/// centred at `(xc, yc)`; returns `(|∇z|, rms residual)`.
pub(super) fn fit_plane(s: &[f64; 10], xc: f64, yc: f64) -> Option<(f64, f64)> {
    let [n, sx, sy, sz, sxx, sxy, syy, sxz, syz, szz] = *s;
    let x = sx - n * xc;
    let y = sy - n * yc;
    let xx = sxx - 2.0 * xc * sx + n * xc * xc;
    let yy = syy - 2.0 * yc * sy + n * yc * yc;
    let xy = sxy - xc * sy - yc * sx + n * xc * yc;
    let xz = sxz - xc * sz;
    let yz = syz - yc * sz;
    // Normal equations [xx xy x; xy yy y; x y n] [a b c] = [xz yz sz], by Cramer's rule.
    let det = xx * (yy * n - y * y) - xy * (xy * n - y * x) + x * (xy * y - yy * x);
    // Collinear cells have no plane. The spread of the cells about their mean, `C`, has
    // `det C = det / n`; its eigenvalue ratio `λ_min/λ_max ≈ det C / (tr C)²` is >= ~1e-3 for
    // any non-collinear set of cells in a window (cells lie on a lattice) and ~1e-10 for
    // collinear ones (rounding of the window sums), so the test is scale-free. (Comparing
    // `det` with `xx·yy·n` instead passes on noise when the cells lie in one row or column:
    // `xx` or `yy` is then itself ~0. Regression test `collinear_ground_cells_have_no_plane`.)
    let trace = (xx - x * x / n) + (yy - y * y / n);
    if (det / n).partial_cmp(&(COLLINEAR_RATIO * trace * trace)).is_none_or(Ordering::is_le) {
        return None;
    }
    let a = (xz * (yy * n - y * y) - xy * (yz * n - y * sz) + x * (yz * y - yy * sz)) / det;
    let b = (xx * (yz * n - y * sz) - xz * (xy * n - y * x) + x * (xy * sz - yz * x)) / det;
    let c = (xx * (yy * sz - y * yz) - xy * (xy * sz - yz * x) + xz * (xy * y - yy * x)) / det;
    let sse = szz - a * xz - b * yz - c * sz;
    Some(((a * a + b * b).sqrt(), (sse.max(0.0) / n).sqrt()))
}
