//! Exact f64 leaf tests: the bounded primitives ([`Solid`]), their ray tests with the origin
//! terms computed once ([`Prepared`], [`SpherePrep`], [`ray_sphere_t`], [`ray_box_t`], ...),
//! and the planes ([`Plane`]).

use glam::DVec3;

use super::PrimitiveId;

/// An exact f64 bounded primitive.
#[derive(Debug, Clone, Copy)]
pub(super) enum Solid {
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
pub(super) struct Plane {
    pub(super) point: DVec3,
    /// Unit normal, pointing out of the solid.
    pub(super) normal: DVec3,
    pub(super) id: PrimitiveId,
}

/// An intersection found by an exact leaf test.
#[derive(Debug, Clone, Copy)]
pub(super) struct LeafHit {
    pub(super) t: f64,
    /// Outward unit normal, or `-dir` when the ray starts inside.
    pub(super) normal: DVec3,
}

impl Solid {
    /// First intersection with `t >= 0` of the ray `o + t·d` (`d` unit).
    pub(super) fn cast(&self, o: DVec3, d: DVec3) -> Option<LeafHit> {
        self.prepare(o).cast(o, d)
    }

    /// The terms of the ray test that depend on the ray origin `o` only (shared by a fan).
    pub(super) fn prepare(&self, o: DVec3) -> Prepared {
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
    pub(super) fn aabb(&self) -> (DVec3, DVec3) {
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
pub(super) struct SpherePrep {
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
pub(super) enum Prepared {
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
    pub(super) fn cast_t(&self, d: DVec3) -> Option<(f64, u8)> {
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
    pub(super) fn normal(&self, o: DVec3, d: DVec3, t: f64, face: u8) -> DVec3 {
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
pub(super) fn ray_box_t(d: DVec3, cos: f64, sin: f64, near: DVec3, far: DVec3) -> Option<(f64, u8)> {
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
    pub(super) fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<LeafHit> {
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
