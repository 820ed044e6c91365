//! The `tilt_angle` layer: how far the robot tilts when it settles on the highest ground
//! under its four wheel patches, worst over its rocking poses and headings (see the
//! parent module's doc).

use glam::DVec2;

use crate::terrain::config::RobotConfig;
use crate::terrain::grid::{GridGeometry, RiskMap};
use super::MapBuilder;

/// One settling triangle: corners `i, j, k` bear the body, the fourth is lifted.
#[derive(Debug, Clone, Copy)]
pub(super) struct Triangle {
    i: usize,
    j: usize,
    k: usize,
    /// `A⁻¹` with `A = [[p_j - p_i], [p_k - p_i]]` (rows), so `∇z = A⁻¹ [Δ_j, Δ_k]`.
    inv: [[f64; 2]; 2],
}

/// The footprint's four corner cells at one heading. Rounding is symmetric, so the corners
/// are `±u, ±v` (FL = -RR, FR = -RL): a parallelogram centred on the cell.
#[derive(Debug, Clone)]
pub(super) struct HeadingStencil {
    pub(super) offsets: [(i64, i64); 4],
    /// The triangle lifting each corner (index = the lifted corner); `None` if degenerate.
    pub(super) triangles: [Option<Triangle>; 4],
}

impl MapBuilder {
    #[inline(never)]
    pub(super) fn tilt(&mut self, g: &GridGeometry, map: &mut RiskMap) {
        let (nx, ny) = (g.nx, g.ny);
        let n = nx * ny;
        // Highest ground in the wheel patch around each cell (separable max, NaN ignored).
        let p = self.patch_half;
        self.patch_tmp.clear();
        self.patch_tmp.resize(n, f32::NAN);
        self.patch_max.clear();
        self.patch_max.resize(n, f32::NAN);
        // Row by row, offset by offset in increasing order: each cell folds the same values
        // in the same order as a per-cell loop would.
        let nan_max = |m: f32, v: f32| if v > m || m.is_nan() { v } else { m };
        for iy in 0..ny {
            let row = &self.height[iy * nx..(iy + 1) * nx];
            let tmp = &mut self.patch_tmp[iy * nx..(iy + 1) * nx];
            for d in -(p as isize)..=p as isize {
                // Cells ix with 0 <= ix + d < nx.
                let (lo, hi) = ((-d).max(0) as usize, (nx as isize - d).min(nx as isize).max(0) as usize);
                if lo >= hi {
                    continue;
                }
                let src = &row[(lo as isize + d) as usize..(hi as isize + d) as usize];
                for (m, &v) in tmp[lo..hi].iter_mut().zip(src) {
                    *m = nan_max(*m, v);
                }
            }
        }
        for iy in 0..ny {
            let out = &mut self.patch_max[iy * nx..(iy + 1) * nx];
            for jy in iy.saturating_sub(p)..(iy + p + 1).min(ny) {
                for (m, &v) in out.iter_mut().zip(&self.patch_tmp[jy * nx..(jy + 1) * nx]) {
                    *m = nan_max(*m, v);
                }
            }
        }
        let Ok([_count, _ground_count, _ground_height, _min, _max, slope, _residual, _step, _depth, out, ..]) = <[&mut [f32]; 21]>::try_from(map.layers_mut()) else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        // Cells at least `reach` from every edge have all their corners inside the map:
        // their corners are flat offsets from the cell, no bounds to test.
        let reach_x = self.stencils.iter().flat_map(|s| s.offsets).map(|(dx, _)| dx.unsigned_abs() as usize).max().unwrap_or(0);
        let reach_y = self.stencils.iter().flat_map(|s| s.offsets).map(|(_, dy)| dy.unsigned_abs() as usize).max().unwrap_or(0);
        // The patch maxima as f64 (NaN stays NaN), converted once instead of per corner.
        self.patch_f64.clear();
        self.patch_f64.extend(self.patch_max.iter().map(|&v| v as f64));
        let patch = &self.patch_f64[..n];
        let height = &self.height[..n];
        let (slope, out) = (&slope[..n], &mut out[..n]);
        // Per heading, its corner offsets in the flat layer and the two settling poses of
        // each diagonal, hoisted out of the cell loop.
        let headings: Vec<HeadingKernel> = self.stencils.iter().map(|s| HeadingKernel::new(s, nx)).collect();
        // The inner cells of a row: their worst tan² so far.
        let worst = &mut self.tilt_worst;
        let (x0, x1) = (reach_x.min(nx), nx.saturating_sub(reach_x).max(reach_x.min(nx)));
        for iy in 0..ny {
            let row = iy * nx;
            let inner = iy >= reach_y && iy + reach_y < ny && x0 < x1;
            // Near the edge (corners may be off the map): cell by cell. The whole row, or
            // the columns outside the inner span.
            let (edge_a, edge_b) = if inner { (0..x0, x1..nx) } else { (0..nx, nx..nx) };
            for ix in edge_a.chain(edge_b) {
                let c = row + ix;
                if !height[c].is_finite() {
                    out[c] = f32::NAN;
                    continue;
                }
                let mut worst_tan2 = -1.0f64;
                for stencil in &self.stencils {
                    if let Some(h) = corner_heights(&self.patch_max, nx, ny, ix, iy, &stencil.offsets) {
                        worst_tan2 = worst_tan2.max(settle_tan2(&stencil.triangles, &h));
                    }
                }
                out[c] = if worst_tan2 >= 0.0 { worst_tan2.sqrt().atan() as f32 } else { slope[c] };
            }
            if !inner {
                continue;
            }
            // Heading by heading over the row's inner cells: each cell still folds its
            // headings in order, with the same values.
            worst.clear();
            worst.resize(x1 - x0, -1.0);
            let has = &height[row + x0..row + x1];
            // Only the runs of cells with ground (a cell without keeps -1 and gets NaN
            // below): real scans leave long stretches without ground (out of range, behind
            // walls). Gaps shorter than `MIN_GAP` are settled with the runs, at less cost than
            // a call.
            const MIN_GAP: usize = 8;
            let runs = &mut self.tilt_runs;
            runs.clear();
            let mut at = 0;
            while let Some(a) = has[at..].iter().position(|h| h.is_finite()).map(|a| at + a) {
                let b = has[a..].iter().position(|h| !h.is_finite()).map_or(has.len(), |b| a + b);
                match runs.last_mut() {
                    Some(last) if a - last.1 < MIN_GAP => last.1 = b,
                    _ => runs.push((a, b)),
                }
                at = b;
            }
            for k in &headings {
                for &(a, b) in runs.iter() {
                    k.settle_row(patch, row + x0 + a, &has[a..b], &mut worst[a..b]);
                }
            }
            let (out_inner, slope_inner) = (&mut out[row + x0..row + x1], &slope[row + x0..row + x1]);
            for (i, &w) in worst.iter().enumerate() {
                out_inner[i] = if !has[i].is_finite() {
                    f32::NAN
                } else if w >= 0.0 {
                    w.sqrt().atan() as f32
                } else {
                    slope_inner[i]
                };
            }
        }
    }
}

