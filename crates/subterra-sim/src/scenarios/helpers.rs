//! Shared helpers of the scenario generators: seeded draws, distances in the plane, spec
//! constructors, perimeter walls and the constants every generator uses.

use rand::RngExt;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::spec::{BoxSpec, PlaneSpec, RegionSpec, RouteSpec};

/// Wall thickness of the generated halls [m].
pub(super) const WALL_THICKNESS_M: f64 = 0.2;
/// Placement attempts per obstacle before the deterministic grid fallback.
pub(super) const MAX_ATTEMPTS: usize = 2000;

pub(super) type Rng = Xoshiro256PlusPlus;

/// A uniform draw in `[lo, hi)` (`lo` when the interval is empty; never panics).
pub(super) fn uni(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// A uniform integer in `[lo, hi]`.
pub(super) fn uni_count(rng: &mut Rng, lo: usize, hi: usize) -> usize {
    rng.random_range(lo..=hi)
}

/// `+1.0` or `-1.0` with equal probability.
pub(super) fn sign(rng: &mut Rng) -> f64 {
    if rng.random::<bool>() { 1.0 } else { -1.0 }
}

pub(super) fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Distance from `p` to the segment `a`-`b` in the plane [m].
pub(super) fn dist_point_segment2(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 { (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
    dist2(p, [a[0] + t * dx, a[1] + t * dy])
}

/// Distance from `p` to a polyline in the plane [m].
pub(super) fn dist_point_polyline2(p: [f64; 2], line: &[[f64; 2]]) -> f64 {
    line.windows(2).map(|w| dist_point_segment2(p, w[0], w[1])).fold(f64::INFINITY, f64::min)
}

pub(super) fn boxed(centre: [f64; 3], size: [f64; 3], yaw: f64, tag: &str) -> BoxSpec {
    BoxSpec { centre, size, yaw, tag: tag.into(), dark: false }
}

pub(super) fn plane(point: [f64; 3], normal: [f64; 3], tag: &str) -> PlaneSpec {
    PlaneSpec { point, normal, tag: tag.into(), dark: false }
}

pub(super) fn region(name: &str, centre: [f64; 3], radius: f64) -> RegionSpec {
    RegionSpec { name: name.into(), centre, radius }
}

pub(super) fn route(from: &str, to: &str) -> RouteSpec {
    RouteSpec { name: format!("{from}-{to}"), from: from.into(), to: to.into() }
}

/// Four axis-aligned wall boxes of `thickness` around the rectangle `[x0, x1] x [y0, y1]`
/// (inner faces on its edges), from `z0` to `z1`; corners overlap.
pub(super) fn perimeter_walls(x0: f64, x1: f64, y0: f64, y1: f64, z0: f64, z1: f64, thickness: f64) -> Vec<BoxSpec> {
    let (zc, h) = (0.5 * (z0 + z1), z1 - z0);
    let (xc, yc) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let (lx, ly) = (x1 - x0 + 2.0 * thickness, y1 - y0 + 2.0 * thickness);
    vec![
        boxed([x0 - 0.5 * thickness, yc, zc], [thickness, ly, h], 0.0, "wall"),
        boxed([x1 + 0.5 * thickness, yc, zc], [thickness, ly, h], 0.0, "wall"),
        boxed([xc, y0 - 0.5 * thickness, zc], [lx, thickness, h], 0.0, "wall"),
        boxed([xc, y1 + 0.5 * thickness, zc], [lx, thickness, h], 0.0, "wall"),
    ]
}
