//! Ground segmentation by line fits in cylindrical coordinates (Himmelsbach, Hundelshausen,
//! Wuensche, "Fast segmentation of 3D point clouds for ground vehicles", IEEE IV 2010).
//!
//! In: points in a gravity-aligned frame centred on the sensor. Out: each point's height
//! above its sector's ground line, hence a ground / obstacle label, and per polar bin the
//! ground line and the lowest evidence of where the floor can be (used by the `negative`
//! risk layer and to fill the ground height between scan rings).
//!
//! # The algorithm, exactly
//!
//! Inputs: points `(x, y, z)` (f32, converted to f64 for every computation below) in a frame
//! whose z axis points up and whose origin is the sensor; `H = sensor_height_m`, the origin's
//! height above the ground near it; a [`GroundConfig`] (`S = sectors`, `Δ = bin_m`,
//! `R = max_range_m`, `B = ceil(R / Δ)` bins).
//!
//! 1. **Polar bins.** `r = sqrt(x² + y²)`. A point with `r >= R` (or a non-finite coordinate)
//!    gets no bin. Otherwise sector `s = min(floor((atan2(y, x) + π) / (2π / S)), S - 1)` and
//!    bin `k = min(floor(r / Δ), B - 1)`.
//! 2. **Prototypes.** Each non-empty bin's prototype is its lowest point `(r, z)` (smallest
//!    z; on a tie, the first in input order).
//! 3. **Line fits, per sector**, visiting its prototypes `p = (r, z)` in increasing bin order.
//!    State: the ground estimate `g`, a height `z_g` seen at radius `r_g` (starts at
//!    `(0, -H)`: the ground the robot stands on), the current segment `seg` (a list of
//!    prototypes, starts empty), the sector's accepted lines. `fit(P)` is the least-squares
//!    line `z = m·r + b` through the points `P`; `rmse(P)` is `sqrt(Σ (z - m·r - b)² / |P|)`
//!    of that fit. A line *starts on the ground* when its first prototype `q` lies within
//!    `max_start_height_m` (Himmelsbach's T_b) of `z_g`, or the line itself comes within
//!    T_b of `z_g` somewhere between `r_g` and `q.r`: the ground rose or fell from where it
//!    was last seen over a stretch the sensor did not see (the blind ring around the robot,
//!    a hole), and the line leads back to it. For each prototype `p`:
//!    - if `seg` is empty: `seg = [p]`;
//!    - else if `p.r - last(seg).r > max_gap_m`: `close(seg)`, then `seg = [p]`;
//!    - else if `|seg| = 1` (`q` its point): if `|q.z - z_g| <= max_start_height_m +
//!      max_slope · max(q.r - r_g, 0)` (the ground can have changed at most that much over
//!      the unseen stretch) and `|p.z - q.z| <= max_slope · (p.r - q.r)`, append `p`;
//!      otherwise `seg = [p]`;
//!    - else (`|seg| >= 2`): with `(m0, b0) = fit(seg)` and `(m1, b1) = fit(seg + [p])`,
//!      append `p` if `|p.z - (m0·p.r + b0)| <= max_prediction_error_m` and
//!      `|m1| <= max_slope` and `rmse(seg + [p]) <= max_rmse_m` and the line `(m1, b1)`
//!      starts on the ground. Otherwise `close(seg)`, set
//!      `seg = [last(seg)]` (the break point starts the next segment) and handle `p` again
//!      by the rules above (it now meets the `|seg| = 1` rule).
//!
//!    With `unseen_rise_min_length_m` = `U` > 0 the sector's first line also *starts on
//!    the ground over an unseen rise* when no line has been accepted before it (the
//!    estimate is still the ground under the robot), `max_start_height_m < q.z - z_g <=
//!    max_start_height_m + max_slope · q.r` for its first prototype `q` (a ramp no steeper
//!    than `max_slope` hidden in the blind ring could lead up to it) and no prototype of the
//!    sector before `q` lies more than `max_start_height_m` below `q` (nothing was seen in
//!    the stretch: no floor, no face of a box). Beyond an accepted line (the far side of a
//!    hole, a crest) the rule does not apply. While a segment grows this counts as starting
//!    on the ground; `close` accepts such a line only if it is a plateau, not a box top or a
//!    slope: its last prototype at least `U` beyond its first, and level (`|m|·U <=
//!    max_start_height_m`).
//!
//!    After the last prototype, `close(seg)`. `close(seg)`: if `|seg| >= min_line_points`
//!    and the line `(m, b) = fit(seg)` starts on the ground, accept it covering bins
//!    `[bin(first(seg)), bin(last(seg))]` and set `g = (last(seg).r, m·last(seg).r + b)`;
//!    otherwise discard it. The top of a box is a level line more than T_b above the ground
//!    everywhere: never accepted, however far away.
//! 4. **Line of each bin.** Bin `k` of a sector takes the first accepted line (in order of
//!    acceptance) whose bin interval contains `k` (the bin is then *covered*); if none does,
//!    the line whose interval is nearest in bins (distance `first - k` or `k - last`; on a tie
//!    the earlier line), except before the sector's first line, where it takes the straight
//!    line from the ground under the sensor `(0, -H)` to that line at its first prototype's
//!    radius `r₁` (`m = (z₁ + H) / r₁, b = -H`; not covered). A sector without lines uses
//!    the flat line `m = 0, b = -H`.
//! 5. **Labels.** A point's height above ground is `h = z - (m·r + b)` with its bin's line;
//!    it is ground iff `|h| <= max_dist_to_line_m`. Points without a bin are obstacles with
//!    `h = NaN`.
//!
//! Byproducts per bin (not part of the labels): the *expected ground* at radius r is the
//! bin's line there, except beyond the last prototype of a rising line (`m > 0`), where it
//! stays at the line's height at that prototype (past a crest the ground may fall away out of
//! sight); *coverage* of a position at radius r in a
//! covered bin holds when r also lies between the radii of the line's first and last
//! prototype; the lowest point's z (`floor_z`), and the steepest downward ray slope
//! `min(z / r)` over the prototypes of all *farther* bins of the sector: a ray from the
//! sensor to such a point passed over this bin at height `slope · r`, so the floor here is
//! at most that high.
//!
//! *Void* (missing ground): per sector, visiting its non-empty bins in increasing order, a
//! run of empty bins between bin `a` and the next non-empty bin `b` is void when the rays
//! that would meet the run's expected ground (its bins' lines, capped as above) leave an angular stretch of
//! more than `void_min_gap_deg` (depression) with no return: of the depressions between
//! `hi` = min(`a`'s shallowest ray, the expected ground at the run's start) and `lo` =
//! max(the steepest ray to a farther bin not steeper than `a`'s shallowest, the expected
//! ground at the run's end), none lies in a bin's ray span `[shallowest, steepest]` (any bin
//! of the sector) for more than that. A bin's ray span is over its points with `h >=
//! -max_dist_to_line_m` (step 5): a return from deeper below its line came through the
//! floor (the inside of a hole, or whatever lies under it: the beam crossed the expected
//! ground where there was none) and is evidence of the void, not a beam that came back.
//! Beams must have crossed the expected ground there and none came back from it: the floor
//! is missing (a hole, or a drop beyond the sensor's range). Runs behind an occluder, past
//! a crest, or beyond a partial occluder are not void: the rays over them came back from
//! farther, or from the occluder.
//!
//! *Shadow* (`drop_shadows`): a drop with a floor (a pit, a ledge) hides the floor behind
//! its near edge. Per sector, a bin's return *came back* when it lies not more than
//! `max_dist_to_line_m` below its line; the bins after a bin's farthest such return, up to
//! the next bin with one, form a *run*. Each bin of a run has a depth below the ground last
//! seen going on (the expected ground of the bin that starts the run, its line continued):
//! that at the bin's far edge minus the steepest downward ray to a farther bin's prototype
//! there, or, if deeper, how far its lowest point lies below it where that is more than
//! `max_dist_to_line_m`. The starting bin's line, not the bin's own: a line accepted from
//! the near rim to the floor or far wall of a pit (a "slope" with nothing returned along
//! it) would otherwise explain the drop away. The floor is missing wherever a ray passed
//! below that ground, and from the return that starts the run to there nothing shows where
//! the drop begins: every position of the run (including the part of the starting bin beyond its
//! farthest return) takes the deepest depth of the run's bins from there on, at least 0
//! (`shadow_depth`), if the ray to that return (at the expected ground there) descends at
//! least `drop_shadow_min_grazing_deg`; otherwise, and before the sector's first return (the
//! blind ring around the sensor), there is no shadow. Ground hidden behind a return is
//! steeper than the ray that grazed it, or falls away: seen at a grazing angle above the
//! robot's safe tilt, every reading of the run is a hazard; at a shallower one (far away,
//! past a crest) it may be a slope the robot could drive, which it sees from closer. Behind
//! a rock the rays over the run pass above the ground (depth 0); between two rings on flat
//! ground they too pass above it.