/// One heading's settling, for cells whose four corners are inside the map: the corners'
/// flat offsets and the `A⁻¹` of the triangles [`settle_tan2`] uses.
struct HeadingKernel {
    offsets: [isize; 4],
    /// Triangles lifting corners 1, 2 (the body on FL-RR), then 0, 3 (on FR-RL).
    tri: [Option<[[f64; 2]; 2]>; 4],
}

impl HeadingKernel {
    fn new(s: &HeadingStencil, nx: usize) -> Self {
        let t = |o: usize| s.triangles[o].map(|t| t.inv);
        Self { offsets: s.offsets.map(|(dx, dy)| dy as isize * nx as isize + dx as isize), tri: [t(1), t(2), t(0), t(3)] }
    }

    /// For the cells `c = start..start + worst.len()` of one row whose four corners are inside
    /// the map: `worst[i] = max(worst[i], settle_tan2(corners))` where `has[i]` (the cell has
    /// ground) and all four corners have ground, as the per-cell loop does (`worst` starts
    /// at -1 and never holds NaN).
    #[inline(never)]
    fn settle_row(&self, patch: &[f64], start: usize, has: &[f32], worst: &mut [f64]) {
        let len = worst.len();
        let corner = |o: isize| &patch[(start as isize + o) as usize..][..len];
        let (s0, s1, s2, s3) = (corner(self.offsets[0]), corner(self.offsets[1]), corner(self.offsets[2]), corner(self.offsets[3]));
        let has = &has[..len];
        if let [Some(t0), Some(t1), Some(t2), Some(t3)] = self.tri {
            // `t0`, `t1` lift corners 1, 2 (the body on FL-RR), `t2`, `t3` lift 0, 3 (on FR-RL).
            // Both diagonals' poses are computed and the result selected, with no branch:
            // which diagonal bears the body, and which cells have ground, vary cell by cell
            // on real terrain, and those branches were mispredicted often. The selected
            // values are the ones the branches would have computed.
            for i in 0..len {
                let h = [s0[i], s1[i], s2[i], s3[i]];
                // Finite iff all four corners are (f32 values: the sum cannot overflow).
                let d = h[0] + h[3] - h[1] - h[2];
                let on_main = support(&t1, h[0], h[1], h[3], support(&t0, h[0], h[2], h[3], -1.0));
                let on_cross = support(&t3, h[0], h[1], h[2], support(&t2, h[1], h[2], h[3], -1.0));
                let tan2 = if d >= 0.0 { on_main } else { on_cross };
                let counts = has[i].is_finite() & d.is_finite() & (tan2 > worst[i]);
                worst[i] = if counts { tan2 } else { worst[i] };
            }
        } else {
            for i in 0..len {
                if !has[i].is_finite() {
                    continue;
                }
                let h = [s0[i], s1[i], s2[i], s3[i]];
                // Finite iff all four corners are (f32 values: the sum cannot overflow).
                let d = h[0] + h[3] - h[1] - h[2];
                if !d.is_finite() {
                    continue;
                }
                let tan2 = if d >= 0.0 {
                    let w = support_opt(&self.tri[0], h[0], h[2], h[3], -1.0);
                    support_opt(&self.tri[1], h[0], h[1], h[3], w)
                } else {
                    let w = support_opt(&self.tri[2], h[1], h[2], h[3], -1.0);
                    support_opt(&self.tri[3], h[0], h[1], h[2], w)
                };
                if tan2 > worst[i] {
                    worst[i] = tan2;
                }
            }
        }
    }
}

