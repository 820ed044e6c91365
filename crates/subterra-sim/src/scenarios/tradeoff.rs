//! Ground worlds with a real choice between a short risky route and a longer safe one
//! ([`slopes`], [`rough`], [`ledge`]), and a narrow winding cave with holes in its floor
//! ([`cave`]). Each is a 0.1 m height field with perimeter walls and a ceiling; `start` and
//! `goal` regions (radius 1 m) on the ground; route start-goal. Every draw comes from one
//! seeded stream, as for the other scenarios.
//!
//! In the three trade-off worlds a band of hazard `x` in about `[7, 13]` m crosses the
//! straight line from start (`x` = 2.5) to goal (`x` = 17.5) and reaches from one side wall to
//! within a few metres of the other; the detour around its end is 8-10 m longer. The band is
//! traversable but risky for the Husky-like robot (risk about 0.2-0.5 per metre where the
//! planner rates it: tilt between its 10° safe and 25° lethal limits, or roughness and steps
//! below its 0.13 m clearance), so a planner pricing risk per metre as `-ln(1 - r)` with a
//! budget and one pricing it `1 + 2r` choose differently. The whole detour lies within 10 m
//! (half the default map) of the start, so a planner on the robot-centred map sees both.

use std::f64::consts::PI;

use rand::SeedableRng;

use super::helpers::{boxed, perimeter_walls, plane, region, route, sign, uni, uni_count, Rng};
use crate::spec::{BoxSpec, HeightFieldSpec, WorldSpec};

/// World size of the trade-off scenarios [m]: x in [0, 20], y in [0, 16].
pub const TRADEOFF_SIZE_M: [f64; 2] = [20.0, 16.0];
/// Height-field spacing [m].
pub const GROUND_RESOLUTION_M: f64 = 0.1;
/// Radius of the start and goal regions [m].
pub const GROUND_REGION_RADIUS_M: f64 = 1.0;
/// Ceiling height [m].
const CEILING_M: f64 = 5.0;
/// x of the start and goal region centres [m].
const START_X_M: f64 = 2.5;
const GOAL_X_M: f64 = 17.5;
/// The hazard band's x extent [m].
const BAND_X_M: (f64, f64) = (7.0, 13.0);

/// Which side the band leaves open, and the y of the start/goal line.
#[derive(Debug, Clone, Copy)]
struct Layout {
    /// +1: the open gap is at large y (the band starts at y = 0); -1: mirrored.
    side: f64,
    /// y of start and goal [m].
    line_y: f64,
    /// Where the band ends toward the gap, measured from its closed wall [m].
    band_end: f64,
}

impl Layout {
    fn draw(rng: &mut Rng) -> Self {
        let side = sign(rng);
        let (_, sy) = (TRADEOFF_SIZE_M[0], TRADEOFF_SIZE_M[1]);
        let from_wall = uni(rng, 3.0, 4.0);
        let band_end = uni(rng, 8.5, 9.5);
        let line_y = if side > 0.0 { from_wall } else { sy - from_wall };
        Self { side, line_y, band_end }
    }

    /// Distance of `y` from the band's closed wall [m].
    fn wall_distance(&self, y: f64) -> f64 {
        if self.side > 0.0 { y } else { TRADEOFF_SIZE_M[1] - y }
    }
}

/// The height field `z(x, y)` sampled on the world's grid, with `hole(x, y)` marking NaN.
fn sample(size: [f64; 2], res: f64, z: impl Fn(f64, f64) -> f64) -> Vec<Vec<f64>> {
    let (cols, rows) = ((size[0] / res).round() as usize + 1, (size[1] / res).round() as usize + 1);
    (0..rows).map(|r| (0..cols).map(|c| z(c as f64 * res, r as f64 * res)).collect()).collect()
}

/// Box-filtered 1-D profile: the mean of `f` over `[x - w/2, x + w/2]` (9 samples), which
/// rounds its corners (a sharp crest overhangs a footprint).
fn rounded(f: impl Fn(f64) -> f64, x: f64, w: f64) -> f64 {
    (0..9).map(|k| f(x + w * (k as f64 / 8.0 - 0.5))).sum::<f64>() / 9.0
}

