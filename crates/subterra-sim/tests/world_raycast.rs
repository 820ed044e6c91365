//! World queries against analytic answers over thousands of seeded random rays and points:
//! plane, sphere, finite cylinder, capsule, yawed box, an inclined height field; the nearest of
//! many objects; bad worlds; the documented example world; and the cost of one ray.
//!
//! The reference answers here are computed independently of `world/` (local frames and
//! face-by-face tests rather than its projections and slabs).

use std::time::Instant;

use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use subterra_sim::spec::{BoxSpec, CapsuleSpec, CylinderSpec, HeightFieldSpec, PlaneSpec, SphereSpec, WorldSpec};
use subterra_sim::world::{PrimitiveKind, World};
use subterra_sim::SimError;

/// Largest allowed error of a hit distance [m] (issue: exact within 1e-4 m).
const TOL_M: f64 = 1e-4;

type Rng = Xoshiro256PlusPlus;

fn rng(seed: u64) -> Rng {
    Rng::seed_from_u64(seed)
}

fn unit(rng: &mut Rng) -> DVec3 {
    loop {
        let v = DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let l = v.length();
        if l > 0.1 && l <= 1.0 {
            return v / l;
        }
    }
}

fn in_cube(rng: &mut Rng, half: f64) -> DVec3 {
    DVec3::new(rng.random_range(-half..half), rng.random_range(-half..half), rng.random_range(-half..half))
}

/// A unit vector perpendicular to `m`.
fn perpendicular(rng: &mut Rng, m: DVec3) -> DVec3 {
    loop {
        let v = unit(rng);
        let p = v - m * v.dot(m);
        if p.length() > 0.1 {
            return p.normalize();
        }
    }
}

/// Orthonormal basis (e1, e2) completing the unit `u`.
fn basis(u: DVec3) -> (DVec3, DVec3) {
    let helper = if u.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let e1 = u.cross(helper).normalize();
    (e1, u.cross(e1))
}

// ---- Reference shapes (independent analytic answers) ---------------------------------------

#[derive(Clone, Copy, Debug)]
enum Shape {
    Sphere { c: DVec3, r: f64 },
    Cylinder { a: DVec3, b: DVec3, r: f64 },
    Capsule { a: DVec3, b: DVec3, r: f64 },
    Box { c: DVec3, size: DVec3, yaw: f64 },
}

/// Smallest t >= 0 of the roots of a t² + b t + c = 0.
fn smallest_root(a: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    let disc = b * b - 4.0 * a * c;
    if a.abs() < 1e-15 || disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    Some(((-b - s) / (2.0 * a), (-b + s) / (2.0 * a)))
}

fn ref_sphere(o: DVec3, d: DVec3, c: DVec3, r: f64) -> Option<f64> {
    let oc = o - c;
    if oc.length() <= r {
        return Some(0.0);
    }
    let (t0, _) = smallest_root(1.0, 2.0 * oc.dot(d), oc.length_squared() - r * r)?;
    (t0 >= 0.0).then_some(t0)
}

/// Ray in the cylinder's frame: z along a->b from 0 to L, x, y across.
fn cyl_frame(o: DVec3, d: DVec3, a: DVec3, b: DVec3) -> (DVec3, DVec3, f64) {
    let u = (b - a).normalize();
    let (e1, e2) = basis(u);
    let p = o - a;
    (DVec3::new(p.dot(e1), p.dot(e2), p.dot(u)), DVec3::new(d.dot(e1), d.dot(e2), d.dot(u)), (b - a).length())
}

/// Hits of the lateral surface x² + y² = r² (any z), as (t, z).
fn side_hits(ol: DVec3, dl: DVec3, r: f64) -> Vec<(f64, f64)> {
    let a = dl.x * dl.x + dl.y * dl.y;
    let b = 2.0 * (ol.x * dl.x + ol.y * dl.y);
    let c = ol.x * ol.x + ol.y * ol.y - r * r;
    match smallest_root(a, b, c) {
        Some((t0, t1)) => [t0, t1].into_iter().filter(|t| *t >= 0.0).map(|t| (t, ol.z + t * dl.z)).collect(),
        None => Vec::new(),
    }
}

fn ref_cylinder(o: DVec3, d: DVec3, a: DVec3, b: DVec3, r: f64) -> Option<f64> {
    let (ol, dl, len) = cyl_frame(o, d, a, b);
    if ol.z >= 0.0 && ol.z <= len && ol.x * ol.x + ol.y * ol.y <= r * r {
        return Some(0.0);
    }
    let mut best = f64::INFINITY;
    for (t, z) in side_hits(ol, dl, r) {
        if (0.0..=len).contains(&z) {
            best = best.min(t);
        }
    }
    if dl.z != 0.0 {
        for cap in [0.0, len] {
            let t = (cap - ol.z) / dl.z;
            let p = ol + dl * t;
            if t >= 0.0 && p.x * p.x + p.y * p.y <= r * r {
                best = best.min(t);
            }
        }
    }
    best.is_finite().then_some(best)
}

