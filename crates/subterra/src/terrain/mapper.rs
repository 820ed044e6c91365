//! The terrain pipeline of one robot: cloud -> prefilter -> ground labels -> fusion window
//! -> a fine map from the newest scan and a coarse map from the fused window.

use std::time::Instant;

use glam::{Mat3, Vec3};

use super::cloud::{as_points, Prefilter, PrefilterStats};
use super::config::{RobotConfig, TerrainConfig};
use super::fusion::{check_rigid, ScanWindow};
use super::grid::RiskMap;
use super::ground::GroundSegmenter;
use super::risk::{BinnedSource, MapBuilder, MissionItem, NewestPolar, ScanSource};
use crate::error::{Error, Result};
use crate::frames::Isometry3;

/// Most cells of the scratch map a fusion window's scans are binned into (about 40 bytes each).
const MAX_SCRATCH_CELLS: f64 = 25_000_000.0;

/// Most keep-out circles of the `mission` layer. Every map update stamps each circle, so
/// 10^6 of them cost seconds per update; a mission plan holds tens.
pub const MAX_MISSION_ITEMS: usize = 10_000;

/// Wall-clock time of each stage of one update \[s\].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TerrainTimings {
    /// Prefilter and transform into world-aligned axes.
    pub prefilter_s: f64,
    /// Ground segmentation.
    pub segment_s: f64,
    /// The coarse fused map (binning the new scan once, merging the window, the layers).
    pub coarse_s: f64,
    /// The fine map.
    pub fine_s: f64,
    /// The whole update.
    pub total_s: f64,
}

/// Counts of one update.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TerrainStats {
    /// What the prefilter dropped and kept.
    pub prefilter: PrefilterStats,
    /// Points of the newest scan labelled ground.
    pub ground_points: usize,
    /// Points of the newest scan labelled obstacle.
    pub obstacle_points: usize,
    /// Scans fused into the coarse map.
    pub fused_scans: usize,
    /// Points of the fused scans.
    pub fused_points: usize,
}

/// What one update gives.
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainOutput {
    /// The coarse, long-range map from the fused window (for the planner).
    pub coarse: RiskMap,
    /// The fine, short-range map from the newest scan (for the tracker), if enabled.
    pub fine: Option<RiskMap>,
    /// Counts.
    pub stats: TerrainStats,
    /// Stage timings.
    pub timings: TerrainTimings,
}

/// Terrain risk mapping for one ground robot and one sensor stream.
#[derive(Debug, Clone)]
pub struct TerrainMapper {
    robot: RobotConfig,
    config: TerrainConfig,
    prefilter: Prefilter,
    segmenter: GroundSegmenter,
    window: ScanWindow,
    coarse: MapBuilder,
    fine: Option<MapBuilder>,
    missions: Vec<MissionItem>,
    body_points: Vec<[f32; 3]>,
    /// Scratch: the newest scan's void samples (missing floor).
    voids: Vec<[f32; 2]>,
}

impl TerrainMapper {
    /// Validates both configs and sizes the buffers.
    pub fn new(robot: RobotConfig, config: TerrainConfig) -> Result<Self> {
        robot.validate()?;
        config.validate()?;
        for (name, map, on) in [("coarse", config.coarse, true), ("fine", config.fine, config.fine_enabled)] {
            let (nx, ny) = MapBuilder::scratch_map(&map, &robot, config.fusion.window_s).cells();
            if on && (nx as f64) * (ny as f64) > MAX_SCRATCH_CELLS {
                return Err(Error::config(
                    "fusion.window_s",
                    format!(
                        "with robot.max_speed_m_s = {} the {name} map's scans are binned on {nx}x{ny} cells (the map grown by the distance driven in the window); at most {MAX_SCRATCH_CELLS:.0}",
                        robot.max_speed_m_s
                    ),
                    config.fusion.window_s,
                ));
            }
        }
        let thr = config.ground.max_dist_to_line_m;
        let builder = |map| MapBuilder::new(map, robot, config.layers, config.risk, config.uncertainty, thr, config.fusion.window_s);
        Ok(Self {
            robot,
            config,
            prefilter: Prefilter::new(config.prefilter, &robot),
            segmenter: GroundSegmenter::new(config.ground)?,
            window: ScanWindow::new(config.fusion),
            coarse: builder(config.coarse),
            fine: config.fine_enabled.then(|| builder(config.fine)),
            missions: Vec::new(),
            body_points: Vec::new(),
            voids: Vec::new(),
        })
    }

