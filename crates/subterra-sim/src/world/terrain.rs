//! The terrain: the height field in f64 ([`Terrain`]) and its parry shape, the walk of a ray
//! over its height pyramid and cells ([`TerrainRay`], [`walk_grid`]), and the culling of many
//! rays from one origin ([`TerrainView`], [`SlopeRange`]).

use glam::DVec3;
use parry3d::math::Vector;
use parry3d::query::PointQuery;
use parry3d::shape::{HeightField, HeightFieldCellStatus};
use parry3d::utils::Array2;

use crate::spec::HeightFieldSpec;

use super::leaf::LeafHit;
use super::PrimitiveId;

/// Terrain: the spec's grid (holes filled) in f64, and the parry height field built from it.
#[derive(Debug, Clone)]
pub(super) struct Terrain {
    pub(super) id: PrimitiveId,
    pub(super) origin: [f64; 2],
    pub(super) resolution: f64,
    pub(super) rows: usize,
    pub(super) cols: usize,
    /// `heights[r * cols + c]`, spec order, holes replaced by a neighbour's height.
    heights: Vec<f64>,
    /// `removed[r * (cols - 1) + c]`: spec cell (r, c) touches a hole.
    removed: Vec<bool>,
    pub(super) any_cell: bool,
    /// Parry height field; local frame: x = world x, y = world z, z = -world y, centred at
    /// `centre` (world x, y of the grid's middle, z = 0).
    shape: HeightField,
    centre: [f64; 2],
    pub(super) min_z: f64,
    pub(super) max_z: f64,
    /// Bounds of the grid (x, y) and of its heights (z) [m].
    pub(super) lo: DVec3,
    pub(super) hi: DVec3,
    /// Height pyramid, finest first: level `l` has blocks of `TERRAIN_BLOCK^(l + 1)` cells a side.
    levels: Vec<TerrainLevel>,
    /// Height range of each cell, widened (beyond `z_range_meets`'s margin and the f32
    /// rounding), `[r * (cols - 1) + c]`; empty (`lo > hi`) for a removed cell.
    cell_z: Vec<SlopeRange>,
}

/// One level of the terrain's height pyramid.
#[derive(Debug, Clone)]
struct TerrainLevel {
    /// Blocks along x and y.
    nx: usize,
    ny: usize,
    /// Block side [m].
    size: f64,
    /// Lowest and highest vertex height of each block's cells that are not removed
    /// (`(+inf, -inf)` when all are), `[by * nx + bx]`.
    z: Vec<(f64, f64)>,
}

/// Children per side of a block of the terrain's height pyramid.
const TERRAIN_BLOCK: usize = 4;
/// Levels of the terrain's height pyramid (blocks of 4, 16, 64 cells a side).
const TERRAIN_LEVELS: usize = 3;

