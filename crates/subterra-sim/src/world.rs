//! A [`WorldSpec`] turned into geometry, and the queries the sensors and vehicles ask of it.
//!
//! In: a validated [`WorldSpec`] (or TOML text, see `docs/world-format.md`). Out: ray casts
//! ([`World::cast_ray`]), clearance ([`World::clearance`]) and ground height
//! ([`World::ground_height`]). World frame ENU (z up), metres.
//!
//! How it is built:
//! - The bounded primitives (cylinders, capsules, boxes, spheres, solid items) sit in a flat
//!   bounding-volume hierarchy of their loosened boxes (binned surface-area splits, f32 slab
//!   tests, nearest child first, early out at the current hit) for ray casts, and in a parry3d
//!   [`Compound`] (its own BVH) for point queries. The leaf test itself is the exact analytic
//!   intersection in f64 (parry's f32 GJK ray cast on a cylinder is off by up to a few mm), so
//!   hit distances are exact to ~1e-9 m.
//! - Many rays from one origin ([`World::cast_rays`], the depth camera and the lidar) are cast
//!   as fans: per fan the primitives in its frustum are found once through the BVH, their
//!   origin terms computed once, and their boxes projected onto a grid of bins over the fan's
//!   image. Per bin and candidate a lower bound of the distance at which the bin's rays may
//!   enter it (from the faces of its box that face the origin, against a cone around the
//!   bin's rays) orders the bin's list, or drops the candidate when no ray of the bin runs
//!   toward such a face. A ray then tests only its bin's few candidates, nearest bound
//!   first, up to its current hit, and the normal of the nearest hit only (none for a lidar
//!   scan). Same answers as [`World::cast_ray`], bit for bit (ties between primitives go to
//!   the lower id).
//! - The terrain is a parry3d [`HeightField`] for clearance queries; cells touching a hole are
//!   removed. Rays walk its grid themselves (a pyramid of blocks of 4 x 4 cells, 16 x 16
//!   and 64 x 64, each with its height range, then cells), testing the two f64 triangles of
//!   each cell they may meet; those are the triangles [`World::ground_height`] interpolates.
//!   Many rays from one origin (a lidar scan, a depth frame) first get a `TerrainView` of
//!   the terrain from there: per azimuth sector and bin of horizontal distance, the range of
//!   slopes under which the terrain is seen. A ray keeps one sector and one slope, so it
//!   walks only the cells of the bins whose range holds its slope: no walk at all above the
//!   horizon, a short one near its hit.
//! - Planes are few and unbounded: handled analytically.
//!
//! Primitive ids ([`PrimitiveId`]) are stable: cylinders, capsules, boxes, spheres and solid
//! items in spec order, then planes, then the height field.
//!
//! Solids: a ray that starts inside a bounded primitive or behind a plane (the solid side is
//! opposite the normal) hits at distance 0 with the normal `-dir`. The terrain is a surface,
//! seen from both sides.

use glam::DVec3;
use glam::DMat3;
use parry3d::math::{Pose, Rot3, Vector};
use parry3d::query::PointQuery;
use parry3d::shape::{Compound, HeightField, HeightFieldCellStatus, SharedShape};
use parry3d::utils::Array2;

use crate::error::{SimError, SimResult};
use crate::spec::{HeightFieldSpec, RegionSpec, WorldSpec};

/// Stable index of a primitive of a [`World`]: cylinders, capsules, boxes, spheres and solid
/// items in spec order, then planes, then the height field.
pub type PrimitiveId = u32;

/// Radius of a solid mission item's sphere [m].
pub const ITEM_RADIUS_M: f64 = 0.15;

/// Largest coordinate or size a world may hold [m]. The geometry library works in f32
/// (7 significant digits): beyond this, mm accuracy is lost.
pub const MAX_COORDINATE_M: f64 = 1.0e5;

/// Smallest `normal.z` of a plane that [`World::ground_height`] counts as ground (about 45°).
pub const GROUND_NORMAL_MIN_Z: f64 = 0.7;

/// Tag given to the terrain's [`PrimitiveInfo`].
pub const TERRAIN_TAG: &str = "terrain";

/// What kind of shape a primitive is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PrimitiveKind {
    /// A finite cylinder between two points.
    Cylinder,
    /// A capsule (segment swept by a sphere).
    Capsule,
    /// A box rotated about z.
    Box,
    /// A sphere.
    Sphere,
    /// An infinite plane.
    Plane,
    /// The terrain height field.
    HeightField,
    /// A solid mission item (a sphere of [`ITEM_RADIUS_M`]).
    Item,
}

/// What the sensors and noise models need to know about a primitive.
#[derive(Debug, Clone, PartialEq)]
pub struct PrimitiveInfo {
    /// Its kind.
    pub kind: PrimitiveKind,
    /// What it is ("cable", "wall", ...; an item's `kind`; [`TERRAIN_TAG`] for the terrain).
    pub tag: String,
    /// Its surface returns no depth.
    pub dark: bool,
    /// Smallest cross-section [m]: diameter of a cylinder, capsule, sphere or item, smallest
    /// side of a box, `f64::INFINITY` for planes and the terrain.
    pub width_m: f64,
}

/// The nearest surface a ray meets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Distance from the ray origin along the unit direction [m].
    pub distance_m: f64,
    /// The hit point, world frame [m].
    pub point: DVec3,
    /// Unit surface normal at the hit, facing the ray (`normal · dir <= 0`).
    pub normal: DVec3,
    /// The primitive hit.
    pub primitive: PrimitiveId,
}

/// The nearest hit of a ray of a fan ([`World::cast_fan`]): [`RayHit`] less the point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FanHit {
    /// Distance along the unit direction [m].
    pub(crate) t: f64,
    /// Unit surface normal facing the ray (zero when the cast was asked for no normals).
    pub(crate) normal: DVec3,
    pub(crate) primitive: PrimitiveId,
}

/// Receives the results of a fan cast ([`World::cast_fan`]): ray index, world direction, hit.
pub(crate) trait FanSink {
    fn put(&mut self, k: usize, d: DVec3, hit: Option<FanHit>);
}

impl<F: FnMut(usize, DVec3, Option<FanHit>)> FanSink for F {
    #[inline(always)]
    fn put(&mut self, k: usize, d: DVec3, hit: Option<FanHit>) {
        self(k, d, hit)
    }
}

impl FanHit {
    /// The [`RayHit`] of the ray `o + t·d`.
    pub(crate) fn ray_hit(self, o: DVec3, d: DVec3) -> RayHit {
        RayHit { distance_m: self.t, point: o + d * self.t, normal: self.normal, primitive: self.primitive }
    }
}

/// A world's geometry, ready for queries. Built once by [`World::from_spec`] or
/// [`World::from_toml_str`]; immutable, `Send + Sync`.
#[derive(Debug, Clone)]
pub struct World {
    spec: WorldSpec,
    infos: Vec<PrimitiveInfo>,
    /// Bounded primitives in id order (index = id).
    solids: Vec<Solid>,
    /// Flat BVH over the loosened boxes of `solids`, for ray casts.
    bvh: FlatBvh,
    /// The same primitives as parry shapes, for point queries; `None` when there are none.
    compound: Option<Compound>,
    planes: Vec<Plane>,
    terrain: Option<Terrain>,
    bounds: (DVec3, DVec3),
}

/// An exact f64 bounded primitive.
#[derive(Debug, Clone, Copy)]
enum Solid {
    Sphere { centre: DVec3, radius: f64 },
    /// `axis` is unit length (or zero when `length == 0`).
    Capsule { a: DVec3, axis: DVec3, length: f64, radius: f64 },
    /// `axis` is unit length, `length > 0`.
    Cylinder { a: DVec3, axis: DVec3, length: f64, radius: f64 },
    /// Rotated by yaw about z: `cos`, `sin` of the yaw.
    Box { centre: DVec3, half: DVec3, cos: f64, sin: f64 },
}

/// An infinite plane; solid behind.
#[derive(Debug, Clone, Copy)]
struct Plane {
    point: DVec3,
    /// Unit normal, pointing out of the solid.
    normal: DVec3,
    id: PrimitiveId,
}

/// Terrain: the spec's grid (holes filled) in f64, and the parry height field built from it.
#[derive(Debug, Clone)]
struct Terrain {
    id: PrimitiveId,
    origin: [f64; 2],
    resolution: f64,
    rows: usize,
    cols: usize,
    /// `heights[r * cols + c]`, spec order, holes replaced by a neighbour's height.
    heights: Vec<f64>,
    /// `removed[r * (cols - 1) + c]`: spec cell (r, c) touches a hole.
    removed: Vec<bool>,
    any_cell: bool,
    /// Parry height field; local frame: x = world x, y = world z, z = -world y, centred at
    /// `centre` (world x, y of the grid's middle, z = 0).
    shape: HeightField,
    centre: [f64; 2],
    min_z: f64,
    max_z: f64,
    /// Bounds of the grid (x, y) and of its heights (z) [m].
    lo: DVec3,
    hi: DVec3,
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

/// An intersection found by an exact leaf test.
#[derive(Debug, Clone, Copy)]
struct LeafHit {
    t: f64,
    /// Outward unit normal, or `-dir` when the ray starts inside.
    normal: DVec3,
}

impl World {
    /// Validates `spec` and builds the world. Every value is checked once: coordinates and
    /// sizes finite (|value| <= [`MAX_COORDINATE_M`]), radii and sizes > 0, cylinder ends
    /// distinct, plane normals non-zero, the height field at least 2 x 2 and rectangular,
    /// region names unique and non-empty, routes naming existing regions.
    ///
    /// # Errors
    /// [`SimError::InvalidWorld`] naming the field, e.g. `cylinder[3].radius`.
    pub fn from_spec(spec: WorldSpec) -> SimResult<World> {
        validate(&spec)?;
        Ok(build(spec))
    }

