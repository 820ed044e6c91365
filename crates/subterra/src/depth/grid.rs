//! The 2.5D voxel grid over a depth image and the per-voxel point counts (the observation).
//!
//! The image is cut into blocks of `k_w x k_h` pixels (column block `i`, row block `j`)
//! and the depth range `[d_min, d_max)` into `N_d` bins of `k_d` metres (bin `k`). A voxel
//! `(i, j, k)` has the flat [`StateId`] `(j·N_w + i)·N_d + k`; one more state, the last,
//! is `s_free` ("no obstacle inside the sensing horizon").

use glam::DVec3;

use crate::camera::PinholeCamera;
use crate::config::GridConfig;
use crate::error::{Error, Result};

/// Added to `(z - d_min)/k_d` before the floor, so that a depth on a bin boundary lands in
/// the bin it starts: in floating point `(0.3 - 0.1)/0.1 = 1.9999999999999998`.
pub const BIN_EPSILON: f64 = 1e-9;

/// Interleaved sub-histograms while counting: consecutive pixels of one block usually fall
/// in the same bin, and separate counters keep the increments from waiting on each other.
const COUNT_LANES: usize = 4; // the counting loop below is written out for four

/// A voxel of the grid: column block `i`, row block `j`, depth bin `k`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct VoxelIndex {
    /// Column block (along the image u axis).
    pub i: u32,
    /// Row block (along the image v axis).
    pub j: u32,
    /// Depth bin (0 is nearest).
    pub k: u32,
}

/// A flat state id: a voxel, or the free state (the last id).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StateId(pub u32);

/// A depth image borrowed from the caller, row-major `height x width`.
#[derive(Debug, Clone, Copy)]
pub enum DepthImage<'a> {
    /// Raw units; metres = raw · `scale_m_per_unit`. 0 means no return.
    U16 {
        /// Pixels, row-major.
        pixels: &'a [u16],
        /// Metres per unit (0.001 for millimetres).
        scale_m_per_unit: f64,
    },
    /// Metres. 0, NaN and ±inf mean no return.
    F32 {
        /// Pixels, row-major.
        pixels: &'a [f32],
    },
}

impl DepthImage<'_> {
    fn len(&self) -> usize {
        match self {
            Self::U16 { pixels, .. } => pixels.len(),
            Self::F32 { pixels } => pixels.len(),
        }
    }
}

/// The observation of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelCounts {
    /// Points per voxel, indexed by voxel state id (length `N_w·N_h·N_d`).
    pub counts: Vec<u32>,
    /// Largest count over all voxels.
    pub max_count: u32,
    /// Pixels with a valid depth inside `[d_min, d_max)`.
    pub in_range: u64,
    /// Pixels with any valid depth (finite, > 0).
    pub valid: u64,
    /// Smallest valid depth of the frame, in or out of range [m].
    pub closest_depth_m: Option<f64>,
}

/// Geometry of the grid for one camera, and the counting of a frame into it.
#[derive(Debug, Clone)]
pub struct DepthVoxelGrid {
    camera: PinholeCamera,
    config: GridConfig,
    n_w: usize,
    n_h: usize,
    n_d: usize,
    /// Pixels in each block `(j·N_w + i)`; smaller at the right and bottom edges.
    block_pixels: Vec<u32>,
    /// Depth bin of every `u16` value for the current scale; `N_d` = not counted.
    lut: Vec<u16>,
    lut_scale: f64,
    /// Lanes x blocks x (N_d + 1) counters, the last slot per block the "not counted" bin.
    scratch: Vec<u32>,
}

impl DepthVoxelGrid {
    /// A grid for `camera` cut as `config` says. The config must be valid.
    pub fn new(camera: PinholeCamera, config: GridConfig) -> Result<Self> {
        camera.validate()?;
        let n_w = camera.width.div_ceil(config.block_width_px) as usize;
        let n_h = camera.height.div_ceil(config.block_height_px) as usize;
        let n_d = ((config.depth_max_m - config.depth_min_m) / config.depth_bin_m).round() as usize;
        if n_d == 0 || n_d >= u16::MAX as usize {
            return Err(Error::config("grid.depth_bin_m", "gives no depth bin or too many", config.depth_bin_m));
        }
        let mut block_pixels = Vec::with_capacity(n_w * n_h);
        for j in 0..n_h {
            for i in 0..n_w {
                let w = (camera.width - i as u32 * config.block_width_px).min(config.block_width_px);
                let h = (camera.height - j as u32 * config.block_height_px).min(config.block_height_px);
                block_pixels.push(w * h);
            }
        }
        Ok(Self {
            camera,
            config,
            n_w,
            n_h,
            n_d,
            block_pixels,
            lut: Vec::new(),
            lut_scale: f64::NAN,
            scratch: vec![0; COUNT_LANES * n_w * n_h * (n_d + 1)],
        })
    }

