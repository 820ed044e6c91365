//! Terrain risk on synthetic scenes with known answers: a simulated spinning lidar is cast
//! analytically against flat ground, boxes, ramps and pits, and each risk layer must say
//! what the geometry implies.

mod terrain_sim;

use terrain_sim::{mount, pose, Aabb, Lidar, Scene};
use glam::{DVec2, DVec3};
use subterra::terrain::{GridGeometry, Layer, MissionItem, RiskMap, TerrainMapper, TerrainOutput};
use subterra::{Isometry3, RobotConfig, TerrainConfig};

fn config_unknown() -> f64 {
    TerrainConfig::default().risk.unknown
}

fn map_scene(scene: &Scene, config: TerrainConfig) -> TerrainOutput {
    let world_from_body = pose(0.0, 0.0, 0.0);
    let points = Lidar::dense().scan(scene, &world_from_body.compose(&mount()));
    let mut mapper = TerrainMapper::new(RobotConfig::default(), config).unwrap();
    mapper.update(&points, 0.0, &world_from_body, &mount(), 1.0).unwrap()
}

/// Cells whose centre lies inside `[x0, x1] x [y0, y1]` grown by `margin` [m].
fn in_rect(g: &GridGeometry, flat: usize, (x0, x1, y0, y1): (f64, f64, f64, f64), margin: f64) -> bool {
    let c = g.centre_of(g.cell_at(flat));
    c.x >= x0 - margin && c.x <= x1 + margin && c.y >= y0 - margin && c.y <= y1 + margin
}

fn cells_where(map: &RiskMap, layer: Layer, pred: impl Fn(f32) -> bool) -> Vec<usize> {
    map.get(layer).iter().enumerate().filter(|(_, &v)| pred(v)).map(|(i, _)| i).collect()
}

fn assert_all_risks_in_unit_interval(map: &RiskMap) {
    for layer in Layer::RISKS.iter().chain(&[Layer::Risk]) {
        assert!(map.get(*layer).iter().all(|v| (0.0..=1.0).contains(v)), "{} leaves [0, 1]", layer.name());
    }
    assert!(map.get(Layer::RiskVariance).iter().all(|v| v.is_finite() && *v >= 0.0));
}

#[test]
fn flat_ground_is_all_ground_and_safe() {
    let out = map_scene(&Scene::default(), TerrainConfig::default());
    assert_eq!(out.stats.obstacle_points, 0, "{:?}", out.stats);
    assert!(out.stats.ground_points > 20_000);
    for map in [&out.coarse, out.fine.as_ref().unwrap()] {
        let observed = cells_where(map, Layer::Observed, |v| v > 0.0);
        assert!(observed.len() > map.geometry().cells() / 2, "{} of {} observed", observed.len(), map.geometry().cells());
        let worst = observed.iter().map(|&c| map.get(Layer::Risk)[c]).fold(0.0f32, f32::max);
        assert!(worst < 0.05, "worst observed risk on flat ground {worst}");
        assert_all_risks_in_unit_interval(map);
    }
}

#[test]
fn a_box_is_lethal_exactly_under_it() {
    let rect = (3.0, 3.6, -0.3, 0.3);
    let scene = Scene { boxes: vec![Aabb { min: DVec3::new(rect.0, rect.2, 0.0), max: DVec3::new(rect.1, rect.3, 0.3) }], ..Scene::default() };
    let out = map_scene(&scene, TerrainConfig::default());
    for map in [&out.coarse, out.fine.as_ref().unwrap()] {
        let g = *map.geometry();
        let lethal = cells_where(map, Layer::Collision, |v| v >= 1.0);
        assert!(!lethal.is_empty());
        for &c in &lethal {
            assert!(in_rect(&g, c, rect, g.resolution_m), "lethal collision cell at {:?} outside the box", g.centre_of(g.cell_at(c)));
        }
        // Every cell under the box that the lidar saw (two points or more) is lethal; the
        // rest of the top is hidden from a sensor 0.6 m high and stays unobserved.
        let under = (0..g.cells()).filter(|&c| in_rect(&g, c, rect, -g.resolution_m / 2.0)).collect::<Vec<_>>();
        let seen = under.iter().filter(|&&c| map.get(Layer::Count)[c] >= 2.0).collect::<Vec<_>>();
        assert!(seen.len() * 10 >= under.len(), "{} of {} cells under the box seen", seen.len(), under.len());
        for &&c in &seen {
            assert!(map.get(Layer::Collision)[c] >= 1.0, "seen cell at {:?} under the box not lethal", g.centre_of(g.cell_at(c)));
        }
        for &c in &under {
            assert!(map.get(Layer::Risk)[c] >= config_unknown() as f32 - 1e-6, "cell at {:?} under the box looks safe (res {})", g.centre_of(g.cell_at(c)), g.resolution_m);
        }
        assert_all_risks_in_unit_interval(map);
    }
}