/// One settling pose of [`settle_tan2`]: the body on corners `i, j, k` (heights `hi, hj,
/// hk`), `worst` folded in as there.
#[inline(always)]
fn support(inv: &[[f64; 2]; 2], hi: f64, hj: f64, hk: f64, worst: f64) -> f64 {
    let (dj, dk) = (hj - hi, hk - hi);
    let gx = inv[0][0] * dj + inv[0][1] * dk;
    let gy = inv[1][0] * dj + inv[1][1] * dk;
    let tan2 = gx * gx + gy * gy;
    if tan2 > worst {
        tan2
    } else {
        worst
    }
}

#[inline(always)]
fn support_opt(t: &Option<[[f64; 2]; 2]>, hi: f64, hj: f64, hk: f64, worst: f64) -> f64 {
    match t {
        Some(inv) => support(inv, hi, hj, hk, worst),
        None => worst,
    }
}

/// The patch heights under the four corners at `offsets` from cell `(ix, iy)`; `None` if a
/// corner is off the map or has no ground.
fn corner_heights(patch_max: &[f32], nx: usize, ny: usize, ix: usize, iy: usize, offsets: &[(i64, i64); 4]) -> Option<[f64; 4]> {
    let mut h = [0.0f64; 4];
    for (corner, &(dx, dy)) in offsets.iter().enumerate() {
        let (jx, jy) = (ix as i64 + dx, iy as i64 + dy);
        if jx < 0 || jy < 0 || jx >= nx as i64 || jy >= ny as i64 {
            return None;
        }
        let v = patch_max[jy as usize * nx + jx as usize];
        if !v.is_finite() {
            return None;
        }
        h[corner] = v as f64;
    }
    Some(h)
}

