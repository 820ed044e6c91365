//! Ray-cast sensors: a pinhole depth camera and a spinning lidar.
//!
//! In: a [`World`], a sensor configuration and the sensor's pose in the world
//! (`world_from_camera` / `world_from_sensor`). Out: a noise-free [`DepthRender`] (depth
//! along the optical axis, the primitive hit and the incidence of every pixel) or a
//! [`LidarScan`] (points of the returns in the sensor frame). [`crate::noise`] turns
//! these into what a real sensor would report.
//!
//! The unit ray directions of every pixel / beam are computed once per configuration
//! ([`DepthCamera::new`], [`Lidar::new`]); a frame then costs one rotation and one ray
//! cast per ray and no allocation per ray. The free functions [`render_depth`] and
//! [`scan_lidar`] build those caches on every call: keep a [`DepthCamera`] / [`Lidar`]
//! when rendering many frames.

use glam::DVec3;
use subterra::{Isometry3, PinholeCamera};

use crate::error::{SimError, SimResult};
use crate::world::{FanCast, FanHit, FanLayout, FanSink, World};

/// D435 depth stream nearest usable depth [m] (Intel RealSense D400 datasheet: ~0.1 m at
/// 640x480 with the minimum disparity shift; the preset).
pub const D435_MIN_RANGE_M: f64 = 0.1;
/// D435 depth stream farthest depth kept [m] (the preset; stereo error beyond
/// grows quadratically, see [`crate::noise`]).
pub const D435_MAX_RANGE_M: f64 = 10.0;

/// Nearest range of the simulated spinning lidars [m] (VLP-16 / OS1 blind zone, rounded up).
pub const LIDAR_MIN_RANGE_M: f64 = 0.3;
/// VLP-16 farthest range [m] (Velodyne VLP-16 datasheet: 100 m).
pub const VLP16_MAX_RANGE_M: f64 = 100.0;
/// VLP-16 azimuth steps per revolution: 0.2° resolution at 10 Hz (datasheet).
pub const VLP16_AZIMUTH_STEPS: u32 = 1800;
/// OS1-64 farthest range [m] (Ouster OS1 datasheet: 120 m).
pub const OS1_MAX_RANGE_M: f64 = 120.0;
/// OS1-64 azimuth steps per revolution (the 1024 x 10 Hz mode; 2048 also exists).
pub const OS1_AZIMUTH_STEPS: u32 = 1024;
/// OS1-64 vertical field of view, half angle [deg] (Ouster OS1 Gen1: 33.2° uniform).
pub const OS1_HALF_FOV_DEG: f64 = 16.6;

/// Largest simulated depth image [px] (4.2 MP: 2048x2048; a frame is one ray per pixel).
const MAX_CAMERA_PIXELS: u64 = 1 << 22;
/// Most azimuth steps accepted; beyond this a value is a mistake, not a lidar.
const MAX_AZIMUTH_STEPS: u32 = 1 << 20;
/// Most rays per lidar revolution accepted (rings x azimuth steps): 4.2 M, 16 times an
/// OS1-128 at 2048 steps.
const MAX_LIDAR_RAYS: u64 = 1 << 22;

/// A depth camera: intrinsics and the depth range it reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthCameraConfig {
    /// Pinhole intrinsics (optical frame x right, y down, z forward; pixel centres at integer (u, v)).
    pub camera: PinholeCamera,
    /// Nearest depth reported [m]; nearer surfaces still occlude but give no return (depth 0).
    pub min_range_m: f64,
    /// Farthest depth reported, along the optical axis [m].
    pub max_range_m: f64,
}

impl DepthCameraConfig {
    /// Intel RealSense D435 depth stream: 640x480, fx = fy = 385 px, cx = 319.5, cy = 239.5, 0.1-10 m.
    pub fn d435() -> Self {
        Self { camera: PinholeCamera::d435(), min_range_m: D435_MIN_RANGE_M, max_range_m: D435_MAX_RANGE_M }
    }

    /// Checks every field: valid intrinsics (`camera.*`), `0 <= min_range_m < max_range_m`, both finite.
    pub fn validate(&self) -> SimResult<()> {
        self.camera.validate().map_err(core_to_sim)?;
        let pixels = self.camera.pixel_count() as u64;
        if pixels > MAX_CAMERA_PIXELS {
            return Err(SimError::config("camera.height", format!("gives {pixels} pixels to render each frame; the simulator renders at most {MAX_CAMERA_PIXELS}"), self.camera.height));
        }
        validate_range(self.min_range_m, self.max_range_m)
    }
}