fn ref_capsule(o: DVec3, d: DVec3, a: DVec3, b: DVec3, r: f64) -> Option<f64> {
    let (ol, dl, len) = cyl_frame(o, d, a, b);
    let mut best = f64::INFINITY;
    for (t, z) in side_hits(ol, dl, r) {
        if (0.0..=len).contains(&z) {
            best = best.min(t);
        }
    }
    for c in [a, b] {
        if let Some(t) = ref_sphere(o, d, c, r) {
            best = best.min(t);
        }
    }
    // Inside the body: the origin's distance to the segment is below r.
    let s = ol.z.clamp(0.0, len);
    if (ol - DVec3::new(0.0, 0.0, s)).length() <= r {
        return Some(0.0);
    }
    best.is_finite().then_some(best)
}

/// Face by face: each of the six face planes, the hit kept if it lies on the face.
fn ref_box(o: DVec3, d: DVec3, c: DVec3, size: DVec3, yaw: f64) -> Option<f64> {
    let (s, co) = yaw.sin_cos();
    let axes = [DVec3::new(co, s, 0.0), DVec3::new(-s, co, 0.0), DVec3::Z];
    let half = size * 0.5;
    let local = |p: DVec3| DVec3::new((p - c).dot(axes[0]), (p - c).dot(axes[1]), (p - c).dot(axes[2]));
    let ol = local(o);
    if ol.x.abs() <= half.x && ol.y.abs() <= half.y && ol.z.abs() <= half.z {
        return Some(0.0);
    }
    let mut best = f64::INFINITY;
    for k in 0..3 {
        for sign in [-1.0, 1.0] {
            let n = axes[k] * sign;
            let p0 = c + n * half[k];
            let denom = n.dot(d);
            if denom >= 0.0 {
                continue;
            }
            let t = n.dot(p0 - o) / denom;
            let q = local(o + d * t);
            let eps = 1e-9;
            let on_face = (0..3).all(|j| j == k || q[j].abs() <= half[j] + eps);
            if t >= 0.0 && on_face {
                best = best.min(t);
            }
        }
    }
    best.is_finite().then_some(best)
}

impl Shape {
    fn cast(&self, o: DVec3, d: DVec3) -> Option<f64> {
        match *self {
            Shape::Sphere { c, r } => ref_sphere(o, d, c, r),
            Shape::Cylinder { a, b, r } => ref_cylinder(o, d, a, b, r),
            Shape::Capsule { a, b, r } => ref_capsule(o, d, a, b, r),
            Shape::Box { c, size, yaw } => ref_box(o, d, c, size, yaw),
        }
    }

    /// Support function h(m) = max over the shape of x·m (m unit).
    fn support(&self, m: DVec3) -> f64 {
        match *self {
            Shape::Sphere { c, r } => c.dot(m) + r,
            Shape::Capsule { a, b, r } => a.dot(m).max(b.dot(m)) + r,
            Shape::Cylinder { a, b, r } => {
                let u = (b - a).normalize();
                a.dot(m).max(b.dot(m)) + r * (1.0 - u.dot(m).powi(2)).max(0.0).sqrt()
            }
            Shape::Box { c, size, yaw } => {
                let (s, co) = yaw.sin_cos();
                let axes = [DVec3::new(co, s, 0.0), DVec3::new(-s, co, 0.0), DVec3::Z];
                c.dot(m) + (0..3).map(|k| 0.5 * size[k] * axes[k].dot(m).abs()).sum::<f64>()
            }
        }
    }

    /// A point strictly inside.
    fn interior(&self, rng: &mut Rng) -> DVec3 {
        match *self {
            Shape::Sphere { c, r } => c + unit(rng) * r * rng.random_range(0.0..0.9),
            Shape::Cylinder { a, b, r } | Shape::Capsule { a, b, r } => {
                let u = (b - a).normalize();
                let (e1, _) = basis(u);
                a + (b - a) * rng.random_range(0.05..0.95) + e1 * r * rng.random_range(-0.9..0.9)
            }
            Shape::Box { c, size, yaw } => {
                let (s, co) = yaw.sin_cos();
                let l = DVec3::new(
                    rng.random_range(-0.45..0.45) * size.x,
                    rng.random_range(-0.45..0.45) * size.y,
                    rng.random_range(-0.45..0.45) * size.z,
                );
                c + DVec3::new(co * l.x - s * l.y, s * l.x + co * l.y, l.z)
            }
        }
    }

