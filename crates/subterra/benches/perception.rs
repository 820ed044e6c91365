//! Per-stage benchmarks of APF-PF at the `flight` preset on a 640x480 `u16` frame.
//!
//! `cargo bench -p subterra --bench perception`

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use subterra::depth::{DepthImage, DepthPerception, DepthVoxelGrid, TransitionModel};
use subterra::{Isometry3, PerceptionConfig, PinholeCamera};

/// A box 0.8 m ahead filling the middle of the image, a wall beyond the horizon, and a
/// sprinkle of no-return pixels: a typical frame with an obstacle in view.
fn box_frame(camera: &PinholeCamera) -> Vec<u16> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut img = vec![3000u16; w * h];
    for v in 140..340 {
        for u in 220..420 {
            img[v * w + u] = 800 + ((u * 7 + v * 13) % 40) as u16;
        }
    }
    for (p, px) in img.iter_mut().enumerate() {
        if p % 17 == 0 {
            *px = 0;
        }
    }
    img
}

fn bench_perception(c: &mut Criterion) {
    let camera = PinholeCamera::d435();
    let config = PerceptionConfig::flight();
    let frame = box_frame(&camera);
    let image = DepthImage::U16 { pixels: &frame, scale_m_per_unit: 0.001 };

    let mut grid = DepthVoxelGrid::new(camera, config.grid).unwrap();
    c.bench_function("count_u16_640x480", |b| b.iter(|| grid.count(black_box(image), 640, 480).unwrap()));

    c.bench_function("transition_build_flight", |b| b.iter(|| TransitionModel::new(black_box(&grid), &config.transition).unwrap()));

    let mut perception = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), config, 0).unwrap();
    for _ in 0..5 {
        perception.update(image, 640, 480).unwrap();
    }
    c.bench_function("update_particle_flight_640x480", |b| b.iter(|| perception.update(black_box(image), 640, 480).unwrap()));

    // Every camera frame arrives fresh from memory (as in `subterra bench perception`): cycle
    // through 256 distinct frames (157 MB, more than the last-level cache), each the box
    // frame with its background moved by a millimetre.
    let fresh: Vec<Vec<u16>> =
        (0..256u16).map(|f| frame.iter().map(|&raw| if raw == 3000 { 3000 + f } else { raw }).collect()).collect();
    let mut next = 0;
    c.bench_function("update_particle_flight_640x480_fresh_frames", |b| {
        b.iter(|| {
            next = (next + 1) % fresh.len();
            let image = DepthImage::U16 { pixels: &fresh[next], scale_m_per_unit: 0.001 };
            perception.update(black_box(image), 640, 480).unwrap()
        });
    });

    let mut histogram_config = config;
    histogram_config.filter.mode = subterra::config::FilterMode::Histogram;
    let mut histogram = DepthPerception::new(camera, Isometry3::body_from_forward_optical(), histogram_config, 0).unwrap();
    c.bench_function("update_histogram_flight_640x480", |b| b.iter(|| histogram.update(black_box(image), 640, 480).unwrap()));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(50).measurement_time(std::time::Duration::from_secs(3));
    targets = bench_perception
}
criterion_main!(benches);