/// Maps the core crate's config errors onto [`SimError::InvalidConfig`] so that every
/// bad parameter of the simulator surfaces the same way.
fn core_to_sim(error: subterra::Error) -> SimError {
    match error {
        subterra::Error::InvalidConfig { field, reason, value } => SimError::InvalidConfig { field, reason, value },
        other => SimError::Core(other),
    }
}

fn validate_range(min_range_m: f64, max_range_m: f64) -> SimResult<()> {
    if !(min_range_m.is_finite() && min_range_m >= 0.0) {
        return Err(SimError::config("min_range_m", "must be finite and >= 0 m", min_range_m));
    }
    if !(max_range_m.is_finite() && max_range_m > min_range_m) {
        return Err(SimError::config("max_range_m", format!("must be finite and > min_range_m = {min_range_m} m"), max_range_m));
    }
    Ok(())
}

/// A noise-free depth frame. Every buffer is row-major, `width * height` long; pixel
/// `(u, v)` is at index `v * width + u`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DepthRender {
    /// Image width [px].
    pub width: u32,
    /// Image height [px].
    pub height: u32,
    /// Depth along the optical axis (z of the hit point in the optical frame) [m];
    /// 0 = no return (nothing within range, or the nearest surface nearer than `min_range_m`).
    pub depth_m: Vec<f32>,
    /// Id of the primitive hit ([`crate::world::PrimitiveId`]), -1 where `depth_m` is 0.
    pub primitive: Vec<i32>,
    /// |cos| of the angle between the ray and the surface normal [1]: 1 head-on, 0 grazing;
    /// 0 where `depth_m` is 0.
    pub incidence_cos: Vec<f32>,
}

impl DepthRender {
    /// A frame with no return anywhere.
    pub fn empty(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self { width, height, depth_m: vec![0.0; n], primitive: vec![-1; n], incidence_cos: vec![0.0; n] }
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Number of pixels with a return.
    pub fn valid_count(&self) -> usize {
        self.depth_m.iter().filter(|&&z| z > 0.0).count()
    }
}

/// Converts a depth image in metres to the `uint16` millimetre encoding of ROS / RealSense
/// (`16UC1`): rounded to the nearest millimetre, 0 stays 0 (no return), depths beyond
/// 65.535 m and non-finite values become 0.
pub fn depth_to_millimetres(depth_m: &[f32]) -> Vec<u16> {
    depth_m
        .iter()
        .map(|&z| {
            let mm = (f64::from(z) * 1000.0).round();
            if mm.is_finite() && mm > 0.0 && mm <= f64::from(u16::MAX) {
                mm as u16
            } else {
                0
            }
        })
        .collect()
}

/// A depth camera with its per-pixel ray directions computed once.
#[derive(Debug, Clone)]
pub struct DepthCamera {
    config: DepthCameraConfig,
    /// Unit ray through each pixel centre, optical frame, row-major.
    rays_camera: Vec<DVec3>,
    /// Ray length at which each pixel's depth reaches `max_range_m` (`max_range_m / ray.z`) [m].
    ray_range: Vec<f64>,
    /// The pixels' rays split into fans (pose-free set-up of [`World`]'s fan casts).
    layout: FanLayout,
}

impl DepthCamera {
    /// Validates `config` and precomputes the unit ray through every pixel centre:
    /// `normalize((u - cx) / fx, (v - cy) / fy, 1)`.
    pub fn new(config: DepthCameraConfig) -> SimResult<Self> {
        config.validate()?;
        let c = config.camera;
        let mut rays_camera = Vec::with_capacity(c.pixel_count());
        for v in 0..c.height {
            let y = (f64::from(v) - c.cy) / c.fy;
            for u in 0..c.width {
                let x = (f64::from(u) - c.cx) / c.fx;
                rays_camera.push(DVec3::new(x, y, 1.0).normalize());
            }
        }
        let ray_range: Vec<f64> = rays_camera.iter().map(|r| config.max_range_m / r.z).collect();
        let layout = FanLayout::new(&rays_camera, &|k| ray_range[k]);
        Ok(Self { config, rays_camera, ray_range, layout })
    }

