//! A [`WorldSpec`] turned into geometry, and the queries the sensors and vehicles ask of it.
//!
//! In: a validated [`WorldSpec`] (or TOML text, see `docs/world-format.md`). Out: ray casts
//! ([`World::cast_ray`]), clearance ([`World::clearance`]) and ground height
//! ([`World::ground_height`]). World frame ENU (z up), metres.
//!
//! How it is built:
//! - The bounded primitives (cylinders, capsules, boxes, spheres, solid items) sit in a parry3d
//!   bounding-volume hierarchy ([`Bvh`]) for ray casts, and in a parry3d [`Compound`] (its own
//!   BVH) for point queries. A ray is tested only against the leaves whose boxes it crosses; the
//!   leaf test itself is the exact analytic intersection in f64 (parry's f32 GJK ray cast on a
//!   cylinder is off by up to a few mm), so hit distances are exact to ~1e-9 m.
//! - The terrain is a parry3d [`HeightField`]; cells touching a hole are removed. Its ray hits
//!   are refined in f64 on the triangle parry reports, and [`World::ground_height`] interpolates
//!   the same triangles in f64.
//! - Planes are few and unbounded: handled analytically.
//!
//! Primitive ids ([`PrimitiveId`]) are stable: cylinders, capsules, boxes, spheres and solid
//! items in spec order, then planes, then the height field.
//!
//! Solids: a ray that starts inside a bounded primitive or behind a plane (the solid side is
//! opposite the normal) hits at distance 0 with the normal `-dir`. The terrain is a surface,
//! seen from both sides.

use glam::DVec3;
use parry3d::bounding_volume::Aabb;
use parry3d::math::{Pose, Rot3, Vector};
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhNode};
use parry3d::query::{PointQuery, Ray, RayCast};
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