    /// Signed distance (negative inside).
    fn sdf(&self, p: DVec3) -> f64 {
        match *self {
            Shape::Sphere { c, r } => (p - c).length() - r,
            Shape::Capsule { a, b, r } => {
                let u = b - a;
                let s = ((p - a).dot(u) / u.length_squared()).clamp(0.0, 1.0);
                (p - a - u * s).length() - r
            }
            Shape::Cylinder { a, b, r } => {
                let (pl, _, len) = cyl_frame(p, DVec3::Z, a, b);
                let q = [pl.truncate().length() - r, (pl.z - 0.5 * len).abs() - 0.5 * len];
                let outside = (q[0].max(0.0).powi(2) + q[1].max(0.0).powi(2)).sqrt();
                outside + q[0].max(q[1]).min(0.0)
            }
            Shape::Box { c, size, yaw } => {
                let (s, co) = yaw.sin_cos();
                let v = p - c;
                let l = DVec3::new(co * v.x + s * v.y, -s * v.x + co * v.y, v.z);
                let q = l.abs() - size * 0.5;
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
            }
        }
    }

    fn add_to(&self, spec: &mut WorldSpec) {
        let tag = String::new();
        match *self {
            Shape::Sphere { c, r } => spec.spheres.push(SphereSpec { centre: c.to_array(), radius: r, tag, dark: false }),
            Shape::Cylinder { a, b, r } => spec.cylinders.push(CylinderSpec { a: a.to_array(), b: b.to_array(), radius: r, tag, dark: false }),
            Shape::Capsule { a, b, r } => spec.capsules.push(CapsuleSpec { a: a.to_array(), b: b.to_array(), radius: r, tag, dark: false }),
            Shape::Box { c, size, yaw } => spec.boxes.push(BoxSpec { centre: c.to_array(), size: size.to_array(), yaw, tag, dark: false }),
        }
    }
}

fn random_shape(rng: &mut Rng, kind: usize, spread: f64) -> Shape {
    let c = in_cube(rng, spread);
    match kind {
        0 => Shape::Sphere { c, r: rng.random_range(0.01..1.5) },
        1 => {
            let half = unit(rng) * rng.random_range(0.05..2.0);
            Shape::Cylinder { a: c - half, b: c + half, r: rng.random_range(0.004..0.8) }
        }
        2 => {
            let half = unit(rng) * rng.random_range(0.05..2.0);
            Shape::Capsule { a: c - half, b: c + half, r: rng.random_range(0.004..0.8) }
        }
        _ => Shape::Box {
            c,
            size: DVec3::new(rng.random_range(0.02..3.0), rng.random_range(0.02..3.0), rng.random_range(0.02..3.0)),
            yaw: rng.random_range(-4.0..4.0),
        },
    }
}

fn single(shape: Shape) -> World {
    let mut spec = WorldSpec::default();
    shape.add_to(&mut spec);
    World::from_spec(spec).expect("valid world")
}

/// Thousands of rays against one random shape of `kind` per trial: rays aimed at an interior
/// point must hit at the analytic distance; rays in a plane beyond the support plane must
/// miss; fully random rays must agree with the reference on hit/miss and distance.
fn check_kind(kind: usize, seed: u64) {
    let mut rng = rng(seed);
    let (mut hits, mut misses) = (0, 0);
    let mut max_err: f64 = 0.0;
    for _ in 0..40 {
        let shape = random_shape(&mut rng, kind, 3.0);
        let world = single(shape);
        for _ in 0..100 {
            // Must hit: from 6-30 m away toward an interior point.
            let target = shape.interior(&mut rng);
            let origin = target + unit(&mut rng) * rng.random_range(6.0..30.0);
            let d = (target - origin).normalize();
            let want = shape.cast(origin, d).expect("reference hits a ray aimed inside");
            let got = world.cast_ray(origin, d, 100.0).unwrap_or_else(|| panic!("{shape:?}: missed from {origin} along {d}, expected {want}"));
            assert!((got.distance_m - want).abs() < TOL_M, "{shape:?}: {} vs {want}", got.distance_m);
            max_err = max_err.max((got.distance_m - want).abs());
            assert!((got.point - (origin + d * want)).length() < TOL_M);
            assert!((got.normal.length() - 1.0).abs() < 1e-9 && got.normal.dot(d) <= 0.0);
            assert_eq!(got.primitive, 0);
            hits += 1;

            // Must miss: the ray lies in the plane x·m = h(m) + δ beyond the support plane.
            let m = unit(&mut rng);
            let delta = rng.random_range(1e-3..0.5);
            let dir = perpendicular(&mut rng, m);
            let origin = m * (shape.support(m) + delta) + perpendicular(&mut rng, m) * rng.random_range(-5.0..5.0);
            let origin = origin - dir * rng.random_range(0.0..10.0);
            assert!(world.cast_ray(origin, dir, 100.0).is_none(), "{shape:?}: hit a ray beyond the support plane");
            misses += 1;

            // Random rays: agree with the reference.
            let origin = in_cube(&mut rng, 8.0);
            let d = unit(&mut rng);
            match (shape.cast(origin, d), world.cast_ray(origin, d, 100.0)) {
                (Some(want), Some(got)) => assert!((got.distance_m - want).abs() < TOL_M, "{shape:?}: {} vs {want}", got.distance_m),
                (None, None) => {}
                (want, got) => panic!("{shape:?}: reference {want:?}, world {got:?} from {origin} along {d}"),
            }
        }
    }
    assert_eq!((hits, misses), (4000, 4000));
    println!("kind {kind}: {hits} rays aimed inside, largest distance error {max_err:.1e} m; {misses} rays beyond the support plane, all missed");
}

