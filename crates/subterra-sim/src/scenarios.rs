//! Seeded generators of the built-in worlds: [`highbay`], [`cable`], [`tunnel`], [`mine`],
//! [`subway`], the ground trade-off worlds [`slopes`], [`rough`], [`ledge`] and the
//! [`cave`] (in `scenarios/tradeoff.rs`), and the flight world [`warehouse`] of shelf racks
//! and dense thin poles (`scenarios/warehouse.rs`); [`generate`] picks one by name.
//!
//! In: a scenario name and a seed. Out: a [`WorldSpec`] (plain data; `World::from_spec`
//! turns it into geometry). Every random draw comes from one
//! `Xoshiro256PlusPlus::seed_from_u64(seed)` stream, so a seed gives the same spec bit for
//! bit and different seeds give different layouts. World frame ENU, metres, radians.
//!
//! Aerial scenarios (`highbay`, `cable`, `tunnel`) put region centres at flight height;
//! ground scenarios (`mine`, `subway`) put them on the ground. Tags used: "floor",
//! "ceiling", "wall", "pole", "cable", "beam", "pipe", "column", "rock", "rubble",
//! "pillar", "rail", "bench".

use std::f64::consts::{PI, TAU};

use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::error::{SimError, SimResult};
use crate::spec::{
    BoxSpec, CapsuleSpec, CylinderSpec, HeightFieldSpec, ItemSpec, PlaneSpec, RegionSpec, RouteSpec, SphereSpec,
    WorldSpec,
};

mod tradeoff;
mod warehouse;

pub use tradeoff::{cave, ledge, rough, slopes, CAVE_SIZE_M, GROUND_REGION_RADIUS_M, TRADEOFF_SIZE_M};
pub use warehouse::{warehouse, WAREHOUSE_FOREST_GAP_M, WAREHOUSE_LENGTH_M, WAREHOUSE_PASSAGE_M, WAREHOUSE_REGION_RADIUS_M, WAREHOUSE_WIDTH_M};

/// Names of the built-in scenarios, in the order the docs list them.
pub const SCENARIOS: [&str; 10] = ["highbay", "cable", "tunnel", "mine", "subway", "slopes", "rough", "ledge", "cave", "warehouse"];

/// The world of the built-in scenario `name` for `seed`.
///
/// # Errors
/// [`SimError::Unknown`] (naming the known scenarios) when `name` is not one of [`SCENARIOS`].
pub fn generate(name: &str, seed: u64) -> SimResult<WorldSpec> {
    match name {
        "highbay" => Ok(highbay(seed)),
        "cable" => Ok(cable(seed)),
        "tunnel" => Ok(tunnel(seed)),
        "warehouse" => Ok(warehouse(seed)),
        "mine" => Ok(mine(seed)),
        "subway" => Ok(subway(seed)),
        "slopes" => Ok(slopes(seed)),
        "rough" => Ok(rough(seed)),
        "ledge" => Ok(ledge(seed)),
        "cave" => Ok(cave(seed)),
        _ => Err(SimError::Unknown { what: "scenario".into(), name: name.into(), known: SCENARIOS.join(", ") }),
    }
}

// ---------------------------------------------------------------------------------------
// Shared helpers
// ---------------------------------------------------------------------------------------

type Rng = Xoshiro256PlusPlus;

