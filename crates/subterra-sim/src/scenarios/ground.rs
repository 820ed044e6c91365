//! The ground-robot scenarios, region centres on the ground: the [`mine`] (a height field
//! with holes, heaps, pits and a free corridor) and the [`subway`] island platform.

use std::f64::consts::{PI, TAU};

use rand::{RngExt, SeedableRng};

use super::helpers::{boxed, dist2, dist_point_polyline2, perimeter_walls, plane, region, route, sign, uni, uni_count, Rng, MAX_ATTEMPTS, WALL_THICKNESS_M};
use crate::spec::{CylinderSpec, HeightFieldSpec, ItemSpec, SphereSpec, WorldSpec};

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
pub(super) struct MineLayout {
    pub(super) spec: WorldSpec,
    /// Centreline of the free corridor from start to goal [m].
    #[cfg_attr(not(test), allow(dead_code))]
    pub(super) corridor: Vec<[f64; 2]>,
}

/// Samples of the terrain grid; `x = c·res`, `y = r·res` (origin at 0, 0).
pub(super) struct Grid {
    pub(super) heights: Vec<Vec<f64>>,
    pub(super) res: f64,
}

impl Grid {
    /// Bilinear height at (x, y); NaN outside the grid or where a sample with a non-zero
    /// weight is a hole.
    pub(super) fn at(&self, x: f64, y: f64) -> f64 {
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

pub(super) fn mine_layout(seed: u64) -> MineLayout {
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