/// The footprint corners at heading `yaw` as cell offsets, and the four settling triangles.
pub(super) fn heading_stencil(robot: &RobotConfig, res: f64, yaw: f64) -> HeadingStencil {
    let (a, b) = (robot.length_m / 2.0, robot.width_m / 2.0);
    let (s, c) = yaw.sin_cos();
    // Front-left, front-right, rear-left, rear-right.
    let corners = [(a, b), (a, -b), (-a, b), (-a, -b)];
    let offsets = corners.map(|(x, y)| (((c * x - s * y) / res).round() as i64, ((s * x + c * y) / res).round() as i64));
    let pos = offsets.map(|(i, j)| DVec2::new(i as f64 * res, j as f64 * res));
    debug_assert!(offsets[0] == (-offsets[3].0, -offsets[3].1) && offsets[1] == (-offsets[2].0, -offsets[2].1));
    let mut triangles = [None; 4];
    for (o, slot) in triangles.iter_mut().enumerate() {
        let rest: Vec<usize> = (0..4).filter(|&q| q != o).collect();
        let (i, j, k) = (rest[0], rest[1], rest[2]);
        let (dj, dk) = (pos[j] - pos[i], pos[k] - pos[i]);
        let det = dj.x * dk.y - dj.y * dk.x;
        if det.abs() < 1e-9 {
            continue;
        }
        // A = [[dj.x, dj.y], [dk.x, dk.y]]; ∇z solves A ∇z = [Δj, Δk].
        let inv = [[dk.y / det, -dj.y / det], [-dk.x / det, dj.x / det]];
        *slot = Some(Triangle { i, j, k, inv });
    }
    HeadingStencil { offsets, triangles }
}

/// The worst `tan²(tilt)` over the poses the body can rest in. On the parallelogram of
/// corners FL, FR, RL, RR (heights `h`), the body rests on the higher diagonal: with
/// `d = h_FL + h_RR - h_FR - h_RL >= 0` on FL-RR and either FR or RL (lifting RL or FR),
/// else on FR-RL and either FL or RR. Both poses of the pair are stable (it rocks).
pub(super) fn settle_tan2(triangles: &[Option<Triangle>; 4], h: &[f64; 4]) -> f64 {
    // The corners bearing the body when corner `o` is lifted are the other three in order
    // (see heading_stencil): spelled out per lifted corner so the indices are constants.
    #[inline(always)]
    fn support(t: &Option<Triangle>, h: &[f64; 4], i: usize, j: usize, k: usize, worst: f64) -> f64 {
        let Some(t) = t else { return worst };
        debug_assert!((t.i, t.j, t.k) == (i, j, k));
        let (dj, dk) = (h[j] - h[i], h[k] - h[i]);
        let gx = t.inv[0][0] * dj + t.inv[0][1] * dk;
        let gy = t.inv[1][0] * dj + t.inv[1][1] * dk;
        // Both finite and >= 0 (never -0), `worst` >= -1: the same as `worst.max(..)`.
        let tan2 = gx * gx + gy * gy;
        if tan2 > worst {
            tan2
        } else {
            worst
        }
    }
    let d = h[0] + h[3] - h[1] - h[2];
    if d >= 0.0 {
        // Lift RL (1) or FR (2): the body rests on FL-RR.
        let worst = support(&triangles[1], h, 0, 2, 3, -1.0);
        support(&triangles[2], h, 0, 1, 3, worst)
    } else {
        let worst = support(&triangles[0], h, 1, 2, 3, -1.0);
        support(&triangles[3], h, 0, 1, 2, worst)
    }
}