/// A uniform draw in `[lo, hi)` (`lo` when the interval is empty; never panics).
fn uni(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// A uniform integer in `[lo, hi]`.
fn uni_count(rng: &mut Rng, lo: usize, hi: usize) -> usize {
    rng.random_range(lo..=hi)
}

/// `+1.0` or `-1.0` with equal probability.
fn sign(rng: &mut Rng) -> f64 {
    if rng.random::<bool>() { 1.0 } else { -1.0 }
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Distance from `p` to the segment `a`-`b` in the plane [m].
fn dist_point_segment2(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 { (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
    dist2(p, [a[0] + t * dx, a[1] + t * dy])
}

/// Distance from `p` to a polyline in the plane [m].
fn dist_point_polyline2(p: [f64; 2], line: &[[f64; 2]]) -> f64 {
    line.windows(2).map(|w| dist_point_segment2(p, w[0], w[1])).fold(f64::INFINITY, f64::min)
}

fn boxed(centre: [f64; 3], size: [f64; 3], yaw: f64, tag: &str) -> BoxSpec {
    BoxSpec { centre, size, yaw, tag: tag.into(), dark: false }
}

fn plane(point: [f64; 3], normal: [f64; 3], tag: &str) -> PlaneSpec {
    PlaneSpec { point, normal, tag: tag.into(), dark: false }
}

fn region(name: &str, centre: [f64; 3], radius: f64) -> RegionSpec {
    RegionSpec { name: name.into(), centre, radius }
}

fn route(from: &str, to: &str) -> RouteSpec {
    RouteSpec { name: format!("{from}-{to}"), from: from.into(), to: to.into() }
}

/// Four axis-aligned wall boxes of `thickness` around the rectangle `[x0, x1] x [y0, y1]`
/// (inner faces on its edges), from `z0` to `z1`; corners overlap.
fn perimeter_walls(x0: f64, x1: f64, y0: f64, y1: f64, z0: f64, z1: f64, thickness: f64) -> Vec<BoxSpec> {
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

// ---------------------------------------------------------------------------------------
// highbay
// ---------------------------------------------------------------------------------------

/// Hall length along x [m]. The APF-PF paper's 17 x 8 m flight hall.
pub const HIGHBAY_LENGTH_M: f64 = 17.0;
/// Hall width along y [m]. APF-PF paper.
pub const HIGHBAY_WIDTH_M: f64 = 8.0;
/// Ceiling height [m] (the floor is z = 0).
pub const HIGHBAY_CEILING_M: f64 = 7.0;
/// Height of the region centres (flight height) [m].
pub const HIGHBAY_FLIGHT_HEIGHT_M: f64 = 1.25;
/// Radius of regions A-D [m].
pub const HIGHBAY_REGION_RADIUS_M: f64 = 0.5;
/// Region centres (x, y) [m]: A and C at the west end, B at the east end, D half way
/// along the north side, so every route crosses the obstacle field.
pub const HIGHBAY_REGIONS: [(&str, [f64; 2]); 4] =
    [("A", [1.5, 2.0]), ("B", [15.5, 2.0]), ("C", [1.5, 6.0]), ("D", [8.5, 6.0])];
/// Routes (from, to). APF-PF paper: A-B, B-C, C-D, D-C, D-B.
pub const HIGHBAY_ROUTES: [(&str, &str); 5] = [("A", "B"), ("B", "C"), ("C", "D"), ("D", "C"), ("D", "B")];
/// Pole diameters [m] and how many of each: the paper's 270, 90 and 22 mm obstacles.
pub const HIGHBAY_POLES: [(f64, usize); 3] = [(0.270, 6), (0.090, 6), (0.022, 4)];
/// Least surface clearance of a pole from a region centre, from another pole and from a
/// wall [m] (horizontal).
pub const HIGHBAY_CLEARANCE_M: f64 = 0.9;
/// Fraction of poles dropped near a route line (within [`HIGHBAY_ROUTE_SPREAD_M`]) rather
/// than anywhere in the hall, so that flights meet obstacles.
const HIGHBAY_NEAR_ROUTE_FRACTION: f64 = 0.5;
/// Lateral spread of the poles dropped near a route [m].
pub const HIGHBAY_ROUTE_SPREAD_M: f64 = 0.5;
/// Wall thickness of the generated halls [m].
const WALL_THICKNESS_M: f64 = 0.2;
/// Placement attempts per obstacle before the deterministic grid fallback.
const MAX_ATTEMPTS: usize = 2000;

/// The APF-PF paper's flight hall: 17 x 8 m (x in [0, 17], y in [0, 8]), floor plane
/// z = 0, ceiling plane z = 7 m, four wall boxes; regions A-D (radius 0.5 m at 1.25 m)
/// and routes A-B, B-C, C-D, D-C, D-B; floor-to-ceiling poles of 0.270 m (6), 0.090 m (6)
/// and 0.022 m (4) diameter, each at least 0.9 m (surface) from every region centre,
/// other pole and wall; half of them are dropped near a route line. Tags "pole", "wall",
/// "floor", "ceiling".
pub fn highbay(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let (l, w, h) = (HIGHBAY_LENGTH_M, HIGHBAY_WIDTH_M, HIGHBAY_CEILING_M);
    let centres: Vec<[f64; 2]> = HIGHBAY_REGIONS.iter().map(|(_, c)| *c).collect();
    let centre_of = |name: &str| HIGHBAY_REGIONS.iter().find(|(n, _)| *n == name).map_or([0.0, 0.0], |(_, c)| *c);
    // Distinct route segments (D-C is C-D flown back).
    let mut segments: Vec<([f64; 2], [f64; 2])> = Vec::new();
    for (from, to) in HIGHBAY_ROUTES {
        let (a, b) = (centre_of(from), centre_of(to));
        if !segments.iter().any(|&(p, q)| (p == a && q == b) || (p == b && q == a)) {
            segments.push((a, b));
        }
    }

    let mut poles: Vec<([f64; 2], f64)> = Vec::new();
    for &(diameter, count) in &HIGHBAY_POLES {
        let r = 0.5 * diameter;
        let margin = HIGHBAY_CLEARANCE_M + r;
        let fits = |p: [f64; 2], poles: &[([f64; 2], f64)]| {
            p[0] >= margin
                && p[0] <= l - margin
                && p[1] >= margin
                && p[1] <= w - margin
                && centres.iter().all(|&c| dist2(p, c) - r >= HIGHBAY_CLEARANCE_M)
                && poles.iter().all(|&(q, rq)| dist2(p, q) - r - rq >= HIGHBAY_CLEARANCE_M)
        };
        for _ in 0..count {
            let mut placed = None;
            for _ in 0..MAX_ATTEMPTS {
                let p = if rng.random::<f64>() < HIGHBAY_NEAR_ROUTE_FRACTION {
                    let (a, b) = segments[rng.random_range(0..segments.len())];
                    let t = uni(&mut rng, 0.1, 0.9);
                    let off = uni(&mut rng, -HIGHBAY_ROUTE_SPREAD_M, HIGHBAY_ROUTE_SPREAD_M);
                    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                    let len = dx.hypot(dy);
                    [a[0] + t * dx - off * dy / len, a[1] + t * dy + off * dx / len]
                } else {
                    [uni(&mut rng, margin, l - margin), uni(&mut rng, margin, w - margin)]
                };
                if fits(p, &poles) {
                    placed = Some(p);
                    break;
                }
            }
            // Deterministic fallback: the first free point of a 5 cm grid (never needed in practice).
            if placed.is_none() {
                let steps = |a: f64, b: f64| ((b - a) / 0.05).floor() as usize;
                'scan: for i in 0..=steps(margin, l - margin) {
                    for j in 0..=steps(margin, w - margin) {
                        let p = [margin + 0.05 * i as f64, margin + 0.05 * j as f64];
                        if fits(p, &poles) {
                            placed = Some(p);
                            break 'scan;
                        }
                    }
                }
            }
            if let Some(p) = placed {
                poles.push((p, r));
            }
        }
    }

    WorldSpec {
        name: "highbay".into(),
        cylinders: poles
            .iter()
            .map(|&(p, r)| CylinderSpec { a: [p[0], p[1], 0.0], b: [p[0], p[1], h], radius: r, tag: "pole".into(), dark: false })
            .collect(),
        boxes: perimeter_walls(0.0, l, 0.0, w, 0.0, h, WALL_THICKNESS_M),
        planes: vec![plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor"), plane([0.0, 0.0, h], [0.0, 0.0, -1.0], "ceiling")],
        regions: HIGHBAY_REGIONS
            .iter()
            .map(|(n, c)| region(n, [c[0], c[1], HIGHBAY_FLIGHT_HEIGHT_M], HIGHBAY_REGION_RADIUS_M))
            .collect(),
        routes: HIGHBAY_ROUTES.iter().map(|(a, b)| route(a, b)).collect(),
        ..WorldSpec::default()
    }
}

// ---------------------------------------------------------------------------------------
// cable
// ---------------------------------------------------------------------------------------

/// Radius of the hanging cable [m] (8 mm diameter). APF-PF paper §V-A.
pub const CABLE_RADIUS_M: f64 = 0.004;
/// Height of the start region's centre (the static robot) above the floor [m].
pub const CABLE_ROBOT_HEIGHT_M: f64 = 1.0;
/// Range of the cable's distance ahead of the robot (along +x) at robot height [m].
pub const CABLE_DISTANCE_M: (f64, f64) = (0.6, 0.9);
/// Range of the background wall's distance ahead of the robot [m] (beyond the 1.2 m
/// sensing horizon of the APF-PF paper).
pub const CABLE_WALL_DISTANCE_M: (f64, f64) = (2.9, 3.1);
/// Height of the cable's upper end (hung from a beam) and its lower end [m].
const CABLE_TOP_M: f64 = 2.6;
const CABLE_BOTTOM_M: f64 = 0.2;

/// The thin-cable test of the APF-PF paper (§V-A): region "start" at (0, 0, 1.0) (x, y at
/// the origin, 1 m above the floor plane z = 0), the robot facing +x; an 8 mm cable
/// (capsule of radius 0.004 m, tag "cable") hanging from a beam at z = 2.6 m down to
/// z = 0.2 m, crossing the view 0.6-0.9 m ahead with a slight seeded offset and tilt;
/// a 6 x 3 m background wall about 3 m ahead.
pub fn cable(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let d = uni(&mut rng, CABLE_DISTANCE_M.0, CABLE_DISTANCE_M.1);
    let y0 = uni(&mut rng, -0.05, 0.05);
    // Tilt: the upper end offset by up to 3 cm; the cable passes (d, y0) at robot height.
    let (tx, ty) = (uni(&mut rng, -0.03, 0.03), uni(&mut rng, -0.03, 0.03));
    let at = |z: f64| {
        let s = (z - CABLE_ROBOT_HEIGHT_M) / (CABLE_TOP_M - CABLE_ROBOT_HEIGHT_M);
        [d + s * tx, y0 + s * ty, z]
    };
    let (top, bottom) = (at(CABLE_TOP_M), at(CABLE_BOTTOM_M));
    let wall_x = uni(&mut rng, CABLE_WALL_DISTANCE_M.0, CABLE_WALL_DISTANCE_M.1);
    WorldSpec {
        name: "cable".into(),
        capsules: vec![CapsuleSpec { a: bottom, b: top, radius: CABLE_RADIUS_M, tag: "cable".into(), dark: false }],
        boxes: vec![
            boxed([wall_x + 0.1, 0.0, 1.5], [0.2, 6.0, 3.0], 0.0, "wall"),
            boxed([top[0], top[1], CABLE_TOP_M + 0.05], [0.1, 3.0, 0.1], 0.0, "beam"),
        ],
        planes: vec![plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor")],
        regions: vec![region("start", [0.0, 0.0, CABLE_ROBOT_HEIGHT_M], 0.5)],
        ..WorldSpec::default()
    }
}

// ---------------------------------------------------------------------------------------
// tunnel
// ---------------------------------------------------------------------------------------

/// Height of the tunnel's region centres (flight height) [m].
pub const TUNNEL_FLIGHT_HEIGHT_M: f64 = 1.2;
/// Range of the tunnel's free width [m].
pub const TUNNEL_WIDTH_M: (f64, f64) = (2.5, 4.0);
/// Range of the tunnel's length along its centreline [m] (whole segments).
pub const TUNNEL_LENGTH_M: (f64, f64) = (32.0, 38.0);
/// Spacing of the waypoint regions "wp1", "wp2", ... along the centreline [m] (about).
pub const TUNNEL_WAYPOINT_SPACING_M: f64 = 4.0;
/// Length of one centreline segment [m].
const TUNNEL_SEGMENT_M: f64 = 1.0;
/// Thickness of the wall and ceiling boxes [m].
const TUNNEL_SHELL_M: f64 = 0.5;
/// Distance of the start and goal regions from the tube's ends [m].
const TUNNEL_END_OFFSET_M: f64 = 1.5;
/// Obstacles (columns, cables, rocks) stay this far along the tube from its ends [m].
const TUNNEL_FEATURE_MARGIN_M: f64 = 4.0;

/// The tunnel's smooth seeded shape: heading, width and ceiling height as functions of
/// the arc length `s` [m].
struct TunnelShape {
    /// (amplitude [rad], period [m], phase [rad]) of the heading's two sinusoids.
    heading: [(f64, f64, f64); 2],
    /// (mean, amplitude, period, phase) of the width [m].
    width: (f64, f64, f64, f64),
    /// (mean, amplitude, period, phase) of the ceiling height [m].
    ceiling: (f64, f64, f64, f64),
}

impl TunnelShape {
    fn heading(&self, s: f64) -> f64 {
        self.heading.iter().map(|&(a, p, ph)| a * (TAU * s / p + ph).sin()).sum()
    }
    fn width(&self, s: f64) -> f64 {
        let (m, a, p, ph) = self.width;
        (m + a * (TAU * s / p + ph).sin()).clamp(TUNNEL_WIDTH_M.0, TUNNEL_WIDTH_M.1)
    }
    fn ceiling(&self, s: f64) -> f64 {
        let (m, a, p, ph) = self.ceiling;
        m + a * (TAU * s / p + ph).sin()
    }
    fn max_ceiling(&self) -> f64 {
        self.ceiling.0 + self.ceiling.1.abs()
    }
}

/// A generated tunnel and the layout it was built from (tests check the layout).
struct TunnelLayout {
    spec: WorldSpec,
    /// Centreline vertices, one per [`TUNNEL_SEGMENT_M`] of arc length [m].
    #[cfg_attr(not(test), allow(dead_code))]
    centreline: Vec<[f64; 2]>,
    /// Free width at each vertex [m].
    #[cfg_attr(not(test), allow(dead_code))]
    widths: Vec<f64>,
}

/// A point of the centreline polyline at arc length `s`, with the unit direction and
/// left normal of its segment.
fn centreline_at(line: &[[f64; 2]], s: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
    let n_seg = line.len().saturating_sub(1).max(1);
    let j = ((s / TUNNEL_SEGMENT_M).floor().max(0.0) as usize).min(n_seg - 1);
    let f = (s / TUNNEL_SEGMENT_M - j as f64).clamp(0.0, 1.0);
    let (a, b) = (line[j], line[(j + 1).min(line.len() - 1)]);
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy).max(f64::EPSILON);
    let dir = [dx / len, dy / len];
    ([a[0] + f * dx, a[1] + f * dy], dir, [-dir[1], dir[0]])
}

fn tunnel_layout(seed: u64) -> TunnelLayout {
    let mut rng = Rng::seed_from_u64(seed);
    let n_seg = uni_count(
        &mut rng,
        (TUNNEL_LENGTH_M.0 / TUNNEL_SEGMENT_M) as usize,
        (TUNNEL_LENGTH_M.1 / TUNNEL_SEGMENT_M) as usize,
    );
    let length = n_seg as f64 * TUNNEL_SEGMENT_M;
    // Heading within +-0.65 rad, so the tube always advances along +x (never crosses
    // itself); curvature <= 0.28 rad/m (radius >= 3.5 m).
    let shape = TunnelShape {
        heading: [
            (uni(&mut rng, 0.3, 0.5), uni(&mut rng, 18.0, 28.0), uni(&mut rng, 0.0, TAU)),
            (uni(&mut rng, 0.05, 0.15), uni(&mut rng, 9.0, 14.0), uni(&mut rng, 0.0, TAU)),
        ],
        width: (uni(&mut rng, 2.9, 3.3), uni(&mut rng, 0.2, 0.5), uni(&mut rng, 8.0, 14.0), uni(&mut rng, 0.0, TAU)),
        ceiling: (uni(&mut rng, 2.9, 3.2), uni(&mut rng, 0.15, 0.35), uni(&mut rng, 7.0, 12.0), uni(&mut rng, 0.0, TAU)),
    };
    let t = TUNNEL_SHELL_M;

    // Centreline and the two wall polylines (inner faces of the walls).
    let mut line = vec![[0.0, 0.0]];
    for j in 0..n_seg {
        let th = shape.heading((j as f64 + 0.5) * TUNNEL_SEGMENT_M);
        let p = line[j];
        line.push([p[0] + TUNNEL_SEGMENT_M * th.cos(), p[1] + TUNNEL_SEGMENT_M * th.sin()]);
    }
    let widths: Vec<f64> = (0..=n_seg).map(|j| shape.width(j as f64 * TUNNEL_SEGMENT_M)).collect();
    let offset = |j: usize, side: f64, by: f64| {
        let th = shape.heading(j as f64 * TUNNEL_SEGMENT_M);
        [line[j][0] - side * by * th.sin(), line[j][1] + side * by * th.cos()]
    };
    let seg_heading: Vec<f64> = line.windows(2).map(|w| (w[1][1] - w[0][1]).atan2(w[1][0] - w[0][0])).collect();

    let wall_top = shape.max_ceiling() + t + 0.2;
    let (wall_z0, wall_z1) = (-0.2, wall_top);
    let mut boxes = Vec::new();
    for side in [1.0, -1.0] {
        for j in 0..n_seg {
            let (a, b) = (offset(j, side, 0.5 * widths[j]), offset(j + 1, side, 0.5 * widths[j + 1]));
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = dx.hypot(dy);
            // Outward normal: left of the direction of travel for the left wall.
            let out = [-side * dy / len, side * dx / len];
            boxes.push(boxed(
                [0.5 * (a[0] + b[0]) + 0.5 * t * out[0], 0.5 * (a[1] + b[1]) + 0.5 * t * out[1], 0.5 * (wall_z0 + wall_z1)],
                [len + t, t, wall_z1 - wall_z0],
                dy.atan2(dx),
                "wall",
            ));
        }
    }
    // Ceiling: one slab per segment, lengthened to close the gaps at the outer side of bends.
    let w_max = widths.iter().fold(0.0_f64, |m, &w| m.max(w));
    for j in 0..n_seg {
        let bend = [j.checked_sub(1), Some(j + 1).filter(|&k| k < n_seg)]
            .iter()
            .flatten()
            .map(|&k| (seg_heading[k] - seg_heading[j]).abs())
            .fold(0.0, f64::max);
        let ext = (0.5 * w_max + t) * bend + 0.1;
        let mid = [0.5 * (line[j][0] + line[j + 1][0]), 0.5 * (line[j][1] + line[j + 1][1])];
        let h = shape.ceiling((j as f64 + 0.5) * TUNNEL_SEGMENT_M);
        boxes.push(boxed([mid[0], mid[1], h + 0.5 * t], [TUNNEL_SEGMENT_M + 2.0 * ext, w_max + 2.0 * t, t], seg_heading[j], "ceiling"));
    }
    // End caps.
    for (j, dir_sign, k) in [(0, -1.0, 0), (n_seg, 1.0, n_seg - 1)] {
        let th = seg_heading[k];
        let c = [line[j][0] + dir_sign * 0.5 * t * th.cos(), line[j][1] + dir_sign * 0.5 * t * th.sin()];
        boxes.push(boxed([c[0], c[1], 0.5 * (wall_z0 + wall_z1)], [t, widths[j] + 2.0 * t + 0.4, wall_z1 - wall_z0], th, "wall"));
    }

    // Regions: start, goal and waypoints along the centreline.
    let region_at = |name: &str, s: f64, r: f64| {
        let (p, _, _) = centreline_at(&line, s);
        region(name, [p[0], p[1], TUNNEL_FLIGHT_HEIGHT_M], r)
    };
    let (s_start, s_goal) = (TUNNEL_END_OFFSET_M, length - TUNNEL_END_OFFSET_M);
    let n_wp = ((s_goal - s_start) / TUNNEL_WAYPOINT_SPACING_M).round().max(1.0) as usize - 1;
    let wp_spacing = (s_goal - s_start) / (n_wp + 1) as f64;
    let wp_s: Vec<f64> = (1..=n_wp).map(|k| s_start + k as f64 * wp_spacing).collect();
    let mut regions = vec![region_at("start", s_start, 0.5)];
    regions.extend(wp_s.iter().enumerate().map(|(k, &s)| region_at(&format!("wp{}", k + 1), s, 0.75)));
    regions.push(region_at("goal", s_goal, 0.5));

    // Feature stations along the arc, with spacing rules between kinds.
    let (s_lo, s_hi) = (TUNNEL_FEATURE_MARGIN_M, length - TUNNEL_FEATURE_MARGIN_M);
    let pick = |rng: &mut Rng, ok: &dyn Fn(f64) -> bool| -> Option<f64> {
        (0..200).map(|_| uni(rng, s_lo, s_hi)).find(|&s| ok(s))
    };
    let far = |s: f64, list: &[f64], gap: f64| list.iter().all(|&q| (s - q).abs() >= gap);

    let mut cylinders = Vec::new();
    let mut capsules = Vec::new();
    let mut spheres = Vec::new();

    // Rock columns, floor to ceiling, leaving >= 0.85 m on both sides.
    let mut col_s: Vec<f64> = Vec::new();
    for _ in 0..uni_count(&mut rng, 3, 4) {
        let Some(s) = pick(&mut rng, &|s| far(s, &col_s, 5.0) && far(s, &wp_s, 1.5)) else { continue };
        let r = uni(&mut rng, 0.2, 0.4);
        let lim = (0.5 * shape.width(s) - r - 0.85).max(0.0);
        let u = uni(&mut rng, -lim, lim);
        let (p, _, n) = centreline_at(&line, s);
        let c = [p[0] + u * n[0], p[1] + u * n[1]];
        cylinders.push(CylinderSpec {
            a: [c[0], c[1], -0.1],
            b: [c[0], c[1], shape.max_ceiling() + t],
            radius: r,
            tag: "column".into(),
            dark: false,
        });
        col_s.push(s);
    }
    // Rock bulges on the walls (spheres sunk into the wall, protruding 0.1-0.35 m).
    for _ in 0..uni_count(&mut rng, 8, 12) {
        let Some(s) = pick(&mut rng, &|s| far(s, &col_s, 2.5)) else { continue };
        let side = sign(&mut rng);
        let (big_r, protrude) = (uni(&mut rng, 0.4, 0.9), uni(&mut rng, 0.1, 0.35));
        let z = uni(&mut rng, 0.2, shape.ceiling(s) - 0.2);
        let (p, _, n) = centreline_at(&line, s);
        let u = side * (0.5 * shape.width(s) + big_r - protrude);
        spheres.push(SphereSpec { centre: [p[0] + u * n[0], p[1] + u * n[1], z], radius: big_r, tag: "rock".into(), dark: false });
    }
    // Cables hanging straight down from the ceiling.
    let mut cable_s: Vec<f64> = Vec::new();
    for _ in 0..uni_count(&mut rng, 4, 6) {
        let Some(s) = pick(&mut rng, &|s| far(s, &col_s, 1.5) && far(s, &wp_s, 1.0) && far(s, &cable_s, 2.0)) else {
            continue;
        };
        let u = uni(&mut rng, -1.0, 1.0) * (0.5 * shape.width(s) - 0.4);
        let (p, _, n) = centreline_at(&line, s);
        let c = [p[0] + u * n[0], p[1] + u * n[1]];
        capsules.push(CapsuleSpec {
            a: [c[0], c[1], uni(&mut rng, 0.9, 1.8)],
            b: [c[0], c[1], shape.max_ceiling() + 0.5 * t],
            radius: uni(&mut rng, 0.004, 0.012),
            tag: "cable".into(),
            dark: false,
        });
        cable_s.push(s);
    }
    // Cables sagging across the tube, anchored in both walls.
    for _ in 0..2 {
        let Some(s) = pick(&mut rng, &|s| far(s, &col_s, 1.5) && far(s, &wp_s, 1.0) && far(s, &cable_s, 1.0)) else {
            continue;
        };
        let (p, _, n) = centreline_at(&line, s);
        let half = 0.5 * shape.width(s) + 0.05;
        let anchor_z = shape.ceiling(s) - 0.25;
        let sag_z = uni(&mut rng, 1.8, (anchor_z - 0.1).clamp(1.8, 2.2));
        let u_mid = uni(&mut rng, -0.5, 0.5);
        let radius = uni(&mut rng, 0.006, 0.015);
        let left = [p[0] + half * n[0], p[1] + half * n[1], anchor_z];
        let mid = [p[0] + u_mid * n[0], p[1] + u_mid * n[1], sag_z];
        let right = [p[0] - half * n[0], p[1] - half * n[1], anchor_z];
        for (a, b) in [(left, mid), (mid, right)] {
            capsules.push(CapsuleSpec { a, b, radius, tag: "cable".into(), dark: false });
        }
        cable_s.push(s);
    }
    // Pipes along the walls: a chain of cylinders following the wall.
    for _ in 0..2 {
        let side = sign(&mut rng);
        let z = uni(&mut rng, 0.3, 2.2);
        let r = uni(&mut rng, 0.05, 0.15);
        let j0 = uni_count(&mut rng, 1, n_seg / 2);
        let j1 = (j0 + uni_count(&mut rng, 8, 16)).min(n_seg - 1);
        for j in j0..j1 {
            let (a, b) = (offset(j, side, 0.5 * widths[j] - r - 0.02), offset(j + 1, side, 0.5 * widths[j + 1] - r - 0.02));
            cylinders.push(CylinderSpec { a: [a[0], a[1], z], b: [b[0], b[1], z], radius: r, tag: "pipe".into(), dark: false });
        }
    }

    let spec = WorldSpec {
        name: "tunnel".into(),
        cylinders,
        capsules,
        boxes,
        spheres,
        planes: vec![plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], "floor")],
        regions,
        routes: vec![route("start", "goal")],
        ..WorldSpec::default()
    };
    TunnelLayout { spec, centreline: line, widths }
}

/// A winding cave-like tube: 32-38 m along a seeded smooth centreline starting at the
/// origin heading roughly +x (heading within +-0.65 rad, bend radius >= 3.5 m), 2.5-4 m
/// wide, ceiling 2.5-3.6 m; walls, end caps and ceiling slabs are 0.5 m boxes, the floor
/// the plane z = 0. Inside: 3-4 rock columns (radius 0.2-0.4 m, >= 0.85 m free beside
/// them), 8-12 rock bulges on the walls, 4-6 cables hanging from the ceiling to 0.9-1.8 m
/// (radius 4-12 mm), 2 cables sagging across the tube to 1.8-2.2 m, 2 pipes (radius
/// 0.05-0.15 m) along the walls. Regions "start" and "goal" 1.5 m from the ends and
/// waypoints "wp1", "wp2", ... about every 4 m (straight legs between them stay
/// clear of the walls), all on the centreline at 1.2 m; route
/// start-goal.
pub fn tunnel(seed: u64) -> WorldSpec {
    tunnel_layout(seed).spec
}

// ---------------------------------------------------------------------------------------
// mine
// ---------------------------------------------------------------------------------------

/// Terrain size along x and y [m] (the height field covers [0, 30] x [0, 20]).
pub const MINE_SIZE_M: [f64; 2] = [30.0, 20.0];
/// Height-field resolution [m].
pub const MINE_RESOLUTION_M: f64 = 0.1;
/// Half width of the corridor between start and goal that is kept free of lethal
/// features (holes, drops, steep mounds, rubble, pillars) [m].
pub const MINE_CORRIDOR_HALF_WIDTH_M: f64 = 1.5;
/// Radius of the start and goal regions [m].
pub const MINE_REGION_RADIUS_M: f64 = 1.0;
/// Keep-out radius of the comm nodes [m].
pub const MINE_COMM_NODE_KEEP_OUT_M: f64 = 0.5;
/// Ceiling height of the mine (a plane) [m].
const MINE_CEILING_M: f64 = 6.0;
/// Lethal features stay this far from start and goal centres [m].
const MINE_REGION_KEEP_M: f64 = 3.0;
/// Gap kept between the footprints of neighbouring features [m].
const MINE_FEATURE_GAP_M: f64 = 0.2;

/// A generated mine and the corridor it keeps free (tests check it).
struct MineLayout {
    spec: WorldSpec,
    /// Centreline of the free corridor from start to goal [m].
    #[cfg_attr(not(test), allow(dead_code))]
    corridor: Vec<[f64; 2]>,
}

/// Samples of the terrain grid; `x = c·res`, `y = r·res` (origin at 0, 0).
struct Grid {
    heights: Vec<Vec<f64>>,
    res: f64,
}

impl Grid {
    /// Bilinear height at (x, y); NaN outside the grid or where a sample with a non-zero
    /// weight is a hole.
    fn at(&self, x: f64, y: f64) -> f64 {
        let rows = self.heights.len();
        let cols = self.heights.first().map_or(0, Vec::len);
        let (fx, fy) = (x / self.res, y / self.res);
        if rows < 2 || cols < 2 || !(fx >= 0.0 && fy >= 0.0 && fx <= (cols - 1) as f64 && fy <= (rows - 1) as f64) {
            return f64::NAN;
        }
        let (c, r) = ((fx.floor() as usize).min(cols - 2), (fy.floor() as usize).min(rows - 2));
        let (tx, ty) = (fx - c as f64, fy - r as f64);
        let mut sum = 0.0;
        for (dr, wy) in [(0, 1.0 - ty), (1, ty)] {
            for (dc, wx) in [(0, 1.0 - tx), (1, tx)] {
                if wx * wy != 0.0 {
                    sum += wx * wy * self.heights[r + dr][c + dc];
                }
            }
        }
        sum
    }
}

fn mine_layout(seed: u64) -> MineLayout {
    let mut rng = Rng::seed_from_u64(seed);
    let [sx, sy] = MINE_SIZE_M;
    let res = MINE_RESOLUTION_M;
    let snap = |v: f64| (v / res).round() * res;
    let start = [5.0, snap(uni(&mut rng, 8.0, 12.0))];
    let goal = [25.0, snap(uni(&mut rng, 8.0, 12.0))];
    // Corridor: the chord bent sideways by 3-4 m at its middle (not a straight drive).
    let bend = sign(&mut rng) * uni(&mut rng, 3.0, 4.0);
    let wiggle = uni(&mut rng, -0.5, 0.5);
    let corridor: Vec<[f64; 2]> = (0..=60)
        .map(|k| {
            let s = k as f64 / 60.0;
            [
                start[0] + s * (goal[0] - start[0]),
                start[1] + s * (goal[1] - start[1]) + bend * (PI * s).sin() + wiggle * (TAU * s).sin(),
            ]
        })
        .collect();

    // Footprints (centre, radius) of everything placed so far, kept apart.
    let mut taken: Vec<([f64; 2], f64)> = Vec::new();
    let free = |p: [f64; 2], r: f64, taken: &[([f64; 2], f64)]| {
        p[0] - r >= 1.0
            && p[0] + r <= sx - 1.0
            && p[1] - r >= 1.0
            && p[1] + r <= sy - 1.0
            && dist_point_polyline2(p, &corridor) >= MINE_CORRIDOR_HALF_WIDTH_M + r + MINE_FEATURE_GAP_M
            && dist2(p, start) >= MINE_REGION_KEEP_M + r
            && dist2(p, goal) >= MINE_REGION_KEEP_M + r
            && taken.iter().all(|&(q, rq)| dist2(p, q) >= r + rq + MINE_FEATURE_GAP_M)
    };
    let place = |rng: &mut Rng, r: f64, taken: &mut Vec<([f64; 2], f64)>| -> Option<[f64; 2]> {
        let p = (0..MAX_ATTEMPTS).map(|_| [uni(rng, 0.0, sx), uni(rng, 0.0, sy)]).find(|&p| free(p, r, taken))?;
        taken.push((p, r));
        Some(p)
    };

    // Comm nodes dropped beside the corridor (keep-out discs narrow it), one elsewhere.
    let mut items = Vec::new();
    let mut node_xy = Vec::new();
    for t0 in [0.3, 0.55, 0.8] {
        let s = t0 + uni(&mut rng, -0.05, 0.05);
        let k = ((s * 60.0).round() as usize).clamp(1, 59);
        let (a, b) = (corridor[k - 1], corridor[k + 1]);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = dx.hypot(dy);
        let u = sign(&mut rng) * uni(&mut rng, 1.3, 1.7);
        let p = [corridor[k][0] - u * dy / len, corridor[k][1] + u * dx / len];
        taken.push((p, MINE_COMM_NODE_KEEP_OUT_M + 0.3));
        node_xy.push(p);
    }
    if let Some(p) = place(&mut rng, MINE_COMM_NODE_KEEP_OUT_M + 0.3, &mut taken) {
        node_xy.push(p);
    }

    // Holes (NaN): one on the straight line from start to goal, 2-3 elsewhere.
    let mut holes: Vec<([f64; 2], f64)> = Vec::new();
    for _ in 0..MAX_ATTEMPTS {
        let (t0, r) = (uni(&mut rng, 0.35, 0.65), uni(&mut rng, 0.6, 0.9));
        let p = [start[0] + t0 * (goal[0] - start[0]), start[1] + t0 * (goal[1] - start[1])];
        if free(p, r, &taken) {
            taken.push((p, r));
            holes.push((p, r));
            break;
        }
    }
    for _ in 0..uni_count(&mut rng, 2, 3) {
        let r = uni(&mut rng, 0.4, 0.9);
        if let Some(p) = place(&mut rng, r, &mut taken) {
            holes.push((p, r));
        }
    }
    // Pits: rotated rectangles sunk 0.3-0.8 m with vertical sides (drop-offs).
    let mut pits: Vec<([f64; 2], [f64; 2], f64, f64)> = Vec::new(); // centre, half sizes, yaw, depth
    for _ in 0..2 {
        let half = [uni(&mut rng, 0.75, 1.75), uni(&mut rng, 0.75, 1.75)];
        let (yaw, depth) = (uni(&mut rng, 0.0, PI), uni(&mut rng, 0.3, 0.8));
        if let Some(p) = place(&mut rng, half[0].hypot(half[1]), &mut taken) {
            pits.push((p, half, yaw, depth));
        }
    }
    // Steep mounds (spoil heaps): cones with 30-40 degree flanks, lethal for a ground robot.
    let mut mounds: Vec<([f64; 2], f64, f64)> = Vec::new(); // centre, height, tan(flank)
    for _ in 0..uni_count(&mut rng, 2, 3) {
        let (h, tan_a) = (uni(&mut rng, 1.0, 1.5), uni(&mut rng, 30.0_f64.to_radians(), 40.0_f64.to_radians()).tan());
        if let Some(p) = place(&mut rng, h / tan_a, &mut taken) {
            mounds.push((p, h, tan_a));
        }
    }
    // Room-and-pillar pillars, floor to ceiling.
    let mut boxes = perimeter_walls(0.0, sx, 0.0, sy, -3.0, MINE_CEILING_M, 0.5);
    for _ in 0..uni_count(&mut rng, 2, 3) {
        let (lx, ly, yaw) = (uni(&mut rng, 1.5, 3.0), uni(&mut rng, 1.5, 3.0), uni(&mut rng, 0.0, PI));
        if let Some(p) = place(&mut rng, 0.5 * lx.hypot(ly), &mut taken) {
            boxes.push(boxed([p[0], p[1], 0.5 * (MINE_CEILING_M - 3.0)], [lx, ly, MINE_CEILING_M + 3.0], yaw, "pillar"));
        }
    }
    // Rubble footprints now, heights after the terrain exists: most of it in 2-3 rock-fall
    // heaps (within 2.5 m of a heap's centre), the rest scattered.
    let heaps: Vec<[f64; 2]> = (0..uni_count(&mut rng, 2, 3)).map(|_| [uni(&mut rng, 2.0, sx - 2.0), uni(&mut rng, 2.0, sy - 2.0)]).collect();
    let place_rubble = |rng: &mut Rng, r: f64, taken: &mut Vec<([f64; 2], f64)>| -> Option<[f64; 2]> {
        let p = (0..MAX_ATTEMPTS)
            .map(|_| {
                if rng.random::<f64>() < 0.7 {
                    let c = heaps[rng.random_range(0..heaps.len())];
                    let (rho, phi) = (2.5 * rng.random::<f64>().sqrt(), uni(rng, 0.0, TAU));
                    [c[0] + rho * phi.cos(), c[1] + rho * phi.sin()]
                } else {
                    [uni(rng, 0.0, sx), uni(rng, 0.0, sy)]
                }
            })
            .find(|&p| free(p, r, taken))?;
        taken.push((p, r));
        Some(p)
    };
    let mut rubble_boxes: Vec<([f64; 2], [f64; 3], f64)> = Vec::new();
    for _ in 0..uni_count(&mut rng, 6, 10) {
        let size = [uni(&mut rng, 0.2, 0.7), uni(&mut rng, 0.2, 0.7), uni(&mut rng, 0.2, 0.6)];
        let yaw = uni(&mut rng, 0.0, PI);
        if let Some(p) = place_rubble(&mut rng, 0.5 * size[0].hypot(size[1]), &mut taken) {
            rubble_boxes.push((p, size, yaw));
        }
    }
    let mut rubble_spheres: Vec<([f64; 2], f64)> = Vec::new();
    for _ in 0..uni_count(&mut rng, 18, 28) {
        let r = uni(&mut rng, 0.08, 0.35);
        if let Some(p) = place_rubble(&mut rng, r, &mut taken) {
            rubble_spheres.push((p, r));
        }
    }

    // Terrain: gentle undulation (<= ~6 degrees), two gentle hills or dips (<= ~5 degrees),
    // roughness of a few cm (value noise on a 0.5 m lattice plus +-5 mm per sample).
    let waves: Vec<(f64, f64, f64, f64)> = (0..2)
        .map(|_| {
            let (amp, wavelength, dir) = (uni(&mut rng, 0.1, 0.18), uni(&mut rng, 16.0, 24.0), uni(&mut rng, 0.0, TAU));
            let k = TAU / wavelength;
            (amp, k * dir.cos(), k * dir.sin(), uni(&mut rng, 0.0, TAU))
        })
        .collect();
    let hills: Vec<([f64; 2], f64, f64)> = (0..2)
        .map(|_| {
            let c = [uni(&mut rng, 0.0, sx), uni(&mut rng, 0.0, sy)];
            (c, sign(&mut rng) * uni(&mut rng, 0.3, 0.5), uni(&mut rng, 3.5, 4.5))
        })
        .collect();
    let lattice = 0.5;
    let (lnx, lny) = ((sx / lattice) as usize + 2, (sy / lattice) as usize + 2);
    let noise: Vec<f64> = (0..lnx * lny).map(|_| uni(&mut rng, -0.025, 0.025)).collect();
    let (cols, rows) = ((sx / res).round() as usize + 1, (sy / res).round() as usize + 1);
    let mut heights = vec![vec![0.0; cols]; rows];
    for (r, row) in heights.iter_mut().enumerate() {
        let y = r as f64 * res;
        for (c, h) in row.iter_mut().enumerate() {
            let x = c as f64 * res;
            let mut z: f64 = waves.iter().map(|&(a, kx, ky, ph)| a * (kx * x + ky * y + ph).sin()).sum();
            z += hills.iter().map(|&(q, a, s)| a * (-((x - q[0]).powi(2) + (y - q[1]).powi(2)) / (2.0 * s * s)).exp()).sum::<f64>();
            let (gx, gy) = (x / lattice, y / lattice);
            let (i, j) = (gx.floor() as usize, gy.floor() as usize);
            let (tx, ty) = (gx - i as f64, gy - j as f64);
            let n = |i: usize, j: usize| noise[(j * lnx + i).min(noise.len() - 1)];
            z += (n(i, j) * (1.0 - tx) + n(i + 1, j) * tx) * (1.0 - ty) + (n(i, j + 1) * (1.0 - tx) + n(i + 1, j + 1) * tx) * ty;
            z += uni(&mut rng, -0.005, 0.005);
            *h = z;
        }
    }
    let mut edit = |centre: [f64; 2], reach: f64, f: &dyn Fn(f64, f64, &mut f64)| {
        let c0 = ((centre[0] - reach) / res).floor().max(0.0) as usize;
        let c1 = (((centre[0] + reach) / res).ceil().max(0.0) as usize).min(cols - 1);
        let r0 = ((centre[1] - reach) / res).floor().max(0.0) as usize;
        let r1 = (((centre[1] + reach) / res).ceil().max(0.0) as usize).min(rows - 1);
        for (r, row) in heights.iter_mut().enumerate().take(r1 + 1).skip(r0) {
            for (c, z) in row.iter_mut().enumerate().take(c1 + 1).skip(c0) {
                f(c as f64 * res - centre[0], r as f64 * res - centre[1], z);
            }
        }
    };
    for &(p, h, tan_a) in &mounds {
        edit(p, h / tan_a, &|dx, dy, z| *z += (h - dx.hypot(dy) * tan_a).max(0.0));
    }
    for &(p, half, yaw, depth) in &pits {
        let (cy, sy_) = (yaw.cos(), yaw.sin());
        edit(p, half[0].hypot(half[1]), &|dx, dy, z| {
            let (u, v) = (cy * dx + sy_ * dy, -sy_ * dx + cy * dy);
            if u.abs() <= half[0] && v.abs() <= half[1] {
                *z -= depth;
            }
        });
    }
    for &(p, r) in &holes {
        edit(p, r, &|dx, dy, z| {
            if dx.hypot(dy) <= r {
                *z = f64::NAN;
            }
        });
    }
    let grid = Grid { heights, res };

    for &(p, size, yaw) in &rubble_boxes {
        boxes.push(boxed([p[0], p[1], grid.at(p[0], p[1]) + 0.3 * size[2]], size, yaw, "rubble"));
    }
    let spheres = rubble_spheres
        .iter()
        .map(|&(p, r)| SphereSpec { centre: [p[0], p[1], grid.at(p[0], p[1]) + 0.4 * r], radius: r, tag: "rubble".into(), dark: false })
        .collect();
    items.extend(node_xy.iter().map(|&p| ItemSpec {
        kind: "comm_node".into(),
        position: [p[0], p[1], grid.at(p[0], p[1]) + 0.15],
        keep_out_radius: MINE_COMM_NODE_KEEP_OUT_M,
        solid: true,
    }));
    let regions = vec![
        region("start", [start[0], start[1], grid.at(start[0], start[1])], MINE_REGION_RADIUS_M),
        region("goal", [goal[0], goal[1], grid.at(goal[0], goal[1])], MINE_REGION_RADIUS_M),
    ];

    let spec = WorldSpec {
        name: "mine".into(),
        boxes,
        spheres,
        planes: vec![plane([0.0, 0.0, MINE_CEILING_M], [0.0, 0.0, -1.0], "ceiling")],
        heightfield: Some(HeightFieldSpec { origin: [0.0, 0.0], resolution: res, heights: grid.heights, hole_value: None, dark: false }),
        regions,
        items,
        routes: vec![route("start", "goal")],
        ..WorldSpec::default()
    };
    MineLayout { spec, corridor }
}

/// A ground robot's mine: a 30 x 20 m height field (0.1 m, 301 x 201 samples, origin at
/// (0, 0)) with gentle undulation and hills (slopes to ~10 degrees) and a few cm of
/// roughness; 2-3 spoil heaps with 30-40 degree flanks (1.0-1.5 m high); 3-4 holes (NaN,
/// radius 0.4-0.9 m), one of them on the straight line from start to goal; 2 pits sunk
/// 0.3-0.8 m with vertical sides; 2-3 floor-to-ceiling pillars; 6-10 rubble boxes and
/// 18-28 rubble spheres (mostly in 2-3 heaps); 4 comm nodes (items, keep-out 0.5 m, solid), three beside the
/// route; perimeter walls, ceiling plane at 6 m. Regions "start" (x = 5) and "goal"
/// (x = 25), radius 1 m, on the terrain; a 3 m wide corridor between them bending 3-4 m
/// sideways is free of lethal features. Route start-goal.
pub fn mine(seed: u64) -> WorldSpec {
    mine_layout(seed).spec
}

// ---------------------------------------------------------------------------------------
// subway
// ---------------------------------------------------------------------------------------

/// Platform length along x [m] (x in [0, 30]).
pub const SUBWAY_PLATFORM_LENGTH_M: f64 = 30.0;
/// Platform width along y [m] (y in [0, 3]); its top is z = 0.
pub const SUBWAY_PLATFORM_WIDTH_M: f64 = 3.0;
/// Range of the track bed's depth below the platform [m].
pub const SUBWAY_TRACK_DEPTH_M: (f64, f64) = (0.95, 1.1);
/// Width of each track bed beside the platform [m].
const SUBWAY_TRACK_WIDTH_M: f64 = 3.5;
/// Station ceiling height above the platform [m].
const SUBWAY_CEILING_M: f64 = 3.5;
/// Height-field resolution [m].
const SUBWAY_RESOLUTION_M: f64 = 0.1;
/// Standard-gauge rail spacing (centre to centre, about) [m].
const RAIL_GAUGE_M: f64 = 1.5;

/// An island platform between two track beds: platform 30 x 3 m at z = 0 (x in [0, 30],
/// y in [0, 3]), track beds 3.5 m wide on both sides and 1 m past both ends, 0.95-1.1 m
/// lower, with +-2 cm ballast roughness and two rails each; one height field (0.1 m,
/// origin (-1, -3.5), 321 x 101 samples). 4-6 columns (radius 0.2-0.3 m) along the
/// platform's middle, 1-2 benches between them, walls and a ceiling plane at 3.5 m.
/// Regions "start" (2, 1.5, 0) and "goal" (28, 1.5, 0), radius 0.75 m; route start-goal.
pub fn subway(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let (pl, pw, res) = (SUBWAY_PLATFORM_LENGTH_M, SUBWAY_PLATFORM_WIDTH_M, SUBWAY_RESOLUTION_M);
    let depth = uni(&mut rng, SUBWAY_TRACK_DEPTH_M.0, SUBWAY_TRACK_DEPTH_M.1);
    let origin = [-1.0, -SUBWAY_TRACK_WIDTH_M];
    let (x1, y1) = (pl + 1.0, pw + SUBWAY_TRACK_WIDTH_M);
    let cols = ((x1 - origin[0]) / res).round() as usize + 1;
    let rows = ((y1 - origin[1]) / res).round() as usize + 1;
    // Platform samples, by index so that its edges fall exactly on samples.
    let (pc0, pc1) = ((-origin[0] / res).round() as usize, ((pl - origin[0]) / res).round() as usize);
    let (pr0, pr1) = ((-origin[1] / res).round() as usize, ((pw - origin[1]) / res).round() as usize);
    let heights: Vec<Vec<f64>> = (0..rows)
        .map(|r| {
            (0..cols)
                .map(|c| {
                    if (pc0..=pc1).contains(&c) && (pr0..=pr1).contains(&r) {
                        0.0
                    } else {
                        -depth + uni(&mut rng, -0.02, 0.02)
                    }
                })
                .collect()
        })
        .collect();

    let mut boxes = perimeter_walls(origin[0], x1, origin[1], y1, -depth - 0.5, SUBWAY_CEILING_M, WALL_THICKNESS_M);
    for track_y in [-0.5 * SUBWAY_TRACK_WIDTH_M, pw + 0.5 * SUBWAY_TRACK_WIDTH_M] {
        for side in [-0.5, 0.5] {
            boxes.push(boxed([0.5 * (origin[0] + x1), track_y + side * RAIL_GAUGE_M, -depth + 0.075], [x1 - origin[0], 0.07, 0.15], 0.0, "rail"));
        }
    }
    let n_col = uni_count(&mut rng, 4, 6);
    let col_x: Vec<f64> = (0..n_col).map(|k| 5.0 + 20.0 * k as f64 / (n_col - 1) as f64 + uni(&mut rng, -0.8, 0.8)).collect();
    let cylinders = col_x
        .iter()
        .map(|&x| {
            let y = 0.5 * pw + uni(&mut rng, -0.15, 0.15);
            CylinderSpec { a: [x, y, 0.0], b: [x, y, SUBWAY_CEILING_M], radius: uni(&mut rng, 0.2, 0.3), tag: "column".into(), dark: false }
        })
        .collect();
    for _ in 0..uni_count(&mut rng, 1, 2) {
        let k = rng.random_range(0..n_col - 1);
        let x = 0.5 * (col_x[k] + col_x[k + 1]) + uni(&mut rng, -0.3, 0.3);
        if !boxes.iter().any(|b| b.tag == "bench" && (b.centre[0] - x).abs() < 2.0) {
            boxes.push(boxed([x, 0.5 * pw, 0.225], [1.6, 0.45, 0.45], 0.0, "bench"));
        }
    }
    WorldSpec {
        name: "subway".into(),
        cylinders,
        boxes,
        planes: vec![plane([0.0, 0.0, SUBWAY_CEILING_M], [0.0, 0.0, -1.0], "ceiling")],
        heightfield: Some(HeightFieldSpec { origin, resolution: res, heights, hole_value: None, dark: false }),
        regions: vec![region("start", [2.0, 0.5 * pw, 0.0], 0.75), region("goal", [pl - 2.0, 0.5 * pw, 0.0], 0.75)],
        routes: vec![route("start", "goal")],
        ..WorldSpec::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // ----- helpers -------------------------------------------------------------------

    /// Bit-exact text of a spec (`==` is false for NaN holes even between equal specs).
    fn bits(spec: &WorldSpec) -> String {
        format!("{spec:?}")
    }

    fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }
    fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }
    fn norm(a: [f64; 3]) -> f64 {
        dot(a, a).sqrt()
    }

    /// Distance from `p` to the segment `a`-`b` in 3-D [m].
    fn seg_dist(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
        let (ab, ap) = (sub(b, a), sub(p, a));
        let t = (dot(ap, ab) / dot(ab, ab).max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
        norm(sub(ap, [t * ab[0], t * ab[1], t * ab[2]]))
    }

    /// Signed distance from `p` to a yawed box [m] (negative inside).
    fn box_dist(p: [f64; 3], b: &BoxSpec) -> f64 {
        let d = sub(p, b.centre);
        let (c, s) = (b.yaw.cos(), b.yaw.sin());
        let local = [c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]];
        let q: Vec<f64> = (0..3).map(|i| local[i].abs() - 0.5 * b.size[i]).collect();
        let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
        outside + q.iter().copied().fold(f64::NEG_INFINITY, f64::max).min(0.0)
    }

    /// A lower bound of the distance from `p` to the nearest primitive (cylinders taken as
    /// capsules, which contain them); the height field is left out.
    fn clearance(spec: &WorldSpec, p: [f64; 3]) -> f64 {
        let cyl = spec.cylinders.iter().map(|c| seg_dist(p, c.a, c.b) - c.radius);
        let cap = spec.capsules.iter().map(|c| seg_dist(p, c.a, c.b) - c.radius);
        let sph = spec.spheres.iter().map(|s| norm(sub(p, s.centre)) - s.radius);
        let bx = spec.boxes.iter().map(|b| box_dist(p, b));
        let pl = spec.planes.iter().map(|q| dot(sub(p, q.point), q.normal) / norm(q.normal));
        cyl.chain(cap).chain(sph).chain(bx).chain(pl).fold(f64::INFINITY, f64::min)
    }

    /// What `World::from_spec` validates, checked on the spec itself.
    fn assert_valid(spec: &WorldSpec) {
        let fin3 = |v: [f64; 3]| v.iter().all(|x| x.is_finite());
        for c in &spec.cylinders {
            assert!(fin3(c.a) && fin3(c.b) && c.radius > 0.0 && c.a != c.b, "{}: cylinder {c:?}", spec.name);
        }
        for c in &spec.capsules {
            assert!(fin3(c.a) && fin3(c.b) && c.radius > 0.0, "{}: capsule {c:?}", spec.name);
        }
        for b in &spec.boxes {
            assert!(fin3(b.centre) && b.yaw.is_finite() && b.size.iter().all(|s| *s > 0.0 && s.is_finite()), "{}: box {b:?}", spec.name);
        }
        for s in &spec.spheres {
            assert!(fin3(s.centre) && s.radius > 0.0, "{}: sphere {s:?}", spec.name);
        }
        for q in &spec.planes {
            assert!(fin3(q.point) && fin3(q.normal) && norm(q.normal) > 0.0, "{}: plane {q:?}", spec.name);
        }
        if let Some(hf) = &spec.heightfield {
            assert!(hf.resolution > 0.0 && hf.origin.iter().all(|v| v.is_finite()));
            assert!(hf.heights.len() >= 2 && hf.heights[0].len() >= 2);
            assert!(hf.heights.iter().all(|row| row.len() == hf.heights[0].len()), "{}: ragged height field", spec.name);
            assert!(hf.heights.iter().flatten().all(|h| h.is_nan() || h.is_finite()));
        }
        for it in &spec.items {
            assert!(fin3(it.position) && it.keep_out_radius > 0.0, "{}: item {it:?}", spec.name);
        }
        for (i, r) in spec.regions.iter().enumerate() {
            assert!(fin3(r.centre) && r.radius > 0.0, "{}: region {r:?}", spec.name);
            assert!(spec.regions[..i].iter().all(|q| q.name != r.name), "{}: duplicate region {}", spec.name, r.name);
        }
        for rt in &spec.routes {
            assert!(spec.regions.iter().any(|r| r.name == rt.from), "{}: route {} from unknown region", spec.name, rt.name);
            assert!(spec.regions.iter().any(|r| r.name == rt.to), "{}: route {} to unknown region", spec.name, rt.name);
            assert_eq!(rt.name, format!("{}-{}", rt.from, rt.to));
        }
    }

    fn region_of<'a>(spec: &'a WorldSpec, name: &str) -> &'a RegionSpec {
        spec.regions.iter().find(|r| r.name == name).unwrap_or_else(|| panic!("{}: no region {name}", spec.name))
    }

    fn grid_of(spec: &WorldSpec) -> Grid {
        let hf = spec.heightfield.as_ref().expect("height field");
        Grid { heights: hf.heights.clone(), res: hf.resolution }
    }

    // ----- helpers of the generators, against hand-computed values ---------------------

    #[test]
    fn point_segment_distance_matches_hand_values() {
        // Foot of the perpendicular inside the segment: distance 1.
        assert_eq!(dist_point_segment2([0.0, 1.0], [-1.0, 0.0], [1.0, 0.0]), 1.0);
        // Beyond the end (3, 4) from (0, 0): the 3-4-5 triangle.
        assert_eq!(dist_point_segment2([4.0, 4.0], [-1.0, 0.0], [1.0, 0.0]), 5.0);
        // Degenerate segment.
        assert_eq!(dist_point_segment2([3.0, 4.0], [0.0, 0.0], [0.0, 0.0]), 5.0);
        // Polyline: the nearer of two segments.
        assert_eq!(dist_point_polyline2([2.0, 0.5], &[[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]]), 1.0);
    }

    #[test]
    fn grid_bilinear_height_matches_hand_values() {
        let g = Grid { heights: vec![vec![0.0, 1.0], vec![2.0, 3.0]], res: 0.1 };
        assert!((g.at(0.05, 0.05) - 1.5).abs() < 1e-12); // mean of the four corners
        assert!((g.at(0.1, 0.0) - 1.0).abs() < 1e-12);
        assert!((g.at(0.025, 0.1) - 2.25).abs() < 1e-12);
        assert!(g.at(-0.01, 0.0).is_nan() && g.at(0.5, 0.0).is_nan(), "outside gives NaN");
    }

    #[test]
    fn perimeter_walls_have_their_inner_faces_on_the_rectangle() {
        let walls = perimeter_walls(1.0, 4.0, -2.0, 3.0, 0.0, 2.0, 0.5);
        let inner_x: Vec<f64> = walls[..2].iter().map(|b| b.centre[0] - (b.centre[0] - 2.5).signum() * 0.5 * b.size[0]).collect();
        let inner_y: Vec<f64> = walls[2..].iter().map(|b| b.centre[1] - (b.centre[1] - 0.5).signum() * 0.5 * b.size[1]).collect();
        assert_eq!(inner_x, vec![1.0, 4.0]);
        assert_eq!(inner_y, vec![-2.0, 3.0]);
        assert!(walls.iter().all(|b| b.centre[2] == 1.0 && b.size[2] == 2.0 && b.tag == "wall"));
        // The signed distance helper: 0.25 m outside the west wall's outer face (x = 0.5).
        assert!((box_dist([0.25, 0.0, 1.0], &walls[0]) - 0.25).abs() < 1e-12);
    }

    // ----- all scenarios -----------------------------------------------------------------

    #[test]
    fn every_scenario_generates_a_valid_named_world() {
        for name in SCENARIOS {
            for seed in [0, 1, 42, u64::MAX] {
                let spec = generate(name, seed).expect("known scenario");
                assert_eq!(spec.name, name);
                assert_valid(&spec);
            }
        }
    }

    #[test]
    fn unknown_scenario_is_an_error_listing_the_known_ones() {
        let err = generate("moon", 3).expect_err("unknown");
        assert_eq!(
            err,
            SimError::Unknown { what: "scenario".into(), name: "moon".into(), known: SCENARIOS.join(", ") }
        );
        assert_eq!(err.to_string(), format!("unknown scenario `moon`; known: {}", SCENARIOS.join(", ")));
        assert!(SCENARIOS.join(", ").starts_with("highbay, cable, tunnel, mine, subway, slopes, rough, ledge, cave"));
        assert!(matches!(generate("Highbay", 0), Err(SimError::Unknown { .. })), "names are case sensitive");
    }

    #[test]
    fn same_seed_gives_the_same_spec_bit_for_bit() {
        for name in SCENARIOS {
            for seed in [0, 9, 123_456_789] {
                let (a, b) = (generate(name, seed).expect("a"), generate(name, seed).expect("b"));
                assert_eq!(bits(&a), bits(&b), "{name} seed {seed}");
                if !matches!(name, "mine" | "cave") {
                    assert_eq!(a, b, "{name} seed {seed}"); // no NaN holes: plain equality holds
                }
            }
        }
    }

    #[test]
    fn different_seeds_give_different_layouts() {
        for name in SCENARIOS {
            let specs: Vec<String> = (0..6).map(|s| bits(&generate(name, s).expect("spec"))).collect();
            for i in 0..specs.len() {
                for j in 0..i {
                    assert_ne!(specs[i], specs[j], "{name}: seeds {i} and {j} give the same world");
                }
            }
        }
    }

    // ----- highbay -------------------------------------------------------------------------

    #[test]
    fn highbay_hall_is_17_by_8_m_with_floor_and_ceiling() {
        let spec = highbay(5);
        let walls: Vec<&BoxSpec> = spec.boxes.iter().filter(|b| b.tag == "wall").collect();
        assert_eq!(walls.len(), 4);
        // Inner faces: the free interior is exactly [0, 17] x [0, 8].
        let mut xs: Vec<f64> = Vec::new();
        let mut ys: Vec<f64> = Vec::new();
        for b in &walls {
            assert_eq!(b.yaw, 0.0);
            if b.size[0] < b.size[1] {
                xs.push(if b.centre[0] < 8.5 { b.centre[0] + 0.5 * b.size[0] } else { b.centre[0] - 0.5 * b.size[0] });
                assert!(b.centre[1] - 0.5 * b.size[1] <= 0.0 && b.centre[1] + 0.5 * b.size[1] >= 8.0, "wall spans the hall");
            } else {
                ys.push(if b.centre[1] < 4.0 { b.centre[1] + 0.5 * b.size[1] } else { b.centre[1] - 0.5 * b.size[1] });
                assert!(b.centre[0] - 0.5 * b.size[0] <= 0.0 && b.centre[0] + 0.5 * b.size[0] >= 17.0, "wall spans the hall");
            }
        }
        xs.sort_by(f64::total_cmp);
        ys.sort_by(f64::total_cmp);
        assert_eq!(xs, vec![0.0, 17.0]);
        assert_eq!(ys, vec![0.0, 8.0]);
        let floor = spec.planes.iter().find(|p| p.tag == "floor").expect("floor");
        assert_eq!((floor.point[2], floor.normal), (0.0, [0.0, 0.0, 1.0]));
        let ceiling = spec.planes.iter().find(|p| p.tag == "ceiling").expect("ceiling");
        assert_eq!(ceiling.normal, [0.0, 0.0, -1.0]);
        assert!((6.0..=8.0).contains(&ceiling.point[2]));
    }

    #[test]
    fn highbay_poles_have_exactly_the_papers_diameters_and_counts() {
        for seed in 0..200 {
            let spec = highbay(seed);
            let mut counts = [0usize; 3];
            for c in &spec.cylinders {
                assert_eq!(c.tag, "pole");
                let d = 2.0 * c.radius;
                let k = HIGHBAY_POLES.iter().position(|&(dia, _)| dia == d).unwrap_or_else(|| panic!("seed {seed}: diameter {d}"));
                counts[k] += 1;
                // Vertical, floor to ceiling.
                assert_eq!((c.a[0], c.a[1], c.a[2]), (c.b[0], c.b[1], 0.0));
                assert_eq!(c.b[2], HIGHBAY_CEILING_M);
            }
            assert_eq!(counts, [6, 6, 4], "seed {seed}");
        }
        assert_eq!(HIGHBAY_POLES.map(|(d, _)| d), [0.270, 0.090, 0.022]);
    }

    #[test]
    fn highbay_poles_keep_their_clearances_from_regions_poles_and_walls() {
        for seed in 0..200 {
            let spec = highbay(seed);
            let poles: Vec<([f64; 2], f64)> = spec.cylinders.iter().map(|c| ([c.a[0], c.a[1]], c.radius)).collect();
            for (i, &(p, r)) in poles.iter().enumerate() {
                for reg in &spec.regions {
                    let gap = dist2(p, [reg.centre[0], reg.centre[1]]) - r;
                    assert!(gap >= HIGHBAY_CLEARANCE_M, "seed {seed}: pole {i} {gap} m from {}", reg.name);
                }
                for &(q, rq) in &poles[..i] {
                    assert!(dist2(p, q) - r - rq >= HIGHBAY_CLEARANCE_M, "seed {seed}: poles too close");
                }
                let to_wall = (p[0]).min(HIGHBAY_LENGTH_M - p[0]).min(p[1]).min(HIGHBAY_WIDTH_M - p[1]) - r;
                assert!(to_wall >= HIGHBAY_CLEARANCE_M, "seed {seed}: pole {to_wall} m from a wall");
            }
        }
    }

    #[test]
    fn highbay_routes_are_the_papers_between_regions_at_flight_height() {
        let spec = highbay(0);
        let names: Vec<&str> = spec.routes.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(names, ["A-B", "B-C", "C-D", "D-C", "D-B"]);
        let regions: Vec<&str> = spec.regions.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(regions, ["A", "B", "C", "D"]);
        for r in &spec.regions {
            assert_eq!(r.radius, 0.5);
            assert!((1.0..=1.5).contains(&r.centre[2]));
            assert!(r.centre[0] >= 1.0 && r.centre[0] <= 16.0 && r.centre[1] >= 1.0 && r.centre[1] <= 7.0);
        }
        // Every route crosses the hall: A-B 14 m, B-C hypot(14, 4), C-D 7 m, D-B hypot(7, 4).
        let len = |a: &str, b: &str| {
            let (p, q) = (region_of(&spec, a).centre, region_of(&spec, b).centre);
            dist2([p[0], p[1]], [q[0], q[1]])
        };
        assert_eq!(len("A", "B"), 14.0);
        assert!((len("B", "C") - 212.0_f64.sqrt()).abs() < 1e-12);
        assert_eq!(len("C", "D"), 7.0);
        assert!((len("D", "B") - 65.0_f64.sqrt()).abs() < 1e-12);
        // Start regions are clear of everything for the 0.27 m quadrotor.
        for seed in 0..50 {
            let spec = highbay(seed);
            for r in &spec.regions {
                assert!(clearance(&spec, r.centre) >= HIGHBAY_CLEARANCE_M - 1e-9, "seed {seed} region {}", r.name);
            }
        }
    }

    #[test]
    fn highbay_flights_meet_obstacles_on_their_routes() {
        for seed in 0..200 {
            let spec = highbay(seed);
            let near = spec
                .cylinders
                .iter()
                .filter(|c| {
                    spec.routes.iter().any(|rt| {
                        let (a, b) = (region_of(&spec, &rt.from).centre, region_of(&spec, &rt.to).centre);
                        dist_point_segment2([c.a[0], c.a[1]], [a[0], a[1]], [b[0], b[1]]) - c.radius <= 0.6
                    })
                })
                .count();
            assert!(near >= 4, "seed {seed}: only {near} poles near a route");
        }
    }

    // ----- cable ---------------------------------------------------------------------------

    #[test]
    fn cable_is_8_mm_and_half_a_metre_to_a_metre_ahead() {
        for seed in 0..100 {
            let spec = cable(seed);
            let start = region_of(&spec, "start");
            assert_eq!(start.centre, [0.0, 0.0, 1.0]);
            let cables: Vec<&CapsuleSpec> = spec.capsules.iter().filter(|c| c.tag == "cable").collect();
            assert_eq!(cables.len(), 1);
            let c = cables[0];
            assert_eq!(c.radius, 0.004);
            // Where the cable crosses the robot's height.
            let t = (start.centre[2] - c.a[2]) / (c.b[2] - c.a[2]);
            let at = [c.a[0] + t * (c.b[0] - c.a[0]), c.a[1] + t * (c.b[1] - c.a[1])];
            assert!((0.5..=1.0).contains(&at[0]) && (0.6 - 1e-9..=0.9 + 1e-9).contains(&at[0]), "seed {seed}: {at:?}");
            assert!(at[1].abs() <= 0.05 + 1e-12, "seed {seed}: cable off the optical axis");
            // It fills the D435's vertical view there (+-32 degrees: +-0.57 m at 0.9 m).
            assert!(c.a[2].min(c.b[2]) <= start.centre[2] - 0.6 && c.a[2].max(c.b[2]) >= start.centre[2] + 0.6);
            // The closest surface to the robot is the cable, at (distance to its axis - 4 mm).
            let axis = seg_dist(start.centre, c.a, c.b);
            assert!((clearance(&spec, start.centre) - (axis - 0.004)).abs() < 1e-12);
            // Background wall beyond the 1.2 m horizon, about 3 m ahead.
            let wall = spec.boxes.iter().find(|b| b.tag == "wall").expect("wall");
            let face = wall.centre[0] - 0.5 * wall.size[0];
            assert!((2.5..=3.5).contains(&face), "seed {seed}: wall at {face}");
            assert!(wall.size[1] >= 4.0 && wall.centre[1] == 0.0);
        }
    }

    // ----- tunnel --------------------------------------------------------------------------

    #[test]
    fn tunnel_is_30_to_40_m_long_and_2_5_to_4_m_wide() {
        for seed in 0..50 {
            let lay = tunnel_layout(seed);
            let length: f64 = lay.centreline.windows(2).map(|w| dist2(w[0], w[1])).sum();
            assert!((32.0 - 1e-9..=38.0 + 1e-9).contains(&length), "seed {seed}: {length}");
            assert!(lay.widths.iter().all(|w| (2.5..=4.0).contains(w)));
            // Smooth and never turning back.
            let heads: Vec<f64> = lay.centreline.windows(2).map(|w| (w[1][1] - w[0][1]).atan2(w[1][0] - w[0][0])).collect();
            assert!(heads.iter().all(|h| h.abs() <= 0.65 + 1e-9));
            assert!(heads.windows(2).all(|w| (w[1] - w[0]).abs() <= 0.3), "seed {seed}: sharp bend");
            // Winding: not a straight tube.
            let span = heads.iter().copied().fold(f64::NEG_INFINITY, f64::max) - heads.iter().copied().fold(f64::INFINITY, f64::min);
            assert!(span >= 0.3, "seed {seed}: heading span {span}");
        }
    }

    #[test]
    fn tunnel_centreline_is_clear_of_walls_ceiling_and_rocks() {
        for seed in 0..30 {
            let lay = tunnel_layout(seed);
            let spec = &lay.spec;
            let length = (lay.centreline.len() - 1) as f64 * TUNNEL_SEGMENT_M;
            // Away from the end caps (at s = 0 and s = length).
            let mut s = 1.2;
            while s <= length - 1.2 {
                let (p, _, _) = centreline_at(&lay.centreline, s);
                let q = [p[0], p[1], TUNNEL_FLIGHT_HEIGHT_M];
                for b in spec.boxes.iter() {
                    assert!(box_dist(q, b) >= 1.0, "seed {seed} s {s}: {} {} m", b.tag, box_dist(q, b));
                }
                for r in spec.spheres.iter() {
                    assert!(norm(sub(q, r.centre)) - r.radius >= 0.75, "seed {seed} s {s}: rock");
                }
                s += 0.25;
            }
        }
    }

    #[test]
    fn tunnel_legs_between_waypoints_stay_clear_of_the_walls() {
        for seed in 0..50 {
            let spec = tunnel(seed);
            // Regions in flight order: start, wp1, wp2, ..., goal.
            let chain: Vec<[f64; 3]> = spec.regions.iter().map(|r| r.centre).collect();
            assert_eq!(spec.regions.first().map(|r| r.name.as_str()), Some("start"));
            assert_eq!(spec.regions.last().map(|r| r.name.as_str()), Some("goal"));
            for (k, leg) in chain.windows(2).enumerate() {
                assert!(norm(sub(leg[1], leg[0])) <= TUNNEL_WAYPOINT_SPACING_M + 1.0, "seed {seed}: leg {k} too long");
                for i in 0..=50 {
                    let t = i as f64 / 50.0;
                    let q = [0, 1, 2].map(|d| leg[0][d] + t * (leg[1][d] - leg[0][d]));
                    let d = spec.boxes.iter().map(|b| box_dist(q, b)).fold(f64::INFINITY, f64::min);
                    assert!(d >= 0.5, "seed {seed}: leg {k} passes {d} m from a wall");
                }
            }
        }
    }

    #[test]
    fn tunnel_regions_are_clear_and_features_present() {
        for seed in 0..50 {
            let spec = tunnel(seed);
            let (start, goal) = (region_of(&spec, "start"), region_of(&spec, "goal"));
            let lay = tunnel_layout(seed);
            let length = (lay.centreline.len() - 1) as f64 * TUNNEL_SEGMENT_M;
            let (p0, _, _) = centreline_at(&lay.centreline, 1.5);
            let (p1, _, _) = centreline_at(&lay.centreline, length - 1.5);
            assert_eq!(start.centre, [p0[0], p0[1], 1.2]);
            assert_eq!(goal.centre, [p1[0], p1[1], 1.2]);
            assert!(dist2(p0, p1) >= 20.0, "seed {seed}: start and goal {} m apart", dist2(p0, p1));
            for r in &spec.regions {
                assert!(clearance(&spec, r.centre) >= 0.6, "seed {seed}: region {} clearance {}", r.name, clearance(&spec, r.centre));
            }
            let count = |tag: &str| spec.cylinders.iter().filter(|c| c.tag == tag).count() + spec.capsules.iter().filter(|c| c.tag == tag).count();
            assert!(count("column") >= 2, "seed {seed}: columns");
            assert!(count("cable") >= 4, "seed {seed}: cables");
            assert!(count("pipe") >= 8, "seed {seed}: pipes");
            assert!(spec.spheres.iter().filter(|s| s.tag == "rock").count() >= 6, "seed {seed}: rocks");
            assert!(spec.capsules.iter().all(|c| (0.004..=0.015).contains(&c.radius)));
            assert_eq!(spec.routes, vec![route("start", "goal")]);
            assert!(spec.regions.iter().filter(|r| r.name.starts_with("wp")).count() >= 3);
        }
    }

    // ----- mine ----------------------------------------------------------------------------

    /// Cells of the grid within `radius` of any point of `line`, as (row, col).
    fn cells_near(grid: &Grid, line: &[[f64; 2]], radius: f64) -> Vec<(usize, usize)> {
        let (rows, cols) = (grid.heights.len(), grid.heights[0].len());
        let lo = line.iter().fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
        let hi = line.iter().fold([f64::NEG_INFINITY; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
        let idx = |v: f64, n: usize| ((v / grid.res).max(0.0) as usize).min(n - 1);
        let mut out = Vec::new();
        for r in idx(lo[1] - radius, rows)..=idx(hi[1] + radius + grid.res, rows) {
            for c in idx(lo[0] - radius, cols)..=idx(hi[0] + radius + grid.res, cols) {
                let p = [c as f64 * grid.res, r as f64 * grid.res];
                if dist_point_polyline2(p, line) <= radius {
                    out.push((r, c));
                }
            }
        }
        out
    }

    #[test]
    fn mine_terrain_is_30_by_20_m_at_10_cm() {
        let spec = mine(2);
        let hf = spec.heightfield.as_ref().expect("height field");
        assert_eq!((hf.origin, hf.resolution), ([0.0, 0.0], 0.1));
        assert_eq!((hf.heights.len(), hf.heights[0].len()), (201, 301)); // 20 m / 0.1 + 1, 30 m / 0.1 + 1
        assert!(spec.planes.iter().all(|p| p.normal[2] < 0.0), "no floor plane under the holes");
    }

    #[test]
    fn mine_has_holes_and_drops_deeper_than_the_robots_clearance() {
        for seed in 0..12 {
            let hf = mine(seed).heightfield.expect("height field");
            let h = &hf.heights;
            let holes = h.iter().flatten().filter(|v| v.is_nan()).count();
            // Four holes of radius >= 0.4 m: at least 4 * (pi 0.4^2 / 0.01) ~ 200 samples.
            assert!(holes >= 150, "seed {seed}: {holes} hole samples");
            let mut deepest_step: f64 = 0.0;
            for r in 0..h.len() - 1 {
                for c in 0..h[0].len() - 1 {
                    for (a, b) in [(h[r][c], h[r][c + 1]), (h[r][c], h[r + 1][c])] {
                        if a.is_finite() && b.is_finite() {
                            deepest_step = deepest_step.max((a - b).abs());
                        }
                    }
                }
            }
            assert!(deepest_step > 0.3 - 0.06, "seed {seed}: deepest step {deepest_step}");
        }
    }

    #[test]
    fn mine_has_a_continuous_slope_steeper_than_25_degrees() {
        let tan25 = 25.0_f64.to_radians().tan();
        let base = 5; // 0.5 m
        for seed in 0..12 {
            let hf = mine(seed).heightfield.expect("height field");
            let h = &hf.heights;
            let mut steepest: f64 = 0.0;
            for r in 0..h.len() - base {
                for c in 0..h[0].len() - base {
                    for (dr, dc) in [(0, 1), (1, 0)] {
                        let run: Vec<f64> = (0..=base).map(|k| h[r + k * dr][c + k * dc]).collect();
                        // A slope, not a drop: finite and no single step above the 0.13 m clearance.
                        if run.iter().all(|v| v.is_finite()) && run.windows(2).all(|w| (w[1] - w[0]).abs() <= 0.13) {
                            steepest = steepest.max((run[base] - run[0]).abs() / (base as f64 * hf.resolution));
                        }
                    }
                }
            }
            assert!(steepest > tan25, "seed {seed}: steepest continuous slope {:.1} deg", steepest.atan().to_degrees());
        }
    }

    #[test]
    fn mine_has_solid_comm_nodes_on_the_ground() {
        for seed in 0..12 {
            let spec = mine(seed);
            let grid = grid_of(&spec);
            let nodes: Vec<&ItemSpec> = spec.items.iter().filter(|i| i.kind == "comm_node").collect();
            assert!(nodes.len() >= 3, "seed {seed}: {} comm nodes", nodes.len());
            for n in nodes {
                assert!(n.solid && n.keep_out_radius == 0.5);
                let g = grid.at(n.position[0], n.position[1]);
                assert!((n.position[2] - g - 0.15).abs() < 1e-12, "seed {seed}: node not resting on the ground");
            }
        }
    }

    #[test]
    fn mine_start_and_goal_are_on_finite_ground_about_20_m_apart() {
        for seed in 0..12 {
            let spec = mine(seed);
            let grid = grid_of(&spec);
            let (s, g) = (region_of(&spec, "start"), region_of(&spec, "goal"));
            let apart = dist2([s.centre[0], s.centre[1]], [g.centre[0], g.centre[1]]);
            assert!((20.0..=20.5).contains(&apart), "seed {seed}: {apart} m");
            for r in [s, g] {
                assert!(r.centre[2].is_finite());
                assert_eq!(r.centre[2], grid.at(r.centre[0], r.centre[1]));
                // The whole region and a 1 m margin is finite ground.
                let around = cells_near(&grid, &[[r.centre[0], r.centre[1]], [r.centre[0], r.centre[1]]], r.radius + 1.0);
                assert!(around.iter().all(|&(i, j)| grid.heights[i][j].is_finite()), "seed {seed}: hole near {}", r.name);
            }
            assert_eq!(spec.routes, vec![route("start", "goal")]);
        }
    }

    #[test]
    fn mine_corridor_is_drivable_and_free_of_lethal_features() {
        let tan15 = 15.0_f64.to_radians().tan();
        for seed in 0..10 {
            let lay = mine_layout(seed);
            let spec = &lay.spec;
            let grid = grid_of(spec);
            let cells = cells_near(&grid, &lay.corridor, 1.2);
            let h = &grid.heights;
            let inside: std::collections::HashSet<(usize, usize)> = cells.iter().copied().collect();
            for &(r, c) in &cells {
                assert!(h[r][c].is_finite(), "seed {seed}: hole in the corridor");
                // Steps to the next sample and slopes over 1 m, both ends in the corridor.
                for (dr, dc, limit) in [(0, 1, 0.05), (1, 0, 0.05), (0, 10, tan15), (10, 0, tan15)] {
                    if inside.contains(&(r + dr, c + dc)) {
                        let rise = (h[r + dr][c + dc] - h[r][c]).abs();
                        assert!(rise <= limit, "seed {seed}: rise {rise} m over {} samples at ({r}, {c})", dr + dc);
                    }
                }
            }
            let hw = MINE_CORRIDOR_HALF_WIDTH_M;
            for sp in &spec.spheres {
                assert!(dist_point_polyline2([sp.centre[0], sp.centre[1]], &lay.corridor) >= hw + sp.radius);
            }
            for b in spec.boxes.iter().filter(|b| b.tag != "wall") {
                assert!(dist_point_polyline2([b.centre[0], b.centre[1]], &lay.corridor) >= hw + 0.5 * b.size[0].hypot(b.size[1]));
            }
            // Comm nodes narrow the corridor but leave its centreline out of their keep-out.
            for n in &spec.items {
                assert!(dist_point_polyline2([n.position[0], n.position[1]], &lay.corridor) >= n.keep_out_radius + 0.6);
            }
        }
    }

    #[test]
    fn mine_straight_drive_from_start_to_goal_meets_a_hole() {
        for seed in 0..24 {
            let spec = mine(seed);
            let grid = grid_of(&spec);
            let (s, g) = (region_of(&spec, "start").centre, region_of(&spec, "goal").centre);
            let blocked = (0..=400).any(|k| {
                let t = k as f64 / 400.0;
                grid.at(s[0] + t * (g[0] - s[0]), s[1] + t * (g[1] - s[1])).is_nan()
            });
            assert!(blocked, "seed {seed}: the straight line is drivable");
        }
    }

    // ----- subway --------------------------------------------------------------------------

    #[test]
    fn subway_platform_is_30_by_3_m_about_1_m_above_the_tracks() {
        for seed in 0..20 {
            let spec = subway(seed);
            let hf = spec.heightfield.as_ref().expect("height field");
            assert_eq!((hf.origin, hf.resolution), ([-1.0, -3.5], 0.1));
            let h = &hf.heights;
            assert_eq!((h.len(), h[0].len()), (101, 321));
            let mut platform = 0;
            for (r, row) in h.iter().enumerate() {
                for (c, &v) in row.iter().enumerate() {
                    let (x, y) = (-1.0 + 0.1 * c as f64, -3.5 + 0.1 * r as f64);
                    let on = (-1e-9..=30.0 + 1e-9).contains(&x) && (-1e-9..=3.0 + 1e-9).contains(&y);
                    if on {
                        assert_eq!(v, 0.0);
                        platform += 1;
                    } else {
                        assert!((-1.12..=-0.93).contains(&v), "seed {seed}: track bed at {v}");
                    }
                }
            }
            assert_eq!(platform, 301 * 31); // 30 m x 3 m at 0.1 m, edges included
            for name in ["start", "goal"] {
                let r = region_of(&spec, name);
                assert!(r.centre[2] == 0.0 && r.centre[1] - r.radius >= 0.0 && r.centre[1] + r.radius <= 3.0);
            }
            let cols: Vec<&CylinderSpec> = spec.cylinders.iter().filter(|c| c.tag == "column").collect();
            assert!((4..=6).contains(&cols.len()));
            for c in cols {
                // >= 1.0 m free between column and platform edge on both sides, >= 1.5 m from regions.
                assert!(c.a[1] - c.radius >= 1.0 && 3.0 - c.a[1] - c.radius >= 1.0);
                for r in &spec.regions {
                    assert!(dist2([c.a[0], c.a[1]], [r.centre[0], r.centre[1]]) >= 1.5);
                }
            }
        }
    }

    // ----- speed and acceptance by the world -------------------------------------------------

    #[cfg(not(debug_assertions))]
    #[test]
    fn every_generator_takes_under_50_ms() {
        for name in SCENARIOS {
            let t0 = std::time::Instant::now();
            let spec = generate(name, 17).expect("spec");
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            assert!(ms < 50.0, "{name}: {ms:.1} ms");
            assert_eq!(spec.name, name);
        }
    }

    mod with_world {
        use super::*;
        use crate::world::World;
        use glam::DVec3;

        fn world(name: &str, seed: u64) -> World {
            World::from_spec(generate(name, seed).expect("spec")).unwrap_or_else(|e| panic!("{name} seed {seed}: {e}"))
        }

        /// Every horizontal ray (and one up) from `p` hits something within `range_m`.
        fn enclosed(w: &World, p: DVec3, range_m: f64) -> bool {
            (0..72).all(|k| {
                let a = k as f64 * TAU / 72.0;
                w.cast_ray(p, DVec3::new(a.cos(), a.sin(), 0.0), range_m).is_some()
            }) && w.cast_ray(p, DVec3::Z, range_m).is_some()
        }

        #[test]
        fn world_accepts_every_generated_scenario() {
            for name in SCENARIOS {
                for seed in 0..4 {
                    let w = world(name, seed);
                    assert!(w.primitive_count() > 0, "{name}");
                    assert_eq!(w.spec().name, name);
                }
            }
        }

        #[test]
        fn highbay_and_tunnel_are_closed_and_their_regions_clear() {
            for seed in 0..4 {
                let w = world("highbay", seed);
                for r in &w.spec().regions {
                    let p = DVec3::from_array(r.centre);
                    assert!(enclosed(&w, p, 20.0), "highbay seed {seed}: open at {}", r.name);
                    assert!(w.clearance(p) >= HIGHBAY_CLEARANCE_M - 1e-6, "highbay seed {seed}: {}", r.name);
                }
                let w = world("tunnel", seed);
                for r in &w.spec().regions {
                    let p = DVec3::from_array(r.centre);
                    assert!(enclosed(&w, p, 40.0), "tunnel seed {seed}: open at {}", r.name);
                    assert!(w.clearance(p) >= 0.6, "tunnel seed {seed}: {} clearance {}", r.name, w.clearance(p));
                }
            }
        }

        #[test]
        fn cable_is_seen_straight_ahead_of_the_robot() {
            for seed in 0..8 {
                let w = world("cable", seed);
                let start = DVec3::from_array(w.region("start").expect("start").centre);
                let c = &w.spec().capsules[0];
                let (a, b) = (DVec3::from_array(c.a), DVec3::from_array(c.b));
                let on_axis = a + (b - a) * ((start.z - a.z) / (b.z - a.z));
                let to = on_axis - start;
                let hit = w.cast_ray(start, to.normalize(), 10.0).expect("hit");
                assert_eq!(w.primitive(hit.primitive).map(|i| i.tag.as_str()), Some("cable"));
                // The ray meets the axis's surface within a few tenths of a mm of |to| - r.
                assert!((hit.distance_m - (to.length() - CABLE_RADIUS_M)).abs() < 5e-4, "seed {seed}: {}", hit.distance_m);
                // Beside the cable, straight ahead past it: the background wall at about 3 m.
                let wall = w.cast_ray(start, DVec3::new(1.0, 0.3, 0.0).normalize(), 10.0).expect("wall");
                assert_eq!(w.primitive(wall.primitive).map(|i| i.tag.as_str()), Some("wall"));
                assert!(wall.distance_m > 2.5);
            }
        }

        #[test]
        fn ground_robot_worlds_have_ground_at_start_and_goal_and_none_over_holes() {
            for seed in 0..4 {
                for name in ["mine", "subway"] {
                    let w = world(name, seed);
                    for r in ["start", "goal"] {
                        let c = w.region(r).expect("region").centre;
                        let g = w.ground_height(c[0], c[1]).unwrap_or_else(|| panic!("{name} seed {seed}: no ground at {r}"));
                        assert!((g - c[2]).abs() < 1e-9, "{name} seed {seed}: {r} at {} vs ground {g}", c[2]);
                    }
                }
                let w = world("mine", seed);
                let hf = w.spec().heightfield.as_ref().expect("hf");
                let h = &hf.heights;
                // A hole sample whose whole neighbourhood is hole: no ground there.
                let inner = (1..h.len() - 1)
                    .flat_map(|r| (1..h[0].len() - 1).map(move |c| (r, c)))
                    .find(|&(r, c)| (r - 1..=r + 1).all(|i| (c - 1..=c + 1).all(|j| h[i][j].is_nan())))
                    .expect("a hole");
                assert_eq!(w.ground_height(inner.1 as f64 * 0.1, inner.0 as f64 * 0.1), None);
                let w = world("subway", seed);
                let track = w.ground_height(10.0, -1.75).expect("track bed");
                assert!((-1.12..=-0.93).contains(&track));
                assert_eq!(w.ground_height(10.0, 0.5), Some(0.0));
            }
        }
    }
}
