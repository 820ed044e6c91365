//! Fan casting: many rays from one origin ([`World::cast_fan`], [`World::cast_fan_cached`],
//! [`FanCast`]) culled per fan: the fan's frustum ([`Frustum`]) through the BVH, its layout
//! ([`FanLayout`], [`FanGeom`], [`BinCone`]), and per bin the candidates nearest first
//! ([`FanPlan`], made in the memory of [`PlanLists`] and [`PlanScratch`], read as [`PlanSlices`]).

use glam::{DMat3, DVec3};

use super::leaf::{ray_box_t, Prepared};
use super::terrain::{TerrainView, TERRAIN_VIEW_MIN_RAYS};
use super::{FanHit, FanSink, PrimitiveId, World};

/// Rays below which a bundle is cast ray by ray (the per-fan set-up does not pay).
const FAN_MIN_RAYS: usize = 64;
/// Rays per culling bin of a fan (about).
const FAN_RAYS_PER_BIN: usize = 16;
/// Most culling bins of a fan.
const FAN_MAX_BINS: usize = 1 << 15;
/// Depth (along a fan's axis) in front of which the fan's culling projects boxes [m].
const FAN_NEAR_M: f64 = 1.0e-6;
/// Every ray of a fan lies within acos(FAN_MIN_COS) ≈ 70° of its axis, else it is split.
const FAN_MIN_COS: f64 = 0.34;

impl World {
    /// The rays `origin + t · rotation · dirs[k]` (`dirs` unit length, finite `origin` and
    /// `rotation`), `0 <= t <= range(k)`, in order of `k`; `sink(k, world direction, hit)`
    /// receives each result. Same answers as [`World::cast_ray`], bit for bit (the normal
    /// only when `NORMALS`; else it is zero).
    ///
    /// The rays are split into fans of at most 70° around their mean direction; per fan the
    /// bounded primitives in its frustum (found through the BVH) are projected once onto a
    /// grid of bins over the fan's gnomonic image, and each ray tests only its bin's list,
    /// nearest first, stopping at the first one beyond its current hit.
    pub(crate) fn cast_fan<const NORMALS: bool, R, S>(&self, origin: DVec3, rotation: DMat3, dirs: &[DVec3], range: &R, sink: &mut S)
    where
        R: Fn(usize) -> f64,
        S: FanSink,
    {
        let view = self.terrain_view(origin, dirs.len());
        self.cast_fan_from::<NORMALS, R, S>(origin, rotation, dirs, 0, range, view.as_ref(), sink);
    }

    /// The terrain seen from `origin`, for `rays` rays from there; `None` when there is no
    /// terrain or the rays are too few for it to pay.
    fn terrain_view(&self, origin: DVec3, rays: usize) -> Option<TerrainView> {
        let t = self.terrain.as_ref()?;
        (t.any_cell && rays >= TERRAIN_VIEW_MIN_RAYS).then(|| TerrainView::new(t, origin))
    }

    #[allow(clippy::too_many_arguments)]
    fn cast_fan_from<const NORMALS: bool, R, S>(&self, origin: DVec3, rotation: DMat3, dirs: &[DVec3], first: usize, range: &R, view: Option<&TerrainView>, sink: &mut S)
    where
        R: Fn(usize) -> f64,
        S: FanSink,
    {
        if dirs.len() < FAN_MIN_RAYS || self.solids.is_empty() {
            for (k, dl) in dirs.iter().enumerate() {
                let d = rotation * *dl;
                let max_t = range(first + k);
                let hit = if max_t.is_nan() || max_t < 0.0 { None } else { self.cast_unit_in(origin, d, max_t, view) };
                sink.put(first + k, d, hit);
            }
            return;
        }
        let axis = dirs.iter().fold(DVec3::ZERO, |acc, d| acc + *d).normalize_or_zero();
        let min_cos = dirs.iter().fold(f64::INFINITY, |acc, d| acc.min(d.dot(axis)));
        if min_cos.is_nan() || min_cos < FAN_MIN_COS {
            let mid = dirs.len() / 2;
            self.cast_fan_from::<NORMALS, R, S>(origin, rotation, &dirs[..mid], first, range, view, sink);
            self.cast_fan_from::<NORMALS, R, S>(origin, rotation, &dirs[mid..], first + mid, range, view, sink);
            return;
        }
        let g = FanGeom::new(axis, dirs, first, range);
        let plan = FanPlan::new(self, origin, rotation, g, &g.cones(), PlanLists::default(), &mut PlanScratch::default());
        for (k, dl) in dirs.iter().enumerate() {
            let d = rotation * *dl;
            let hit = self.fan_ray::<NORMALS, true>(plan.slices(), origin, d, range(first + k), plan.g.bin(*dl), view);
            sink.put(first + k, d, hit);
        }
    }