fn ramp_tilt_values(angle_deg: f64) -> Vec<f32> {
    let scene = Scene { ramp_angle: angle_deg.to_radians(), ramp_start_x: 3.0, ..Scene::default() };
    let out = map_scene(&scene, TerrainConfig::default());
    let map = &out.coarse;
    assert_all_risks_in_unit_interval(map);
    let g = *map.geometry();
    // Cells well onto the ramp (the footprint entirely on it) and near the sensor's axis.
    (0..g.cells()).filter(|&c| in_rect(&g, c, (4.0, 6.0, -1.5, 1.5), 0.0) && map.get(Layer::Observed)[c] > 0.0).map(|c| map.get(Layer::Tilt)[c]).collect()
}

#[test]
fn a_15_degree_ramp_gives_the_tilt_ramp_value() {
    let values = ramp_tilt_values(15.0);
    assert!(values.len() > 100, "{} ramp cells", values.len());
    // Ramp 10° -> 25°: 15° is one third.
    let expected = (15.0 - 10.0) / (25.0 - 10.0);
    let mut sorted = values.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2];
    assert!((median - expected).abs() < 0.05, "median tilt risk {median}, expected {expected}");
    let close = values.iter().filter(|v| (**v - expected).abs() < 0.1).count();
    assert!(close * 10 >= values.len() * 9, "{close} of {} within 0.1", values.len());
}

#[test]
fn a_30_degree_ramp_is_lethal() {
    let values = ramp_tilt_values(30.0);
    assert!(values.len() > 50, "{} ramp cells", values.len());
    let lethal = values.iter().filter(|&&v| v >= 1.0).count();
    assert!(lethal * 10 >= values.len() * 9, "{lethal} of {} lethal", values.len());
}

fn pit_scene(depth: f64) -> (Scene, (f64, f64, f64, f64)) {
    let rect = (4.0, 5.5, -0.75, 0.75);
    (Scene { pits: vec![Aabb { min: DVec3::new(rect.0, rect.2, -depth), max: DVec3::new(rect.1, rect.3, 0.0) }], ..Scene::default() }, rect)
}

#[test]
fn a_deep_hole_is_lethal_and_a_shallow_dip_is_not() {
    let (scene, rect) = pit_scene(0.5);
    let out = map_scene(&scene, TerrainConfig::default());
    // The hole is beyond the fine map's 4 m reach: the coarse map sees it.
    for map in [&out.coarse] {
        let g = *map.geometry();
        let lethal = cells_where(map, Layer::Negative, |v| v >= 1.0);
        assert!(lethal.len() >= 5, "{} lethal negative cells", lethal.len());
        for &c in &lethal {
            assert!(in_rect(&g, c, rect, g.resolution_m), "lethal negative cell at {:?} outside the hole", g.centre_of(g.cell_at(c)));
        }
        assert_all_risks_in_unit_interval(map);
    }
    let (scene, _) = pit_scene(0.05);
    let out = map_scene(&scene, TerrainConfig::default());
    for map in [&out.coarse, out.fine.as_ref().unwrap()] {
        let worst = map.get(Layer::Negative).iter().fold(0.0f32, |a, &b| a.max(b));
        assert!(worst < 0.5, "a 5 cm dip gives negative risk {worst}");
        let lethal = cells_where(map, Layer::Risk, |v| v >= 1.0);
        assert!(lethal.is_empty(), "{} lethal cells around a 5 cm dip", lethal.len());
    }
}