    /// Parses a TOML world (format: `docs/world-format.md`) and builds it.
    ///
    /// # Errors
    /// [`SimError::InvalidWorld`] with `field = "line L, column C"` for syntax errors, unknown
    /// keys and wrong types; the field's name for invalid values.
    pub fn from_toml_str(text: &str) -> SimResult<World> {
        let spec: WorldSpec = subterra::error::parse_toml_located(text).map_err(|(at, message)| SimError::world(at, message))?;
        World::from_spec(spec)
    }

    /// The description this world was built from.
    pub fn spec(&self) -> &WorldSpec {
        &self.spec
    }

    /// What primitive `id` is; `None` for an unknown id.
    pub fn primitive(&self, id: PrimitiveId) -> Option<&PrimitiveInfo> {
        self.infos.get(id as usize)
    }

    /// Number of primitives (ids are `0..primitive_count()`).
    pub fn primitive_count(&self) -> usize {
        self.infos.len()
    }

    /// All primitives, indexed by id.
    pub fn primitives(&self) -> &[PrimitiveInfo] {
        &self.infos
    }

    /// The named region, if any.
    pub fn region(&self, name: &str) -> Option<&RegionSpec> {
        self.spec.regions.iter().find(|r| r.name == name)
    }

    /// Axis-aligned bounds `(min, max)` of the bounded geometry (primitives, solid items,
    /// terrain) [m]. Planes are unbounded and not included; a world without bounded geometry
    /// gives `(0, 0)`.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.bounds
    }

    /// The nearest surface along the ray `origin + t·dir`, `0 <= t <= max_range_m` [m].
    ///
    /// `dir` should be unit length (it is normalised here; `distance_m` is in metres either
    /// way). Bounded primitives are found through a bounding-volume hierarchy; planes
    /// analytically; the terrain with a two-level cell walk. A ray starting inside a bounded
    /// primitive or behind a plane hits at distance 0. `None`: no hit in range, or a
    /// non-finite or zero input (`max_range_m` may be `f64::INFINITY`). When two bounded
    /// primitives are hit at exactly the same distance, the lower id is reported.
    pub fn cast_ray(&self, origin: DVec3, dir: DVec3, max_range_m: f64) -> Option<RayHit> {
        if !origin.is_finite() || !dir.is_finite() || max_range_m.is_nan() || max_range_m < 0.0 {
            return None;
        }
        let len = dir.length();
        if len <= 0.0 {
            return None;
        }
        self.cast_unit(origin, dir / len, max_range_m)
    }

    /// Many rays from one origin: `out[i]` is [`World::cast_ray`]`(origin, dirs[i],
    /// max_ranges[i])` (bit for bit). `max_ranges` holds one range per direction, or a single
    /// range for all [m]. Faster than a loop of `cast_ray` when the rays are many (hundreds
    /// or more): the primitives are culled once per fan of rays (see the module notes) instead
    /// of once per ray.
    ///
    /// # Errors
    /// [`SimError::InvalidInput`] when `max_ranges` or `out` does not match `dirs` in length.
    pub fn cast_rays(&self, origin: DVec3, dirs: &[DVec3], max_ranges: &[f64], out: &mut [Option<RayHit>]) -> SimResult<()> {
        if max_ranges.len() != dirs.len() && max_ranges.len() != 1 {
            return Err(SimError::input("max_ranges", format!("has {} values for {} directions (give one per direction, or one for all)", max_ranges.len(), dirs.len())));
        }
        if out.len() != dirs.len() {
            return Err(SimError::input("out", format!("has {} slots for {} directions", out.len(), dirs.len())));
        }
        out.fill(None);
        if !origin.is_finite() {
            return Ok(());
        }
        let range_of = |i: usize| if max_ranges.len() == 1 { max_ranges[0] } else { max_ranges[i] };
        // Unit directions are used as given; others are normalised (and invalid ones skipped),
        // exactly as `cast_ray` does.
        let mut index = Vec::with_capacity(dirs.len());
        let mut units = Vec::with_capacity(dirs.len());
        for (i, &d) in dirs.iter().enumerate() {
            let len = d.length();
            let range = range_of(i);
            if d.is_finite() && len > 0.0 && !range.is_nan() && range >= 0.0 {
                index.push(i);
                units.push(d / len);
            }
        }
        self.cast_fan::<true, _, _>(origin, DMat3::IDENTITY, &units, &|k| range_of(index[k]), &mut |k, d, hit: Option<FanHit>| out[index[k]] = hit.map(|h| h.ray_hit(origin, d)));
        Ok(())
    }

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