    /// The robot model.
    pub fn robot(&self) -> &RobotConfig {
        &self.robot
    }

    /// The config.
    pub fn config(&self) -> &TerrainConfig {
        &self.config
    }

    /// Replaces the mission items whose keep-out circles make the `mission` layer.
    pub fn set_mission_items(&mut self, items: &[MissionItem]) -> Result<()> {
        if items.len() > MAX_MISSION_ITEMS {
            return Err(Error::input("items", format!("{} items: more than {MAX_MISSION_ITEMS}, the most accepted", items.len())));
        }
        for (i, item) in items.iter().enumerate() {
            if !item.position_world.is_finite() {
                return Err(Error::input("items", format!("item {i} has a non-finite position {:?}", item.position_world)));
            }
            if !(item.radius_m.is_finite() && item.radius_m >= 0.0) {
                return Err(Error::input("items", format!("item {i} has radius {} m; must be finite and >= 0", item.radius_m)));
            }
        }
        self.missions = items.to_vec();
        Ok(())
    }

    /// Forgets every scan (the recovery behaviour "clear the map").
    pub fn reset(&mut self) {
        self.window.clear();
    }

    /// Scans held in the fusion window.
    pub fn window_len(&self) -> usize {
        self.window.len()
    }

    /// The newest scan's kept points relative to the body origin, world-aligned axes \[m\],
    /// and each one's height above its ground line \[m\] (ground iff within
    /// `ground.max_dist_to_line_m`; NaN: no line).
    pub fn newest_points_level(&self) -> Option<(Vec<[f32; 3]>, &[f32])> {
        let scan = self.window.newest()?;
        let s = scan.sensor_level.as_vec3();
        Some((scan.points.iter().map(|p| (Vec3::from_array(*p) + s).to_array()).collect(), &scan.heights))
    }

