//! Depth camera and lidar geometry against analytic answers, and noise statistics
//! against their configuration.

// A pixel index drives several parallel buffers (depth, primitive, incidence, noise) here.
#![allow(clippy::needless_range_loop)]

use glam::{DMat3, DVec3};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use subterra::{Isometry3, PinholeCamera};
use subterra_sim::noise::{DepthNoise, DepthNoiseModel, LidarNoise, LidarNoiseModel};
use subterra_sim::sensors::{render_depth, scan_lidar, DepthCamera, DepthCameraConfig, DepthRender, Lidar, LidarConfig, LidarScan};
use subterra_sim::spec::{CapsuleSpec, CylinderSpec, PlaneSpec, SphereSpec, WorldSpec};
use subterra_sim::world::{PrimitiveKind, World};
use subterra_sim::SimError;

fn plane(point: [f64; 3], normal: [f64; 3], tag: &str) -> PlaneSpec {
    PlaneSpec { point, normal, tag: tag.into(), dark: false }
}

fn sphere(centre: [f64; 3], radius: f64, tag: &str, dark: bool) -> SphereSpec {
    SphereSpec { centre, radius, tag: tag.into(), dark }
}

fn world(spec: WorldSpec) -> World {
    World::from_spec(spec).expect("test world is valid")
}

/// A camera at `position` looking along world +x (image right = world -y, image down = world -z).
fn looking_along_x(position: DVec3) -> Isometry3 {
    Isometry3 { rotation: Isometry3::body_from_forward_optical().rotation, translation: position }
}

/// Optical-frame point of pixel index `p` at depth `z`.
fn back_project(camera: &PinholeCamera, p: usize, z: f32) -> DVec3 {
    let (u, v) = ((p % camera.width as usize) as f64, (p / camera.width as usize) as f64);
    camera.back_project(u, v, f64::from(z))
}

/// Unit ray of pixel index `p` in the optical frame, computed here independently.
fn pixel_ray(camera: &PinholeCamera, p: usize) -> DVec3 {
    back_project(camera, p, 1.0).normalize()
}

fn tag_of(world: &World, id: i32) -> Option<&str> {
    u32::try_from(id).ok().and_then(|id| world.primitive(id)).map(|p| p.tag.as_str())
}

fn std_dev(xs: &[f64]) -> f64 {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}

fn small_camera() -> DepthCameraConfig {
    // A quarter-resolution D435: same field of view, quicker tests.
    DepthCameraConfig { camera: PinholeCamera { fx: 192.5, fy: 192.5, cx: 159.5, cy: 119.5, width: 320, height: 240 }, min_range_m: 0.1, max_range_m: 10.0 }
}

// ---------------------------------------------------------------- depth camera geometry