    /// [`World::cast_fan`] with the fans laid out beforehand: `layout` is
    /// [`FanLayout::new`]`(dirs, range)` (the same `dirs` and `range`). Same answers.
    pub(crate) fn cast_fan_cached<const NORMALS: bool, R, S>(&self, origin: DVec3, rotation: DMat3, dirs: &[DVec3], layout: &FanLayout, range: &R, sink: &mut S)
    where
        R: Fn(usize) -> f64,
        S: FanSink,
    {
        if layout.len() != dirs.len() {
            self.cast_fan::<NORMALS, R, S>(origin, rotation, dirs, range, sink);
            return;
        }
        let view = self.terrain_view(origin, dirs.len());
        let view = view.as_ref();
        // This thread's plan memory, taken for the call (a sink that casts again, or panics,
        // leaves fresh memory to the next call).
        let mut scratch = PlanScratch::take();
        let mut lists = PlanLists::take();
        for (&(first, len, geom), cones) in layout.fans.iter().zip(&layout.cones) {
            let fan = &dirs[first..first + len];
            let bins = &layout.bins[first..first + len];
            match geom {
                Some(g) if !self.solids.is_empty() => {
                    let plan = FanPlan::new(self, origin, rotation, g, cones, lists, &mut scratch);
                    self.cast_planned_fan::<NORMALS, R, S>(plan.slices(), origin, rotation, fan, bins, first, range, view, sink);
                    lists = plan.into_lists();
                }
                _ => {
                    for (k, dl) in fan.iter().enumerate() {
                        let d = rotation * *dl;
                        let max_t = range(first + k);
                        let hit = if max_t.is_nan() || max_t < 0.0 { None } else { self.cast_unit_in(origin, d, max_t, view) };
                        sink.put(first + k, d, hit);
                    }
                }
            }
        }
        lists.give();
        scratch.give();
    }

    /// The per-pose set-up of [`World::cast_fan_cached`] (a plan per fan, the terrain view),
    /// to cast the rays in parts, e.g. from several threads ([`FanCast::cast`]).
    pub(crate) fn fan_cast<'a>(&'a self, origin: DVec3, rotation: DMat3, layout: &'a FanLayout) -> FanCast<'a> {
        // Every plan in lists of its own from this thread's pool (back there when the
        // `FanCast` is dropped), all made with one scratch.
        let mut scratch = PlanScratch::take();
        let plans = layout
            .fans
            .iter()
            .zip(&layout.cones)
            .map(|(&(_, _, geom), cones)| match geom {
                Some(g) if !self.solids.is_empty() => Some(FanPlan::new(self, origin, rotation, g, cones, PlanLists::take(), &mut scratch)),
                _ => None,
            })
            .collect();
        scratch.give();
        FanCast { world: self, origin, rotation, layout, plans, view: self.terrain_view(origin, layout.len()) }
    }