use super::config::GroundConfig;
use crate::error::{Error, Result};
use crate::terrain::cloud::as_points;

/// Marks a point without a polar bin.
const NO_BIN: u32 = u32::MAX;

/// One accepted ground line of a sector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundLine {
    /// Slope dz/dr [1].
    pub m: f64,
    /// Height at r = 0 [m].
    pub b: f64,
    /// First bin covered.
    pub first_bin: u32,
    /// Last bin covered.
    pub last_bin: u32,
    /// Radius of the first prototype [m].
    pub first_r_m: f64,
    /// Radius of the last prototype [m].
    pub last_r_m: f64,
}

/// What the segmentation knows about one polar bin (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolarBin {
    /// Whether an accepted line covers the bin and the queried radius lies between the
    /// line's first and last prototype.
    pub covered: bool,
    /// The expected ground at the queried radius: the bin's line, capped beyond a rising line's
    /// last prototype (module doc) [m, sensor-centred].
    pub ground_z: f64,
    /// Upper bound of the floor at the queried radius: the lower of the bin's lowest point
    /// and the lowest ray that passed over it; `+inf` without evidence [m, sensor-centred].
    pub floor_bound_z: f64,
    /// Whether the bin is void: beams crossed its expected ground and none returned.
    pub void: bool,
    /// How deep the drop may be that begins at the queried radius: the deepest evidence of
    /// missing ground in the shadow run it lies in (module doc, *Shadow*), 0 outside one [m].
    pub shadow_depth: f64,
}

/// A polar bin's prototype and steepest ray, gathered while binning.
#[derive(Debug, Clone, Copy)]
struct BinAccumulator {
    proto_r: f64,
    /// The prototype's z (an input `f32`, so exact).
    proto_z: f32,
    /// After the sweep: the smallest prototype `z/r` of the farther bins.
    ray_slope: f32,
    /// The largest `z/r` of the bin's points (its shallowest ray); `-inf` when empty.
    top_slope: f32,
    /// The smallest `z/r` of the bin's points (its steepest ray); `+inf` when empty.
    low_slope: f32,
    /// After the sweep: whether the bin is void (module doc).
    void: bool,
    /// The radius of the bin's farthest return that came back (not more than
    /// `max_dist_to_line_m` below its line); `-inf` when none did.
    solid_r: f32,
    /// After the sweep: the shadow depth beyond `solid_r` (module doc, *Shadow*) [m].
    shadow_depth: f32,
}

impl BinAccumulator {
    const EMPTY: Self = Self {
        proto_r: 0.0,
        proto_z: f32::INFINITY,
        ray_slope: f32::INFINITY,
        top_slope: f32::NEG_INFINITY,
        low_slope: f32::INFINITY,
        void: false,
        solid_r: f32::NEG_INFINITY,
        shadow_depth: 0.0,
    };
}

/// A polar bin's ground line and the radii it covers (empty range if not covered).
#[derive(Debug, Clone, Copy)]
struct BinLine {
    m: f64,
    b: f64,
    cover_lo: f64,
    cover_hi: f64,
    /// Beyond this radius the expected ground stays at the line's height there: the radius of
    /// a rising line's last prototype (`+inf` for a level or falling one).
    cap_r: f64,
}

impl BinLine {
    const NONE: Self = Self { m: 0.0, b: 0.0, cover_lo: f64::INFINITY, cover_hi: f64::NEG_INFINITY, cap_r: f64::INFINITY };

    /// The bin's line over its own bins and, uncovered, the nearest line's, capped beyond a
    /// rising line's last prototype.
    fn of(line: &GroundLine, covered: bool) -> Self {
        let cap_r = if line.m > 0.0 { line.last_r_m } else { f64::INFINITY };
        let (cover_lo, cover_hi) = if covered { (line.first_r_m, line.last_r_m) } else { (f64::INFINITY, f64::NEG_INFINITY) };
        Self { m: line.m, b: line.b, cover_lo, cover_hi, cap_r }
    }

    /// The expected ground at radius `r`: the line, but beyond a rising line's last prototype
    /// no higher than there. Past a crest the ground may fall away out of sight: beams passing
    /// over the crest below the line's continuation are no evidence of a hole.
    #[inline]
    fn expected(&self, r: f64) -> f64 {
        self.m * if r > self.cap_r { self.cap_r } else { r } + self.b
    }
}

/// Running least-squares sums of a segment, centred on its first point.
#[derive(Debug, Clone, Copy, Default)]
struct LineSums {
    n: f64,
    r0: f64,
    z0: f64,
    sr: f64,
    sz: f64,
    srr: f64,
    srz: f64,
    szz: f64,
}

impl LineSums {
    fn start(r: f64, z: f64) -> Self {
        Self { n: 1.0, r0: r, z0: z, ..Default::default() }
    }

    fn with(&self, r: f64, z: f64) -> Self {
        let (dr, dz) = (r - self.r0, z - self.z0);
        Self {
            n: self.n + 1.0,
            sr: self.sr + dr,
            sz: self.sz + dz,
            srr: self.srr + dr * dr,
            srz: self.srz + dr * dz,
            szz: self.szz + dz * dz,
            ..*self
        }
    }

    /// `(m, b, rmse)` of the least-squares line; `None` when degenerate.
    fn fit(&self) -> Option<(f64, f64, f64)> {
        let denom = self.n * self.srr - self.sr * self.sr;
        if !(denom > 0.0) {
            return None;
        }
        let m = (self.n * self.srz - self.sr * self.sz) / denom;
        let bc = (self.sz - m * self.sr) / self.n;
        let sse = self.szz - 2.0 * m * self.srz - 2.0 * bc * self.sz + m * m * self.srr + 2.0 * m * bc * self.sr + self.n * bc * bc;
        let b = bc + self.z0 - m * self.r0;
        Some((m, b, (sse.max(0.0) / self.n).sqrt()))
    }
}

/// Ground segmentation with reusable buffers. The config is trusted once [`new`](Self::new)
/// has validated it.
#[derive(Debug, Clone)]
pub struct GroundSegmenter {
    config: GroundConfig,
    bins: usize,
    /// Per point: flat polar bin `s·B + k`, or [`NO_BIN`].
    point_bin: Vec<u32>,
    /// Per polar bin: the prototype (lowest point) and the steepest ray.
    acc: Vec<BinAccumulator>,
    /// One sector's non-empty bins' ray spans in [`mark_voids`](Self::mark_voids), each
    /// computed when first needed (NaN: not yet).
    spans: Vec<(f64, f64)>,
    /// One sector's non-empty bins, in order, in [`mark_voids`](Self::mark_voids).
    full_bins: Vec<usize>,
    /// One sector's run start per bin in [`mark_shadows`](Self::mark_shadows) ([`NO_BIN`]:
    /// none).
    run_start: Vec<u32>,
    /// Per polar bin while binning: the smallest [`proto_key`] of its points (`u64::MAX`:
    /// empty).
    proto_key: Vec<u64>,
    /// Per polar bin: the index of its line in `bin_lines` (4 bytes a bin instead of a
    /// 32-byte line: the table is written every scan and read at random per point and per
    /// map cell, and this way it stays in cache).
    bin_line: Vec<u32>,
    /// The lines the bins use: each accepted line covering its bins and not covering, and
    /// the flat line of each sector without lines.
    bin_lines: Vec<BinLine>,
    /// Accepted lines of every sector, and each sector's range in it.
    lines: Vec<GroundLine>,
    sector_lines: Vec<(u32, u32)>,
    /// Unit vectors of the sector boundaries at angles `-π + s·2π/S`, `s = 0..=S`.
    sector_edges: Vec<(f64, f64)>,
    sensor_height_m: f64,
    /// `1 / bin_m`.
    inv_bin: f64,
}

impl GroundSegmenter {
    /// Validates `config` and sizes the polar tables.
    pub fn new(config: GroundConfig) -> Result<Self> {
        config.validate()?;
        let bins = config.bins();
        let polar = config.sectors as usize * bins;
        Ok(Self {
            config,
            bins,
            point_bin: Vec::new(),
            acc: vec![BinAccumulator::EMPTY; polar],
            proto_key: vec![u64::MAX; polar],
            spans: vec![(f64::NAN, f64::NAN); bins],
            full_bins: Vec::with_capacity(bins),
            run_start: Vec::with_capacity(bins),
            // Before the first scan every bin has the line of `BinLine::NONE`.
            bin_line: vec![0; polar],
            bin_lines: vec![BinLine::NONE],
            lines: Vec::new(),
            sector_lines: vec![(0, 0); config.sectors as usize],
            sector_edges: (0..=config.sectors)
                .map(|s| {
                    let a = -std::f64::consts::PI + s as f64 * std::f64::consts::TAU / config.sectors as f64;
                    (a.cos(), a.sin())
                })
                .collect(),
            sensor_height_m: 0.0,
            inv_bin: 1.0 / config.bin_m,
        })
    }

    /// The config.
    pub fn config(&self) -> &GroundConfig {
        &self.config
    }