/// A world of the trade-off family from its height field and extra boxes.
fn ground_world(name: &str, size: [f64; 2], heights: Vec<Vec<f64>>, extra: Vec<BoxSpec>, start: [f64; 2], goal: [f64; 2]) -> WorldSpec {
    let res = GROUND_RESOLUTION_M;
    let at = |p: [f64; 2]| {
        let (c, r) = ((p[0] / res).round() as usize, (p[1] / res).round() as usize);
        heights.get(r).and_then(|row| row.get(c)).copied().unwrap_or(0.0)
    };
    let regions = vec![
        region("start", [start[0], start[1], at(start)], GROUND_REGION_RADIUS_M),
        region("goal", [goal[0], goal[1], at(goal)], GROUND_REGION_RADIUS_M),
    ];
    let mut boxes = perimeter_walls(0.0, size[0], 0.0, size[1], -3.0, CEILING_M, 0.5);
    boxes.extend(extra);
    WorldSpec {
        name: name.into(),
        boxes,
        planes: vec![plane([0.0, 0.0, CEILING_M], [0.0, 0.0, -1.0], "ceiling")],
        heightfield: Some(HeightFieldSpec { origin: [0.0, 0.0], resolution: res, heights, hole_value: None, dark: false }),
        regions,
        routes: vec![route("start", "goal")],
        ..WorldSpec::default()
    }
}

/// A few centimetres of floor roughness: value noise on a 0.5 m lattice, `±amp` [m].
fn floor_noise(rng: &mut Rng, size: [f64; 2], amp: f64) -> impl Fn(f64, f64) -> f64 {
    let lattice = 0.5;
    let (nx, ny) = ((size[0] / lattice) as usize + 2, (size[1] / lattice) as usize + 2);
    let values: Vec<f64> = (0..nx * ny).map(|_| uni(rng, -amp, amp)).collect();
    move |x: f64, y: f64| {
        let (gx, gy) = (x / lattice, y / lattice);
        let (i, j) = (gx.floor().max(0.0) as usize, gy.floor().max(0.0) as usize);
        let (tx, ty) = (gx - i as f64, gy - j as f64);
        let n = |i: usize, j: usize| values[(j.min(ny - 1)) * nx + i.min(nx - 1)];
        (n(i, j) * (1.0 - tx) + n(i + 1, j) * tx) * (1.0 - ty) + (n(i, j + 1) * (1.0 - tx) + n(i + 1, j + 1) * tx) * ty
    }
}

/// `slopes`: a ridge across the way, its flanks inclined 13-17° (tilt risk 0.2-0.47 for the
/// Husky's 10°-25° ramp), 0.6-0.8 m high with a 1 m crest, rounded over 0.8 m (no sharp
/// crest or foot), its far end capped by a flank of the same slope and walled off (a rock
/// wall 2 m high along it); beyond the wall 6-7 m of flat floor. Crossing it is ~5 m on the flanks; going round it ~8 m longer.
pub fn slopes(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let layout = Layout::draw(&mut rng);
    let crest_x = uni(&mut rng, 9.5, 10.5);
    let tan = uni(&mut rng, 13.0_f64.to_radians(), 17.0_f64.to_radians()).tan();
    let height = uni(&mut rng, 0.6, 0.8);
    let end = layout.band_end - height / tan;
    let noise = floor_noise(&mut rng, TRADEOFF_SIZE_M, 0.01);
    let sharp = move |x: f64, w: f64| (height - tan * ((x - crest_x).abs() - 0.5).max(0.0)).max(0.0).min(height - tan * (w - end).max(0.0)).max(0.0);
    let heights = sample(TRADEOFF_SIZE_M, GROUND_RESOLUTION_M, |x, y| {
        let w = layout.wall_distance(y);
        rounded(|x| sharp(x, w), x, 0.8).min(rounded(|w| sharp(x, w), w, 0.8)) + noise(x, y)
    });
    // A rock wall along the ridge's end, between it and the detour: the detour is a passage of
    // its own, and the ridge's far side is not seen past its end.
    let wall_w = layout.band_end + 0.3;
    let wall_y = if layout.side > 0.0 { wall_w } else { TRADEOFF_SIZE_M[1] - wall_w };
    let wall = boxed([0.5 * (BAND_X_M.0 + BAND_X_M.1), wall_y, 0.5], [BAND_X_M.1 - BAND_X_M.0 + 1.0, 0.4, 2.0], 0.0, "wall");
    let (start, goal) = ([START_X_M, layout.line_y], [GOAL_X_M, layout.line_y + uni(&mut rng, -0.5, 0.5)]);
    ground_world("slopes", TRADEOFF_SIZE_M, heights, vec![wall], start, goal)
}

