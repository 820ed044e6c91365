//! The transition model `T(s -> s') ∝ hn(L1(s, s'); σ_s) · hn(z(s'); σ_z)`, precomputed once.
//!
//! Documented on [`TransitionModel`].

use rand::Rng;

use super::alias::AliasTable;
use super::grid::{DepthVoxelGrid, StateId, VoxelIndex};
use crate::config::{FreeStateDepth, TransitionConfig};
use crate::error::{Error, Result};

/// Redraws of an out-of-grid offset before the exact (slow) fallback draw is used. With
/// class tables the acceptance rate is about 0.6 or more for every voxel of a sensible
/// grid, so this is never reached in practice; it only guards against degenerate parameters.
pub(crate) const MAX_OFFSET_REDRAWS: usize = 4096;

/// Most classes of source columns (and, separately, of source rows) that share one offset
/// table per source depth bin: at most `MAX_CLASSES²·N_d` tables. The tables hold about
/// `(MAX_CLASSES + 1)²·S·N_d` 8-byte slots (flight: 2.7 MB; 40x30 blocks x 17 bins, S ≈ 20k:
/// about 70 MB, against 3.3 GB for a dense f64 matrix); a member's first attempt lands in
/// the grid with probability ≈ (n/(n + n/C))² for n blocks in C classes (flight: 0.55-0.86).
pub(super) const MAX_CLASSES: usize = 4;

/// A signed offset `(di, dj, k')` of a class table, with its flat state delta
/// `(dj·N_w + di)·N_d + k'` from the source block's first state.
#[derive(Debug, Clone, Copy, Default)]
struct Offset {
    delta: i32,
    di: i16,
    dj: i16,
}

/// One alias slot over a class table's offsets: keep the slot's own offset if the 32-bit
/// coin is below `keep`, else take offset `alias`.
#[derive(Debug, Clone, Copy)]
struct OffsetSlot {
    keep: u32,
    alias: u32,
}

/// Contiguous classes of `0..n`: at most `MAX_CLASSES` (4) runs of near-equal length.
#[derive(Debug, Clone)]
struct Classes {
    /// Class of each index.
    of: Vec<u16>,
    /// First and last index of each class.
    bounds: Vec<(usize, usize)>,
}

impl Classes {
    fn new(n: usize) -> Self {
        let c = n.clamp(1, MAX_CLASSES);
        let bounds: Vec<(usize, usize)> = (0..c).map(|m| (m * n / c, (m + 1) * n / c - 1)).collect();
        let mut of = vec![0u16; n];
        for (m, &(lo, hi)) in bounds.iter().enumerate() {
            of[lo..=hi].fill(m as u16);
        }
        Self { of, bounds }
    }

    /// The offsets that some member of class `m` keeps inside `0..n`: `-hi ..= n-1-lo`.
    fn offsets(&self, m: usize, n: usize) -> std::ops::RangeInclusive<i64> {
        let (lo, hi) = self.bounds[m];
        -(hi as i64)..=(n - 1 - lo) as i64
    }
}

/// Draws voxel successors of one source voxel (see [`TransitionModel::voxel_sampler`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct VoxelSampler<'a> {
    model: &'a TransitionModel,
    from: usize,
    i: i32,
    j: i32,
    /// First state of the source block, `(j·N_w + i)·N_d`.
    base: usize,
    slots: &'a [OffsetSlot],
    offsets: &'a [Offset],
}

