//! Polar binning: which sector and bin each point falls in (a fast `atan2` settled by
//! cross products with the sector boundaries), each bin's prototype (its lowest point) and
//! the steepest ray over it (steps 1 and 2 of the algorithm in the parent module's doc).

use std::cmp::Ordering;

use super::{BinAccumulator, GroundSegmenter, NO_BIN};

impl GroundSegmenter {
    pub(super) fn bin_points(&mut self, points: &[[f32; 3]]) {
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
            if r.partial_cmp(&max_r).is_none_or(Ordering::is_ge) || !z.is_finite() {
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

    /// `min(floor((atan2(y, x) + π) / (2π/S)), S - 1)`: see [`sector_of`].
    #[cfg(test)]
    pub(super) fn sector_of(&self, x: f64, y: f64, sector_scale: f64) -> usize {
        sector_of(&self.sector_edges, x, y, sector_scale)
    }
}

/// `min(floor((atan2(y, x) + π) / (2π/S)), S - 1)` with `edges` the `S + 1` unit vectors of
/// the sector boundaries: a fast `atan2` gives the sector to within one, and two cross
/// products with the boundary vectors settle it (they agree with libm's `atan2` except within
/// ~1e-15 rad of a boundary).
#[inline]
pub(super) fn sector_of(edges: &[(f64, f64)], x: f64, y: f64, sector_scale: f64) -> usize {
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
pub(super) fn sector_beside(edges: &[(f64, f64)], near: usize, x: f64, y: f64) -> Option<usize> {
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
pub(super) fn proto_key(z: f32, index: usize) -> u64 {
    // + 0.0 turns -0 into +0; then the bits, flipped to sort as the values do.
    let bits = (z + 0.0).to_bits();
    let ordered = bits ^ (((bits as i32) >> 31) as u32 | 0x8000_0000);
    (ordered as u64) << 32 | index as u64
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
