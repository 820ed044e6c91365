//! Ground segmentation by line fits in cylindrical coordinates (Himmelsbach, Hundelshausen,
//! Wuensche, "Fast segmentation of 3D point clouds for ground vehicles", IEEE IV 2010).
//!
//! Documented on [`segment_ground`].

mod drops;
mod lines;
mod polar;
#[cfg(test)]
mod tests;

use std::cmp::Ordering;

use super::config::GroundConfig;
use crate::error::{Error, Result};
use crate::terrain::cloud::as_points;
use polar::fast_atan2;
#[cfg(doc)]
use polar::proto_key;

/// Marks a point without a polar bin.
const NO_BIN: u32 = u32::MAX;

/// One accepted ground line of a sector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct GroundLine {
    /// Slope dz/dr \[1\].
    pub m: f64,
    /// Height at r = 0 \[m\].
    pub b: f64,
    /// First bin covered.
    pub first_bin: u32,
    /// Last bin covered.
    pub last_bin: u32,
    /// Radius of the first prototype \[m\].
    pub first_r_m: f64,
    /// Radius of the last prototype \[m\].
    pub last_r_m: f64,
}

/// What the segmentation knows about one polar bin (see `segment_ground`'s docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PolarBin {
    /// Whether an accepted line covers the bin and the queried radius lies between the
    /// line's first and last prototype.
    pub covered: bool,
    /// The expected ground at the queried radius: the bin's line, capped beyond a rising line's
    /// last prototype (`segment_ground`'s docs) [m, sensor-centred].
    pub ground_z: f64,
    /// Upper bound of the floor at the queried radius: the lower of the bin's lowest point
    /// and the lowest ray that passed over it; `+inf` without evidence [m, sensor-centred].
    pub floor_bound_z: f64,
    /// Whether the bin is void: beams crossed its expected ground and none returned.
    pub void: bool,
    /// How deep the drop may be that begins at the queried radius: the deepest evidence of
    /// missing ground in the shadow run it lies in (`segment_ground`'s docs, *Shadow*), 0 outside one \[m\].
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
    /// After the sweep: whether the bin is void (`segment_ground`'s docs).
    void: bool,
    /// The radius of the bin's farthest return that came back (not more than
    /// `max_dist_to_line_m` below its line); `-inf` when none did.
    solid_r: f32,
    /// After the sweep: the shadow depth beyond `solid_r` (`segment_ground`'s docs, *Shadow*) \[m\].
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