#[test]
fn sphere_rays_match_analytic() {
    check_kind(0, 1);
}

#[test]
fn finite_cylinder_rays_match_analytic() {
    check_kind(1, 2);
}

#[test]
fn capsule_rays_match_analytic() {
    check_kind(2, 3);
}

#[test]
fn yawed_box_rays_match_analytic() {
    check_kind(3, 4);
}

#[test]
fn plane_rays_match_analytic() {
    let mut rng = rng(5);
    let (mut hits, mut misses) = (0, 0);
    for _ in 0..50 {
        let point = in_cube(&mut rng, 5.0);
        let n = unit(&mut rng);
        let spec = WorldSpec {
            planes: vec![PlaneSpec { point: point.to_array(), normal: (n * rng.random_range(0.1..10.0)).to_array(), tag: String::new(), dark: false }],
            ..Default::default()
        };
        let world = World::from_spec(spec).expect("valid");
        for _ in 0..100 {
            let origin = in_cube(&mut rng, 20.0);
            let d = unit(&mut rng);
            let s = n.dot(origin - point);
            let want = if s < 0.0 {
                Some(0.0) // behind: inside the solid
            } else if n.dot(d) < 0.0 {
                Some(-s / n.dot(d))
            } else {
                None
            };
            let max = 50.0;
            let want = want.filter(|t| *t <= max);
            match (want, world.cast_ray(origin, d, max)) {
                (Some(w), Some(g)) => {
                    assert!((g.distance_m - w).abs() < TOL_M, "{} vs {w}", g.distance_m);
                    if w > 0.0 {
                        assert!((g.normal - n).length() < 1e-9);
                    }
                    hits += 1;
                }
                (None, None) => misses += 1,
                (w, g) => panic!("reference {w:?}, world {g:?}"),
            }
        }
    }
    assert!(hits > 1000 && misses > 1000, "{hits} hits, {misses} misses");
}

/// A world of `n` random objects of every kind, as reference shapes and as a [`World`].
fn clutter(seed: u64, n: usize, spread: f64) -> (Vec<Shape>, World) {
    let mut rng = rng(seed);
    let shapes: Vec<Shape> = (0..n).map(|i| random_shape(&mut rng, i % 4, spread)).collect();
    let mut spec = WorldSpec::default();
    // Ids enumerate cylinders, capsules, boxes, spheres: add in that order and remember it.
    let mut ordered = Vec::with_capacity(n);
    for kind in [1, 2, 3, 0] {
        for (i, s) in shapes.iter().enumerate() {
            if i % 4 == kind {
                s.add_to(&mut spec);
                ordered.push(*s);
            }
        }
    }
    (ordered, World::from_spec(spec).expect("valid"))
}

fn brute_force(shapes: &[Shape], o: DVec3, d: DVec3, max: f64) -> Option<(usize, f64)> {
    shapes
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.cast(o, d).map(|t| (i, t)))
        .filter(|(_, t)| *t <= max)
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

#[test]
fn nearest_of_many_objects_wins() {
    // A row of spheres along x: the first one in front wins, from either side.
    let spec = WorldSpec {
        spheres: (0..5).map(|i| SphereSpec { centre: [2.0 + 2.0 * i as f64, 0.0, 0.0], radius: 0.5, tag: String::new(), dark: false }).collect(),
        ..Default::default()
    };
    let row = World::from_spec(spec).expect("valid");
    assert_eq!(row.cast_ray(DVec3::ZERO, DVec3::X, 100.0).map(|h| (h.primitive, h.distance_m)), Some((0, 1.5)));
    assert_eq!(row.cast_ray(DVec3::new(20.0, 0.0, 0.0), DVec3::NEG_X, 100.0).map(|h| (h.primitive, h.distance_m)), Some((4, 9.5)));
    assert_eq!(row.cast_ray(DVec3::new(5.0, 0.0, 0.0), DVec3::X, 100.0).map(|h| (h.primitive, h.distance_m)), Some((2, 0.5)));

    // 200 random objects: the BVH answer equals the brute-force nearest over all of them.
    let (shapes, world) = clutter(6, 200, 10.0);
    let mut rng = rng(7);
    let mut hits = 0;
    for _ in 0..5000 {
        let o = in_cube(&mut rng, 14.0);
        let d = unit(&mut rng);
        let max = rng.random_range(1.0..30.0);
        match (brute_force(&shapes, o, d, max), world.cast_ray(o, d, max)) {
            (Some((i, t)), Some(hit)) => {
                assert!((hit.distance_m - t).abs() < TOL_M, "{} vs {t}", hit.distance_m);
                if t > 0.0 {
                    // Equal distances (touching objects) may name either.
                    let other = shapes[hit.primitive as usize].cast(o, d).unwrap_or(f64::INFINITY);
                    assert!(hit.primitive as usize == i || (other - t).abs() < TOL_M);
                }
                hits += 1;
            }
            (None, None) => {}
            (want, got) => panic!("brute force {want:?}, world {got:?}"),
        }
    }
    assert!(hits > 500, "{hits}");
}