    /// The camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// The grid config.
    pub fn config(&self) -> &GridConfig {
        &self.config
    }

    /// `(N_w, N_h, N_d)`.
    pub fn shape(&self) -> (usize, usize, usize) {
        (self.n_w, self.n_h, self.n_d)
    }

    /// Number of voxels `N_w·N_h·N_d`.
    pub fn voxel_count(&self) -> usize {
        self.n_w * self.n_h * self.n_d
    }

    /// Number of states: the voxels and the free state.
    pub fn state_count(&self) -> usize {
        self.voxel_count() + 1
    }

    /// The free state's id (the last).
    pub fn free_state(&self) -> StateId {
        StateId(self.voxel_count() as u32)
    }

    /// Flat id of a voxel. The index must be inside the grid.
    pub fn state_of(&self, v: VoxelIndex) -> StateId {
        StateId(((v.j as usize * self.n_w + v.i as usize) * self.n_d + v.k as usize) as u32)
    }

    /// The voxel of a state, `None` for the free state or an id past the grid.
    pub fn voxel_of(&self, s: StateId) -> Option<VoxelIndex> {
        let s = s.0 as usize;
        if s >= self.voxel_count() {
            return None;
        }
        let k = s % self.n_d;
        let block = s / self.n_d;
        Some(VoxelIndex { i: (block % self.n_w) as u32, j: (block / self.n_w) as u32, k: k as u32 })
    }

    /// Pixels in the image block of voxel `v` (`k_w·k_h` inside, fewer at the edges).
    pub fn block_pixel_count(&self, v: VoxelIndex) -> u32 {
        self.block_pixels[v.j as usize * self.n_w + v.i as usize]
    }

    /// Depth of the centre of bin `k` [m].
    pub fn bin_centre_m(&self, k: u32) -> f64 {
        self.config.depth_min_m + (k as f64 + 0.5) * self.config.depth_bin_m
    }

    /// The depth bin of a depth `z_m`, or `None` if it is no return or out of range.
    pub fn bin_of_depth(&self, z_m: f64) -> Option<u32> {
        if !(z_m.is_finite() && z_m > 0.0 && z_m < self.config.depth_max_m) {
            return None;
        }
        let k = ((z_m - self.config.depth_min_m) / self.config.depth_bin_m + BIN_EPSILON).floor();
        (k >= 0.0 && k < self.n_d as f64).then_some(k as u32)
    }

    /// Centre of voxel `v` in the camera optical frame [m]: the block's centre pixel
    /// back-projected at the bin's centre depth.
    pub fn voxel_centre_camera(&self, v: VoxelIndex) -> DVec3 {
        let (kw, kh) = (self.config.block_width_px, self.config.block_height_px);
        let u0 = v.i * kw;
        let u1 = ((v.i + 1) * kw).min(self.camera.width);
        let v0 = v.j * kh;
        let v1 = ((v.j + 1) * kh).min(self.camera.height);
        let u_c = (u0 + u1 - 1) as f64 / 2.0;
        let v_c = (v0 + v1 - 1) as f64 / 2.0;
        self.camera.back_project(u_c, v_c, self.bin_centre_m(v.k))
    }

    /// Distance from voxel `v` to the nearest of the grid's left, right, top, bottom and
    /// far faces, in voxels (1 on a face): the Manhattan distance to `s_free`.
    pub fn face_distance(&self, v: VoxelIndex) -> u32 {
        let (i, j, k) = (v.i as usize, v.j as usize, v.k as usize);
        [i + 1, self.n_w - i, j + 1, self.n_h - j, self.n_d - k].into_iter().min().unwrap_or(1) as u32
    }

    fn check_shape(&self, argument: &str, width: u32, height: u32, len: usize) -> Result<()> {
        if width != self.camera.width || height != self.camera.height {
            return Err(Error::ImageShapeMismatch {
                argument: argument.to_owned(),
                expected_height: self.camera.height,
                expected_width: self.camera.width,
                got_height: height,
                got_width: width,
            });
        }
        if len != self.camera.pixel_count() {
            return Err(Error::input(argument, format!("has {len} pixels, expected {}", self.camera.pixel_count())));
        }
        Ok(())
    }

