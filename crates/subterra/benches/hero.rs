//! HeRO odometry multiplexer benchmark: one `push` per source and one `update`, with four
//! sources at 50 Hz driving a curve, every check (stale, jump, covariance, the six pairwise
//! consistency comparisons over a 2 s window of history) running. Goal: < 20 µs per update
//! with four sources, negligible next to a map update.
//!
//! `cargo bench -p subterra --bench hero`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::{DMat3, DVec3};
use subterra::hero::{HeroConfig, OdometryMux, OdometrySample, SourceSpec, Twist};
use subterra::Isometry3;

const RATE_HZ: f64 = 50.0;
const SOURCES: usize = 4;

/// The pose on a circle of 5 m radius driven at 1 m/s, at time `t`, seen from source `k`'s
/// own world frame (each offset and turned).
fn sample(k: usize, t: f64) -> OdometrySample {
    let yaw = t / 5.0;
    let truth = Isometry3 { rotation: DMat3::from_rotation_z(yaw), translation: DVec3::new(5.0 * yaw.sin(), 5.0 - 5.0 * yaw.cos(), 0.0) };
    let frame = Isometry3 { rotation: DMat3::from_rotation_z(0.3 * k as f64), translation: DVec3::new(k as f64, -(k as f64), 0.0) };
    let mut covariance = [0.0; 36];
    covariance[0] = 0.01;
    covariance[7] = 0.01;
    covariance[35] = 0.001;
    OdometrySample {
        stamp_s: t,
        world_from_body: Isometry3 { rotation: frame.rotation * truth.rotation, translation: frame.rotation * truth.translation + frame.translation },
        covariance: Some(covariance),
        twist: Some(Twist { linear: DVec3::X, angular: DVec3::new(0.0, 0.0, 0.2) }),
    }
}

fn bench_update(c: &mut Criterion) {
    let specs: Vec<SourceSpec> = (0..SOURCES).map(|k| SourceSpec { name: format!("s{k}"), rate_hz: RATE_HZ }).collect();
    let mut mux = OdometryMux::new(HeroConfig::default(), &specs).expect("valid sources");
    let mut step = 0u64;
    let mut advance = |mux: &mut OdometryMux| {
        let t = step as f64 / RATE_HZ;
        step += 1;
        for k in 0..SOURCES {
            mux.push(k, sample(k, t)).expect("valid sample");
        }
        mux.update(t).expect("valid time")
    };
    // Fill the history past the consistency window first.
    for _ in 0..(4.0 * RATE_HZ) as usize {
        advance(&mut mux);
    }
    c.bench_function("hero/push x4 + update (4 sources, 50 Hz, 2 s window)", |b| b.iter(|| black_box(advance(&mut mux))));
}

criterion_group!(benches, bench_update);
criterion_main!(benches);