/// z = 0.3 + 0.2 x - 0.1 y on a 31 x 21 grid (rows along y) at 0.25 m from (-2, 1).
fn inclined_field(holes: &[(usize, usize)]) -> (World, impl Fn(f64, f64) -> f64) {
    let plane = |x: f64, y: f64| 0.3 + 0.2 * x - 0.1 * y;
    let (origin, res, rows, cols) = ([-2.0, 1.0], 0.25, 31, 21);
    let heights = (0..rows)
        .map(|r| {
            (0..cols)
                .map(|c| if holes.contains(&(r, c)) { f64::NAN } else { plane(origin[0] + c as f64 * res, origin[1] + r as f64 * res) })
                .collect()
        })
        .collect();
    let spec = WorldSpec { heightfield: Some(HeightFieldSpec { origin, resolution: res, heights, hole_value: None, dark: false }), ..Default::default() };
    (World::from_spec(spec).expect("valid"), plane)
}

#[test]
fn ground_height_on_inclined_heightfield() {
    // Hole at row 10 (y = 3.5), column 6 (x = -0.5): the cells x in [-0.75, -0.25], y in [3.25, 3.75].
    let (world, plane) = inclined_field(&[(10, 6)]);
    let mut rng = rng(8);
    let mut checked = 0;
    for _ in 0..5000 {
        let x = rng.random_range(-2.0..3.0);
        let y = rng.random_range(1.0..8.5);
        let over_hole = (-0.75..=-0.25).contains(&x) && (3.25..=3.75).contains(&y);
        match world.ground_height(x, y) {
            Some(h) => {
                assert!(!over_hole, "({x}, {y}) is over the hole");
                assert!((h - plane(x, y)).abs() < 1e-6, "{h} vs {}", plane(x, y));
                // A vertical ray from above sees the same surface.
                let hit = world.cast_ray(DVec3::new(x, y, 10.0), DVec3::NEG_Z, 20.0).expect("vertical hit");
                assert!((hit.point.z - h).abs() < 1e-6);
                checked += 1;
            }
            None => assert!(over_hole, "no ground at ({x}, {y})"),
        }
    }
    assert!(checked > 4800);
    assert_eq!(world.ground_height(-0.5, 3.5), None);
    assert_eq!(world.ground_height(-2.01, 2.0), None);
    assert_eq!(world.ground_height(0.0, 8.51), None);
    assert!((world.ground_height(3.0, 8.5).expect("corner") - plane(3.0, 8.5)).abs() < 1e-9);
}

#[test]
fn oblique_rays_into_inclined_heightfield_match_the_plane() {
    let (world, plane) = inclined_field(&[]);
    let n = DVec3::new(-0.2, 0.1, 1.0).normalize();
    let mut rng = rng(9);
    let mut hits = 0;
    for _ in 0..3000 {
        let origin = DVec3::new(rng.random_range(-1.0..2.0), rng.random_range(2.0..7.0), rng.random_range(2.0..6.0));
        let mut d = unit(&mut rng);
        d.z = -d.z.abs().max(0.3);
        let d = d.normalize();
        // Analytic: plane through (0, 0, 0.3) with normal n.
        let t = n.dot(DVec3::new(0.0, 0.0, 0.3) - origin) / n.dot(d);
        let p = origin + d * t;
        let inside = p.x > -1.9 && p.x < 2.9 && p.y > 1.1 && p.y < 8.4;
        let hit = world.cast_ray(origin, d, 50.0);
        if inside {
            let hit = hit.expect("terrain hit");
            assert!((hit.distance_m - t).abs() < TOL_M, "{} vs {t}", hit.distance_m);
            assert!((hit.point.z - plane(hit.point.x, hit.point.y)).abs() < 1e-6);
            assert!((hit.normal - n).length() < 1e-6);
            hits += 1;
        }
    }
    assert!(hits > 500, "{hits}");
}