    /// Segments `points` (sensor-centred, z up; see the module doc) and writes each point's
    /// height above its ground line to `heights_out` (NaN for points without a bin).
    pub fn segment(&mut self, points: &[[f32; 3]], sensor_height_m: f64, heights_out: &mut Vec<f32>) -> Result<()> {
        if !sensor_height_m.is_finite() {
            return Err(Error::input("sensor_height_m", format!("must be finite, got {sensor_height_m}")));
        }
        if u32::try_from(points.len()).is_err() {
            return Err(Error::input("points", format!("has {} points; at most {}", points.len(), u32::MAX)));
        }
        self.sensor_height_m = sensor_height_m;
        self.bin_points(points);
        self.fit_lines();
        heights_out.clear();
        let (bin_line, lines) = (&self.bin_line[..], &self.bin_lines[..]);
        // Each bin's `solid_r` (module doc, *Shadow*) in the same pass: the radius of its
        // farthest point not more than `max_dist_to_line_m` below its line (with voids on,
        // `gather_ray_spans` finds it among the same points). The test is the same for every
        // point: predicted, not a data-dependent branch.
        let track = self.config.drop_shadows && self.config.void_min_gap_deg == 0.0;
        let below = -(self.config.max_dist_to_line_m as f32);
        let acc = &mut self.acc[..];
        heights_out.extend(points.iter().zip(&self.point_bin).map(|(p, &sb)| {
            if sb == NO_BIN {
                return f32::NAN;
            }
            let (x, y) = (p[0] as f64, p[1] as f64);
            let r = (x * x + y * y).sqrt();
            let line = &lines[bin_line[sb as usize] as usize];
            let h = (p[2] as f64 - (line.m * r + line.b)) as f32;
            if track {
                let acc = &mut acc[sb as usize];
                acc.solid_r = if h >= below && r > 0.0 { acc.solid_r.max(r as f32) } else { acc.solid_r };
            }
            h
        }));
        if self.config.void_min_gap_deg != 0.0 {
            // Also each bin's `solid_r`: the same points, one pass.
            self.gather_ray_spans(points, heights_out);
            self.mark_voids();
        }
        if self.config.drop_shadows {
            self.mark_shadows();
        }
        Ok(())
    }

    /// Two positions `(x, y)` (sensor-centred, level) on the centre ray of every void bin of
    /// the last segmentation (at a quarter and three quarters of the bin), into `out`: where
    /// the map records that the floor was found missing.
    pub fn void_samples(&self, out: &mut Vec<[f32; 2]>) {
        out.clear();
        let bins = self.bins;
        let sectors = self.config.sectors as usize;
        for s in 0..sectors {
            let row = &self.acc[s * bins..(s + 1) * bins];
            if !row.iter().any(|b| b.void) {
                continue;
            }
            let a = -std::f64::consts::PI + (s as f64 + 0.5) * std::f64::consts::TAU / sectors as f64;
            let (sin, cos) = a.sin_cos();
            for (k, _) in row.iter().enumerate().filter(|(_, b)| b.void) {
                for f in [0.25, 0.75] {
                    let r = (k as f64 + f) * self.config.bin_m;
                    out.push([(r * cos) as f32, (r * sin) as f32]);
                }
            }
        }
    }

    /// Whether a height above ground (from [`segment`](Self::segment)) is ground.
    #[inline]
    pub fn is_ground(&self, height_above_ground_m: f32) -> bool {
        height_above_ground_m.abs() <= self.config.max_dist_to_line_m as f32
    }

    /// The accepted lines of `sector`, in order of radius.
    pub fn lines(&self, sector: usize) -> &[GroundLine] {
        match self.sector_lines.get(sector) {
            Some(&(a, b)) => &self.lines[a as usize..b as usize],
            None => &[],
        }
    }

    /// What the last segmentation knows at the sensor-centred horizontal position
    /// `(x, y)` [m]; `None` outside the polar range. Uses a fast `atan2` (error < 2e-5 rad),
    /// so a position within that of a sector boundary may be given the neighbouring sector.
    #[inline]
    pub fn query(&self, x: f64, y: f64) -> Option<PolarBin> {
        let r = (x * x + y * y).sqrt();
        if !(r < self.config.max_range_m) {
            return None;
        }
        let sectors = self.config.sectors as usize;
        // In [0, S]: `as i64` truncates as `as usize` would.
        let s = (((fast_atan2(y, x) + std::f64::consts::PI) * (sectors as f64 / std::f64::consts::TAU)) as i64 as usize).min(sectors - 1);
        Some(self.polar_bin(s, r))
    }

    /// [`query`](Self::query) at the positions `(xs[i], y)`, in order: `f(i, bin)` for each
    /// one inside the polar range, with exactly the bin `query` gives.
    #[inline]
    pub(crate) fn query_row(&self, xs: &[f64], y: f64, mut f: impl FnMut(usize, PolarBin)) {
        let sectors = self.config.sectors as usize;
        let scale = sectors as f64 / std::f64::consts::TAU;
        let max_r = self.config.max_range_m;
        for (i, &x) in xs.iter().enumerate() {
            let r = (x * x + y * y).sqrt();
            if !(r < max_r) {
                continue;
            }
            // In [0, S]: `as i64` truncates as `as usize` would.
            let s = (((fast_atan2(y, x) + std::f64::consts::PI) * scale) as i64 as usize).min(sectors - 1);
            f(i, self.polar_bin(s, r));
        }
    }

    /// What polar bin `(s, bin of r)` knows at radius `r`.
    #[inline]
    fn polar_bin(&self, s: usize, r: f64) -> PolarBin {
        // r < max_range_m, so r / bin_m is in [0, bins]: `as i64` truncates as `as usize` would.
        let k = ((r * self.inv_bin) as i64 as usize).min(self.bins - 1);
        let sb = s * self.bins + k;
        // Both tables have one entry per polar bin: one bounds check for the two.
        let n = self.bin_line.len().min(self.acc.len());
        let (line, acc) = (&self.bin_lines[self.bin_line[..n][sb] as usize], &self.acc[..n][sb]);
        let ground_z = line.expected(r);
        // `min` of the two where the prototype's z is never NaN (+inf when empty): the ray
        // bound is taken only when lower (a NaN ray bound, inf·0, leaves the prototype's z).
        let (proto_z, ray_z) = (acc.proto_z as f64, acc.ray_slope as f64 * r);
        let floor_bound_z = if ray_z < proto_z { ray_z } else { proto_z };
        let shadow_depth = if r > f64::from(acc.solid_r) { f64::from(acc.shadow_depth) } else { 0.0 };
        PolarBin { covered: r >= line.cover_lo && r <= line.cover_hi, ground_z, floor_bound_z, void: acc.void, shadow_depth }
    }

    fn bin_points(&mut self, points: &[[f32; 3]]) {
        let c = &self.config;
        let bins = self.bins;
        let sectors = c.sectors as usize;
        let sector_scale = c.sectors as f64 / std::f64::consts::TAU;
        let (max_r, bin_m) = (c.max_range_m, c.bin_m);
        self.acc.fill(BinAccumulator::EMPTY);
        // Sized first and filled by a plain loop, so that everything the loop reads stays in
        // registers.
        self.point_bin.clear();
        self.point_bin.resize(points.len(), NO_BIN);
        let edges = &self.sector_edges[..];
        // Two passes: first each point's bin, then the prototypes. Interleaved, each point's
        // read-modify-write of its bin waits on the long sqrt-divide chain that finds the bin;
        // apart, the first pass is pure arithmetic and the second has its addresses at hand.
        // The previous point's sector: scans come ring by ring or column by column, so the
        // next point is usually in it or beside it.
        let mut last = usize::MAX;
        for (bin, p) in self.point_bin.iter_mut().zip(points) {
            let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
            let r = (x * x + y * y).sqrt();
            if !(r < max_r) || !z.is_finite() {
                continue;
            }
            let s = match sector_beside(edges, last, x, y) {
                Some(s) => s,
                None => sector_of(edges, x, y, sector_scale),
            };
            last = s;
            // r / bin_m is in [0, bins]: `as i64` truncates as `as usize` would.
            let k = ((r / bin_m) as i64 as usize).min(bins - 1);
            *bin = (s * bins + k) as u32;
        }
        // Each bin's lowest point as the smallest key: an integer `min`, without the branch
        // that a "lower?" test compiles to (whether a point is its bin's lowest so far depends
        // on the data, and real scans mispredicted it often).
        let keys = &mut self.proto_key[..];
        keys.fill(u64::MAX);
        for (i, (&sb, p)) in self.point_bin.iter().zip(points).enumerate() {
            if sb == NO_BIN {
                continue;
            }
            let key = &mut keys[sb as usize];
            *key = (*key).min(proto_key(p[2], i));
        }
        // Per bin: its prototype, and the steepest ray to any point of a farther bin of the
        // sector.
        for s in 0..sectors {
            let row = &mut self.acc[s * bins..(s + 1) * bins];
            let mut farther = f32::INFINITY;
            for (bin, &key) in row.iter_mut().zip(&self.proto_key[s * bins..(s + 1) * bins]).rev() {
                bin.ray_slope = farther;
                if key == u64::MAX {
                    // An empty bin's own slope would be +inf: it leaves `farther` as it is.
                    continue;
                }
                // The same r as in the first pass.
                let p = points[key as u32 as usize];
                let (x, y) = (p[0] as f64, p[1] as f64);
                let r = (x * x + y * y).sqrt();
                (bin.proto_r, bin.proto_z) = (r, p[2]);
                if r > 0.0 {
                    farther = farther.min((p[2] as f64 / r) as f32);
                }
            }
        }
    }