    /// The rays `fan` (local directions, `bins` their bins in `plan`'s grid; ray `k` is
    /// `first + k` for `range` and `sink`) of a fan with a plan. A loop of its own for fans
    /// whose plan meets the terrain and for those that do not: the latter's loop holds no
    /// terrain code (fewer registers spilled per ray).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn cast_planned_fan<const NORMALS: bool, R, S>(
        &self,
        plan: PlanSlices<'_>,
        origin: DVec3,
        rotation: DMat3,
        fan: &[DVec3],
        bins: &[u32],
        first: usize,
        range: &R,
        view: Option<&TerrainView>,
        sink: &mut S,
    ) where
        R: Fn(usize) -> f64,
        S: FanSink,
    {
        if plan.terrain && self.terrain.is_some() {
            for (k, (dl, &bin)) in fan.iter().zip(bins).enumerate() {
                let d = rotation * *dl;
                let hit = self.fan_ray::<NORMALS, true>(plan, origin, d, range(first + k), bin as usize, view);
                sink.put(first + k, d, hit);
            }
        } else {
            for (k, (dl, &bin)) in fan.iter().zip(bins).enumerate() {
                let d = rotation * *dl;
                let hit = self.fan_ray::<NORMALS, false>(plan, origin, d, range(first + k), bin as usize, view);
                sink.put(first + k, d, hit);
            }
        }
    }

    /// One ray of a fan: world direction `d`, range `max_t`, bin `bin` of the plan's grid.
    /// The normal is computed (for the nearest hit only) when `NORMALS`; the terrain is cast
    /// when `TERRAIN` and the plan meets it (`TERRAIN` false: the plan does not).
    #[inline(always)]
    fn fan_ray<const NORMALS: bool, const TERRAIN: bool>(&self, plan: PlanSlices<'_>, origin: DVec3, d: DVec3, max_t: f64, bin: usize, view: Option<&TerrainView>) -> Option<FanHit> {
        if max_t.is_nan() || max_t < 0.0 {
            return None;
        }
        // The nearest so far: `limit` is its distance (or `max_t`); planes first, in order,
        // a later one only when strictly nearer.
        let mut limit = max_t;
        let mut found = false;
        let mut plane_hit: Option<(usize, bool)> = None;
        for (i, (plane, &s)) in self.planes.iter().zip(plan.plane_s).enumerate() {
            let (t, inside) = if s < 0.0 {
                (0.0, true)
            } else {
                let denom = plane.normal.dot(d);
                if denom >= 0.0 {
                    continue;
                }
                // Not NaN: s >= 0 finite, denom < 0.
                let t = -s / denom;
                if t > limit {
                    continue;
                }
                (t, false)
            };
            if !found || t < limit {
                limit = t;
                found = true;
                plane_hit = Some((i, inside));
            }
        }
        // Bounded primitives, nearest box first: the nearest hit, then the lowest id. No hit
        // yet: `solid_id` is `PrimitiveId::MAX` (above every id), so that a hit at `limit`
        // counts, as `t <= limit` does.
        let mut solid_t = limit;
        let mut solid_id = PrimitiveId::MAX;
        let (mut solid_index, mut solid_face) = (0u32, 0u8);
        for &(near, index) in plan.candidates(bin) {
            if near > solid_t {
                break;
            }
            let Some((id, prepared)) = plan.prepared.get(index as usize) else { continue };
            // Boxes (the common kind) matched first, their test inlined here (this form
            // measured faster than a plain `cast_t`, though the kinds still share one jump).
            let hit = match prepared {
                Prepared::Box { cos, sin, near, far, .. } => ray_box_t(d, *cos, *sin, *near, *far),
                other => other.cast_t(d),
            };
            if let Some((t, face)) = hit {
                if t < solid_t || (t == solid_t && *id < solid_id) {
                    solid_t = t;
                    solid_id = *id;
                    (solid_index, solid_face) = (index, face);
                }
            }
        }
        let mut best: Option<FanHit> = None;
        if let Some((i, inside)) = plane_hit {
            let plane = &self.planes[i];
            best = Some(FanHit { t: limit, normal: if !NORMALS { DVec3::ZERO } else if inside { -d } else { plane.normal }, primitive: plane.id });
        }
        if solid_id != PrimitiveId::MAX && (!found || solid_t < limit) {
            let normal = if NORMALS { plan.prepared[solid_index as usize].1.normal(origin, d, solid_t, solid_face) } else { DVec3::ZERO };
            best = Some(FanHit { t: solid_t, normal, primitive: solid_id });
        }
        self.finish::<NORMALS>(origin, d, max_t, best, TERRAIN && plan.terrain, view)
    }
}

/// The pyramid (apex `origin`) of a fan's rays, cut at `range`: four side planes through the
/// apex, normals pointing inside.
pub(super) struct Frustum {
    origin: DVec3,
    normals: [DVec3; 4],
    range: f64,
}

impl Frustum {
    /// Whether the box `(lo, hi)` may meet the pyramid (conservative).
    pub(super) fn meets(&self, lo: DVec3, hi: DVec3) -> bool {
        let c = (lo + hi) * 0.5 - self.origin;
        let h = (hi - lo) * 0.5;
        let slack = 1.0e-9 * (1.0 + c.abs().element_sum() + h.element_sum());
        for n in &self.normals {
            if n.dot(c) + n.abs().dot(h) < -slack {
                return false;
            }
        }
        box_distance(self.origin, lo, hi) <= self.range
    }
}

/// Distance from `p` to the box `(lo, hi)` (0 inside).
fn box_distance(p: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    (lo - p).max(p - hi).max(DVec3::ZERO).length()
}