impl Terrain {
    pub(super) fn new(spec: &HeightFieldSpec, id: PrimitiveId) -> Terrain {
        let rows = spec.heights.len();
        let cols = spec.heights.first().map_or(0, Vec::len);
        let is_hole = |h: f64| h.is_nan() || spec.hole_value.is_some_and(|v| h == v);
        let mut heights = vec![0.0; rows * cols];
        let mut known = vec![false; rows * cols];
        let mut queue = std::collections::VecDeque::new();
        for (r, row) in spec.heights.iter().enumerate() {
            for (c, &h) in row.iter().enumerate() {
                if !is_hole(h) {
                    heights[r * cols + c] = h;
                    known[r * cols + c] = true;
                    queue.push_back((r, c));
                }
            }
        }
        let hole: Vec<bool> = known.iter().map(|k| !k).collect();
        // Fill holes with the height of the nearest known sample (breadth first), so the
        // field stays finite; the cells around them are removed below.
        while let Some((r, c)) = queue.pop_front() {
            let h = heights[r * cols + c];
            let neighbours = [(r.wrapping_sub(1), c), (r + 1, c), (r, c.wrapping_sub(1)), (r, c + 1)];
            for (nr, nc) in neighbours {
                if nr < rows && nc < cols && !known[nr * cols + nc] {
                    known[nr * cols + nc] = true;
                    heights[nr * cols + nc] = h;
                    queue.push_back((nr, nc));
                }
            }
        }
        let mut removed = vec![false; (rows - 1) * (cols - 1)];
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                removed[r * (cols - 1) + c] =
                    hole[r * cols + c] || hole[r * cols + c + 1] || hole[(r + 1) * cols + c] || hole[(r + 1) * cols + c + 1];
            }
        }
        let res = spec.resolution;
        let size_x = (cols - 1) as f64 * res;
        let size_y = (rows - 1) as f64 * res;
        // Parry: row i runs along local z = -world y, so parry row i is spec row rows-1-i.
        let field = Array2::from_fn(rows, cols, |i, j| heights[(rows - 1 - i) * cols + j] as f32);
        let mut shape = HeightField::new(field, Vector::new(size_x as f32, 1.0, size_y as f32));
        for r in 0..rows - 1 {
            for c in 0..cols - 1 {
                if removed[r * (cols - 1) + c] {
                    shape.set_cell_status(rows - 2 - r, c, HeightFieldCellStatus::CELL_REMOVED);
                }
            }
        }
        let (min_z, max_z) = heights.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &h| (lo.min(h), hi.max(h)));
        let (cells_x, cells_y) = (cols - 1, rows - 1);
        let mut levels: Vec<TerrainLevel> = Vec::with_capacity(TERRAIN_LEVELS);
        let (mut span, mut size) = (1usize, res);
        for _ in 0..TERRAIN_LEVELS {
            span *= TERRAIN_BLOCK;
            size *= TERRAIN_BLOCK as f64;
            let (nx, ny) = (cells_x.div_ceil(span), cells_y.div_ceil(span));
            let mut z = vec![(f64::INFINITY, f64::NEG_INFINITY); nx * ny];
            for r in 0..cells_y {
                for c in 0..cells_x {
                    if removed[r * cells_x + c] {
                        continue;
                    }
                    let b = &mut z[(r / span) * nx + c / span];
                    for h in [heights[r * cols + c], heights[r * cols + c + 1], heights[(r + 1) * cols + c], heights[(r + 1) * cols + c + 1]] {
                        b.0 = b.0.min(h);
                        b.1 = b.1.max(h);
                    }
                }
            }
            levels.push(TerrainLevel { nx, ny, size, z });
        }
        let cell_z = (0..cells_y * cells_x)
            .map(|i| {
                let (r, c) = (i / cells_x, i % cells_x);
                if removed[i] {
                    return SlopeRange::EMPTY;
                }
                let h = [heights[r * cols + c], heights[r * cols + c + 1], heights[(r + 1) * cols + c], heights[(r + 1) * cols + c + 1]];
                let (lo, hi) = h.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &z| (a.min(z), b.max(z)));
                SlopeRange::outward(lo, hi)
            })
            .collect();
        let lo = DVec3::new(spec.origin[0], spec.origin[1], min_z);
        let hi = DVec3::new(spec.origin[0] + size_x, spec.origin[1] + size_y, max_z);
        Terrain {
            lo,
            hi,
            levels,
            cell_z,
            id,
            origin: spec.origin,
            resolution: res,
            rows,
            cols,
            heights,
            any_cell: removed.iter().any(|r| !r),
            removed,
            shape,
            centre: [spec.origin[0] + 0.5 * size_x, spec.origin[1] + 0.5 * size_y],
            min_z,
            max_z,
        }
    }

    fn h(&self, r: usize, c: usize) -> f64 {
        self.heights[r * self.cols + c]
    }

    fn to_local(&self, p: DVec3) -> Vector {
        Vector::new((p.x - self.centre[0]) as f32, p.z as f32, (self.centre[1] - p.y) as f32)
    }

    pub(super) fn covers(&self, x: f64, y: f64) -> bool {
        let fx = (x - self.origin[0]) / self.resolution;
        let fy = (y - self.origin[1]) / self.resolution;
        (0.0..=(self.cols - 1) as f64).contains(&fx) && (0.0..=(self.rows - 1) as f64).contains(&fy)
    }

    /// Surface height at a covered `(x, y)`, on parry's triangulation: cell (r, c) is split
    /// along the diagonal from sample (r, c) to (r + 1, c + 1).
    pub(super) fn height_at(&self, x: f64, y: f64) -> Option<f64> {
        let fx = (x - self.origin[0]) / self.resolution;
        let fy = (y - self.origin[1]) / self.resolution;
        let c = (fx.floor().max(0.0) as usize).min(self.cols - 2);
        let r = (fy.floor().max(0.0) as usize).min(self.rows - 2);
        if *self.removed.get(r * (self.cols - 1) + c)? {
            return None;
        }
        let u = fx - c as f64; // along x
        let v = fy - r as f64; // along y
        let (h00, h10, h01, h11) = (self.h(r, c), self.h(r, c + 1), self.h(r + 1, c), self.h(r + 1, c + 1));
        Some(if u <= v {
            // Triangle (r, c), (r + 1, c), (r + 1, c + 1).
            h00 + v * (h01 - h00) + u * (h11 - h01)
        } else {
            // Triangle (r, c), (r, c + 1), (r + 1, c + 1).
            h00 + u * (h10 - h00) + v * (h11 - h10)
        })
    }

    /// Ray against the surface (seen from both sides), `t <= max_t`, exact in f64 on the same
    /// triangles as [`Terrain::height_at`]. The ray is clipped to the grid's box, then walks
    /// the blocks it crosses, skipping those whose height range it passes above or below,
    /// and inside the others the cells likewise; only cells it may meet are tested.
    pub(super) fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
        let (t0, t1) = self.clip(o, d, max_t)?;
        let hit = self.walk(o, d, t0, t1)?;
        (hit.t <= max_t).then_some(hit)
    }

    /// [`Terrain::cast`] from `view`'s origin `o`: the same answer, walking only the stretches
    /// of the ray where `view` says the terrain may be met. The normal only when `NORMALS`
    /// (else zero), except for the (nearly) vertical rays it hands to [`Terrain::cast`].
    ///
    /// The quick refusals (a slope no terrain point has) are inlined into the caller; the walk
    /// ([`Terrain::walk_view`]) is not, so that the many rays it refuses (a lidar's upward
    /// beams) skip its call and set-up.
    #[inline(always)]
    pub(super) fn cast_in_view<const NORMALS: bool>(&self, view: &TerrainView, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
        let dxy = (d.x * d.x + d.y * d.y).sqrt();
        if dxy.is_nan() || dxy <= TERRAIN_VIEW_MIN_DXY {
            // (Nearly) vertical: the walk is short.
            return self.cast(o, d, max_t);
        }
        if !self.any_cell {
            return None;
        }
        let k = d.z / dxy;
        // Slopes no terrain point seen from the origin has (anywhere, then in the sector):
        // no walk.
        if !view.all.admits(k) {
            return None;
        }
        let sector = sector_of(pseudo_angle(d.x, d.y));
        if !view.tail.get(sector * view.groups).is_some_and(|r| r.admits(k)) {
            return None;
        }
        self.walk_view::<NORMALS>(view, o, d, max_t, dxy, k, sector)
    }

    /// The walk of [`Terrain::cast_in_view`] for a ray of horizontal length `dxy`, slope `k`
    /// in sector `sector` of the view.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn walk_view<const NORMALS: bool>(&self, view: &TerrainView, o: DVec3, d: DVec3, max_t: f64, dxy: f64, k: f64, sector: usize) -> Option<LeafHit> {
        // The view's bins hold the grid: no clipping to its box needed.
        let (t0, t1) = (0.0, max_t);
        let (row, group, tail) = view.row(sector);
        let scale = view.inv_w * dxy;
        let last = row.len() - 1;
        let j1 = if t1 * scale < index_f64(last) { index_of(t1 * scale) } else { last };
        let mut ray: Option<TerrainRay> = None;
        let mut j = 0;
        while j <= j1 {
            let g = j / TERRAIN_VIEW_GROUP;
            if !tail[g].admits(k) {
                return None;
            }
            if !group[g].admits(k) {
                j = (g + 1) * TERRAIN_VIEW_GROUP;
                continue;
            }
            // Within the group (whose tail and union admit `k`): on to its first bin that does.
            let end = ((g + 1) * TERRAIN_VIEW_GROUP).min(j1 + 1);
            while j < end && !row[j].admits(k) {
                j += 1;
            }
            if j == end {
                continue;
            }
            let ja = j;
            while j < j1 && row[j + 1].admits(k) {
                j += 1;
            }
            // Bins ja..=j, widened by a hair, within [t0, t1].
            let ta = ((index_f64(ja) / scale) * (1.0 - 1.0e-9) - 1.0e-9).max(t0);
            let tb = ((index_f64(j + 1) / scale) * (1.0 + 1.0e-9) + 1.0e-9).min(t1);
            if ta <= tb {
                let ray = ray.get_or_insert_with(|| TerrainRay::new(self, o, d));
                if let Some(hit) = self.walk_cells::<NORMALS>(ray, ta, tb) {
                    return (hit.t <= max_t).then_some(hit);
                }
            }
            j += 1;
        }
        None
    }

    /// The ray's part `[t0, t1]` (`t0 >= 0`, `t1 <= max_t`) inside the grid's box (widened by
    /// a hair); `None` when it misses the box or there is no cell.
    #[inline]
    fn clip(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<(f64, f64)> {
        if !self.any_cell {
            return None;
        }
        // Clip to the box, widened by a hair.
        let (mut t0, mut t1) = (0.0f64, max_t);
        for k in 0..3 {
            let pad = 1.0e-9 * (1.0 + self.lo[k].abs().max(self.hi[k].abs()));
            let (lo, hi) = (self.lo[k] - pad, self.hi[k] + pad);
            if d[k] == 0.0 {
                if o[k] < lo || o[k] > hi {
                    return None;
                }
                continue;
            }
            let (a, b) = ((lo - o[k]) / d[k], (hi - o[k]) / d[k]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        if t0.is_nan() || t1.is_nan() || t0 > t1 {
            return None;
        }
        Some((t0, t1))
    }

    /// The first hit of the ray over `[t0, t1]`, walking the pyramid from the top.
    #[inline]
    fn walk(&self, o: DVec3, d: DVec3, t0: f64, t1: f64) -> Option<LeafHit> {
        self.walk_ray(&TerrainRay::new(self, o, d), t0, t1)
    }

    /// [`Terrain::walk`] of a prepared ray.
    #[inline]
    fn walk_ray(&self, ray: &TerrainRay, t0: f64, t1: f64) -> Option<LeafHit> {
        let top = self.levels.len() - 1;
        let level = &self.levels[top];
        self.walk_level(ray, top, (0, level.nx), (0, level.ny), t0, t1)
    }

    /// The first hit of the ray over `[t0, t1]`, walking the cells (no pyramid): for short
    /// stretches near the surface.
    #[inline]
    fn walk_cells<const NORMALS: bool>(&self, ray: &TerrainRay, t0: f64, t1: f64) -> Option<LeafHit> {
        let (cells_x, cells_y) = (self.cols - 1, self.rows - 1);
        let (oz, dz) = (ray.o.z, ray.d.z);
        walk_grid(ray, self.resolution, (0, cells_x), (0, cells_y), t0, t1, |c, r, ta, tb| {
            // A quick, looser test than `cast_cell`'s own (which follows); removed cells fail it.
            let z = self.cell_z[r * cells_x + c];
            let (za, zb) = (oz + dz * ta, oz + dz * tb);
            let (lo, hi) = if za <= zb { (za, zb) } else { (zb, za) };
            if hi < f64::from(z.lo) || lo > f64::from(z.hi) {
                return None;
            }
            self.cast_cell_ray::<NORMALS>(ray, r, c, ta, tb)
        })
    }

    /// Walks the blocks of pyramid level `level` in the index ranges given, over `[ta, tb]`,
    /// descending into those whose height range the ray meets; the first hit found ends it.
    #[allow(clippy::too_many_arguments)]
    fn walk_level(&self, ray: &TerrainRay, level: usize, i_range: (usize, usize), j_range: (usize, usize), ta: f64, tb: f64) -> Option<LeafHit> {
        let l = &self.levels[level];
        let (o, d) = (ray.o, ray.d);
        walk_grid(ray, l.size, i_range, j_range, ta, tb, |bx, by, ta, tb| {
            let (zlo, zhi) = l.z[by * l.nx + bx];
            if !z_range_meets(o.z, d.z, ta, tb, zlo, zhi) {
                return None;
            }
            if level == 0 {
                let (cells_x, cells_y) = (self.cols - 1, self.rows - 1);
                let i_range = (bx * TERRAIN_BLOCK, ((bx + 1) * TERRAIN_BLOCK).min(cells_x));
                let j_range = (by * TERRAIN_BLOCK, ((by + 1) * TERRAIN_BLOCK).min(cells_y));
                walk_grid(ray, self.resolution, i_range, j_range, ta, tb, |c, r, ta, tb| {
                    if self.removed[r * cells_x + c] {
                        return None;
                    }
                    self.cast_cell_ray::<true>(ray, r, c, ta, tb)
                })
            } else {
                let child = &self.levels[level - 1];
                let i_range = (bx * TERRAIN_BLOCK, ((bx + 1) * TERRAIN_BLOCK).min(child.nx));
                let j_range = (by * TERRAIN_BLOCK, ((by + 1) * TERRAIN_BLOCK).min(child.ny));
                self.walk_level(ray, level - 1, i_range, j_range, ta, tb)
            }
        })
    }

    /// Ray against the two triangles of cell (r, c), whose part of the ray is `[ta, tb]`.
    #[cfg(test)]
    fn cast_cell(&self, o: DVec3, d: DVec3, r: usize, c: usize, ta: f64, tb: f64) -> Option<LeafHit> {
        self.cast_cell_ray::<true>(&TerrainRay::new(self, o, d), r, c, ta, tb)
    }

    /// [`Terrain::cast_cell`] of a prepared ray; the normal only when `NORMALS` (else zero:
    /// a lidar needs none).
    #[inline]
    fn cast_cell_ray<const NORMALS: bool>(&self, ray: &TerrainRay, r: usize, c: usize, ta: f64, tb: f64) -> Option<LeafHit> {
        let (o, d) = (ray.o, ray.d);
        let at = r * self.cols + c;
        let (h00, h10, h01, h11) = (self.heights[at], self.heights[at + 1], self.heights[at + self.cols], self.heights[at + self.cols + 1]);
        // Heights are finite (holes are filled): plain comparisons give `min` / `max`.
        let lo = |a: f64, b: f64| if b < a { b } else { a };
        let hi = |a: f64, b: f64| if b > a { b } else { a };
        if !z_range_meets(o.z, d.z, ta, tb, lo(lo(h00, h10), lo(h01, h11)), hi(hi(h00, h10), hi(h01, h11))) {
            return None;
        }
        // Cell coordinates: u along x, v along y, both in [0, 1] over the cell.
        let res = self.resolution;
        let (ou, ov) = (ray.gu - c as f64, ray.gv - r as f64);
        let (du, dv) = (ray.du, ray.dv);
        // Triangle A (u <= v): z = h00 + u (h11 - h01) + v (h01 - h00); B (u > v):
        // z = h00 + u (h10 - h00) + v (h11 - h10). A hit on the ray where z_ray = z_plane.
        const EDGE: f64 = 1.0e-12;
        // (t, gu, gv) of the nearest hit; its normal is worked out once, at the end.
        let mut best: Option<(f64, f64, f64)> = None;
        for (gu, gv, in_triangle) in [(h11 - h01, h01 - h00, true), (h10 - h00, h11 - h10, false)] {
            let g0 = o.z - (h00 + ou * gu + ov * gv);
            let g1 = d.z - (du * gu + dv * gv);
            if g1 == 0.0 {
                continue;
            }
            let t = -g0 / g1;
            if t.is_nan() || t < 0.0 || best.is_some_and(|b| b.0 <= t) {
                continue;
            }
            let (u, v) = (ou + du * t, ov + dv * t);
            let inside = if in_triangle {
                u >= -EDGE && v <= 1.0 + EDGE && u <= v + EDGE
            } else {
                v >= -EDGE && u <= 1.0 + EDGE && v <= u + EDGE
            };
            if inside {
                best = Some((t, gu, gv));
            }
        }
        best.map(|(t, gu, gv)| LeafHit { t, normal: if NORMALS { DVec3::new(-gu / res, -gv / res, 1.0).normalize() } else { DVec3::ZERO } })
    }

    /// Distance to the surface, negative below it where it covers `p` (not over a hole).
    pub(super) fn clearance(&self, p: DVec3) -> Option<f64> {
        if !self.any_cell {
            return None;
        }
        let d = f64::from(self.shape.distance_to_local_point(self.to_local(p), true));
        let below = self.covers(p.x, p.y) && self.height_at(p.x, p.y).is_some_and(|h| p.z < h);
        Some(if below { -d } else { d })
    }
}

/// Fans of at least this many rays cull the terrain through a [`TerrainView`].
pub(super) const TERRAIN_VIEW_MIN_RAYS: usize = 2048;
/// Azimuth sectors of a [`TerrainView`].
const TERRAIN_VIEW_SECTORS: usize = 256;
/// Most distance bins of a [`TerrainView`] (a sector's row).
const TERRAIN_VIEW_MAX_BINS: usize = 512;
/// Rays whose horizontal part `hypot(d.x, d.y)` is below this walk the terrain without the view.
const TERRAIN_VIEW_MIN_DXY: f64 = 1.0e-6;
/// Bins of a [`TerrainView`] summarised together (to skip them at once).
const TERRAIN_VIEW_GROUP: usize = 8;
/// Most bins a pyramid block spans for which a [`TerrainView`] works out slopes bin by bin
/// (more: the block's slopes in each).
const TERRAIN_VIEW_BLOCK_BINS: usize = 8;
/// Relative widening of a bin's distances when a [`TerrainView`] works out a block's slopes
/// in it (a ray's bin bounds are widened by 1e-9 relative and absolute).
const TERRAIN_VIEW_BIN_PAD: f64 = 1.0e-6;

/// The terrain as seen from one origin `o`, for culling many rays from there: around `o`,
/// azimuth sectors (of a pseudo-angle) by bins of horizontal distance `r`, each with the
/// range of slopes `(z - o.z) / r` of the terrain points it holds (through the boxes of the
/// pyramid's finest blocks, rounded outward). A ray from `o` stays in one sector, with a
/// fixed slope `d.z / hypot(d.x, d.y)`: it may meet the terrain only in the bins whose slope
/// range holds its own, and walks only those.
#[derive(Debug, Clone)]
pub(super) struct TerrainView {
    /// Bins per sector.
    bins: usize,
    /// 1 / bin width [1/m].
    inv_w: f64,
    /// `[sector * bins + bin]`.
    slopes: Vec<SlopeRange>,
    /// Groups per sector (`bins.div_ceil(TERRAIN_VIEW_GROUP)`).
    groups: usize,
    /// Union of each group of `TERRAIN_VIEW_GROUP` bins, `[sector * groups + group]`.
    group: Vec<SlopeRange>,
    /// Union of the bins from each group's first on, `[sector * groups + group]`.
    tail: Vec<SlopeRange>,
    /// Union of all bins.
    all: SlopeRange,
}

/// Range of slopes of a bin of a [`TerrainView`]; empty (`lo > hi`) when it holds no terrain.
#[derive(Debug, Clone, Copy)]
struct SlopeRange {
    lo: f32,
    hi: f32,
}

impl SlopeRange {
    const EMPTY: SlopeRange = SlopeRange { lo: f32::INFINITY, hi: f32::NEG_INFINITY };

    /// `[lo, hi]` widened by more than 1e-9 and the f32 rounding.
    fn outward(lo: f64, hi: f64) -> SlopeRange {
        SlopeRange { lo: (lo - 1.0e-6 * (1.0 + lo.abs())) as f32, hi: (hi + 1.0e-6 * (1.0 + hi.abs())) as f32 }
    }

    fn union(self, other: SlopeRange) -> SlopeRange {
        SlopeRange { lo: self.lo.min(other.lo), hi: self.hi.max(other.hi) }
    }

    #[inline(always)]
    fn admits(self, k: f64) -> bool {
        f64::from(self.lo) <= k && k <= f64::from(self.hi)
    }
}

/// Pseudo-angle of the direction `(x, y)` in `[0, 4]`: monotonic in the angle from +x toward
/// +y over `[0, 2π)` (0 for a zero vector).
#[inline(always)]
fn pseudo_angle(x: f64, y: f64) -> f64 {
    let s = x.abs() + y.abs();
    if s.is_nan() || s <= 0.0 {
        return 0.0;
    }
    let a = x / s;
    if y >= 0.0 {
        1.0 - a
    } else {
        3.0 + a
    }
}

fn sector_of(pa: f64) -> usize {
    index_of(pa * (TERRAIN_VIEW_SECTORS as f64 / 4.0)).min(TERRAIN_VIEW_SECTORS - 1)
}

impl TerrainView {
    pub(super) fn new(t: &Terrain, o: DVec3) -> TerrainView {
        let level = &t.levels[0];
        let size = level.size;
        let (ox, oy) = (o.x - t.origin[0], o.y - t.origin[1]);
        // Farthest corner of the grid (blocks may overhang it: use theirs).
        let (gx, gy) = (level.nx as f64 * size, level.ny as f64 * size);
        let far = ox.abs().max((gx - ox).abs()).hypot(oy.abs().max((gy - oy).abs()));
        let mut w = size;
        if far / w >= TERRAIN_VIEW_MAX_BINS as f64 - 2.0 {
            w = far / (TERRAIN_VIEW_MAX_BINS as f64 - 2.0);
        }
        let bins = ((far / w) as usize + 2).min(TERRAIN_VIEW_MAX_BINS);
        let inv_w = 1.0 / w;
        let mut view = TerrainView { bins, inv_w, slopes: vec![SlopeRange::EMPTY; TERRAIN_VIEW_SECTORS * bins], groups: 0, group: Vec::new(), tail: Vec::new(), all: SlopeRange::EMPTY };
        let pad = |x: f64| 1.0e-9 * (1.0 + x.abs());
        // Per corner of the blocks (`[cy * (nx + 1) + cx]`), relative to `o`: its pseudo-angle
        // and distance (each shared by up to four blocks).
        let corner_count = (level.nx + 1) * (level.ny + 1);
        let (mut corner_angle, mut corner_distance) = (Vec::with_capacity(corner_count), Vec::with_capacity(corner_count));
        for cy in 0..=level.ny {
            let y = index_f64(cy) * size - oy;
            for cx in 0..=level.nx {
                let x = index_f64(cx) * size - ox;
                corner_angle.push(pseudo_angle(x, y));
                corner_distance.push((x * x + y * y).sqrt());
            }
        }
        for by in 0..level.ny {
            for bx in 0..level.nx {
                let (zlo, zhi) = level.z[by * level.nx + bx];
                if zlo > zhi {
                    continue;
                }
                let (zlo, zhi) = (zlo - pad(zlo) - o.z, zhi + pad(zhi) - o.z);
                // The block's square relative to `o`, and the indices of its corners (in the
                // order of `corners` below).
                let (x0, x1) = (index_f64(bx) * size - ox, index_f64(bx + 1) * size - ox);
                let (y0, y1) = (index_f64(by) * size - oy, index_f64(by + 1) * size - oy);
                let c00 = by * (level.nx + 1) + bx;
                let at = [c00, c00 + 1, c00 + level.nx + 1, c00 + level.nx + 2];
                let dx = if x0 > 0.0 { x0 } else if x1 < 0.0 { -x1 } else { 0.0 };
                let dy = if y0 > 0.0 { y0 } else if y1 < 0.0 { -y1 } else { 0.0 };
                // Nearest point: a corner when beside the block along both axes, else on an
                // edge (`dx` or `dy` away). Farthest: a corner. Widened by far more than the
                // rounding of the square roots.
                let nearest = if dx > 0.0 && dy > 0.0 { at.iter().fold(f64::INFINITY, |m, &c| m.min(corner_distance[c])) } else { dx + dy };
                let farthest = at.iter().fold(0.0f64, |m, &c| m.max(corner_distance[c]));
                let rmin = (nearest * (1.0 - 1.0e-9) - 1.0e-9).max(0.0);
                let rmax = farthest * (1.0 + 1.0e-9) + 1.0e-9;
                // Slopes (z - o.z) / r over the block's part at distances [r0, r1]: the
                // extremes at r0 or r1.
                let slopes = |r0: f64, r1: f64| {
                    let hi = if zhi >= 0.0 {
                        if r0 > 0.0 { zhi / r0 } else { f64::INFINITY }
                    } else {
                        zhi / r1
                    };
                    let lo = if zlo <= 0.0 {
                        if r0 > 0.0 { zlo / r0 } else { f64::NEG_INFINITY }
                    } else {
                        zlo / r1
                    };
                    SlopeRange::outward(lo, hi)
                };
                let (j0, j1) = (((rmin * inv_w) as usize).min(bins - 1), ((rmax * inv_w) as usize).min(bins - 1));
                // Each bin gets the slopes of the block's part within it (its distances widened
                // by more than the rounding of a ray's bin bounds; the last bin holds all beyond).
                let mut ranges = [SlopeRange::EMPTY; TERRAIN_VIEW_BLOCK_BINS];
                let per_bin = j1 - j0 < TERRAIN_VIEW_BLOCK_BINS;
                if per_bin {
                    for (j, range) in (j0..=j1).zip(&mut ranges) {
                        let r0 = if j == j0 { rmin } else { rmin.max(j as f64 * w * (1.0 - TERRAIN_VIEW_BIN_PAD)) };
                        let r1 = if j == j1 { rmax } else { rmax.min((j + 1) as f64 * w * (1.0 + TERRAIN_VIEW_BIN_PAD)) };
                        *range = slopes(r0, r1);
                    }
                }
                let whole = slopes(rmin, rmax);
                let mut mark = |s0: usize, s1: usize| {
                    for s in s0..=s1 {
                        for (k, b) in view.slopes[s * bins + j0..=s * bins + j1].iter_mut().enumerate() {
                            let range = if per_bin { ranges[k] } else { whole };
                            // What `min` / `max` give (`b` is never NaN; a NaN bound leaves
                            // it), as plain selects.
                            if range.lo < b.lo {
                                b.lo = range.lo;
                            }
                            if range.hi > b.hi {
                                b.hi = range.hi;
                            }
                        }
                    }
                };
                if x0 <= 0.0 && x1 >= 0.0 && y0 <= 0.0 && y1 >= 0.0 {
                    // `o` is over the block: every direction.
                    mark(0, TERRAIN_VIEW_SECTORS - 1);
                    continue;
                }
                let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)];
                const EPS: f64 = 1.0e-9;
                if y0 < 0.0 && y1 >= 0.0 && x0 > 0.0 {
                    // Across the +x axis, where the pseudo-angle wraps from 4 to 0.
                    let below = corners.iter().zip(at).filter(|(c, _)| c.1 < 0.0).fold(4.0f64, |a, (_, i)| a.min(corner_angle[i]));
                    let above = corners.iter().zip(at).filter(|(c, _)| c.1 >= 0.0).fold(0.0f64, |a, (_, i)| a.max(corner_angle[i]));
                    mark(sector_of((below - EPS).max(0.0)), TERRAIN_VIEW_SECTORS - 1);
                    mark(0, sector_of(above + EPS));
                } else {
                    let (a, b) = at.iter().fold((4.0f64, 0.0f64), |(a, b), &i| (a.min(corner_angle[i]), b.max(corner_angle[i])));
                    let (a, b) = (a - EPS, b + EPS);
                    mark(sector_of(a.max(0.0)), sector_of(b));
                    // Next to the wrap, a hair on the other side.
                    if a < 0.0 {
                        mark(TERRAIN_VIEW_SECTORS - 1, TERRAIN_VIEW_SECTORS - 1);
                    }
                    if b >= 4.0 {
                        mark(0, 0);
                    }
                }
            }
        }
        let groups = bins.div_ceil(TERRAIN_VIEW_GROUP);
        view.groups = groups;
        view.group = vec![SlopeRange::EMPTY; TERRAIN_VIEW_SECTORS * groups];
        view.tail = vec![SlopeRange::EMPTY; TERRAIN_VIEW_SECTORS * groups];
        for s in 0..TERRAIN_VIEW_SECTORS {
            let row = &view.slopes[s * bins..(s + 1) * bins];
            for (g, chunk) in row.chunks(TERRAIN_VIEW_GROUP).enumerate() {
                view.group[s * groups + g] = chunk.iter().fold(SlopeRange::EMPTY, |a, b| a.union(*b));
            }
            let mut acc = SlopeRange::EMPTY;
            for g in (0..groups).rev() {
                acc = acc.union(view.group[s * groups + g]);
                view.tail[s * groups + g] = acc;
            }
            view.all = view.all.union(acc);
        }
        view
    }

    /// The bins, groups and tails of sector `s`.
    #[inline]
    fn row(&self, s: usize) -> (&[SlopeRange], &[SlopeRange], &[SlopeRange]) {
        let g = s * self.groups..(s + 1) * self.groups;
        (&self.slopes[s * self.bins..(s + 1) * self.bins], &self.group[g.clone()], &self.tail[g])
    }
}

