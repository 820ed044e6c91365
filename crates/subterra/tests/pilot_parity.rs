//! The pilot's step gives the same bits from Rust as from Python: both run the canonical
//! sequence below and must reproduce the digest committed in `tests/data/pilot_parity.txt`
//! (the Python side: `tests/python/test_pilot.py`).

use glam::DVec3;
use subterra::apf::{Pilot, PilotCamera, PilotController, QmdpConfig};
use subterra::config::PerceptionConfig;
use subterra::depth::DepthImage;
use subterra::{Isometry3, PinholeCamera};

const FRAMES: usize = 30;

/// Frame `n` of the canonical sequence (640x480 millimetres): a box closing in from 1.5 m
/// at 35 mm a frame, and on every third frame a thin pole 0.4 m ahead on the right (300
/// points a block: the memory's near-field guard takes it, the belief does not).
fn frame(n: usize) -> Vec<u16> {
    let mut depth = vec![0u16; 640 * 480];
    for v in 160..320 {
        for u in 220..420 {
            depth[v * 640 + u] = (1500 - 35 * n) as u16;
        }
    }
    if n.is_multiple_of(3) {
        for v in 0..480 {
            for u in 500..506 {
                depth[v * 640 + u] = 400;
            }
        }
    }
    depth
}

/// FNV-1a, 64 bits, over the little-endian bytes of `values`.
fn fnv1a(hash: &mut u64, values: &[f64]) {
    for v in values {
        for b in v.to_le_bytes() {
            *hash ^= u64::from(b);
            *hash = hash.wrapping_mul(0x0100_0000_01b3);
        }
    }
}

fn digest(preset: &str, controller: PilotController) -> String {
    let camera = PilotCamera { camera: PinholeCamera::d435(), body_from_camera: Isometry3::body_from_forward_optical() };
    let config = PerceptionConfig::preset(preset).unwrap();
    let mut pilot = Pilot::new(config, &[camera], controller, QmdpConfig::default(), 11).unwrap();
    pilot.set_goal(DVec3::new(6.0, 0.5, 1.0)).unwrap();
    let mut hash = 0xcbf2_9ce4_8422_2325_u64;
    for n in 0..FRAMES {
        let depth = frame(n);
        let pose = Isometry3 { translation: DVec3::new(0.03 * n as f64, 0.0, 1.0), ..Isometry3::default() };
        let out = pilot.step(&[DepthImage::U16 { pixels: &depth, scale_m_per_unit: 0.001 }], n as f64 / 15.0, &pose).unwrap();
        let c = out.command;
        let r = out.repulsive_body;
        fnv1a(&mut hash, &[c.v_x_m_s, c.v_y_m_s, c.v_z_m_s, c.yaw_rate_rad_s, r.x, r.y, r.z, out.perceptions[0].p_free]);
    }
    format!("{hash:016x}")
}

/// The digest of `key` in the committed file (lines `key digest`; `#` starts a comment).
fn committed(key: &str) -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/pilot_parity.txt");
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_once(' '))
        .find(|(k, _)| *k == key)
        .map(|(_, d)| d.trim().to_owned())
        .unwrap_or_default()
}

#[test]
fn the_pilot_reproduces_the_committed_digest() {
    let got: Vec<(&str, String)> = [
        ("flight-escape/apf-pf", "flight-escape", PilotController::Apf),
        ("acc2021/apf-pf-qmdp", "acc2021", PilotController::Qmdp),
    ]
    .into_iter()
    .map(|(key, preset, controller)| (key, digest(preset, controller)))
    .collect();
    if std::env::var_os("SUBTERRA_PRINT_DIGEST").is_some() {
        for (key, d) in &got {
            println!("{key} {d}");
        }
    }
    for (key, d) in got {
        assert_eq!(d, committed(key), "{key}: the pilot's bits changed (tests/data/pilot_parity.txt)");
    }
}
