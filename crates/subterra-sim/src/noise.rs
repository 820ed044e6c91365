//! Sensor noise: composable, seeded stages applied in order to a noise-free
//! [`DepthRender`] or [`LidarScan`].
//!
//! In: the noise-free output of [`crate::sensors`], the [`World`] (for the properties of
//! the primitive each pixel hit), and a random stream seeded by the caller. Out: the
//! depth image a real camera would report (metres, 0 = no return) or the lidar returns
//! that survive, moved along their rays.
//!
//! Each depth stage reads the current image (the output of the stages before it) and,
//! for the geometric rules (thin, grazing, dark), the truth of the render: which
//! primitive a pixel hit, its true depth and the incidence of the ray. Only pixels with a
//! return (depth > 0) are ever changed, except by [`DepthNoise::PhantomSpeckle`], whose
//! false returns may land on empty pixels. A noisy depth that falls to <= 0 becomes 0 (no
//! return): a depth image cannot hold a negative depth.
//!
//! Randomness is drawn only from the stream passed in, in a fixed order (stage by stage,
//! pixel index ascending), so the same seed gives the same bits.

use rand::Rng;
use rand_distr::{Distribution, Poisson, StandardNormal};

use crate::error::{SimError, SimResult};
use crate::sensors::{DepthCameraConfig, DepthRender, LidarScan};
use crate::world::World;

/// The paper's test noise σ [m]: Gaussian 0.2 m on every / every 2nd / every 10th pixel.
pub const PAPER_SIGMA_M: f64 = 0.2;

/// D435-like stereo RMS error, constant term `c` [m] (calibration and quantisation floor).
/// Approximation of Intel's depth RMS error `z² · subpixel / (f · baseline)`; see [`D435_STEREO_Q_PER_M`].
pub const D435_STEREO_C_M: f64 = 0.001;
/// D435-like stereo RMS error, linear term `l` [m/m] (texture- and filter-dependent part).
pub const D435_STEREO_L: f64 = 0.002;
/// D435-like stereo RMS error, quadratic term `q` [1/m]: `subpixel / (f · baseline)` with
/// f = 385 px, baseline 50 mm and a subpixel accuracy of ≈ 0.05 px (Intel, "Tuning depth
/// cameras for best performance", RMS error formula) gives 0.0026 /m, rounded to 0.0025.
pub const D435_STEREO_Q_PER_M: f64 = 0.0025;
/// D435-like fraction of valid pixels randomly lost (holes in low-texture patches).
pub const D435_DROPOUT_PROBABILITY: f64 = 0.02;
/// D435-like narrowest structure that still gets depth [px]: stereo matching windows
/// (a few pixels wide) lose anything narrower than about two pixels.
pub const D435_MIN_WIDTH_PX: f64 = 2.0;
/// D435-like largest angle between ray and surface normal that still gets depth [rad] (80°).
pub const D435_MAX_INCIDENCE_RAD: f64 = 80.0 * std::f64::consts::PI / 180.0;
/// D435-like depth jump that marks an edge for flying pixels [m].
pub const D435_EDGE_JUMP_M: f64 = 0.25;
/// D435-like probability that an edge pixel flies [1].
pub const D435_FLYING_PROBABILITY: f64 = 0.5;
/// Phantom speckle: mean number of blobs per frame [1/frame].
pub const PHANTOM_BLOBS_PER_FRAME: f64 = 1.0;
/// Phantom speckle: blob radius [px].
pub const PHANTOM_RADIUS_PX: f64 = 6.0;
/// Phantom speckle: nearest false depth [m].
pub const PHANTOM_MIN_DEPTH_M: f64 = 0.3;
/// Phantom speckle: farthest false depth [m].
pub const PHANTOM_MAX_DEPTH_M: f64 = 1.5;

/// Most phantom blobs per frame accepted (a mean beyond this is a mistake).
const MAX_BLOBS_PER_FRAME: f64 = 10_000.0;
/// Largest phantom blob radius accepted [px].
const MAX_BLOB_RADIUS_PX: f64 = 4096.0;