#[test]
fn clearance_matches_analytic_distances() {
    let mut rng = rng(10);
    for kind in 0..4 {
        for _ in 0..20 {
            let shape = random_shape(&mut rng, kind, 3.0);
            let world = single(shape);
            for _ in 0..50 {
                let p = if rng.random_range(0.0..1.0) < 0.3 { shape.interior(&mut rng) } else { in_cube(&mut rng, 6.0) };
                let want = shape.sdf(p);
                let got = world.clearance(p);
                assert!((got - want).abs() < TOL_M, "{shape:?} at {p}: {got} vs {want}");
            }
        }
    }
    // Plane: signed.
    let spec = WorldSpec { planes: vec![PlaneSpec { point: [0.0, 0.0, 1.0], normal: [0.0, 3.0, 4.0], tag: String::new(), dark: false }], ..Default::default() };
    let world = World::from_spec(spec).expect("valid");
    assert!((world.clearance(DVec3::new(5.0, 1.0, 2.0)) - (0.6 + 0.8)).abs() < 1e-12);
    assert!((world.clearance(DVec3::new(5.0, -1.0, 0.0)) - (-0.6 - 0.8)).abs() < 1e-12);
    // Terrain: perpendicular distance to the inclined surface, negative below it.
    let (world, plane) = inclined_field(&[]);
    let slope = (1.0f64 + 0.2 * 0.2 + 0.1 * 0.1).sqrt();
    for _ in 0..500 {
        let (x, y) = (rng.random_range(-1.0..2.0), rng.random_range(2.5..7.0));
        let dz = rng.random_range(-0.5..0.8);
        let got = world.clearance(DVec3::new(x, y, plane(x, y) + dz));
        assert!((got - dz / slope).abs() < TOL_M, "{got} vs {}", dz / slope);
    }
}

fn invalid_field(text: &str) -> (String, String) {
    match World::from_toml_str(text) {
        Err(SimError::InvalidWorld { field, reason }) => (field, reason),
        other => panic!("expected InvalidWorld, got {other:?}"),
    }
}

#[test]
fn bad_worlds_name_the_field_or_line() {
    let cylinders = "[[cylinder]]\na = [0, 0, 0]\nb = [0, 0, 1]\nradius = 0.1\n".repeat(3);
    let (field, reason) = invalid_field(&format!("{cylinders}[[cylinder]]\na = [0, 0, 0]\nb = [0, 0, 1]\nradius = -0.1\n"));
    assert_eq!(field, "cylinder[3].radius");
    assert!(reason.contains("> 0"), "{reason}");
    let message = World::from_toml_str(&format!("{cylinders}[[cylinder]]\na = [0, 0, 0]\nb = [0, 0, 1]\nradius = -0.1\n")).unwrap_err().to_string();
    assert_eq!(message, "world: cylinder[3].radius: must be finite and > 0 (got -0.1)");

    assert_eq!(invalid_field("[[sphere]]\ncentre = [0, nan, 0]\nradius = 1\n").0, "sphere[0].centre");
    assert_eq!(invalid_field("[[box]]\ncentre = [0, 0, 0]\nsize = [1, 0, 1]\n").0, "box[0].size[1]");
    assert_eq!(invalid_field("[[cylinder]]\na = [1, 1, 1]\nb = [1, 1, 1]\nradius = 1\n").0, "cylinder[0].b");
    assert_eq!(invalid_field("[heightfield]\norigin = [0, 0]\nresolution = 1\nheights = [[0, 0, 0], [0, 0]]\n").0, "heightfield.heights[1]");
    assert_eq!(invalid_field("[heightfield]\norigin = [0, 0]\nresolution = 1\nheights = [[0, 0, 0]]\n").0, "heightfield.heights");
    assert_eq!(invalid_field("[heightfield]\norigin = [0, 0]\nresolution = 1\nheights = [[0, 0], [0, inf]]\n").0, "heightfield.heights[1][1]");
    assert_eq!(invalid_field("[heightfield]\norigin = [0, 0]\nresolution = 0\nheights = [[0, 0], [0, 0]]\n").0, "heightfield.resolution");
    assert_eq!(invalid_field("[[plane]]\npoint = [0, 0, 0]\nnormal = [0, 0, 0]\n").0, "plane[0].normal");
    let regions = "[[region]]\nname = \"A\"\ncentre = [0, 0, 0]\nradius = 1\n[[region]]\nname = \"B\"\ncentre = [1, 0, 0]\nradius = 1\n";
    let (field, reason) = invalid_field(&format!("{regions}[[region]]\nname = \"A\"\ncentre = [2, 0, 0]\nradius = 1\n"));
    assert_eq!(field, "region[2].name");
    assert!(reason.contains("duplicate") && reason.contains("region[0]"), "{reason}");
    let (field, reason) = invalid_field(&format!("{regions}[[route]]\nname = \"A-C\"\nfrom = \"A\"\nto = \"C\"\n"));
    assert_eq!(field, "route[0].to");
    assert!(reason.contains("`C`") && reason.contains("A, B"), "{reason}");
    assert_eq!(invalid_field("[[item]]\nkind = \"comm_node\"\nposition = [0, 0, 0]\nkeep_out_radius = -1\n").0, "item[0].keep_out_radius");

    // Malformed TOML: line and column of the fault.
    assert_eq!(invalid_field("name = \"x\"\n[[sphere]]\ncentre = [0, 0, 0\nradius = 1\n").0.split(',').next(), Some("line 4"));
    assert_eq!(invalid_field("name = \"x\"\n[[sphere]\n").0, "line 2, column 10");
    // Unknown key, and a wrong type.
    let (field, reason) = invalid_field("[[sphere]]\ncentre = [0, 0, 0]\nradius = 1\nradiuss = 2\n");
    assert_eq!(field, "sphere[0].radiuss (line 4, column 1)");
    assert!(reason.contains("radiuss"), "{reason}");
    let (field, _) = invalid_field("[[box]]\ncentre = [0, 0, 0]\nsize = \"big\"\n");
    assert_eq!(field, "box[0].size (line 3, column 8)");
    assert_eq!(invalid_field("[[cylindre]]\n").0, "cylindre (line 1, column 3)");
}

