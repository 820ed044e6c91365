//! Rigid transforms between frames (ROS REP 103/105 conventions).
//!
//! A transform is named `target_from_source`: `body_from_camera.transform_point(p_camera)`
//! gives `p_body`. Body frame FLU (x forward, y left, z up); camera optical frame
//! (x right, y down, z forward); world frame ENU. Metres and radians.

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Tolerance on `RᵀR = I` and `det R = 1` when a rotation comes from user data.
const ROTATION_TOLERANCE: f64 = 1e-6;

/// Largest translation of a pose accepted \[m\]: 1000 km from the world origin. Beyond it a
/// value is a mistake (or geographic coordinates that must be re-centred): `f32` map points
/// would be off by more than 6 cm.
pub const MAX_TRANSLATION_M: f64 = 1e6;

/// Largest |stamp| accepted \[s\]: 10^10 s (317 years; Unix and ROS times until 2286). Beyond
/// it a value is corrupt, and an `f64` no longer resolves the 10 µs between two samples.
pub const MAX_STAMP_S: f64 = 1e10;

/// Checks that a time stamp `stamp_s` \[s\] is finite and within [`MAX_STAMP_S`] of zero;
/// the error names `argument`.
pub fn check_stamp(argument: &str, stamp_s: f64) -> Result<()> {
    if !(stamp_s.is_finite() && stamp_s.abs() <= MAX_STAMP_S) {
        return Err(Error::input(argument, format!("must be finite and within {MAX_STAMP_S:e} s of zero, got {stamp_s}")));
    }
    Ok(())
}

/// Checks that the coordinates `coords_m` of a position (or of a goal relative to the robot)
/// are finite and within [`MAX_TRANSLATION_M`] of the origin (Euclidean norm); the error names
/// `argument`.
pub fn check_position(argument: &str, coords_m: &[f64]) -> Result<()> {
    // The Euclidean norm, as the message says (hypot: no overflow for 1e300).
    let norm = coords_m.iter().fold(0.0f64, |a, &c| a.hypot(c));
    if !(coords_m.iter().all(|c| c.is_finite()) && norm <= MAX_TRANSLATION_M) {
        return Err(Error::input(
            argument,
            format!("must be finite and within {MAX_TRANSLATION_M:e} m of the origin; re-centre the coordinates, got {coords_m:?}"),
        ));
    }
    Ok(())
}

/// A rigid transform `target_from_source`: rotation then translation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Isometry3 {
    /// Rotation taking source-frame vectors to the target frame.
    pub rotation: DMat3,
    /// Origin of the source frame expressed in the target frame \[m\].
    pub translation: DVec3,
}

impl Default for Isometry3 {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Isometry3 {
    /// The identity transform.
    pub const IDENTITY: Self = Self { rotation: DMat3::IDENTITY, translation: DVec3::ZERO };

    /// `body_from_camera` of a camera looking along the body's x axis, at the body origin:
    /// optical z -> body x, optical x -> body -y, optical y -> body -z.
    pub fn body_from_forward_optical() -> Self {
        Self {
            rotation: DMat3::from_cols(DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X),
            translation: DVec3::ZERO,
        }
    }

    /// `body_from_camera` of a camera looking up (+z of the body), its image top toward
    /// the body's +x: optical z -> body z, optical y -> body -x, optical x -> body +y.
    pub fn body_from_upward_optical() -> Self {
        Self {
            rotation: DMat3::from_cols(DVec3::Y, DVec3::NEG_X, DVec3::Z),
            translation: DVec3::ZERO,
        }
    }

    /// Builds a transform from a row-major 4x4 homogeneous matrix, checking that the
    /// upper 3x3 block is a proper rotation and the last row is `[0, 0, 0, 1]`.
    pub fn from_matrix_rows(argument: &str, m: &[[f64; 4]; 4]) -> Result<Self> {
        if m.iter().flatten().any(|x| !x.is_finite()) {
            return Err(Error::input(argument, "contains NaN or infinity"));
        }
        if m[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(Error::input(argument, format!("last row must be [0, 0, 0, 1], got {:?}", m[3])));
        }
        let rotation = DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        );
        let orthogonality = (rotation.transpose() * rotation - DMat3::IDENTITY).abs().to_cols_array();
        let worst = orthogonality.iter().fold(0.0_f64, |a, &b| a.max(b));
        if worst > ROTATION_TOLERANCE || (rotation.determinant() - 1.0).abs() > ROTATION_TOLERANCE {
            return Err(Error::input(
                argument,
                format!("upper 3x3 block is not a rotation (|RᵀR - I| = {worst:.2e}, det = {:.6})", rotation.determinant()),
            ));
        }
        let translation = DVec3::new(m[0][3], m[1][3], m[2][3]);
        let distance_m = translation.length();
        if distance_m.is_nan() || distance_m > MAX_TRANSLATION_M {
            return Err(Error::input(
                argument,
                format!("translation {:?} m is beyond {MAX_TRANSLATION_M:e} m of the world origin; re-centre the coordinates", translation.to_array()),
            ));
        }
        Ok(Self { rotation, translation })
    }