/// One stage of depth-camera noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DepthNoise {
    /// The paper's test noise: Gaussian `N(0, sigma_m²)` added to every pixel whose
    /// row-major index is a multiple of `every_n` (1: every pixel, 2: every 2nd, ...) and
    /// that has a return.
    PaperGaussian {
        /// Standard deviation [m], >= 0.
        sigma_m: f64,
        /// Period of the pattern [px], >= 1.
        every_n: u32,
    },
    /// Stereo depth noise growing with depth: `N(0, σ(z)²)` with `σ = c_m + l·z + q_per_m·z²`,
    /// `z` the pixel's current depth, on every pixel with a return.
    Stereo {
        /// Constant term [m], >= 0.
        c_m: f64,
        /// Linear term [m/m], >= 0.
        l: f64,
        /// Quadratic term [1/m], >= 0.
        q_per_m: f64,
    },
    /// Each pixel with a return loses it with `probability`, independently.
    Dropout {
        /// Probability in [0, 1].
        probability: f64,
    },
    /// No return on structures narrower than `min_width_px` in the image: a pixel whose
    /// primitive has a projected width `width_m · fx / z` (true depth z) below it.
    ThinNoReturn {
        /// Narrowest width that still returns [px], >= 0.
        min_width_px: f64,
    },
    /// No return where the angle between the ray and the surface normal exceeds `max_angle_rad`.
    GrazingNoReturn {
        /// Largest incidence angle that still returns [rad], in [0, π/2].
        max_angle_rad: f64,
    },
    /// No return on dark (light-absorbing) primitives.
    DarkNoReturn,
    /// Flying pixels at depth edges: a pixel with a return whose 4-neighbour (with a return)
    /// differs by more than `edge_jump_m` takes, with `probability`, a depth drawn uniformly
    /// between its own and that neighbour's (the neighbour with the largest jump).
    FlyingPixels {
        /// Depth difference that makes an edge [m], > 0.
        edge_jump_m: f64,
        /// Probability in [0, 1].
        probability: f64,
    },
    /// Phantom speckle: a Poisson number (mean `blobs_per_frame`) of roughly circular
    /// blobs of false near returns, centred uniformly in the image (continuous
    /// coordinates), each of one depth drawn uniformly in `[min_depth_m, max_depth_m]`.
    /// A blob covers the pixels whose centres lie within `radius_px` of its centre (a
    /// pixelised disk of about π·radius_px² pixels); it replaces a pixel's depth where it
    /// is nearer than the current one or where there is no return.
    PhantomSpeckle {
        /// Mean blobs per frame [1/frame], in [0, 10000].
        blobs_per_frame: f64,
        /// Blob radius [px], in (0, 4096].
        radius_px: f64,
        /// Nearest false depth [m], > 0.
        min_depth_m: f64,
        /// Farthest false depth [m], >= min_depth_m.
        max_depth_m: f64,
    },
}

impl DepthNoise {
    /// Checks the parameters; `field` prefixes the names in the error (e.g. `stages[2]`).
    pub fn validate(&self, field: &str) -> SimResult<()> {
        match *self {
            DepthNoise::PaperGaussian { sigma_m, every_n } => {
                non_negative(field, "sigma_m", sigma_m)?;
                if every_n == 0 {
                    return Err(SimError::config(format!("{field}.every_n"), "must be >= 1", every_n));
                }
                Ok(())
            }
            DepthNoise::Stereo { c_m, l, q_per_m } => {
                non_negative(field, "c_m", c_m)?;
                non_negative(field, "l", l)?;
                non_negative(field, "q_per_m", q_per_m)
            }
            DepthNoise::Dropout { probability } => probability_in_range(field, "probability", probability),
            DepthNoise::ThinNoReturn { min_width_px } => non_negative(field, "min_width_px", min_width_px),
            DepthNoise::GrazingNoReturn { max_angle_rad } => {
                if !(max_angle_rad.is_finite() && (0.0..=std::f64::consts::FRAC_PI_2).contains(&max_angle_rad)) {
                    return Err(SimError::config(format!("{field}.max_angle_rad"), "must be finite, in [0, π/2] rad", max_angle_rad));
                }
                Ok(())
            }
            DepthNoise::DarkNoReturn => Ok(()),
            DepthNoise::FlyingPixels { edge_jump_m, probability } => {
                if !(edge_jump_m.is_finite() && edge_jump_m > 0.0) {
                    return Err(SimError::config(format!("{field}.edge_jump_m"), "must be finite and > 0 m", edge_jump_m));
                }
                probability_in_range(field, "probability", probability)
            }
            DepthNoise::PhantomSpeckle { blobs_per_frame, radius_px, min_depth_m, max_depth_m } => {
                if !(blobs_per_frame.is_finite() && (0.0..=MAX_BLOBS_PER_FRAME).contains(&blobs_per_frame)) {
                    return Err(SimError::config(
                        format!("{field}.blobs_per_frame"),
                        format!("must be finite, in [0, {MAX_BLOBS_PER_FRAME}]"),
                        blobs_per_frame,
                    ));
                }
                if !(radius_px.is_finite() && radius_px > 0.0 && radius_px <= MAX_BLOB_RADIUS_PX) {
                    return Err(SimError::config(format!("{field}.radius_px"), format!("must be finite, in (0, {MAX_BLOB_RADIUS_PX}] px"), radius_px));
                }
                if !(min_depth_m.is_finite() && min_depth_m > 0.0) {
                    return Err(SimError::config(format!("{field}.min_depth_m"), "must be finite and > 0 m", min_depth_m));
                }
                if !(max_depth_m.is_finite() && max_depth_m >= min_depth_m) {
                    return Err(SimError::config(format!("{field}.max_depth_m"), format!("must be finite and >= min_depth_m = {min_depth_m} m"), max_depth_m));
                }
                Ok(())
            }
        }
    }
}

