//! A carrot ahead along a path of waypoints: the goal a potential field pulls toward when
//! the way to the real goal is long and winding (subterra; the paper flies to one goal).
//!
//! Documented on [`PathFollower`].

use glam::DVec3;

use crate::error::{Error, Result};

/// How far back from the progress the projection looks \[m\].
pub(super) const BACK_WINDOW_M: f64 = 0.5;
/// How far beyond the carrot the projection looks \[m\].
pub(super) const AHEAD_WINDOW_M: f64 = 1.0;
/// Carrot distance used by `subterra fly` \[m\]: 1.5 m, a little beyond the 1.2 m horizon of
/// the depth filter, so that the pull points along the path past what the camera sees.
pub const DEFAULT_LOOKAHEAD_M: f64 = 1.5;

/// What one [`PathFollower::update`] gives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CarrotOutput {
    /// The point to pull toward, world frame \[m\].
    pub carrot_world: DVec3,
    /// Arc length along the path reached so far \[m\].
    pub progress_m: f64,
    /// Distance still to go: along the path from the progress, plus the robot's distance to it \[m\].
    pub remaining_m: f64,
}

/// A path with its progress.
///
/// A potential field only sees what is near. Pulled straight at a goal 30 m down a winding
/// tunnel it flies into the first bend's wall; pulled toward a point a little ahead along a
/// path that keeps clear of the walls (the tunnel world's waypoint regions, or a user's
/// path), it only has to deal with what is near. This is pure pursuit's lookahead point
/// (Coulter 1992, "Implementation of the Pure Pursuit Path Tracking Algorithm", CMU-RI-TR-92-01).
///
/// In: the path (at least two points, world frame) once, then the robot's position per
/// step. Out: the carrot, the remaining distance along the path and the progress made.
///
/// # One update, exactly
/// 1. **Project.** The robot's position is projected onto the path, looking only at arc
///    lengths within `[s - BACK_WINDOW_M, s + lookahead_m + AHEAD_WINDOW_M]` of the progress `s`
///    so far (the path's later legs, behind a wall, are not jumped to); the nearest
///    point's arc length becomes the progress if it is larger (the progress never goes back).
/// 2. **Carrot.** The point of the path `lookahead_m` beyond the progress (the path's last
///    point once that is past its end).
/// 3. **Remaining.** The arc length from the progress to the end, plus the robot's
///    distance to its projection.
#[derive(Debug, Clone)]
pub struct PathFollower {
    points: Vec<DVec3>,
    /// Arc length at each point.
    arc: Vec<f64>,
    lookahead_m: f64,
    progress_m: f64,
}

impl PathFollower {
    /// A follower of `points_world` (at least two, finite; repeated points are dropped)
    /// with a carrot `lookahead_m` ahead (> 0).
    pub fn new(points_world: &[DVec3], lookahead_m: f64) -> Result<Self> {
        if !(lookahead_m.is_finite() && lookahead_m > 0.0) {
            return Err(Error::input("lookahead_m", format!("must be finite and > 0, got {lookahead_m}")));
        }
        for (i, p) in points_world.iter().enumerate() {
            crate::frames::check_position(&format!("path[{i}]"), &p.to_array())?;
        }
        let mut points: Vec<DVec3> = Vec::with_capacity(points_world.len());
        for &p in points_world {
            if points.last().is_none_or(|&q| (p - q).length() > 0.0) {
                points.push(p);
            }
        }
        if points.len() < 2 {
            return Err(Error::input("path", format!("needs at least two distinct points, got {}", points.len())));
        }
        let mut arc = vec![0.0];
        for w in points.windows(2) {
            arc.push(arc[arc.len() - 1] + (w[1] - w[0]).length());
        }
        Ok(Self { points, arc, lookahead_m, progress_m: 0.0 })
    }

    /// The path's points.
    pub fn points(&self) -> &[DVec3] {
        &self.points
    }

    /// The path's length \[m\].
    pub fn length_m(&self) -> f64 {
        self.arc[self.arc.len() - 1]
    }

    /// The carrot distance \[m\].
    pub fn lookahead_m(&self) -> f64 {
        self.lookahead_m
    }

    /// Starts again from the path's first point.
    pub fn reset(&mut self) {
        self.progress_m = 0.0;
    }

    /// The point at arc length `s` (clamped to the path).
    pub fn point_at(&self, s: f64) -> DVec3 {
        let s = s.clamp(0.0, self.length_m());
        let i = self.arc.partition_point(|&a| a <= s).clamp(1, self.points.len() - 1) - 1;
        let len = self.arc[i + 1] - self.arc[i];
        let f = if len > 0.0 { (s - self.arc[i]) / len } else { 0.0 };
        self.points[i] + f * (self.points[i + 1] - self.points[i])
    }