    fn ensure_lut(&mut self, scale: f64) -> Result<()> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(Error::input("scale", format!("metres per unit must be finite and > 0, got {scale}")));
        }
        if self.lut_scale == scale {
            return Ok(());
        }
        let none = self.n_d as u16;
        self.lut = (0..=u16::MAX as u32)
            .map(|raw| if raw == 0 { none } else { self.bin_of_depth(raw as f64 * scale).map_or(none, |k| k as u16) })
            .collect();
        self.lut_scale = scale;
        Ok(())
    }

    /// Counts the valid in-range pixels of `image` (`width x height`) per voxel.
    pub fn count(&mut self, image: DepthImage<'_>, width: u32, height: u32) -> Result<VoxelCounts> {
        self.check_shape("depth", width, height, image.len())?;
        self.scratch.fill(0);
        let slots = self.n_d + 1;
        let lane_stride = self.n_w * self.n_h * slots;
        let (kw, kh) = (self.config.block_width_px as usize, self.config.block_height_px as usize);
        let w = width as usize;
        let (valid, closest_depth_m) = match image {
            DepthImage::U16 { pixels, scale_m_per_unit } => {
                self.ensure_lut(scale_m_per_unit)?;
                let lut = &self.lut[..];
                for (v, row) in pixels.chunks_exact(w).enumerate() {
                    let row_base = (v / kh) * self.n_w * slots;
                    for (i, segment) in row.chunks(kw).enumerate() {
                        let base = row_base + i * slots;
                        let (l0, rest) = self.scratch[base..].split_at_mut(lane_stride);
                        let (l1, rest) = rest.split_at_mut(lane_stride);
                        let (l2, l3) = rest.split_at_mut(lane_stride);
                        let (l0, l1, l2, l3) = (&mut l0[..slots], &mut l1[..slots], &mut l2[..slots], &mut l3[..slots]);
                        let mut quads = segment.chunks_exact(COUNT_LANES);
                        for q in &mut quads {
                            l0[lut[q[0] as usize] as usize] += 1;
                            l1[lut[q[1] as usize] as usize] += 1;
                            l2[lut[q[2] as usize] as usize] += 1;
                            l3[lut[q[3] as usize] as usize] += 1;
                        }
                        for &raw in quads.remainder() {
                            l0[lut[raw as usize] as usize] += 1;
                        }
                    }
                }
                // raw - 1 wraps 0 (no return) to the top, so the minimum is the nearest return;
                // a separate pass, which the compiler vectorises.
                let smallest_minus_one = pixels.iter().map(|&raw| raw.wrapping_sub(1)).min().unwrap_or(u16::MAX);
                let zeros = pixels.iter().filter(|&&raw| raw == 0).count() as u64;
                let valid = pixels.len() as u64 - zeros;
                let closest = (valid > 0).then(|| (smallest_minus_one as f64 + 1.0) * scale_m_per_unit);
                (valid, closest)
            }
            DepthImage::F32 { pixels } => {
                let mut closest = f64::INFINITY;
                let mut valid = 0u64;
                for (v, row) in pixels.chunks_exact(w).enumerate() {
                    let row_base = (v / kh) * self.n_w * slots;
                    for (u, &z) in row.iter().enumerate() {
                        let z = z as f64;
                        if z.is_finite() && z > 0.0 {
                            valid += 1;
                            closest = closest.min(z);
                        }
                        let k = self.bin_of_depth(z).map_or(self.n_d, |k| k as usize);
                        self.scratch[row_base + (u / kw) * slots + k] += 1;
                    }
                }
                (valid, (valid > 0).then_some(closest))
            }
        };
        let mut counts = vec![0u32; self.voxel_count()];
        for (block, out) in counts.chunks_exact_mut(self.n_d).enumerate() {
            for lane in 0..COUNT_LANES {
                let src = &self.scratch[lane * lane_stride + block * slots..][..self.n_d];
                for (o, s) in out.iter_mut().zip(src) {
                    *o += s;
                }
            }
        }
        let max_count = counts.iter().copied().max().unwrap_or(0);
        let in_range = counts.iter().map(|&c| c as u64).sum();
        Ok(VoxelCounts { counts, max_count, in_range, valid, closest_depth_m })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::PerceptionConfig;

    fn flight_grid() -> DepthVoxelGrid {
        DepthVoxelGrid::new(PinholeCamera::d435(), PerceptionConfig::flight().grid).unwrap()
    }

    #[test]
    fn flight_grid_shape_and_ids() {
        let g = flight_grid();
        assert_eq!(g.shape(), (13, 10, 11));
        assert_eq!(g.state_count(), 1431);
        let v = VoxelIndex { i: 2, j: 1, k: 2 };
        assert_eq!(g.state_of(v), StateId((13 + 2) * 11 + 2));
        assert_eq!(g.voxel_of(g.state_of(v)), Some(v));
        assert_eq!(g.voxel_of(g.free_state()), None);
        // The last column of a 640-px image is 40 px wide, the last row 30 px high.
        assert_eq!(g.block_pixel_count(VoxelIndex { i: 12, j: 0, k: 0 }), 40 * 50);
        assert_eq!(g.block_pixel_count(VoxelIndex { i: 12, j: 9, k: 0 }), 40 * 30);
        assert_eq!(g.block_pixel_count(VoxelIndex { i: 0, j: 0, k: 0 }), 2500);
    }

    #[test]
    fn depth_bins_by_hand() {
        let g = flight_grid();
        assert_eq!(g.bin_of_depth(0.1), Some(0));
        assert_eq!(g.bin_of_depth(0.3), Some(2)); // (0.3-0.1)/0.1 is 1.9999999999999998 in f64
        assert_eq!(g.bin_of_depth(0.35), Some(2));
        assert_eq!(g.bin_of_depth(1.199), Some(10));
        assert_eq!(g.bin_of_depth(1.2), None);
        assert_eq!(g.bin_of_depth(0.099), None);
        assert_eq!(g.bin_of_depth(f64::NAN), None);
        assert_eq!(g.bin_of_depth(0.0), None);
        assert!((g.bin_centre_m(0) - 0.15).abs() < 1e-12);
    }

    #[test]
    fn voxel_of_a_known_pixel() {
        let mut g = flight_grid();
        let mut img = vec![0u16; 640 * 480];
        img[60 * 640 + 120] = 350; // u=120, v=60, 0.35 m -> voxel (2, 1, 2)
        img[479 * 640 + 639] = 1199; // bottom-right pixel, bin 10
        img[0] = 1200; // at d_max: out of range
        img[1] = 99; // before d_min
        let c = g.count(DepthImage::U16 { pixels: &img, scale_m_per_unit: 0.001 }, 640, 480).unwrap();
        assert_eq!(c.counts[g.state_of(VoxelIndex { i: 2, j: 1, k: 2 }).0 as usize], 1);
        assert_eq!(c.counts[g.state_of(VoxelIndex { i: 12, j: 9, k: 10 }).0 as usize], 1);
        assert_eq!(c.in_range, 2);
        assert_eq!(c.valid, 4);
        assert_eq!(c.max_count, 1);
        assert!((c.closest_depth_m.unwrap() - 0.099).abs() < 1e-12);
    }

    #[test]
    fn float_and_u16_images_count_alike() {
        let mut g = flight_grid();
        let raw: Vec<u16> = (0..640u64 * 480).map(|p| ((p * 7919) % 1500) as u16).collect();
        let metres: Vec<f32> = raw.iter().map(|&r| if r == 0 { f32::NAN } else { r as f32 / 1000.0 }).collect();
        let a = g.count(DepthImage::U16 { pixels: &raw, scale_m_per_unit: 0.001 }, 640, 480).unwrap();
        let b = g.count(DepthImage::F32 { pixels: &metres }, 640, 480).unwrap();
        // f32 metres may round across a bin edge for a handful of values; the totals agree.
        assert_eq!(a.valid, b.valid);
        let differing: u32 = a.counts.iter().zip(&b.counts).map(|(x, y)| x.abs_diff(*y)).sum();
        assert!(differing <= 2 * 640 * 480 / 1500 * 12, "{differing}");
        let in_range = raw.iter().filter(|&&r| (100..1200).contains(&r)).count() as u64;
        assert_eq!(a.in_range, in_range);
    }

    #[test]
    fn shape_mismatch_is_an_error() {
        let mut g = flight_grid();
        let img = vec![0u16; 10];
        let err = g.count(DepthImage::U16 { pixels: &img, scale_m_per_unit: 0.001 }, 5, 2).unwrap_err();
        assert!(matches!(err, Error::ImageShapeMismatch { got_width: 5, .. }));
        let img = vec![0u16; 640 * 480];
        let err = g.count(DepthImage::U16 { pixels: &img, scale_m_per_unit: -1.0 }, 640, 480).unwrap_err();
        assert!(err.to_string().contains("scale"));
    }

    #[test]
    fn face_distance_counts_the_far_face_but_not_the_near_one() {
        let g = flight_grid();
        assert_eq!(g.face_distance(VoxelIndex { i: 0, j: 4, k: 5 }), 1); // left face
        assert_eq!(g.face_distance(VoxelIndex { i: 6, j: 4, k: 10 }), 1); // far face
        assert_eq!(g.face_distance(VoxelIndex { i: 6, j: 4, k: 0 }), 5); // near face does not count
    }
}