fn non_negative(prefix: &str, name: &str, value: f64) -> SimResult<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimError::config(format!("{prefix}.{name}"), "must be finite and >= 0", value))
    }
}

fn probability_in_range(prefix: &str, name: &str, value: f64) -> SimResult<()> {
    if value.is_finite() && (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(SimError::config(format!("{prefix}.{name}"), "must be a probability in [0, 1]", value))
    }
}

/// The names accepted by [`DepthNoiseModel::preset`].
pub const DEPTH_NOISE_PRESETS: [&str; 6] = ["none", "paper-every-pixel", "paper-every-2nd", "paper-every-10th", "d435", "d435-phantom"];

/// A chain of depth noise stages, applied in order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DepthNoiseModel {
    /// The stages, first applied first.
    pub stages: Vec<DepthNoise>,
}

impl DepthNoiseModel {
    /// A validated model.
    pub fn new(stages: Vec<DepthNoise>) -> SimResult<Self> {
        let model = Self { stages };
        model.validate()?;
        Ok(model)
    }

    /// Checks every stage; errors name the field as `stages[i].name`.
    pub fn validate(&self) -> SimResult<()> {
        for (i, stage) in self.stages.iter().enumerate() {
            stage.validate(&format!("stages[{i}]"))?;
        }
        Ok(())
    }

    /// A named preset (see [`DEPTH_NOISE_PRESETS`]):
    /// - `none`: no stage;
    /// - `paper-every-pixel`, `paper-every-2nd`, `paper-every-10th`: the paper's Gaussian
    ///   σ = 0.2 m on every / every 2nd / every 10th pixel;
    /// - `d435`: dark, thin (< 2 px), grazing (> 80°) no-return, flying pixels (jump 0.25 m,
    ///   p = 0.5), stereo σ = 0.001 + 0.002 z + 0.0025 z², dropout 2 %, in that order;
    /// - `d435-phantom`: `d435` then phantom speckle (1 blob/frame, radius 6 px, 0.3-1.5 m).
    pub fn preset(name: &str) -> SimResult<Self> {
        let paper = |every_n| Self { stages: vec![DepthNoise::PaperGaussian { sigma_m: PAPER_SIGMA_M, every_n }] };
        let d435 = || {
            vec![
                DepthNoise::DarkNoReturn,
                DepthNoise::ThinNoReturn { min_width_px: D435_MIN_WIDTH_PX },
                DepthNoise::GrazingNoReturn { max_angle_rad: D435_MAX_INCIDENCE_RAD },
                DepthNoise::FlyingPixels { edge_jump_m: D435_EDGE_JUMP_M, probability: D435_FLYING_PROBABILITY },
                DepthNoise::Stereo { c_m: D435_STEREO_C_M, l: D435_STEREO_L, q_per_m: D435_STEREO_Q_PER_M },
                DepthNoise::Dropout { probability: D435_DROPOUT_PROBABILITY },
            ]
        };
        match name {
            "none" => Ok(Self::default()),
            "paper-every-pixel" => Ok(paper(1)),
            "paper-every-2nd" => Ok(paper(2)),
            "paper-every-10th" => Ok(paper(10)),
            "d435" => Ok(Self { stages: d435() }),
            "d435-phantom" => {
                let mut stages = d435();
                stages.push(DepthNoise::PhantomSpeckle {
                    blobs_per_frame: PHANTOM_BLOBS_PER_FRAME,
                    radius_px: PHANTOM_RADIUS_PX,
                    min_depth_m: PHANTOM_MIN_DEPTH_M,
                    max_depth_m: PHANTOM_MAX_DEPTH_M,
                });
                Ok(Self { stages })
            }
            _ => Err(SimError::Unknown { what: "depth noise preset".into(), name: name.into(), known: DEPTH_NOISE_PRESETS.join(", ") }),
        }
    }