    /// The row-major 4x4 homogeneous matrix.
    pub fn to_matrix_rows(&self) -> [[f64; 4]; 4] {
        let r = self.rotation;
        let t = self.translation;
        [
            [r.x_axis.x, r.y_axis.x, r.z_axis.x, t.x],
            [r.x_axis.y, r.y_axis.y, r.z_axis.y, t.y],
            [r.x_axis.z, r.y_axis.z, r.z_axis.z, t.z],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    /// Maps a point from the source frame to the target frame.
    pub fn transform_point(&self, p_source: DVec3) -> DVec3 {
        self.rotation * p_source + self.translation
    }

    /// Maps a free vector (a force, a velocity) from the source frame to the target frame.
    pub fn transform_vector(&self, v_source: DVec3) -> DVec3 {
        self.rotation * v_source
    }

    /// The inverse transform `source_from_target`.
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.transpose();
        Self { rotation, translation: -(rotation * self.translation) }
    }

    /// Composition: `(a_from_b * b_from_c) = a_from_c`.
    pub fn compose(&self, b_from_c: &Self) -> Self {
        Self {
            rotation: self.rotation * b_from_c.rotation,
            translation: self.rotation * b_from_c.translation + self.translation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_optical_axes_map_to_flu() {
        let body_from_camera = Isometry3::body_from_forward_optical();
        // A point 2 m straight ahead of the lens is 2 m ahead of the body.
        assert_eq!(body_from_camera.transform_point(DVec3::new(0.0, 0.0, 2.0)), DVec3::new(2.0, 0.0, 0.0));
        // Image right is body right (-y); image down is body down (-z).
        assert_eq!(body_from_camera.transform_vector(DVec3::X), DVec3::NEG_Y);
        assert_eq!(body_from_camera.transform_vector(DVec3::Y), DVec3::NEG_Z);
        assert!((body_from_camera.rotation.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn matrix_round_trip_and_inverse() {
        let mut t = Isometry3::body_from_upward_optical();
        t.translation = DVec3::new(0.1, -0.2, 0.3);
        let back = Isometry3::from_matrix_rows("m", &t.to_matrix_rows()).unwrap();
        assert_eq!(back, t);
        let p = DVec3::new(1.0, 2.0, 3.0);
        let q = t.inverse().transform_point(t.transform_point(p));
        assert!((q - p).length() < 1e-12);
        assert!((t.compose(&t.inverse()).translation).length() < 1e-12);
    }

    #[test]
    fn rejects_non_rotation_and_nan() {
        let mut m = Isometry3::IDENTITY.to_matrix_rows();
        m[0][0] = 2.0;
        assert!(matches!(Isometry3::from_matrix_rows("body_from_camera", &m), Err(Error::InvalidInput { argument, .. }) if argument == "body_from_camera"));
        let mut m = Isometry3::IDENTITY.to_matrix_rows();
        m[1][3] = f64::NAN;
        assert!(Isometry3::from_matrix_rows("m", &m).is_err());
        let mut m = Isometry3::IDENTITY.to_matrix_rows();
        m[0][3] = 1e308;
        let err = Isometry3::from_matrix_rows("world_from_body", &m).unwrap_err().to_string();
        assert!(err.contains("world_from_body") && err.contains("re-centre"), "{err}");
        m[0][3] = 0.99 * MAX_TRANSLATION_M;
        assert!(Isometry3::from_matrix_rows("world_from_body", &m).is_ok());
        // A reflection is orthogonal but not a rotation.
        let mut m = Isometry3::IDENTITY.to_matrix_rows();
        m[2][2] = -1.0;
        assert!(Isometry3::from_matrix_rows("m", &m).is_err());
    }

    #[test]
    fn stamps_and_positions_beyond_any_world_name_their_argument() {
        // Probe findings: stamps of 1e308 s and goals 1e308 m away were taken everywhere.
        for bad in [1e308, -1e308, 1.0001e10, f64::NAN] {
            let err = check_stamp("stamp", bad).unwrap_err().to_string();
            assert!(err.contains("argument `stamp`") && err.contains("1e10 s"), "{err}");
        }
        assert!(check_stamp("stamp", MAX_STAMP_S).is_ok() && check_stamp("stamp", -1.0).is_ok());
        let err = check_position("goal", &[0.0, 1e308]).unwrap_err().to_string();
        assert!(err.contains("argument `goal`") && err.contains("re-centre"), "{err}");
        assert!(check_position("goal", &[f64::INFINITY]).is_err());
        // The distance from the origin, not each axis: (9e5, 9e5) is 1.27e6 m away.
        assert!(check_position("goal", &[0.0, -MAX_TRANSLATION_M]).is_ok());
        assert!(check_position("goal", &[0.9 * MAX_TRANSLATION_M, 0.9 * MAX_TRANSLATION_M]).is_err());
        assert!(check_position("goal", &[1e300, 1e300]).is_err());
    }
}