    /// Steps 1-3 for the robot at `position_world`.
    pub fn update(&mut self, position_world: DVec3) -> Result<CarrotOutput> {
        if !position_world.is_finite() {
            return Err(Error::input("position_world", format!("must be finite, got {position_world}")));
        }
        let (lo, hi) = (self.progress_m - BACK_WINDOW_M, self.progress_m + self.lookahead_m + AHEAD_WINDOW_M);
        let mut best: Option<(f64, f64)> = None;
        for i in 0..self.points.len() - 1 {
            let (s0, s1) = (self.arc[i], self.arc[i + 1]);
            if s1 < lo || s0 > hi {
                continue;
            }
            let (a, b) = (self.points[i], self.points[i + 1]);
            let len = s1 - s0;
            let along = ((position_world - a).dot(b - a) / len).clamp((lo - s0).max(0.0), (hi - s0).min(len));
            let d = (position_world - (a + (b - a) * (along / len))).length();
            if best.is_none_or(|(_, bd)| d < bd) {
                best = Some((s0 + along, d));
            }
        }
        if let Some((s, _)) = best {
            self.progress_m = self.progress_m.max(s);
        }
        let projection = self.point_at(self.progress_m);
        Ok(CarrotOutput {
            carrot_world: self.point_at(self.progress_m + self.lookahead_m),
            progress_m: self.progress_m,
            remaining_m: self.length_m() - self.progress_m + (position_world - projection).length(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn l_path() -> PathFollower {
        // 4 m east, then 3 m north.
        PathFollower::new(&[DVec3::ZERO, DVec3::new(4.0, 0.0, 0.0), DVec3::new(4.0, 3.0, 0.0)], 1.5).unwrap()
    }

    #[test]
    fn the_carrot_leads_along_the_path_and_round_the_corner() {
        let mut p = l_path();
        assert_eq!(p.length_m(), 7.0);
        let out = p.update(DVec3::new(1.0, 0.5, 0.0)).unwrap();
        assert!((out.progress_m - 1.0).abs() < 1e-12);
        assert!((out.carrot_world - DVec3::new(2.5, 0.0, 0.0)).length() < 1e-12);
        assert!((out.remaining_m - (6.0 + 0.5)).abs() < 1e-12);
        // 0.5 m before the corner the carrot is 1 m up the second leg.
        let out = p.update(DVec3::new(3.5, 0.0, 0.0)).unwrap();
        assert!((out.carrot_world - DVec3::new(4.0, 1.0, 0.0)).length() < 1e-12, "{}", out.carrot_world);
        // Past the end: the carrot is the last point.
        // The window (3.5 + 1.5 + 1 m) stops the progress at 6 m on the first step there.
        let out = p.update(DVec3::new(4.0, 2.5, 0.0)).unwrap();
        assert_eq!(out.carrot_world, DVec3::new(4.0, 3.0, 0.0));
        assert!((out.progress_m - 6.0).abs() < 1e-12 && (out.remaining_m - 1.5).abs() < 1e-12, "{out:?}");
        let out = p.update(DVec3::new(4.0, 2.5, 0.0)).unwrap();
        assert!((out.progress_m - 6.5).abs() < 1e-12 && (out.remaining_m - 0.5).abs() < 1e-12, "{out:?}");
    }

    #[test]
    fn progress_never_goes_back_nor_jumps_to_a_far_leg() {
        let mut p = l_path();
        p.update(DVec3::new(2.0, 0.0, 0.0)).unwrap();
        // Pushed back 1 m: the progress stays at 2 m.
        let out = p.update(DVec3::new(1.0, 0.0, 0.0)).unwrap();
        assert!((out.progress_m - 2.0).abs() < 1e-12);
        // Near the second leg's end (6.5 m along) but the window ends at 2 + 1.5 + 1 = 4.5 m:
        // the progress goes no further than the window allows.
        let out = p.update(DVec3::new(4.1, 2.5, 0.0)).unwrap();
        assert!(out.progress_m <= 4.5 + 1e-12 && out.progress_m > 2.0, "{}", out.progress_m);
        p.reset();
        assert_eq!(p.update(DVec3::ZERO).unwrap().progress_m, 0.0);
    }

    #[test]
    fn bad_paths_name_the_argument() {
        assert!(PathFollower::new(&[DVec3::ZERO], 1.0).unwrap_err().to_string().contains("path"));
        assert!(PathFollower::new(&[DVec3::ZERO, DVec3::ZERO], 1.0).unwrap_err().to_string().contains("two distinct"));
        assert!(PathFollower::new(&[DVec3::ZERO, DVec3::NAN], 1.0).unwrap_err().to_string().contains("finite"));
        assert!(PathFollower::new(&[DVec3::ZERO, DVec3::X], 0.0).unwrap_err().to_string().contains("lookahead_m"));
        assert!(l_path().update(DVec3::INFINITY).unwrap_err().to_string().contains("position_world"));
    }
}