    /// The noisy depth image [m] (row-major, 0 = no return). Never fails: an invalid
    /// model or a render whose buffers do not match its size gives the render's depth
    /// unchanged — call [`Self::try_apply`] to get the error instead.
    pub fn apply<R: Rng + ?Sized>(&self, render: &DepthRender, world: &World, config: &DepthCameraConfig, rng: &mut R) -> Vec<f32> {
        self.try_apply(render, world, config, rng).unwrap_or_else(|_| render.depth_m.clone())
    }

    /// As [`Self::apply`], with errors: an invalid stage ([`SimError::InvalidConfig`]) or a
    /// render whose buffers are not `width * height` long ([`SimError::InvalidInput`]).
    pub fn try_apply<R: Rng + ?Sized>(&self, render: &DepthRender, world: &World, config: &DepthCameraConfig, rng: &mut R) -> SimResult<Vec<f32>> {
        self.validate()?;
        let n = render.pixel_count();
        if render.depth_m.len() != n || render.primitive.len() != n || render.incidence_cos.len() != n {
            return Err(SimError::input(
                "render",
                format!(
                    "buffers must hold width x height = {n} pixels, got depth {}, primitive {}, incidence {}",
                    render.depth_m.len(),
                    render.primitive.len(),
                    render.incidence_cos.len()
                ),
            ));
        }
        let mut depth = render.depth_m.clone();
        for stage in &self.stages {
            apply_stage(stage, &mut depth, render, world, config, rng);
        }
        Ok(depth)
    }
}

fn apply_stage<R: Rng + ?Sized>(stage: &DepthNoise, depth: &mut [f32], render: &DepthRender, world: &World, config: &DepthCameraConfig, rng: &mut R) {
    match *stage {
        DepthNoise::PaperGaussian { sigma_m, every_n } => {
            for z in depth.iter_mut().step_by(every_n.max(1) as usize) {
                if *z > 0.0 {
                    *z = positive_or_zero(f64::from(*z) + sigma_m * standard_normal(rng));
                }
            }
        }
        DepthNoise::Stereo { c_m, l, q_per_m } => {
            for z in depth.iter_mut().filter(|z| **z > 0.0) {
                let zf = f64::from(*z);
                let sigma = c_m + l * zf + q_per_m * zf * zf;
                *z = positive_or_zero(zf + sigma * standard_normal(rng));
            }
        }
        DepthNoise::Dropout { probability } => {
            for z in depth.iter_mut().filter(|z| **z > 0.0) {
                if uniform(rng) < probability {
                    *z = 0.0;
                }
            }
        }
        DepthNoise::ThinNoReturn { min_width_px } => {
            let fx = config.camera.fx;
            for ((z, &id), &z_true) in depth.iter_mut().zip(&render.primitive).zip(&render.depth_m) {
                if *z > 0.0 && z_true > 0.0 {
                    let width_m = primitive_width(world, id);
                    if width_m * fx / f64::from(z_true) < min_width_px {
                        *z = 0.0;
                    }
                }
            }
        }
        DepthNoise::GrazingNoReturn { max_angle_rad } => {
            let min_cos = max_angle_rad.cos();
            for (z, &cos) in depth.iter_mut().zip(&render.incidence_cos) {
                // Compared on the angle's cosine: angle > max  <=>  cos < cos(max).
                if *z > 0.0 && f64::from(cos) < min_cos {
                    *z = 0.0;
                }
            }
        }
        DepthNoise::DarkNoReturn => {
            for (z, &id) in depth.iter_mut().zip(&render.primitive) {
                if *z > 0.0 && primitive_dark(world, id) {
                    *z = 0.0;
                }
            }
        }
        DepthNoise::FlyingPixels { edge_jump_m, probability } => flying_pixels(depth, render.width as usize, edge_jump_m, probability, rng),
        DepthNoise::PhantomSpeckle { blobs_per_frame, radius_px, min_depth_m, max_depth_m } => {
            let blobs = poisson(rng, blobs_per_frame);
            for _ in 0..blobs {
                let centre_u = uniform(rng) * f64::from(render.width) - 0.5;
                let centre_v = uniform(rng) * f64::from(render.height) - 0.5;
                let blob_depth = (min_depth_m + uniform(rng) * (max_depth_m - min_depth_m)) as f32;
                stamp_blob(depth, render.width, render.height, centre_u, centre_v, radius_px, blob_depth);
            }
        }
    }
}

