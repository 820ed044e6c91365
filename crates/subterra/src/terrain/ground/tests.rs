//! Tests of the ground segmentation: synthetic scans (flat ground, holes, pits, boxes, a
//! falling floor) and the internal helpers checked against their plain definitions.

use super::lines::LineSums;
use super::polar::{proto_key, sector_beside, sector_of};
use super::*;

/// A level lidar `H` above flat ground: rings every 0.5° of depression from 16.5° to
/// 1.5°, a column every 0.25° of azimuth; no return where `void(x, y)` (a hole with no
/// floor in range) and, where `wall(x, y)` gives a height, a vertical face up to it.
fn ring_scan(h: f64, void: impl Fn(f64, f64) -> bool, wall: impl Fn(f64, f64) -> Option<(f64, f64)>) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    for col in 0..1440 {
        let az = (col as f64 + 0.5) * 0.25f64.to_radians();
        let (sin, cos) = az.sin_cos();
        for ring in 0..31 {
            let d = (16.5 - 0.5 * ring as f64).to_radians();
            let r = h / d.tan();
            if let Some((wall_r, top)) = wall(cos, sin) {
                // The face at wall_r blocks rays below its top.
                let z = -wall_r * d.tan();
                if r >= wall_r && z <= top - h {
                    out.push([(wall_r * cos) as f32, (wall_r * sin) as f32, z as f32]);
                    continue;
                }
            }
            if !void(r * cos, r * sin) {
                out.push([(r * cos) as f32, (r * sin) as f32, -h as f32]);
            }
        }
    }
    out
}

#[test]
fn hole_whose_beams_come_back_from_below_the_ground_is_void() {
    // Regression (mine seed 16, "fall"): the beams that entered a hole came back from the
    // mine's wall 16 m away, 2-3 m below the floor; their ray spans covered the hole's
    // depressions, so it was taken for a shadow and rated drivable ground.
    let h = 0.76;
    let hole = |x: f64, y: f64| (x - 3.5).hypot(y) < 0.6;
    let mut points = ring_scan(h, hole, |_, _| None);
    for col in 0..1440 {
        let (sin, cos) = ((col as f64 + 0.5) * 0.25f64.to_radians()).sin_cos();
        for ring in 0..31 {
            let d = (16.5 - 0.5 * ring as f64).to_radians();
            if hole(h / d.tan() * cos, h / d.tan() * sin) {
                points.push([(16.0 * cos) as f32, (16.0 * sin) as f32, (-16.0 * d.tan()) as f32]);
            }
        }
    }
    let config = GroundConfig { void_min_gap_deg: crate::terrain::config::SPINNING_LIDAR_VOID_MIN_GAP_DEG, ..GroundConfig::default() };
    let mut seg = GroundSegmenter::new(config).unwrap();
    let mut heights = Vec::new();
    seg.segment(&points, h, &mut heights).unwrap();
    for (x, y) in [(3.5, 0.0), (3.1, 0.1), (3.9, -0.2)] {
        assert!(seg.query(x, y).unwrap().void, "hole at ({x}, {y}) not void");
    }
    for (x, y) in [(3.5, 1.0), (5.0, 0.0), (-2.0, 0.5), (0.0, 3.0)] {
        assert!(!seg.query(x, y).unwrap().void, "ground at ({x}, {y}) taken for void");
    }
}

/// A level lidar `h` above flat ground (rings as [`ring_scan`]) with a pit `depth` deep
/// between radii `near` and `near + 1.5` m for azimuths within 15° of +x, vertical sides:
/// rays over the near edge reach the floor or the far wall; behind a 0.3 m rock face 3 m
/// away along -x, the shadow of a rock.
fn pit_scan(h: f64, depth: f64, near: f64) -> Vec<[f32; 3]> {
    let far = near + 1.5;
    let mut out = Vec::new();
    for col in 0..1440 {
        let az = (col as f64 + 0.5) * 0.25f64.to_radians();
        let (sin, cos) = az.sin_cos();
        let pit = cos > 15f64.to_radians().cos();
        let rock = cos < -0.99 && sin.abs() < 0.1;
        for ring in 0..31 {
            let t = (16.5 - 0.5 * ring as f64).to_radians().tan();
            let r = h / t;
            let (r, z) = if pit && (near..=far).contains(&r) {
                let floor = (h + depth) / t;
                if floor <= far { (floor, -h - depth) } else { (far, -far * t) }
            } else if rock && r >= 3.0 && -3.0 * t <= 0.3 - h {
                (3.0, -3.0 * t)
            } else {
                (r, -h)
            };
            out.push([(r * cos) as f32, (r * sin) as f32, z as f32]);
        }
    }
    out
}