/// A cached fan cast set up for one pose ([`World::fan_cast`]).
pub(crate) struct FanCast<'a> {
    world: &'a World,
    origin: DVec3,
    rotation: DMat3,
    layout: &'a FanLayout,
    /// The plan of each fan of the layout; `None`: cast ray by ray.
    plans: Vec<Option<FanPlan>>,
    view: Option<TerrainView>,
}

impl Drop for FanCast<'_> {
    /// The plans' lists go back to the pool of the thread that drops the cast.
    fn drop(&mut self) {
        for plan in std::mem::take(&mut self.plans).into_iter().flatten() {
            plan.into_lists().give();
        }
    }
}

impl FanCast<'_> {
    /// Casts the rays `span` of `dirs` (the directions the layout was made of) as
    /// [`World::cast_fan_cached`] does; `range` and `sink` take the index into `dirs`.
    pub(crate) fn cast<const NORMALS: bool, R, S>(&self, dirs: &[DVec3], span: std::ops::Range<usize>, range: &R, sink: &mut S)
    where
        R: Fn(usize) -> f64,
        S: FanSink,
    {
        if self.layout.len() != dirs.len() {
            return;
        }
        self.world.cast_planned::<NORMALS, R, S>(self.origin, self.rotation, self.layout, &self.plans, self.view.as_ref(), dirs, span, range, sink);
    }
}

impl World {
    /// [`FanCast::cast`]; a function of its own, so that the world's fields stay in registers
    /// across the sink's writes.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn cast_planned<const NORMALS: bool, R, S>(
        &self,
        origin: DVec3,
        rotation: DMat3,
        layout: &FanLayout,
        plans: &[Option<FanPlan>],
        view: Option<&TerrainView>,
        dirs: &[DVec3],
        span: std::ops::Range<usize>,
        range: &R,
        sink: &mut S,
    ) where
        R: Fn(usize) -> f64,
        S: FanSink,
    {
        for (&(first, len, _), plan) in layout.fans.iter().zip(plans) {
            let (a, b) = (first.max(span.start), (first + len).min(span.end));
            if a >= b {
                continue;
            }
            let fan = &dirs[a..b];
            match plan {
                Some(plan) => {
                    // The plan's slices in locals (kept in registers across the sink's writes).
                    let plan = plan.slices();
                    let bins = &layout.bins[a..b];
                    self.cast_planned_fan::<NORMALS, R, S>(plan, origin, rotation, fan, bins, a, range, view, sink);
                }
                None => {
                    for (k, dl) in fan.iter().enumerate() {
                        let d = rotation * *dl;
                        let max_t = range(a + k);
                        let hit = if max_t.is_nan() || max_t < 0.0 { None } else { self.cast_unit_in(origin, d, max_t, view) };
                        sink.put(a + k, d, hit);
                    }
                }
            }
        }
    }
}

/// Per-fan culling: the fan's rays in gnomonic coordinates `(u, v)` around its axis, a grid of
/// bins over them, and per bin the primitives whose boxes project into it, nearest first.
struct FanPlan {
    /// The fan's frame and bin grid.
    g: FanGeom,
    /// Bin `b`'s candidates are `entries[starts[b]..starts[b + 1]]`: (distance to the box,
    /// index into `prepared`), nearest first.
    starts: Vec<u32>,
    entries: Vec<(f64, u32)>,
    /// The visible primitives, prepared for the fan's origin, nearest box first.
    prepared: Vec<(PrimitiveId, Prepared)>,
    /// Signed distance of the origin to each plane (as `Plane::cast` computes it).
    plane_s: Vec<f64>,
    /// The terrain's box meets the fan.
    terrain: bool,
}

/// The pose-free part of a fan: its frame, the extent of its rays' gnomonic image, the
/// bin grid and the longest range.
#[derive(Debug, Clone, Copy)]
struct FanGeom {
    axis: DVec3,
    e1: DVec3,
    e2: DVec3,
    u0: f64,
    u1: f64,
    v0: f64,
    v1: f64,
    su: f64,
    sv: f64,
    nbx: usize,
    nby: usize,
    rmax: f64,
}