/// A noisy depth as f32, or 0 (no return) when it fell to or below zero.
fn positive_or_zero(z: f64) -> f32 {
    if z > 0.0 {
        z as f32
    } else {
        0.0
    }
}

/// `width_m` of the primitive, or infinity (never thin) when the id is unknown.
fn primitive_width(world: &World, id: i32) -> f64 {
    u32::try_from(id).ok().and_then(|id| world.primitive(id)).map_or(f64::INFINITY, |p| p.width_m)
}

fn primitive_dark(world: &World, id: i32) -> bool {
    u32::try_from(id).ok().and_then(|id| world.primitive(id)).is_some_and(|p| p.dark)
}

fn flying_pixels<R: Rng + ?Sized>(depth: &mut [f32], width: usize, edge_jump_m: f64, probability: f64, rng: &mut R) {
    if width == 0 {
        return;
    }
    let before = depth.to_vec();
    let height = before.len() / width;
    let jump = edge_jump_m as f32;
    // Pass 1: mark the pixels with a return that have a 4-neighbour with a return more than
    // `jump` away (each pair is tested once). Most pixels are not on an edge; only the
    // marked ones take the per-pixel path below, in pixel order, so the random stream is
    // consumed exactly as a plain scan over every pixel would.
    let jumps = |a: f32, b: f32| a > 0.0 && b > 0.0 && (a - b).abs() > jump;
    let mut edge = vec![false; before.len()];
    for v in 0..height {
        let row = &before[v * width..(v + 1) * width];
        for u in 0..width.saturating_sub(1) {
            if jumps(row[u], row[u + 1]) {
                edge[v * width + u] = true;
                edge[v * width + u + 1] = true;
            }
        }
        if v + 1 < height {
            let next = &before[(v + 1) * width..(v + 2) * width];
            for u in 0..width {
                if jumps(row[u], next[u]) {
                    edge[v * width + u] = true;
                    edge[(v + 1) * width + u] = true;
                }
            }
        }
    }
    for (p, _) in edge.iter().enumerate().filter(|(_, &e)| e) {
        let (v, u) = (p / width, p % width);
        let z = before[p];
        // The 4-neighbour with a return and the largest jump above `jump`.
        let mut largest = jump;
        let mut other = 0.0_f32;
        let mut consider = |zq: f32| {
            if zq > 0.0 && (zq - z).abs() > largest {
                largest = (zq - z).abs();
                other = zq;
            }
        };
        if u > 0 {
            consider(before[p - 1]);
        }
        if u + 1 < width {
            consider(before[p + 1]);
        }
        if v > 0 {
            consider(before[p - width]);
        }
        if v + 1 < height {
            consider(before[p + width]);
        }
        if other > 0.0 && uniform(rng) < probability {
            let (z, zq) = (f64::from(z), f64::from(other));
            depth[p] = (z + uniform(rng) * (zq - z)) as f32;
        }
    }
}

/// Writes `blob_depth` into the pixels whose centres lie within `radius_px` of
/// (`centre_u`, `centre_v`) [px], where it is nearer than the current depth or there is none.
fn stamp_blob(depth: &mut [f32], width: u32, height: u32, centre_u: f64, centre_v: f64, radius_px: f64, blob_depth: f32) {
    let clamp = |x: f64, side: u32| x.clamp(0.0, f64::from(side) - 1.0) as usize;
    let (u0, u1) = (clamp((centre_u - radius_px).floor(), width), clamp((centre_u + radius_px).ceil(), width));
    let (v0, v1) = (clamp((centre_v - radius_px).floor(), height), clamp((centre_v + radius_px).ceil(), height));
    let radius2 = radius_px * radius_px;
    for v in v0..=v1 {
        for u in u0..=u1 {
            if (u as f64 - centre_u).powi(2) + (v as f64 - centre_v).powi(2) > radius2 {
                continue;
            }
            if let Some(z) = depth.get_mut(v * width as usize + u) {
                if *z <= 0.0 || blob_depth < *z {
                    *z = blob_depth;
                }
            }
        }
    }
}

