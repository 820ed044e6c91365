//! The 2.5D voxel grid over a depth image and the per-voxel point counts (the observation).
//!
//! The image is cut into blocks of `k_w x k_h` pixels (column block `i`, row block `j`)
//! and the depth range `[d_min, d_max)` into `N_d` bins of `k_d` metres (bin `k`). A voxel
//! `(i, j, k)` has the flat [`StateId`] `(j·N_w + i)·N_d + k`; one more state, the last,
//! is `s_free` ("no obstacle inside the sensing horizon").

use glam::DVec3;

use crate::camera::PinholeCamera;
use crate::config::{GridConfig, VoxelPosition};
use crate::error::{Error, Result};

/// Added to `(z - d_min)/k_d` before the floor, so that a depth on a bin boundary lands in
/// the bin it starts: in floating point `(0.3 - 0.1)/0.1 = 1.9999999999999998`.
pub(super) const BIN_EPSILON: f64 = 1e-9;

/// Metres per raw unit of a `uint16` depth image accepted \[m/unit\]: 1 µm (a full scale of
/// 65 mm) to 1 m (65 km). Cameras use 0.1 mm to 1 mm; outside the range a value is a mistake
/// (a denormal scale puts every pixel at 0 m).
pub const DEPTH_SCALE_RANGE_M_PER_UNIT: (f64, f64) = (1e-6, 1.0);

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
    /// Smallest valid depth of the frame, in or out of range \[m\].
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
    /// How raw `u16` values fall into bins at `binning_scale`.
    binning: RawBinning,
    binning_scale: f64,
    /// Per-column counters of one block row while counting by edges.
    scratch: Vec<u16>,
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
            binning: RawBinning::Lut(Vec::new()), // built on the first u16 frame
            binning_scale: f64::NAN,
            scratch: Vec::new(),
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

    /// Depth of the centre of bin `k` \[m\].
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

    /// Centre of voxel `v` in the camera optical frame \[m\]: the block's centre pixel
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

    /// The block's top-left corner pixel `(i·k_w, j·k_h)` back-projected at the bin's near
    /// edge `d_min + k·k_d`, in the camera optical frame \[m\]: where the authors' code places
    /// a voxel (the conservative distance).
    pub fn voxel_near_corner_camera(&self, v: VoxelIndex) -> DVec3 {
        let (kw, kh) = (self.config.block_width_px, self.config.block_height_px);
        let near = self.config.depth_min_m + v.k as f64 * self.config.depth_bin_m;
        self.camera.back_project((v.i * kw) as f64, (v.j * kh) as f64, near)
    }

    /// The point of voxel `v` that a repulsive force comes from, in the camera optical frame \[m\].
    pub fn voxel_point_camera(&self, v: VoxelIndex, position: VoxelPosition) -> DVec3 {
        match position {
            VoxelPosition::NearCorner => self.voxel_near_corner_camera(v),
            VoxelPosition::Centre => self.voxel_centre_camera(v),
        }
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

    fn ensure_binning(&mut self, scale: f64) -> Result<()> {
        let (lo, hi) = DEPTH_SCALE_RANGE_M_PER_UNIT;
        if !(scale.is_finite() && (lo..=hi).contains(&scale)) {
            return Err(Error::input("scale", format!("metres per unit must be in [{lo:e}, {hi}] m/unit, got {scale:e}")));
        }
        if self.binning_scale == scale {
            return Ok(());
        }
        let none = self.n_d as u16;
        let lut: Vec<u16> = (0..=u16::MAX as u32)
            .map(|raw| if raw == 0 { none } else { self.bin_of_depth(raw as f64 * scale).map_or(none, |k| k as u16) })
            .collect();
        self.binning = RawBinning::from_lut(&lut, self.n_d);
        self.binning_scale = scale;
        Ok(())
    }

    /// Counts the valid in-range pixels of `image` (`width x height`) per voxel.
    pub fn count(&mut self, image: DepthImage<'_>, width: u32, height: u32) -> Result<VoxelCounts> {
        self.check_shape("depth", width, height, image.len())?;
        let mut counts = vec![0u32; self.voxel_count()];
        let (kw, kh) = (self.config.block_width_px as usize, self.config.block_height_px as usize);
        let w = width as usize;
        let n_d = self.n_d;
        let (valid, closest_depth_m) = match image {
            DepthImage::U16 { pixels, scale_m_per_unit } => {
                self.ensure_binning(scale_m_per_unit)?;
                let (valid, smallest_minus_one) = match &self.binning {
                    RawBinning::Edges(edges) => {
                        count_by_edges(pixels, w, kw, kh, self.n_w, n_d, edges, &mut self.scratch, &mut counts)
                    }
                    RawBinning::Lut(lut) => {
                        let mut valid = 0u64;
                        for (v, row) in pixels.chunks_exact(w).enumerate() {
                            let row_base = (v / kh) * self.n_w * n_d;
                            for (u, &raw) in row.iter().enumerate() {
                                valid += (raw != 0) as u64;
                                let k = lut[raw as usize] as usize;
                                if k < n_d {
                                    counts[row_base + (u / kw) * n_d + k] += 1;
                                }
                            }
                        }
                        // raw - 1 wraps 0 (no return) to the top, so the minimum is the nearest
                        // return; a separate pass, which the compiler vectorises.
                        (valid, pixels.iter().map(|&raw| raw.wrapping_sub(1)).min().unwrap_or(u16::MAX))
                    }
                };
                let closest = (valid > 0).then_some((smallest_minus_one as f64 + 1.0) * scale_m_per_unit);
                (valid, closest)
            }
            DepthImage::F32 { pixels } => {
                let mut closest = f64::INFINITY;
                let mut valid = 0u64;
                for (v, row) in pixels.chunks_exact(w).enumerate() {
                    let row_base = (v / kh) * self.n_w * n_d;
                    for (u, &z) in row.iter().enumerate() {
                        let z = z as f64;
                        if z.is_finite() && z > 0.0 {
                            valid += 1;
                            closest = closest.min(z);
                        }
                        if let Some(k) = self.bin_of_depth(z) {
                            counts[row_base + (u / kw) * n_d + k as usize] += 1;
                        }
                    }
                }
                (valid, (valid > 0).then_some(closest))
            }
        };
        let max_count = counts.iter().copied().max().unwrap_or(0);
        let in_range = counts.iter().map(|&c| c as u64).sum();
        Ok(VoxelCounts { counts, max_count, in_range, valid, closest_depth_m })
    }
}