/// Rays split into fans once, for casting them from many poses ([`World::cast_fan_cached`]):
/// what [`World::cast_fan`] computes per call that depends on the directions and ranges only.
#[derive(Debug, Clone, Default)]
pub(crate) struct FanLayout {
    /// (first ray, ray count, geometry; `None`: cast ray by ray).
    fans: Vec<(usize, usize, Option<FanGeom>)>,
    /// The cones of each fan's bins ([`FanGeom::cones`]; empty for a fan cast ray by ray).
    cones: Vec<Vec<BinCone>>,
    /// Bin of each ray in its fan's grid.
    bins: Vec<u32>,
}

impl FanLayout {
    /// Splits `dirs` (unit, local frame) as [`World::cast_fan`] does; `range(k)` is ray `k`'s range.
    pub(crate) fn new<R: Fn(usize) -> f64>(dirs: &[DVec3], range: &R) -> FanLayout {
        let mut layout = FanLayout { fans: Vec::new(), cones: Vec::new(), bins: vec![0; dirs.len()] };
        layout.split(dirs, 0, range);
        layout
    }

    fn split<R: Fn(usize) -> f64>(&mut self, dirs: &[DVec3], first: usize, range: &R) {
        if dirs.len() < FAN_MIN_RAYS {
            self.fans.push((first, dirs.len(), None));
            self.cones.push(Vec::new());
            return;
        }
        let axis = dirs.iter().fold(DVec3::ZERO, |acc, d| acc + *d).normalize_or_zero();
        let min_cos = dirs.iter().fold(f64::INFINITY, |acc, d| acc.min(d.dot(axis)));
        if min_cos.is_nan() || min_cos < FAN_MIN_COS {
            let mid = dirs.len() / 2;
            self.split(&dirs[..mid], first, range);
            self.split(&dirs[mid..], first + mid, range);
            return;
        }
        let g = FanGeom::new(axis, dirs, first, range);
        for (k, d) in dirs.iter().enumerate() {
            self.bins[first + k] = g.bin(*d) as u32;
        }
        self.fans.push((first, dirs.len(), Some(g)));
        self.cones.push(g.cones());
    }

    /// Number of rays laid out.
    pub(crate) fn len(&self) -> usize {
        self.bins.len()
    }
}

/// A circular cone (local frame of the fan) holding every ray of one bin, widened a little.
#[derive(Debug, Clone, Copy)]
struct BinCone {
    /// Unit axis.
    c: DVec3,
    /// Cosine and sine of the half angle.
    cos: f64,
    sin: f64,
}

impl BinCone {
    /// Largest `n · d` over the unit directions `d` of the cone (`n` unit).
    #[inline]
    fn max_dot(&self, n: DVec3) -> f64 {
        let ct = n.dot(self.c);
        if ct >= self.cos {
            1.0
        } else {
            // cos(θ - ρ) for the angle θ between `n` and the axis, ρ the half angle.
            ct * self.cos + (1.0 - ct * ct).max(0.0).sqrt() * self.sin
        }
    }
}

impl FanGeom {
    /// The cone of each bin (`[by * nbx + bx]`): around the direction through the middle of
    /// the bin's rectangle of gnomonic coordinates, through its corners (the cone's image is
    /// convex), the half angle widened by a relative 1e-6 and 1e-7 rad beyond rounding.
    fn cones(&self) -> Vec<BinCone> {
        let edge_u = |i: usize| if self.su > 0.0 { self.u0 + i as f64 / self.su } else { self.u0 };
        let edge_v = |j: usize| if self.sv > 0.0 { self.v0 + j as f64 / self.sv } else { self.v0 };
        let dir = |u: f64, v: f64| (self.axis + self.e1 * u + self.e2 * v).normalize();
        let mut cones = Vec::with_capacity(self.nbx * self.nby);
        for by in 0..self.nby {
            let (va, vb) = (edge_v(by), edge_v(by + 1));
            for bx in 0..self.nbx {
                let (ua, ub) = (edge_u(bx), edge_u(bx + 1));
                let c = dir(0.5 * (ua + ub), 0.5 * (va + vb));
                let cos_min = [(ua, va), (ub, va), (ua, vb), (ub, vb)].iter().fold(1.0f64, |m, &(u, v)| m.min(c.dot(dir(u, v))));
                let rho = cos_min.clamp(-1.0, 1.0).acos() * (1.0 + 1.0e-6) + 1.0e-7;
                let (sin, cos) = rho.min(std::f64::consts::PI).sin_cos();
                cones.push(BinCone { c, cos, sin });
            }
        }
        cones
    }

