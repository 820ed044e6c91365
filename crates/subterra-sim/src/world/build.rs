//! Validation and construction: a [`WorldSpec`] checked field by field ([`validate`]) and
//! turned into a [`World`] ([`build`]).

use glam::DVec3;
use parry3d::math::{Pose, Rot3, Vector};
use parry3d::shape::{Compound, SharedShape};

use crate::error::{SimError, SimResult};
use crate::spec::{HeightFieldSpec, WorldSpec};

use super::bvh::FlatBvh;
use super::leaf::{Plane, Solid};
use super::terrain::Terrain;
use super::{to_f32, PrimitiveId, PrimitiveInfo, PrimitiveKind, World, ITEM_RADIUS_M, MAX_COORDINATE_M, TERRAIN_TAG};

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

pub(super) fn validate(spec: &WorldSpec) -> SimResult<()> {
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
pub(super) fn build(spec: WorldSpec) -> World {
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