#[test]
fn the_ground_a_pit_edge_hides_is_as_deep_as_the_pit() {
    // Regression (mine seed 363, "fall"): the cells just past a pit's near edge had no
    // return, and the rays that grazed them, on their way to the far wall, passed barely
    // below the ground there: rated ground, the robot's corner went over the edge.
    let h = 0.7;
    let mut seg = GroundSegmenter::new(GroundConfig::default()).unwrap();
    let mut heights = Vec::new();
    seg.segment(&pit_scan(h, 0.5, 3.0), h, &mut heights).unwrap();
    let shadow = |x: f64, y: f64| seg.query(x, y).unwrap().shadow_depth;
    // Just past the edge, where the rays still pass within a few cm of the ground, and on.
    for (x, y) in [(3.05, 0.0), (3.15, 0.1), (3.5, -0.3), (4.2, 0.0)] {
        assert!(shadow(x, y) > 0.3, "pit at ({x}, {y}): shadow depth {}", shadow(x, y));
        assert!(seg.query(x, y).unwrap().ground_z - seg.query(x, y).unwrap().floor_bound_z < 0.13 || x > 3.5, "the rays alone rate ({x}, {y}) deep");
    }
    // Before the edge, beside the pit, between rings far off, behind the rock: none.
    for (x, y) in [(2.85, 0.0), (3.5, 2.5), (0.0, -9.0), (12.0, 6.0), (-3.3, 0.0), (-4.0, 0.1), (0.5, 0.5)] {
        assert!(shadow(x, y) < 0.03, "no drop at ({x}, {y}): shadow depth {}", shadow(x, y));
    }
    let mut off = GroundSegmenter::new(GroundConfig { drop_shadows: false, ..GroundConfig::default() }).unwrap();
    off.segment(&pit_scan(h, 0.5, 3.0), h, &mut heights).unwrap();
    assert_eq!(off.query(3.05, 0.0).unwrap().shadow_depth, 0.0);
    // The same pit 5 m out is seen at 8° (below the 10° default): it may be a slope the
    // robot could drive; at a 7° limit it is a drop's shadow.
    seg.segment(&pit_scan(h, 0.5, 5.0), h, &mut heights).unwrap();
    assert_eq!(seg.query(5.05, 0.0).unwrap().shadow_depth, 0.0);
    let mut shallow = GroundSegmenter::new(GroundConfig { drop_shadow_min_grazing_deg: 7.0, ..GroundConfig::default() }).unwrap();
    shallow.segment(&pit_scan(h, 0.5, 5.0), h, &mut heights).unwrap();
    let deep = shallow.query(5.05, 0.0).unwrap().shadow_depth;
    assert!(deep > 0.13, "{deep}");
    let err = GroundSegmenter::new(GroundConfig { drop_shadow_min_grazing_deg: 90.0, ..GroundConfig::default() }).unwrap_err().to_string();
    assert!(err.contains("drop_shadow_min_grazing_deg"), "{err}");
}