    fn new<R: Fn(usize) -> f64>(axis: DVec3, dirs: &[DVec3], first: usize, range: &R) -> FanGeom {
        let (e1, e2) = axis.any_orthonormal_pair();
        let (mut u0, mut u1, mut v0, mut v1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        let mut rmax: f64 = 0.0;
        for (k, d) in dirs.iter().enumerate() {
            let inv = 1.0 / d.dot(axis);
            let (u, v) = (d.dot(e1) * inv, d.dot(e2) * inv);
            u0 = u0.min(u);
            u1 = u1.max(u);
            v0 = v0.min(v);
            v1 = v1.max(v);
            let r = range(first + k);
            if r > rmax {
                rmax = r;
            }
        }
        let bins = (dirs.len() / FAN_RAYS_PER_BIN).clamp(1, FAN_MAX_BINS);
        let (du, dv) = (u1 - u0, v1 - v0);
        let nbx = if du <= 0.0 {
            1
        } else if dv <= 0.0 {
            bins
        } else {
            ((bins as f64 * du / dv).sqrt().round() as usize).clamp(1, bins)
        };
        let nby = (bins / nbx).max(1);
        let su = if du > 0.0 { nbx as f64 / du } else { 0.0 };
        let sv = if dv > 0.0 { nby as f64 / dv } else { 0.0 };
        FanGeom { axis, e1, e2, u0, u1, v0, v1, su, sv, nbx, nby, rmax }
    }

    fn bin_u(&self, u: f64) -> usize {
        // `as i32` saturates (NaN gives 0); one instruction, unlike `as usize`.
        (((u - self.u0) * self.su) as i32).clamp(0, self.nbx as i32 - 1) as usize
    }

    fn bin_v(&self, v: f64) -> usize {
        (((v - self.v0) * self.sv) as i32).clamp(0, self.nby as i32 - 1) as usize
    }

    /// Bin of the ray with local unit direction `d`.
    #[inline]
    fn bin(&self, d: DVec3) -> usize {
        let inv = 1.0 / d.dot(self.axis);
        self.bin_v(d.dot(self.e2) * inv) * self.nbx + self.bin_u(d.dot(self.e1) * inv)
    }
}

impl FanPlan {
    /// The plan of fan `g` (its bins' cones `cones`) from `origin`, in the memory of `lists`
    /// (back with [`FanPlan::into_lists`]), made with `scratch`.
    fn new(world: &World, origin: DVec3, rotation: DMat3, g: FanGeom, cones: &[BinCone], lists: PlanLists, scratch: &mut PlanScratch) -> FanPlan {
        let FanGeom { axis, e1, e2, u0, u1, v0, v1, nbx, nby, rmax, .. } = g;
        let PlanScratch { ids, visible, triples, counts, cursor } = scratch;
        let PlanLists { starts, entries, prepared, plane_s } = lists;
        let mut plan = FanPlan { g, starts, entries, prepared, plane_s, terrain: false };
        plan.starts.clear();
        plan.starts.resize(nbx * nby + 1, 0);
        plan.plane_s.clear();
        plan.plane_s.extend(world.planes.iter().map(|p| p.normal.dot(origin - p.point)));

        // World frame of the fan, and its pyramid widened by a hair.
        let (wa, w1, w2) = (rotation * axis, rotation * e1, rotation * e2);
        let pad = |x: f64| 1.0e-9 * (1.0 + x.abs());
        let frustum = Frustum {
            origin,
            normals: [w1 - wa * (u0 - pad(u0)), wa * (u1 + pad(u1)) - w1, w2 - wa * (v0 - pad(v0)), wa * (v1 + pad(v1)) - w2],
            range: rmax,
        };
        plan.terrain = world.terrain.as_ref().is_some_and(|t| t.any_cell && frustum.meets(t.lo, t.hi));

        ids.clear();
        world.bvh.visible(&frustum, ids);
        // (distance, id, bin rectangle)
        visible.clear();
        for &id in ids.iter() {
            let (lo, hi) = world.bvh.boxes[id as usize];
            let near = box_distance(origin, lo, hi);
            let cells = if near <= FAN_NEAR_M / FAN_MIN_COS {
                // The apex touches the box: it may cover any direction of the fan.
                [0, nbx - 1, 0, nby - 1]
            } else {
                // Project the part of the box in front of the plane z = FAN_NEAR_M (every hit
                // lies there, being farther than FAN_NEAR_M / FAN_MIN_COS): its corners there
                // and where its edges cross that plane.
                let mut corners = [(0.0, 0.0, 0.0); 8];
                for (k, c) in corners.iter_mut().enumerate() {
                    let p = DVec3::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    ) - origin;
                    *c = (p.dot(w1), p.dot(w2), p.dot(wa));
                }
                let mut rect = [f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY];
                let mut add = |u: f64, v: f64| rect = [rect[0].min(u), rect[1].max(u), rect[2].min(v), rect[3].max(v)];
                for (k, &(x, y, z)) in corners.iter().enumerate() {
                    if z >= FAN_NEAR_M {
                        add(x / z, y / z);
                    }
                    for bit in [1, 2, 4] {
                        if k & bit != 0 {
                            continue;
                        }
                        let (x2, y2, z2) = corners[k | bit];
                        if (z < FAN_NEAR_M) != (z2 < FAN_NEAR_M) {
                            let s = (FAN_NEAR_M - z) / (z2 - z);
                            add((x + (x2 - x) * s) / FAN_NEAR_M, (y + (y2 - y) * s) / FAN_NEAR_M);
                        }
                    }
                }
                if rect[0].is_nan() || rect[0] > rect[1] {
                    continue;
                }
                let (ra, rb, rc, rd) = (rect[0] - pad(rect[0]), rect[1] + pad(rect[1]), rect[2] - pad(rect[2]), rect[3] + pad(rect[3]));
                if rb < u0 || ra > u1 || rd < v0 || rc > v1 {
                    continue;
                }
                [g.bin_u(ra), g.bin_u(rb), g.bin_v(rc), g.bin_v(rd)]
            };
            visible.push((near, id, cells));
        }
        visible.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        plan.prepared.clear();
        plan.prepared.extend(visible.iter().map(|&(_, id, _)| (id, world.solids[id as usize].prepare(origin))));
        // Per (bin, candidate): a lower bound of the distance at which the bin's rays may
        // meet the candidate, from the faces of its box (the box itself for a box, its
        // loosened bounds else) that face the origin: a ray enters each such face's plane no
        // nearer than s / (n · d) (s its distance from the origin, n its normal). A bin whose
        // rays all run parallel to or away from such a plane never meets the candidate.
        let to_local = rotation.transpose();
        triples.clear();
        for (index, &(near, id, [bx0, bx1, by0, by1])) in visible.iter().enumerate() {
            let mut slabs = [(DVec3::ZERO, 0.0); 3];
            let mut count = 0;
            let mut face = |n: DVec3, s: f64| {
                slabs[count] = (to_local * n, s);
                count += 1;
            };
            match plan.prepared[index].1 {
                Prepared::Inside => {}
                Prepared::Box { half, cos, sin, ol, .. } => {
                    let axes = [DVec3::new(cos, sin, 0.0), DVec3::new(-sin, cos, 0.0), DVec3::Z];
                    for k in 0..3 {
                        if ol[k] < -half[k] {
                            face(axes[k], -half[k] - ol[k]);
                        } else if ol[k] > half[k] {
                            face(-axes[k], ol[k] - half[k]);
                        }
                    }
                }
                _ => {
                    let (lo, hi) = world.bvh.boxes[id as usize];
                    for (k, axis) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
                        if origin[k] < lo[k] {
                            face(axis, lo[k] - origin[k]);
                        } else if origin[k] > hi[k] {
                            face(-axis, origin[k] - hi[k]);
                        }
                    }
                }
            }
            let slabs = &slabs[..count];
            for by in by0..=by1 {
                let row = by * nbx + bx0..=by * nbx + bx1;
                'bin: for (bin, cone) in row.clone().zip(&cones[row]) {
                    let mut bound = near;
                    for &(n, s) in slabs {
                        let m = cone.max_dot(n);
                        if m <= 0.0 {
                            continue 'bin;
                        }
                        // Not NaN (s finite, m > 0).
                        let b = s / m * (1.0 - 1.0e-9);
                        if b > bound {
                            bound = b;
                        }
                    }
                    triples.push((bin as u32, bound, index as u32));
                }
            }
        }
        counts.clear();
        counts.resize(nbx * nby, 0);
        for &(bin, _, _) in triples.iter() {
            counts[bin as usize] += 1;
        }
        let mut total = 0u32;
        for (b, c) in counts.iter().enumerate() {
            plan.starts[b] = total;
            total += c;
        }
        plan.starts[nbx * nby] = total;
        plan.entries.clear();
        plan.entries.resize(total as usize, (0.0, 0));
        cursor.clear();
        cursor.extend_from_slice(&plan.starts[..nbx * nby]);
        for &(bin, bound, index) in triples.iter() {
            let slot = &mut cursor[bin as usize];
            plan.entries[*slot as usize] = (bound, index);
            *slot += 1;
        }
        for b in 0..nbx * nby {
            let list = &mut plan.entries[plan.starts[b] as usize..plan.starts[b + 1] as usize];
            // Short lists: insertion sort by bound (ties in candidate order).
            for i in 1..list.len() {
                let mut j = i;
                while j > 0 && list[j - 1].0 > list[j].0 {
                    list.swap(j - 1, j);
                    j -= 1;
                }
            }
        }
        plan
    }

    /// The plan's lists, for the next plan.
    fn into_lists(self) -> PlanLists {
        PlanLists { starts: self.starts, entries: self.entries, prepared: self.prepared, plane_s: self.plane_s }
    }

    /// The parts of the plan its rays read.
    #[inline]
    fn slices(&self) -> PlanSlices<'_> {
        PlanSlices { starts: &self.starts, entries: &self.entries, prepared: &self.prepared, plane_s: &self.plane_s, terrain: self.terrain }
    }
}