impl VoxelSampler<'_> {
    /// One draw from `T(from, ·)` restricted to the grid: an offset from the source's class
    /// table, redrawn while it leaves the grid.
    #[inline]
    pub(crate) fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> usize {
        for _ in 0..MAX_OFFSET_REDRAWS {
            if let Some(to) = self.try_offset(rng.next_u64()) {
                return to;
            }
        }
        self.sample_exactly(rng)
    }

    /// Fills `out` with independent draws of [`Self::sample`]. Branch-free rejection: every
    /// candidate is written and the cursor advances only when it is inside the grid. A
    /// rejection sampler's accepted value does not depend on how many attempts it took, so
    /// the budget of `MAX_OFFSET_REDRAWS` attempts per draw, after which the remaining
    /// draws are exact ones, leaves the draws independent and exact.
    #[inline]
    pub(crate) fn fill<R: Rng + ?Sized>(&self, rng: &mut R, out: &mut [u32]) {
        let need = out.len();
        let mut n = 0;
        let mut budget = need.saturating_mul(MAX_OFFSET_REDRAWS);
        while n < need && budget > 0 {
            budget -= 1;
            let (inside, to) = self.candidate(rng.next_u64());
            out[n] = to as u32;
            n += inside as usize;
        }
        for o in &mut out[n..] {
            *o = self.sample_exactly(rng) as u32;
        }
    }

    /// One rejection-sampling attempt with the 64 random bits `r`: the target if the offset
    /// they draw stays in the grid. Repeating until `Some` is one draw of [`Self::sample`].
    ///
    /// Bits 63..32 pick the slot (multiply-shift), bits 31..0 are the alias coin.
    #[inline]
    pub(crate) fn try_offset(&self, r: u64) -> Option<usize> {
        let (inside, to) = self.candidate(r);
        inside.then_some(to)
    }

    /// [`Self::try_offset`] without the branch: whether the drawn target is in the grid, and
    /// the target (meaningless when it is not).
    #[inline]
    pub(crate) fn candidate(&self, r: u64) -> (bool, usize) {
        let m = self.model;
        let slot = (((r >> 32) * self.slots.len() as u64) >> 32) as usize;
        let s = self.slots[slot];
        // Keep-or-alias without a branch (the coin is unpredictable): all ones takes the alias.
        let take_alias = (((r as u32) >= s.keep) as usize).wrapping_neg();
        let pick = slot ^ ((slot ^ s.alias as usize) & take_alias);
        let o = self.offsets[pick];
        let it = self.i + o.di as i32;
        let jt = self.j + o.dj as i32;
        // Negative coordinates wrap to huge unsigned values and fail the same test.
        let inside = ((it as u32 as usize) < m.n_w) & ((jt as u32 as usize) < m.n_h);
        (inside, self.base.wrapping_add(o.delta as isize as usize))
    }

    /// The exact O(S) draw, the fallback after [`MAX_OFFSET_REDRAWS`] failed attempts.
    pub(crate) fn sample_exactly<R: Rng + ?Sized>(&self, rng: &mut R) -> usize {
        self.model.sample_in_grid_exactly(self.from, rng)
    }
}

/// The precomputed transition model of one grid.
///
/// `hn(x; σ) = exp(-x²/2σ²)`, `L1` is the Manhattan distance in voxels and `z(s')` the
/// depth of the target voxel's centre. The free state sits on the grid's left, right,
/// top, bottom and far faces (`L1(v, s_free)` = the face distance of `v`); its depth in the
/// bias factor is [`FreeStateDepth`]: 0 (factor 1, as the authors' code stores `s_free` at
/// the point (0, 0, 0)) or the horizon `d_max` (factor `e^{-d_max²/2σ_z²}`).
///
/// Memory is O(S·N_d), never O(S²): the in-grid kernel depends only on the offset and
/// the target depth, so alias tables over offsets serve every source voxel of a class.
/// Source columns are cut into at most `MAX_CLASSES` (4) runs, rows likewise, and each
/// (source depth bin, column class, row class) has one table over the signed offsets
/// `(di, dj, k')` that keep *some* member of the class inside the grid (O(S) entries each,
/// at most `MAX_CLASSES²·N_d` tables). A draw from voxel `v` first picks "free or grid"
/// with `v`'s own probability of going free, then an offset from its class table,
/// redrawing offsets that leave the grid — which is exactly the conditional over `v`'s
/// in-grid targets. A member rejects only the offsets outside its own range that other
/// members keep, so most draws succeed at the first attempt, corners included.
/// The free state's row is one alias table over all states.
#[derive(Debug, Clone)]
pub struct TransitionModel {
    n_w: usize,
    n_h: usize,
    n_d: usize,
    /// `hn(L; σ_s)` for every Manhattan distance `L` that occurs.
    kernel: Vec<f64>,
    /// `hn(z(k); σ_z)` relative to the nearest bin, per target bin.
    depth_weight: Vec<f64>,
    /// Per voxel: probability of moving to `s_free`.
    p_free: Vec<f64>,
    /// The same as a 32-bit fixed-point threshold.
    free_threshold: Vec<u32>,
    /// Per voxel: `1 / Σ_all targets` (the row normaliser).
    inv_row_sum: Vec<f64>,
    /// Column and row classes of source voxels.
    column_classes: Classes,
    row_classes: Classes,
    /// Per class pair `(row class·C_w + column class)`: the signed offsets that some member
    /// keeps in the grid (`di`, `dj` over the members' union, every `k'`), and where they start.
    offsets: Vec<Offset>,
    offset_ranges: Vec<(usize, usize)>,
    /// Per `(source bin·C_h + row class)·C_w + column class`: alias slots over that class
    /// pair's offsets (O(S) each, O(S·N_d) in all), and where they start.
    slots: Vec<OffsetSlot>,
    slot_ranges: Vec<(usize, usize)>,
    /// `T(s_free -> ·)`, dense over all states.
    free_row: Vec<f64>,
    free_table: AliasTable,
    /// `kernel_rows[(k·(L_max+1) + m)·N_d + k']` = `hn(m + |k - k'|; σ_s)`, for the exact prediction.
    kernel_rows: Vec<f64>,
    max_plane_l1: usize,
}