    /// The configuration.
    pub fn config(&self) -> &DepthCameraConfig {
        &self.config
    }

    /// The unit ray through pixel index `v * width + u`, optical frame; `None` outside the image.
    pub fn ray_camera(&self, pixel: usize) -> Option<DVec3> {
        self.rays_camera.get(pixel).copied()
    }

    /// Renders one frame seen from `world_from_camera` (optical frame). A pose with a
    /// non-finite value gives a frame with no return.
    pub fn render(&self, world: &World, world_from_camera: &Isometry3) -> DepthRender {
        let mut out = DepthRender::default();
        self.render_into(world, world_from_camera, &mut out);
        out
    }

    /// As [`Self::render`], reusing `out`'s buffers (no allocation once they have the size).
    pub fn render_into(&self, world: &World, world_from_camera: &Isometry3, out: &mut DepthRender) {
        if !pose_is_finite(world_from_camera) {
            self.prepare(out);
            return;
        }
        self.size(out);
        let (min_m, max_m) = (self.config.min_range_m, self.config.max_range_m);
        // ray.z > 0 for every pixel: the ray through the image plane z = 1.
        let ranges: &[f64] = &self.ray_range;
        let range = |k: usize| ranges[k];
        let rays: &[DVec3] = &self.rays_camera;
        let mut sink = DepthSink { first: 0, rays, depth: &mut out.depth_m, primitive: &mut out.primitive, incidence: &mut out.incidence_cos, min_m, max_m };
        let (origin, rotation) = (world_from_camera.translation, world_from_camera.rotation);
        world.cast_fan_cached::<true, _, _>(origin, rotation, rays, &self.layout, &range, &mut sink);
    }

    /// As [`Self::render`], splitting the rows over `threads` OS threads (scoped; 0 or 1
    /// renders on the calling thread). The per-pose set-up (culling the primitives per fan
    /// of rays) is done once, on the calling thread; the output is identical to [`Self::render`].
    pub fn render_parallel(&self, world: &World, world_from_camera: &Isometry3, threads: usize) -> DepthRender {
        let mut out = DepthRender::default();
        self.render_parallel_into(world, world_from_camera, threads, &mut out);
        out
    }

    /// As [`Self::render_parallel`], into `out`'s buffers (as [`Self::render_into`]).
    pub fn render_parallel_into(&self, world: &World, world_from_camera: &Isometry3, threads: usize, out: &mut DepthRender) {
        if !pose_is_finite(world_from_camera) {
            self.prepare(out);
            return;
        }
        self.size(out);
        let width = self.config.camera.width as usize;
        let height = self.config.camera.height as usize;
        let threads = threads.clamp(1, height.max(1));
        let cast = world.fan_cast(world_from_camera.translation, world_from_camera.rotation, &self.layout);
        if threads == 1 {
            self.render_span(&cast, 0, &mut out.depth_m, &mut out.primitive, &mut out.incidence_cos);
            return;
        }
        let chunk = height.div_ceil(threads) * width;
        let cast = &cast;
        std::thread::scope(|scope| {
            let spans = out.depth_m.chunks_mut(chunk).zip(out.primitive.chunks_mut(chunk)).zip(out.incidence_cos.chunks_mut(chunk));
            for (index, ((depth, primitive), incidence)) in spans.enumerate() {
                scope.spawn(move || self.render_span(cast, index * chunk, depth, primitive, incidence));
            }
        });
    }

    /// Sizes `out` to the image and clears it to "no return".
    fn prepare(&self, out: &mut DepthRender) {
        let n = self.rays_camera.len();
        out.width = self.config.camera.width;
        out.height = self.config.camera.height;
        out.depth_m.clear();
        out.depth_m.resize(n, 0.0);
        out.primitive.clear();
        out.primitive.resize(n, -1);
        out.incidence_cos.clear();
        out.incidence_cos.resize(n, 0.0);
    }

    /// Sizes `out` to the image, keeping whatever values it holds ([`Self::render_span`]
    /// writes every pixel).
    fn size(&self, out: &mut DepthRender) {
        let n = self.rays_camera.len();
        out.width = self.config.camera.width;
        out.height = self.config.camera.height;
        out.depth_m.resize(n, 0.0);
        out.primitive.resize(n, -1);
        out.incidence_cos.resize(n, 0.0);
    }