/// Ground segmentation with reusable buffers. The config is trusted once [`new`](Self::new)
/// has validated it.
#[derive(Debug, Clone)]
pub(super) struct GroundSegmenter {
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
    pub(super) fn new(config: GroundConfig) -> Result<Self> {
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

    /// Segments `points` (sensor-centred, z up; see `segment_ground`'s docs) and writes each point's
    /// height above its ground line to `heights_out` (NaN for points without a bin).
    pub(super) fn segment(&mut self, points: &[[f32; 3]], sensor_height_m: f64, heights_out: &mut Vec<f32>) -> Result<()> {
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
        // Each bin's `solid_r` (`segment_ground`'s docs, *Shadow*) in the same pass: the radius of its
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
    pub(super) fn void_samples(&self, out: &mut Vec<[f32; 2]>) {
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
    pub(super) fn is_ground(&self, height_above_ground_m: f32) -> bool {
        height_above_ground_m.abs() <= self.config.max_dist_to_line_m as f32
    }

    /// What the last segmentation knows at the sensor-centred horizontal position
    /// `(x, y)` \[m\]; `None` outside the polar range. Uses a fast `atan2` (error < 2e-5 rad),
    /// so a position within that of a sector boundary may be given the neighbouring sector.
    #[cfg(test)]
    #[inline]
    pub(super) fn query(&self, x: f64, y: f64) -> Option<PolarBin> {
        let r = (x * x + y * y).sqrt();
        if r.partial_cmp(&self.config.max_range_m).is_none_or(Ordering::is_ge) {
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
            if r.partial_cmp(&max_r).is_none_or(Ordering::is_ge) {
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
}

/// Lowest sensor height above the ground accepted by [`segment_ground`] (and the terrain
/// CLI's `--sensor-height`) \[m\]; below: a typo, or a value in kilometres.
pub const MIN_SENSOR_HEIGHT_M: f64 = 0.01;
/// Highest sensor height accepted \[m\]; beyond: a typo, or millimetres.
pub const MAX_SENSOR_HEIGHT_M: f64 = 100.0;

/// Labels each point of `points` (row-major `(N, 3)`, sensor-centred, z up) ground (`true`)
/// or obstacle (`false`) by line fits in cylindrical coordinates (Himmelsbach et al., IEEE IV
/// 2010; set out exactly below); `sensor_height_m` is the
/// origin's height above the ground near it \[m\].
///
/// In: points in a gravity-aligned frame centred on the sensor. Out: each point's height
/// above its sector's ground line, hence a ground / obstacle label, and per polar bin the
/// ground line and the lowest evidence of where the floor can be (used by the `negative`
/// risk layer and to fill the ground height between scan rings).
///
/// # The algorithm, exactly
///
/// Inputs: points `(x, y, z)` (f32, converted to f64 for every computation below) in a frame
/// whose z axis points up and whose origin is the sensor; `H = sensor_height_m`, the origin's
/// height above the ground near it; a [`GroundConfig`] (`S = sectors`, `Δ = bin_m`,
/// `R = max_range_m`, `B = ceil(R / Δ)` bins).
///
/// 1. **Polar bins.** `r = sqrt(x² + y²)`. A point with `r >= R` (or a non-finite coordinate)
///    gets no bin. Otherwise sector `s = min(floor((atan2(y, x) + π) / (2π / S)), S - 1)` and
///    bin `k = min(floor(r / Δ), B - 1)`.
/// 2. **Prototypes.** Each non-empty bin's prototype is its lowest point `(r, z)` (smallest
///    z; on a tie, the first in input order).
/// 3. **Line fits, per sector**, visiting its prototypes `p = (r, z)` in increasing bin order.
///    State: the ground estimate `g`, a height `z_g` seen at radius `r_g` (starts at
///    `(0, -H)`: the ground the robot stands on), the current segment `seg` (a list of
///    prototypes, starts empty), the sector's accepted lines. `fit(P)` is the least-squares
///    line `z = m·r + b` through the points `P`; `rmse(P)` is `sqrt(Σ (z - m·r - b)² / |P|)`
///    of that fit. A line *starts on the ground* when its first prototype `q` lies within
///    `max_start_height_m` (Himmelsbach's T_b) of `z_g`, or the line itself comes within
///    T_b of `z_g` somewhere between `r_g` and `q.r`: the ground rose or fell from where it
///    was last seen over a stretch the sensor did not see (the blind ring around the robot,
///    a hole), and the line leads back to it. For each prototype `p`:
///    - if `seg` is empty: `seg = [p]`;
///    - else if `p.r - last(seg).r > max_gap_m`: `close(seg)`, then `seg = [p]`;
///    - else if `|seg| = 1` (`q` its point): if `|q.z - z_g| <= max_start_height_m +
///      max_slope · max(q.r - r_g, 0)` (the ground can have changed at most that much over
///      the unseen stretch) and `|p.z - q.z| <= max_slope · (p.r - q.r)`, append `p`;
///      otherwise `seg = [p]`;
///    - else (`|seg| >= 2`): with `(m0, b0) = fit(seg)` and `(m1, b1) = fit(seg + [p])`,
///      append `p` if `|p.z - (m0·p.r + b0)| <= max_prediction_error_m` and
///      `|m1| <= max_slope` and `rmse(seg + [p]) <= max_rmse_m` and the line `(m1, b1)`
///      starts on the ground. Otherwise `close(seg)`, set
///      `seg = [last(seg)]` (the break point starts the next segment) and handle `p` again
///      by the rules above (it now meets the `|seg| = 1` rule).
///
///    With `unseen_rise_min_length_m` = `U` > 0 the sector's first line also *starts on
///    the ground over an unseen rise* when no line has been accepted before it (the
///    estimate is still the ground under the robot), `max_start_height_m < q.z - z_g <=
///    max_start_height_m + max_slope · q.r` for its first prototype `q` (a ramp no steeper
///    than `max_slope` hidden in the blind ring could lead up to it) and no prototype of the
///    sector before `q` lies more than `max_start_height_m` below `q` (nothing was seen in
///    the stretch: no floor, no face of a box). Beyond an accepted line (the far side of a
///    hole, a crest) the rule does not apply. While a segment grows this counts as starting
///    on the ground; `close` accepts such a line only if it is a plateau, not a box top or a
///    slope: its last prototype at least `U` beyond its first, and level (`|m|·U <=
///    max_start_height_m`).
///
///    After the last prototype, `close(seg)`. `close(seg)`: if `|seg| >= min_line_points`
///    and the line `(m, b) = fit(seg)` starts on the ground, accept it covering bins
///    `[bin(first(seg)), bin(last(seg))]` and set `g = (last(seg).r, m·last(seg).r + b)`;
///    otherwise discard it. The top of a box is a level line more than T_b above the ground
///    everywhere: never accepted, however far away.
/// 4. **Line of each bin.** Bin `k` of a sector takes the first accepted line (in order of
///    acceptance) whose bin interval contains `k` (the bin is then *covered*); if none does,
///    the line whose interval is nearest in bins (distance `first - k` or `k - last`; on a tie
///    the earlier line), except before the sector's first line, where it takes the straight
///    line from the ground under the sensor `(0, -H)` to that line at its first prototype's
///    radius `r₁` (`m = (z₁ + H) / r₁, b = -H`; not covered). A sector without lines uses
///    the flat line `m = 0, b = -H`.
/// 5. **Labels.** A point's height above ground is `h = z - (m·r + b)` with its bin's line;
///    it is ground iff `|h| <= max_dist_to_line_m`. Points without a bin are obstacles with
///    `h = NaN`.
///
/// Byproducts per bin (not part of the labels): the *expected ground* at radius r is the
/// bin's line there, except beyond the last prototype of a rising line (`m > 0`), where it
/// stays at the line's height at that prototype (past a crest the ground may fall away out of
/// sight); *coverage* of a position at radius r in a
/// covered bin holds when r also lies between the radii of the line's first and last
/// prototype; the lowest point's z (`floor_z`), and the steepest downward ray slope
/// `min(z / r)` over the prototypes of all *farther* bins of the sector: a ray from the
/// sensor to such a point passed over this bin at height `slope · r`, so the floor here is
/// at most that high.
///
/// *Void* (missing ground): per sector, visiting its non-empty bins in increasing order, a
/// run of empty bins between bin `a` and the next non-empty bin `b` is void when the rays
/// that would meet the run's expected ground (its bins' lines, capped as above) leave an angular stretch of
/// more than `void_min_gap_deg` (depression) with no return: of the depressions between
/// `hi` = min(`a`'s shallowest ray, the expected ground at the run's start) and `lo` =
/// max(the steepest ray to a farther bin not steeper than `a`'s shallowest, the expected
/// ground at the run's end), none lies in a bin's ray span `[shallowest, steepest]` (any bin
/// of the sector) for more than that. A bin's ray span is over its points with `h >=
/// -max_dist_to_line_m` (step 5): a return from deeper below its line came through the
/// floor (the inside of a hole, or whatever lies under it: the beam crossed the expected
/// ground where there was none) and is evidence of the void, not a beam that came back.
/// Beams must have crossed the expected ground there and none came back from it: the floor
/// is missing (a hole, or a drop beyond the sensor's range). Runs behind an occluder, past
/// a crest, or beyond a partial occluder are not void: the rays over them came back from
/// farther, or from the occluder.
///
/// *Shadow* (`drop_shadows`): a drop with a floor (a pit, a ledge) hides the floor behind
/// its near edge. Per sector, a bin's return *came back* when it lies not more than
/// `max_dist_to_line_m` below its line; the bins after a bin's farthest such return, up to
/// the next bin with one, form a *run*. Each bin of a run has a depth below the ground last
/// seen going on (the expected ground of the bin that starts the run, its line continued):
/// that at the bin's far edge minus the steepest downward ray to a farther bin's prototype
/// there, or, if deeper, how far its lowest point lies below it where that is more than
/// `max_dist_to_line_m`. The starting bin's line, not the bin's own: a line accepted from
/// the near rim to the floor or far wall of a pit (a "slope" with nothing returned along
/// it) would otherwise explain the drop away. The floor is missing wherever a ray passed
/// below that ground, and from the return that starts the run to there nothing shows where
/// the drop begins: every position of the run (including the part of the starting bin beyond its
/// farthest return) takes the deepest depth of the run's bins from there on, at least 0
/// (`shadow_depth`), if the ray to that return (at the expected ground there) descends at
/// least `drop_shadow_min_grazing_deg`; otherwise, and before the sector's first return (the
/// blind ring around the sensor), there is no shadow. Ground hidden behind a return is
/// steeper than the ray that grazed it, or falls away: seen at a grazing angle above the
/// robot's safe tilt, every reading of the run is a hazard; at a shallower one (far away,
/// past a crest) it may be a slope the robot could drive, which it sees from closer. Behind
/// a rock the rays over the run pass above the ground (depth 0); between two rings on flat
/// ground they too pass above it.
pub fn segment_ground(points: &[f32], config: &GroundConfig, sensor_height_m: f64) -> Result<Vec<bool>> {
    let points = as_points("points", points)?;
    if !(MIN_SENSOR_HEIGHT_M..=MAX_SENSOR_HEIGHT_M).contains(&sensor_height_m) {
        return Err(crate::error::Error::input(
            "sensor_height_m",
            format!("must be in [{MIN_SENSOR_HEIGHT_M}, {MAX_SENSOR_HEIGHT_M}] m, got {sensor_height_m}"),
        ));
    }
    let mut segmenter = GroundSegmenter::new(*config)?;
    let mut heights = Vec::new();
    segmenter.segment(points, sensor_height_m, &mut heights)?;
    Ok(heights.iter().map(|&h| segmenter.is_ground(h)).collect())
}