/// A world's geometry, ready for queries. Built once by [`World::from_spec`] or
/// [`World::from_toml_str`]; immutable, `Send + Sync`.
#[derive(Debug, Clone)]
pub struct World {
    spec: WorldSpec,
    infos: Vec<PrimitiveInfo>,
    /// Bounded primitives in id order (index = id).
    solids: Vec<Solid>,
    /// Loosened boxes of `solids`, for ray casts.
    bvh: Bvh,
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
}

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
        let spec: WorldSpec = toml::from_str(text).map_err(|e| {
            let field = match e.span() {
                Some(span) => {
                    let (line, column) = line_column(text, span.start);
                    format!("line {line}, column {column}")
                }
                None => "toml".to_string(),
            };
            SimError::world(field, e.message().trim().to_string())
        })?;
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
    /// analytically; the terrain with parry's cell walk. A ray starting inside a bounded
    /// primitive or behind a plane hits at distance 0. `None`: no hit in range, or a
    /// non-finite or zero input (`max_range_m` may be `f64::INFINITY`).
    pub fn cast_ray(&self, origin: DVec3, dir: DVec3, max_range_m: f64) -> Option<RayHit> {
        if !origin.is_finite() || !dir.is_finite() || max_range_m.is_nan() || max_range_m < 0.0 {
            return None;
        }
        let len = dir.length();
        if len <= 0.0 {
            return None;
        }
        let d = dir / len;
        let mut best: Option<(LeafHit, PrimitiveId)> = None;
        let mut limit = max_range_m;

        // Planes first: cheap, and their hit (a wall, the floor) shortens the BVH walk.
        for plane in &self.planes {
            if let Some(hit) = plane.cast(origin, d, limit) {
                if best.is_none() || hit.t < limit {
                    limit = hit.t;
                    best = Some((hit, plane.id));
                }
            }
        }
        if let Some((id, hit)) = self.cast_solids(origin, d, limit) {
            if best.is_none() || hit.t < limit {
                limit = hit.t;
                best = Some((hit, id));
            }
        }
        if let Some(terrain) = &self.terrain {
            if let Some(hit) = terrain.cast(origin, d, limit) {
                if best.is_none() || hit.t < limit {
                    best = Some((hit, terrain.id));
                }
            }
        }
        best.map(|(hit, id)| {
            let normal = if hit.normal.dot(d) > 0.0 { -hit.normal } else { hit.normal };
            RayHit { distance_m: hit.t, point: origin + d * hit.t, normal, primitive: id }
        })
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

    /// Nearest bounded primitive along the ray, through the BVH.
    fn cast_solids(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<(PrimitiveId, LeafHit)> {
        if self.solids.is_empty() {
            return None;
        }
        let o32 = to_f32(o);
        let inv = Vector::new(inv_component(d.x), inv_component(d.y), inv_component(d.z));
        let max_cost = if max_t.is_finite() { (max_t as f32) * (1.0 + 1.0e-5) + 1.0e-4 } else { f32::MAX };
        let aabb_cost = |node: &BvhNode, _best: f32| -> f32 {
            let t1 = (node.mins() - o32) * inv;
            let t2 = (node.maxs() - o32) * inv;
            let t_near = t1.min(t2).max_element().max(0.0);
            let t_far = t1.max(t2).min_element();
            if t_far >= t_near {
                t_near
            } else {
                f32::MAX
            }
        };
        let leaf_cost = |leaf: u32, _best: f32| -> Option<(f32, LeafHit)> {
            let hit = self.solids.get(leaf as usize)?.cast(o, d)?;
            (hit.t <= max_t).then_some((hit.t as f32, hit))
        };
        self.bvh.find_best(max_cost, aabb_cost, leaf_cost).map(|(id, (_, hit))| (id, hit))
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

/// 1-based line and column (in characters) of byte offset `at` in `text`.
fn line_column(text: &str, at: usize) -> (usize, usize) {
    let at = at.min(text.len());
    let before = text.get(..at).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before.get(line_start..).map_or(0, |s| s.chars().count()) + 1;
    (line, column)
}

// ---------------------------------------------------------------------------------------------
// Exact f64 leaf tests.

impl Solid {
    /// First intersection with `t >= 0` of the ray `o + t·d` (`d` unit).
    fn cast(&self, o: DVec3, d: DVec3) -> Option<LeafHit> {
        match *self {
            Solid::Sphere { centre, radius } => ray_sphere(o, d, centre, radius),
            Solid::Capsule { a, axis, length, radius } => ray_capsule(o, d, a, axis, length, radius),
            Solid::Cylinder { a, axis, length, radius } => ray_cylinder(o, d, a, axis, length, radius),
            Solid::Box { centre, half, cos, sin } => ray_box(o, d, centre, half, cos, sin),
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

fn inside_hit(d: DVec3) -> LeafHit {
    LeafHit { t: 0.0, normal: -d }
}

/// Ray against a sphere (solid).
fn ray_sphere(o: DVec3, d: DVec3, centre: DVec3, radius: f64) -> Option<LeafHit> {
    let oc = o - centre;
    let c = oc.length_squared() - radius * radius;
    if c <= 0.0 {
        return Some(inside_hit(d));
    }
    let b = oc.dot(d);
    if b >= 0.0 {
        return None;
    }
    // Discriminant from the perpendicular miss distance (no cancellation far away).
    let q = oc - d * b;
    let disc = radius * radius - q.length_squared();
    if disc < 0.0 {
        return None;
    }
    // Smaller root, in the cancellation-free form c / (-b + sqrt(disc)).
    let t = c / (-b + disc.sqrt());
    let normal = (o + d * t - centre) / radius;
    Some(LeafHit { t, normal: normal.normalize_or(-d) })
}

/// Entry into the infinite cylinder of radius `radius` around the line `a + s·axis`, from
/// outside it: `(t, s)` of the hit.
fn ray_infinite_cylinder(o: DVec3, d: DVec3, a: DVec3, axis: DVec3, radius: f64) -> Option<(f64, f64)> {
    let oa = o - a;
    let s0 = oa.dot(axis);
    let du = d.dot(axis);
    let op = oa - axis * s0;
    let dp = d - axis * du;
    let qa = dp.length_squared();
    let c = op.length_squared() - radius * radius;
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
    let t = c / (-qb + disc.sqrt());
    Some((t, s0 + t * du))
}

/// Ray against a finite cylinder with flat caps (solid).
fn ray_cylinder(o: DVec3, d: DVec3, a: DVec3, axis: DVec3, length: f64, radius: f64) -> Option<LeafHit> {
    let oa = o - a;
    let s0 = oa.dot(axis);
    let op = oa - axis * s0;
    let r2 = radius * radius;
    if (0.0..=length).contains(&s0) && op.length_squared() <= r2 {
        return Some(inside_hit(d));
    }
    let mut best: Option<LeafHit> = None;
    if let Some((t, s)) = ray_infinite_cylinder(o, d, a, axis, radius) {
        if (0.0..=length).contains(&s) {
            let radial = o + d * t - a - axis * s;
            best = Some(LeafHit { t, normal: radial.normalize_or(-d) });
        }
    }
    let du = d.dot(axis);
    if du != 0.0 {
        let dp = d - axis * du;
        for (cap_s, normal) in [(0.0, -axis), (length, axis)] {
            let t = (cap_s - s0) / du;
            if t >= 0.0 && best.is_none_or(|b| t < b.t) && (op + dp * t).length_squared() <= r2 {
                best = Some(LeafHit { t, normal });
            }
        }
    }
    best
}

/// Ray against a capsule (solid): the side of its cylinder and its two end spheres.
fn ray_capsule(o: DVec3, d: DVec3, a: DVec3, axis: DVec3, length: f64, radius: f64) -> Option<LeafHit> {
    let oa = o - a;
    let s0 = oa.dot(axis).clamp(0.0, length);
    if (oa - axis * s0).length_squared() <= radius * radius {
        return Some(inside_hit(d));
    }
    let mut best: Option<LeafHit> = None;
    if length > 0.0 {
        if let Some((t, s)) = ray_infinite_cylinder(o, d, a, axis, radius) {
            if (0.0..=length).contains(&s) {
                let radial = o + d * t - a - axis * s;
                best = Some(LeafHit { t, normal: radial.normalize_or(-d) });
            }
        }
    }
    for centre in [a, a + axis * length] {
        if let Some(hit) = ray_sphere(o, d, centre, radius) {
            if best.is_none_or(|b| hit.t < b.t) {
                best = Some(hit);
            }
        }
    }
    best
}

/// Ray against a box of half extents `half` rotated by yaw (`cos`, `sin`) about z (solid).
fn ray_box(o: DVec3, d: DVec3, centre: DVec3, half: DVec3, cos: f64, sin: f64) -> Option<LeafHit> {
    let to_local = |v: DVec3| DVec3::new(cos * v.x + sin * v.y, -sin * v.x + cos * v.y, v.z);
    let ol = to_local(o - centre);
    let dl = to_local(d);
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut enter = DVec3::ZERO;
    for k in 0..3 {
        let (ok, dk, hk) = (ol[k], dl[k], half[k]);
        if dk == 0.0 {
            if ok.abs() > hk {
                return None;
            }
            continue;
        }
        let t1 = (-hk - ok) / dk;
        let t2 = (hk - ok) / dk;
        let (tn, tf, sign) = if t1 < t2 { (t1, t2, -1.0) } else { (t2, t1, 1.0) };
        if tn > t_near {
            t_near = tn;
            enter = DVec3::ZERO;
            enter[k] = sign;
        }
        t_far = t_far.min(tf);
    }
    if t_far < t_near || t_far < 0.0 {
        return None;
    }
    if t_near <= 0.0 {
        return Some(inside_hit(d));
    }
    let normal = DVec3::new(cos * enter.x - sin * enter.y, sin * enter.x + cos * enter.y, enter.z);
    Some(LeafHit { t: t_near, normal })
}

impl Plane {
    /// Ray against the half-space behind the plane, `t <= max_t`.
    fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
        let s = self.normal.dot(o - self.point);
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
        Terrain {
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

    fn vertex(&self, r: usize, c: usize) -> DVec3 {
        DVec3::new(self.origin[0] + c as f64 * self.resolution, self.origin[1] + r as f64 * self.resolution, self.h(r, c))
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

    /// The triangle parry's triangle id `id` names, world frame.
    fn triangle(&self, id: u32) -> Option<[DVec3; 3]> {
        let cells = (self.rows - 1) * (self.cols - 1);
        let id = id as usize;
        let (k, left) = if id < cells { (id, true) } else { (id - cells, false) };
        if k >= cells {
            return None;
        }
        let (i, j) = (k % (self.rows - 1), k / (self.rows - 1));
        let (r, c) = (self.rows - 2 - i, j);
        Some(if left {
            [self.vertex(r + 1, c), self.vertex(r, c), self.vertex(r + 1, c + 1)]
        } else {
            [self.vertex(r, c), self.vertex(r, c + 1), self.vertex(r + 1, c + 1)]
        })
    }

    /// Ray against the surface, `t <= max_t`; parry's hit refined on its triangle in f64.
    fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
        if !self.any_cell {
            return None;
        }
        let ray = Ray::new(self.to_local(o), Vector::new(d.x as f32, d.z as f32, -d.y as f32));
        let max32 = if max_t.is_finite() { (max_t as f32) * (1.0 + 1.0e-5) + 1.0e-4 } else { f32::MAX };
        let hit = self.shape.cast_local_ray_and_get_normal(&ray, max32, true)?;
        let t32 = f64::from(hit.time_of_impact);
        let n32 = DVec3::new(f64::from(hit.normal.x), -f64::from(hit.normal.z), f64::from(hit.normal.y));
        let mut out = LeafHit { t: t32, normal: n32.normalize_or(-d) };
        if let Some([a, b, c]) = self.triangle(hit.subshape) {
            let n = (b - a).cross(c - a);
            let denom = n.dot(d);
            if denom.abs() > 1.0e-9 * n.length() {
                let t = n.dot(a - o) / denom;
                if t >= 0.0 && (t - t32).abs() <= 1.0e-3 + 1.0e-4 * t32 {
                    out = LeafHit { t, normal: n.normalize_or(out.normal) };
                }
            }
        }
        (out.t <= max_t).then_some(out)
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
    let mut leaves = Vec::with_capacity(solids.len());
    for s in &solids {
        let (mn, mx) = s.aabb();
        lo = lo.min(mn);
        hi = hi.max(mx);
        // Loosened so that f32 rounding in the traversal never culls a grazing f64 hit.
        let margin = 1.0e-4 + 1.0e-6 * mn.abs().max(mx.abs()).max_element();
        leaves.push(Aabb::new(to_f32(mn - DVec3::splat(margin)), to_f32(mx + DVec3::splat(margin))));
    }
    let bvh = Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves);
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
        assert_eq!(field_of(err), "line 6, column 1");
        assert_eq!(line_column("ab\ncdé\nf", 7), (2, 4));
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
}