/// How raw `u16` values map to depth bins for one scale.
#[derive(Debug, Clone)]
enum RawBinning {
    /// The bins are consecutive runs of raw values (always the case: the bin is a monotone
    /// function of the raw value inside one interval of valid values). `edges[0] = 0`, and
    /// `edges[1 + k]` is one less than the first raw value of bin `k` (`k = 0..=N_d`, bin
    /// `N_d` meaning "past the last bin"), so a pixel lies in bin `k` exactly when
    /// `edges[1 + k] < raw <= edges[2 + k]`, and it has a return when `raw > edges[0]`.
    Edges(Vec<u16>),
    /// Depth bin of every raw value, `N_d` = not counted (the general fallback).
    Lut(Vec<u16>),
}

impl RawBinning {
    /// The edges if the look-up table is a non-decreasing run of bins between two
    /// not-counted stretches, else the table itself.
    fn from_lut(lut: &[u16], n_d: usize) -> Self {
        let none = n_d as u16;
        let first = lut.iter().position(|&k| k != none);
        let Some(first) = first else {
            // Nothing is ever counted: every bin starts past the last raw value.
            return Self::Edges(std::iter::once(0).chain(std::iter::repeat_n(u16::MAX, n_d + 1)).collect());
        };
        let end = lut[first..].iter().position(|&k| k == none).map_or(lut.len(), |p| first + p);
        let run = &lut[first..end];
        let monotone = run.windows(2).all(|p| p[0] <= p[1]) && lut[end..].iter().all(|&k| k == none);
        if !monotone || first == 0 {
            return Self::Lut(lut.to_vec());
        }
        // starts[k] = first raw value whose bin is >= k, or `end`.
        let mut edges = Vec::with_capacity(n_d + 2);
        edges.push(0u16);
        for k in 0..n_d {
            let start = first + run.partition_point(|&b| (b as usize) < k);
            edges.push((start - 1) as u16);
        }
        edges.push((end - 1) as u16);
        Self::Edges(edges)
    }
}