#[test]
fn cells_beyond_the_sensors_reach_are_unknown() {
    let mut config = TerrainConfig::default();
    config.prefilter.max_range_m = 5.0;
    let out = map_scene(&Scene::default(), config);
    let map = &out.coarse;
    let g = *map.geometry();
    let unknown_value = config.risk.unknown as f32;
    let mut far = 0;
    for c in 0..g.cells() {
        if g.centre_of(g.cell_at(c)).length() > 6.0 {
            far += 1;
            assert_eq!(map.get(Layer::Observed)[c], 0.0);
            assert_eq!(map.get(Layer::Unknown)[c], unknown_value);
            assert_eq!(map.get(Layer::Risk)[c], unknown_value);
        }
    }
    assert!(far > 10_000);
    assert!(unknown_value > 0.0 && unknown_value < 1.0);
}

#[test]
fn a_mission_item_makes_a_lethal_circle_of_its_radius() {
    let world_from_body = pose(0.0, 0.0, 0.0);
    let points = Lidar::dense().scan(&Scene::default(), &world_from_body.compose(&mount()));
    let mut mapper = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
    let item = MissionItem { position_world: DVec2::new(2.0, 3.0), radius_m: 1.0 };
    mapper.set_mission_items(&[item]).unwrap();
    let out = mapper.update(&points, 0.0, &world_from_body, &mount(), 1.0).unwrap();
    let map = &out.coarse;
    let g = *map.geometry();
    let mut inside = 0;
    for c in 0..g.cells() {
        let d = (g.centre_of(g.cell_at(c)) - item.position_world).length();
        let m = map.get(Layer::Mission)[c];
        if d <= item.radius_m {
            inside += 1;
            assert_eq!(m, 1.0);
            assert_eq!(map.get(Layer::Risk)[c], 1.0);
        } else {
            assert_eq!(m, 0.0, "mission risk {m} at {d} m");
        }
    }
    // π r² / res² ≈ 314 cells.
    assert!((300..330).contains(&inside), "{inside} cells inside");
    assert_eq!(map.risk_at(2.0, 3.0), Some(1.0));
    assert_eq!(map.risk_at(100.0, 0.0), None);
}

#[test]
fn risk_stays_in_the_unit_interval_on_random_scenes() {
    // A small seeded generator (xorshift) of boxes and pits around the robot.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..4 {
        let mut scene = Scene { ramp_angle: (next() * 20.0 - 5.0).to_radians(), ramp_start_x: 2.0 + next() * 5.0, ..Scene::default() };
        for _ in 0..4 {
            let (x, y) = (next() * 16.0 - 8.0, next() * 16.0 - 8.0);
            if x.abs() < 1.5 && y.abs() < 1.5 {
                continue;
            }
            let (w, h) = (0.2 + next(), 0.05 + next());
            let b = Aabb { min: DVec3::new(x, y, -h), max: DVec3::new(x + w, y + w, h) };
            if next() < 0.5 {
                scene.boxes.push(b);
            } else {
                scene.pits.push(Aabb { max: DVec3::new(x + w, y + w, 0.0), ..b });
            }
        }
        let out = map_scene(&scene, TerrainConfig::default());
        assert_all_risks_in_unit_interval(&out.coarse);
        assert_all_risks_in_unit_interval(out.fine.as_ref().unwrap());
        for alpha in [0.5, 0.9, 0.99] {
            assert!(out.coarse.cvar(alpha).unwrap().iter().zip(out.coarse.get(Layer::Risk)).all(|(c, r)| (0.0..=1.0).contains(c) && c >= r));
        }
    }
}