    /// Renders pixels `first..first + depth.len()` into the given slices, every pixel.
    fn render_span(&self, cast: &FanCast<'_>, first: usize, depth: &mut [f32], primitive: &mut [i32], incidence: &mut [f32]) {
        let (min_m, max_m) = (self.config.min_range_m, self.config.max_range_m);
        let span = first..first + depth.len();
        // ray.z > 0 for every pixel: the ray through the image plane z = 1.
        let ranges = self.ray_range.get(span.clone()).unwrap_or(&[]);
        let range = |k: usize| ranges[k.wrapping_sub(first)];
        let rays = self.rays_camera.get(span.clone()).unwrap_or(&[]);
        let mut sink = DepthSink { first, rays, depth, primitive, incidence, min_m, max_m };
        cast.cast::<true, _, _>(&self.rays_camera, span, &range, &mut sink);
    }
}

/// Writes the pixels of a span as [`World`]'s fan cast finds their hits.
struct DepthSink<'a> {
    /// Index of the span's first pixel (where the slices start).
    first: usize,
    rays: &'a [DVec3],
    depth: &'a mut [f32],
    primitive: &'a mut [i32],
    incidence: &'a mut [f32],
    min_m: f64,
    max_m: f64,
}

impl FanSink for DepthSink<'_> {
    #[inline(always)]
    fn put(&mut self, k: usize, dir: DVec3, hit: Option<FanHit>) {
        let i = k.wrapping_sub(self.first);
        let (Some(depth), Some(primitive), Some(incidence), Some(ray)) = (self.depth.get_mut(i), self.primitive.get_mut(i), self.incidence.get_mut(i), self.rays.get(i)) else {
            return;
        };
        let Some(hit) = hit else {
            (*depth, *primitive, *incidence) = (0.0, -1, 0.0);
            return;
        };
        let z = hit.t * ray.z;
        if !(z >= self.min_m && z <= self.max_m) {
            (*depth, *primitive, *incidence) = (0.0, -1, 0.0);
            return;
        }
        *depth = z as f32;
        *primitive = i32::try_from(hit.primitive).unwrap_or(-1);
        *incidence = dir.dot(hit.normal).abs().min(1.0) as f32;
    }
}

fn pose_is_finite(pose: &Isometry3) -> bool {
    pose.translation.is_finite() && pose.rotation.is_finite()
}

/// Renders a noise-free depth frame (optical frame x right, y down, z forward; a pixel's
/// ray passes through its centre `(u, v)`). Builds a [`DepthCamera`] per call; an invalid
/// `config` (see [`DepthCameraConfig::validate`]) gives an empty 0 x 0 frame — use
/// [`DepthCamera::new`] to get the error.
pub fn render_depth(world: &World, config: &DepthCameraConfig, world_from_camera: &Isometry3) -> DepthRender {
    match DepthCamera::new(*config) {
        Ok(camera) => camera.render(world, world_from_camera),
        Err(_) => DepthRender::default(),
    }
}

/// A spinning lidar: the elevation of each ring, the azimuth steps per revolution and the range.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarConfig {
    /// Elevation of each ring above the sensor's x-y plane [rad], ring index order; in [-π/2, π/2].
    pub vertical_angles_rad: Vec<f64>,
    /// Azimuth steps per revolution; step `k` points at azimuth `2π k / azimuth_steps` from +x toward +y.
    pub azimuth_steps: u32,
    /// Nearest range reported [m]; nearer surfaces occlude but give no return.
    pub min_range_m: f64,
    /// Farthest range [m].
    pub max_range_m: f64,
}

impl LidarConfig {
    /// Velodyne VLP-16: 16 rings from -15° to +15° every 2°, 1800 azimuth steps (0.2°), 0.3-100 m.
    pub fn vlp16() -> Self {
        Self {
            vertical_angles_rad: (0..16).map(|i| f64::from(-15 + 2 * i).to_radians()).collect(),
            azimuth_steps: VLP16_AZIMUTH_STEPS,
            min_range_m: LIDAR_MIN_RANGE_M,
            max_range_m: VLP16_MAX_RANGE_M,
        }
    }