    /// Each bin's ray span for the void detection (module doc, *Void*): the slopes `z/r` of
    /// its points that are not more than `max_dist_to_line_m` below its ground line, and its
    /// `solid_r` (the largest `r` of the same points; module doc, *Shadow*). A return
    /// from deeper came through the floor: its ray crossed the expected ground where there
    /// was none (a hole's inside, or what lies under it), so it is evidence for a void, not a
    /// beam that came back from the ground.
    fn gather_ray_spans(&mut self, points: &[[f32; 3]], heights: &[f32]) {
        let below = -(self.config.max_dist_to_line_m as f32);
        let acc = &mut self.acc[..];
        for ((&sb, p), &h) in self.point_bin.iter().zip(points).zip(heights) {
            if sb == NO_BIN || !(h >= below) {
                continue;
            }
            // The same r as in `bin_points`.
            let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
            let r = (x * x + y * y).sqrt();
            if r > 0.0 {
                let acc = &mut acc[sb as usize];
                acc.top_slope = acc.top_slope.max((z / r) as f32);
                acc.low_slope = acc.low_slope.min((z / r) as f32);
                acc.solid_r = acc.solid_r.max(r as f32);
            }
        }
    }

    /// The shadow depth of every bin (module doc, *Shadow*): per sector, from the sensor out,
    /// the return that starts each bin's run; from the farthest bin in, the deepest missing
    /// ground below that return's line over the rest of the run, kept where that return is
    /// seen steeply enough.
    fn mark_shadows(&mut self) {
        let bins = self.bins;
        let (bin_m, thr) = (self.config.bin_m, self.config.max_dist_to_line_m);
        let min_tan = self.config.drop_shadow_min_grazing_deg.to_radians().tan();
        let starts = &mut self.run_start;
        starts.clear();
        starts.resize(bins, NO_BIN);
        for s in 0..self.config.sectors as usize {
            let (row, bin_line) = (&mut self.acc[s * bins..(s + 1) * bins], &self.bin_line[s * bins..(s + 1) * bins]);
            let line = |k: usize| &self.bin_lines[bin_line[k] as usize];
            // The run's start: the nearest bin at or before with a return that came back, if
            // the sensor sees that return steeply enough (else, and in the blind ring, none).
            let mut start = NO_BIN;
            for (k, acc) in row.iter().enumerate() {
                if acc.solid_r > f32::NEG_INFINITY {
                    let r = f64::from(acc.solid_r);
                    start = if -line(k).expected(r) >= min_tan * r { k as u32 } else { NO_BIN };
                }
                starts[k] = start;
            }
            let mut run = 0.0f32;
            for (k, acc) in row.iter_mut().enumerate().rev() {
                let start = starts[k];
                let deepest = if start == NO_BIN {
                    f32::NEG_INFINITY
                } else {
                    // How far the floor lies below where the ground last seen would go on:
                    // under the lowest ray over the bin's far edge, and at the bin's lowest
                    // point if that lies deeper than a ground return may (it came through
                    // the floor).
                    let ground = line(start as usize);
                    let r = (k + 1) as f64 * bin_m;
                    let under_ray = ground.expected(r) - f64::from(acc.ray_slope) * r;
                    let below = ground.expected(acc.proto_r) - f64::from(acc.proto_z);
                    let own = (if below > thr { under_ray.max(below) } else { under_ray }) as f32;
                    if own > run { own } else { run }
                };
                acc.shadow_depth = deepest.max(0.0);
                // A return that came back ends the run beyond it; the next starts fresh.
                run = if acc.solid_r > f32::NEG_INFINITY { 0.0 } else { deepest.max(0.0) };
            }
        }
    }

    /// Marks the void runs of every sector (module doc, *Void*).
    fn mark_voids(&mut self) {
        if self.config.void_min_gap_deg == 0.0 {
            return; // off: `bin_points` left every bin non-void
        }
        let bins = self.bins;
        let bin_m = self.config.bin_m;
        let min_gap = self.config.void_min_gap_deg.to_radians();
        // Depression angle of a ray of slope z/r [rad].
        let dep = |slope: f64| (-slope).atan();
        for s in 0..self.config.sectors as usize {
            let (row, bin_line) = (&mut self.acc[s * bins..(s + 1) * bins], &self.bin_line[s * bins..(s + 1) * bins]);
            let lines = |k: usize| &self.bin_lines[bin_line[k] as usize];
            // Depression of the expected ground (the bin's line) at radius r.
            let ground = |k: usize, r: f64| dep(lines(k).expected(r) / r);
            // Each non-empty bin's rays: (shallowest, steepest) depression. Every gap asks for
            // the spans of the bins beyond it (and maybe of all): each is computed once per
            // sector, in `spans` (the same values, without an `atan` pair per bin and gap).
            let span = |b: &BinAccumulator| (dep(f64::from(b.top_slope)), dep(f64::from(b.low_slope)));
            let full = |b: &BinAccumulator| b.proto_z.is_finite() && b.proto_r > 0.0;
            let spans = &mut self.spans[..bins];
            spans.fill((f64::NAN, f64::NAN));
            let cached = |known: &mut (f64, f64), b: &BinAccumulator| {
                if known.0.is_nan() {
                    *known = span(b);
                }
                *known
            };
            // The non-empty bins listed once: each gap walks those beyond it (and maybe all),
            // without testing every bin again (a branch real scans mispredict).
            let full_bins = &mut self.full_bins;
            full_bins.clear();
            full_bins.extend((0..bins).filter(|&k| full(&row[k])));
            for j in 1..full_bins.len() {
                let (a, k) = (full_bins[j - 1], full_bins[j]);
                if k <= a + 1 {
                    continue;
                }
                // The rays that would meet the expected ground of the run a+1..k, and did not
                // come back from `a`, nor (down to the steepest of them) from farther bins.
                let top = cached(&mut spans[a], &row[a]).0;
                let hi = top.min(ground(a + 1, (a + 1) as f64 * bin_m));
                let farther = full_bins[j..].iter().flat_map(|&q| {
                    let (x, y) = cached(&mut spans[q], &row[q]);
                    [x, y]
                });
                let Some(lo) = farther.filter(|&d| d <= top).reduce(f64::max) else { continue };
                let lo = lo.max(ground(k - 1, k as f64 * bin_m));
                if hi - lo <= min_gap {
                    continue;
                }
                // Rays of any bin of the sector inside (lo, hi) are beams that came back: the
                // void needs an empty stretch of more than `min_gap` between them.
                let mut cuts: Vec<(f64, f64)> = full_bins.iter().map(|&q| cached(&mut spans[q], &row[q])).filter(|&(x, y)| y > lo && x < hi).collect();
                cuts.sort_by(|p, q| p.0.total_cmp(&q.0));
                let mut from = lo;
                let mut empty = 0.0f64;
                for (x, y) in cuts {
                    empty = empty.max(x - from);
                    from = from.max(y);
                }
                empty = empty.max(hi - from);
                if empty > min_gap {
                    row[a + 1..k].iter_mut().for_each(|b| b.void = true);
                }
            }
        }
    }

    /// `min(floor((atan2(y, x) + π) / (2π/S)), S - 1)`: see [`sector_of`].
    #[cfg(test)]
    fn sector_of(&self, x: f64, y: f64, sector_scale: f64) -> usize {
        sector_of(&self.sector_edges, x, y, sector_scale)
    }

