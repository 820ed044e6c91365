//! The ground robot's body-box collision probes: coarse cells, each with fine probe balls.

use glam::DVec3;

use super::ground_robot::GroundRobotConfig;

/// Largest side of a coarse collision cell [m]; small enough that the cell's
/// circumscribed sphere stays clear of the ground on level terrain.
const COLLISION_COARSE_CELL_M: f64 = 0.25;
/// Largest radius of a fine collision probe ball [m].
const COLLISION_FINE_RADIUS_MAX_M: f64 = 0.075;

/// One cell of the body box above the clearance (body frame): a coarse test sphere and
/// the fine probe balls inside it.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct CollisionCell {
    pub(super) centre_body: DVec3,
    pub(super) half_diagonal_m: f64,
    pub(super) fine_body: Vec<DVec3>,
}

/// The body box's collision probes: coarse cells, each with fine balls of one radius.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct CollisionProbes {
    pub(super) cells: Vec<CollisionCell>,
    pub(super) fine_radius_m: f64,
}

impl CollisionProbes {
    pub(super) fn new(config: &GroundRobotConfig) -> Self {
        let (l, w) = (config.length_m, config.width_m);
        let (c, h) = (config.ground_clearance_m, config.height_m);
        let nx = (l / COLLISION_COARSE_CELL_M).ceil().max(1.0) as usize;
        let ny = (w / COLLISION_COARSE_CELL_M).ceil().max(1.0) as usize;
        let (sx, sy) = (l / nx as f64, w / ny as f64);
        let z_mid = 0.5 * (c + h);
        let half_diagonal_m = DVec3::new(0.5 * sx, 0.5 * sy, 0.5 * (h - c)).length();
        let mut cells: Vec<CollisionCell> = Vec::with_capacity(nx * ny);
        for i in 0..nx {
            for j in 0..ny {
                let centre_body = DVec3::new(-0.5 * l + (i as f64 + 0.5) * sx, -0.5 * w + (j as f64 + 0.5) * sy, z_mid);
                cells.push(CollisionCell { centre_body, half_diagonal_m, fine_body: Vec::new() });
            }
        }
        // Fine balls inside the box: centres on a grid at most √2·r apart along each axis
        // (their discs cover the inset footprint), from r inside every face.
        let r = (0.25 * (h - c)).min(COLLISION_FINE_RADIUS_MAX_M).min(0.5 * l).min(0.5 * w);
        let spacing = std::f64::consts::SQRT_2 * r;
        let count = |span: f64| ((span / spacing).ceil().max(0.0) as usize) + 1;
        let axis = |half: f64, n: usize| -> Vec<f64> {
            if n <= 1 {
                vec![0.0]
            } else {
                (0..n).map(|k| -half + r + (2.0 * (half - r)) * k as f64 / (n - 1) as f64).collect()
            }
        };
        let xs = axis(0.5 * l, count(l - 2.0 * r));
        let ys = axis(0.5 * w, count(w - 2.0 * r));
        let nz = count(h - c - 2.0 * r).max(2);
        let zs: Vec<f64> = (0..nz).map(|k| c + r + (h - c - 2.0 * r) * k as f64 / (nz - 1) as f64).collect();
        for &x in &xs {
            for &y in &ys {
                let i = (((x + 0.5 * l) / sx).floor().max(0.0) as usize).min(nx - 1);
                let j = (((y + 0.5 * w) / sy).floor().max(0.0) as usize).min(ny - 1);
                if let Some(cell) = cells.get_mut(i * ny + j) {
                    for &z in &zs {
                        cell.fine_body.push(DVec3::new(x, y, z));
                    }
                }
            }
        }
        Self { cells, fine_radius_m: r }
    }
}