#[test]
fn example_world_loads_and_answers() {
    let world = World::from_toml_str(include_str!("../../../docs/examples/world.toml")).expect("example world is valid");
    let spec = world.spec();
    assert_eq!(spec.name, "example-room");
    // cylinder, capsule, box, sphere, solid item, 4 planes, terrain.
    assert_eq!(world.primitive_count(), 10);
    let kinds: Vec<PrimitiveKind> = (0..10).filter_map(|i| world.primitive(i).map(|p| p.kind)).collect();
    use PrimitiveKind::*;
    assert_eq!(kinds, [Cylinder, Capsule, Box, Sphere, Item, Plane, Plane, Plane, Plane, HeightField]);
    assert_eq!(world.primitive(1).map(|p| (p.tag.as_str(), p.width_m)), Some(("cable", 0.008)));
    assert_eq!(world.primitive(8).map(|p| p.dark), Some(true));
    assert_eq!(world.region("B").map(|r| r.centre), Some([9.0, 5.0, 1.0]));
    assert!(world.region("C").is_none());
    // Looking east at the pole from x = 1: its surface at x = 4 - 0.045.
    let hit = world.cast_ray(DVec3::new(1.0, 3.0, 1.5), DVec3::X, 10.0).expect("pole");
    assert_eq!(hit.primitive, 0);
    assert!((hit.distance_m - 2.955).abs() < 1e-9);
    // Looking north from the pole's far side: the dark wall at y = 6.
    let hit = world.cast_ray(DVec3::new(4.5, 3.0, 1.5), DVec3::Y, 10.0).expect("wall");
    assert_eq!((hit.primitive, hit.distance_m), (8, 3.0));
    // Ground: the floor plane, the terrain, and the hole (sample row 1, column 3 = (7.5, 0.5)).
    assert_eq!(world.ground_height(3.0, 2.0), Some(0.0));
    assert!((world.ground_height(7.0, 1.0).expect("terrain") - 0.15).abs() < 1e-12);
    assert_eq!(world.ground_height(7.5, 0.5), None);
    let (lo, hi) = world.bounds();
    assert!(lo.x <= 1.6 && hi.x >= 9.0 && lo.z <= 0.0 && hi.z >= 3.0, "{lo} {hi}");
    // The comm node sits on the floor: clearance 1 m above its centre is 0.85 m.
    assert!((world.clearance(DVec3::new(5.0, 1.0, 1.15)) - 0.85).abs() < 1e-5);
}

#[test]
fn documented_example_parses() {
    let doc = include_str!("../../../docs/world-format.md");
    let start = doc.find("```toml\n").expect("a toml block") + "```toml\n".len();
    let len = doc[start..].find("```").expect("closed block");
    let world = World::from_toml_str(&doc[start..start + len]).expect("the documented example is valid");
    assert_eq!(world.primitive_count(), 4); // cylinder, capsule, plane, terrain
    assert_eq!(world.ground_height(7.5, 0.5), None); // the hole_value sample
    assert_eq!(world.ground_height(8.0, 1.0), None); // the NaN sample
    assert!((world.ground_height(6.5, 0.5).expect("terrain") - 0.1).abs() < 1e-12);
    assert_eq!(world.ground_height(7.0, 0.5), None); // cell (1, 2) touches the hole at (1, 3)
    let err = World::from_toml_str("[[sphere]]\ncentre = [0, 0, 0]\nradius = 1\nradiuss = 2\n").unwrap_err().to_string();
    assert!(err.starts_with("world: sphere[0].radiuss (line 4, column 1): unknown field `radiuss`, expected"), "{err}");
}