    fn fit_lines(&mut self) {
        let c = self.config;
        let bins = self.bins;
        self.lines.clear();
        self.bin_lines.clear();
        // The segment: its prototypes' (r, z, bin) and running sums.
        let mut seg: Vec<(f64, f64, u32)> = Vec::with_capacity(bins);
        let mut seen: Vec<f64> = Vec::with_capacity(bins);
        for s in 0..c.sectors as usize {
            let first_line = self.lines.len();
            let mut g = GroundEstimate { r: 0.0, z: -self.sensor_height_m, after_line: false };
            seg.clear();
            let mut sums = LineSums::default();
            // The sector's prototypes so far; `seg` is `seen[seg_start..seg_start + seg.len()]`.
            seen.clear();
            let mut seg_start = 0;
            for (k, acc) in self.acc[s * bins..(s + 1) * bins].iter().enumerate() {
                if !acc.proto_z.is_finite() {
                    continue;
                }
                let (r, z) = (acc.proto_r, acc.proto_z as f64);
                let here = seen.len();
                seen.push(z);
                loop {
                    let Some(&(qr, qz, _)) = seg.last() else {
                        seg.push((r, z, k as u32));
                        sums = LineSums::start(r, z);
                        seg_start = here;
                        break;
                    };
                    if r - qr > c.max_gap_m {
                        close(&c, &seg, &sums, &mut g, &seen[..seg_start], &mut self.lines);
                        seg.clear();
                        seg.push((r, z, k as u32));
                        sums = LineSums::start(r, z);
                        seg_start = here;
                        break;
                    }
                    if seg.len() == 1 {
                        if may_start(&c, (qr, qz), g) && (z - qz).abs() <= c.max_slope * (r - qr) {
                            seg.push((r, z, k as u32));
                            sums = sums.with(r, z);
                        } else {
                            seg.clear();
                            seg.push((r, z, k as u32));
                            sums = LineSums::start(r, z);
                            seg_start = here;
                        }
                        break;
                    }
                    let grown = sums.with(r, z);
                    let accept = match (sums.fit(), grown.fit()) {
                        (Some((m0, b0, _)), Some((m1, b1, rmse1))) => {
                            (z - (m0 * r + b0)).abs() <= c.max_prediction_error_m
                                && m1.abs() <= c.max_slope
                                && rmse1 <= c.max_rmse_m
                                && (starts_on_ground(&c, (seg[0].0, seg[0].1), m1, b1, g)
                                    || rises_unseen(&c, (seg[0].0, seg[0].1), &seen[..seg_start], g))
                        }
                        _ => false,
                    };
                    if accept {
                        seg.push((r, z, k as u32));
                        sums = grown;
                        break;
                    }
                    close(&c, &seg, &sums, &mut g, &seen[..seg_start], &mut self.lines);
                    let keep = seg[seg.len() - 1];
                    seg_start += seg.len() - 1;
                    seg.clear();
                    seg.push(keep);
                    sums = LineSums::start(keep.0, keep.1);
                }
            }
            close(&c, &seg, &sums, &mut g, &seen[..seg_start], &mut self.lines);
            self.sector_lines[s] = (first_line as u32, self.lines.len() as u32);
            self.assign_lines(s);
        }
    }

    /// Step 4: the line of each bin of sector `s`, range by range: before the first line,
    /// each line's own bins (a bin shared with the previous line stays with that one), the
    /// gaps between lines (the nearer line, the earlier on a tie), after the last line.
    fn assign_lines(&mut self, s: usize) {
        let bins = self.bins;
        let (a, b) = self.sector_lines[s];
        let lines = &self.lines[a as usize..b as usize];
        let row = &mut self.bin_line[s * bins..(s + 1) * bins];
        // Line j of the sector is `bin_lines[base + 2j]` covering its bins, `base + 2j + 1` not.
        let base = self.bin_lines.len() as u32;
        if lines.is_empty() {
            self.bin_lines.push(BinLine { b: -self.sensor_height_m, ..BinLine::NONE });
            row.fill(base);
            return;
        }
        for line in lines {
            self.bin_lines.push(BinLine::of(line, true));
            self.bin_lines.push(BinLine::of(line, false));
        }
        let covered = |j: usize| base + 2 * j as u32;
        let uncovered = |j: usize| base + 2 * j as u32 + 1;
        // Bins below `next` are assigned. Before the first line, the ground runs from under
        // the sensor to the line's first prototype (not the line drawn back: a short steep
        // line off a bump would put the ground under the robot high above it).
        let mut next = (lines[0].first_bin as usize).min(bins);
        let first = &lines[0];
        let approach = if first.first_r_m > 0.0 {
            let h = self.sensor_height_m;
            self.bin_lines.push(BinLine { m: (first.m * first.first_r_m + first.b + h) / first.first_r_m, b: -h, ..BinLine::NONE });
            base + 2 * lines.len() as u32
        } else {
            uncovered(0)
        };
        row[..next].fill(approach);
        for (j, line) in lines.iter().enumerate() {
            let (lo, hi) = (line.first_bin as usize, (line.last_bin as usize + 1).min(bins));
            if j > 0 && next < lo {
                // The gap after the previous line: bin k goes to it iff k - prev.last <= lo - k.
                let split = (lines[j - 1].last_bin as usize + lo) / 2 + 1;
                row[next..split].fill(uncovered(j - 1));
                row[split..lo].fill(uncovered(j));
                next = lo;
            }
            if next < hi {
                row[next..hi].fill(covered(j));
                next = hi;
            }
        }
        row[next..].fill(uncovered(lines.len() - 1));
    }
}

/// `min(floor((atan2(y, x) + π) / (2π/S)), S - 1)` with `edges` the `S + 1` unit vectors of
/// the sector boundaries: a fast `atan2` gives the sector to within one, and two cross
/// products with the boundary vectors settle it (they agree with libm's `atan2` except within
/// ~1e-15 rad of a boundary).
#[inline]
fn sector_of(edges: &[(f64, f64)], x: f64, y: f64, sector_scale: f64) -> usize {
    let sectors = edges.len() - 1;
    if sectors < 8 {
        return (((y.atan2(x) + std::f64::consts::PI) * sector_scale) as usize).min(sectors - 1);
    }
    // In [0, S]: `as i64` truncates as `as usize` would.
    let s = (((fast_atan2(y, x) + std::f64::consts::PI) * sector_scale) as i64 as usize).min(sectors - 1);
    let (lx, ly) = edges[s];
    if lx * y - ly * x < 0.0 {
        return s.saturating_sub(1);
    }
    let (ux, uy) = edges[s + 1];
    if ux * y - uy * x >= 0.0 && s + 1 < sectors {
        s + 1
    } else {
        s
    }
}

/// [`sector_of`] without the `atan2` where it is sector `near` or one beside it, else `None`.
///
/// With `c_e` = (cross product of boundary `e` with the point `>= 0`), computed exactly as
/// `sector_of` does, a sector `h <= S - 2` with `c_h` and not `c_(h+1)` holds the point up to
/// rounding (a sector spans less than π/2), so the fast `atan2` (error < 1.2e-5 rad, below
/// a sector's width for every valid `S`) lands in `h - 1`, `h` or `h + 1`, and from each of
/// those `sector_of`'s two tests end in `h`.
#[inline]
fn sector_beside(edges: &[(f64, f64)], near: usize, x: f64, y: f64) -> Option<usize> {
    let sectors = edges.len() - 1;
    if sectors < 8 || near >= sectors - 1 {
        return None;
    }
    let at_or_above = |e: usize| {
        let (ex, ey) = edges[e];
        ex * y - ey * x >= 0.0
    };
    let (lo, hi) = (at_or_above(near), at_or_above(near + 1));
    if lo && !hi {
        Some(near)
    } else if hi {
        (near + 2 < sectors && !at_or_above(near + 2)).then_some(near + 1)
    } else {
        (near >= 1 && at_or_above(near - 1)).then(|| near - 1)
    }
}

/// The key of point `index` (below 2^32) with height `z` (finite) among the points of a
/// bin: the smallest key is the lowest point, the first in input order on a tie (`-0` and
/// `+0` tie, as they compare equal).
#[inline]
fn proto_key(z: f32, index: usize) -> u64 {
    // + 0.0 turns -0 into +0; then the bits, flipped to sort as the values do.
    let bits = (z + 0.0).to_bits();
    let ordered = bits ^ (((bits as i32) >> 31) as u32 | 0x8000_0000);
    (ordered as u64) << 32 | index as u64
}

/// The ground estimate of a sector while its lines are fitted (module doc, step 3): height
/// `z` [m] last seen at radius `r` [m]; `after_line`: the sector has an accepted line (else
/// the estimate is the ground under the robot).
#[derive(Debug, Clone, Copy)]
struct GroundEstimate {
    r: f64,
    z: f64,
    after_line: bool,
}

/// Whether a segment may start at the prototype `q = (r, z)` (module doc, step 3): within
/// `max_start_height_m` of the estimate, widened by `max_slope` per metre beyond it.
#[inline]
fn may_start(c: &GroundConfig, q: (f64, f64), g: GroundEstimate) -> bool {
    (q.1 - g.z).abs() <= c.max_start_height_m + c.max_slope * (q.0 - g.r).max(0.0)
}

/// Whether the line `z = m·r + b` whose first prototype is `first = (r, z)` starts on the
/// ground estimate `g` (module doc, step 3).
fn starts_on_ground(c: &GroundConfig, first: (f64, f64), m: f64, b: f64, g: GroundEstimate) -> bool {
    let t = c.max_start_height_m;
    if (first.1 - g.z).abs() <= t {
        return true;
    }
    // The line's height over the estimate is linear in r: over [lo, hi] it is within t of
    // 0 iff it changes sign there or an end is within t.
    let (lo, hi) = if g.r <= first.0 { (g.r, first.0) } else { (first.0, g.r) };
    let (d_lo, d_hi) = (m * lo + b - g.z, m * hi + b - g.z);
    (d_lo <= 0.0) != (d_hi < 0.0) || d_lo.abs().min(d_hi.abs()) <= t
}