    /// Ouster OS1-64: 64 rings spread uniformly over ±16.6°, 1024 azimuth steps, 0.3-120 m.
    pub fn os1_64() -> Self {
        let rings = 64;
        let step_deg = 2.0 * OS1_HALF_FOV_DEG / f64::from(rings - 1);
        Self {
            vertical_angles_rad: (0..rings).map(|i| (-OS1_HALF_FOV_DEG + step_deg * f64::from(i)).to_radians()).collect(),
            azimuth_steps: OS1_AZIMUTH_STEPS,
            min_range_m: LIDAR_MIN_RANGE_M,
            max_range_m: OS1_MAX_RANGE_M,
        }
    }

    /// Checks every field: at least one ring and at most 65 535, every elevation finite in
    /// [-π/2, π/2], `azimuth_steps >= 1`, `0 <= min_range_m < max_range_m`.
    pub fn validate(&self) -> SimResult<()> {
        let rings = self.vertical_angles_rad.len();
        if rings == 0 || rings > usize::from(u16::MAX) {
            return Err(SimError::config("vertical_angles_rad", "must hold 1..=65535 ring elevations", rings));
        }
        for (i, &angle) in self.vertical_angles_rad.iter().enumerate() {
            if !(angle.is_finite() && angle.abs() <= std::f64::consts::FRAC_PI_2) {
                return Err(SimError::config(format!("vertical_angles_rad[{i}]"), "must be finite, within [-π/2, π/2] rad", angle));
            }
        }
        if self.azimuth_steps == 0 || self.azimuth_steps > MAX_AZIMUTH_STEPS {
            return Err(SimError::config("azimuth_steps", format!("must be in 1..={MAX_AZIMUTH_STEPS}"), self.azimuth_steps));
        }
        if rings as u64 * u64::from(self.azimuth_steps) > MAX_LIDAR_RAYS {
            return Err(SimError::config("azimuth_steps", format!("rings x azimuth steps must be <= {MAX_LIDAR_RAYS}"), self.azimuth_steps));
        }
        validate_range(self.min_range_m, self.max_range_m)
    }

    /// Rays per revolution (rings x azimuth steps).
    pub fn ray_count(&self) -> usize {
        self.vertical_angles_rad.len() * self.azimuth_steps as usize
    }
}

/// One lidar revolution: the returns only, in firing order (azimuth step by azimuth
/// step, rings in config order within a step).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LidarScan {
    /// Points in the sensor frame FLU (x forward, y left, z up) [m].
    pub points_sensor: Vec<[f32; 3]>,
    /// Ring index of each point (index into [`LidarConfig::vertical_angles_rad`]).
    pub ring: Vec<u16>,
    /// Id of the primitive hit by each point.
    pub primitive: Vec<i32>,
}

impl LidarScan {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.points_sensor.len()
    }

    /// Whether there is no point.
    pub fn is_empty(&self) -> bool {
        self.points_sensor.is_empty()
    }

    fn clear(&mut self) {
        self.points_sensor.clear();
        self.ring.clear();
        self.primitive.clear();
    }
}

/// A spinning lidar with its beam directions computed once.
#[derive(Debug, Clone)]
pub struct Lidar {
    config: LidarConfig,
    /// Unit beam directions in the sensor frame, firing order.
    beams_sensor: Vec<DVec3>,
    /// Ring of each beam.
    beam_ring: Vec<u16>,
    /// The beams split into fans (pose-free set-up of [`World`]'s fan casts).
    layout: FanLayout,
}

impl Lidar {
    /// Validates `config` and precomputes the beam directions
    /// `(cos e cos a, cos e sin a, sin e)` for elevation `e` and azimuth `a = 2π k / steps`.
    pub fn new(config: LidarConfig) -> SimResult<Self> {
        config.validate()?;
        let n = config.ray_count();
        let mut beams_sensor = Vec::with_capacity(n);
        let mut beam_ring = Vec::with_capacity(n);
        let rings: Vec<(f64, f64)> = config.vertical_angles_rad.iter().map(|e| e.sin_cos()).collect();
        for k in 0..config.azimuth_steps {
            let azimuth = std::f64::consts::TAU * f64::from(k) / f64::from(config.azimuth_steps);
            let (sin_a, cos_a) = azimuth.sin_cos();
            for (ring, &(sin_e, cos_e)) in rings.iter().enumerate() {
                beams_sensor.push(DVec3::new(cos_e * cos_a, cos_e * sin_a, sin_e));
                // validate() bounds the ring count by u16::MAX.
                beam_ring.push(ring as u16);
            }
        }
        let max_m = config.max_range_m;
        let layout = FanLayout::new(&beams_sensor, &|_| max_m);
        Ok(Self { config, beams_sensor, beam_ring, layout })
    }