/// `rough`: a rubble field across the way: 150-220 rounded rocks 4-10 cm high (below the
/// Husky's 0.13 m clearance; steps and roughness rate it 0.2-0.6), 0.15-0.3 m across,
/// packed into the band. Crossing it is 6 m of rubble; going round it ~8 m longer.
pub fn rough(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let layout = Layout::draw(&mut rng);
    let noise = floor_noise(&mut rng, TRADEOFF_SIZE_M, 0.01);
    let rocks: Vec<([f64; 2], f64, f64)> = (0..uni_count(&mut rng, 150, 220))
        .map(|_| {
            let w = uni(&mut rng, 0.0, layout.band_end);
            let y = if layout.side > 0.0 { w } else { TRADEOFF_SIZE_M[1] - w };
            ([uni(&mut rng, BAND_X_M.0, BAND_X_M.1), y], uni(&mut rng, 0.04, 0.10), uni(&mut rng, 0.075, 0.15))
        })
        .collect();
    let heights = sample(TRADEOFF_SIZE_M, GROUND_RESOLUTION_M, |x, y| {
        // The highest rock over the sample (rocks do not stack above their own height).
        let rock = rocks
            .iter()
            .filter(|(c, _, r)| (x - c[0]).abs() < 3.0 * r && (y - c[1]).abs() < 3.0 * r)
            .map(|&(c, h, r)| h * (-((x - c[0]).powi(2) + (y - c[1]).powi(2)) / (2.0 * r * r)).exp())
            .fold(0.0, f64::max);
        rock + noise(x, y)
    });
    let (start, goal) = ([START_X_M, layout.line_y], [GOAL_X_M, layout.line_y + uni(&mut rng, -0.5, 0.5)]);
    ground_world("rough", TRADEOFF_SIZE_M, heights, Vec::new(), start, goal)
}

/// `ledge`: across the way a rock mass (1.2 m high, near-vertical) on the closed side and a
/// trench (0.7-1.0 m deep, vertical sides: a drop) on the open side, with between them, on
/// the straight line, a ledge 2.0-2.4 m wide tilted 13-16° down toward the trench (tilt risk
/// 0.2-0.4), joined to the floor at both ends over 1 m. Beyond the trench 4-5 m of flat floor.
/// Crossing on the ledge is 6 m beside the drop; going round the trench ~8 m longer.
pub fn ledge(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let layout = Layout::draw(&mut rng);
    let width = uni(&mut rng, 2.0, 2.4);
    let tan = uni(&mut rng, 13.0_f64.to_radians(), 16.0_f64.to_radians()).tan();
    let depth = uni(&mut rng, 0.7, 1.0);
    let noise = floor_noise(&mut rng, TRADEOFF_SIZE_M, 0.01);
    let centre = layout.wall_distance(layout.line_y);
    let (inner, outer) = (centre - 0.5 * width, centre + 0.5 * width);
    let heights = sample(TRADEOFF_SIZE_M, GROUND_RESOLUTION_M, |x, y| {
        let w = layout.wall_distance(y);
        let (x0, x1) = BAND_X_M;
        if !(x0..=x1).contains(&x) || w > layout.band_end {
            return noise(x, y);
        }
        if w < inner {
            return 1.2;
        }
        if w > outer {
            return -depth;
        }
        // The ledge, tilted toward the trench, blended into the floor over 1 m at its ends.
        let blend = ((x - x0).min(x1 - x) / 1.0).clamp(0.0, 1.0);
        blend * tan * (centre - w) + noise(x, y)
    });
    let (start, goal) = ([START_X_M, layout.line_y], [GOAL_X_M, layout.line_y]);
    ground_world("ledge", TRADEOFF_SIZE_M, heights, Vec::new(), start, goal)
}