    /// Adds one scan and returns the maps.
    ///
    /// `points_sensor`: row-major `(N, 3)` in the sensor frame \[m\], N >= 1; NaN and infinite
    /// points are dropped and counted. `stamp_s`: the scan's time, not earlier than the
    /// previous scan's \[s\]. `world_from_body`: odometry pose (rigid). `body_from_sensor`: the
    /// sensor's mounting (rigid). `confidence`: odometry confidence in [0, 1] (0: fuse the
    /// newest scan alone).
    pub fn update(
        &mut self,
        points_sensor: &[f32],
        stamp_s: f64,
        world_from_body: &Isometry3,
        body_from_sensor: &Isometry3,
        confidence: f64,
    ) -> Result<TerrainOutput> {
        let started = Instant::now();
        let points = as_points("points_sensor", points_sensor)?;
        if points.is_empty() {
            return Err(Error::input("points_sensor", "is empty; a scan needs at least one point"));
        }
        crate::frames::check_stamp("stamp_s", stamp_s)?;
        if let Some(previous) = self.window.newest_stamp() {
            if stamp_s < previous {
                return Err(Error::input("stamp_s", format!("{stamp_s} is earlier than the previous scan's {previous}; call reset() after a time jump")));
            }
        }
        if !(confidence.is_finite() && (0.0..=1.0).contains(&confidence)) {
            return Err(Error::input("confidence", format!("must be in [0, 1], got {confidence}")));
        }
        check_rigid("world_from_body", world_from_body)?;
        check_rigid("body_from_sensor", body_from_sensor)?;

        let mut timings = TerrainTimings::default();
        let mut stats = TerrainStats::default();
        let mut body_points = std::mem::take(&mut self.body_points);
        stats.prefilter = self.prefilter.apply(points, body_from_sensor, &mut body_points);
        // World-aligned axes, centred on the sensor.
        let sensor_level = world_from_body.rotation * body_from_sensor.translation;
        let rotation: Mat3 = world_from_body.rotation.as_mat3();
        let shift = (-sensor_level).as_vec3();
        let mut scan = self.window.blank();
        scan.stamp_s = stamp_s;
        scan.body_world = world_from_body.translation;
        scan.sensor_level = sensor_level;
        scan.points.clear();
        scan.points.extend(body_points.iter().map(|p| (rotation * Vec3::from_array(*p) + shift).to_array()));
        self.body_points = body_points;
        let t_segment = Instant::now();
        timings.prefilter_s = (t_segment - started).as_secs_f64();

        // The body origin is on the ground (base_footprint): the sensor is sensor_level.z above it.
        self.segmenter.segment(&scan.points, sensor_level.z, &mut scan.heights)?;
        stats.ground_points = scan.heights.iter().filter(|&&h| self.segmenter.is_ground(h)).count();
        stats.obstacle_points = scan.heights.len() - stats.ground_points;
        let t_coarse = Instant::now();
        timings.segment_s = (t_coarse - t_segment).as_secs_f64();
        let mut binned = std::mem::take(&mut scan.binned);
        self.segmenter.void_samples(&mut self.voids);
        self.coarse.bin_scan(&scan.points, &scan.heights, &self.voids, scan.body_world + sensor_level, sensor_level.z, &mut binned);
        scan.binned = binned;
        self.window.push(scan);

        let body_world = world_from_body.translation;
        let polar = NewestPolar { segmenter: &self.segmenter, sensor_level };
        let binned: Vec<BinnedSource<'_>> = self
            .window
            .fused(confidence)
            .map(|s| BinnedSource { cells: &s.binned, dz: (s.body_world.z - body_world.z) as f32, age_s: (stamp_s - s.stamp_s) as f32 })
            .collect();
        stats.fused_scans = binned.len();
        stats.fused_points = self.window.fused(confidence).map(|s| s.points.len()).sum();
        let coarse = self.coarse.build(body_world, stamp_s, &[], &binned, Some(&polar), &self.missions);
        let t_fine = Instant::now();
        timings.coarse_s = (t_fine - t_coarse).as_secs_f64();
        let newest = self.window.newest().map(|s| ScanSource { points_level: &s.points, heights: &s.heights, offset: s.offset_from(body_world).as_vec3(), age_s: 0.0 });
        let fine = self.fine.as_mut().map(|builder| builder.build(body_world, stamp_s, newest.as_slice(), &[], Some(&polar), &self.missions));
        let done = Instant::now();
        timings.fine_s = (done - t_fine).as_secs_f64();
        timings.total_s = (done - started).as_secs_f64();
        Ok(TerrainOutput { coarse, fine, stats, timings })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_inputs_name_their_argument() {
        let mut m = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
        let id = Isometry3::IDENTITY;
        let pts = [3.0f32, 0.0, -0.5];
        let err = |r: Result<TerrainOutput>| r.unwrap_err().to_string();
        assert!(err(m.update(&[1.0, 2.0], 0.0, &id, &id, 1.0)).contains("points_sensor"));
        assert!(err(m.update(&[], 0.0, &id, &id, 1.0)).contains("points_sensor"));
        assert!(err(m.update(&pts, f64::NAN, &id, &id, 1.0)).contains("stamp_s"));
        assert!(err(m.update(&pts, 0.0, &id, &id, 1.5)).contains("confidence"));
        let mut nan = id;
        nan.rotation.y_axis.z = f64::NAN;
        assert!(err(m.update(&pts, 0.0, &nan, &id, 1.0)).contains("world_from_body"));
        let mut shear = id;
        shear.rotation.y_axis.x = 0.3;
        assert!(err(m.update(&pts, 0.0, &id, &shear, 1.0)).contains("body_from_sensor"));
        m.update(&pts, 1.0, &id, &id, 1.0).unwrap();
        assert!(err(m.update(&pts, 0.5, &id, &id, 1.0)).contains("stamp_s"));
        let bad = MissionItem { position_world: glam::DVec2::new(0.0, f64::NAN), radius_m: 1.0 };
        assert!(m.set_mission_items(&[bad]).unwrap_err().to_string().contains("items"));
        let mut config = TerrainConfig::default();
        config.layers.tilt_headings = 0;
        assert!(TerrainMapper::new(RobotConfig::default(), config).unwrap_err().to_string().contains("layers.tilt_headings"));
    }

    #[test]
    fn all_nan_scan_is_counted_not_an_error() {
        let mut m = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
        let out = m.update(&[f32::NAN; 9], 0.0, &Isometry3::IDENTITY, &Isometry3::IDENTITY, 1.0).unwrap();
        assert_eq!((out.stats.prefilter.non_finite, out.stats.prefilter.kept), (3, 0));
        assert!(out.coarse.get(super::super::grid::Layer::Risk).iter().all(|r| (0.0..=1.0).contains(r)));
    }

    /// Every layer's bits (NaN-safe equality).
    fn bits(map: &RiskMap) -> Vec<u32> {
        super::super::grid::Layer::ALL.iter().flat_map(|&l| map.get(l).iter().map(|v| v.to_bits())).collect()
    }

    /// Flat ground 0.6 m below the sensor in rings, with a pole at `pole` and a pit beside it.
    fn rings_with_pole(pole: (f32, f32)) -> Vec<f32> {
        let mut flat = Vec::new();
        for ring in 0..40 {
            let r = 1.0 + ring as f32 * 0.2;
            for a in 0..720 {
                let t = (a as f32 * 0.5).to_radians();
                let (x, y) = (r * t.cos(), r * t.sin());
                let pit = (x - pole.0 - 1.0).hypot(y - pole.1) < 0.5;
                if !pit {
                    flat.extend_from_slice(&[x, y, -0.6]);
                }
            }
        }
        for i in 0..30 {
            flat.extend_from_slice(&[pole.0, pole.1, -0.6 + 0.05 * i as f32]);
        }
        flat
    }

    #[test]
    fn a_map_in_recycled_storage_equals_a_fresh_one() {
        let id = Isometry3::IDENTITY;
        let mount = Isometry3 { translation: glam::DVec3::new(0.0, 0.0, 0.6), ..id };
        let (a, b) = (rings_with_pole((3.0, 0.5)), rings_with_pole((-2.0, 1.5)));
        let mut fresh = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
        let want = fresh.update(&b, 0.0, &id, &mount, 1.0).unwrap();
        let mut m = TerrainMapper::new(RobotConfig::default(), TerrainConfig::default()).unwrap();
        let mission = [MissionItem { position_world: glam::DVec2::new(1.0, -1.0), radius_m: 0.5 }];
        m.set_mission_items(&mission).unwrap();
        // The caller keeps the first maps: the next ones get new storage, these stay as they were.
        let kept = m.update(&a, 0.0, &id, &mount, 1.0).unwrap();
        let kept_bits = bits(&kept.coarse);
        m.reset();
        m.set_mission_items(&[]).unwrap();
        let second = m.update(&b, 0.0, &id, &mount, 1.0).unwrap();
        assert_ne!(kept.coarse.storage().as_ptr(), second.coarse.storage().as_ptr());
        assert_eq!(bits(&kept.coarse), kept_bits);
        assert_ne!(bits(&kept.coarse), bits(&second.coarse));
        // Dropped maps: the next maps are written over their layers (mission circle, pole
        // and pit of the other scan) and equal the fresh mapper's.
        drop(second);
        m.reset();
        m.set_mission_items(&mission).unwrap();
        let first = m.update(&a, 0.0, &id, &mount, 1.0).unwrap();
        let storage = (first.coarse.storage().as_ptr(), first.fine.as_ref().map(|f| f.storage().as_ptr()));
        drop(first);
        m.reset();
        m.set_mission_items(&[]).unwrap();
        let got = m.update(&b, 0.0, &id, &mount, 1.0).unwrap();
        assert_eq!((got.coarse.storage().as_ptr(), got.fine.as_ref().map(|f| f.storage().as_ptr())), storage);
        assert_eq!(bits(&got.coarse), bits(&want.coarse));
        assert_eq!(bits(got.fine.as_ref().unwrap()), bits(want.fine.as_ref().unwrap()));
        drop(got);
        m.reset();
        m.set_mission_items(&mission).unwrap();
        let again = m.update(&a, 0.0, &id, &mount, 1.0).unwrap();
        assert_eq!(again.coarse.storage().as_ptr(), storage.0);
        assert_eq!(bits(&again.coarse), kept_bits);
    }
}
