//! A simulated spinning lidar cast analytically against simple scenes: a ground that is
//! flat or ramps up beyond a line, pits (holes with vertical walls) and solid boxes.

#![allow(dead_code)]

use glam::{DMat3, DVec3};
use subterra::Isometry3;

/// An axis-aligned box `[min, max]` (a solid obstacle, or a pit's volume below z = 0).
#[derive(Debug, Clone, Copy)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

/// The world.
#[derive(Debug, Clone, Default)]
pub struct Scene {
    /// Ground rises at this angle [rad] for x >= `ramp_start_x` (0: flat ground z = 0).
    pub ramp_angle: f64,
    pub ramp_start_x: f64,
    pub pits: Vec<Aabb>,
    pub boxes: Vec<Aabb>,
}

/// Entry and exit parameters of the ray `o + t·d` through a box (slab method).
fn slabs(o: DVec3, d: DVec3, b: &Aabb) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for k in 0..3 {
        if d[k].abs() < 1e-12 {
            if o[k] < b.min[k] || o[k] > b.max[k] {
                return None;
            }
            continue;
        }
        let (a, c) = ((b.min[k] - o[k]) / d[k], (b.max[k] - o[k]) / d[k]);
        t0 = t0.max(a.min(c));
        t1 = t1.min(a.max(c));
    }
    (t0 <= t1).then_some((t0, t1))
}

impl Scene {
    /// First hit of the ray from `o` along unit `d`, within `max_t`.
    pub fn cast(&self, o: DVec3, d: DVec3, max_t: f64) -> Option<f64> {
        let mut best = f64::INFINITY;
        // Ground: the plane z = 0 for x < start, the incline beyond.
        if d.z.abs() > 1e-12 {
            let t = -o.z / d.z;
            if t > 0.0 && (self.ramp_angle == 0.0 || o.x + t * d.x < self.ramp_start_x) {
                best = best.min(self.through_pits(o, d, t));
            }
        }
        if self.ramp_angle != 0.0 {
            // z = (x - x0)·tan: (o.z + t d.z) = (o.x + t d.x - x0)·k.
            let k = self.ramp_angle.tan();
            let denom = d.z - k * d.x;
            if denom.abs() > 1e-12 {
                let t = (k * (o.x - self.ramp_start_x) - o.z) / denom;
                if t > 0.0 && o.x + t * d.x >= self.ramp_start_x {
                    best = best.min(t);
                }
            }
        }
        for b in &self.boxes {
            if let Some((t0, _)) = slabs(o, d, b) {
                if t0 > 0.0 {
                    best = best.min(t0);
                }
            }
        }
        (best <= max_t).then_some(best)
    }

    /// Where a ray that reaches the ground plane at `t` really stops, given the pits.
    fn through_pits(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
        let p = o + t * d;
        for pit in &self.pits {
            if p.x > pit.min.x && p.x < pit.max.x && p.y > pit.min.y && p.y < pit.max.y {
                // Inside the pit's mouth: the ray leaves the pit's volume through a wall or the bottom.
                if let Some((_, t1)) = slabs(o, d, pit) {
                    return t1;
                }
            }
        }
        t
    }
}

/// A spinning lidar: `beams` elevations evenly over `[min_deg, max_deg]`, `azimuths` steps.
#[derive(Debug, Clone, Copy)]
pub struct Lidar {
    pub beams: usize,
    pub min_deg: f64,
    pub max_deg: f64,
    pub azimuths: usize,
    pub max_range_m: f64,
}

impl Lidar {
    /// 64 beams over [-25°, 15°], 1024 azimuths, 40 m.
    pub fn dense() -> Self {
        Self { beams: 64, min_deg: -25.0, max_deg: 15.0, azimuths: 1024, max_range_m: 40.0 }
    }

    /// One scan in the sensor frame, flat `[x, y, z, ...]`; rays without a return are left out.
    pub fn scan(&self, scene: &Scene, world_from_sensor: &Isometry3) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.beams * self.azimuths * 3);
        let o = world_from_sensor.translation;
        for b in 0..self.beams {
            let el = (self.min_deg + (self.max_deg - self.min_deg) * b as f64 / (self.beams - 1) as f64).to_radians();
            for a in 0..self.azimuths {
                let az = std::f64::consts::TAU * a as f64 / self.azimuths as f64;
                let d_sensor = DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
                let d = world_from_sensor.rotation * d_sensor;
                if let Some(t) = scene.cast(o, d, self.max_range_m) {
                    let p = d_sensor * t;
                    out.extend_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
                }
            }
        }
        out
    }
}

/// `world_from_body` at `(x, y)` on the ground with heading `yaw`.
pub fn pose(x: f64, y: f64, yaw: f64) -> Isometry3 {
    Isometry3 { rotation: DMat3::from_rotation_z(yaw), translation: DVec3::new(x, y, 0.0) }
}

/// The lidar 0.6 m above the body origin, axes aligned with the body.
pub fn mount() -> Isometry3 {
    Isometry3 { rotation: DMat3::IDENTITY, translation: DVec3::new(0.0, 0.0, 0.6) }
}