fn half_normal(x: f64, sigma: f64) -> f64 {
    (-x * x / (2.0 * sigma * sigma)).exp()
}

impl TransitionModel {
    /// Precomputes the model for `grid`.
    pub fn new(grid: &DepthVoxelGrid, config: &TransitionConfig) -> Result<Self> {
        let (n_w, n_h, n_d) = grid.shape();
        let sigma_s = config.sigma_s_voxels;
        let sigma_z = config.sigma_z_m;
        let max_plane_l1 = (n_w - 1) + (n_h - 1);
        let max_l1 = max_plane_l1 + (n_d - 1);
        let kernel: Vec<f64> = (0..=max_l1).map(|l| half_normal(l as f64, sigma_s)).collect();
        // Depth weights relative to the nearest bin: rows are normalised, so a common factor
        // cancels, and this keeps them from underflowing for a small σ_z.
        let z0 = grid.bin_centre_m(0);
        let relative = |z: f64| (-(z * z - z0 * z0) / (2.0 * sigma_z * sigma_z)).exp();
        let depth_weight: Vec<f64> = (0..n_d as u32).map(|k| relative(grid.bin_centre_m(k))).collect();
        let free_depth_weight = match config.free_state_depth {
            FreeStateDepth::Zero => relative(0.0),
            FreeStateDepth::Horizon => relative(grid.config().depth_max_m),
        };

        // H[(j·N_w + i)·N_d + e] = Σ_{in-grid i', j'} hn(|i-i'| + |j-j'| + e): the in-plane sum
        // of the kernel for a source block at a depth offset e.
        let plane_counts = |n: usize, i: usize| -> Vec<usize> {
            // How many in-grid i' lie at each distance a = |i - i'|.
            (0..n).map(|a| if a == 0 { 1 } else { (i >= a) as usize + (i + a < n) as usize }).collect()
        };
        let mut in_plane = vec![0.0; n_w * n_h * n_d];
        for j in 0..n_h {
            let cj = plane_counts(n_h, j);
            for i in 0..n_w {
                let ci = plane_counts(n_w, i);
                // Number of in-grid targets at each in-plane Manhattan distance m.
                let mut at_distance = vec![0usize; max_plane_l1 + 1];
                for (a, &na) in ci.iter().enumerate() {
                    for (b, &nb) in cj.iter().enumerate() {
                        at_distance[a + b] += na * nb;
                    }
                }
                for e in 0..n_d {
                    in_plane[(j * n_w + i) * n_d + e] =
                        at_distance.iter().enumerate().map(|(m, &c)| c as f64 * kernel[m + e]).sum();
                }
            }
        }

        let voxels = grid.voxel_count();
        let mut p_free = Vec::with_capacity(voxels);
        let mut inv_row_sum = Vec::with_capacity(voxels);
        let mut free_row = Vec::with_capacity(voxels + 1);
        for s in 0..voxels {
            let v = grid.voxel_of(StateId(s as u32)).unwrap_or(VoxelIndex { i: 0, j: 0, k: 0 });
            let block = v.j as usize * n_w + v.i as usize;
            let k = v.k as usize;
            let in_grid: f64 = (0..n_d).map(|kt| depth_weight[kt] * in_plane[block * n_d + k.abs_diff(kt)]).sum();
            let face = kernel[grid.face_distance(v) as usize];
            let to_free = face * free_depth_weight;
            let total = in_grid + to_free;
            if !(total.is_finite() && total > 0.0) {
                return Err(Error::config(
                    "transition",
                    format!("every transition weight of voxel {v:?} underflows (σ_s = {sigma_s}, σ_z = {sigma_z})"),
                    total,
                ));
            }
            p_free.push(to_free / total);
            inv_row_sum.push(1.0 / total);
            free_row.push(face * depth_weight[k]);
        }
        free_row.push(kernel[0] * free_depth_weight);
        let free_total: f64 = free_row.iter().sum();
        free_row.iter_mut().for_each(|w| *w /= free_total);
        let free_table = AliasTable::new(&free_row)
            .ok_or_else(|| Error::config("transition", "the free state's row has no mass", free_total))?;
        let free_threshold = p_free.iter().map(|&p| (p * 4_294_967_296.0).min(u32::MAX as f64) as u32).collect();

        if n_w > i16::MAX as usize || n_h > i16::MAX as usize || 4 * voxels > i32::MAX as usize {
            return Err(Error::config("grid", "has more than 32767 blocks across or down, or too many voxels", n_w.max(n_h)));
        }
        // Sources are grouped into column and row classes; each (bin, column class, row
        // class) gets one alias table over the signed offsets that keep *some* member in the
        // grid, weighted by the kernel. A member rejects only the offsets outside its own
        // range, so the draw is the exact conditional over its in-grid targets, and the
        // acceptance rate stays high even at the grid's corners.
        let column_classes = Classes::new(n_w);
        let row_classes = Classes::new(n_h);
        let (c_w, c_h) = (column_classes.bounds.len(), row_classes.bounds.len());
        let box_len = |classes: &Classes, n: usize| -> usize { (0..classes.bounds.len()).map(|m| classes.offsets(m, n).count()).sum() };
        let mut offsets = Vec::with_capacity(box_len(&column_classes, n_w) * box_len(&row_classes, n_h) * n_d);
        let mut offset_ranges = Vec::with_capacity(c_w * c_h);
        for ch in 0..c_h {
            for cw in 0..c_w {
                let start = offsets.len();
                for dj in row_classes.offsets(ch, n_h) {
                    for di in column_classes.offsets(cw, n_w) {
                        for kt in 0..n_d {
                            let delta = (dj * n_w as i64 + di) * n_d as i64 + kt as i64;
                            offsets.push(Offset { delta: delta as i32, di: di as i16, dj: dj as i16 });
                        }
                    }
                }
                offset_ranges.push((start, offsets.len()));
            }
        }
        let mut slots = Vec::with_capacity(offsets.len() * n_d);
        let mut slot_ranges = Vec::with_capacity(n_d * c_w * c_h);
        let mut weights = Vec::new();
        for k in 0..n_d {
            for ch in 0..c_h {
                for cw in 0..c_w {
                    let (start, end) = offset_ranges[ch * c_w + cw];
                    weights.clear();
                    for (n, o) in offsets[start..end].iter().enumerate() {
                        let kt = n % n_d;
                        let l1 = o.di.unsigned_abs() as usize + o.dj.unsigned_abs() as usize + k.abs_diff(kt);
                        weights.push(kernel[l1] * depth_weight[kt]);
                    }
                    let table = AliasTable::new(&weights).ok_or_else(|| {
                        Error::config("transition", format!("depth bin {k} has no in-grid transition mass"), 0)
                    })?;
                    let first = slots.len();
                    slots.extend(table.slots().map(|(keep, alias)| OffsetSlot { keep, alias }));
                    slot_ranges.push((first, slots.len()));
                }
            }
        }

        let mut kernel_rows = vec![0.0; n_d * (max_plane_l1 + 1) * n_d];
        for k in 0..n_d {
            for m in 0..=max_plane_l1 {
                for kt in 0..n_d {
                    kernel_rows[(k * (max_plane_l1 + 1) + m) * n_d + kt] = kernel[m + k.abs_diff(kt)];
                }
            }
        }

        Ok(Self {
            n_w,
            n_h,
            n_d,
            kernel,
            depth_weight,
            p_free,
            free_threshold,
            inv_row_sum,
            column_classes,
            row_classes,
            offsets,
            offset_ranges,
            slots,
            slot_ranges,
            free_row,
            free_table,
            kernel_rows,
            max_plane_l1,
        })
    }

