//! Settling on the terrain: the [`Settle`] of a footprint, its contact plane, and the
//! resting-plane and convex-hull geometry it is computed with.

use glam::{DMat3, DVec2, DVec3};

use super::ground_robot::{Failure, GroundRobotConfig};

/// Tolerance of the resting-plane test "every sample on or below the plane" [m].
const PLANE_TOLERANCE_M: f64 = 1e-9;

/// The footprint settled on the terrain: the contact plane under the robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settle {
    /// Height of the contact plane under the footprint centre: the body origin's z [m].
    pub z_m: f64,
    /// Roll (rotation about body x; left side up is positive) [rad].
    pub roll_rad: f64,
    /// Pitch (rotation about body y; REP 103: nose **down** is positive) [rad].
    pub pitch_rad: f64,
    /// Slope of the contact plane `(dz/dx, dz/dy)` in the world frame [m/m].
    pub gradient: DVec2,
    /// Deepest footprint sample below the contact plane [m] (0 on a plane).
    pub max_gap_m: f64,
    /// Deepest drop under an overhanging sample [m]: over the samples outside the convex
    /// hull (in x-y) of the supporting samples (those on the plane), the largest of
    /// `min(gap below the plane, lowest support's height - sample's ground height)`. Low
    /// samples inside that hull are bridged (a valley, a ditch under the belly) and do not
    /// count; a lifted wheel over ground as high as the lowest support (one corner on the
    /// foot of a ramp, the other three on the floor) gives 0.
    pub overhang_gap_m: f64,
    /// Footprint samples with ground under them.
    pub samples_on_ground: usize,
    /// Footprint samples over a hole (no ground).
    pub samples_over_hole: usize,
}

impl Settle {
    /// The unit normal of the contact plane (world frame, pointing up).
    pub fn normal(&self) -> DVec3 {
        DVec3::new(-self.gradient.x, -self.gradient.y, 1.0).normalize()
    }

    /// The body rotation `world_from_body` for heading `yaw_rad`: body x along the plane
    /// in the heading direction, body z along the plane normal.
    pub fn rotation(&self, yaw_rad: f64) -> DMat3 {
        let (s, c) = yaw_rad.sin_cos();
        let forward = DVec2::new(c, s);
        let x_b = DVec3::new(c, s, self.gradient.dot(forward)).normalize();
        let z_b = self.normal();
        let y_b = z_b.cross(x_b);
        DMat3::from_cols(x_b, y_b, z_b)
    }

    /// The terrain failure this contact implies, if any: out of world, fall (hole, or an
    /// overhang deeper than `max_drop_m`), rollover — in that order.
    pub fn failure(&self, config: &GroundRobotConfig) -> Option<Failure> {
        if self.samples_on_ground == 0 {
            Some(Failure::OutOfWorld)
        } else if self.samples_over_hole > 0 || self.overhang_gap_m > config.max_drop_m {
            Some(Failure::Fall)
        } else if self.roll_rad.abs() > config.rollover_roll_rad || self.pitch_rad.abs() > config.rollover_pitch_rad {
            Some(Failure::Rollover)
        } else {
            None
        }
    }
}

/// A plane `z = a + b·(x - x0) + c·(y - y0)` around a reference point `(x0, y0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ContactPlane {
    pub(super) origin: DVec2,
    pub(super) z0: f64,
    pub(super) gradient: DVec2,
}

impl ContactPlane {
    pub(super) fn height(&self, xy: DVec2) -> f64 {
        self.z0 + self.gradient.dot(xy - self.origin)
    }
}

/// The resting plane of points `(dx, dy, z)` given relative to the footprint centre: the
/// plane on or above every point whose height at `(0, 0)` is lowest — a linear programme
/// whose optimum is the plane through three of the points (the facet of their upper
/// convex hull above the centre), found by trying every non-collinear triple (15 points:
/// 455 triples). Ties (a centre on a hull edge) go to the least tilted plane. Returns
/// `(z at the centre, gradient)`, or `None` with fewer than three non-collinear points.
pub(crate) fn resting_plane(points: &[DVec3]) -> Option<(f64, DVec2)> {
    let scale = points.iter().map(|p| p.x.abs().max(p.y.abs())).fold(0.0_f64, f64::max).max(1e-9);
    let min_det = 1e-9 * scale * scale;
    let mut best: Option<(f64, DVec2)> = None;
    let n = points.len();
    for i in 0..n {
        for j in (i + 1)..n {
            for k in (j + 1)..n {
                let (p, q, r) = (points[i], points[j], points[k]);
                // Solve z = a + b x + c y through p, q, r.
                let (ux, uy, uz) = (q.x - p.x, q.y - p.y, q.z - p.z);
                let (vx, vy, vz) = (r.x - p.x, r.y - p.y, r.z - p.z);
                let det = ux * vy - uy * vx;
                if det.abs() < min_det {
                    continue;
                }
                let b = (uz * vy - uy * vz) / det;
                let c = (ux * vz - uz * vx) / det;
                let a = p.z - b * p.x - c * p.y;
                let above_all = points.iter().all(|s| s.z <= a + b * s.x + c * s.y + PLANE_TOLERANCE_M);
                if !above_all {
                    continue;
                }
                let g = DVec2::new(b, c);
                let better = match best {
                    None => true,
                    Some((a_best, g_best)) => {
                        a < a_best - PLANE_TOLERANCE_M || (a <= a_best + PLANE_TOLERANCE_M && g.length_squared() < g_best.length_squared())
                    }
                };
                if better {
                    best = Some((a, g));
                }
            }
        }
    }
    best
}

/// The convex hull of 2-D points, counter-clockwise, without collinear vertices
/// (Andrew's monotone chain). Fewer than three distinct points give them back as they are.
pub(crate) fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut pts: Vec<DVec2> = points.to_vec();
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &DVec2>> = if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Whether `p` lies inside or on the boundary of a counter-clockwise convex hull
/// (within 1e-9 m); a hull of fewer than three vertices contains nothing.
pub(crate) fn hull_contains(hull: &[DVec2], p: DVec2) -> bool {
    const TOLERANCE_M: f64 = 1e-9;
    if hull.len() < 3 {
        return false;
    }
    (0..hull.len()).all(|i| {
        let a = hull[i];
        let b = hull[(i + 1) % hull.len()];
        let edge = b - a;
        // Signed distance of p to the left of edge a -> b.
        edge.perp_dot(p - a) / edge.length() >= -TOLERANCE_M
    })
}