    /// The configuration.
    pub fn config(&self) -> &LidarConfig {
        &self.config
    }

    /// One revolution from `world_from_sensor` (sensor frame FLU). A non-finite pose gives no return.
    pub fn scan(&self, world: &World, world_from_sensor: &Isometry3) -> LidarScan {
        // Room for a return of every beam: no reallocation while the scan fills it.
        let n = self.beams_sensor.len();
        let mut out = LidarScan { points_sensor: Vec::with_capacity(n), ring: Vec::with_capacity(n), primitive: Vec::with_capacity(n) };
        self.scan_into(world, world_from_sensor, &mut out);
        out
    }

    /// As [`Self::scan`], reusing `out`'s buffers.
    pub fn scan_into(&self, world: &World, world_from_sensor: &Isometry3, out: &mut LidarScan) {
        out.clear();
        if !pose_is_finite(world_from_sensor) {
            return;
        }
        let rotation = world_from_sensor.rotation;
        let origin = world_from_sensor.translation;
        let (min_m, max_m) = (self.config.min_range_m, self.config.max_range_m);
        let mut sink = LidarSink { beams: &self.beams_sensor, rings: &self.beam_ring, out, min_m, max_m };
        world.cast_fan_cached::<false, _, _>(origin, rotation, &self.beams_sensor, &self.layout, &|_| max_m, &mut sink);
    }
}

/// Appends the returns of a scan as [`World`]'s fan cast finds them.
struct LidarSink<'a> {
    beams: &'a [DVec3],
    rings: &'a [u16],
    out: &'a mut LidarScan,
    min_m: f64,
    max_m: f64,
}

impl FanSink for LidarSink<'_> {
    #[inline(always)]
    fn put(&mut self, k: usize, _dir: DVec3, hit: Option<FanHit>) {
        let Some(hit) = hit else { return };
        let r = hit.t;
        if !(r >= self.min_m && r <= self.max_m) {
            return;
        }
        let (Some(beam), Some(&ring)) = (self.beams.get(k), self.rings.get(k)) else { return };
        let p = *beam * r;
        self.out.points_sensor.push([p.x as f32, p.y as f32, p.z as f32]);
        self.out.ring.push(ring);
        self.out.primitive.push(i32::try_from(hit.primitive).unwrap_or(-1));
    }
}