/// A uniform draw in [0, 1) from the top 53 bits of one `next_u64`.
fn uniform<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1_u64 << 53) as f64)
}

/// A standard normal draw (rand_distr's ziggurat).
fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    StandardNormal.sample(rng)
}

/// A Poisson draw of mean `lambda` (rand_distr); 0 for a mean that is not positive.
fn poisson<R: Rng + ?Sized>(rng: &mut R, lambda: f64) -> u64 {
    match Poisson::new(lambda) {
        Ok(p) if lambda > 0.0 => p.sample(rng) as u64,
        _ => 0,
    }
}

/// One stage of lidar noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LidarNoise {
    /// Gaussian `N(0, sigma_m²)` added to each point's range, along its ray; a range that
    /// falls to <= 0 loses the point.
    Range {
        /// Standard deviation [m], >= 0.
        sigma_m: f64,
    },
    /// Each point is lost with `probability`, independently.
    Dropout {
        /// Probability in [0, 1].
        probability: f64,
    },
}

impl LidarNoise {
    /// Checks the parameters; `field` prefixes the names in the error.
    pub fn validate(&self, field: &str) -> SimResult<()> {
        match *self {
            LidarNoise::Range { sigma_m } => non_negative(field, "sigma_m", sigma_m),
            LidarNoise::Dropout { probability } => probability_in_range(field, "probability", probability),
        }
    }
}

/// Lidar range σ of the presets [m]: Velodyne VLP-16 "±3 cm typical" and Ouster OS1
/// "±3 cm" range accuracy, read as 2σ.
pub const LIDAR_RANGE_SIGMA_M: f64 = 0.015;
/// Lidar fraction of returns lost in the presets (dark or specular patches).
pub const LIDAR_DROPOUT_PROBABILITY: f64 = 0.01;

/// The names accepted by [`LidarNoiseModel::preset`].
pub const LIDAR_NOISE_PRESETS: [&str; 3] = ["none", "vlp16", "os1_64"];

/// A chain of lidar noise stages, applied in order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LidarNoiseModel {
    /// The stages, first applied first.
    pub stages: Vec<LidarNoise>,
}

impl LidarNoiseModel {
    /// A validated model.
    pub fn new(stages: Vec<LidarNoise>) -> SimResult<Self> {
        let model = Self { stages };
        model.validate()?;
        Ok(model)
    }

    /// Checks every stage; errors name the field as `stages[i].name`.
    pub fn validate(&self) -> SimResult<()> {
        for (i, stage) in self.stages.iter().enumerate() {
            stage.validate(&format!("stages[{i}]"))?;
        }
        Ok(())
    }

    /// A named preset: `none`; `vlp16` and `os1_64`: range σ = 1.5 cm then dropout 1 %.
    pub fn preset(name: &str) -> SimResult<Self> {
        match name {
            "none" => Ok(Self::default()),
            "vlp16" | "os1_64" => {
                Ok(Self { stages: vec![LidarNoise::Range { sigma_m: LIDAR_RANGE_SIGMA_M }, LidarNoise::Dropout { probability: LIDAR_DROPOUT_PROBABILITY }] })
            }
            _ => Err(SimError::Unknown { what: "lidar noise preset".into(), name: name.into(), known: LIDAR_NOISE_PRESETS.join(", ") }),
        }
    }

    /// The noisy scan. Never fails: an invalid model gives the scan unchanged — call
    /// [`Self::try_apply`] to get the error instead.
    pub fn apply<R: Rng + ?Sized>(&self, scan: &LidarScan, rng: &mut R) -> LidarScan {
        self.try_apply(scan, rng).unwrap_or_else(|_| scan.clone())
    }

