//! Evidence of missing ground: void runs (beams crossed the expected ground and none came
//! back) and drop shadows (the floor hidden behind a drop's near edge), as the *Void* and
//! *Shadow* sections of the parent module's doc define them.

use std::cmp::Ordering;

use super::{BinAccumulator, GroundSegmenter, NO_BIN};

impl GroundSegmenter {
    /// Each bin's ray span for the void detection (`segment_ground`'s docs, *Void*): the slopes `z/r` of
    /// its points that are not more than `max_dist_to_line_m` below its ground line, and its
    /// `solid_r` (the largest `r` of the same points; `segment_ground`'s docs, *Shadow*). A return
    /// from deeper came through the floor: its ray crossed the expected ground where there
    /// was none (a hole's inside, or what lies under it), so it is evidence for a void, not a
    /// beam that came back from the ground.
    pub(super) fn gather_ray_spans(&mut self, points: &[[f32; 3]], heights: &[f32]) {
        let below = -(self.config.max_dist_to_line_m as f32);
        let acc = &mut self.acc[..];
        for ((&sb, p), &h) in self.point_bin.iter().zip(points).zip(heights) {
            if sb == NO_BIN || h.partial_cmp(&below).is_none_or(Ordering::is_lt) {
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

    /// The shadow depth of every bin (`segment_ground`'s docs, *Shadow*): per sector, from the sensor out,
    /// the return that starts each bin's run; from the farthest bin in, the deepest missing
    /// ground below that return's line over the rest of the run, kept where that return is
    /// seen steeply enough.
    pub(super) fn mark_shadows(&mut self) {
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

    /// Marks the void runs of every sector (`segment_ground`'s docs, *Void*).
    pub(super) fn mark_voids(&mut self) {
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
}
