//! Tests of the scenario generators: their helpers against hand values, every scenario's
//! layout against the papers' numbers, and the worlds `World::from_spec` builds from them.

use std::f64::consts::TAU;

use super::*;
use super::aerial::{centreline_at, tunnel_layout, TUNNEL_SEGMENT_M};
use super::ground::{mine_layout, Grid};
use super::helpers::{dist2, dist_point_polyline2, dist_point_segment2, perimeter_walls, route};
use crate::spec::{BoxSpec, CapsuleSpec, CylinderSpec, ItemSpec, RegionSpec};

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
            for b in &spec.boxes {
                assert!(box_dist(q, b) >= 1.0, "seed {seed} s {s}: {} {} m", b.tag, box_dist(q, b));
            }
            for r in &spec.spheres {
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