/// Exact counting by bin edges: for every image column and edge `e`, the number of pixels
/// of a block row with `raw > e`; a block's count in bin `k` is then the number above bin
/// `k`'s lower edge minus the number above its upper edge. Branch-free and vectorisable
/// (no per-pixel scatter). Returns the number of pixels with a return and the smallest
/// `raw - 1` (wrapping, so no return counts as the largest value).
///
/// Each vector of pixels is loaded once and compared with every edge, the per-edge column
/// counters staying in registers down a block row (up to 16 edges, i.e. `N_d <= 14`; more
/// take a loop per edge). Edges and pixels are biased by 2^15 so that one signed compare
/// tests the unsigned order.
#[allow(clippy::too_many_arguments)]
fn count_by_edges(
    pixels: &[u16],
    w: usize,
    kw: usize,
    kh: usize,
    n_w: usize,
    n_d: usize,
    edges: &[u16],
    scratch: &mut Vec<u16>,
    counts: &mut [u32],
) -> (u64, u16) {
    // The only unsafe code of the crate: calls of the safe `#[target_feature]` kernels,
    // each after the runtime check of the features it is compiled with.
    #[cfg(target_arch = "x86_64")]
    #[allow(unsafe_code)]
    {
        if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512bw") {
            // SAFETY: the CPU supports AVX-512F and AVX-512BW (checked just above), the only
            // requirement of calling a function compiled with those target features.
            return unsafe { count_by_edges_avx512(pixels, w, kw, kh, n_w, n_d, edges, scratch, counts) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of
            // calling a function compiled with `target_feature(enable = "avx2")`.
            return unsafe { count_by_edges_avx2(pixels, w, kw, kh, n_w, n_d, edges, scratch, counts) };
        }
    }
    count_by_edges_impl::<16>(pixels, w, kw, kh, n_w, n_d, edges, scratch, counts, |_| {})
}