#[test]
fn plane_facing_the_camera_has_its_distance_in_every_pixel() {
    let config = DepthCameraConfig::d435();
    let camera = DepthCamera::new(config).unwrap();
    for d in [0.5, 3.7, 9.5] {
        let w = world(WorldSpec { planes: vec![plane([d + 2.0, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")], ..Default::default() });
        let render = camera.render(&w, &looking_along_x(DVec3::new(2.0, 0.0, 1.0)));
        assert_eq!((render.width, render.height), (640, 480));
        assert_eq!(render.depth_m.len(), 640 * 480);
        let worst = render.depth_m.iter().map(|&z| (f64::from(z) - d).abs()).fold(0.0, f64::max);
        assert!(worst < 2e-5 * d.max(1.0), "d = {d}: worst error {worst}");
        for p in (0..render.depth_m.len()).step_by(97) {
            assert_eq!(tag_of(&w, render.primitive[p]), Some("wall"));
            // Head-on plane: |cos incidence| is the ray's optical z component.
            let expected = pixel_ray(&config.camera, p).z;
            assert!((f64::from(render.incidence_cos[p]) - expected).abs() < 1e-5, "pixel {p}");
        }
    }
    // Beyond max range and nearer than min range: no return anywhere.
    for d in [10.5, 0.05] {
        let w = world(WorldSpec { planes: vec![plane([d, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")], ..Default::default() });
        let render = render_depth(&w, &config, &looking_along_x(DVec3::ZERO));
        assert_eq!(render.valid_count(), 0, "d = {d}");
        assert!(render.primitive.iter().all(|&id| id == -1));
        assert!(render.incidence_cos.iter().all(|&c| c == 0.0));
    }
}

#[test]
fn depth_is_along_the_optical_axis_not_the_ray() {
    // Plane at 4 m: the corner pixel's ray is 1.45 x longer, its depth still 4 m;
    // the point 9.5 m along the axis but beyond 10 m along the corner ray is still seen.
    let config = DepthCameraConfig::d435();
    let w = world(WorldSpec { planes: vec![plane([9.5, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")], ..Default::default() });
    let render = render_depth(&w, &config, &looking_along_x(DVec3::ZERO));
    let corner_ray_length = 9.5 / pixel_ray(&config.camera, 0).z;
    assert!(corner_ray_length > 13.0);
    assert!((render.depth_m[0] - 9.5).abs() < 1e-4);
}

#[test]
fn back_projected_pixels_lie_on_a_tilted_plane() {
    let config = DepthCameraConfig::d435();
    let p0 = DVec3::new(4.0, 0.0, 0.0);
    let n = DVec3::new(-1.0, 0.3, 0.5).normalize();
    let w = world(WorldSpec { planes: vec![plane(p0.to_array(), n.to_array(), "tilted")], ..Default::default() });
    // Yawed 0.2 rad left, pitched 0.1 rad down, rolled 0.05 rad.
    let rotation = DMat3::from_rotation_z(0.2) * DMat3::from_rotation_y(0.1) * DMat3::from_rotation_x(0.05) * Isometry3::body_from_forward_optical().rotation;
    let pose = Isometry3 { rotation, translation: DVec3::new(0.0, 0.0, 1.0) };
    let render = render_depth(&w, &config, &pose);
    let mut checked = 0;
    for p in 0..render.depth_m.len() {
        let z = render.depth_m[p];
        if z == 0.0 {
            continue;
        }
        let p_world = pose.transform_point(back_project(&config.camera, p, z));
        let off = n.dot(p_world - p0).abs();
        assert!(off < 1e-4, "pixel {p}: {off} m off the plane");
        // Incidence: |cos| between the world ray and the normal.
        let ray_world = pose.transform_vector(pixel_ray(&config.camera, p));
        assert!((f64::from(render.incidence_cos[p]) - ray_world.dot(n).abs()).abs() < 1e-5);
        checked += 1;
    }
    // The plane fills most of the view (the far part beyond 10 m drops out).
    assert!(checked > 200_000, "{checked}");
}

#[test]
fn sphere_silhouette_is_the_cone_of_its_angular_radius() {
    let config = DepthCameraConfig::d435();
    let (distance, radius) = (3.0, 0.5);
    let centre = DVec3::new(distance, 0.0, 1.0);
    let w = world(WorldSpec { spheres: vec![sphere(centre.to_array(), radius, "ball", false)], ..Default::default() });
    let render = render_depth(&w, &config, &looking_along_x(DVec3::new(0.0, 0.0, 1.0)));
    let half_angle = (radius / distance).asin();
    let margin = 2e-3; // rad, ~0.8 px: skip the rim, where f32 geometry decides
    let (mut inside, mut outside) = (0, 0);
    for p in 0..render.depth_m.len() {
        let angle = pixel_ray(&config.camera, p).z.acos();
        let z = render.depth_m[p];
        if angle < half_angle - margin {
            assert!(z > 0.0, "pixel {p} inside the silhouette has no return");
            let p_world = looking_along_x(DVec3::new(0.0, 0.0, 1.0)).transform_point(back_project(&config.camera, p, z));
            assert!(((p_world - centre).length() - radius).abs() < 1e-4, "pixel {p}");
            let id = u32::try_from(render.primitive[p]).unwrap();
            assert!(matches!(w.primitive(id).unwrap().kind, PrimitiveKind::Sphere));
            inside += 1;
        } else if angle > half_angle + margin {
            assert_eq!(z, 0.0, "pixel {p} outside the silhouette has a return");
            outside += 1;
        }
    }
    // Silhouette area ≈ π (f tan θ)² = π (385 · 0.169)² ≈ 13 300 px.
    let expected = std::f64::consts::PI * (385.0 * half_angle.tan()).powi(2);
    assert!((f64::from(render.valid_count() as u32) - expected).abs() < 0.02 * expected, "{} vs {expected}", render.valid_count());
    assert!(inside > 12_500 && outside > 280_000, "{inside} {outside}");
}

#[test]
fn parallel_render_is_identical() {
    let config = DepthCameraConfig::d435();
    let w = world(WorldSpec {
        planes: vec![plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor")],
        spheres: vec![sphere([3.0, 0.5, 1.0], 0.4, "ball", false)],
        ..Default::default()
    });
    let camera = DepthCamera::new(config).unwrap();
    let pose = looking_along_x(DVec3::new(0.0, 0.0, 1.0));
    let serial = camera.render(&w, &pose);
    for threads in [0, 1, 3, 7] {
        assert_eq!(camera.render_parallel(&w, &pose, threads), serial, "{threads} threads");
    }
    // A NaN pose: no return, no panic.
    let bad = Isometry3 { rotation: pose.rotation, translation: DVec3::new(f64::NAN, 0.0, 0.0) };
    assert_eq!(camera.render(&w, &bad).valid_count(), 0);
}

// ---------------------------------------------------------------- lidar geometry

fn floor_and_ceiling(h: f64) -> World {
    world(WorldSpec { planes: vec![plane([0.0, 0.0, -h], [0.0, 0.0, 1.0], "floor"), plane([0.0, 0.0, h], [0.0, 0.0, -1.0], "ceiling")], ..Default::default() })
}

#[test]
fn lidar_rings_and_azimuths_are_exact() {
    // 0.5 m: the flattest OS1 ring (0.26°) meets the planes at 109 m, inside its 120 m.
    let h = 0.5;
    let w = floor_and_ceiling(h);
    for config in [LidarConfig::vlp16(), LidarConfig::os1_64()] {
        let scan = scan_lidar(&w, &config, &Isometry3::IDENTITY);
        let rings = config.vertical_angles_rad.len();
        // No ring is horizontal, so every beam hits the floor or the ceiling.
        assert_eq!(scan.len(), rings * config.azimuth_steps as usize);
        let mut per_ring = vec![0_u32; rings];
        for (i, (q, &ring)) in scan.points_sensor.iter().zip(&scan.ring).enumerate() {
            let p = DVec3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
            let elevation = config.vertical_angles_rad[usize::from(ring)];
            assert!((p.z.atan2(p.truncate().length()) - elevation).abs() < 1e-6, "point {i}");
            // Range to a horizontal plane at ±h: h / |sin e|.
            let expected = h / elevation.sin().abs();
            assert!((p.length() - expected).abs() < 1e-4 * expected.max(1.0), "point {i}: {} vs {expected}", p.length());
            // Firing order: azimuth step k = i / rings at 2π k / steps.
            let k = (i / rings) as f64;
            let azimuth = std::f64::consts::TAU * k / f64::from(config.azimuth_steps);
            let got = p.y.atan2(p.x).rem_euclid(std::f64::consts::TAU);
            let diff = (got - azimuth).abs();
            assert!(diff.min(std::f64::consts::TAU - diff) < 1e-5, "point {i}");
            assert_eq!(usize::from(ring), i % rings);
            assert_eq!(tag_of(&w, scan.primitive[i]), Some(if elevation > 0.0 { "ceiling" } else { "floor" }));
            per_ring[usize::from(ring)] += 1;
        }
        assert!(per_ring.iter().all(|&c| c == config.azimuth_steps));
    }
}

/// Range along the unit ray `d` from the origin to a vertical infinite cylinder of radius
/// `r` around (cx, cy), or None when it misses (origin outside the cylinder).
fn ray_to_vertical_cylinder(d: DVec3, cx: f64, cy: f64, r: f64) -> Option<f64> {
    let (a, b, c) = (d.x * d.x + d.y * d.y, -2.0 * (d.x * cx + d.y * cy), cx * cx + cy * cy - r * r);
    let disc = b * b - 4.0 * a * c;
    (a > 0.0 && disc >= 0.0).then(|| (-b - disc.sqrt()) / (2.0 * a)).filter(|&t| t > 0.0)
}

#[test]
fn lidar_ranges_to_a_pole_are_exact() {
    // A pole of radius 0.4 m, 6 m ahead-left, tall enough for every ring within 100 m.
    let (cx, cy, r) = (5.0, 3.0, 0.4);
    let w = world(WorldSpec {
        cylinders: vec![CylinderSpec { a: [cx, cy, -40.0], b: [cx, cy, 40.0], radius: r, tag: "pole".into(), dark: false }],
        ..Default::default()
    });
    let config = LidarConfig::vlp16();
    let lidar = Lidar::new(config.clone()).unwrap();
    // Sensor at z = 0.5 m, yawed by 0.3 rad: the pole sits at bearing atan2(3, 5) - 0.3 in the sensor frame.
    let yaw = 0.3;
    let pose = Isometry3 { rotation: DMat3::from_rotation_z(yaw), translation: DVec3::new(0.0, 0.0, 0.5) };
    let scan = lidar.scan(&w, &pose);
    let rings = config.vertical_angles_rad.len();
    let mut expected_hits = 0;
    let mut found = scan.points_sensor.iter().zip(&scan.ring).peekable();
    for k in 0..config.azimuth_steps {
        let azimuth = std::f64::consts::TAU * f64::from(k) / f64::from(config.azimuth_steps);
        for (ring, &e) in config.vertical_angles_rad.iter().enumerate() {
            let beam = DVec3::new(e.cos() * azimuth.cos(), e.cos() * azimuth.sin(), e.sin());
            let expected = ray_to_vertical_cylinder(DMat3::from_rotation_z(yaw) * beam, cx, cy, r);
            // The next returned point, if it belongs to this beam.
            let got = found.peek().and_then(|(q, &qr)| {
                let p = DVec3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
                (usize::from(qr) == ring && (p.normalize() - beam).length() < 1e-5).then_some(p.length())
            });
            match (expected, got) {
                (Some(t), Some(range)) => {
                    assert!((range - t).abs() < 1e-4, "step {k} ring {ring}: {range} vs {t}");
                    expected_hits += 1;
                    found.next();
                }
                (None, None) => {}
                (Some(t), None) => {
                    // Only a ray grazing the rim may be missed in f32 geometry.
                    let miss = (DMat3::from_rotation_z(yaw) * beam).truncate().normalize().perp_dot(DVec3::new(cx, cy, 0.0).truncate()).abs();
                    assert!((miss - r).abs() < 1e-4, "step {k} ring {ring}: missed a return at {t} m");
                }
                (None, Some(range)) => panic!("step {k} ring {ring}: unexpected return at {range} m"),
            }
        }
    }
    assert!(found.next().is_none());
    // Angular width of the pole: 2 asin(0.4 / sqrt(34)) = 7.87° -> ~39 azimuth steps x 16 rings.
    assert!(expected_hits > 35 * rings, "{expected_hits}");
}

// ---------------------------------------------------------------- depth noise statistics

fn wall_render(d: f64, config: &DepthCameraConfig) -> (World, DepthRender) {
    let w = world(WorldSpec { planes: vec![plane([d, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")], ..Default::default() });
    let render = render_depth(&w, config, &looking_along_x(DVec3::ZERO));
    (w, render)
}

fn apply(stages: Vec<DepthNoise>, render: &DepthRender, w: &World, config: &DepthCameraConfig, seed: u64) -> Vec<f32> {
    let model = DepthNoiseModel::new(stages).unwrap();
    model.try_apply(render, w, config, &mut Xoshiro256PlusPlus::seed_from_u64(seed)).unwrap()
}

#[test]
fn paper_gaussian_std_and_every_nth_pattern_are_exact() {
    let config = DepthCameraConfig::d435();
    let (w, render) = wall_render(5.0, &config);
    assert_eq!(render.valid_count(), 640 * 480);
    for every_n in [1_u32, 2, 10] {
        let noisy = apply(vec![DepthNoise::PaperGaussian { sigma_m: 0.2, every_n }], &render, &w, &config, 11);
        let mut residuals = Vec::new();
        let mut unchanged_in_pattern = 0;
        for (p, (&a, &b)) in noisy.iter().zip(&render.depth_m).enumerate() {
            let changed = a.to_bits() != b.to_bits();
            if p % every_n as usize == 0 {
                residuals.push(f64::from(a) - f64::from(b));
                unchanged_in_pattern += usize::from(!changed);
            } else {
                assert!(!changed, "every {every_n}: pixel {p} is off the pattern but changed");
            }
        }
        assert_eq!(residuals.len(), (640_usize * 480).div_ceil(every_n as usize));
        // A pattern pixel keeps its f32 value only when its draw is within half an ulp of
        // zero (|N(0, 0.2)| < 2.4e-7 m at 5 m: probability 1e-6 per pixel).
        assert!(unchanged_in_pattern <= 2, "every {every_n}: {unchanged_in_pattern} pattern pixels unchanged");
        let s = std_dev(&residuals);
        assert!((s - 0.2).abs() < 0.05 * 0.2, "every {every_n}: std {s}");
        let mean = residuals.iter().sum::<f64>() / residuals.len() as f64;
        assert!(mean.abs() < 0.01, "every {every_n}: mean {mean}");
    }
    // Presets are the same stages.
    let preset = DepthNoiseModel::preset("paper-every-2nd").unwrap();
    assert_eq!(preset.stages, vec![DepthNoise::PaperGaussian { sigma_m: 0.2, every_n: 2 }]);
}

#[test]
fn paper_gaussian_leaves_no_return_pixels_alone() {
    let config = small_camera();
    let (w, render) = wall_render(50.0, &config); // beyond range: no return
    let noisy = apply(vec![DepthNoise::PaperGaussian { sigma_m: 0.2, every_n: 1 }], &render, &w, &config, 1);
    assert!(noisy.iter().all(|&z| z == 0.0));
}

#[test]
fn stereo_noise_grows_with_depth_as_configured() {
    let config = DepthCameraConfig::d435();
    let (c, l, q) = (0.001, 0.002, 0.0025);
    for d in [1.0, 4.0, 8.0] {
        let (w, render) = wall_render(d, &config);
        let noisy = apply(vec![DepthNoise::Stereo { c_m: c, l, q_per_m: q }], &render, &w, &config, 5);
        let residuals: Vec<f64> = noisy.iter().zip(&render.depth_m).map(|(&a, &b)| f64::from(a) - f64::from(b)).collect();
        let sigma = c + l * d + q * d * d; // 1 m: 5.5 mm; 4 m: 49 mm; 8 m: 177 mm
        let s = std_dev(&residuals);
        assert!((s - sigma).abs() < 0.05 * sigma, "d = {d}: std {s} vs {sigma}");
    }
}

#[test]
fn dropout_fraction_matches_probability() {
    let config = DepthCameraConfig::d435();
    let (w, render) = wall_render(3.0, &config);
    for probability in [0.0, 0.02, 0.3, 1.0] {
        let noisy = apply(vec![DepthNoise::Dropout { probability }], &render, &w, &config, 9);
        let dropped = noisy.iter().filter(|&&z| z == 0.0).count() as f64 / noisy.len() as f64;
        assert!((dropped - probability).abs() < 0.01, "p = {probability}: dropped {dropped}");
        // Survivors keep their depth bit for bit.
        assert!(noisy.iter().zip(&render.depth_m).all(|(&a, &b)| a == 0.0 || a == b));
    }
}

#[test]
fn same_seed_same_bits_other_seed_other_bits() {
    let config = small_camera();
    let w = world(WorldSpec {
        planes: vec![plane([6.0, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall"), plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor")],
        spheres: vec![sphere([3.0, 0.3, 1.0], 0.4, "ball", false)],
        capsules: vec![CapsuleSpec { a: [1.5, -2.0, 1.2], b: [1.5, 2.0, 1.2], radius: 0.004, tag: "cable".into(), dark: false }],
        ..Default::default()
    });
    let render = render_depth(&w, &config, &looking_along_x(DVec3::new(0.0, 0.0, 1.0)));
    let model = DepthNoiseModel::preset("d435-phantom").unwrap();
    let run = |seed| model.apply(&render, &w, &config, &mut Xoshiro256PlusPlus::seed_from_u64(seed));
    let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
    assert_eq!(bits(run(42)), bits(run(42)));
    assert_ne!(bits(run(42)), bits(run(43)));
    let lidar_scan = scan_lidar(&floor_and_ceiling(1.0), &LidarConfig::vlp16(), &Isometry3::IDENTITY);
    let lidar_noise = LidarNoiseModel::preset("vlp16").unwrap();
    let a = lidar_noise.apply(&lidar_scan, &mut Xoshiro256PlusPlus::seed_from_u64(1));
    let b = lidar_noise.apply(&lidar_scan, &mut Xoshiro256PlusPlus::seed_from_u64(1));
    assert_eq!(a, b);
    assert_ne!(a, lidar_noise.apply(&lidar_scan, &mut Xoshiro256PlusPlus::seed_from_u64(2)));
}

#[test]
fn thin_cable_vanishes_where_narrower_than_min_width() {
    // An 8 mm cable across the view, 2 px minimum: 0.008 · 385 / z >= 2  <=>  z <= 1.54 m.
    let config = DepthCameraConfig::d435();
    let stages = vec![DepthNoise::ThinNoReturn { min_width_px: 2.0 }];
    for (distance, seen) in [(0.8, true), (1.4, true), (1.7, false), (3.0, false)] {
        let w = world(WorldSpec {
            planes: vec![plane([6.0, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")],
            cylinders: vec![CylinderSpec { a: [distance, -3.0, 1.0], b: [distance, 3.0, 1.0], radius: 0.004, tag: "cable".into(), dark: false }],
            ..Default::default()
        });
        let render = render_depth(&w, &config, &looking_along_x(DVec3::new(0.0, 0.0, 1.0)));
        let cable: Vec<usize> = (0..render.primitive.len()).filter(|&p| tag_of(&w, render.primitive[p]) == Some("cable")).collect();
        // The noise-free render sees the cable at every distance (a ray per pixel hits it).
        assert!(cable.len() >= 640, "{distance} m: {} cable pixels", cable.len());
        let noisy = apply(stages.clone(), &render, &w, &config, 0);
        let kept = cable.iter().filter(|&&p| noisy[p] > 0.0).count();
        if seen {
            assert_eq!(kept, cable.len(), "{distance} m");
        } else {
            assert_eq!(kept, 0, "{distance} m");
        }
        // The wall (infinite width) is never thin.
        assert!((0..noisy.len()).filter(|&p| tag_of(&w, render.primitive[p]) == Some("wall")).all(|p| noisy[p] > 0.0));
    }
}

#[test]
fn grazing_rays_lose_their_return() {
    // Floor seen from 1 m up, looking horizontally: the angle to the normal is acos(|d_z|).
    let config = DepthCameraConfig::d435();
    let w = world(WorldSpec { planes: vec![plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor")], ..Default::default() });
    let pose = looking_along_x(DVec3::new(0.0, 0.0, 1.0));
    let render = render_depth(&w, &config, &pose);
    let max_angle = 70.0_f64.to_radians();
    let noisy = apply(vec![DepthNoise::GrazingNoReturn { max_angle_rad: max_angle }], &render, &w, &config, 0);
    let (mut kept, mut lost) = (0, 0);
    for p in 0..noisy.len() {
        if render.depth_m[p] == 0.0 {
            assert_eq!(noisy[p], 0.0);
            continue;
        }
        let angle = pose.transform_vector(pixel_ray(&config.camera, p)).z.abs().acos();
        if angle < max_angle - 1e-4 {
            assert_eq!(noisy[p], render.depth_m[p], "pixel {p}");
            kept += 1;
        } else if angle > max_angle + 1e-4 {
            assert_eq!(noisy[p], 0.0, "pixel {p}");
            lost += 1;
        }
    }
    assert!(kept > 10_000 && lost > 10_000, "{kept} {lost}");
}

#[test]
fn dark_surfaces_give_no_return() {
    let config = small_camera();
    let w = world(WorldSpec {
        planes: vec![plane([6.0, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")],
        spheres: vec![sphere([3.0, 0.0, 0.0], 0.5, "dark ball", true), sphere([3.0, 1.5, 0.0], 0.5, "bright ball", false)],
        ..Default::default()
    });
    let render = render_depth(&w, &config, &looking_along_x(DVec3::ZERO));
    let noisy = apply(vec![DepthNoise::DarkNoReturn], &render, &w, &config, 0);
    let mut dark = 0;
    for p in 0..noisy.len() {
        match tag_of(&w, render.primitive[p]) {
            Some("dark ball") => {
                assert_eq!(noisy[p], 0.0);
                dark += 1;
            }
            Some(_) => assert_eq!(noisy[p], render.depth_m[p]),
            None => assert_eq!(noisy[p], 0.0),
        }
    }
    assert!(dark > 1000, "{dark}");
}

#[test]
fn flying_pixels_land_between_the_sides_of_an_edge() {
    let config = small_camera();
    let w = world(WorldSpec {
        planes: vec![plane([6.0, 0.0, 0.0], [-1.0, 0.0, 0.0], "wall")],
        spheres: vec![sphere([2.0, 0.0, 0.0], 0.4, "ball", false)],
        ..Default::default()
    });
    let render = render_depth(&w, &config, &looking_along_x(DVec3::ZERO));
    let width = render.width as usize;
    let noisy = apply(vec![DepthNoise::FlyingPixels { edge_jump_m: 1.0, probability: 1.0 }], &render, &w, &config, 4);
    let mut flown = 0;
    for p in 0..noisy.len() {
        let z = render.depth_m[p];
        let (u, v) = (p % width, p / width);
        let neighbours = [(u > 0).then(|| p - 1), (u + 1 < width).then(|| p + 1), (v > 0).then(|| p - width), (p + width < noisy.len()).then(|| p + width)];
        let far_side = neighbours
            .into_iter()
            .flatten()
            .map(|q| render.depth_m[q])
            .filter(|&zq| zq > 0.0 && (zq - z).abs() > 1.0)
            .max_by(|a, b| (a - z).abs().total_cmp(&(b - z).abs()));
        match far_side {
            Some(zq) => {
                let (lo, hi) = (z.min(zq), z.max(zq));
                assert!(noisy[p] >= lo && noisy[p] <= hi, "pixel {p}: {} not in [{lo}, {hi}]", noisy[p]);
                flown += 1;
            }
            None => assert_eq!(noisy[p], z, "pixel {p} is no edge"),
        }
    }
    // Both sides of the silhouette's rim: ~2 x 2π · 192.5 · tan(asin(0.2)) ≈ 500 pixels.
    assert!(flown > 300, "{flown}");
}

/// Number of 4-connected components of the pixels where `mask` holds.
fn components(mask: &[bool], width: usize) -> usize {
    let mut seen = vec![false; mask.len()];
    let mut count = 0;
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        count += 1;
        seen[start] = true;
        stack.push(start);
        while let Some(p) = stack.pop() {
            let (u, v) = (p % width, p / width);
            let next = [(u > 0).then(|| p - 1), (u + 1 < width).then(|| p + 1), (v > 0).then(|| p - width), (p + width < mask.len()).then(|| p + width)];
            for q in next.into_iter().flatten() {
                if mask[q] && !seen[q] {
                    seen[q] = true;
                    stack.push(q);
                }
            }
        }
    }
    count
}

#[test]
fn phantom_blobs_appear_at_the_configured_rate() {
    let config = small_camera();
    let (w, render) = wall_render(8.0, &config);
    let (rate, radius) = (3.0, 3.0);
    let model =
        DepthNoiseModel::new(vec![DepthNoise::PhantomSpeckle { blobs_per_frame: rate, radius_px: radius, min_depth_m: 0.5, max_depth_m: 1.5 }]).unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(77);
    let frames = 400;
    let (mut blobs, mut pixels) = (0, 0);
    for _ in 0..frames {
        let noisy = model.apply(&render, &w, &config, &mut rng);
        let mask: Vec<bool> = noisy.iter().map(|&z| z < 7.0).collect();
        for (&z, &m) in noisy.iter().zip(&mask) {
            if m {
                assert!((0.5..=1.5).contains(&z), "{z}");
            } else {
                assert_eq!(z, 8.0);
            }
        }
        blobs += components(&mask, config.camera.width as usize);
        pixels += mask.iter().filter(|&&m| m).count();
    }
    let mean_blobs = blobs as f64 / f64::from(frames);
    // Poisson(3) over 400 frames: standard error 0.087; overlaps merge ~2 % of blobs.
    assert!((mean_blobs - rate).abs() < 0.1 * rate, "{mean_blobs} blobs per frame");
    // Area of a blob: π r² ≈ 28.3 px on average over its sub-pixel position (a little
    // less at the image border).
    let area = pixels as f64 / blobs as f64;
    assert!(area > 22.0 && area < 34.0, "{area} px per blob");
}

#[test]
fn d435_preset_keeps_a_plausible_frame() {
    let config = DepthCameraConfig::d435();
    let (w, render) = wall_render(2.0, &config);
    let noisy = DepthNoiseModel::preset("d435").unwrap().apply(&render, &w, &config, &mut Xoshiro256PlusPlus::seed_from_u64(0));
    let valid: Vec<f64> = noisy.iter().filter(|&&z| z > 0.0).map(|&z| f64::from(z) - 2.0).collect();
    let kept = valid.len() as f64 / noisy.len() as f64;
    // Dropout 2 %, nothing thin, dark or grazing (the corner ray meets the wall at 46°).
    assert!((kept - 0.98).abs() < 0.01, "{kept}");
    let sigma = 0.001 + 0.002 * 2.0 + 0.0025 * 4.0;
    assert!((std_dev(&valid) - sigma).abs() < 0.05 * sigma);
}

// ---------------------------------------------------------------- lidar noise

#[test]
fn lidar_range_noise_and_dropout_match_configuration() {
    let w = floor_and_ceiling(1.0);
    let scan: LidarScan = scan_lidar(&w, &LidarConfig::vlp16(), &Isometry3::IDENTITY);
    let n = scan.len();
    let sigma = 0.05;
    let noisy = LidarNoiseModel::new(vec![LidarNoise::Range { sigma_m: sigma }]).unwrap().apply(&scan, &mut Xoshiro256PlusPlus::seed_from_u64(3));
    assert_eq!(noisy.len(), n);
    assert_eq!(noisy.ring, scan.ring);
    let mut residuals = Vec::with_capacity(n);
    for (a, b) in noisy.points_sensor.iter().zip(&scan.points_sensor) {
        let (a, b) = (DVec3::from_array(a.map(f64::from)), DVec3::from_array(b.map(f64::from)));
        // Along the ray: the direction is unchanged.
        assert!((a.normalize() - b.normalize()).length() < 1e-6);
        residuals.push(a.length() - b.length());
    }
    let s = std_dev(&residuals);
    assert!((s - sigma).abs() < 0.05 * sigma, "{s}");
    for probability in [0.1, 0.5] {
        let kept = LidarNoiseModel::new(vec![LidarNoise::Dropout { probability }]).unwrap().apply(&scan, &mut Xoshiro256PlusPlus::seed_from_u64(4));
        let dropped = 1.0 - kept.len() as f64 / n as f64;
        assert!((dropped - probability).abs() < 0.01, "{dropped}");
        assert_eq!(kept.ring.len(), kept.len());
        assert_eq!(kept.primitive.len(), kept.len());
    }
}

// ---------------------------------------------------------------- bad parameters

fn field_of(result: Result<impl std::fmt::Debug, SimError>) -> String {
    match result {
        Err(SimError::InvalidConfig { field, .. }) => field,
        other => panic!("expected InvalidConfig, got {other:?}"),
    }
}

#[test]
fn bad_parameters_name_the_field() {
    assert_eq!(field_of(DepthNoiseModel::new(vec![DepthNoise::PaperGaussian { sigma_m: -0.2, every_n: 1 }])), "stages[0].sigma_m");
    assert_eq!(field_of(DepthNoiseModel::new(vec![DepthNoise::DarkNoReturn, DepthNoise::Dropout { probability: 1.2 }])), "stages[1].probability");
    assert_eq!(field_of(DepthNoiseModel::new(vec![DepthNoise::Stereo { c_m: f64::NAN, l: 0.0, q_per_m: 0.0 }])), "stages[0].c_m");
    assert_eq!(field_of(DepthNoiseModel::new(vec![DepthNoise::ThinNoReturn { min_width_px: f64::NAN }])), "stages[0].min_width_px");
    assert_eq!(
        field_of(DepthNoiseModel::new(vec![DepthNoise::PhantomSpeckle { blobs_per_frame: -1.0, radius_px: 3.0, min_depth_m: 0.3, max_depth_m: 1.0 }])),
        "stages[0].blobs_per_frame"
    );
    assert_eq!(field_of(LidarNoiseModel::new(vec![LidarNoise::Range { sigma_m: -0.01 }])), "stages[0].sigma_m");
    assert_eq!(field_of(LidarNoiseModel::new(vec![LidarNoise::Dropout { probability: f64::NAN }])), "stages[0].probability");
    let mut lidar = LidarConfig::os1_64();
    lidar.azimuth_steps = 0;
    assert_eq!(field_of(Lidar::new(lidar)), "azimuth_steps");
    let mut lidar = LidarConfig::vlp16();
    lidar.max_range_m = f64::NAN;
    assert_eq!(field_of(Lidar::new(lidar)), "max_range_m");
    let mut camera = DepthCameraConfig::d435();
    camera.camera.fy = -1.0;
    assert_eq!(field_of(DepthCamera::new(camera)), "camera.fy");
    let mut camera = DepthCameraConfig::d435();
    camera.min_range_m = f64::NAN;
    assert_eq!(field_of(DepthCamera::new(camera)), "min_range_m");
    // The never-failing entry points degrade without panicking.
    let w = floor_and_ceiling(1.0);
    assert_eq!(render_depth(&w, &camera, &Isometry3::IDENTITY), DepthRender::default());
    let bad_model = DepthNoiseModel { stages: vec![DepthNoise::PaperGaussian { sigma_m: 0.2, every_n: 0 }] };
    let config = small_camera();
    let (w, render) = wall_render(2.0, &config);
    assert_eq!(bad_model.apply(&render, &w, &config, &mut Xoshiro256PlusPlus::seed_from_u64(0)), render.depth_m);
    assert_eq!(field_of(bad_model.try_apply(&render, &w, &config, &mut Xoshiro256PlusPlus::seed_from_u64(0))), "stages[0].every_n");
    assert!(matches!(DepthNoiseModel::preset("d455"), Err(SimError::Unknown { .. })));
}