    /// Number of states.
    pub fn state_count(&self) -> usize {
        self.p_free.len() + 1
    }

    fn free_state(&self) -> usize {
        self.p_free.len()
    }

    fn voxel(&self, s: usize) -> (usize, usize, usize) {
        let block = s / self.n_d;
        (block % self.n_w, block / self.n_w, s % self.n_d)
    }

    /// Bytes held by the model (all O(S·N_d)).
    pub fn memory_bytes(&self) -> usize {
        let f = std::mem::size_of::<f64>();
        let tables = self.slots.capacity() * std::mem::size_of::<OffsetSlot>()
            + self.offsets.capacity() * std::mem::size_of::<Offset>()
            + (self.slot_ranges.capacity() + self.offset_ranges.capacity()) * std::mem::size_of::<(usize, usize)>()
            + (self.column_classes.of.capacity() + self.row_classes.of.capacity()) * 2;
        (self.kernel.capacity() + self.depth_weight.capacity() + self.p_free.capacity() + self.inv_row_sum.capacity()
            + self.free_row.capacity() + self.kernel_rows.capacity())
            * f
            + self.free_threshold.capacity() * 4
            + self.free_table.memory_bytes()
            + tables
    }

    /// The probability `T(from -> to)`, computed from the model's parts (for tests and tools).
    pub fn probability(&self, from: StateId, to: StateId) -> f64 {
        let (from, to) = (from.0 as usize, to.0 as usize);
        let free = self.free_state();
        if from == free {
            return self.free_row[to];
        }
        if to == free {
            return self.p_free[from];
        }
        let (i, j, k) = self.voxel(from);
        let (it, jt, kt) = self.voxel(to);
        let l1 = i.abs_diff(it) + j.abs_diff(jt) + k.abs_diff(kt);
        self.kernel[l1] * self.depth_weight[kt] * self.inv_row_sum[from]
    }

