//! The reference path: a polyline in world coordinates, parametrised by arc length.

use glam::DVec2;

use crate::error::{Error, Result};

/// A polyline without repeated consecutive points, and its cumulative arc length.
#[derive(Debug, Clone, Default)]
pub(crate) struct Reference {
    points: Vec<DVec2>,
    /// `s[i]`: arc length from the first point to `points[i]` \[m\].
    s: Vec<f64>,
}

/// Where a point of the path is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PathPoint {
    /// The point \[m\].
    pub position: DVec2,
    /// Unit tangent of its segment (the later segment at a vertex).
    pub tangent: DVec2,
}

impl Reference {
    /// Replaces the path. `path` needs at least two points, all finite, and a positive
    /// length; consecutive repeated points are dropped. Errors name `reference_path`.
    pub(super) fn set(&mut self, path: &[DVec2]) -> Result<()> {
        if path.len() < 2 {
            return Err(Error::input("reference_path", format!("needs at least 2 points, got {}", path.len())));
        }
        if let Some(i) = path.iter().position(|p| !p.is_finite()) {
            return Err(Error::input("reference_path", format!("point {i} is not finite: ({}, {})", path[i].x, path[i].y)));
        }
        self.points.clear();
        self.s.clear();
        for &p in path {
            match self.points.last() {
                Some(&last) if last == p => continue,
                Some(&last) => {
                    let s = self.s[self.s.len() - 1] + last.distance(p);
                    self.points.push(p);
                    self.s.push(s);
                }
                None => {
                    self.points.push(p);
                    self.s.push(0.0);
                }
            }
        }
        if self.points.len() < 2 {
            return Err(Error::input("reference_path", "has zero length (all points are the same)"));
        }
        Ok(())
    }

    /// Total length \[m\].
    pub(super) fn length(&self) -> f64 {
        self.s[self.s.len() - 1]
    }

    /// Arc length of the point of the path closest to `p` (the first such point along the
    /// path when several are equally close).
    pub(super) fn project(&self, p: DVec2) -> f64 {
        let mut best = (f64::INFINITY, 0.0);
        for i in 0..self.points.len() - 1 {
            let (a, b) = (self.points[i], self.points[i + 1]);
            let e = b - a;
            let len = self.s[i + 1] - self.s[i];
            let t = ((p - a).dot(e) / e.length_squared()).clamp(0.0, 1.0);
            let d2 = p.distance_squared(a + t * e);
            if d2 < best.0 {
                best = (d2, self.s[i] + t * len);
            }
        }
        best.1
    }

    /// The point at arc length `s` (clamped to the path) with the direction of the chord
    /// from `s - half_window_m` to `s + half_window_m` (both clamped) as its tangent, so the
    /// tangent turns smoothly through a corner; `half_window_m = 0` gives the segment's own.
    pub(super) fn at_smoothed(&self, s: f64, half_window_m: f64) -> PathPoint {
        let here = self.at(s);
        if half_window_m <= 0.0 {
            return here;
        }
        let chord = self.at(s + half_window_m).position - self.at(s - half_window_m).position;
        let len = chord.length();
        // A chord shorter than the window (a hairpin) has no reliable direction.
        let tangent = if len > 0.5 * half_window_m { chord / len } else { here.tangent };
        PathPoint { position: here.position, tangent }
    }

    /// The point at arc length `s` (clamped to the path).
    pub(super) fn at(&self, s: f64) -> PathPoint {
        let segments = self.points.len() - 1;
        // Last segment whose start is at or before s.
        let i = self.s.partition_point(|&si| si <= s).saturating_sub(1).min(segments - 1);
        let (a, b) = (self.points[i], self.points[i + 1]);
        let len = self.s[i + 1] - self.s[i];
        let t = ((s - self.s[i]) / len).clamp(0.0, 1.0);
        PathPoint { position: a + t * (b - a), tangent: (b - a) / len }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arc_length_projection_and_lookup_by_hand() {
        let mut r = Reference::default();
        r.set(&[DVec2::new(0.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(2.0, 3.0)]).unwrap();
        assert_eq!(r.length(), 5.0);
        assert_eq!(r.project(DVec2::new(1.0, -1.0)), 1.0);
        assert_eq!(r.project(DVec2::new(3.0, 1.0)), 3.0);
        assert_eq!(r.project(DVec2::new(-4.0, 0.5)), 0.0);
        let p = r.at(3.5);
        assert_eq!((p.position, p.tangent), (DVec2::new(2.0, 1.5), DVec2::new(0.0, 1.0)));
        assert_eq!(r.at(2.0).tangent, DVec2::new(0.0, 1.0));
        assert_eq!(r.at(99.0).position, DVec2::new(2.0, 3.0));
        assert_eq!(r.at(-1.0).position, DVec2::new(0.0, 0.0));
        // Through the corner at s = 2 the chord of ±0.5 m turns by 45°.
        let c = r.at_smoothed(2.0, 0.5);
        assert_eq!(c.position, DVec2::new(2.0, 0.0));
        assert!((c.tangent - DVec2::new(1.0, 1.0).normalize()).length() < 1e-12, "{c:?}");
        assert_eq!(r.at_smoothed(1.0, 0.5).tangent, DVec2::new(1.0, 0.0));
    }

    #[test]
    fn bad_paths_name_the_argument() {
        let mut r = Reference::default();
        for bad in [vec![DVec2::ZERO], vec![DVec2::ZERO, DVec2::ZERO], vec![DVec2::ZERO, DVec2::new(f64::NAN, 0.0)]] {
            assert!(r.set(&bad).unwrap_err().to_string().contains("`reference_path`"));
        }
    }
}