/// Whether a segment whose first prototype is `first = (r, z)` starts over an unseen rise
/// from `g` (module doc, step 3; off when `unseen_rise_min_length_m` is 0); `before` holds
/// the heights of the sector's prototypes before `first`.
#[inline]
fn rises_unseen(c: &GroundConfig, first: (f64, f64), before: &[f64], g: GroundEstimate) -> bool {
    let rise = first.1 - g.z;
    c.unseen_rise_min_length_m > 0.0
        && !g.after_line
        && rise > c.max_start_height_m
        && rise <= c.max_start_height_m + c.max_slope * (first.0 - g.r).max(0.0)
        && before.iter().all(|&z| z >= first.1 - c.max_start_height_m)
}

/// `close(seg)` of the module doc; `before` holds the heights of the sector's prototypes
/// before `seg[0]`.
fn close(c: &GroundConfig, seg: &[(f64, f64, u32)], sums: &LineSums, g: &mut GroundEstimate, before: &[f64], lines: &mut Vec<GroundLine>) {
    if seg.len() < c.min_line_points as usize {
        return;
    }
    let Some((m, b, _)) = sums.fit() else { return };
    let first = (seg[0].0, seg[0].1);
    let unseen_rise = || {
        rises_unseen(c, first, before, *g)
            && seg[seg.len() - 1].0 - first.0 >= c.unseen_rise_min_length_m
            && m.abs() * c.unseen_rise_min_length_m <= c.max_start_height_m
    };
    if !starts_on_ground(c, first, m, b, *g) && !unseen_rise() {
        return;
    }
    let (last_r, _, last_bin) = seg[seg.len() - 1];
    lines.push(GroundLine { m, b, first_bin: seg[0].2, last_bin, first_r_m: seg[0].0, last_r_m: last_r });
    *g = GroundEstimate { r: last_r, z: m * last_r + b, after_line: true };
}

/// Labels each point of `points` (row-major `(N, 3)`, sensor-centred, z up) ground (`true`)
/// or obstacle (`false`) by the algorithm of the [module doc](self); `sensor_height_m` is
/// the origin's height above the ground near it [m].
pub fn segment_ground(points: &[f32], config: &GroundConfig, sensor_height_m: f64) -> Result<Vec<bool>> {
    let points = as_points("points", points)?;
    let mut segmenter = GroundSegmenter::new(*config)?;
    let mut heights = Vec::new();
    segmenter.segment(points, sensor_height_m, &mut heights)?;
    Ok(heights.iter().map(|&h| segmenter.is_ground(h)).collect())
}