    /// As [`Self::apply`], with errors: an invalid stage or a scan whose buffers differ in length.
    pub fn try_apply<R: Rng + ?Sized>(&self, scan: &LidarScan, rng: &mut R) -> SimResult<LidarScan> {
        self.validate()?;
        let n = scan.points_sensor.len();
        if scan.ring.len() != n || scan.primitive.len() != n {
            return Err(SimError::input(
                "scan",
                format!("buffers must have one length, got points {n}, ring {}, primitive {}", scan.ring.len(), scan.primitive.len()),
            ));
        }
        let mut out = scan.clone();
        for stage in &self.stages {
            let mut keep = Vec::with_capacity(out.points_sensor.len());
            match *stage {
                LidarNoise::Range { sigma_m } => {
                    for p in &mut out.points_sensor {
                        let v = [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
                        let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                        let noisy = r + sigma_m * standard_normal(rng);
                        let alive = r > 0.0 && noisy > 0.0;
                        if alive {
                            let s = noisy / r;
                            *p = [(v[0] * s) as f32, (v[1] * s) as f32, (v[2] * s) as f32];
                        }
                        keep.push(alive);
                    }
                }
                LidarNoise::Dropout { probability } => {
                    keep.extend((0..out.points_sensor.len()).map(|_| uniform(rng) >= probability));
                }
            }
            retain_points(&mut out, &keep);
        }
        Ok(out)
    }
}

fn retain_points(scan: &mut LidarScan, keep: &[bool]) {
    let mut i = 0;
    scan.points_sensor.retain(|_| (keep.get(i).copied().unwrap_or(true), i += 1).0);
    let mut i = 0;
    scan.ring.retain(|_| (keep.get(i).copied().unwrap_or(true), i += 1).0);
    let mut i = 0;
    scan.primitive.retain(|_| (keep.get(i).copied().unwrap_or(true), i += 1).0);
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    #[test]
    fn uniform_uses_the_top_53_bits() {
        struct Fixed(u64);
        impl rand::TryRng for Fixed {
            type Error = std::convert::Infallible;
            fn try_next_u32(&mut self) -> Result<u32, Self::Error> {
                Ok(self.0 as u32)
            }
            fn try_next_u64(&mut self) -> Result<u64, Self::Error> {
                Ok(self.0)
            }
            fn try_fill_bytes(&mut self, _: &mut [u8]) -> Result<(), Self::Error> {
                Ok(())
            }
        }
        assert_eq!(uniform(&mut Fixed(0)), 0.0);
        assert_eq!(uniform(&mut Fixed(1 << 63)), 0.5);
        assert_eq!(uniform(&mut Fixed(u64::MAX)), 1.0 - 2f64.powi(-53));
    }

    #[test]
    fn gaussian_and_poisson_moments() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let n = 1_000_000;
        let xs: Vec<f64> = (0..n).map(|_| standard_normal(&mut rng)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        let kurtosis = xs.iter().map(|x| (x - mean).powi(4)).sum::<f64>() / n as f64 / (var * var);
        // Standard errors: mean 0.001, variance 0.0014, kurtosis 0.005.
        assert!(mean.abs() < 0.005, "{mean}");
        assert!((var - 1.0).abs() < 0.007, "{var}");
        assert!((kurtosis - 3.0).abs() < 0.03, "{kurtosis}");
        // P(|x| < 1) = 0.682689; P(|x| > 3.4426) = 5.76e-4: 576 ± 24 of 1e6.
        let within = xs.iter().filter(|x| x.abs() < 1.0).count() as f64 / n as f64;
        assert!((within - 0.682_689).abs() < 0.002, "{within}");
        let tail = xs.iter().filter(|x| x.abs() > 3.442_619_855_899).count();
        assert!((480..680).contains(&tail), "{tail}");
        // Poisson: mean = variance = λ, small and large means.
        for lambda in [0.5, 4.0, 75.0] {
            let ks: Vec<f64> = (0..20_000).map(|_| poisson(&mut rng, lambda) as f64).collect();
            let m = ks.iter().sum::<f64>() / ks.len() as f64;
            let v = ks.iter().map(|k| (k - m).powi(2)).sum::<f64>() / ks.len() as f64;
            assert!((m - lambda).abs() < 0.03 * lambda.max(1.0), "λ {lambda}: mean {m}");
            assert!((v - lambda).abs() < 0.06 * lambda.max(1.0), "λ {lambda}: var {v}");
        }
        assert_eq!(poisson(&mut rng, 0.0), 0);
    }

    #[test]
    fn presets_are_valid_and_ordered() {
        for name in DEPTH_NOISE_PRESETS {
            DepthNoiseModel::preset(name).unwrap().validate().unwrap();
        }
        assert_eq!(DepthNoiseModel::preset("paper-every-10th").unwrap().stages, vec![DepthNoise::PaperGaussian { sigma_m: 0.2, every_n: 10 }]);
        let d435 = DepthNoiseModel::preset("d435").unwrap();
        assert_eq!(d435.stages.len(), 6);
        assert_eq!(d435.stages[4], DepthNoise::Stereo { c_m: 0.001, l: 0.002, q_per_m: 0.0025 });
        assert!(matches!(DepthNoiseModel::preset("d435-phantom").unwrap().stages.last(), Some(DepthNoise::PhantomSpeckle { .. })));
        assert!(matches!(DepthNoiseModel::preset("foo"), Err(SimError::Unknown { .. })));
        for name in LIDAR_NOISE_PRESETS {
            LidarNoiseModel::preset(name).unwrap().validate().unwrap();
        }
        // The quadratic term: 0.05 px / (385 px * 0.05 m) = 0.0026 /m.
        assert!((0.05 / (385.0 * 0.05) - D435_STEREO_Q_PER_M).abs() < 2e-4);
    }

    #[test]
    fn bad_stages_name_the_field() {
        let cases: [(DepthNoise, &str); 7] = [
            (DepthNoise::PaperGaussian { sigma_m: -0.1, every_n: 1 }, "stages[0].sigma_m"),
            (DepthNoise::PaperGaussian { sigma_m: 0.1, every_n: 0 }, "stages[0].every_n"),
            (DepthNoise::Stereo { c_m: 0.0, l: f64::NAN, q_per_m: 0.0 }, "stages[0].l"),
            (DepthNoise::Dropout { probability: 1.5 }, "stages[0].probability"),
            (DepthNoise::GrazingNoReturn { max_angle_rad: 2.0 }, "stages[0].max_angle_rad"),
            (DepthNoise::FlyingPixels { edge_jump_m: 0.0, probability: 0.5 }, "stages[0].edge_jump_m"),
            (DepthNoise::PhantomSpeckle { blobs_per_frame: 1.0, radius_px: 3.0, min_depth_m: 1.0, max_depth_m: 0.5 }, "stages[0].max_depth_m"),
        ];
        for (stage, field) in cases {
            let err = DepthNoiseModel::new(vec![stage]).unwrap_err();
            assert!(matches!(&err, SimError::InvalidConfig { field: f, .. } if f == field), "{err}");
        }
        let err = LidarNoiseModel::new(vec![LidarNoise::Dropout { probability: 0.1 }, LidarNoise::Range { sigma_m: -1.0 }]).unwrap_err();
        assert!(matches!(&err, SimError::InvalidConfig { field, .. } if field == "stages[1].sigma_m"), "{err}");
    }

    #[test]
    fn flying_pixel_lands_between_the_two_sides() {
        // One row: 1 m | 3 m. With probability 1 both edge pixels fly, each to a depth
        // between 1 and 3 m; the far pixels stay.
        let mut depth = vec![1.0_f32, 1.0, 3.0, 3.0];
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        flying_pixels(&mut depth, 4, 0.5, 1.0, &mut rng);
        assert_eq!(depth[0], 1.0);
        assert_eq!(depth[3], 3.0);
        assert!(depth[1] > 1.0 && depth[1] < 3.0, "{depth:?}");
        assert!(depth[2] > 1.0 && depth[2] < 3.0, "{depth:?}");
        // Below the jump nothing moves.
        let mut depth = vec![1.0_f32, 1.2];
        flying_pixels(&mut depth, 2, 0.5, 1.0, &mut rng);
        assert_eq!(depth, vec![1.0, 1.2]);
    }

    #[test]
    fn blob_covers_its_disk() {
        // Radius 2 at (5, 5): the 13 pixels within 2 px (1 + 4 + 4 + 4), nothing else;
        // a nearer surface (0.5 m) stays in front of the 0.7 m blob.
        let mut depth = vec![0.0_f32; 121];
        depth[5 * 11 + 6] = 0.5;
        stamp_blob(&mut depth, 11, 11, 5.0, 5.0, 2.0, 0.7);
        for v in 0..11 {
            for u in 0..11 {
                let d = ((u as f64 - 5.0).powi(2) + (v as f64 - 5.0).powi(2)).sqrt();
                let expected = if (u, v) == (6, 5) {
                    0.5
                } else if d <= 2.0 {
                    0.7
                } else {
                    0.0
                };
                assert_eq!(depth[v * 11 + u], expected, "({u}, {v})");
            }
        }
        assert_eq!(depth.iter().filter(|&&z| z == 0.7).count(), 12);
        // Clipped at the image corner: a quarter disk plus the axes, 6 pixels.
        let mut depth = vec![0.0_f32; 121];
        stamp_blob(&mut depth, 11, 11, 0.0, 0.0, 2.0, 0.7);
        assert_eq!(depth.iter().filter(|&&z| z == 0.7).count(), 6);
    }
}
