//! Pinhole camera model (no distortion: depth cameras publish rectified images).

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::error::{require_positive, Error, Result};

/// Largest image side accepted \[px\]; beyond this a value is a mistake, not a camera.
const MAX_IMAGE_SIDE_PX: u32 = 16_384;
/// Largest image accepted \[px\]: 16.7 MP, four times the largest depth camera sold.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 24;
/// Focal lengths accepted \[px\]: below 1 px a pixel spans more than 90 degrees, above
/// 10^6 px the whole image is a pinhole's view of a few millidegrees.
const FOCAL_RANGE_PX: (f64, f64) = (1.0, 1e6);

/// Pinhole intrinsics of a depth camera in the optical frame (x right, y down, z forward).
/// Pixel `(u, v)` has its centre at integer coordinates (the OpenCV / ROS convention).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    /// Focal length along u \[px\].
    pub fx: f64,
    /// Focal length along v \[px\].
    pub fy: f64,
    /// Principal point u \[px\].
    pub cx: f64,
    /// Principal point v \[px\].
    pub cy: f64,
    /// Image width \[px\].
    pub width: u32,
    /// Image height \[px\].
    pub height: u32,
}

impl PinholeCamera {
    /// A validated camera.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: u32, height: u32) -> Result<Self> {
        let camera = Self { fx, fy, cx, cy, width, height };
        camera.validate()?;
        Ok(camera)
    }

    /// The simulated Intel RealSense D435 depth stream: 640x480, fx = fy = 385 px.
    pub fn d435() -> Self {
        Self { fx: 385.0, fy: 385.0, cx: 319.5, cy: 239.5, width: 640, height: 480 }
    }

    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        require_positive("camera.fx", self.fx)?;
        require_positive("camera.fy", self.fy)?;
        let (lo, hi) = FOCAL_RANGE_PX;
        for (field, f) in [("camera.fx", self.fx), ("camera.fy", self.fy)] {
            if !(lo..=hi).contains(&f) {
                return Err(Error::config(field, format!("must be in [{lo}, {hi:e}] px (a focal length in pixels)"), f));
            }
        }
        for (field, side) in [("camera.width", self.width), ("camera.height", self.height)] {
            if side == 0 || side > MAX_IMAGE_SIDE_PX {
                return Err(Error::config(field, format!("must be in 1..={MAX_IMAGE_SIDE_PX} px"), side));
            }
        }
        let pixels = u64::from(self.width) * u64::from(self.height);
        if pixels > MAX_IMAGE_PIXELS {
            return Err(Error::config("camera.height", format!("gives {pixels} pixels with camera.width = {}; at most {MAX_IMAGE_PIXELS}", self.width), self.height));
        }
        // The principal point lies on the image or near it (cropped or shifted sensors).
        for (field, c, side) in [("camera.cx", self.cx, self.width), ("camera.cy", self.cy, self.height)] {
            let side = f64::from(side);
            if !(c.is_finite() && (-side..=2.0 * side).contains(&c)) {
                return Err(Error::config(field, format!("must be finite and within one image size of the image ([{}, {}] px)", -side, 2.0 * side), c));
            }
        }
        Ok(())
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The point at pixel `(u, v)` with depth `z_m` along the optical axis, in the optical frame.
    pub fn back_project(&self, u: f64, v: f64, z_m: f64) -> DVec3 {
        DVec3::new((u - self.cx) * z_m / self.fx, (v - self.cy) * z_m / self.fy, z_m)
    }

    /// The pixel `(u, v)` where an optical-frame point projects, or `None` behind the camera.
    pub fn project(&self, p_camera: DVec3) -> Option<(f64, f64)> {
        (p_camera.z > 0.0).then(|| (self.fx * p_camera.x / p_camera.z + self.cx, self.fy * p_camera.y / p_camera.z + self.cy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn back_projection_inverts_projection() {
        let camera = PinholeCamera::d435();
        // The principal point is on the optical axis.
        assert_eq!(camera.back_project(319.5, 239.5, 2.0), DVec3::new(0.0, 0.0, 2.0));
        // 385 px right of it at 1 m depth is 1 m right.
        assert_eq!(camera.back_project(319.5 + 385.0, 239.5, 1.0), DVec3::new(1.0, 0.0, 1.0));
        let p = DVec3::new(-0.3, 0.2, 1.7);
        let (u, v) = camera.project(p).unwrap();
        assert!((camera.back_project(u, v, 1.7) - p).length() < 1e-12);
        assert!(camera.project(DVec3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn validation_names_the_field() {
        let err = PinholeCamera::new(0.0, 1.0, 0.0, 0.0, 10, 10).unwrap_err();
        assert!(err.to_string().contains("camera.fx"), "{err}");
        let err = PinholeCamera::new(1.0, 1.0, f64::NAN, 0.0, 10, 10).unwrap_err();
        assert!(err.to_string().contains("camera.cx"), "{err}");
        let err = PinholeCamera::new(1.0, 1.0, 0.0, 0.0, 0, 10).unwrap_err();
        assert!(err.to_string().contains("camera.width"), "{err}");
    }
}