#[test]
fn hole_with_no_floor_is_void_and_a_rock_shadow_is_not() {
    // Regression: a bottomless hole (the mine's NaN holes) gave no return and no
    // negative evidence; the robot drove its wheels over it (mine seed 0, "fall").
    let h = 0.76;
    let hole = |x: f64, y: f64| (x - 3.5).hypot(y) < 0.6;
    // A 0.3 m rock face 3 m away along -x (its top 0.46 m below the sensor).
    let rock = |cos: f64, sin: f64| (cos < -0.99 && sin.abs() < 0.1).then_some((3.0, 0.3));
    let points = ring_scan(h, hole, rock);
    let mut heights = Vec::new();
    // Off by default: no bin is void.
    let mut off = GroundSegmenter::new(GroundConfig::default()).unwrap();
    off.segment(&points, h, &mut heights).unwrap();
    assert!(!off.query(3.5, 0.0).unwrap().void);
    let config = GroundConfig { void_min_gap_deg: crate::terrain::config::SPINNING_LIDAR_VOID_MIN_GAP_DEG, ..GroundConfig::default() };
    let mut seg = GroundSegmenter::new(config).unwrap();
    seg.segment(&points, h, &mut heights).unwrap();
    for (x, y) in [(3.5, 0.0), (3.1, 0.1), (3.9, -0.2)] {
        assert!(seg.query(x, y).unwrap().void, "hole at ({x}, {y}) not void");
    }
    // Plain ground beside the hole, beyond it, and opposite it; the rock's shadow.
    for (x, y) in [(3.5, 1.0), (5.0, 0.0), (-2.0, 0.5), (0.0, 3.0), (-4.0, 0.0), (-3.8, 0.1)] {
        assert!(!seg.query(x, y).unwrap().void, "ground at ({x}, {y}) taken for void");
    }
    let mut samples = Vec::new();
    seg.void_samples(&mut samples);
    assert!(!samples.is_empty());
    assert!(samples.iter().all(|p| (f64::from(p[0]) - 3.5).hypot(f64::from(p[1])) < 0.8), "void samples off the hole");
    // A coarser sensor: rings 2° apart (VLP-16) over the same ground leave no void.
    let sparse: Vec<[f32; 3]> = ring_scan(h, |_, _| false, |_, _| None).into_iter().enumerate().filter(|(i, _)| i % 31 % 4 == 0).map(|(_, p)| p).collect();
    seg.segment(&sparse, h, &mut heights).unwrap();
    samples.clear();
    seg.void_samples(&mut samples);
    assert!(samples.is_empty(), "{} void samples on flat ground seen by 2° rings", samples.len());
}

/// A level lidar `h` above the ground at its foot, `ground(x, y)` the ground's height
/// (vertical faces where it jumps): rings every 0.5° of depression from 16.5° to 1.5°, a
/// column every 0.5°, each return found by marching the ray in 5 mm steps.
fn heightfield_scan(h: f64, ground: impl Fn(f64, f64) -> f64) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    for col in 0..720 {
        let (sin, cos) = ((col as f64 + 0.5) * 0.5f64.to_radians()).sin_cos();
        for ring in 0..31 {
            let t = (16.5 - 0.5 * ring as f64).to_radians().tan();
            if let Some(r) = (1..8000).map(|i| f64::from(i) * 0.005).find(|&r| h - r * t <= ground(r * cos, r * sin)) {
                out.push([(r * cos) as f32, (r * sin) as f32, (-r * t) as f32]);
            }
        }
    }
    out
}