/// A wall seen from `world_from_body`: the global indices of its lethal collision cells.
fn wall_cells(world_from_body: &Isometry3, mapper: &mut TerrainMapper, stamp: f64, confidence: f64) -> (TerrainOutput, Vec<(i64, i64)>) {
    let scene = Scene { boxes: vec![Aabb { min: DVec3::new(4.04, -2.0, 0.0), max: DVec3::new(4.34, 2.0, 1.0) }], ..Scene::default() };
    let points = Lidar::dense().scan(&scene, &world_from_body.compose(&mount()));
    let out = mapper.update(&points, stamp, world_from_body, &mount(), confidence).unwrap();
    let g = *out.coarse.geometry();
    let cells = cells_where(&out.coarse, Layer::Collision, |v| v >= 1.0)
        .into_iter()
        .map(|c| {
            let i = g.cell_at(c);
            (i.ix as i64 + g.origin_cell.0, i.iy as i64 + g.origin_cell.1)
        })
        .collect();
    (out, cells)
}

#[test]
fn a_wall_seen_from_two_poses_lands_in_the_same_cells() {
    let a = pose(0.03, 0.02, 0.0);
    let b = pose(1.27, -0.61, 0.35);
    let (_, from_a) = wall_cells(&a, &mut TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap(), 0.0, 1.0);
    let (_, from_b) = wall_cells(&b, &mut TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap(), 0.0, 1.0);
    // The wall's face: 40 cells along y.
    assert!(from_a.len() >= 35, "{} wall cells", from_a.len());
    let common = from_a.iter().filter(|c| from_b.contains(c)).count();
    let union = from_a.len() + from_b.len() - common;
    assert!(common * 10 >= union * 8, "{common} common of {union}");
    // Every lethal cell is on the wall (x in [4, 4.3], |y| <= 2), from both poses.
    for &(gx, gy) in from_a.iter().chain(&from_b) {
        let (x, y) = ((gx as f64 + 0.5) * 0.1, (gy as f64 + 0.5) * 0.1);
        assert!((3.9..=4.4).contains(&x) && y.abs() <= 2.1, "wall cell at ({x}, {y})");
    }
    // Fused: the second scan re-expressed in the first's cells adds no smear.
    let mut mapper = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
    wall_cells(&a, &mut mapper, 0.0, 1.0);
    let (out, fused) = wall_cells(&b, &mut mapper, 0.1, 1.0);
    assert_eq!(out.stats.fused_scans, 2);
    for &(gx, gy) in &fused {
        let (x, y) = ((gx as f64 + 0.5) * 0.1, (gy as f64 + 0.5) * 0.1);
        assert!((3.9..=4.4).contains(&x) && y.abs() <= 2.1, "fused wall cell at ({x}, {y})");
    }
}

#[test]
fn confidence_zero_uses_only_the_newest_scan() {
    let world_from_body = pose(0.0, 0.0, 0.0);
    let with_box = Scene { boxes: vec![Aabb { min: DVec3::new(3.0, -0.5, 0.0), max: DVec3::new(3.5, 0.5, 0.5) }], ..Scene::default() };
    let old = Lidar::dense().scan(&with_box, &world_from_body.compose(&mount()));
    let new = Lidar::dense().scan(&Scene::default(), &world_from_body.compose(&mount()));
    let lethal = |out: &TerrainOutput| cells_where(&out.coarse, Layer::Collision, |v| v >= 1.0).len();
    for (confidence, fused, box_seen) in [(1.0, 2, true), (0.0, 1, false)] {
        let mut mapper = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
        mapper.update(&old, 0.0, &world_from_body, &mount(), 1.0).unwrap();
        let out = mapper.update(&new, 0.1, &world_from_body, &mount(), confidence).unwrap();
        assert_eq!(out.stats.fused_scans, fused);
        assert_eq!(lethal(&out) > 0, box_seen, "confidence {confidence}: {} lethal cells", lethal(&out));
        // The fine map is the newest scan alone whatever the confidence.
        assert_eq!(cells_where(out.fine.as_ref().unwrap(), Layer::Collision, |v| v >= 1.0).len(), 0);
    }
}
