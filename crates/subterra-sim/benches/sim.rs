//! Sensor simulation speed: a 640x480 D435 depth frame of `highbay` and `tunnel`, a full
//! OS1-64 scan (64 x 1024 rays) of `mine` and a VLP-16 scan of `highbay`, each on one
//! core; the depth frame also split over all cores; and the `d435-phantom` noise chain.
//! Targets (issue 3): depth frame <= 10 ms on one core, lidar scan <= 5 ms. The depth benches
//! render into reused buffers (`render_into`, `render_parallel_into`), as a simulation loop
//! that keeps its frames would.
//!
//! Run: `cargo bench -p subterra-sim --bench sim`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::{DMat3, DVec3};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use subterra::Isometry3;
use subterra_sim::noise::DepthNoiseModel;
use subterra_sim::scenarios;
use subterra_sim::sensors::{DepthCamera, DepthCameraConfig, DepthRender, Lidar, LidarConfig};
use subterra_sim::world::World;

/// Seed of the benchmark worlds.
const SEED: u64 = 1;
/// Height of the lidar above the ground robot's contact point [m] (a Husky-mounted OS1).
const LIDAR_MOUNT_HEIGHT_M: f64 = 0.7;

fn scenario(name: &str) -> World {
    let spec = scenarios::generate(name, SEED).unwrap_or_else(|e| panic!("scenario {name}: {e}"));
    World::from_spec(spec).unwrap_or_else(|e| panic!("world {name}: {e}"))
}

fn region_centre(world: &World, name: &str) -> DVec3 {
    DVec3::from_array(world.region(name).unwrap_or_else(|| panic!("region {name}")).centre)
}

/// `world_from_camera` of a level camera at `position` looking toward `target` (horizontally).
fn camera_looking_at(position: DVec3, target: DVec3) -> Isometry3 {
    let yaw = (target.y - position.y).atan2(target.x - position.x);
    Isometry3 { rotation: DMat3::from_rotation_z(yaw) * Isometry3::body_from_forward_optical().rotation, translation: position }
}

fn bench_depth(c: &mut Criterion) {
    let camera = DepthCamera::new(DepthCameraConfig::d435()).expect("d435 is valid");
    let threads = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);

    let highbay = scenario("highbay");
    // From region A toward B: the hall's length, with poles of all three sizes in view.
    let highbay_pose = camera_looking_at(region_centre(&highbay, "A"), region_centre(&highbay, "B"));
    let frame = camera.render(&highbay, &highbay_pose);
    assert!(frame.valid_count() > frame.pixel_count() / 2, "highbay frame mostly empty");
    // One frame into reused buffers, as a simulation loop renders (rendered once before the
    // benchmark too, so that the check below holds when a filter skips it).
    let mut out = DepthRender::default();
    camera.render_into(&highbay, &highbay_pose, &mut out);
    c.bench_function("depth_d435_highbay_1core", |b| b.iter(|| camera.render_into(black_box(&highbay), black_box(&highbay_pose), &mut out)));
    assert_eq!(out, frame, "render_into differs from render");
    c.bench_function(&format!("depth_d435_highbay_{threads}threads"), |b| {
        b.iter(|| camera.render_parallel_into(black_box(&highbay), black_box(&highbay_pose), threads, &mut out));
    });
    assert_eq!(out, frame, "render_parallel_into differs from render");

    let tunnel = scenario("tunnel");
    let tunnel_pose = camera_looking_at(region_centre(&tunnel, "start"), region_centre(&tunnel, "wp1"));
    let frame = camera.render(&tunnel, &tunnel_pose);
    assert!(frame.valid_count() > frame.pixel_count() / 2, "tunnel frame mostly empty");
    // One frame into reused buffers, as a simulation loop renders (rendered once before the
    // benchmark too, so that the check below holds when a filter skips it).
    let mut out = DepthRender::default();
    camera.render_into(&tunnel, &tunnel_pose, &mut out);
    c.bench_function("depth_d435_tunnel_1core", |b| b.iter(|| camera.render_into(black_box(&tunnel), black_box(&tunnel_pose), &mut out)));
    assert_eq!(out, frame, "render_into differs from render");
    c.bench_function(&format!("depth_d435_tunnel_{threads}threads"), |b| {
        b.iter(|| camera.render_parallel_into(black_box(&tunnel), black_box(&tunnel_pose), threads, &mut out));
    });
    assert_eq!(out, frame, "render_parallel_into differs from render");

    let noise = DepthNoiseModel::preset("d435-phantom").expect("preset exists");
    let highbay_frame = camera.render(&highbay, &highbay_pose);
    let config = *camera.config();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(SEED);
    c.bench_function("noise_d435_phantom_640x480", |b| b.iter(|| noise.apply(black_box(&highbay_frame), &highbay, &config, &mut rng)));
}

fn bench_lidar(c: &mut Criterion) {
    let os1 = Lidar::new(LidarConfig::os1_64()).expect("os1_64 is valid");
    let mine = scenario("mine");
    let start = region_centre(&mine, "start");
    let ground = mine.ground_height(start.x, start.y).unwrap_or(start.z);
    let mine_pose = Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::new(start.x, start.y, ground + LIDAR_MOUNT_HEIGHT_M) };
    let scan = os1.scan(&mine, &mine_pose);
    assert!(scan.len() > os1.config().ray_count() / 4, "mine scan mostly empty");
    c.bench_function("lidar_os1_64_mine_1core", |b| b.iter(|| os1.scan(black_box(&mine), black_box(&mine_pose))));

    let vlp = Lidar::new(LidarConfig::vlp16()).expect("vlp16 is valid");
    let highbay = scenario("highbay");
    let highbay_pose = Isometry3 { rotation: DMat3::IDENTITY, translation: region_centre(&highbay, "A") };
    c.bench_function("lidar_vlp16_highbay_1core", |b| b.iter(|| vlp.scan(black_box(&highbay), black_box(&highbay_pose))));
}

criterion_group!(benches, bench_depth, bench_lidar);
criterion_main!(benches);
