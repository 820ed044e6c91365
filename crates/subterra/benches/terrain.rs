//! Terrain risk benchmarks: one 100k-point scan -> full risk map (200x200, all layers), and
//! a 10-scan fused window.
//!
//! `cargo bench -p subterra --bench terrain`

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use std::hint::black_box;
use subterra::terrain::{segment_ground, GroundConfig, TerrainMapper};
use subterra::{RobotConfig, TerrainConfig};

#[path = "../tests/terrain_sim/mod.rs"]
mod terrain_sim;
use terrain_sim::{mount, pose, Aabb, Lidar, Scene};

/// A mine-like scene: a ramp ahead, boxes (rubble, walls, a ceiling 3 m up) and pits around
/// the robot.
fn scene() -> Scene {
    let b = |x0: f64, y0: f64, x1: f64, y1: f64, h: f64| Aabb { min: DVec3::new(x0, y0, 0.0), max: DVec3::new(x1, y1, h) };
    let pit = |x0: f64, y0: f64, x1: f64, y1: f64, d: f64| Aabb { min: DVec3::new(x0, y0, -d), max: DVec3::new(x1, y1, 0.0) };
    Scene {
        ramp_angle: 12f64.to_radians(),
        ramp_start_x: 6.0,
        boxes: vec![b(3.0, -0.3, 3.6, 0.3, 0.3), b(-4.0, 3.0, 4.0, 3.4, 2.0), b(-4.0, -3.4, 4.0, -3.0, 2.0), b(-6.0, -1.0, -5.0, 1.0, 0.5), Aabb { min: DVec3::new(-60.0, -60.0, 3.0), max: DVec3::new(60.0, 60.0, 3.5) }],
        pits: vec![pit(2.0, 1.0, 3.0, 2.0, 0.5), pit(-3.0, -2.0, -2.0, -1.0, 0.3)],
    }
}

/// 64 beams x 1563 azimuths: 100k returns under the ceiling.
fn lidar() -> Lidar {
    Lidar { azimuths: 1563, ..Lidar::dense() }
}

/// CPU time this thread has run [ns] (Linux `schedstat`), to see past a loaded machine's
/// wall-clock noise; `None` elsewhere.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

/// Median stage timings of 15 updates of one scan, and their mean CPU time, printed for orientation.
fn print_stage_medians(label: &str, mapper: &mut TerrainMapper, points: &[f32]) {
    let mut rows = Vec::new();
    let cpu_start = thread_cpu_ns();
    for _ in 0..15 {
        mapper.reset();
        let t = mapper.update(points, 0.0, &pose(0.0, 0.0, 0.0), &mount(), 1.0).unwrap().timings;
        rows.push([t.prefilter_s, t.segment_s, t.coarse_s, t.fine_s, t.total_s]);
    }
    let cpu_ms = cpu_start.zip(thread_cpu_ns()).map(|(a, b)| (b - a) as f64 / 15.0 / 1e6).unwrap_or(f64::NAN);
    let median = |k: usize| {
        let mut v: Vec<f64> = rows.iter().map(|r| r[k] * 1e3).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "{label}: prefilter {:.2} ms, segment {:.2} ms, coarse map {:.2} ms, fine map {:.2} ms, total {:.2} ms (wall medians); {cpu_ms:.2} ms CPU per update (mean)",
        median(0),
        median(1),
        median(2),
        median(3),
        median(4)
    );
}

fn bench_terrain(c: &mut Criterion) {
    let scene = scene();
    let lidar = lidar();
    let world_from_body = pose(0.0, 0.0, 0.0);
    let points = lidar.scan(&scene, &world_from_body.compose(&mount()));
    assert!(points.len() / 3 > 95_000, "{} points", points.len() / 3);

    let coarse_only = TerrainConfig { fine_enabled: false, ..TerrainConfig::default() };
    let mut mapper = TerrainMapper::new(RobotConfig::default(), coarse_only).unwrap();
    let mut stamp = 0.0;
    print_stage_medians("one scan, coarse only", &mut mapper, &points);
    c.bench_function("terrain_scan_100k_coarse_200x200", |b| {
        b.iter(|| {
            mapper.reset();
            mapper.update(black_box(&points), 0.0, &world_from_body, &mount(), 1.0).unwrap()
        });
    });

    let mut mapper = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
    print_stage_medians("one scan, coarse and fine", &mut mapper, &points);
    c.bench_function("terrain_scan_100k_coarse_and_fine", |b| {
        b.iter(|| {
            mapper.reset();
            mapper.update(black_box(&points), 0.0, &world_from_body, &mount(), 1.0).unwrap()
        });
    });

    // Ten scans from poses along a path, 0.1 s apart: the window holds all ten.
    let poses: Vec<_> = (0..10).map(|k| pose(0.1 * k as f64, 0.02 * k as f64, 0.01 * k as f64)).collect();
    let scans: Vec<Vec<f32>> = poses.iter().map(|p| lidar.scan(&scene, &p.compose(&mount()))).collect();
    let mut config = coarse_only;
    config.fusion.max_scans = 10;
    let mut mapper = TerrainMapper::new(RobotConfig::default(), config).unwrap();
    let mut k = 0;
    for (scan, p) in scans.iter().zip(&poses) {
        mapper.update(scan, stamp, p, &mount(), 1.0).unwrap();
        stamp += 0.1;
    }
    c.bench_function("terrain_fused_window_10x100k_coarse_200x200", |b| {
        b.iter(|| {
            k = (k + 1) % scans.len();
            stamp += 0.01;
            let out = mapper.update(black_box(&scans[k]), stamp, &poses[k], &mount(), 1.0).unwrap();
            debug_assert_eq!(out.stats.fused_scans, 10);
            out
        });
    });

    // The lidar's frame is level here, so the scan is already sensor-centred.
    let config = GroundConfig::default();
    c.bench_function("segment_ground_100k", |b| b.iter(|| segment_ground(black_box(&points), &config, 0.6).unwrap()));
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(4));
    targets = bench_terrain
}
criterion_main!(benches);