    /// The whole row `T(from -> ·)`.
    pub fn row(&self, from: StateId) -> Vec<f64> {
        (0..self.state_count()).map(|to| self.probability(from, StateId(to as u32))).collect()
    }

    /// `T(from -> s_free)`.
    pub fn p_free(&self, from: usize) -> f64 {
        if from == self.free_state() {
            self.free_row[from]
        } else {
            self.p_free[from]
        }
    }

    /// Draws a successor of state `from`.
    #[inline]
    pub fn sample<R: Rng + ?Sized>(&self, from: usize, rng: &mut R) -> usize {
        let free = self.free_state();
        if from == free {
            return self.free_table.sample(rng);
        }
        if ((rng.next_u64() >> 32) as u32) < self.free_threshold[from] {
            return free;
        }
        self.sample_voxel(from, rng)
    }

    /// Draws a successor of `from` conditioned on it being a voxel (not `s_free`).
    #[inline]
    pub fn sample_voxel<R: Rng + ?Sized>(&self, from: usize, rng: &mut R) -> usize {
        let free = self.free_state();
        if from == free {
            // T(free -> free) is tiny for any sensible grid: rejection costs almost nothing.
            for _ in 0..MAX_OFFSET_REDRAWS {
                let to = self.free_table.sample(rng);
                if to != free {
                    return to;
                }
            }
            return self.free_row[..free].iter().enumerate().fold((0, 0.0), |best, (s, &p)| if p > best.1 { (s, p) } else { best }).0;
        }
        self.voxel_sampler(from).sample(rng)
    }