/// The lists of a [`FanPlan`], kept (per thread, [`PlanLists::take`]) from one plan to the
/// next: a frame's plans (hundreds of kilobytes for a depth frame of a cluttered world) then
/// reuse the pages of the last frame's instead of having fresh ones mapped and cleared by
/// the kernel.
#[derive(Default)]
struct PlanLists {
    starts: Vec<u32>,
    entries: Vec<(f64, u32)>,
    prepared: Vec<(PrimitiveId, Prepared)>,
    plane_s: Vec<f64>,
}

impl PlanLists {
    /// Lists from this thread's pool (or new ones).
    fn take() -> PlanLists {
        PLAN_LISTS.try_with(|pool| pool.borrow_mut().pop()).ok().flatten().unwrap_or_default()
    }

    /// Back to this thread's pool.
    fn give(self) {
        // While the thread ends the pool may be gone: the lists are then dropped.
        let _ = PLAN_LISTS.try_with(|pool| pool.borrow_mut().push(self));
    }
}

/// The scratch memory of making a [`FanPlan`], kept per thread likewise ([`PLAN_SCRATCH`]).
#[derive(Default)]
struct PlanScratch {
    /// Ids of the primitives in the fan's frustum.
    ids: Vec<u32>,
    /// (distance, id, bin rectangle) of those the fan may meet.
    visible: Vec<(f64, PrimitiveId, [usize; 4])>,
    /// (bin, bound, candidate), before they are sorted into bins.
    triples: Vec<(u32, f64, u32)>,
    counts: Vec<u32>,
    cursor: Vec<u32>,
}

