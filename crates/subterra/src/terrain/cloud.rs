//! Prefilter of a raw point cloud: non-finite points, range limits, the robot's own box,
//! optional voxel downsampling and sparse-outlier removal (pipeline step 1).
//!
//! In: points in the sensor frame, `body_from_sensor`. Out: the kept points in the body
//! frame, in input order, and how many each rule dropped.

use std::collections::HashMap;

use glam::{DVec3, Mat3, Vec3};

use super::config::{PrefilterConfig, RobotConfig};
use crate::error::{Error, Result};
use crate::frames::Isometry3;

/// How many points each rule of the prefilter dropped, in the order the rules run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PrefilterStats {
    /// Points given.
    pub input: usize,
    /// Points with a NaN or infinite coordinate (dropped and counted, not an error).
    pub non_finite: usize,
    /// Points nearer than `min_range_m` or farther than `max_range_m` from the sensor.
    pub out_of_range: usize,
    /// Points inside the robot's own box (plus margin).
    pub self_hits: usize,
    /// Points merged away by voxel downsampling.
    pub downsampled: usize,
    /// Sparse outliers removed.
    pub outliers: usize,
    /// Points kept.
    pub kept: usize,
}

/// Views a flat `[x0, y0, z0, x1, ...]` slice as points, checking its length.
pub(super) fn as_points<'a>(argument: &str, flat: &'a [f32]) -> Result<&'a [[f32; 3]]> {
    let (points, rest) = flat.as_chunks::<3>();
    if !rest.is_empty() {
        return Err(Error::input(argument, format!("must hold (N, 3) coordinates; its length {} is not a multiple of 3", flat.len())));
    }
    Ok(points)
}

/// The prefilter of one robot.
#[derive(Debug, Clone)]
pub(super) struct Prefilter {
    config: PrefilterConfig,
    /// Self box in the body frame, lower corner \[m\].
    box_min: Vec3,
    /// Self box in the body frame, upper corner \[m\].
    box_max: Vec3,
}

impl Prefilter {
    /// A prefilter for `robot`; the configs are trusted (validated by the caller).
    pub(super) fn new(config: PrefilterConfig, robot: &RobotConfig) -> Self {
        let m = config.self_margin_m;
        let box_min = DVec3::new(-robot.length_m / 2.0 - m, -robot.width_m / 2.0 - m, -m).as_vec3();
        let box_max = DVec3::new(robot.length_m / 2.0 + m, robot.width_m / 2.0 + m, robot.height_m + m).as_vec3();
        Self { config, box_min, box_max }
    }

    /// Filters `points_sensor` and appends the kept points, in the body frame, to `out_body`
    /// (cleared first).
    pub(super) fn apply(&self, points_sensor: &[[f32; 3]], body_from_sensor: &Isometry3, out_body: &mut Vec<[f32; 3]>) -> PrefilterStats {
        let c = &self.config;
        out_body.clear();
        out_body.reserve(points_sensor.len());
        let mut stats = self.point_rules(points_sensor, body_from_sensor, |b| out_body.push(b.to_array()));
        if c.voxel_m > 0.0 {
            let before = out_body.len();
            voxel_downsample(out_body, c.voxel_m as f32);
            stats.downsampled = before - out_body.len();
        }
        if c.outlier_min_neighbors > 0 {
            let before = out_body.len();
            remove_sparse_outliers(out_body, c.outlier_cell_m as f32, c.outlier_min_neighbors);
            stats.outliers = before - out_body.len();
        }
        stats.kept = out_body.len();
        stats
    }

    /// The per-point rules (non-finite, range, self box): `keep(b)` for each kept point in
    /// the body frame, in input order.
    #[inline(always)]
    fn point_rules(&self, points_sensor: &[[f32; 3]], body_from_sensor: &Isometry3, mut keep: impl FnMut(Vec3)) -> PrefilterStats {
        let c = &self.config;
        let mut stats = PrefilterStats { input: points_sensor.len(), ..Default::default() };
        let rotation: Mat3 = body_from_sensor.rotation.as_mat3();
        let translation = body_from_sensor.translation.as_vec3();
        let (min_sq, max_sq) = ((c.min_range_m * c.min_range_m) as f32, (c.max_range_m * c.max_range_m) as f32);
        let (lo, hi) = (self.box_min, self.box_max);
        for p in points_sensor {
            let v = Vec3::from_array(*p);
            let r_sq = v.length_squared();
            // In range implies finite (a NaN or infinite coordinate makes `r_sq` NaN or
            // infinite, and `max_sq` is finite: max_range_m <= 1000 m): one test for the
            // common case, the two rules in order otherwise.
            if !(r_sq >= min_sq && r_sq <= max_sq) {
                if !v.is_finite() {
                    stats.non_finite += 1;
                } else {
                    stats.out_of_range += 1;
                }
                continue;
            }
            let b = rotation * v + translation;
            if b.cmpge(lo).all() && b.cmple(hi).all() {
                stats.self_hits += 1;
                continue;
            }
            keep(b);
        }
        stats
    }
}