/// World size of `cave` [m]: x in [0, 24], y in [0, 12].
pub const CAVE_SIZE_M: [f64; 2] = [24.0, 12.0];

/// Holes start this far along the passage from the cave's start [m]: a Husky's lidar sees no
/// ground within its blind ring (2.35 m), plus the footprint's circumscribed radius (0.6 m)
/// and a margin; a hole closer than that could not be seen before the robot was over it.
pub const CAVE_START_CLEAR_M: f64 = 3.5;

/// `cave`: a winding passage 2.6-3.2 m wide from x = 2 to x = 22 (centreline `y = 6 + a·sin(2π
/// x / L + φ)`, a = 1.2-2.0 m, L = 12-16 m: the tightest bend's radius, at least 1.8 m,
/// exceeds half the width, so the walls never pinch the passage), walled by rock without
/// gaps (chains of boxes 2 m high along both sides),
/// its floor a few centimetres rough with 3-5 holes (NaN, radius 0.25-0.45 m) in it, each
/// off the centreline so that at least 1.2 m stays passable beside it.
pub fn cave(seed: u64) -> WorldSpec {
    let mut rng = Rng::seed_from_u64(seed);
    let [sx, sy] = CAVE_SIZE_M;
    let width = uni(&mut rng, 2.6, 3.2);
    let (amp, wavelength, phase) = (uni(&mut rng, 1.2, 2.0), uni(&mut rng, 12.0, 16.0), uni(&mut rng, 0.0, 2.0 * PI));
    let centre_y = move |x: f64| 0.5 * sy + amp * (2.0 * PI * x / wavelength + phase).sin();
    let slope = move |x: f64| amp * 2.0 * PI / wavelength * (2.0 * PI * x / wavelength + phase).cos();
    let (x0, x1) = (2.0, sx - 2.0);
    // Holes along the passage, kept from start, goal and each other: none within
    // CAVE_START_CLEAR_M of the start, where a lidar on the robot never sees the floor.
    let mut holes: Vec<([f64; 2], f64)> = Vec::new();
    for _ in 0..uni_count(&mut rng, 3, 5) {
        for _ in 0..200 {
            let x = uni(&mut rng, x0 + 1.2 + CAVE_START_CLEAR_M, x1 - 3.0);
            let r = uni(&mut rng, 0.25, 0.45);
            // Off the centreline: the far side keeps 1.2 m to the wall.
            let max_off = 0.5 * width - 0.2;
            let off = sign(&mut rng) * uni(&mut rng, (r + 1.2 - 0.5 * width).max(0.0), max_off - r);
            let n = (1.0 + slope(x).powi(2)).sqrt();
            let p = [x - off * slope(x) / n, centre_y(x) + off / n];
            if holes.iter().all(|&(q, rq)| (p[0] - q[0]).hypot(p[1] - q[1]) > r + rq + 2.0) {
                holes.push((p, r));
                break;
            }
        }
    }
    let noise = floor_noise(&mut rng, CAVE_SIZE_M, 0.015);
    let heights = sample(CAVE_SIZE_M, GROUND_RESOLUTION_M, |x, y| {
        if holes.iter().any(|&(p, r)| (x - p[0]).hypot(y - p[1]) <= r) {
            f64::NAN
        } else {
            noise(x, y)
        }
    });
    // Walls: on each side a chain of boxes 0.5 m thick whose inner faces follow the
    // passage's edge (the centreline offset by half the width) in chords of about 0.6 m,
    // each overlapping its neighbours by 0.25 m at both ends, so that no gap opens on the
    // outside of a bend (a rock wall, not a fence the lidar sees through).
    let mut walls = Vec::new();
    for side in [-1.0, 1.0] {
        let edge = |x: f64| {
            let n = (1.0 + slope(x).powi(2)).sqrt();
            let off = side * 0.5 * width;
            [x - off * slope(x) / n, centre_y(x) + off / n]
        };
        let mut last = edge(x0 - 0.5);
        let mut corners = vec![last];
        let mut x = x0 - 0.5;
        while x < x1 + 0.5 {
            x = (x + 0.01).min(x1 + 0.5);
            let p = edge(x);
            if (p[0] - last[0]).hypot(p[1] - last[1]) >= 0.6 || x >= x1 + 0.5 {
                corners.push(p);
                last = p;
            }
        }
        for pair in corners.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = dx.hypot(dy);
            // The chord's normal away from the passage (the side's offset direction).
            let (mut nx, mut ny) = (-dy / len, dx / len);
            if ny * side < 0.0 {
                (nx, ny) = (-nx, -ny);
            }
            let c = [0.5 * (a[0] + b[0]) + 0.25 * nx, 0.5 * (a[1] + b[1]) + 0.25 * ny, 0.75];
            walls.push(boxed(c, [len + 0.5, 0.5, 2.5], dy.atan2(dx), "wall"));
        }
    }
    // End caps behind start and goal.
    for x in [x0 - 0.5, x1 + 0.5] {
        walls.push(boxed([x, centre_y(x), 0.75], [0.5, width + 1.5, 2.5], slope(x).atan(), "wall"));
    }
    let (start, goal) = ([x0 + 1.2, centre_y(x0 + 1.2)], [x1 - 1.2, centre_y(x1 - 1.2)]);
    ground_world("cave", CAVE_SIZE_M, heights, walls, start, goal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(spec: &WorldSpec) -> &Vec<Vec<f64>> {
        &spec.heightfield.as_ref().unwrap().heights
    }

    fn height(spec: &WorldSpec, p: [f64; 2]) -> f64 {
        let h = grid(spec);
        h[(p[1] / GROUND_RESOLUTION_M).round() as usize][(p[0] / GROUND_RESOLUTION_M).round() as usize]
    }

    /// Largest slope [deg] of the height field between neighbouring samples over `[x0, x1] x [y0, y1]`.
    fn max_slope_deg(spec: &WorldSpec, x: (f64, f64), y: (f64, f64)) -> f64 {
        let h = grid(spec);
        let res = GROUND_RESOLUTION_M;
        let mut worst: f64 = 0.0;
        for r in ((y.0 / res) as usize)..((y.1 / res) as usize) {
            for c in ((x.0 / res) as usize)..((x.1 / res) as usize) {
                for (dr, dc) in [(0, 1), (1, 0)] {
                    let d = (h[r + dr][c + dc] - h[r][c]).abs();
                    if d.is_finite() {
                        worst = worst.max((d / res).atan().to_degrees());
                    }
                }
            }
        }
        worst
    }

    #[test]
    fn the_trade_off_worlds_are_seeded_and_differ_by_seed() {
        for f in [slopes as fn(u64) -> WorldSpec, rough, ledge, cave] {
            let (a, b, c) = (f(3), f(3), f(4));
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "{}", a.name);
            assert_ne!(format!("{a:?}"), format!("{c:?}"), "{}", a.name);
        }
    }

    #[test]
    fn the_slope_is_between_the_safe_and_lethal_tilt_and_the_detour_is_flat() {
        for seed in 0..10 {
            let s = slopes(seed);
            let start = s.regions[0].centre;
            // On the straight line across the ridge the flank reaches 13-17° (up to 2.5° more
            // between two samples from the floor's roughness); the gap beyond the band stays
            // below 3°.
            let worst = max_slope_deg(&s, (7.0, 13.0), (start[1] - 0.3, start[1] + 0.3));
            assert!((12.0..19.5).contains(&worst), "seed {seed}: {worst}");
            let gap = if start[1] < 8.0 { (13.5, 15.5) } else { (0.5, 2.5) };
            assert!(max_slope_deg(&s, (7.0, 13.0), gap) < 3.0, "seed {seed}");
        }
    }

    #[test]
    fn the_ledge_has_a_drop_on_one_side_and_a_wall_on_the_other() {
        for seed in 0..10 {
            let s = ledge(seed);
            let y = s.regions[0].centre[1];
            // Along the ledge's middle the floor is there; 1.5 m off to each side, a drop
            // deeper than 0.6 m and a wall higher than 1 m.
            let at = |dy: f64| height(&s, [10.0, y + dy]);
            assert!(at(0.0).abs() < 0.1, "seed {seed}: {}", at(0.0));
            let (lo, hi) = (at(-1.5).min(at(1.5)), at(-1.5).max(at(1.5)));
            assert!(lo < -0.6 && hi > 1.0, "seed {seed}: {lo} {hi}");
        }
    }

    #[test]
    fn the_rubble_stays_below_the_clearance() {
        for seed in 0..5 {
            let s = rough(seed);
            let top = grid(&s).iter().flatten().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
            assert!(top < 0.12, "seed {seed}: {top}");
        }
    }

    /// Whether `p` lies inside one of `spec`'s boxes (in the xy plane).
    fn in_a_box(spec: &WorldSpec, p: [f64; 2]) -> bool {
        spec.boxes.iter().any(|b| {
            let (dx, dy) = (p[0] - b.centre[0], p[1] - b.centre[1]);
            let (c, s) = (b.yaw.cos(), b.yaw.sin());
            (c * dx + s * dy).abs() <= 0.5 * b.size[0] && (-s * dx + c * dy).abs() <= 0.5 * b.size[1]
        })
    }

    #[test]
    fn the_cave_walls_have_no_gap() {
        // Flood the floor from the start on a 5 cm grid, through every point no box covers:
        // the flood stays in the passage (which never comes within 1.9 m of the world's
        // long sides) instead of leaking through a gap between wall boxes.
        let h = 0.05;
        let (nx, ny) = ((CAVE_SIZE_M[0] / h) as usize, (CAVE_SIZE_M[1] / h) as usize);
        for seed in 0..4 {
            let s = cave(seed);
            let start = s.regions[0].centre;
            let free: Vec<bool> = (0..nx * ny).map(|k| !in_a_box(&s, [(k % nx) as f64 * h + 0.5 * h, (k / nx) as f64 * h + 0.5 * h])).collect();
            let mut seen = vec![false; nx * ny];
            let first = ((start[1] / h) as usize) * nx + (start[0] / h) as usize;
            assert!(free[first], "seed {seed}: the start is inside a wall");
            let (mut stack, mut reached) = (vec![first], 0usize);
            seen[first] = true;
            while let Some(k) = stack.pop() {
                reached += 1;
                let (i, j) = (k % nx, k / nx);
                let y = j as f64 * h;
                assert!((1.0..CAVE_SIZE_M[1] - 1.0).contains(&y), "seed {seed}: the floor leaks out at ({}, {y})", i as f64 * h);
                for (di, dj) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                    let (a, b) = (i as i64 + di, j as i64 + dj);
                    if a < 0 || b < 0 || a >= nx as i64 || b >= ny as i64 {
                        continue;
                    }
                    let n = b as usize * nx + a as usize;
                    if free[n] && !seen[n] {
                        seen[n] = true;
                        stack.push(n);
                    }
                }
            }
            // The passage itself is open: 21 m of it between the end caps, 2.6-3.2 m wide.
            let area = reached as f64 * h * h;
            assert!((50.0..95.0).contains(&area), "seed {seed}: {area} m²");
        }
    }

    #[test]
    fn the_cave_has_holes_in_its_floor_and_a_clear_start_and_goal() {
        for seed in 0..10 {
            let s = cave(seed);
            let holes = grid(&s).iter().flatten().filter(|v| v.is_nan()).count();
            assert!(holes >= 3 * 15, "seed {seed}: {holes} hole samples");
            for r in &s.regions {
                assert!(height(&s, [r.centre[0], r.centre[1]]).is_finite(), "seed {seed}: {}", r.name);
            }
            // No hole within the start's clear zone (less its largest radius).
            let start = s.regions.iter().find(|r| r.name == "start").expect("a start region").centre;
            for (iy, row) in grid(&s).iter().enumerate() {
                for (ix, v) in row.iter().enumerate() {
                    if v.is_nan() {
                        let (x, y) = (ix as f64 * GROUND_RESOLUTION_M, iy as f64 * GROUND_RESOLUTION_M);
                        assert!((x - start[0]).abs() > CAVE_START_CLEAR_M - 0.5, "seed {seed}: a hole at ({x}, {y})");
                    }
                }
            }
        }
    }
}