/// Whether the ray's height over `[ta, tb]` meets `[zlo, zhi]` (widened by a hair).
#[inline]
fn z_range_meets(oz: f64, dz: f64, ta: f64, tb: f64, zlo: f64, zhi: f64) -> bool {
    let (za, zb) = (oz + dz * ta, oz + dz * tb);
    let pad = 1.0e-9 * (1.0 + zlo.abs().max(zhi.abs()));
    za.max(zb) >= zlo - pad && za.min(zb) <= zhi + pad
}

/// A ray against the terrain, with the terms its walk and cell tests share.
struct TerrainRay {
    o: DVec3,
    d: DVec3,
    /// The origin relative to the grid's corner (x, y) [m].
    px: f64,
    py: f64,
    /// `1 / d.x`, `1 / d.y`.
    ix: f64,
    iy: f64,
    /// `ix`, `iy`, `px`, `py` are finite.
    finite: bool,
    /// The origin and direction in cells (x / resolution).
    gu: f64,
    gv: f64,
    du: f64,
    dv: f64,
}

impl TerrainRay {
    #[inline]
    fn new(t: &Terrain, o: DVec3, d: DVec3) -> TerrainRay {
        let (px, py) = (o.x - t.origin[0], o.y - t.origin[1]);
        let res = t.resolution;
        let (ix, iy) = (1.0 / d.x, 1.0 / d.y);
        let finite = ix.is_finite() && iy.is_finite() && px.is_finite() && py.is_finite();
        TerrainRay { o, d, px, py, ix, iy, finite, gu: px / res, gv: py / res, du: d.x / res, dv: d.y / res }
    }
}