fn voxel_key(p: &[f32; 3], inv: f32) -> (i32, i32, i32) {
    ((p[0] * inv).floor() as i32, (p[1] * inv).floor() as i32, (p[2] * inv).floor() as i32)
}

/// Keeps the first point of each voxel `floor(p / voxel_m)`, in input order.
pub(super) fn voxel_downsample(points: &mut Vec<[f32; 3]>, voxel_m: f32) {
    let inv = 1.0 / voxel_m;
    let mut seen: HashMap<(i32, i32, i32), ()> = HashMap::with_capacity(points.len());
    points.retain(|p| seen.insert(voxel_key(p, inv), ()).is_none());
}

/// Removes points with fewer than `min_neighbors` other points in their cube
/// `floor(p / cell_m)` and the 26 cubes around it.
pub(super) fn remove_sparse_outliers(points: &mut Vec<[f32; 3]>, cell_m: f32, min_neighbors: u32) {
    let inv = 1.0 / cell_m;
    let mut counts: HashMap<(i32, i32, i32), u32> = HashMap::with_capacity(points.len());
    for p in points.iter() {
        *counts.entry(voxel_key(p, inv)).or_insert(0) += 1;
    }
    let mut around: HashMap<(i32, i32, i32), u32> = HashMap::with_capacity(counts.len());
    for &(x, y, z) in counts.keys() {
        let mut total = 0;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    total += counts.get(&(x + dx, y + dy, z + dz)).copied().unwrap_or(0);
                }
            }
        }
        around.insert((x, y, z), total);
    }
    // The point itself is in its own cube: neighbours = total - 1.
    points.retain(|p| around.get(&voxel_key(p, inv)).copied().unwrap_or(0) > min_neighbors);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::config::TerrainConfig;

    #[test]
    fn each_rule_drops_and_counts() {
        let mut config = TerrainConfig::default().prefilter;
        config.max_range_m = 10.0;
        let robot = RobotConfig::default();
        let pre = Prefilter::new(config, &robot);
        // Sensor 0.5 m above the body origin, axes aligned.
        let body_from_sensor = Isometry3 { translation: DVec3::new(0.0, 0.0, 0.5), ..Isometry3::IDENTITY };
        let points = [
            [5.0, 0.0, -0.5],          // kept: ground 5 m ahead
            [f32::NAN, 0.0, 0.0],      // non-finite
            [0.0, f32::INFINITY, 0.0], // non-finite
            [0.1, 0.0, 0.0],           // nearer than 0.3 m
            [20.0, 0.0, 0.0],          // beyond 10 m
            [0.5, 0.0, -0.3],          // on the robot's own deck (0.2 m above ground, 0.5 m ahead)
            [0.0, 2.0, -0.5],          // kept
        ];
        let mut out = Vec::new();
        let stats = pre.apply(&points, &body_from_sensor, &mut out);
        assert_eq!((stats.input, stats.non_finite, stats.out_of_range, stats.self_hits, stats.kept), (7, 2, 2, 1, 2));
        assert_eq!(out, vec![[5.0, 0.0, 0.0], [0.0, 2.0, 0.0]]);
    }

    #[test]
    fn voxel_downsampling_keeps_first_of_each_voxel() {
        let mut points = vec![[0.01, 0.01, 0.01], [0.05, 0.02, 0.0], [0.15, 0.0, 0.0], [0.02, 0.09, 0.0]];
        voxel_downsample(&mut points, 0.1);
        assert_eq!(points, vec![[0.01, 0.01, 0.01], [0.15, 0.0, 0.0]]);
    }

    #[test]
    fn isolated_points_are_outliers() {
        let mut points: Vec<[f32; 3]> = (0..10).map(|i| [i as f32 * 0.05, 0.0, 0.0]).collect();
        points.push([5.0, 5.0, 5.0]);
        remove_sparse_outliers(&mut points, 0.5, 2);
        assert_eq!(points.len(), 10);
        assert!(points.iter().all(|p| p[0] < 1.0));
    }

    #[test]
    fn wrong_length_names_the_argument() {
        let err = as_points("points_sensor", &[1.0, 2.0]).unwrap_err();
        assert!(err.to_string().contains("points_sensor"));
        assert_eq!(as_points("p", &[1.0, 2.0, 3.0]).unwrap(), &[[1.0, 2.0, 3.0]]);
    }

    #[test]
    fn points_view_the_callers_memory() {
        let flat: Vec<f32> = (0..12).map(|i| i as f32).collect();
        let points = as_points("p", &flat).unwrap();
        assert_eq!((points.as_ptr().cast::<f32>(), points.len()), (flat.as_ptr(), 4));
        assert_eq!(points[3], [9.0, 10.0, 11.0]);
        assert!(as_points("p", &[]).unwrap().is_empty());
    }
}
