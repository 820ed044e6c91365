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
use parry3d::math::Vector;
use parry3d::query::PointQuery;
use parry3d::shape::Compound;

use crate::error::{SimError, SimResult};
use crate::spec::{RegionSpec, WorldSpec};

mod build;
mod bvh;
mod fan;
mod leaf;
mod terrain;
#[cfg(test)]
mod tests;

use build::{build, validate};
use bvh::FlatBvh;
pub(crate) use fan::{FanCast, FanLayout};
use leaf::{LeafHit, Plane, Solid};
use terrain::{Terrain, TerrainView};

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
        self(k, d, hit);
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

fn to_f32(p: DVec3) -> Vector {
    Vector::new(p.x as f32, p.y as f32, p.z as f32)
}