    /// A sampler of the voxel successors of voxel `from`, for drawing many particles of
    /// one state without decoding the state each time. `from` must be a voxel.
    pub(crate) fn voxel_sampler(&self, from: usize) -> VoxelSampler<'_> {
        let (i, j, k) = self.voxel(from);
        let (cw, ch) = (self.column_classes.of[i] as usize, self.row_classes.of[j] as usize);
        let c_w = self.column_classes.bounds.len();
        let class = ch * c_w + cw;
        let (start, end) = self.offset_ranges[class];
        let (first, last) = self.slot_ranges[(k * self.row_classes.bounds.len() + ch) * c_w + cw];
        VoxelSampler {
            model: self,
            from,
            i: i as i32,
            j: j as i32,
            base: from - k,
            slots: &self.slots[first..last],
            offsets: &self.offsets[start..end],
        }
    }

    /// Inverse-CDF draw over the in-grid targets of `from`: O(S), for degenerate cases only.
    fn sample_in_grid_exactly<R: Rng + ?Sized>(&self, from: usize, rng: &mut R) -> usize {
        let u = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64) * (1.0 - self.p_free[from]);
        let mut acc = 0.0;
        let last = self.free_state() - 1;
        for to in 0..=last {
            acc += self.probability(StateId(from as u32), StateId(to as u32));
            if u < acc {
                return to;
            }
        }
        last
    }

    /// Exact prediction `out(s') = Σ_s belief(s)·T(s -> s')`. O(S²) time, O(S) memory.
    ///
    /// The in-grid kernel between two blocks depends only on their in-plane distance `m`, so
    /// per source block the contribution to a target block at distance `m` is one vector
    /// over target bins, `Σ_k c(k)·hn(m + |k - k'|)`: computed once per distinct `m` (an
    /// `N_d x N_d` product) and added to every target block at that distance.
    pub fn predict(&self, belief: &[f64], out: &mut [f64]) {
        let free = self.free_state();
        let n_d = self.n_d;
        let stride = self.max_plane_l1 + 1;
        out.fill(0.0);
        let mut to_free = belief[free] * self.free_row[free];
        let mut scaled = vec![0.0; n_d];
        let mut at_distance = vec![0.0; stride * n_d];
        for block in 0..self.n_w * self.n_h {
            let (i, j) = (block % self.n_w, block / self.n_w);
            let mut any = false;
            for (k, c) in scaled.iter_mut().enumerate() {
                let s = block * n_d + k;
                let b = belief[s];
                to_free += b * self.p_free[s];
                *c = b * self.inv_row_sum[s];
                any |= b != 0.0;
            }
            if !any {
                continue;
            }
            let m_max = i.max(self.n_w - 1 - i) + j.max(self.n_h - 1 - j);
            let vectors = &mut at_distance[..(m_max + 1) * n_d];
            vectors.fill(0.0);
            for (k, &c) in scaled.iter().enumerate() {
                if c == 0.0 {
                    continue;
                }
                let rows = &self.kernel_rows[k * stride * n_d..][..(m_max + 1) * n_d];
                for (v, w) in vectors.iter_mut().zip(rows) {
                    *v += c * w;
                }
            }
            for jt in 0..self.n_h {
                let dj = j.abs_diff(jt);
                for it in 0..self.n_w {
                    let m = i.abs_diff(it) + dj;
                    let target = &mut out[(jt * self.n_w + it) * n_d..][..n_d];
                    for (o, v) in target.iter_mut().zip(&vectors[m * n_d..(m + 1) * n_d]) {
                        *o += v;
                    }
                }
            }
        }
        // Apply the target-depth factor once per target, and add the free state's row.
        for (s, o) in out[..free].iter_mut().enumerate() {
            *o = *o * self.depth_weight[s % n_d] + belief[free] * self.free_row[s];
        }
        out[free] = to_free;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PinholeCamera;
    use crate::config::{GridConfig, PerceptionConfig};
    use rand::SeedableRng;
    use rand_pcg::Pcg64Mcg;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A 2x2x2 grid: 2x2 pixel image, 1x1 px blocks, two 0.5 m bins over [0.5, 1.5).
    fn tiny() -> (DepthVoxelGrid, TransitionModel) {
        tiny_with(FreeStateDepth::Horizon)
    }

    fn tiny_with(free_state_depth: FreeStateDepth) -> (DepthVoxelGrid, TransitionModel) {
        let camera = PinholeCamera::new(1.0, 1.0, 0.5, 0.5, 2, 2).unwrap();
        let grid = DepthVoxelGrid::new(
            camera,
            GridConfig { block_width_px: 1, block_height_px: 1, depth_bin_m: 0.5, depth_min_m: 0.5, depth_max_m: 1.5 },
        )
        .unwrap();
        let model = TransitionModel::new(&grid, &TransitionConfig { sigma_s_voxels: 1.0, sigma_z_m: 1.0, free_state_depth }).unwrap();
        (grid, model)
    }

    #[test]
    fn tiny_row_by_hand() {
        // The free state's depth factor: hn(d_max) = hn(1.5) at the horizon, hn(0) = 1 at depth 0.
        let hn = |x: f64| (-x * x / 2.0).exp();
        for (free_state_depth, z_free) in [(FreeStateDepth::Horizon, hn(1.5)), (FreeStateDepth::Zero, 1.0)] {
            tiny_rows_by_hand(free_state_depth, z_free);
        }
    }

    fn tiny_rows_by_hand(free_state_depth: FreeStateDepth, z_free: f64) {
        let (grid, model) = tiny_with(free_state_depth);
        // Source voxel (0,0,0): bin centre depths 0.75 m and 1.25 m, d_max 1.5 m.
        let hn = |x: f64| (-x * x / 2.0).exp();
        let zw = |k: u32| hn(grid.bin_centre_m(k));
        let from = VoxelIndex { i: 0, j: 0, k: 0 };
        let mut weights = vec![0.0; 9];
        for to in 0..8u32 {
            let v = grid.voxel_of(StateId(to)).unwrap();
            let l1 = v.i + v.j + v.k;
            weights[to as usize] = hn(l1 as f64) * zw(v.k);
        }
        // Face distance of (0,0,0): on the left and top faces -> 1.
        weights[8] = hn(1.0) * z_free;
        let total: f64 = weights.iter().sum();
        let row = model.row(grid.state_of(from));
        for (p, w) in row.iter().zip(&weights) {
            assert!((p - w / total).abs() < 1e-14, "{row:?}");
        }
        // The free state's row: hn(face(v'))·hn(z(v')), and hn(0)·hn(z_free) to itself.
        let mut free = vec![0.0; 9];
        for to in 0..8u32 {
            let v = grid.voxel_of(StateId(to)).unwrap();
            free[to as usize] = hn(grid.face_distance(v) as f64) * zw(v.k);
        }
        free[8] = z_free;
        let total: f64 = free.iter().sum();
        for (p, w) in model.row(grid.free_state()).iter().zip(&free) {
            assert!((p - w / total).abs() < 1e-14);
        }
    }

    #[test]
    fn flight_rows_sum_to_one() {
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), PerceptionConfig::flight().grid).unwrap();
        let model = TransitionModel::new(&grid, &PerceptionConfig::flight().transition).unwrap();
        for s in [0u32, 17, 700, 1429, 1430] {
            let sum: f64 = model.row(StateId(s)).iter().sum();
            assert!((sum - 1.0).abs() < 1e-12, "row {s} sums to {sum}");
        }
        // O(S·N_d), not O(S²): far below a dense f64 table.
        assert!(model.memory_bytes() < 1431 * 1431 * 8 / 4, "{}", model.memory_bytes());
    }

    #[test]
    fn sampling_matches_the_rows() {
        let (grid, model) = tiny();
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        for from in [0usize, 5, 8] {
            let row = model.row(StateId(from as u32));
            let n = 200_000;
            let mut hist = vec![0u32; grid.state_count()];
            for _ in 0..n {
                hist[model.sample(from, &mut rng)] += 1;
            }
            for (h, p) in hist.iter().zip(&row) {
                let sd = (p * (1.0 - p) / n as f64).sqrt();
                assert!((*h as f64 / n as f64 - p).abs() < 5.0 * sd + 1e-9, "from {from}: {hist:?} vs {row:?}");
            }
        }
    }

    /// Checks a histogram of `n` in-grid draws from `from` against `T(from, ·)` restricted to the grid.
    fn assert_matches_row(grid: &DepthVoxelGrid, model: &TransitionModel, from: usize, hist: &[u32], n: usize) {
        let row = model.row(StateId(from as u32));
        let in_grid = 1.0 - row[grid.free_state().0 as usize];
        assert_eq!(hist.iter().map(|&h| h as usize).sum::<usize>(), n);
        assert_eq!(hist[grid.free_state().0 as usize], 0, "from {from}: an in-grid draw gave s_free");
        for (to, (h, p)) in hist.iter().zip(&row).enumerate().take(grid.voxel_count()) {
            let p = p / in_grid;
            let sd = (p * (1.0 - p) / n as f64).sqrt();
            // Rare targets: allow a few stray counts (Poisson tail) on top of five sd.
            assert!((*h as f64 / n as f64 - p).abs() < 5.0 * sd + 4.0 / n as f64, "from {from} to {to}: {h} vs {p}");
        }
    }

    /// Flight voxels where offsets leave the grid often or the class tables differ: the four
    /// corners, the middle of each edge, members on both sides of a class boundary, the
    /// centre; near, middle and far bins.
    fn flight_test_voxels(grid: &DepthVoxelGrid) -> Vec<usize> {
        let (n_w, n_h, n_d) = grid.shape();
        let (w, h, d) = (n_w as u32 - 1, n_h as u32 - 1, n_d as u32 - 1);
        [(0, 0, 0), (w, 0, d), (0, h, 7), (w, h, 0), (6, 0, 3), (0, 5, d), (w, 4, 5), (5, h, 1), (2, 1, 7), (3, 2, 7), (6, 4, 7), (6, 5, 0)]
            .into_iter()
            .map(|(i, j, k)| grid.state_of(VoxelIndex { i, j, k }).0 as usize)
            .collect()
    }

    #[test]
    fn flight_sampling_matches_the_rows() {
        // The class offset tables, one draw at a time, on a grid where offsets leave it often.
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), PerceptionConfig::flight().grid).unwrap();
        let model = TransitionModel::new(&grid, &PerceptionConfig::flight().transition).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(11);
        for from in flight_test_voxels(&grid) {
            let n = 300_000;
            let mut hist = vec![0u32; grid.state_count()];
            let sampler = model.voxel_sampler(from);
            for _ in 0..n {
                hist[sampler.sample(&mut rng)] += 1;
            }
            assert_matches_row(&grid, &model, from, &hist, n);
        }
    }

    #[test]
    fn flight_batch_sampling_matches_the_rows() {
        // The branch-free batch draw the particle filter uses, in batches of uneven sizes.
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), PerceptionConfig::flight().grid).unwrap();
        let model = TransitionModel::new(&grid, &PerceptionConfig::flight().transition).unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
        let mut batch = vec![0u32; 4099];
        for from in flight_test_voxels(&grid) {
            let mut hist = vec![0u32; grid.state_count()];
            let sampler = model.voxel_sampler(from);
            let mut n = 0;
            for size in [1usize, 2, 3, 4099].into_iter().cycle().take(292) {
                sampler.fill(&mut rng, &mut batch[..size]);
                for &to in &batch[..size] {
                    hist[to as usize] += 1;
                }
                n += size;
            }
            assert_matches_row(&grid, &model, from, &hist, n);
        }
    }

    #[test]
    fn class_tables_keep_most_draws_and_memory_linear() {
        // Acceptance of the first attempt, from the tables themselves: at least 0.5 for every
        // flight voxel (the folded tables gave ~0.3 at corners).
        let grid = DepthVoxelGrid::new(PinholeCamera::d435(), PerceptionConfig::flight().grid).unwrap();
        let model = TransitionModel::new(&grid, &PerceptionConfig::flight().transition).unwrap();
        for from in 0..grid.voxel_count() {
            let sampler = model.voxel_sampler(from);
            let len = sampler.slots.len() as f64;
            let inside = |o: Offset| {
                let (it, jt) = (sampler.i + o.di as i32, sampler.j + o.dj as i32);
                ((0..grid.shape().0 as i32).contains(&it) && (0..grid.shape().1 as i32).contains(&jt)) as u8 as f64
            };
            let mut kept = 0.0;
            for (slot, s) in sampler.slots.iter().enumerate() {
                let p_own = s.keep as f64 / 4_294_967_296.0;
                kept += (p_own * inside(sampler.offsets[slot]) + (1.0 - p_own) * inside(sampler.offsets[s.alias as usize])) / len;
            }
            assert!(kept > 0.5, "voxel {from}: acceptance {kept}");
        }
        // A 20k-state grid: tables grow with S·N_d (about 25·S·N_d slots), nowhere near S².
        let camera = PinholeCamera::new(300.0, 300.0, 320.0, 240.0, 640, 480).unwrap();
        let big = DepthVoxelGrid::new(
            camera,
            GridConfig { block_width_px: 16, block_height_px: 16, depth_bin_m: 0.1, depth_min_m: 0.1, depth_max_m: 1.8 },
        )
        .unwrap();
        let s = big.state_count();
        assert!(s > 20_000, "{s}");
        let model = TransitionModel::new(&big, &PerceptionConfig::flight().transition).unwrap();
        assert!(model.memory_bytes() < s * 17 * 30 * 8 + (1 << 20), "{}", model.memory_bytes());
        assert!(model.memory_bytes() < s * s, "{}", model.memory_bytes());
    }

    #[test]
    fn predict_equals_the_dense_product() {
        let grid = DepthVoxelGrid::new(
            PinholeCamera::new(100.0, 100.0, 30.0, 20.0, 61, 41).unwrap(),
            GridConfig { block_width_px: 10, block_height_px: 10, depth_bin_m: 0.2, depth_min_m: 0.2, depth_max_m: 1.0 },
        )
        .unwrap();
        let model = TransitionModel::new(&grid, &TransitionConfig { sigma_s_voxels: 2.0, sigma_z_m: 0.4, free_state_depth: FreeStateDepth::Horizon }).unwrap();
        let s = grid.state_count();
        let belief: Vec<f64> = (0..s).map(|i| ((i * 37) % 11) as f64).collect();
        let total: f64 = belief.iter().sum();
        let belief: Vec<f64> = belief.iter().map(|b| b / total).collect();
        let mut fast = vec![0.0; s];
        model.predict(&belief, &mut fast);
        for (to, &got) in fast.iter().enumerate() {
            let dense: f64 = (0..s).map(|from| belief[from] * model.probability(StateId(from as u32), StateId(to as u32))).sum();
            assert!((got - dense).abs() < 1e-14, "state {to}: {got} vs {dense}");
        }
        assert!((fast.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}
