//! Ground line fits per sector (step 3 of the algorithm in the parent module's doc) and
//! the line each polar bin takes from them (step 4).

use std::cmp::Ordering;

use super::{BinLine, GroundLine, GroundSegmenter};
use crate::terrain::config::GroundConfig;

impl GroundSegmenter {
    pub(super) fn fit_lines(&mut self) {
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
    pub(super) fn assign_lines(&mut self, s: usize) {
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

/// Running least-squares sums of a segment, centred on its first point.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LineSums {
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
    pub(super) fn start(r: f64, z: f64) -> Self {
        Self { n: 1.0, r0: r, z0: z, ..Default::default() }
    }

    pub(super) fn with(&self, r: f64, z: f64) -> Self {
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
    pub(super) fn fit(&self) -> Option<(f64, f64, f64)> {
        let denom = self.n * self.srr - self.sr * self.sr;
        if denom.partial_cmp(&0.0).is_none_or(Ordering::is_le) {
            return None;
        }
        let m = (self.n * self.srz - self.sr * self.sz) / denom;
        let bc = (self.sz - m * self.sr) / self.n;
        let sse = self.szz - 2.0 * m * self.srz - 2.0 * bc * self.sz + m * m * self.srr + 2.0 * m * bc * self.sr + self.n * bc * bc;
        let b = bc + self.z0 - m * self.r0;
        Some((m, b, (sse.max(0.0) / self.n).sqrt()))
    }
}

/// The ground estimate of a sector while its lines are fitted (`segment_ground`'s docs, step 3): height
/// `z` \[m\] last seen at radius `r` \[m\]; `after_line`: the sector has an accepted line (else
/// the estimate is the ground under the robot).
#[derive(Debug, Clone, Copy)]
struct GroundEstimate {
    r: f64,
    z: f64,
    after_line: bool,
}

/// Whether a segment may start at the prototype `q = (r, z)` (`segment_ground`'s docs, step 3): within
/// `max_start_height_m` of the estimate, widened by `max_slope` per metre beyond it.
#[inline]
fn may_start(c: &GroundConfig, q: (f64, f64), g: GroundEstimate) -> bool {
    (q.1 - g.z).abs() <= c.max_start_height_m + c.max_slope * (q.0 - g.r).max(0.0)
}

/// Whether the line `z = m·r + b` whose first prototype is `first = (r, z)` starts on the
/// ground estimate `g` (`segment_ground`'s docs, step 3).
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
/// from `g` (`segment_ground`'s docs, step 3; off when `unseen_rise_min_length_m` is 0); `before` holds
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

/// `close(seg)` of `segment_ground`'s docs; `before` holds the heights of the sector's prototypes
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
