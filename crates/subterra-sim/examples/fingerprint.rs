//! Fingerprints of the sensor simulation: a hash of every bit of depth frames (depth,
//! primitive, incidence) and lidar scans over seeded poses in each built-in scenario, and of
//! single `cast_ray` answers; it checks that threaded frames equal them. Two builds (with one
//! toolchain: the hasher may change between Rust versions) that print the same lines render
//! the same bits: run it before and after a change meant to be faster only.
//!
//! Run: `cargo run --release -p subterra-sim --example fingerprint [POSES]`.

use std::hash::{DefaultHasher, Hash, Hasher};

use glam::{DMat3, DVec3};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use subterra::Isometry3;
use subterra_sim::scenarios;
use subterra_sim::sensors::{DepthCamera, DepthCameraConfig, Lidar, LidarConfig};
use subterra_sim::world::World;

/// Poses per scenario unless given on the command line.
const DEFAULT_POSES: usize = 12;

fn main() {
    let poses = match std::env::args().nth(1) {
        None => DEFAULT_POSES,
        Some(arg) => arg.parse().unwrap_or_else(|_| panic!("POSES must be a whole number, got {arg:?}")),
    };
    let camera = DepthCamera::new(DepthCameraConfig::d435()).expect("d435 is valid");
    let lidars = [Lidar::new(LidarConfig::os1_64()).expect("os1_64 is valid"), Lidar::new(LidarConfig::vlp16()).expect("vlp16 is valid")];
    for name in scenarios::SCENARIOS {
        let world = World::from_spec(scenarios::generate(name, 1).expect("scenario generates")).expect("scenario builds");
        let (lo, hi) = world.bounds();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let (mut depth, mut lidar, mut single) = (DefaultHasher::new(), DefaultHasher::new(), DefaultHasher::new());
        let mut threaded = Default::default();
        for _ in 0..poses {
            let pose = random_pose(&world, lo, hi, &mut rng);
            let frame = camera.render(&world, &pose);
            camera.render_parallel_into(&world, &pose, 2, &mut threaded);
            assert_eq!(threaded, frame, "{name}: a frame on 2 threads differs from one on 1");
            for k in 0..frame.pixel_count() {
                (frame.depth_m[k].to_bits(), frame.primitive[k], frame.incidence_cos[k].to_bits()).hash(&mut depth);
            }
            // The lidar tilted as the camera is, and level.
            let level = Isometry3 { rotation: DMat3::IDENTITY, translation: pose.translation };
            for (l, p) in lidars.iter().flat_map(|l| [(l, &pose), (l, &level)]) {
                let scan = l.scan(&world, p);
                scan.len().hash(&mut lidar);
                for (p, (ring, id)) in scan.points_sensor.iter().zip(scan.ring.iter().zip(&scan.primitive)) {
                    (p.map(f32::to_bits), ring, id).hash(&mut lidar);
                }
            }
            for _ in 0..256 {
                let d = DVec3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5);
                match world.cast_ray(pose.translation, d, 50.0) {
                    Some(h) => (h.distance_m.to_bits(), h.normal.to_array().map(f64::to_bits), h.primitive).hash(&mut single),
                    None => 0u8.hash(&mut single),
                }
            }
        }
        println!("{name:8} depth {:016x} lidar {:016x} rays {:016x}", depth.finish(), lidar.finish(), single.finish());
    }
}

/// A pose inside the world's box, above the ground where there is one, tilted up to 0.3 rad.
fn random_pose(world: &World, lo: DVec3, hi: DVec3, rng: &mut Xoshiro256PlusPlus) -> Isometry3 {
    let x = lo.x + (hi.x - lo.x) * rng.random::<f64>();
    let y = lo.y + (hi.y - lo.y) * rng.random::<f64>();
    let ground = world.ground_height(x, y).unwrap_or(lo.z);
    let z = ground + 0.3 + 1.5 * rng.random::<f64>();
    let tilt = |rng: &mut Xoshiro256PlusPlus| 0.6 * (rng.random::<f64>() - 0.5);
    let rotation = DMat3::from_rotation_z(std::f64::consts::TAU * rng.random::<f64>()) * DMat3::from_rotation_y(tilt(rng)) * DMat3::from_rotation_x(tilt(rng));
    Isometry3 { rotation: rotation * Isometry3::body_from_forward_optical().rotation, translation: DVec3::new(x, y, z) }
}
