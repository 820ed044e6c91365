//! The A*'s open list: an indexed binary min-heap of packed `(f, h, cell)` keys, one per
//! open cell, whose keys are lowered in place.

#[cfg(doc)]
use crate::plan::grid::MAX_GRID_CELLS;

/// The open-list key of the cell of flat index `flat`: `f.to_bits() << 64 | (h as f32).to_bits() << 32 | flat`
/// as one integer. `f, h >= 0`, so their bits order as their values: the smallest key is the
/// entry of smallest `(f, h, flat index)`. Grids have at most [`MAX_GRID_CELLS`] `<= 2^32` cells.
#[inline]
pub(super) fn open_key(f: f64, h: f64, flat: usize) -> u128 {
    let tie = (((h as f32).to_bits() as u64) << 32) | flat as u64;
    ((f.to_bits() as u128) << 64) | tie as u128
}

/// The flat index of an open-list key's cell.
#[inline]
pub(super) fn key_flat(key: u128) -> usize {
    key as u32 as usize
}

/// The open list: an indexed binary min-heap of [`open_key`]s, one per open cell (the children
/// of slot `i` are the slots `2i + 1` and `2i + 2`). Each open cell's slot is recorded, so an
/// improved cell's key is lowered in place: no stale entries.
#[derive(Debug, Clone, Default)]
pub(super) struct OpenList {
    keys: Vec<u128>,
    /// The slot of each open cell's key, by flat index (meaningless for other cells).
    slots: Vec<u32>,
}

impl OpenList {
    /// Empties the list for a search over `cells` cells.
    pub(super) fn begin(&mut self, cells: usize) {
        self.keys.clear();
        if self.slots.len() < cells {
            self.slots.resize(cells, 0);
        }
    }

    /// Puts `key` into slot `i` and records the slot.
    #[inline(always)]
    fn place(&mut self, i: usize, key: u128) {
        self.keys[i] = key;
        self.slots[key_flat(key)] = i as u32;
    }

    /// Moves the hole at slot `hole` up while its parent's key is above `key`, then puts `key`
    /// there.
    #[inline(always)]
    fn sift_up(&mut self, mut hole: usize, key: u128) {
        while hole > 0 {
            let parent = (hole - 1) / 2;
            let above = self.keys[parent];
            if above < key {
                break;
            }
            self.place(hole, above);
            hole = parent;
        }
        self.place(hole, key);
    }

    /// Adds the key of a cell not in the list.
    #[inline]
    pub(super) fn push(&mut self, key: u128) {
        let hole = self.keys.len();
        self.keys.push(key);
        self.sift_up(hole, key);
    }

    /// Lowers the key of a cell in the list to `key` (at most its old key: same cell and `h`,
    /// `f` not larger).
    #[inline]
    pub(super) fn decrease(&mut self, key: u128) {
        let hole = self.slots[key_flat(key)] as usize;
        self.sift_up(hole, key);
    }

    /// The smallest key, removed. Floyd's deletion: the root's hole moves down along the smaller
    /// children to the bottom, then the last key sifts up from there (it usually belongs near
    /// the bottom: one comparison per level on the way down instead of two).
    #[inline]
    pub(super) fn pop(&mut self) -> Option<u128> {
        let last = self.keys.pop()?;
        let Some(&top) = self.keys.first() else {
            return Some(last);
        };
        let mut hole = 0;
        let mut child = 1;
        while let Some(pair) = self.keys.get(child..child + 2) {
            let smaller = child + (pair[1] < pair[0]) as usize;
            self.place(hole, self.keys[smaller]);
            hole = smaller;
            child = 2 * hole + 1;
        }
        if let Some(&key) = self.keys.get(child) {
            self.place(hole, key);
            hole = child;
        }
        self.sift_up(hole, last);
        Some(top)
    }
}
