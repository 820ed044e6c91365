//! The robot's footprint at a predicted state and its signed distance to the lethal polygons:
//! the clearance the plan is checked with and the margin intrusion the merit penalises.

use super::geometry::{separation, Footprint};
use super::{ConvexPolygon, MpcConfig, UnicycleState};

/// Footprint of a state.
pub(super) fn footprint(c: &MpcConfig, s: &UnicycleState) -> Footprint {
    Footprint::at(s.position(), s.heading_rad, c.footprint.length_m, c.footprint.width_m)
}

/// The smallest signed distance from the footprint at `s` to any polygon \[m\]; infinite if none.
pub(super) fn clearance(c: &MpcConfig, polygons: &[ConvexPolygon], s: &UnicycleState) -> f64 {
    let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
    let fp = footprint(c, s);
    let mut best = f64::INFINITY;
    for p in polygons {
        // The bounding circles' gap is a lower bound of the distance.
        if s.position().distance(p.centre) - half_diagonal - p.radius_m < best {
            best = best.min(separation(&fp, p).distance_m);
        }
    }
    best
}

/// Smallest obstacle slack of the footprint at `s` (>= 0) \[m\]: its largest intrusion into
/// the margin of any polygon.
pub(super) fn obstacle_slack(c: &MpcConfig, polygons: &[ConvexPolygon], s: &UnicycleState) -> f64 {
    let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
    let margin = c.obstacles.margin_m;
    let fp = footprint(c, s);
    let mut worst = 0.0f64;
    for p in polygons {
        if s.position().distance(p.centre) - half_diagonal - p.radius_m < margin - worst {
            worst = worst.max(margin - separation(&fp, p).distance_m);
        }
    }
    worst
}