/// Asks for the cache line holding `pixel` (a hint: no fault, no effect on results).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse")]
#[inline]
fn prefetch(pixel: &u16) {
    std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((pixel as *const u16).cast());
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw")]
#[allow(clippy::too_many_arguments)]
fn count_by_edges_avx512(
    pixels: &[u16],
    w: usize,
    kw: usize,
    kh: usize,
    n_w: usize,
    n_d: usize,
    edges: &[u16],
    scratch: &mut Vec<u16>,
    counts: &mut [u32],
) -> (u64, u16) {
    count_by_edges_impl::<32>(pixels, w, kw, kh, n_w, n_d, edges, scratch, counts, |p| prefetch(p))
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
fn count_by_edges_avx2(
    pixels: &[u16],
    w: usize,
    kw: usize,
    kh: usize,
    n_w: usize,
    n_d: usize,
    edges: &[u16],
    scratch: &mut Vec<u16>,
    counts: &mut [u32],
) -> (u64, u16) {
    count_by_edges_impl::<16>(pixels, w, kw, kh, n_w, n_d, edges, scratch, counts, |p| prefetch(p))
}

/// Column counters of one strip of `L` columns down `rows` (a block row), for `NE` edges
/// biased by 2^15: `acc[k][l]` = pixels of column `l` above edge `k`. Also lowers `low` to
/// the smallest `raw - 1` seen (wrapping), and hints the same columns of the rows `ahead`
/// (the next block row) to the cache: the strips read down columns, which the hardware
/// prefetchers follow poorly when the frame comes from memory.
#[inline(always)]
fn strip_counts<const L: usize, const NE: usize>(
    rows: &[u16],
    ahead: &[u16],
    w: usize,
    c0: usize,
    biased_edges: &[i16],
    low: &mut [u16; L],
    prefetch: impl Fn(&u16),
) -> [[u16; L]; NE] {
    let mut e = [i16::MAX; NE];
    e.copy_from_slice(&biased_edges[..NE]);
    let mut acc = [[0u16; L]; NE];
    let mut lo = *low;
    let mut ahead = ahead.chunks_exact(w);
    for row in rows.chunks_exact(w) {
        if let Some(next) = ahead.next() {
            if let Some(p) = next.get(c0) {
                prefetch(p);
            }
        }
        let Some(x) = row.get(c0..c0 + L) else { break };
        let mut xs = [0i16; L];
        for l in 0..L {
            xs[l] = (x[l] ^ 0x8000) as i16;
            lo[l] = lo[l].min(x[l].wrapping_sub(1));
        }
        for k in 0..NE {
            for l in 0..L {
                acc[k][l] += (xs[l] > e[k]) as u16;
            }
        }
    }
    *low = lo;
    acc
}

/// The same for any number of edges, one edge at a time (the counters of one edge stay in
/// registers; the strip is read once per edge).
#[inline(always)]
fn strip_counts_any<const L: usize>(rows: &[u16], w: usize, c0: usize, biased_edges: &[i16], acc: &mut [u16], low: &mut [u16; L]) {
    for (k, &e) in biased_edges.iter().enumerate() {
        let mut a = [0u16; L];
        for row in rows.chunks_exact(w) {
            let Some(x) = row.get(c0..c0 + L) else { break };
            for l in 0..L {
                a[l] += (((x[l] ^ 0x8000) as i16) > e) as u16;
            }
        }
        acc[k * w + c0..k * w + c0 + L].copy_from_slice(&a);
    }
    for row in rows.chunks_exact(w) {
        for (lo, &x) in low.iter_mut().zip(&row[c0..c0 + L]) {
            *lo = (*lo).min(x.wrapping_sub(1));
        }
    }
}


#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn count_by_edges_impl<const L: usize>(
    pixels: &[u16],
    w: usize,
    kw: usize,
    kh: usize,
    n_w: usize,
    n_d: usize,
    edges: &[u16],
    scratch: &mut Vec<u16>,
    counts: &mut [u32],
    prefetch: impl Fn(&u16) + Copy,
) -> (u64, u16) {
    let n_e = edges.len();
    scratch.clear();
    scratch.resize(n_e * w, 0);
    let acc = &mut scratch[..];
    let biased: Vec<i16> = edges.iter().map(|&e| (e ^ 0x8000) as i16).collect();
    let mut valid = 0u64;
    let mut low = [u16::MAX; L];
    let mut low_tail = u16::MAX;
    let mut above = vec![0u32; n_e];
    // Rows are taken at most u16::MAX at a time so the column counters cannot overflow.
    let rows_total = pixels.len() / w.max(1);
    let mut v0 = 0;
    while v0 < rows_total {
        let j = v0 / kh;
        let v1 = ((j + 1) * kh).min(rows_total).min(v0 + u16::MAX as usize);
        let rows = &pixels[v0 * w..v1 * w];
        let ahead = &pixels[v1 * w..(v1 + (v1 - v0)).min(rows_total) * w];
        let strips = w / L;
        for c in 0..strips {
            let c0 = c * L;
            macro_rules! register_edges {
                ($($ne:literal)*) => {
                    match n_e {
                        $($ne => {
                            let a = strip_counts::<L, $ne>(rows, ahead, w, c0, &biased, &mut low, prefetch);
                            for (k, a) in a.iter().enumerate() {
                                acc[k * w + c0..k * w + c0 + L].copy_from_slice(a);
                            }
                        })*
                        _ => strip_counts_any::<L>(rows, w, c0, &biased, acc, &mut low),
                    }
                };
            }
            register_edges!(2 3 4 5 6 7 8 9 10 11 12 13 14 15 16);
        }
        let c0 = strips * L;
        if c0 < w {
            for (k, &e) in edges.iter().enumerate() {
                let a = &mut acc[k * w + c0..(k + 1) * w];
                a.fill(0);
                for row in rows.chunks_exact(w) {
                    for (a, &x) in a.iter_mut().zip(&row[c0..]) {
                        *a += (x > e) as u16;
                    }
                }
            }
            for row in rows.chunks_exact(w) {
                for &x in &row[c0..] {
                    low_tail = low_tail.min(x.wrapping_sub(1));
                }
            }
        }
        for i in 0..n_w {
            let (u0, u1) = (i * kw, ((i + 1) * kw).min(w));
            for (k, g) in above.iter_mut().enumerate() {
                *g = acc[k * w + u0..k * w + u1].iter().map(|&x| x as u32).sum();
            }
            valid += above[0] as u64;
            let out = &mut counts[(j * n_w + i) * n_d..][..n_d];
            for (k, o) in out.iter_mut().enumerate() {
                *o += above[1 + k] - above[2 + k];
            }
        }
        v0 = v1;
    }
    (valid, low.iter().copied().fold(low_tail, u16::min))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{GridConfig, PerceptionConfig};

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

    /// Per-pixel reference counting straight from the definition.
    fn reference_counts(g: &DepthVoxelGrid, img: &[u16], scale: f64) -> (Vec<u32>, u64) {
        let (n_w, _, n_d) = g.shape();
        let (kw, kh) = (g.config().block_width_px as usize, g.config().block_height_px as usize);
        let w = g.camera().width as usize;
        let mut counts = vec![0u32; g.voxel_count()];
        for (p, &raw) in img.iter().enumerate() {
            if raw == 0 {
                continue;
            }
            if let Some(k) = g.bin_of_depth(raw as f64 * scale) {
                counts[((p / w / kh) * n_w + (p % w) / kw) * n_d + k as usize] += 1;
            }
        }
        (counts, img.iter().filter(|&&r| r != 0).count() as u64)
    }

    #[test]
    fn counting_by_edges_equals_per_pixel_binning() {
        // Odd sizes (columns not a multiple of the vector chunk, partial edge blocks), scales
        // that put bin edges between raw values, and values across the whole u16 range.
        for (width, height, kw, kh, bin, lo, hi) in
            [(640u32, 480u32, 50u32, 50u32, 0.1, 0.1, 1.2), (97, 61, 7, 13, 0.07, 0.05, 3.0), (33, 5, 33, 2, 0.3, 0.0, 60.0)]
        {
            let camera = PinholeCamera::new(100.0, 100.0, width as f64 / 2.0, height as f64 / 2.0, width, height).unwrap();
            let config = GridConfig { block_width_px: kw, block_height_px: kh, depth_bin_m: bin, depth_min_m: lo, depth_max_m: hi };
            let mut g = DepthVoxelGrid::new(camera, config).unwrap();
            let n = (width * height) as u64;
            for (seed, scale) in [(1u64, 0.001), (2, 0.00025), (3, 0.0013), (4, 0.001)] {
                let img: Vec<u16> = (0..n)
                    .map(|p| {
                        let x = (p ^ seed).wrapping_mul(0x9e37_79b9_7f4a_7c15).rotate_left(29).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                        if seed == 4 { (x >> 48) as u16 } else { ((x >> 40) % 1700) as u16 }
                    })
                    .collect();
                let c = g.count(DepthImage::U16 { pixels: &img, scale_m_per_unit: scale }, width, height).unwrap();
                let (counts, valid) = reference_counts(&g, &img, scale);
                assert_eq!(c.counts, counts, "{width}x{height}, scale {scale}");
                assert_eq!(c.valid, valid);
                assert_eq!(c.in_range, counts.iter().map(|&x| x as u64).sum::<u64>());
            }
        }
    }

    #[test]
    fn every_instruction_set_counts_alike() {
        // The portable loop and each x86 copy this CPU can run, for register-resident edges
        // (flight: 13) and the per-edge loop (more than 16 edges), on odd widths.
        for (width, height, kw, kh, bin, lo, hi) in
            [(640u32, 480u32, 50u32, 50u32, 0.1, 0.1, 1.2), (97, 61, 7, 13, 0.07, 0.05, 3.0), (71, 9, 10, 4, 0.25, 0.2, 2.0)]
        {
            let camera = PinholeCamera::new(100.0, 100.0, width as f64 / 2.0, height as f64 / 2.0, width, height).unwrap();
            let config = GridConfig { block_width_px: kw, block_height_px: kh, depth_bin_m: bin, depth_min_m: lo, depth_max_m: hi };
            let mut g = DepthVoxelGrid::new(camera, config).unwrap();
            let img: Vec<u16> = (0..(width * height) as u64)
                .map(|p| ((p.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) % 3500) as u16)
                .collect();
            let c = g.count(DepthImage::U16 { pixels: &img, scale_m_per_unit: 0.001 }, width, height).unwrap();
            let (counts, valid) = reference_counts(&g, &img, 0.001);
            assert_eq!(c.counts, counts);
            let RawBinning::Edges(edges) = g.binning.clone() else { panic!("u16 bins are runs of raw values") };
            let (n_w, _, n_d) = g.shape();
            let smallest = img.iter().map(|&r| r.wrapping_sub(1)).min().unwrap();
            let mut variants: Vec<(&str, CountFn)> =
                vec![("portable", |p, w, kw, kh, n_w, n_d, e, s, c| count_by_edges_impl::<16>(p, w, kw, kh, n_w, n_d, e, s, c, |_| {}))];
            // Calls of the `#[target_feature]` kernels after the runtime feature checks.
            #[cfg(target_arch = "x86_64")]
            #[allow(unsafe_code)]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    variants.push(("avx2", |p, w, kw, kh, n_w, n_d, e, s, c| {
                        // SAFETY: AVX2 support was checked before this variant was added.
                        unsafe { count_by_edges_avx2(p, w, kw, kh, n_w, n_d, e, s, c) }
                    }));
                }
                if std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512bw") {
                    variants.push(("avx512", |p, w, kw, kh, n_w, n_d, e, s, c| {
                        // SAFETY: AVX-512F and AVX-512BW support was checked before this variant was added.
                        unsafe { count_by_edges_avx512(p, w, kw, kh, n_w, n_d, e, s, c) }
                    }));
                }
            }
            for (name, f) in variants {
                let mut out = vec![0u32; g.voxel_count()];
                let mut scratch = Vec::new();
                let got = f(&img, width as usize, kw as usize, kh as usize, n_w, n_d, &edges, &mut scratch, &mut out);
                assert_eq!(got, (valid, smallest), "{name}, {width}x{height}");
                assert_eq!(out, counts, "{name}, {width}x{height}");
            }
        }
    }

    type CountFn = fn(&[u16], usize, usize, usize, usize, usize, &[u16], &mut Vec<u16>, &mut [u32]) -> (u64, u16);

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
