//! Tests of the world through its queries: hits against hand-computed answers, validation
//! errors, and fans and terrain views against single rays, bit for bit.


use super::*;
use crate::spec::{BoxSpec, CapsuleSpec, CylinderSpec, HeightFieldSpec, ItemSpec, PlaneSpec, RegionSpec, RouteSpec, SphereSpec};

fn sphere(centre: [f64; 3], radius: f64) -> SphereSpec {
    SphereSpec { centre, radius, tag: String::new(), dark: false }
}

pub(super) fn world(spec: WorldSpec) -> World {
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
pub(super) fn next(state: &mut u64) -> f64 {
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
