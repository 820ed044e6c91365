//! The aerial scenarios, region centres at flight height: the APF-PF paper's flight hall
//! [`highbay`], its thin-cable test [`cable`] and the winding cave-like [`tunnel`].

use std::f64::consts::TAU;

use rand::{RngExt, SeedableRng};

use super::helpers::{boxed, dist2, perimeter_walls, plane, region, route, sign, uni, uni_count, Rng, MAX_ATTEMPTS, WALL_THICKNESS_M};
use crate::spec::{CapsuleSpec, CylinderSpec, SphereSpec, WorldSpec};

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
pub(super) const TUNNEL_SEGMENT_M: f64 = 1.0;
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
pub(super) struct TunnelLayout {
    pub(super) spec: WorldSpec,
    /// Centreline vertices, one per [`TUNNEL_SEGMENT_M`] of arc length [m].
    #[cfg_attr(not(test), allow(dead_code))]
    pub(super) centreline: Vec<[f64; 2]>,
    /// Free width at each vertex [m].
    #[cfg_attr(not(test), allow(dead_code))]
    pub(super) widths: Vec<f64>,
}

/// A point of the centreline polyline at arc length `s`, with the unit direction and
/// left normal of its segment.
pub(super) fn centreline_at(line: &[[f64; 2]], s: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
    let n_seg = line.len().saturating_sub(1).max(1);
    let j = ((s / TUNNEL_SEGMENT_M).floor().max(0.0) as usize).min(n_seg - 1);
    let f = (s / TUNNEL_SEGMENT_M - j as f64).clamp(0.0, 1.0);
    let (a, b) = (line[j], line[(j + 1).min(line.len() - 1)]);
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy).max(f64::EPSILON);
    let dir = [dx / len, dy / len];
    ([a[0] + f * dx, a[1] + f * dy], dir, [-dir[1], dir[0]])
}

pub(super) fn tunnel_layout(seed: u64) -> TunnelLayout {
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