impl PlanScratch {
    /// This thread's scratch, taken (a call made meanwhile gets a new one).
    fn take() -> PlanScratch {
        PLAN_SCRATCH.try_with(std::cell::RefCell::take).unwrap_or_default()
    }

    /// Back to this thread.
    fn give(self) {
        // While the thread ends the slot may be gone: the scratch is then dropped.
        let _ = PLAN_SCRATCH.try_with(|s| s.replace(self));
    }
}

thread_local! {
    /// Each thread's spare [`PlanLists`] (as many as it ever held plans at once: a frame's
    /// worth, kept while the thread lives).
    static PLAN_LISTS: std::cell::RefCell<Vec<PlanLists>> = const { std::cell::RefCell::new(Vec::new()) };
    /// Each thread's [`PlanScratch`] (taken for a call; a call made meanwhile gets fresh).
    static PLAN_SCRATCH: std::cell::RefCell<PlanScratch> = std::cell::RefCell::new(PlanScratch::default());
}

/// The parts of a [`FanPlan`] its rays read, as slices.
#[derive(Clone, Copy)]
struct PlanSlices<'a> {
    starts: &'a [u32],
    entries: &'a [(f64, u32)],
    prepared: &'a [(PrimitiveId, Prepared)],
    plane_s: &'a [f64],
    terrain: bool,
}

impl PlanSlices<'_> {
    /// Candidates of the rays in bin `b`, nearest bound first.
    #[inline]
    fn candidates(&self, b: usize) -> &[(f64, u32)] {
        let (s, e) = (self.starts[b] as usize, self.starts[b + 1] as usize);
        &self.entries[s..e]
    }
}