    /// [`World::cast_ray`] for a unit `d`.
    fn cast_unit(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<RayHit> {
        self.cast_unit_in(o, d, max_t, None).map(|h| h.ray_hit(o, d))
    }

    /// [`World::cast_unit`], the terrain culled through `view` (from `o`) when given.
    fn cast_unit_in(&self, o: DVec3, d: DVec3, max_t: f64, view: Option<&TerrainView>) -> Option<FanHit> {
        let mut best = self.nearest_plane(o, d, max_t);
        let limit = best.map_or(max_t, |(h, _)| h.t);
        if let Some((id, hit)) = self.bvh.cast(&self.solids, o, d, limit) {
            if best.is_none() || hit.t < limit {
                best = Some((hit, id));
            }
        }
        self.finish::<true>(o, d, max_t, best.map(|(hit, id)| FanHit { t: hit.t, normal: hit.normal, primitive: id }), true, view)
    }

    /// Nearest plane hit within `max_t` (planes are few and unbounded).
    fn nearest_plane(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<(LeafHit, PrimitiveId)> {
        let mut best: Option<(LeafHit, PrimitiveId)> = None;
        let mut limit = max_t;
        for plane in &self.planes {
            if let Some(hit) = plane.cast(o, d, limit) {
                if best.is_none() || hit.t < limit {
                    limit = hit.t;
                    best = Some((hit, plane.id));
                }
            }
        }
        best
    }

    /// Adds the terrain (when `terrain`) to `best` and turns the normal toward the ray
    /// (when `NORMALS`).
    #[inline(always)]
    fn finish<const NORMALS: bool>(&self, o: DVec3, d: DVec3, max_t: f64, mut best: Option<FanHit>, terrain: bool, view: Option<&TerrainView>) -> Option<FanHit> {
        if terrain {
            if let Some(t) = &self.terrain {
                let limit = best.map_or(max_t, |h| h.t);
                let hit = match view {
                    Some(view) => t.cast_in_view::<NORMALS>(view, o, d, limit),
                    None => t.cast(o, d, limit),
                };
                if let Some(hit) = hit {
                    if best.is_none() || hit.t < limit {
                        best = Some(FanHit { t: hit.t, normal: hit.normal, primitive: t.id });
                    }
                }
            }
        }
        if NORMALS {
            if let Some(h) = &mut best {
                if h.normal.dot(d) > 0.0 {
                    h.normal = -h.normal;
                }
            }
        }
        best
    }

    /// Euclidean distance from `p` to the nearest solid surface [m]: bounded primitives
    /// (parry point query), planes (signed, negative behind) and the terrain (negative when
    /// `p` is below it where it covers `p` and is not a hole). Negative or zero when `p` is
    /// inside a solid; `f64::INFINITY` in an empty world; NaN for a non-finite `p`.
    pub fn clearance(&self, p: DVec3) -> f64 {
        if !p.is_finite() {
            return f64::NAN;
        }
        let mut best = f64::INFINITY;
        if let Some(compound) = &self.compound {
            let q = to_f32(p);
            let d = if compound.contains_local_point(q) {
                // Inside: the distance to the nearest boundary, negated.
                -f64::from(compound.distance_to_local_point(q, false).abs())
            } else {
                f64::from(compound.distance_to_local_point(q, true))
            };
            best = best.min(d);
        }
        for plane in &self.planes {
            best = best.min(plane.normal.dot(p - plane.point));
        }
        if let Some(terrain) = &self.terrain {
            if let Some(d) = terrain.clearance(p) {
                best = best.min(d);
            }
        }
        best
    }

    /// Height of the ground at `(x, y)` [m]: the terrain's surface there when the height field
    /// covers the point (the same triangles the ray casts see) — `None` over a hole —, else the
    /// highest upward-facing plane (`normal.z > GROUND_NORMAL_MIN_Z`) there, else `None`.
    pub fn ground_height(&self, x: f64, y: f64) -> Option<f64> {
        if !x.is_finite() || !y.is_finite() {
            return None;
        }
        if let Some(terrain) = &self.terrain {
            if terrain.covers(x, y) {
                return terrain.height_at(x, y);
            }
        }
        self.planes
            .iter()
            .filter(|pl| pl.normal.z > GROUND_NORMAL_MIN_Z)
            .map(|pl| pl.point.z - (pl.normal.x * (x - pl.point.x) + pl.normal.y * (y - pl.point.y)) / pl.normal.z)
            .fold(None, |acc: Option<f64>, h| Some(acc.map_or(h, |a| a.max(h))))
    }
}

/// 1 / component, kept finite for the slab test (`|d| < 1e-30` counts as 1e-30).
fn inv_component(d: f64) -> f32 {
    const TINY: f64 = 1.0e-30;
    let d = if d.abs() < TINY { TINY.copysign(d) } else { d };
    (1.0 / d) as f32
}

fn to_f32(p: DVec3) -> Vector {
    Vector::new(p.x as f32, p.y as f32, p.z as f32)
}

// ---------------------------------------------------------------------------------------------
// Ray-cast acceleration: a flat BVH for single rays, per-fan culling for bundles of rays.

/// Largest number of primitives in a BVH leaf.
const BVH_LEAF_SIZE: usize = 2;
/// Depth of the traversal stack; the builder never makes a deeper tree.
const BVH_STACK: usize = 64;
/// Depth from which the builder splits at the median (so the depth stays below `BVH_STACK`).
const BVH_MEDIAN_DEPTH: usize = 32;
/// Centroid bins of the surface-area split.
const BVH_BINS: usize = 12;
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

/// Whether a hit at `t` on primitive `id` beats `best` (nearest first, then the lower id),
/// `t <= limit`. The order of testing then never changes the answer.
fn improves(t: f64, id: PrimitiveId, limit: f64, best: Option<(PrimitiveId, LeafHit)>) -> bool {
    t <= limit && best.is_none_or(|(bid, b)| t < b.t || (t == b.t && id < bid))
}

/// f32 bound on the distance of a node worth visiting, loosened so that f32 rounding never
/// culls an f64 hit at `limit`.
fn cutoff32(limit: f64) -> f32 {
    if limit.is_finite() {
        (limit as f32) * (1.0 + 1.0e-5) + 1.0e-4
    } else {
        f32::MAX
    }
}

/// A BVH node: its (loosened, f32) box and either two children or a run of primitives.
#[derive(Debug, Clone, Copy, Default)]
struct FlatNode {
    min: [f32; 3],
    /// Interior: index of the first child (the second follows); leaf: first index into `items`.
    first: u32,
    max: [f32; 3],
    /// 0 for an interior node, else the number of primitives of the leaf.
    count: u32,
}

/// A bounding-volume hierarchy over the bounded primitives, stored flat (depth-first,
/// children adjacent), built with binned surface-area splits.
#[derive(Debug, Clone, Default)]
struct FlatBvh {
    nodes: Vec<FlatNode>,
    /// Primitive ids in leaf order.
    items: Vec<u32>,
    /// Loosened f64 box (min, max) of every primitive, by id.
    boxes: Vec<(DVec3, DVec3)>,
}

/// A ray in f32 for box tests: origin and finite inverse direction.
struct Ray32 {
    o: [f32; 3],
    inv: [f32; 3],
}

impl Ray32 {
    fn new(o: DVec3, d: DVec3) -> Ray32 {
        Ray32 { o: [o.x as f32, o.y as f32, o.z as f32], inv: [inv_component(d.x), inv_component(d.y), inv_component(d.z)] }
    }

    /// Entry distance into the node's box when it is entered before `cutoff`.
    #[inline(always)]
    fn enter(&self, n: &FlatNode, cutoff: f32) -> Option<f32> {
        let tx1 = (n.min[0] - self.o[0]) * self.inv[0];
        let tx2 = (n.max[0] - self.o[0]) * self.inv[0];
        let ty1 = (n.min[1] - self.o[1]) * self.inv[1];
        let ty2 = (n.max[1] - self.o[1]) * self.inv[1];
        let tz1 = (n.min[2] - self.o[2]) * self.inv[2];
        let tz2 = (n.max[2] - self.o[2]) * self.inv[2];
        let t_near = tx1.min(tx2).max(ty1.min(ty2)).max(tz1.min(tz2)).max(0.0);
        let t_far = tx1.max(tx2).min(ty1.max(ty2)).min(tz1.max(tz2)).min(cutoff);
        (t_near <= t_far).then_some(t_near)
    }
}

fn half_area(lo: DVec3, hi: DVec3) -> f64 {
    let e = (hi - lo).max(DVec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

impl FlatBvh {
    fn build(boxes: Vec<(DVec3, DVec3)>) -> FlatBvh {
        let n = boxes.len();
        let mut bvh = FlatBvh { nodes: Vec::with_capacity(2 * n), items: (0..n as u32).collect(), boxes };
        if n > 0 {
            bvh.nodes.push(FlatNode::default());
            bvh.subdivide(0, 0, n, 0);
        }
        bvh
    }

    fn centroid(&self, id: u32) -> DVec3 {
        let (lo, hi) = self.boxes[id as usize];
        (lo + hi) * 0.5
    }

    fn subdivide(&mut self, node: usize, start: usize, end: usize, depth: usize) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        let mut clo = lo;
        let mut chi = hi;
        for &id in &self.items[start..end] {
            let (a, b) = self.boxes[id as usize];
            lo = lo.min(a);
            hi = hi.max(b);
            let c = (a + b) * 0.5;
            clo = clo.min(c);
            chi = chi.max(c);
        }
        // The f64 boxes are loosened far beyond f32 rounding: plain conversion stays conservative.
        self.nodes[node].min = [lo.x as f32, lo.y as f32, lo.z as f32];
        self.nodes[node].max = [hi.x as f32, hi.y as f32, hi.z as f32];
        let count = end - start;
        if count <= BVH_LEAF_SIZE || depth + 2 >= BVH_STACK {
            self.nodes[node].first = start as u32;
            self.nodes[node].count = count as u32;
            return;
        }
        let extent = chi - clo;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mut mid = start + count / 2;
        let binned = depth < BVH_MEDIAN_DEPTH && extent[axis] > 0.0;
        if binned {
            let scale = BVH_BINS as f64 / extent[axis];
            let bin_of = |c: DVec3| (((c[axis] - clo[axis]) * scale) as usize).min(BVH_BINS - 1);
            let mut bins = [(0usize, DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)); BVH_BINS];
            for &id in &self.items[start..end] {
                let (a, b) = self.boxes[id as usize];
                let bin = &mut bins[bin_of((a + b) * 0.5)];
                bin.0 += 1;
                bin.1 = bin.1.min(a);
                bin.2 = bin.2.max(b);
            }
            // Cost of splitting after bin s: left area x count + right area x count.
            let mut right_cost = [0.0; BVH_BINS];
            let (mut n, mut a, mut b) = (0usize, DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            for s in (1..BVH_BINS).rev() {
                n += bins[s].0;
                a = a.min(bins[s].1);
                b = b.max(bins[s].2);
                right_cost[s] = if n > 0 { half_area(a, b) * n as f64 } else { 0.0 };
            }
            let (mut n, mut a, mut b) = (0usize, DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            let mut best = (f64::INFINITY, 0usize);
            for s in 1..BVH_BINS {
                n += bins[s - 1].0;
                a = a.min(bins[s - 1].1);
                b = b.max(bins[s - 1].2);
                if n == 0 || n == count {
                    continue;
                }
                let cost = half_area(a, b) * n as f64 + right_cost[s];
                if cost < best.0 {
                    best = (cost, s);
                }
            }
            if best.1 > 0 {
                let split = best.1;
                let (mut i, mut j) = (start, end);
                while i < j {
                    if bin_of(self.centroid(self.items[i])) < split {
                        i += 1;
                    } else {
                        j -= 1;
                        self.items.swap(i, j);
                    }
                }
                mid = i;
            }
        }
        if !binned || mid == start || mid == end {
            mid = start + count / 2;
            let boxes = &self.boxes;
            let key = |id: &u32| {
                let (a, b) = boxes[*id as usize];
                a[axis] + b[axis]
            };
            self.items[start..end].sort_by(|x, y| key(x).total_cmp(&key(y)).then(x.cmp(y)));
        }
        let left = self.nodes.len();
        self.nodes.push(FlatNode::default());
        self.nodes.push(FlatNode::default());
        self.nodes[node].first = left as u32;
        self.nodes[node].count = 0;
        self.subdivide(left, start, mid, depth + 1);
        self.subdivide(left + 1, mid, end, depth + 1);
    }

    /// Nearest primitive hit along the unit ray within `max_t` (nearest, then lowest id).
    fn cast(&self, solids: &[Solid], o: DVec3, d: DVec3, max_t: f64) -> Option<(PrimitiveId, LeafHit)> {
        let root = self.nodes.first()?;
        let ray = Ray32::new(o, d);
        let mut cutoff = cutoff32(max_t);
        ray.enter(root, cutoff)?;
        let mut best: Option<(PrimitiveId, LeafHit)> = None;
        let mut limit = max_t;
        let mut stack = [(0u32, 0.0f32); BVH_STACK];
        let mut sp = 0usize;
        let mut node = 0usize;
        loop {
            let n = self.nodes[node];
            if n.count > 0 {
                let first = n.first as usize;
                for &id in &self.items[first..first + n.count as usize] {
                    if let Some(hit) = solids[id as usize].cast(o, d) {
                        if improves(hit.t, id, limit, best) {
                            limit = hit.t;
                            cutoff = cutoff32(limit);
                            best = Some((id, hit));
                        }
                    }
                }
            } else {
                let a = n.first as usize;
                let ta = ray.enter(&self.nodes[a], cutoff);
                let tb = ray.enter(&self.nodes[a + 1], cutoff);
                match (ta, tb) {
                    (Some(ta), Some(tb)) => {
                        let (near, far, t_far) = if ta <= tb { (a, a + 1, tb) } else { (a + 1, a, ta) };
                        stack[sp] = (far as u32, t_far);
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = a;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = a + 1;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let (next, t) = stack[sp];
                if t <= cutoff {
                    node = next as usize;
                    break;
                }
            }
        }
    }

    /// Ids of the primitives whose boxes may meet `frustum`, through the tree.
    fn visible(&self, frustum: &Frustum, out: &mut Vec<u32>) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = Vec::with_capacity(BVH_STACK);
        stack.push(0usize);
        while let Some(node) = stack.pop() {
            let n = self.nodes[node];
            let lo = DVec3::new(f64::from(n.min[0]), f64::from(n.min[1]), f64::from(n.min[2]));
            let hi = DVec3::new(f64::from(n.max[0]), f64::from(n.max[1]), f64::from(n.max[2]));
            if !frustum.meets(lo, hi) {
                continue;
            }
            if n.count > 0 {
                let first = n.first as usize;
                for &id in &self.items[first..first + n.count as usize] {
                    let (a, b) = self.boxes[id as usize];
                    if frustum.meets(a, b) {
                        out.push(id);
                    }
                }
            } else {
                stack.push(n.first as usize + 1);
                stack.push(n.first as usize);
            }
        }
    }
}

/// The pyramid (apex `origin`) of a fan's rays, cut at `range`: four side planes through the
/// apex, normals pointing inside.
struct Frustum {
    origin: DVec3,
    normals: [DVec3; 4],
    range: f64,
}

impl Frustum {
    /// Whether the box `(lo, hi)` may meet the pyramid (conservative).
    fn meets(&self, lo: DVec3, hi: DVec3) -> bool {
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
        PLAN_SCRATCH.try_with(|s| s.take()).unwrap_or_default()
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

// ---------------------------------------------------------------------------------------------
// Exact f64 leaf tests.

impl Solid {
    /// First intersection with `t >= 0` of the ray `o + t·d` (`d` unit).
    fn cast(&self, o: DVec3, d: DVec3) -> Option<LeafHit> {
        self.prepare(o).cast(o, d)
    }

    /// The terms of the ray test that depend on the ray origin `o` only (shared by a fan).
    fn prepare(&self, o: DVec3) -> Prepared {
        match *self {
            Solid::Sphere { centre, radius } => match SpherePrep::new(o, centre, radius) {
                Some(s) => Prepared::Sphere { centre, radius, s },
                None => Prepared::Inside,
            },
            Solid::Cylinder { a, axis, length, radius } => {
                let oa = o - a;
                let s0 = oa.dot(axis);
                let op = oa - axis * s0;
                let r2 = radius * radius;
                if (0.0..=length).contains(&s0) && op.length_squared() <= r2 {
                    return Prepared::Inside;
                }
                Prepared::Cylinder { a, axis, length, radius, s0, op, c: op.length_squared() - r2 }
            }
            Solid::Capsule { a, axis, length, radius } => {
                let oa = o - a;
                let clamped = oa.dot(axis).clamp(0.0, length);
                if (oa - axis * clamped).length_squared() <= radius * radius {
                    return Prepared::Inside;
                }
                let s0 = oa.dot(axis);
                let op = oa - axis * s0;
                let b = a + axis * length;
                // Outside the capsule, hence outside both end spheres (their `c > 0`) up to
                // rounding; an end sphere that still counts the origin inside reports t = 0.
                let end = |centre: DVec3| SpherePrep::new(o, centre, radius).map_or((centre, SpherePrep { oc: DVec3::ZERO, c: -1.0 }), |s| (centre, s));
                Prepared::Capsule { a, axis, length, radius, s0, op, c: op.length_squared() - radius * radius, ends: [end(a), end(b)] }
            }
            Solid::Box { centre, half, cos, sin } => {
                let v = o - centre;
                let ol = DVec3::new(cos * v.x + sin * v.y, -sin * v.x + cos * v.y, v.z);
                // The slab distances' numerators, as `ray_box_t` computed them per ray.
                Prepared::Box { half, cos, sin, ol, near: -half - ol, far: half - ol }
            }
        }
    }

    /// Axis-aligned bounds (min, max) [m].
    fn aabb(&self) -> (DVec3, DVec3) {
        match *self {
            Solid::Sphere { centre, radius } => (centre - DVec3::splat(radius), centre + DVec3::splat(radius)),
            Solid::Capsule { a, axis, length, radius } => {
                let b = a + axis * length;
                (a.min(b) - DVec3::splat(radius), a.max(b) + DVec3::splat(radius))
            }
            Solid::Cylinder { a, axis, length, radius } => {
                let b = a + axis * length;
                // The end discs reach r·sqrt(1 - u_k²) along axis k.
                let e = (DVec3::ONE - axis * axis).max(DVec3::ZERO);
                let e = DVec3::new(e.x.sqrt(), e.y.sqrt(), e.z.sqrt()) * radius;
                (a.min(b) - e, a.max(b) + e)
            }
            Solid::Box { centre, half, cos, sin } => {
                let e = DVec3::new(cos.abs() * half.x + sin.abs() * half.y, sin.abs() * half.x + cos.abs() * half.y, half.z);
                (centre - e, centre + e)
            }
        }
    }
}

/// Origin terms of a ray against a sphere: `oc = o - centre`, `c = |oc|² - r² > 0`.
#[derive(Debug, Clone, Copy)]
struct SpherePrep {
    oc: DVec3,
    c: f64,
}

impl SpherePrep {
    /// `None` when the origin is inside (or on) the sphere.
    fn new(o: DVec3, centre: DVec3, radius: f64) -> Option<SpherePrep> {
        let oc = o - centre;
        let c = oc.length_squared() - radius * radius;
        (c > 0.0).then_some(SpherePrep { oc, c })
    }
}

/// A solid with the origin terms of its ray test computed ([`Solid::prepare`]).
#[derive(Debug, Clone, Copy)]
enum Prepared {
    /// The origin is inside: every ray hits at 0.
    Inside,
    Sphere { centre: DVec3, radius: f64, s: SpherePrep },
    /// `s0`, `op`: the origin's position along and across the axis; `c = |op|² - r²`.
    Cylinder { a: DVec3, axis: DVec3, length: f64, radius: f64, s0: f64, op: DVec3, c: f64 },
    /// As the cylinder, and the end spheres (centre, terms; `c <= 0`: origin inside it).
    Capsule { a: DVec3, axis: DVec3, length: f64, radius: f64, s0: f64, op: DVec3, c: f64, ends: [(DVec3, SpherePrep); 2] },
    /// `ol`: the origin in the box frame; `near = -half - ol`, `far = half - ol`.
    Box { half: DVec3, cos: f64, sin: f64, ol: DVec3, near: DVec3, far: DVec3 },
}

/// Face tag of a leaf hit whose ray starts inside the solid (normal `-dir`).
const FACE_INSIDE: u8 = 7;

impl Prepared {
    /// First intersection with `t >= 0` of the ray `o + t·d` (`d` unit; `o` the prepared origin).
    #[inline]
    fn cast(&self, o: DVec3, d: DVec3) -> Option<LeafHit> {
        let (t, face) = self.cast_t(d)?;
        Some(LeafHit { t, normal: self.normal(o, d, t, face) })
    }

    /// [`Prepared::cast`] without the normal: the distance and a tag of the face hit, from
    /// which [`Prepared::normal`] gives the normal (the same values as computed together).
    #[inline(always)]
    fn cast_t(&self, d: DVec3) -> Option<(f64, u8)> {
        match *self {
            Prepared::Inside => Some((0.0, FACE_INSIDE)),
            Prepared::Sphere { radius, s, .. } => ray_sphere_t(d, radius, s).map(|t| (t, 0)),
            Prepared::Cylinder { axis, length, radius, s0, op, c, .. } => {
                let du = d.dot(axis);
                let dp = d - axis * du;
                let mut best: Option<(f64, u8)> = None;
                if let Some(t) = ray_infinite_cylinder(op, dp, radius, c) {
                    let s = s0 + t * du;
                    if (0.0..=length).contains(&s) {
                        best = Some((t, 0));
                    }
                }
                if du != 0.0 {
                    let r2 = radius * radius;
                    for (cap_s, face) in [(0.0, 1), (length, 2)] {
                        let t = (cap_s - s0) / du;
                        if t >= 0.0 && best.is_none_or(|b| t < b.0) && (op + dp * t).length_squared() <= r2 {
                            best = Some((t, face));
                        }
                    }
                }
                best
            }
            Prepared::Capsule { axis, length, radius, s0, op, c, ends, .. } => {
                let mut best: Option<(f64, u8)> = None;
                if length > 0.0 {
                    let du = d.dot(axis);
                    let dp = d - axis * du;
                    if let Some(t) = ray_infinite_cylinder(op, dp, radius, c) {
                        let s = s0 + t * du;
                        if (0.0..=length).contains(&s) {
                            best = Some((t, 0));
                        }
                    }
                }
                for (face, (_, s)) in [(1, ends[0]), (2, ends[1])] {
                    let hit = if s.c > 0.0 { ray_sphere_t(d, radius, s).map(|t| (t, face)) } else { Some((0.0, FACE_INSIDE)) };
                    if let Some(hit) = hit {
                        if best.is_none_or(|b| hit.0 < b.0) {
                            best = Some(hit);
                        }
                    }
                }
                best
            }
            Prepared::Box { cos, sin, near, far, .. } => ray_box_t(d, cos, sin, near, far),
        }
    }

    /// Outward normal of the hit at `t` on face `face` found by [`Prepared::cast_t`] for the same ray.
    #[inline(always)]
    fn normal(&self, o: DVec3, d: DVec3, t: f64, face: u8) -> DVec3 {
        if face == FACE_INSIDE {
            return -d;
        }
        match *self {
            Prepared::Inside => -d,
            Prepared::Sphere { centre, radius, .. } => sphere_normal(o, d, t, centre, radius),
            Prepared::Cylinder { a, axis, s0, .. } => match face {
                0 => {
                    let s = s0 + t * d.dot(axis);
                    (o + d * t - a - axis * s).normalize_or(-d)
                }
                1 => -axis,
                _ => axis,
            },
            Prepared::Capsule { a, axis, radius, s0, ends, .. } => match face {
                0 => {
                    let s = s0 + t * d.dot(axis);
                    (o + d * t - a - axis * s).normalize_or(-d)
                }
                1 => sphere_normal(o, d, t, ends[0].0, radius),
                _ => sphere_normal(o, d, t, ends[1].0, radius),
            },
            Prepared::Box { cos, sin, .. } => {
                let s = if face & 1 == 0 { -1.0 } else { 1.0 };
                match face >> 1 {
                    0 => DVec3::new(cos * s, sin * s, 0.0),
                    1 => DVec3::new(-sin * s, cos * s, 0.0),
                    _ => DVec3::new(0.0, 0.0, s),
                }
            }
        }
    }
}

fn inside_hit(d: DVec3) -> LeafHit {
    LeafHit { t: 0.0, normal: -d }
}

/// Ray against a sphere (solid) whose origin is outside it (`s`): the distance of the hit.
#[inline]
fn ray_sphere_t(d: DVec3, radius: f64, s: SpherePrep) -> Option<f64> {
    let b = s.oc.dot(d);
    if b >= 0.0 {
        return None;
    }
    // Discriminant from the perpendicular miss distance (no cancellation far away).
    let q = s.oc - d * b;
    let disc = radius * radius - q.length_squared();
    if disc < 0.0 {
        return None;
    }
    // Smaller root, in the cancellation-free form c / (-b + sqrt(disc)).
    Some(s.c / (-b + disc.sqrt()))
}

/// Outward normal of a sphere at the ray's point at `t`.
#[inline]
fn sphere_normal(o: DVec3, d: DVec3, t: f64, centre: DVec3, radius: f64) -> DVec3 {
    ((o + d * t - centre) / radius).normalize_or(-d)
}

/// Entry into the infinite cylinder of radius `radius` around an axis, from outside it:
/// `op` is the origin's offset across the axis, `dp` the direction's, `c = |op|² - r²`.
/// Returns the distance of the hit.
#[inline]
fn ray_infinite_cylinder(op: DVec3, dp: DVec3, radius: f64, c: f64) -> Option<f64> {
    let qa = dp.length_squared();
    if qa < 1.0e-24 || c <= 0.0 {
        return None;
    }
    let qb = op.dot(dp);
    if qb >= 0.0 {
        return None;
    }
    // qb² - qa·c = qa·r² - |op × dp|² (Lagrange), free of cancellation.
    let disc = qa * radius * radius - op.cross(dp).length_squared();
    if disc < 0.0 {
        return None;
    }
    Some(c / (-qb + disc.sqrt()))
}

/// Ray against a box of half extents `half` rotated by yaw (`cos`, `sin`) about z (solid),
/// the ray origin `ol` in the box frame given as `near = -half - ol` and `far = half - ol`.
/// The distance and the face entered (`2 · axis`, `+ 1` on the positive side;
/// [`FACE_INSIDE`] from inside).
#[inline]
fn ray_box_t(d: DVec3, cos: f64, sin: f64, near: DVec3, far: DVec3) -> Option<(f64, u8)> {
    let dl = DVec3::new(cos * d.x + sin * d.y, -sin * d.x + cos * d.y, d.z);
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    // Entering face.
    let mut enter = 0u8;
    #[inline(always)]
    fn slab(a: f64, b: f64, dk: f64, k: u8, t_near: &mut f64, t_far: &mut f64, enter: &mut u8) -> bool {
        if dk == 0.0 {
            // |ol| <= half: -half - ol <= 0 <= half - ol (a difference of floats has the sign
            // of the exact one).
            return a <= 0.0 && b >= 0.0;
        }
        let inv = 1.0 / dk;
        let t1 = a * inv;
        let t2 = b * inv;
        let (tn, tf, face) = if t1 < t2 { (t1, t2, 2 * k) } else { (t2, t1, 2 * k + 1) };
        if tn > *t_near {
            *t_near = tn;
            *enter = face;
        }
        // What `t_far.min(tf)` gives (`t_far` is never NaN; a NaN `tf` leaves it), as a
        // select (one `minsd`) instead of `min`'s NaN blend.
        *t_far = if tf < *t_far { tf } else { *t_far };
        true
    }
    if !slab(near.x, far.x, dl.x, 0, &mut t_near, &mut t_far, &mut enter)
        || !slab(near.y, far.y, dl.y, 1, &mut t_near, &mut t_far, &mut enter)
        || !slab(near.z, far.z, dl.z, 2, &mut t_near, &mut t_far, &mut enter)
    {
        return None;
    }
    if t_far < t_near || t_far < 0.0 {
        return None;
    }
    if t_near <= 0.0 {
        return Some((0.0, FACE_INSIDE));
    }
    Some((t_near, enter))
}

impl Plane {
    /// Ray against the half-space behind the plane, `t <= max_t`.
    fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
        self.cast_prepared(self.normal.dot(o - self.point), d, max_t)
    }

    /// As [`Plane::cast`] with the origin's signed distance `s` to the plane given.
    #[inline]
    fn cast_prepared(&self, s: f64, d: DVec3, max_t: f64) -> Option<LeafHit> {
        if s < 0.0 {
            return Some(inside_hit(d));
        }
        let denom = self.normal.dot(d);
        if denom >= 0.0 {
            return None;
        }
        let t = -s / denom;
        (t <= max_t).then_some(LeafHit { t, normal: self.normal })
    }
}

// ---------------------------------------------------------------------------------------------
// Terrain.

impl Terrain {
    fn new(spec: &HeightFieldSpec, id: PrimitiveId) -> Terrain {
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

    fn covers(&self, x: f64, y: f64) -> bool {
        let fx = (x - self.origin[0]) / self.resolution;
        let fy = (y - self.origin[1]) / self.resolution;
        (0.0..=(self.cols - 1) as f64).contains(&fx) && (0.0..=(self.rows - 1) as f64).contains(&fy)
    }

    /// Surface height at a covered `(x, y)`, on parry's triangulation: cell (r, c) is split
    /// along the diagonal from sample (r, c) to (r + 1, c + 1).
    fn height_at(&self, x: f64, y: f64) -> Option<f64> {
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
    fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
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
    fn cast_in_view<const NORMALS: bool>(&self, view: &TerrainView, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
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
    fn clearance(&self, p: DVec3) -> Option<f64> {
        if !self.any_cell {
            return None;
        }
        let d = f64::from(self.shape.distance_to_local_point(self.to_local(p), true));
        let below = self.covers(p.x, p.y) && self.height_at(p.x, p.y).is_some_and(|h| p.z < h);
        Some(if below { -d } else { d })
    }
}

/// Fans of at least this many rays cull the terrain through a [`TerrainView`].
const TERRAIN_VIEW_MIN_RAYS: usize = 2048;
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
struct TerrainView {
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
    fn new(t: &Terrain, o: DVec3) -> TerrainView {
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

// ---------------------------------------------------------------------------------------------
// Validation and construction.

fn check_point(field: String, v: [f64; 3]) -> SimResult<DVec3> {
    if v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE_M) {
        Ok(DVec3::from_array(v))
    } else {
        Err(SimError::world(field, format!("must be finite and within ±{MAX_COORDINATE_M} m (got {v:?})")))
    }
}

fn check_positive(field: String, v: f64) -> SimResult<f64> {
    if v.is_finite() && v > 0.0 && v <= MAX_COORDINATE_M {
        Ok(v)
    } else {
        Err(SimError::world(field, format!("must be finite and > 0 (got {v})")))
    }
}

fn validate(spec: &WorldSpec) -> SimResult<()> {
    for (i, s) in spec.cylinders.iter().enumerate() {
        let a = check_point(format!("cylinder[{i}].a"), s.a)?;
        let b = check_point(format!("cylinder[{i}].b"), s.b)?;
        check_positive(format!("cylinder[{i}].radius"), s.radius)?;
        if (b - a).length() <= 0.0 {
            return Err(SimError::world(format!("cylinder[{i}].b"), "must differ from `a` (zero length)"));
        }
    }
    for (i, s) in spec.capsules.iter().enumerate() {
        check_point(format!("capsule[{i}].a"), s.a)?;
        check_point(format!("capsule[{i}].b"), s.b)?;
        check_positive(format!("capsule[{i}].radius"), s.radius)?;
    }
    for (i, s) in spec.boxes.iter().enumerate() {
        check_point(format!("box[{i}].centre"), s.centre)?;
        for (k, &v) in s.size.iter().enumerate() {
            check_positive(format!("box[{i}].size[{k}]"), v)?;
        }
        if !s.yaw.is_finite() {
            return Err(SimError::world(format!("box[{i}].yaw"), format!("must be finite (got {})", s.yaw)));
        }
    }
    for (i, s) in spec.spheres.iter().enumerate() {
        check_point(format!("sphere[{i}].centre"), s.centre)?;
        check_positive(format!("sphere[{i}].radius"), s.radius)?;
    }
    for (i, s) in spec.planes.iter().enumerate() {
        check_point(format!("plane[{i}].point"), s.point)?;
        let n = DVec3::from_array(s.normal);
        if !n.is_finite() || !n.normalize_or_zero().is_normalized() {
            return Err(SimError::world(format!("plane[{i}].normal"), format!("must be finite and non-zero (got {:?})", s.normal)));
        }
    }
    if let Some(hf) = &spec.heightfield {
        validate_heightfield(hf)?;
    }
    let mut names: Vec<&str> = Vec::with_capacity(spec.regions.len());
    for (i, r) in spec.regions.iter().enumerate() {
        if r.name.trim().is_empty() {
            return Err(SimError::world(format!("region[{i}].name"), "must not be empty"));
        }
        if let Some(j) = names.iter().position(|n| *n == r.name) {
            return Err(SimError::world(format!("region[{i}].name"), format!("duplicate region name `{}` (also region[{j}])", r.name)));
        }
        names.push(&r.name);
        check_point(format!("region[{i}].centre"), r.centre)?;
        check_positive(format!("region[{i}].radius"), r.radius)?;
    }
    for (i, item) in spec.items.iter().enumerate() {
        check_point(format!("item[{i}].position"), item.position)?;
        let k = item.keep_out_radius;
        if !(k.is_finite() && (0.0..=MAX_COORDINATE_M).contains(&k)) {
            return Err(SimError::world(format!("item[{i}].keep_out_radius"), format!("must be finite and >= 0 (got {k})")));
        }
    }
    for (i, route) in spec.routes.iter().enumerate() {
        for (key, name) in [("from", &route.from), ("to", &route.to)] {
            if !names.contains(&name.as_str()) {
                let known = if names.is_empty() { "none".to_string() } else { names.join(", ") };
                return Err(SimError::world(format!("route[{i}].{key}"), format!("no region named `{name}` (known: {known})")));
            }
        }
    }
    Ok(())
}

fn validate_heightfield(hf: &HeightFieldSpec) -> SimResult<()> {
    check_point("heightfield.origin".to_string(), [hf.origin[0], hf.origin[1], 0.0])?;
    check_positive("heightfield.resolution".to_string(), hf.resolution)?;
    let rows = hf.heights.len();
    let cols = hf.heights.first().map_or(0, Vec::len);
    if rows < 2 || cols < 2 {
        return Err(SimError::world("heightfield.heights", format!("needs at least 2 rows and 2 columns (got {rows} x {cols})")));
    }
    for (r, row) in hf.heights.iter().enumerate() {
        if row.len() != cols {
            return Err(SimError::world(format!("heightfield.heights[{r}]"), format!("has {} values, row 0 has {cols} (rows must all be the same length)", row.len())));
        }
        for (c, &h) in row.iter().enumerate() {
            if !(h.is_nan() || (h.is_finite() && h.abs() <= MAX_COORDINATE_M)) {
                return Err(SimError::world(format!("heightfield.heights[{r}][{c}]"), format!("must be finite, or NaN for a hole (got {h})")));
            }
        }
    }
    if let Some(v) = hf.hole_value {
        if !v.is_finite() {
            return Err(SimError::world("heightfield.hole_value", format!("must be finite (got {v})")));
        }
    }
    let extent = (rows.max(cols) - 1) as f64 * hf.resolution;
    if hf.origin[0].abs() + extent > MAX_COORDINATE_M || hf.origin[1].abs() + extent > MAX_COORDINATE_M {
        return Err(SimError::world("heightfield.resolution", format!("the grid reaches beyond ±{MAX_COORDINATE_M} m")));
    }
    Ok(())
}

/// Builds a validated spec.
fn build(spec: WorldSpec) -> World {
    let mut infos = Vec::new();
    let mut solids = Vec::new();
    let mut parts: Vec<(Pose, SharedShape)> = Vec::new();
    let info = |kind, tag: &str, dark, width_m| PrimitiveInfo { kind, tag: tag.to_string(), dark, width_m };

    for s in &spec.cylinders {
        let (a, b) = (DVec3::from_array(s.a), DVec3::from_array(s.b));
        let length = (b - a).length();
        let axis = (b - a) / length;
        solids.push(Solid::Cylinder { a, axis, length, radius: s.radius });
        let rotation = Rot3::from_rotation_arc(Vector::Y, to_f32(axis).normalize());
        parts.push((Pose::from_parts(to_f32((a + b) * 0.5), rotation), SharedShape::cylinder((length * 0.5) as f32, s.radius as f32)));
        infos.push(info(PrimitiveKind::Cylinder, &s.tag, s.dark, 2.0 * s.radius));
    }
    for s in &spec.capsules {
        let (a, b) = (DVec3::from_array(s.a), DVec3::from_array(s.b));
        let length = (b - a).length();
        let axis = if length > 0.0 { (b - a) / length } else { DVec3::ZERO };
        solids.push(Solid::Capsule { a, axis, length, radius: s.radius });
        parts.push((Pose::identity(), SharedShape::capsule(to_f32(a), to_f32(b), s.radius as f32)));
        infos.push(info(PrimitiveKind::Capsule, &s.tag, s.dark, 2.0 * s.radius));
    }
    for s in &spec.boxes {
        let centre = DVec3::from_array(s.centre);
        let half = DVec3::from_array(s.size) * 0.5;
        solids.push(Solid::Box { centre, half, cos: s.yaw.cos(), sin: s.yaw.sin() });
        let pose = Pose::from_parts(to_f32(centre), Rot3::from_rotation_z(s.yaw as f32));
        parts.push((pose, SharedShape::cuboid(half.x as f32, half.y as f32, half.z as f32)));
        let width = s.size.iter().copied().fold(f64::INFINITY, f64::min);
        infos.push(info(PrimitiveKind::Box, &s.tag, s.dark, width));
    }
    for s in &spec.spheres {
        let centre = DVec3::from_array(s.centre);
        solids.push(Solid::Sphere { centre, radius: s.radius });
        parts.push((Pose::from_translation(to_f32(centre)), SharedShape::ball(s.radius as f32)));
        infos.push(info(PrimitiveKind::Sphere, &s.tag, s.dark, 2.0 * s.radius));
    }
    for item in spec.items.iter().filter(|i| i.solid) {
        let centre = DVec3::from_array(item.position);
        solids.push(Solid::Sphere { centre, radius: ITEM_RADIUS_M });
        parts.push((Pose::from_translation(to_f32(centre)), SharedShape::ball(ITEM_RADIUS_M as f32)));
        infos.push(info(PrimitiveKind::Item, &item.kind, false, 2.0 * ITEM_RADIUS_M));
    }

    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    let mut leaves: Vec<(DVec3, DVec3)> = Vec::with_capacity(solids.len());
    for s in &solids {
        let (mn, mx) = s.aabb();
        lo = lo.min(mn);
        hi = hi.max(mx);
        // Loosened so that f32 rounding in the traversal never culls a grazing f64 hit.
        let margin = 1.0e-4 + 1.0e-6 * mn.abs().max(mx.abs()).max_element();
        leaves.push((mn - DVec3::splat(margin), mx + DVec3::splat(margin)));
    }
    let bvh = FlatBvh::build(leaves);
    let compound = (!parts.is_empty()).then(|| Compound::new(parts));

    let mut planes = Vec::with_capacity(spec.planes.len());
    for s in &spec.planes {
        let id = infos.len() as PrimitiveId;
        planes.push(Plane { point: DVec3::from_array(s.point), normal: DVec3::from_array(s.normal).normalize(), id });
        infos.push(info(PrimitiveKind::Plane, &s.tag, s.dark, f64::INFINITY));
    }

    let terrain = spec.heightfield.as_ref().map(|hf| {
        let id = infos.len() as PrimitiveId;
        infos.push(info(PrimitiveKind::HeightField, TERRAIN_TAG, hf.dark, f64::INFINITY));
        let t = Terrain::new(hf, id);
        let size = DVec3::new((t.cols - 1) as f64 * t.resolution, (t.rows - 1) as f64 * t.resolution, 0.0);
        let origin = DVec3::new(t.origin[0], t.origin[1], t.min_z);
        lo = lo.min(origin);
        hi = hi.max(DVec3::new(origin.x + size.x, origin.y + size.y, t.max_z));
        t
    });

    let bounds = if lo.is_finite() && hi.is_finite() { (lo, hi) } else { (DVec3::ZERO, DVec3::ZERO) };
    World { spec, infos, solids, bvh, compound, planes, terrain, bounds }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::{BoxSpec, CapsuleSpec, CylinderSpec, ItemSpec, PlaneSpec, RegionSpec, RouteSpec, SphereSpec};

    fn sphere(centre: [f64; 3], radius: f64) -> SphereSpec {
        SphereSpec { centre, radius, tag: String::new(), dark: false }
    }

    fn world(spec: WorldSpec) -> World {
        World::from_spec(spec).expect("valid world")
    }

    fn field_of(err: SimError) -> String {
        match err {
            SimError::InvalidWorld { field, .. } => field,
            other => panic!("expected InvalidWorld, got {other:?}"),
        }
    }

    #[test]
    fn sphere_hit_at_hand_computed_distance() {
        let w = world(WorldSpec { spheres: vec![sphere([5.0, 0.0, 0.0], 1.0)], ..Default::default() });
        let hit = w.cast_ray(DVec3::ZERO, DVec3::X, 10.0).expect("hit");
        assert!((hit.distance_m - 4.0).abs() < 1e-12);
        assert!((hit.normal - DVec3::NEG_X).length() < 1e-12);
        assert_eq!(hit.primitive, 0);
        // Out of range, and pointing away.
        assert!(w.cast_ray(DVec3::ZERO, DVec3::X, 3.9).is_none());
        assert!(w.cast_ray(DVec3::ZERO, DVec3::NEG_X, 10.0).is_none());
        // Offset by 0.6 m: t = 5 - sqrt(1 - 0.36) = 4.2.
        let hit = w.cast_ray(DVec3::new(0.0, 0.6, 0.0), DVec3::X, 10.0).expect("hit");
        assert!((hit.distance_m - 4.2).abs() < 1e-12);
        // From inside: distance 0, normal against the ray.
        let hit = w.cast_ray(DVec3::new(5.0, 0.0, 0.0), DVec3::Y, 10.0).expect("hit");
        assert_eq!(hit.distance_m, 0.0);
        assert_eq!(hit.normal, DVec3::NEG_Y);
    }

    #[test]
    fn yawed_box_hit_at_half_diagonal() {
        // A 2 x 2 x 2 box yawed 45°: along x its corner is sqrt(2) from the centre.
        let w = world(WorldSpec {
            boxes: vec![BoxSpec { centre: [10.0, 0.0, 0.0], size: [2.0, 2.0, 2.0], yaw: std::f64::consts::FRAC_PI_4, tag: String::new(), dark: false }],
            ..Default::default()
        });
        let hit = w.cast_ray(DVec3::new(0.0, 0.3, 0.0), DVec3::X, 20.0).expect("hit");
        // The diamond's corner is at x = 10 - sqrt(2); at y = 0.3 the ray meets the face
        // y' = +1 (x - y = 10 - sqrt(2) in the world), whose normal is (-1, 1, 0) / sqrt(2).
        assert!((hit.distance_m - (10.3 - 2f64.sqrt())).abs() < 1e-12);
        let expected = DVec3::new(-1.0, 1.0, 0.0).normalize();
        assert!((hit.normal - expected).length() < 1e-12);
        assert_eq!(w.primitive(0).map(|p| p.width_m), Some(2.0));
    }

    #[test]
    fn cylinder_cap_and_side() {
        // Vertical cylinder, z from 0 to 2, radius 0.5, at x = 3.
        let w = world(WorldSpec {
            cylinders: vec![CylinderSpec { a: [3.0, 0.0, 0.0], b: [3.0, 0.0, 2.0], radius: 0.5, tag: "pole".into(), dark: false }],
            ..Default::default()
        });
        let side = w.cast_ray(DVec3::new(0.0, 0.0, 1.0), DVec3::X, 10.0).expect("side");
        assert!((side.distance_m - 2.5).abs() < 1e-12);
        let cap = w.cast_ray(DVec3::new(3.2, 0.1, 5.0), DVec3::NEG_Z, 10.0).expect("cap");
        assert!((cap.distance_m - 3.0).abs() < 1e-12);
        assert!((cap.normal - DVec3::Z).length() < 1e-12);
        // Just past the top: misses.
        assert!(w.cast_ray(DVec3::new(0.0, 0.0, 2.01), DVec3::X, 10.0).is_none());
        let info = w.primitive(0).expect("info");
        assert_eq!((info.kind, info.tag.as_str(), info.width_m), (PrimitiveKind::Cylinder, "pole", 1.0));
        // Clearance from the axis point at 1 m: 1 - 0.5.
        assert!((w.clearance(DVec3::new(4.0, 0.0, 1.0)) - 0.5).abs() < 1e-6);
        // Inside, 0.1 m from the side: -0.1.
        assert!((w.clearance(DVec3::new(3.4, 0.0, 1.0)) + 0.1).abs() < 1e-6);
    }

    #[test]
    fn capsule_end_is_round() {
        let w = world(WorldSpec {
            capsules: vec![CapsuleSpec { a: [0.0, 0.0, 0.0], b: [0.0, 0.0, 1.0], radius: 0.2, tag: String::new(), dark: false }],
            ..Default::default()
        });
        // From above along the axis: the top sphere at z = 1.2.
        let hit = w.cast_ray(DVec3::new(0.0, 0.0, 3.0), DVec3::NEG_Z, 10.0).expect("hit");
        assert!((hit.distance_m - 1.8).abs() < 1e-12);
        // From the side at mid height: the body at x = 0.2.
        let hit = w.cast_ray(DVec3::new(2.0, 0.0, 0.5), DVec3::NEG_X, 10.0).expect("hit");
        assert!((hit.distance_m - 1.8).abs() < 1e-12);
    }

    #[test]
    fn planes_are_solid_behind_and_ids_follow_bounded_primitives() {
        let w = world(WorldSpec {
            spheres: vec![sphere([0.0, 0.0, 5.0], 1.0)],
            planes: vec![PlaneSpec { point: [0.0, 0.0, 0.0], normal: [0.0, 0.0, 2.0], tag: "floor".into(), dark: false }],
            items: vec![ItemSpec { kind: "comm_node".into(), position: [3.0, 0.0, 0.15], keep_out_radius: 1.0, solid: true }],
            ..Default::default()
        });
        assert_eq!(w.primitive_count(), 3);
        assert_eq!(w.primitive(1).map(|p| p.kind), Some(PrimitiveKind::Item));
        assert_eq!(w.primitive(2).map(|p| p.kind), Some(PrimitiveKind::Plane));
        let hit = w.cast_ray(DVec3::new(0.0, 0.0, 2.0), DVec3::NEG_Z, 10.0).expect("floor");
        assert_eq!((hit.primitive, hit.distance_m), (2, 2.0));
        assert_eq!(hit.normal, DVec3::Z);
        // Behind the plane: inside the solid.
        assert_eq!(w.cast_ray(DVec3::new(0.0, 0.0, -1.0), DVec3::X, 10.0).map(|h| h.distance_m), Some(0.0));
        assert!((w.clearance(DVec3::new(10.0, 0.0, -0.5)) + 0.5).abs() < 1e-12);
        // The solid item is a 0.15 m sphere.
        let hit = w.cast_ray(DVec3::new(0.0, 0.0, 0.15), DVec3::X, 10.0).expect("item");
        assert_eq!(hit.primitive, 1);
        assert!((hit.distance_m - 2.85).abs() < 1e-12);
        // Ground: the floor plane.
        assert_eq!(w.ground_height(7.0, -3.0), Some(0.0));
    }

    #[test]
    fn inclined_plane_ground_height() {
        // z = 0.5 x: normal (-0.5, 0, 1).
        let w = world(WorldSpec {
            planes: vec![PlaneSpec { point: [0.0, 0.0, 0.0], normal: [-0.5, 0.0, 1.0], tag: String::new(), dark: false }],
            ..Default::default()
        });
        assert!((w.ground_height(2.0, 9.0).expect("ground") - 1.0).abs() < 1e-12);
        // A wall (normal.z = 0) is not ground.
        let wall = world(WorldSpec {
            planes: vec![PlaneSpec { point: [0.0, 0.0, 0.0], normal: [1.0, 0.0, 0.0], tag: String::new(), dark: false }],
            ..Default::default()
        });
        assert_eq!(wall.ground_height(1.0, 1.0), None);
    }

    #[test]
    fn heightfield_rows_follow_y_and_holes_remove_cells() {
        // 3 rows (y = 0, 1, 2) x 3 columns (x = 0, 1, 2); heights = y; one hole at (row 2, col 2).
        let hf = HeightFieldSpec {
            origin: [0.0, 0.0],
            resolution: 1.0,
            heights: vec![vec![0.0, 0.0, 0.0], vec![1.0, 1.0, 1.0], vec![2.0, 2.0, -99.0]],
            hole_value: Some(-99.0),
            dark: false,
        };
        let w = world(WorldSpec { heightfield: Some(hf), ..Default::default() });
        assert_eq!(w.primitive(0).map(|p| p.kind), Some(PrimitiveKind::HeightField));
        assert!((w.ground_height(0.5, 0.25).expect("ground") - 0.25).abs() < 1e-12);
        assert!((w.ground_height(0.5, 1.75).expect("ground") - 1.75).abs() < 1e-12);
        // Cell (row 1, col 1) touches the hole.
        assert_eq!(w.ground_height(1.5, 1.5), None);
        // Outside the grid, nothing below.
        assert_eq!(w.ground_height(-0.1, 1.0), None);
        let hit = w.cast_ray(DVec3::new(0.5, 1.5, 5.0), DVec3::NEG_Z, 10.0).expect("terrain");
        assert!((hit.distance_m - 3.5).abs() < 1e-9);
        let expected = DVec3::new(0.0, -1.0, 1.0).normalize();
        assert!((hit.normal - expected).length() < 1e-9);
        // Through the hole.
        assert!(w.cast_ray(DVec3::new(1.5, 1.5, 5.0), DVec3::NEG_Z, 10.0).is_none());
        let (lo, hi) = w.bounds();
        assert_eq!((lo, hi), (DVec3::new(0.0, 0.0, 0.0), DVec3::new(2.0, 2.0, 2.0)));
        // 0.5 m below the surface at (0.5, 1.0): negative clearance.
        assert!(w.clearance(DVec3::new(0.5, 1.0, 0.5)) < 0.0);
    }

    #[test]
    fn validation_names_the_field() {
        let bad_radius = WorldSpec { spheres: vec![sphere([0.0; 3], 1.0), sphere([0.0; 3], -1.0)], ..Default::default() };
        assert_eq!(field_of(World::from_spec(bad_radius).unwrap_err()), "sphere[1].radius");
        let regions = vec![
            RegionSpec { name: "A".into(), centre: [0.0; 3], radius: 1.0 },
            RegionSpec { name: "A".into(), centre: [1.0; 3], radius: 1.0 },
        ];
        assert_eq!(field_of(World::from_spec(WorldSpec { regions, ..Default::default() }).unwrap_err()), "region[1].name");
        let route = WorldSpec {
            regions: vec![RegionSpec { name: "A".into(), centre: [0.0; 3], radius: 1.0 }],
            routes: vec![RouteSpec { name: "A-B".into(), from: "A".into(), to: "B".into() }],
            ..Default::default()
        };
        assert_eq!(field_of(World::from_spec(route).unwrap_err()), "route[0].to");
    }

    #[test]
    fn toml_errors_give_line_and_column() {
        let err = World::from_toml_str("name = \"x\"\n\n[[sphere]]\ncentre = [0, 0, 0]\nradius = 1\ncolour = 3\n").unwrap_err();
        let field = field_of(err);
        assert!(field.starts_with("sphere[0]") && field.ends_with("(line 6, column 1)"), "{field}");
        assert_eq!(subterra::error::line_column("ab\ncdé\nf", 7), (2, 4));
        let err = World::from_toml_str("name = \"x\"\n[[sphere]]\ncentre = [0, 0, 0]\nradius = \"big\"\n").unwrap_err();
        assert_eq!(field_of(err), "sphere[0].radius (line 4, column 10)");
    }

    #[test]
    fn zero_length_capsule_is_a_sphere_and_world_is_shareable() {
        fn shareable<T: Send + Sync>() {}
        shareable::<World>();
        let w = world(WorldSpec {
            capsules: vec![CapsuleSpec { a: [1.0, 2.0, 3.0], b: [1.0, 2.0, 3.0], radius: 0.5, tag: String::new(), dark: false }],
            ..Default::default()
        });
        let hit = w.cast_ray(DVec3::new(1.0, 2.0, 0.0), DVec3::Z, 10.0).expect("hit");
        assert!((hit.distance_m - 2.5).abs() < 1e-12);
        assert!((w.clearance(DVec3::new(1.0, 4.0, 3.0)) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn all_hole_heightfield_has_no_surface() {
        let hf = HeightFieldSpec { origin: [0.0, 0.0], resolution: 1.0, heights: vec![vec![f64::NAN; 2]; 2], hole_value: None, dark: false };
        let w = world(WorldSpec { heightfield: Some(hf), ..Default::default() });
        assert_eq!(w.ground_height(0.5, 0.5), None);
        assert!(w.cast_ray(DVec3::new(0.5, 0.5, 1.0), DVec3::NEG_Z, 10.0).is_none());
        assert_eq!(w.clearance(DVec3::new(0.5, 0.5, 1.0)), f64::INFINITY);
    }

    #[test]
    fn empty_world_has_no_hits() {
        let w = world(WorldSpec::default());
        assert!(w.cast_ray(DVec3::ZERO, DVec3::X, f64::INFINITY).is_none());
        assert_eq!(w.clearance(DVec3::ZERO), f64::INFINITY);
        assert_eq!(w.bounds(), (DVec3::ZERO, DVec3::ZERO));
        assert_eq!(w.primitive_count(), 0);
    }

    /// A tiny seeded generator for the tests below (splitmix64).
    fn next(state: &mut u64) -> f64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)) as f64 / u64::MAX as f64
    }

    #[test]
    fn fans_give_the_single_ray_answers_bit_for_bit() {
        let mut state = 5u64;
        // A 64 x 48 pinhole grid (~80° x 64°) and a 360° x ±17° lidar-like fan.
        let camera: Vec<DVec3> = (0..48).flat_map(|v| (0..64).map(move |u| DVec3::new((u as f64 - 31.5) / 38.5, (v as f64 - 23.5) / 38.5, 1.0).normalize())).collect();
        let lidar: Vec<DVec3> = (0..256)
            .flat_map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 256.0;
                (0..16).map(move |r| {
                    let e = (-17.0 + 34.0 * r as f64 / 15.0).to_radians();
                    DVec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
                })
            })
            .collect();
        for name in crate::scenarios::SCENARIOS {
            let w = world(crate::scenarios::generate(name, 3).expect("scenario"));
            let (lo, hi) = w.bounds();
            let mut compared = 0;
            let mut hits = 0;
            for _ in 0..6 {
                let origin = lo + (hi - lo) * DVec3::new(next(&mut state), next(&mut state), next(&mut state));
                let rotation = DMat3::from_rotation_z(next(&mut state) * 6.3) * DMat3::from_rotation_x(next(&mut state) * 6.3);
                for (dirs, range) in [(&camera, 10.0), (&lidar, 120.0)] {
                    let max = |k: usize| range * (0.5 + (k % 7) as f64 / 12.0);
                    w.cast_fan::<true, _, _>(origin, rotation, dirs, &max, &mut |k, d, hit: Option<FanHit>| {
                        assert_eq!(d, rotation * dirs[k]);
                        assert_eq!(hit.map(|h| h.ray_hit(origin, d)), w.cast_unit(origin, d, max(k)), "{name}: ray {k} from {origin}");
                        compared += 1;
                        hits += usize::from(hit.is_some());
                    });
                    // The cached fan layout gives the same answers too.
                    let layout = FanLayout::new(dirs, &max);
                    let mut cached = 0;
                    w.cast_fan_cached::<true, _, _>(origin, rotation, dirs, &layout, &max, &mut |k, d, hit: Option<FanHit>| {
                        assert_eq!(k, cached);
                        assert_eq!(d, rotation * dirs[k]);
                        assert_eq!(hit.map(|h| h.ray_hit(origin, d)), w.cast_unit(origin, d, max(k)), "{name}: cached ray {k} from {origin}");
                        cached += 1;
                    });
                    assert_eq!(cached, dirs.len());
                    // Without normals: the same distances and primitives.
                    w.cast_fan_cached::<false, _, _>(origin, rotation, dirs, &layout, &max, &mut |k, d, hit: Option<FanHit>| {
                        let want = w.cast_unit(origin, d, max(k));
                        assert_eq!(hit.map(|h| (h.t, h.primitive)), want.map(|h| (h.distance_m, h.primitive)), "{name}: no-normal ray {k}");
                    });
                }
            }
            assert_eq!(compared, 6 * (camera.len() + lidar.len()));
            assert!(hits > compared / 4, "{name}: {hits} hits of {compared}");
        }
    }

    #[test]
    fn cast_rays_equals_cast_ray_and_checks_lengths() {
        let w = world(crate::scenarios::generate("tunnel", 2).expect("scenario"));
        let origin = DVec3::from_array(w.region("start").expect("start").centre);
        let mut state = 9u64;
        let mut dirs: Vec<DVec3> = (0..500).map(|_| DVec3::new(next(&mut state) - 0.5, next(&mut state) - 0.5, next(&mut state) - 0.5) * 3.0).collect();
        dirs[7] = DVec3::ZERO;
        dirs[8] = DVec3::new(f64::NAN, 0.0, 1.0);
        let ranges: Vec<f64> = (0..500).map(|i| if i == 9 { -1.0 } else { 2.0 + (i % 10) as f64 }).collect();
        let mut out = vec![None; 500];
        w.cast_rays(origin, &dirs, &ranges, &mut out).expect("lengths match");
        for (i, hit) in out.iter().enumerate() {
            assert_eq!(*hit, w.cast_ray(origin, dirs[i], ranges[i]), "ray {i}");
        }
        assert!(out[7].is_none() && out[8].is_none() && out[9].is_none());
        assert!(out.iter().filter(|h| h.is_some()).count() > 200);
        // One range for all.
        w.cast_rays(origin, &dirs, &[4.0], &mut out).expect("broadcast range");
        assert_eq!(out[0], w.cast_ray(origin, dirs[0], 4.0));
        assert!(matches!(w.cast_rays(origin, &dirs, &ranges[..3], &mut out), Err(SimError::InvalidInput { argument, .. }) if argument == "max_ranges"));
        assert!(matches!(w.cast_rays(origin, &dirs, &ranges, &mut out[..3]), Err(SimError::InvalidInput { argument, .. }) if argument == "out"));
    }

    #[test]
    fn terrain_view_gives_the_single_ray_answers_near_the_ground() {
        // Lidar-like fans from just above the terrain (where grazing rays walk far), and from
        // below it: the culled walk must find exactly the hits of the full walk.
        let lidar: Vec<DVec3> = (0..512)
            .flat_map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 512.0;
                (0..8).map(move |r| {
                    let e = (-20.0 + 25.0 * r as f64 / 7.0).to_radians();
                    DVec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
                })
            })
            .collect();
        let mut state = 21u64;
        for name in ["mine", "subway"] {
            let w = world(crate::scenarios::generate(name, 2).expect("scenario"));
            let (lo, hi) = w.bounds();
            let mut terrain_hits = 0;
            for i in 0..5 {
                let (x, y) = (lo.x + (hi.x - lo.x) * next(&mut state), lo.y + (hi.y - lo.y) * next(&mut state));
                let ground = w.ground_height(x, y).unwrap_or(0.0);
                let z = if i == 4 { ground - 0.3 } else { ground + 0.05 + 1.5 * next(&mut state) };
                let origin = DVec3::new(x, y, z);
                let rotation = DMat3::from_rotation_z(next(&mut state) * 6.3) * DMat3::from_rotation_x(0.2 * (next(&mut state) - 0.5));
                let max = |k: usize| 60.0 * (0.3 + (k % 5) as f64 / 6.0);
                let terrain = (w.primitive_count() - 1) as PrimitiveId;
                w.cast_fan::<true, _, _>(origin, rotation, &lidar, &max, &mut |k, d, hit: Option<FanHit>| {
                    assert_eq!(hit.map(|h| h.ray_hit(origin, d)), w.cast_unit(origin, d, max(k)), "{name}: ray {k} from {origin}");
                    terrain_hits += usize::from(hit.is_some_and(|h| h.primitive == terrain));
                });
            }
            assert!(terrain_hits > 2000, "{name}: {terrain_hits} terrain hits");
        }
    }

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
