//! The risk layers from the geometric ones, their combination into `risk` and its
//! uncertainty (`risk_variance`), and the keep-out circles of mission items.

use glam::{DVec2, DVec3};

use crate::terrain::grid::{GridGeometry, RiskMap};
use super::{select_f32, CellAccumulator, MapBuilder, MissionItem};

impl MapBuilder {
    #[inline(never)]
    pub(super) fn risks(&mut self, g: &GridGeometry, body_world: DVec3, missions: &[MissionItem], map: &mut RiskMap) {
        let n = g.cells();
        let r = self.risk;
        let tilt_ramp = self.robot.tilt_ramp_rad();
        let u = self.uncertainty;
        let z0 = body_world.z as f32;
        // One slice per layer, in `Layer::ALL` order, each exactly `n` long.
        let Ok([count_l, ground_count, ground_height, min_height, max_height, _slope, residual, step_height, negative_depth, tilt_angle, observed_l, age_l, collision_l, step_l, negative_l, tilt_l, rough_l, unknown_l, mission_l, risk_l, variance_l]) =
            <[&mut [f32]; 21]>::try_from(map.layers_mut())
        else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        mission_l.fill(0.0);
        for item in missions {
            stamp_mission(g, item, r.mission_margin_m, mission_l);
        }
        let cells = &mut self.cells[..n];
        let height = &self.height[..n];
        // Re-sliced to `n` so that the loops index without bounds checks.
        let (count_l, ground_count, ground_height, min_height, max_height, age_l) =
            (&mut count_l[..n], &mut ground_count[..n], &mut ground_height[..n], &mut min_height[..n], &mut max_height[..n], &mut age_l[..n]);
        for c in 0..n {
            let cell = &cells[c];
            let count = cell.count;
            count_l[c] = count as f32;
            ground_count[c] = cell.ground_n as f32;
            ground_height[c] = height[c] + z0;
            // Whether the cell has points, as a float comparison (an empty cell's bounds are
            // +inf and -inf, a non-empty one's finite): selects on it compile without a
            // branch, which real scans, mixing empty and non-empty cells, mispredicted.
            let has = cell.min_z <= cell.max_z;
            min_height[c] = select_f32(has, cell.min_z + z0, f32::NAN);
            max_height[c] = select_f32(has, cell.max_z + z0, f32::NAN);
            age_l[c] = select_f32(has, cell.min_age, f32::NAN);
        }
        let (residual, step_height, negative_depth, tilt_angle, observed_l) =
            (&residual[..n], &step_height[..n], &negative_depth[..n], &tilt_angle[..n], &mut observed_l[..n]);
        let (collision_l, step_l, negative_l, tilt_l, rough_l, unknown_l, mission_l, risk_l, variance_l) = (
            &mut collision_l[..n],
            &mut step_l[..n],
            &mut negative_l[..n],
            &mut tilt_l[..n],
            &mut rough_l[..n],
            &mut unknown_l[..n],
            &mut mission_l[..n],
            &mut risk_l[..n],
            &mut variance_l[..n],
        );
        // σ² of an observed cell with `count` points (0 counts as 1), the newest `age` s old.
        let variance = |count: u32, age: f64| {
            let var_h = u.range_sigma_m * u.range_sigma_m / (count.max(1) as f64) + (u.drift_m_per_s * age).powi(2);
            let sigma = (var_h.sqrt() / u.height_span_m).min(u.max_sigma);
            (sigma * sigma) as f32
        };
        let var_unobserved = (u.max_sigma * u.max_sigma) as f32;
        // The same at age 0, by count (most cells of a fresh scan).
        let mut var_fresh = [0.0f32; 64];
        for (k, v) in var_fresh.iter_mut().enumerate() {
            *v = variance(k as u32, 0.0);
        }
        for c in 0..n {
            // The last reader of the cell: it is left empty for the next map.
            let cell = &std::mem::replace(&mut cells[c], CellAccumulator::EMPTY);
            let count = cell.count;
            let has = cell.min_z <= cell.max_z;
            let negative = r.negative_m.eval(negative_depth[c] as f64);
            // A cell rated by ray reasoning (beams passed below where its ground should have
            // been) is observed: what it says is known, not guessed.
            let observed = observed_l[c] > 0.0 || negative > 0.0;
            observed_l[c] = select_f32(observed, 1.0, 0.0);
            let collision = r.collision_points.eval(cell.collision_n as f64);
            let step = r.step_m.eval(step_height[c] as f64);
            let tilt = tilt_ramp.eval(tilt_angle[c] as f64);
            let rough = r.roughness_m.eval(residual[c] as f64);
            let unknown = if observed { 0.0 } else { r.unknown };
            let m = mission_l[c] as f64;
            // Same order as Layer::RISKS. A cell with every risk 0 (ramps give +0, never -0)
            // gets +0 in each, and combined risk 1 - 1 = +0.
            if collision != 0.0 || step != 0.0 || negative != 0.0 || tilt != 0.0 || rough != 0.0 || unknown != 0.0 || m != 0.0 {
                collision_l[c] = collision as f32;
                step_l[c] = step as f32;
                negative_l[c] = negative as f32;
                tilt_l[c] = tilt as f32;
                rough_l[c] = rough as f32;
                unknown_l[c] = unknown as f32;
                let keep = 1.0 * (1.0 - collision) * (1.0 - step) * (1.0 - negative) * (1.0 - tilt) * (1.0 - rough) * (1.0 - unknown) * (1.0 - m);
                risk_l[c] = (1.0 - keep).clamp(0.0, 1.0) as f32;
            } else {
                for layer in [&mut collision_l[c], &mut step_l[c], &mut negative_l[c], &mut tilt_l[c], &mut rough_l[c], &mut unknown_l[c], &mut risk_l[c]] {
                    *layer = 0.0;
                }
            }
            // No points: count 0 (the same as 1) and age 0. Selects again, as `has` above.
            let age = if has { cell.min_age } else { 0.0 };
            let var = if age == 0.0 && (count as usize) < var_fresh.len() {
                // Age ±0 adds exactly 0 (drift·age squared): the value of `count` alone.
                var_fresh[count as usize]
            } else {
                variance(count, age as f64)
            };
            variance_l[c] = if observed { var } else { var_unobserved };
        }
    }
}

fn stamp_mission(g: &GridGeometry, item: &MissionItem, margin_m: f64, out: &mut [f32]) {
    let reach = item.radius_m + margin_m;
    if !(reach.is_finite() && item.position_world.is_finite() && item.radius_m >= 0.0) {
        return;
    }
    let res = g.resolution_m;
    let origin = g.origin_m();
    let lo = ((item.position_world - reach - origin) / res).floor();
    let hi = ((item.position_world + reach - origin) / res).ceil();
    let (x0, x1) = (lo.x.max(0.0) as usize, (hi.x.max(0.0) as usize).min(g.nx));
    let (y0, y1) = (lo.y.max(0.0) as usize, (hi.y.max(0.0) as usize).min(g.ny));
    for iy in y0..y1 {
        for ix in x0..x1 {
            let centre = origin + (DVec2::new(ix as f64, iy as f64) + 0.5) * res;
            let d = (centre - item.position_world).length();
            let value = if d <= item.radius_m {
                1.0
            } else if margin_m > 0.0 {
                (1.0 - (d - item.radius_m) / margin_m).max(0.0)
            } else {
                0.0
            };
            let c = iy * g.nx + ix;
            out[c] = out[c].max(value as f32);
        }
    }
}