/// `atan2(y, x)` to within 2e-5 rad (a minimax polynomial on [0, 1] and octant folding).
#[inline]
pub(crate) fn fast_atan2(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (num, den, swap) = if ay > ax { (ax, ay, true) } else { (ay, ax, false) };
    if den == 0.0 {
        return 0.0;
    }
    let t = num / den;
    let t2 = t * t;
    // Minimax coefficients for atan on [0, 1], |error| <= 1e-5 (Abramowitz & Stegun 4.4.49); with rounding < 2e-5.
    let mut a = t * (0.999_866_0 + t2 * (-0.330_299_5 + t2 * (0.180_141_0 + t2 * (-0.085_133_0 + t2 * 0.020_835_1))));
    if swap {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A level lidar `H` above flat ground: rings every 0.5° of depression from 16.5° to
    /// 1.5°, a column every 0.25° of azimuth; no return where `void(x, y)` (a hole with no
    /// floor in range) and, where `wall(x, y)` gives a height, a vertical face up to it.
    fn ring_scan(h: f64, void: impl Fn(f64, f64) -> bool, wall: impl Fn(f64, f64) -> Option<(f64, f64)>) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        for col in 0..1440 {
            let az = (col as f64 + 0.5) * 0.25f64.to_radians();
            let (sin, cos) = az.sin_cos();
            for ring in 0..31 {
                let d = (16.5 - 0.5 * ring as f64).to_radians();
                let r = h / d.tan();
                if let Some((wall_r, top)) = wall(cos, sin) {
                    // The face at wall_r blocks rays below its top.
                    let z = -wall_r * d.tan();
                    if r >= wall_r && z <= top - h {
                        out.push([(wall_r * cos) as f32, (wall_r * sin) as f32, z as f32]);
                        continue;
                    }
                }
                if !void(r * cos, r * sin) {
                    out.push([(r * cos) as f32, (r * sin) as f32, -h as f32]);
                }
            }
        }
        out
    }

    #[test]
    fn hole_whose_beams_come_back_from_below_the_ground_is_void() {
        // Regression (mine seed 16, "fall"): the beams that entered a hole came back from the
        // mine's wall 16 m away, 2-3 m below the floor; their ray spans covered the hole's
        // depressions, so it was taken for a shadow and rated drivable ground.
        let h = 0.76;
        let hole = |x: f64, y: f64| (x - 3.5).hypot(y) < 0.6;
        let mut points = ring_scan(h, hole, |_, _| None);
        for col in 0..1440 {
            let (sin, cos) = ((col as f64 + 0.5) * 0.25f64.to_radians()).sin_cos();
            for ring in 0..31 {
                let d = (16.5 - 0.5 * ring as f64).to_radians();
                if hole(h / d.tan() * cos, h / d.tan() * sin) {
                    points.push([(16.0 * cos) as f32, (16.0 * sin) as f32, (-16.0 * d.tan()) as f32]);
                }
            }
        }
        let config = GroundConfig { void_min_gap_deg: crate::terrain::config::SPINNING_LIDAR_VOID_MIN_GAP_DEG, ..GroundConfig::default() };
        let mut seg = GroundSegmenter::new(config).unwrap();
        let mut heights = Vec::new();
        seg.segment(&points, h, &mut heights).unwrap();
        for (x, y) in [(3.5, 0.0), (3.1, 0.1), (3.9, -0.2)] {
            assert!(seg.query(x, y).unwrap().void, "hole at ({x}, {y}) not void");
        }
        for (x, y) in [(3.5, 1.0), (5.0, 0.0), (-2.0, 0.5), (0.0, 3.0)] {
            assert!(!seg.query(x, y).unwrap().void, "ground at ({x}, {y}) taken for void");
        }
    }

    /// A level lidar `h` above flat ground (rings as [`ring_scan`]) with a pit `depth` deep
    /// between radii `near` and `near + 1.5` m for azimuths within 15° of +x, vertical sides:
    /// rays over the near edge reach the floor or the far wall; behind a 0.3 m rock face 3 m
    /// away along -x, the shadow of a rock.
    fn pit_scan(h: f64, depth: f64, near: f64) -> Vec<[f32; 3]> {
        let far = near + 1.5;
        let mut out = Vec::new();
        for col in 0..1440 {
            let az = (col as f64 + 0.5) * 0.25f64.to_radians();
            let (sin, cos) = az.sin_cos();
            let pit = cos > 15f64.to_radians().cos();
            let rock = cos < -0.99 && sin.abs() < 0.1;
            for ring in 0..31 {
                let t = (16.5 - 0.5 * ring as f64).to_radians().tan();
                let r = h / t;
                let (r, z) = if pit && (near..=far).contains(&r) {
                    let floor = (h + depth) / t;
                    if floor <= far { (floor, -h - depth) } else { (far, -far * t) }
                } else if rock && r >= 3.0 && -3.0 * t <= 0.3 - h {
                    (3.0, -3.0 * t)
                } else {
                    (r, -h)
                };
                out.push([(r * cos) as f32, (r * sin) as f32, z as f32]);
            }
        }
        out
    }

    #[test]
    fn the_ground_a_pit_edge_hides_is_as_deep_as_the_pit() {
        // Regression (mine seed 363, "fall"): the cells just past a pit's near edge had no
        // return, and the rays that grazed them, on their way to the far wall, passed barely
        // below the ground there: rated ground, the robot's corner went over the edge.
        let h = 0.7;
        let mut seg = GroundSegmenter::new(GroundConfig::default()).unwrap();
        let mut heights = Vec::new();
        seg.segment(&pit_scan(h, 0.5, 3.0), h, &mut heights).unwrap();
        let shadow = |x: f64, y: f64| seg.query(x, y).unwrap().shadow_depth;
        // Just past the edge, where the rays still pass within a few cm of the ground, and on.
        for (x, y) in [(3.05, 0.0), (3.15, 0.1), (3.5, -0.3), (4.2, 0.0)] {
            assert!(shadow(x, y) > 0.3, "pit at ({x}, {y}): shadow depth {}", shadow(x, y));
            assert!(seg.query(x, y).unwrap().ground_z - seg.query(x, y).unwrap().floor_bound_z < 0.13 || x > 3.5, "the rays alone rate ({x}, {y}) deep");
        }
        // Before the edge, beside the pit, between rings far off, behind the rock: none.
        for (x, y) in [(2.85, 0.0), (3.5, 2.5), (0.0, -9.0), (12.0, 6.0), (-3.3, 0.0), (-4.0, 0.1), (0.5, 0.5)] {
            assert!(shadow(x, y) < 0.03, "no drop at ({x}, {y}): shadow depth {}", shadow(x, y));
        }
        let mut off = GroundSegmenter::new(GroundConfig { drop_shadows: false, ..GroundConfig::default() }).unwrap();
        off.segment(&pit_scan(h, 0.5, 3.0), h, &mut heights).unwrap();
        assert_eq!(off.query(3.05, 0.0).unwrap().shadow_depth, 0.0);
        // The same pit 5 m out is seen at 8° (below the 10° default): it may be a slope the
        // robot could drive; at a 7° limit it is a drop's shadow.
        seg.segment(&pit_scan(h, 0.5, 5.0), h, &mut heights).unwrap();
        assert_eq!(seg.query(5.05, 0.0).unwrap().shadow_depth, 0.0);
        let mut shallow = GroundSegmenter::new(GroundConfig { drop_shadow_min_grazing_deg: 7.0, ..GroundConfig::default() }).unwrap();
        shallow.segment(&pit_scan(h, 0.5, 5.0), h, &mut heights).unwrap();
        let deep = shallow.query(5.05, 0.0).unwrap().shadow_depth;
        assert!(deep > 0.13, "{deep}");
        let err = GroundSegmenter::new(GroundConfig { drop_shadow_min_grazing_deg: 90.0, ..GroundConfig::default() }).unwrap_err().to_string();
        assert!(err.contains("drop_shadow_min_grazing_deg"), "{err}");
    }

    #[test]
    fn hole_with_no_floor_is_void_and_a_rock_shadow_is_not() {
        // Regression: a bottomless hole (the mine's NaN holes) gave no return and no
        // negative evidence; the robot drove its wheels over it (mine seed 0, "fall").
        let h = 0.76;
        let hole = |x: f64, y: f64| (x - 3.5).hypot(y) < 0.6;
        // A 0.3 m rock face 3 m away along -x (its top 0.46 m below the sensor).
        let rock = |cos: f64, sin: f64| (cos < -0.99 && sin.abs() < 0.1).then_some((3.0, 0.3));
        let points = ring_scan(h, hole, rock);
        let mut heights = Vec::new();
        // Off by default: no bin is void.
        let mut off = GroundSegmenter::new(GroundConfig::default()).unwrap();
        off.segment(&points, h, &mut heights).unwrap();
        assert!(!off.query(3.5, 0.0).unwrap().void);
        let config = GroundConfig { void_min_gap_deg: crate::terrain::config::SPINNING_LIDAR_VOID_MIN_GAP_DEG, ..GroundConfig::default() };
        let mut seg = GroundSegmenter::new(config).unwrap();
        seg.segment(&points, h, &mut heights).unwrap();
        for (x, y) in [(3.5, 0.0), (3.1, 0.1), (3.9, -0.2)] {
            assert!(seg.query(x, y).unwrap().void, "hole at ({x}, {y}) not void");
        }
        // Plain ground beside the hole, beyond it, and opposite it; the rock's shadow.
        for (x, y) in [(3.5, 1.0), (5.0, 0.0), (-2.0, 0.5), (0.0, 3.0), (-4.0, 0.0), (-3.8, 0.1)] {
            assert!(!seg.query(x, y).unwrap().void, "ground at ({x}, {y}) taken for void");
        }
        let mut samples = Vec::new();
        seg.void_samples(&mut samples);
        assert!(!samples.is_empty());
        assert!(samples.iter().all(|p| (f64::from(p[0]) - 3.5).hypot(f64::from(p[1])) < 0.8), "void samples off the hole");
        // A coarser sensor: rings 2° apart (VLP-16) over the same ground leave no void.
        let sparse: Vec<[f32; 3]> = ring_scan(h, |_, _| false, |_, _| None).into_iter().enumerate().filter(|(i, _)| i % 31 % 4 == 0).map(|(_, p)| p).collect();
        seg.segment(&sparse, h, &mut heights).unwrap();
        samples.clear();
        seg.void_samples(&mut samples);
        assert!(samples.is_empty(), "{} void samples on flat ground seen by 2° rings", samples.len());
    }

    /// A level lidar `h` above the ground at its foot, `ground(x, y)` the ground's height
    /// (vertical faces where it jumps): rings every 0.5° of depression from 16.5° to 1.5°, a
    /// column every 0.5°, each return found by marching the ray in 5 mm steps.
    fn heightfield_scan(h: f64, ground: impl Fn(f64, f64) -> f64) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        for col in 0..720 {
            let (sin, cos) = ((col as f64 + 0.5) * 0.5f64.to_radians()).sin_cos();
            for ring in 0..31 {
                let t = (16.5 - 0.5 * ring as f64).to_radians().tan();
                if let Some(r) = (1..8000).map(|i| f64::from(i) * 0.005).find(|&r| h - r * t <= ground(r * cos, r * sin)) {
                    out.push([(r * cos) as f32, (r * sin) as f32, (-r * t) as f32]);
                }
            }
        }
        out
    }

    #[test]
    fn ground_falling_away_in_the_blind_ring_is_ground_and_a_box_top_is_not() {
        // Regression (mine seed 8): the terrain ahead falls away (here 8.5°) from the robot's feet, so the
        // nearest ring meets it 0.25 m below -H; no line could start more than T_b = 0.2 m
        // from -H, every point up to the next rise was an obstacle (a lethal `collision` fan).
        let h = 0.7;
        let dip = |x: f64| -0.15 * x.max(0.0);
        // Behind the robot, a 0.3 m box 0.8 m deep.
        let boxed = |x: f64, y: f64| (-3.5..=-2.7).contains(&x) && y.abs() < 0.5;
        let points = heightfield_scan(h, |x, y| if boxed(x, y) { 0.3 } else { dip(x) });
        let mut seg = GroundSegmenter::new(GroundConfig::default()).unwrap();
        let mut heights = Vec::new();
        seg.segment(&points, h, &mut heights).unwrap();
        let (mut ahead_n, mut ahead_ground, mut top_n, mut top_ground) = (0, 0, 0, 0);
        for (p, &hg) in points.iter().zip(&heights) {
            let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            if x > 2.0 && y.abs() < 0.5 * x {
                ahead_n += 1;
                ahead_ground += usize::from(seg.is_ground(hg));
            }
            if boxed(x - 0.03, y) && z > 0.25 - h {
                top_n += 1;
                top_ground += usize::from(seg.is_ground(hg));
            }
        }
        assert!(ahead_n > 500 && ahead_ground == ahead_n, "{ahead_ground} of {ahead_n} points of the falling ground are ground");
        assert!(top_n > 20 && top_ground == 0, "{top_ground} of {top_n} box-top points are ground");
        // A level line more than T_b above the ground is no ground at any distance: a 0.3 m
        // high plateau beyond a 2 m gap with no returns (a trench whose floor is out of sight).
        let trench = heightfield_scan(h, |x, _| if x < 4.0 { 0.0 } else if x < 6.0 { -5.0 } else { 0.3 });
        seg.segment(&trench, h, &mut heights).unwrap();
        let plateau: Vec<bool> = trench.iter().zip(&heights).filter(|(p, _)| p[0] > 6.1 && p[1].abs() < 1.0).map(|(_, &hg)| seg.is_ground(hg)).collect();
        assert!(plateau.len() > 20 && plateau.iter().all(|&g| !g), "{} of {} plateau points ground", plateau.iter().filter(|&&g| g).count(), plateau.len());
    }

    fn flat_ring_cloud(height: f32) -> Vec<f32> {
        let mut flat = Vec::new();
        for ring in 0..12 {
            let r = 1.0 + ring as f32 * 0.7;
            for a in 0..360 {
                let t = (a as f32).to_radians();
                flat.extend_from_slice(&[r * t.cos(), r * t.sin(), -height]);
            }
        }
        flat
    }

    #[test]
    fn flat_ground_is_all_ground() {
        let flat = flat_ring_cloud(0.6);
        let labels = segment_ground(&flat, &GroundConfig::default(), 0.6).unwrap();
        assert!(labels.iter().all(|&g| g));
    }

    #[test]
    fn a_pole_above_flat_ground_is_obstacle() {
        let mut flat = flat_ring_cloud(0.6);
        let n_ground = flat.len() / 3;
        for i in 0..10 {
            flat.extend_from_slice(&[3.05, 0.05, -0.6 + 0.15 * (i + 1) as f32]);
        }
        let labels = segment_ground(&flat, &GroundConfig::default(), 0.6).unwrap();
        assert!(labels[..n_ground].iter().all(|&g| g));
        assert!(labels[n_ground..].iter().all(|&g| !g), "{:?}", &labels[n_ground..]);
    }

    #[test]
    fn proto_keys_sort_as_lowest_then_first() {
        let zs = [-3.5f32, -1e-30, -0.0, 0.0, 1e-30, 0.25, 7.0, f32::MAX, f32::MIN];
        for (i, &a) in zs.iter().enumerate() {
            for (j, &b) in zs.iter().enumerate() {
                // Point 5 with z = a against point 9 with z = b: 5 wins iff a <= b.
                assert_eq!(proto_key(a, 5) < proto_key(b, 9), a <= b, "{a} {b}");
                assert_eq!(proto_key(a, i) == proto_key(b, j), a == b && i == j, "{a} {b}");
            }
        }
        assert_eq!(proto_key(-2.0, 7) as u32, 7);
    }

    #[test]
    fn line_sums_fit_by_hand() {
        // z = 0.5 r - 1 through three points, then one 0.3 m off.
        let s = LineSums::start(1.0, -0.5).with(2.0, 0.0).with(3.0, 0.5);
        let (m, b, rmse) = s.fit().unwrap();
        assert!((m - 0.5).abs() < 1e-12 && (b + 1.0).abs() < 1e-12 && rmse < 1e-9);
        // Points (0,0), (1,0), (2,0.3): m = 0.15, b = -0.05, residuals 0.05, -0.1, 0.05.
        let (m, b, rmse) = LineSums::start(0.0, 0.0).with(1.0, 0.0).with(2.0, 0.3).fit().unwrap();
        assert!((m - 0.15).abs() < 1e-12 && (b + 0.05).abs() < 1e-12);
        assert!((rmse - (0.015f64 / 3.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn sectors_agree_with_libm_atan2() {
        let config = GroundConfig::default();
        let seg = GroundSegmenter::new(config).unwrap();
        let scale = config.sectors as f64 / std::f64::consts::TAU;
        let exact = |x: f64, y: f64| (((y.atan2(x) + std::f64::consts::PI) * scale) as usize).min(config.sectors as usize - 1);
        let mut state = 12345u64;
        for i in 0..200_000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let a = (state >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::TAU - std::f64::consts::PI;
            // Every 4th point sits within 1e-9 rad of a sector boundary.
            let a = if i % 4 == 0 { -std::f64::consts::PI + ((a + std::f64::consts::PI) * scale).round() / scale + 1e-9 * a.signum() } else { a };
            let r = 0.5 + (i % 97) as f64 * 0.3;
            let (x, y) = (r * a.cos(), r * a.sin());
            assert_eq!(seg.sector_of(x, y, scale), exact(x, y), "angle {a}");
        }
    }

    #[test]
    fn sector_beside_agrees_with_sector_of() {
        let mut state = 777u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for sectors in [8u32, 9, 360, 720, 100_000] {
            let config = GroundConfig { sectors, max_range_m: 10.0, bin_m: 5.0, ..GroundConfig::default() };
            let seg = GroundSegmenter::new(config).unwrap();
            let scale = sectors as f64 / std::f64::consts::TAU;
            let edges = &seg.sector_edges;
            let mut found = 0;
            for i in 0..100_000 {
                let a = next() * std::f64::consts::TAU - std::f64::consts::PI;
                // Every 3rd point sits within 1e-12 rad of a sector boundary; some on the axes.
                let a = match i % 3 {
                    0 => -std::f64::consts::PI + ((a + std::f64::consts::PI) * scale).round() / scale + 1e-12 * (next() - 0.5),
                    1 if i % 300 == 1 => (i % 8) as f64 * std::f64::consts::FRAC_PI_4 - std::f64::consts::PI,
                    _ => a,
                };
                let r = 0.5 + 9.0 * next();
                let (x, y) = (r * a.cos(), r * a.sin());
                let exact = sector_of(edges, x, y, scale);
                for near in [exact.wrapping_sub(2), exact.wrapping_sub(1), exact, exact + 1, exact + 2, 0, sectors as usize - 1, usize::MAX] {
                    if let Some(s) = sector_beside(edges, near, x, y) {
                        assert_eq!(s, exact, "sectors {sectors}, angle {a}, near {near}");
                        found += 1;
                    }
                }
            }
            assert!(found > 200_000, "{found}");
        }
    }

    #[test]
    fn query_row_is_query() {
        let mut flat = flat_ring_cloud(0.6);
        flat.extend_from_slice(&[3.0, 0.1, -0.2, -2.0, 4.0, -1.4, 0.0, -5.0, -0.9]);
        let points = as_points("points", &flat).unwrap();
        let mut seg = GroundSegmenter::new(GroundConfig::default()).unwrap();
        let mut heights = Vec::new();
        seg.segment(points, 0.6, &mut heights).unwrap();
        let xs: Vec<f64> = (0..500).map(|i| -45.0 + i as f64 * 0.18 + 0.001).collect();
        for j in 0..300 {
            let y = -45.0 + j as f64 * 0.3;
            let mut got = Vec::new();
            seg.query_row(&xs, y, |i, bin| got.push((i, bin)));
            let want: Vec<_> = xs.iter().enumerate().filter_map(|(i, &x)| seg.query(x, y).map(|bin| (i, bin))).collect();
            assert_eq!(got, want);
        }
    }

    /// Step 4 bin by bin, as the module doc states it.
    fn assign_by_bin(lines: &[GroundLine], bins: usize, h: f64) -> Vec<BinLine> {
        (0..bins)
            .map(|k| {
                if lines.is_empty() {
                    return BinLine { b: -h, ..BinLine::NONE };
                }
                let first = &lines[0];
                if k < first.first_bin as usize && first.first_r_m > 0.0 {
                    // From the ground under the sensor to the first line's first prototype.
                    return BinLine { m: (first.m * first.first_r_m + first.b + h) / first.first_r_m, b: -h, ..BinLine::NONE };
                }
                if let Some(line) = lines.iter().find(|l| l.first_bin as usize <= k && k <= l.last_bin as usize) {
                    return BinLine::of(line, true);
                }
                let dist = |l: &GroundLine| if k < l.first_bin as usize { l.first_bin as usize - k } else { k - l.last_bin as usize };
                let nearest = lines.iter().min_by_key(|l| dist(l)).unwrap();
                BinLine::of(nearest, false)
            })
            .collect()
    }

    #[test]
    fn bin_lines_by_range_match_bin_by_bin() {
        let config = GroundConfig { sectors: 1, ..GroundConfig::default() };
        let mut seg = GroundSegmenter::new(config).unwrap();
        let bins = seg.bins;
        seg.sensor_height_m = 0.6;
        let mut state = 99u64;
        let mut next = |n: usize| {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 33) % n as u64) as usize
        };
        for trial in 0..3000 {
            // Lines in bin order, each starting at or after the previous one's last bin and
            // spanning two bins or more (min_line_points >= 2 prototypes, one per bin).
            let mut lines = Vec::new();
            let mut at = if trial % 3 == 0 { 0 } else { next(12) };
            while at + 1 < bins && lines.len() < 1 + trial % 7 {
                let first = at;
                let last = (first + [1, 2, 5, 30][next(4)]).min(bins - 1);
                let m = lines.len() as f64 * 0.01 + trial as f64 * 1e-4;
                lines.push(GroundLine { m, b: -0.5 - m, first_bin: first as u32, last_bin: last as u32, first_r_m: first as f64 * 0.2 + 0.05, last_r_m: last as f64 * 0.2 + 0.1 });
                // Shared break bin, adjacent, or a gap (odd and even widths).
                at = last + [0, 1, 2, 3, 8, 15][next(6)];
            }
            seg.lines = lines.clone();
            seg.bin_lines.clear();
            seg.sector_lines[0] = (0, lines.len() as u32);
            seg.assign_lines(0);
            let want = assign_by_bin(&lines, bins, 0.6);
            for (k, b) in want.iter().enumerate() {
                let a = &seg.bin_lines[seg.bin_line[k] as usize];
                let bits = |l: &BinLine| [l.m.to_bits(), l.b.to_bits(), l.cover_lo.to_bits(), l.cover_hi.to_bits()];
                assert_eq!(bits(a), bits(b), "trial {trial}, bin {k}, lines {lines:?}");
            }
        }
    }

    #[test]
    fn fast_atan2_is_close() {
        for i in 0..1000 {
            let t = i as f64 * 0.0123 - 6.0;
            let (y, x) = (t.sin() * 3.0, t.cos() * 3.0);
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{t}");
        }
    }

    #[test]
    fn wrong_inputs_name_their_argument() {
        assert!(segment_ground(&[1.0, 2.0], &GroundConfig::default(), 0.5).unwrap_err().to_string().contains("points"));
        assert!(segment_ground(&[1.0, 2.0, 3.0], &GroundConfig::default(), f64::NAN).unwrap_err().to_string().contains("sensor_height_m"));
        let config = GroundConfig { sectors: 0, ..GroundConfig::default() };
        assert!(segment_ground(&[], &config, 0.5).unwrap_err().to_string().contains("ground.sectors"));
    }
}