/// One noise-free lidar revolution seen from `world_from_sensor` (sensor frame FLU: x
/// forward, z up); points only for returns. Builds a [`Lidar`] per call; an invalid
/// `config` gives an empty scan — use [`Lidar::new`] to get the error.
pub fn scan_lidar(world: &World, config: &LidarConfig, world_from_sensor: &Isometry3) -> LidarScan {
    match Lidar::new(config.clone()) {
        Ok(lidar) => lidar.scan(world, world_from_sensor),
        Err(_) => LidarScan::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn d435_rays_pass_through_pixel_centres() {
        let camera = DepthCamera::new(DepthCameraConfig::d435()).unwrap();
        // Pixel (0, 0): ((0 - 319.5) / 385, (0 - 239.5) / 385, 1), normalised.
        let (x, y) = (-319.5 / 385.0, -239.5 / 385.0);
        let norm = (x * x + y * y + 1.0_f64).sqrt();
        let ray = camera.ray_camera(0).unwrap();
        assert!((ray - DVec3::new(x / norm, y / norm, 1.0 / norm)).length() < 1e-15);
        // Pixel (639, 479) is the mirror image of (0, 0) about the principal point.
        let last = camera.ray_camera(640 * 480 - 1).unwrap();
        assert!((last - DVec3::new(-x / norm, -y / norm, 1.0 / norm)).length() < 1e-15);
        // Pixel (319 + 385, 239): 384.5 px right of cx -> x/z = 384.5 / 385.
        let ray = camera.ray_camera(239 * 640 + 319).unwrap();
        assert!((ray.x / ray.z - (-0.5 / 385.0)).abs() < 1e-15);
        assert!(camera.ray_camera(640 * 480).is_none());
    }

    #[test]
    fn lidar_presets_match_datasheets() {
        let vlp = LidarConfig::vlp16();
        assert_eq!(vlp.vertical_angles_rad.len(), 16);
        assert!((vlp.vertical_angles_rad[0] - (-15.0_f64).to_radians()).abs() < 1e-15);
        assert!((vlp.vertical_angles_rad[15] - 15.0_f64.to_radians()).abs() < 1e-15);
        assert_eq!(vlp.ray_count(), 16 * 1800);
        let os1 = LidarConfig::os1_64();
        assert_eq!(os1.vertical_angles_rad.len(), 64);
        assert!((os1.vertical_angles_rad[0] + 16.6_f64.to_radians()).abs() < 1e-12);
        assert!((os1.vertical_angles_rad[63] - 16.6_f64.to_radians()).abs() < 1e-12);
        // Uniform spacing: 33.2° / 63.
        let step = os1.vertical_angles_rad[1] - os1.vertical_angles_rad[0];
        assert!((step - (33.2_f64 / 63.0).to_radians()).abs() < 1e-12);
        assert_eq!(os1.azimuth_steps, 1024);
        vlp.validate().unwrap();
        os1.validate().unwrap();
    }

    #[test]
    fn lidar_beams_fire_azimuth_by_azimuth() {
        let lidar = Lidar::new(LidarConfig { vertical_angles_rad: vec![0.0, 0.5], azimuth_steps: 4, min_range_m: 0.1, max_range_m: 10.0 }).unwrap();
        // Step 1 is 90° left (+y); ring 1 is 0.5 rad up.
        assert!((lidar.beams_sensor[2] - DVec3::Y).length() < 1e-15);
        assert!((lidar.beams_sensor[3] - DVec3::new(0.0, 0.5_f64.cos(), 0.5_f64.sin())).length() < 1e-15);
        assert_eq!(lidar.beam_ring, vec![0, 1, 0, 1, 0, 1, 0, 1]);
    }

    #[test]
    fn bad_configs_name_the_field() {
        let mut c = DepthCameraConfig::d435();
        c.camera.fx = f64::NAN;
        assert!(matches!(c.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "camera.fx"));
        let mut c = DepthCameraConfig::d435();
        c.min_range_m = -1.0;
        assert!(matches!(c.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "min_range_m"));
        let mut c = DepthCameraConfig::d435();
        c.max_range_m = 0.05;
        assert!(matches!(c.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "max_range_m"));
        let mut l = LidarConfig::vlp16();
        l.azimuth_steps = 0;
        assert!(matches!(l.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "azimuth_steps"));
        let mut l = LidarConfig::vlp16();
        l.vertical_angles_rad[3] = f64::NAN;
        assert!(matches!(l.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "vertical_angles_rad[3]"));
        let mut l = LidarConfig::vlp16();
        l.vertical_angles_rad.clear();
        assert!(matches!(l.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "vertical_angles_rad"));
    }

    #[test]
    fn render_into_a_used_buffer_equals_a_fresh_render() {
        let world = World::from_spec(crate::scenarios::generate("highbay", 1).unwrap()).unwrap();
        let camera = DepthCamera::new(DepthCameraConfig::d435()).unwrap();
        let centre = DVec3::from_array(world.region("A").unwrap().centre);
        let look = Isometry3::body_from_forward_optical().rotation;
        let near = Isometry3 { rotation: look, translation: centre };
        let far = Isometry3 { rotation: glam::DMat3::from_rotation_z(2.0) * look, translation: centre };
        let mut out = camera.render(&world, &near);
        assert!(out.valid_count() > 0);
        camera.render_into(&world, &far, &mut out);
        let fresh = camera.render(&world, &far);
        assert_eq!(out, fresh);
        assert_eq!(fresh, camera.render_parallel(&world, &far, 3));
        // And threaded, into the used buffer (twice: the second reuses the plans' memory).
        for _ in 0..2 {
            camera.render_parallel_into(&world, &near, 2, &mut out);
            assert_eq!(out, camera.render(&world, &near));
        }
        // A non-finite pose clears the buffer to "no return".
        camera.render_into(&world, &Isometry3 { rotation: look, translation: DVec3::NAN }, &mut out);
        assert_eq!(out, DepthRender::empty(640, 480));
    }

    #[test]
    fn millimetre_encoding_rounds_and_saturates() {
        assert_eq!(depth_to_millimetres(&[0.0, 1.2344, 1.2346, 65.535, 70.0, f32::NAN, -1.0]), vec![0, 1234, 1235, 65535, 0, 0, 0]);
    }
}