/// `k as f64` for a grid index (far below 2^53, so exact either way): through `i64`, one
/// instruction on x86-64 where the conversion from `u64` takes several.
#[inline(always)]
fn index_f64(k: usize) -> f64 {
    k as i64 as f64
}

/// `x as usize` for `x >= 0` or NaN (the same value: truncated, saturated, NaN gives 0):
/// through `i64`, fewer instructions than the saturating conversion to `u64`.
#[inline(always)]
fn index_of(x: f64) -> usize {
    x as i64 as usize
}

/// Walks the square cells (side `size`, cell (i, j) spans `[i, i + 1) · size` along x) that
/// the ray `p + t·d` (x, y only; `p` relative to the grid's corner) crosses for `t` in
/// `[t0, t1]`, in order, within the index ranges `[i0, i1) x [j0, j1)`; `visit(i, j, ta, tb)`
/// gets each cell and the ray's part in it, and the first `Some` it returns ends the walk.
#[inline]
fn walk_grid<T>(
    ray: &TerrainRay,
    size: f64,
    (i0, i1): (usize, usize),
    (j0, j1): (usize, usize),
    t0: f64,
    t1: f64,
    mut visit: impl FnMut(usize, usize, f64, f64) -> Option<T>,
) -> Option<T> {
    if i0 >= i1 || j0 >= j1 {
        return None;
    }
    // `as usize` truncates and saturates (NaN gives 0): with the clamp at `lo >= 0` this is
    // the floor (no libm call).
    let (px, py, dx, dy, ix, iy) = (ray.px, ray.py, ray.d.x, ray.d.y, ray.ix, ray.iy);
    let start = |p: f64, d: f64, lo: usize, hi: usize| (index_of(((p + d * t0) / size).max(index_f64(lo)))).min(hi - 1);
    let (mut i, mut j) = (start(px, dx, i0, i1), start(py, dy, j0, j1));
    // Distance at which the ray leaves cell index `k` along an axis.
    let exit = |p: f64, d: f64, inv: f64, k: usize| {
        if d > 0.0 {
            (index_f64(k + 1) * size - p) * inv
        } else if d < 0.0 {
            (index_f64(k) * size - p) * inv
        } else {
            f64::INFINITY
        }
    };
    let mut t = t0;
    let (mut tx, mut ty) = (exit(px, dx, ix, i), exit(py, dy, iy, j));
    // With finite inverses (and `t0`, `t1` not NaN) no exit distance is NaN: plain
    // comparisons then give what `min` / `max` give (which skip a NaN), more cheaply.
    let plain = ray.finite && !t0.is_nan() && !t1.is_nan();
    loop {
        let t_out = if plain {
            let m = if ty < tx { ty } else { tx };
            let m = if t1 < m { t1 } else { m };
            if m < t { t } else { m }
        } else {
            tx.min(ty).min(t1).max(t)
        };
        if let Some(found) = visit(i, j, t, t_out) {
            return Some(found);
        }
        if t_out >= t1 {
            return None;
        }
        if tx <= ty {
            if dx > 0.0 && i + 1 < i1 {
                i += 1;
            } else if dx < 0.0 && i > i0 {
                i -= 1;
            } else {
                return None;
            }
            tx = exit(px, dx, ix, i);
        } else {
            if dy > 0.0 && j + 1 < j1 {
                j += 1;
            } else if dy < 0.0 && j > j0 {
                j -= 1;
            } else {
                return None;
            }
            ty = exit(py, dy, iy, j);
        }
        t = t_out;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::tests::{next, world};


    #[test]
    fn terrain_walk_finds_the_brute_force_nearest_triangle() {
        let w = world(crate::scenarios::generate("mine", 4).expect("scenario"));
        let t = w.terrain.as_ref().expect("terrain");
        let (cells_x, cells_y) = (t.cols - 1, t.rows - 1);
        let mut state = 11u64;
        let mut hits = 0;
        for i in 0..400 {
            let o = DVec3::new(next(&mut state) * 30.0, next(&mut state) * 20.0, 0.2 + next(&mut state) * 2.0);
            let d = DVec3::new(next(&mut state) - 0.5, next(&mut state) - 0.5, -(next(&mut state) * 0.4) + if i % 5 == 0 { 0.3 } else { 0.0 }).normalize();
            let max_t = 40.0;
            let mut want: Option<LeafHit> = None;
            for r in 0..cells_y {
                for c in 0..cells_x {
                    if t.removed[r * cells_x + c] {
                        continue;
                    }
                    if let Some(h) = t.cast_cell(o, d, r, c, 0.0, max_t) {
                        if h.t <= max_t && want.is_none_or(|b| h.t < b.t) {
                            want = Some(h);
                        }
                    }
                }
            }
            let got = t.cast(o, d, max_t);
            match (want, got) {
                (Some(a), Some(b)) => {
                    assert!((a.t - b.t).abs() < 1e-9, "ray {i}: {} vs {}", a.t, b.t);
                    hits += 1;
                }
                (None, None) => {}
                (a, b) => panic!("ray {i}: brute force {a:?}, walk {b:?}"),
            }
        }
        assert!(hits > 200, "{hits}");
    }
}
