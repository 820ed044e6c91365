//! Walker/Vose alias tables: O(1) draws from a fixed discrete distribution.

use std::cmp::Ordering;

use rand::Rng;

/// One slot of an alias table: keep the slot if the 32-bit coin is below `keep`,
/// else take `alias`. A slot that always keeps itself has `alias` equal to itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct AliasSlot {
    keep: u32,
    alias: u32,
}

/// An alias table over `0..len`.
#[derive(Debug, Clone)]
pub(crate) struct AliasTable {
    slots: Vec<AliasSlot>,
}

impl AliasTable {
    /// Builds the table for non-negative finite `weights` with a positive sum.
    /// Returns `None` when the weights cannot form a distribution.
    pub(crate) fn new(weights: &[f64]) -> Option<Self> {
        let n = weights.len();
        let total: f64 = weights.iter().sum();
        if n == 0 || n > u32::MAX as usize || !(total.is_finite() && total > 0.0) || weights.iter().any(|w| w.partial_cmp(&0.0).is_none_or(Ordering::is_lt)) {
            return None;
        }
        let mut scaled: Vec<f64> = weights.iter().map(|w| w * n as f64 / total).collect();
        let mut slots: Vec<AliasSlot> = (0..n as u32).map(|i| AliasSlot { keep: u32::MAX, alias: i }).collect();
        let (mut small, mut large): (Vec<usize>, Vec<usize>) = (0..n).partition(|&i| scaled[i] < 1.0);
        while let (Some(&s), Some(&l)) = (small.last(), large.last()) {
            small.pop();
            slots[s] = AliasSlot { keep: (scaled[s] * 4_294_967_296.0) as u32, alias: l as u32 };
            scaled[l] -= 1.0 - scaled[s];
            if scaled[l] < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        // Whatever is left holds probability 1 up to rounding: those slots keep themselves.
        Some(Self { slots })
    }

    /// The slots as `(keep, alias)`: keep slot `i` if a uniform 32-bit coin is below `keep`.
    pub(crate) fn slots(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.slots.iter().map(|s| (s.keep, s.alias))
    }

    /// Bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        self.slots.capacity() * std::mem::size_of::<AliasSlot>()
    }

    /// One draw. One 64-bit random number: the high half picks the slot (multiply-shift,
    /// bias below `len / 2³²`), the low half is the coin.
    #[inline]
    pub(crate) fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> usize {
        self.pick(rng.next_u64())
    }

    /// The draw that the 64 random bits `r` give (see [`AliasTable::sample`]). Branch-free:
    /// a slot that always keeps itself is its own alias, so the coin's rare failure on
    /// `keep = u32::MAX` (coin `u32::MAX`) still yields the slot.
    #[inline]
    pub(crate) fn pick(&self, r: u64) -> usize {
        let slot = (((r >> 32) * self.slots.len() as u64) >> 32) as usize;
        let AliasSlot { keep, alias } = self.slots[slot];
        if (r as u32) < keep {
            slot
        } else {
            alias as usize
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64Mcg;

    #[test]
    fn draws_follow_the_weights() {
        let weights = [1.0, 0.0, 3.0, 6.0];
        let table = AliasTable::new(&weights).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        let mut hist = [0u32; 4];
        let n = 400_000;
        for _ in 0..n {
            hist[table.sample(&mut rng)] += 1;
        }
        assert_eq!(hist[1], 0, "a zero weight is never drawn");
        for (h, w) in hist.iter().zip(weights) {
            let p = w / 10.0;
            let sd = (p * (1.0 - p) / n as f64).sqrt();
            assert!((*h as f64 / n as f64 - p).abs() < 5.0 * sd + 1e-12, "{hist:?}");
        }
    }

    #[test]
    fn rejects_degenerate_weights() {
        assert!(AliasTable::new(&[]).is_none());
        assert!(AliasTable::new(&[0.0, 0.0]).is_none());
        assert!(AliasTable::new(&[1.0, f64::NAN]).is_none());
        assert!(AliasTable::new(&[1.0, -1.0, 3.0]).is_none());
    }
}