#[test]
fn ground_falling_away_in_the_blind_ring_is_ground_and_a_box_top_is_not() {
    // Regression (mine seed 8): the terrain ahead falls away (here 8.5°) from the robot's feet, so the
    // nearest ring meets it 0.25 m below -H; no line could start more than T_b = 0.2 m
    // from -H, every point up to the next rise was an obstacle (a lethal `collision` fan).
    let h = 0.7;
    let dip = |x: f64| -0.15 * x.max(0.0);
    // Behind the robot, a 0.3 m box 0.8 m deep.
    let boxed = |x: f64, y: f64| (-3.5..=-2.7).contains(&x) && y.abs() < 0.5;
    let points = heightfield_scan(h, |x, y| if boxed(x, y) { 0.3 } else { dip(x) });
    let mut seg = GroundSegmenter::new(GroundConfig::default()).unwrap();
    let mut heights = Vec::new();
    seg.segment(&points, h, &mut heights).unwrap();
    let (mut ahead_n, mut ahead_ground, mut top_n, mut top_ground) = (0, 0, 0, 0);
    for (p, &hg) in points.iter().zip(&heights) {
        let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        if x > 2.0 && y.abs() < 0.5 * x {
            ahead_n += 1;
            ahead_ground += usize::from(seg.is_ground(hg));
        }
        if boxed(x - 0.03, y) && z > 0.25 - h {
            top_n += 1;
            top_ground += usize::from(seg.is_ground(hg));
        }
    }
    assert!(ahead_n > 500 && ahead_ground == ahead_n, "{ahead_ground} of {ahead_n} points of the falling ground are ground");
    assert!(top_n > 20 && top_ground == 0, "{top_ground} of {top_n} box-top points are ground");
    // A level line more than T_b above the ground is no ground at any distance: a 0.3 m
    // high plateau beyond a 2 m gap with no returns (a trench whose floor is out of sight).
    let trench = heightfield_scan(h, |x, _| if x < 4.0 { 0.0 } else if x < 6.0 { -5.0 } else { 0.3 });
    seg.segment(&trench, h, &mut heights).unwrap();
    let plateau: Vec<bool> = trench.iter().zip(&heights).filter(|(p, _)| p[0] > 6.1 && p[1].abs() < 1.0).map(|(_, &hg)| seg.is_ground(hg)).collect();
    assert!(plateau.len() > 20 && plateau.iter().all(|&g| !g), "{} of {} plateau points ground", plateau.iter().filter(|&&g| g).count(), plateau.len());
}

fn flat_ring_cloud(height: f32) -> Vec<f32> {
    let mut flat = Vec::new();
    for ring in 0..12 {
        let r = 1.0 + ring as f32 * 0.7;
        for a in 0..360 {
            let t = (a as f32).to_radians();
            flat.extend_from_slice(&[r * t.cos(), r * t.sin(), -height]);
        }
    }
    flat
}

#[test]
fn flat_ground_is_all_ground() {
    let flat = flat_ring_cloud(0.6);
    let labels = segment_ground(&flat, &GroundConfig::default(), 0.6).unwrap();
    assert!(labels.iter().all(|&g| g));
}

#[test]
fn a_pole_above_flat_ground_is_obstacle() {
    let mut flat = flat_ring_cloud(0.6);
    let n_ground = flat.len() / 3;
    for i in 0..10 {
        flat.extend_from_slice(&[3.05, 0.05, -0.6 + 0.15 * (i + 1) as f32]);
    }
    let labels = segment_ground(&flat, &GroundConfig::default(), 0.6).unwrap();
    assert!(labels[..n_ground].iter().all(|&g| g));
    assert!(labels[n_ground..].iter().all(|&g| !g), "{:?}", &labels[n_ground..]);
}

#[test]
fn proto_keys_sort_as_lowest_then_first() {
    let zs = [-3.5f32, -1e-30, -0.0, 0.0, 1e-30, 0.25, 7.0, f32::MAX, f32::MIN];
    for (i, &a) in zs.iter().enumerate() {
        for (j, &b) in zs.iter().enumerate() {
            // Point 5 with z = a against point 9 with z = b: 5 wins iff a <= b.
            assert_eq!(proto_key(a, 5) < proto_key(b, 9), a <= b, "{a} {b}");
            assert_eq!(proto_key(a, i) == proto_key(b, j), a == b && i == j, "{a} {b}");
        }
    }
    assert_eq!(proto_key(-2.0, 7) as u32, 7);
}

#[test]
fn line_sums_fit_by_hand() {
    // z = 0.5 r - 1 through three points, then one 0.3 m off.
    let s = LineSums::start(1.0, -0.5).with(2.0, 0.0).with(3.0, 0.5);
    let (m, b, rmse) = s.fit().unwrap();
    assert!((m - 0.5).abs() < 1e-12 && (b + 1.0).abs() < 1e-12 && rmse < 1e-9);
    // Points (0,0), (1,0), (2,0.3): m = 0.15, b = -0.05, residuals 0.05, -0.1, 0.05.
    let (m, b, rmse) = LineSums::start(0.0, 0.0).with(1.0, 0.0).with(2.0, 0.3).fit().unwrap();
    assert!((m - 0.15).abs() < 1e-12 && (b + 0.05).abs() < 1e-12);
    assert!((rmse - (0.015f64 / 3.0).sqrt()).abs() < 1e-12);
}