/// Cost of one ray into a 200-object world (printed; run with `--release -- --nocapture`).
#[test]
fn single_ray_cost_in_a_200_object_world() {
    let (shapes, world) = clutter(11, 200, 10.0);
    let mut rng = rng(12);
    const BATCH: usize = 1000;
    const BATCHES: usize = 300;
    let rays: Vec<(DVec3, DVec3)> = (0..BATCH * BATCHES).map(|_| (in_cube(&mut rng, 12.0), unit(&mut rng))).collect();
    // Correctness on a sample first.
    for (o, d) in rays.iter().take(500) {
        let want = brute_force(&shapes, *o, *d, 20.0).map(|(_, t)| t);
        let got = world.cast_ray(*o, *d, 20.0).map(|h| h.distance_m);
        assert_eq!(want.is_some(), got.is_some());
        if let (Some(w), Some(g)) = (want, got) {
            assert!((w - g).abs() < TOL_M);
        }
    }
    let mut per_ray_ns = Vec::with_capacity(BATCHES);
    let mut hits = 0usize;
    for batch in rays.chunks(BATCH) {
        let start = Instant::now();
        for (o, d) in batch {
            hits += usize::from(std::hint::black_box(world.cast_ray(*o, *d, 20.0)).is_some());
        }
        per_ray_ns.push(start.elapsed().as_nanos() as f64 / BATCH as f64);
    }
    per_ray_ns.sort_by(f64::total_cmp);
    let brute_start = Instant::now();
    for (o, d) in rays.iter().take(BATCH * 10) {
        std::hint::black_box(brute_force(&shapes, *o, *d, 20.0));
    }
    let brute_ns = brute_start.elapsed().as_nanos() as f64 / (BATCH * 10) as f64;
    println!(
        "cast_ray, 200 objects, {} rays ({hits} hits): median {:.0} ns/ray, p90 {:.0} ns/ray; brute-force reference loop {brute_ns:.0} ns/ray",
        rays.len(),
        per_ray_ns[BATCHES / 2],
        per_ray_ns[BATCHES * 9 / 10]
    );
    assert!(hits > 0);

    // A flight hall like `highbay`: 17 x 8 x 4 m of planes and 200 poles and boxes; rays from
    // inside, 10 m range, as a depth camera casts them.
    let mut spec = WorldSpec::default();
    for (point, normal) in [
        ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 4.0], [0.0, 0.0, -1.0]),
        ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
        ([17.0, 0.0, 0.0], [-1.0, 0.0, 0.0]),
        ([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.0, 8.0, 0.0], [0.0, -1.0, 0.0]),
    ] {
        spec.planes.push(PlaneSpec { point, normal, tag: String::new(), dark: false });
    }
    for i in 0..200 {
        let (x, y) = (rng.random_range(0.5..16.5), rng.random_range(0.5..7.5));
        if i % 4 == 3 {
            let size = [rng.random_range(0.2..1.0), rng.random_range(0.2..1.0), rng.random_range(0.2..2.0)];
            spec.boxes.push(BoxSpec { centre: [x, y, 0.5 * size[2]], size, yaw: rng.random_range(0.0..3.0), tag: String::new(), dark: false });
        } else {
            let radius = [0.135, 0.045, 0.011][i % 3];
            spec.cylinders.push(CylinderSpec { a: [x, y, 0.0], b: [x, y, 4.0], radius, tag: String::new(), dark: false });
        }
    }
    let hall = World::from_spec(spec).expect("valid");
    let rays: Vec<(DVec3, DVec3)> = (0..BATCH * BATCHES)
        .map(|_| (DVec3::new(rng.random_range(1.0..16.0), rng.random_range(1.0..7.0), rng.random_range(0.5..2.5)), unit(&mut rng)))
        .collect();
    let mut per_ray_ns = Vec::with_capacity(BATCHES);
    for batch in rays.chunks(BATCH) {
        let start = Instant::now();
        for (o, d) in batch {
            std::hint::black_box(hall.cast_ray(*o, *d, 10.0));
        }
        per_ray_ns.push(start.elapsed().as_nanos() as f64 / BATCH as f64);
    }
    per_ray_ns.sort_by(f64::total_cmp);
    println!("cast_ray, 17 x 8 m hall (6 planes, 200 objects), {} rays from inside: median {:.0} ns/ray", rays.len(), per_ray_ns[BATCHES / 2]);
}

#[path = "../../subterra/tests/common/mutate.rs"]
mod mutate;

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 300, rng_seed: proptest::test_runner::RngSeed::Fixed(22), ..Default::default() })]

    /// The example world damaged in any way parses, or gives a one-line error; never a panic.
    #[test]
    fn damaged_worlds_parse_or_give_a_one_line_error(edits in proptest::collection::vec(mutate::edit_strategy(), 1..4)) {
        let text = include_str!("../../../docs/examples/world.toml");
        let damaged = edits.iter().fold(text.to_string(), |t, e| mutate::apply(&t, e));
        if let Err(e) = World::from_toml_str(&damaged) {
            let message = e.to_string();
            proptest::prop_assert!(!message.contains('\n') && message.len() < 2000, "{message}");
        }
    }
}