#[test]
fn sectors_agree_with_libm_atan2() {
    let config = GroundConfig::default();
    let seg = GroundSegmenter::new(config).unwrap();
    let scale = config.sectors as f64 / std::f64::consts::TAU;
    let exact = |x: f64, y: f64| (((y.atan2(x) + std::f64::consts::PI) * scale) as usize).min(config.sectors as usize - 1);
    let mut state = 12345u64;
    for i in 0..200_000 {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let a = (state >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::TAU - std::f64::consts::PI;
        // Every 4th point sits within 1e-9 rad of a sector boundary.
        let a = if i % 4 == 0 { -std::f64::consts::PI + ((a + std::f64::consts::PI) * scale).round() / scale + 1e-9 * a.signum() } else { a };
        let r = 0.5 + (i % 97) as f64 * 0.3;
        let (x, y) = (r * a.cos(), r * a.sin());
        assert_eq!(seg.sector_of(x, y, scale), exact(x, y), "angle {a}");
    }
}

#[test]
fn sector_beside_agrees_with_sector_of() {
    let mut state = 777u64;
    let mut next = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for sectors in [8u32, 9, 360, 720, 100_000] {
        let config = GroundConfig { sectors, max_range_m: 10.0, bin_m: 5.0, ..GroundConfig::default() };
        let seg = GroundSegmenter::new(config).unwrap();
        let scale = sectors as f64 / std::f64::consts::TAU;
        let edges = &seg.sector_edges;
        let mut found = 0;
        for i in 0..100_000 {
            let a = next() * std::f64::consts::TAU - std::f64::consts::PI;
            // Every 3rd point sits within 1e-12 rad of a sector boundary; some on the axes.
            let a = match i % 3 {
                0 => -std::f64::consts::PI + ((a + std::f64::consts::PI) * scale).round() / scale + 1e-12 * (next() - 0.5),
                1 if i % 300 == 1 => (i % 8) as f64 * std::f64::consts::FRAC_PI_4 - std::f64::consts::PI,
                _ => a,
            };
            let r = 0.5 + 9.0 * next();
            let (x, y) = (r * a.cos(), r * a.sin());
            let exact = sector_of(edges, x, y, scale);
            for near in [exact.wrapping_sub(2), exact.wrapping_sub(1), exact, exact + 1, exact + 2, 0, sectors as usize - 1, usize::MAX] {
                if let Some(s) = sector_beside(edges, near, x, y) {
                    assert_eq!(s, exact, "sectors {sectors}, angle {a}, near {near}");
                    found += 1;
                }
            }
        }
        assert!(found > 200_000, "{found}");
    }
}

#[test]
fn query_row_is_query() {
    let mut flat = flat_ring_cloud(0.6);
    flat.extend_from_slice(&[3.0, 0.1, -0.2, -2.0, 4.0, -1.4, 0.0, -5.0, -0.9]);
    let points = as_points("points", &flat).unwrap();
    let mut seg = GroundSegmenter::new(GroundConfig::default()).unwrap();
    let mut heights = Vec::new();
    seg.segment(points, 0.6, &mut heights).unwrap();
    let xs: Vec<f64> = (0..500).map(|i| -45.0 + i as f64 * 0.18 + 0.001).collect();
    for j in 0..300 {
        let y = -45.0 + j as f64 * 0.3;
        let mut got = Vec::new();
        seg.query_row(&xs, y, |i, bin| got.push((i, bin)));
        let want: Vec<_> = xs.iter().enumerate().filter_map(|(i, &x)| seg.query(x, y).map(|bin| (i, bin))).collect();
        assert_eq!(got, want);
    }
}

/// Step 4 bin by bin, as `segment_ground`'s docs state it.
fn assign_by_bin(lines: &[GroundLine], bins: usize, h: f64) -> Vec<BinLine> {
    (0..bins)
        .map(|k| {
            if lines.is_empty() {
                return BinLine { b: -h, ..BinLine::NONE };
            }
            let first = &lines[0];
            if k < first.first_bin as usize && first.first_r_m > 0.0 {
                // From the ground under the sensor to the first line's first prototype.
                return BinLine { m: (first.m * first.first_r_m + first.b + h) / first.first_r_m, b: -h, ..BinLine::NONE };
            }
            if let Some(line) = lines.iter().find(|l| l.first_bin as usize <= k && k <= l.last_bin as usize) {
                return BinLine::of(line, true);
            }
            let dist = |l: &GroundLine| if k < l.first_bin as usize { l.first_bin as usize - k } else { k - l.last_bin as usize };
            let nearest = lines.iter().min_by_key(|l| dist(l)).unwrap();
            BinLine::of(nearest, false)
        })
        .collect()
}

#[test]
fn bin_lines_by_range_match_bin_by_bin() {
    let config = GroundConfig { sectors: 1, ..GroundConfig::default() };
    let mut seg = GroundSegmenter::new(config).unwrap();
    let bins = seg.bins;
    seg.sensor_height_m = 0.6;
    let mut state = 99u64;
    let mut next = |n: usize| {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 33) % n as u64) as usize
    };
    for trial in 0..3000 {
        // Lines in bin order, each starting at or after the previous one's last bin and
        // spanning two bins or more (min_line_points >= 2 prototypes, one per bin).
        let mut lines = Vec::new();
        let mut at = if trial % 3 == 0 { 0 } else { next(12) };
        while at + 1 < bins && lines.len() < 1 + trial % 7 {
            let first = at;
            let last = (first + [1, 2, 5, 30][next(4)]).min(bins - 1);
            let m = lines.len() as f64 * 0.01 + trial as f64 * 1e-4;
            lines.push(GroundLine { m, b: -0.5 - m, first_bin: first as u32, last_bin: last as u32, first_r_m: first as f64 * 0.2 + 0.05, last_r_m: last as f64 * 0.2 + 0.1 });
            // Shared break bin, adjacent, or a gap (odd and even widths).
            at = last + [0, 1, 2, 3, 8, 15][next(6)];
        }
        seg.lines = lines.clone();
        seg.bin_lines.clear();
        seg.sector_lines[0] = (0, lines.len() as u32);
        seg.assign_lines(0);
        let want = assign_by_bin(&lines, bins, 0.6);
        for (k, b) in want.iter().enumerate() {
            let a = &seg.bin_lines[seg.bin_line[k] as usize];
            let bits = |l: &BinLine| [l.m.to_bits(), l.b.to_bits(), l.cover_lo.to_bits(), l.cover_hi.to_bits()];
            assert_eq!(bits(a), bits(b), "trial {trial}, bin {k}, lines {lines:?}");
        }
    }
}

#[test]
fn fast_atan2_is_close() {
    for i in 0..1000 {
        let t = i as f64 * 0.0123 - 6.0;
        let (y, x) = (t.sin() * 3.0, t.cos() * 3.0);
        assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{t}");
    }
}

#[test]
fn wrong_inputs_name_their_argument() {
    assert!(segment_ground(&[1.0, 2.0], &GroundConfig::default(), 0.5).unwrap_err().to_string().contains("points"));
    assert!(segment_ground(&[1.0, 2.0, 3.0], &GroundConfig::default(), f64::NAN).unwrap_err().to_string().contains("sensor_height_m"));
    // Probe finding: 1e308, -5 and 5e-324 m were taken; the CLI's bounds hold here too.
    for h in [1e308, -5.0, 5e-324, MAX_SENSOR_HEIGHT_M * 1.01] {
        assert!(segment_ground(&[1.0, 2.0, 3.0], &GroundConfig::default(), h).unwrap_err().to_string().contains("sensor_height_m"));
    }
    let config = GroundConfig { sectors: 0, ..GroundConfig::default() };
    assert!(segment_ground(&[], &config, 0.5).unwrap_err().to_string().contains("ground.sectors"));
}
