//! A fixed-size hash index beside a sorted key array: from a key to its position in the
//! array in one or a few probes, where a binary search takes about log2(len) compares.
//!
//! The object dictionary and the FHPP parameter store keep their entries sorted (for ordered
//! walks and the error codes of a miss) and look them up by key many times per simulated
//! control cycle. The index is an open-addressing table of positions: each key has a home cell
//! (a multiplicative hash), and collisions take the next cells, at most [`PROBES`] of them. A
//! key that found no free cell among those is simply not indexed: [`HashIndex::search`] then
//! answers by a binary search of the sorted array, so the index only ever speeds a lookup up
//! and never decides one.

/// Cells tried from a key's home cell.
pub const PROBES: usize = 4;

/// An empty cell.
const EMPTY: u16 = u16::MAX;

/// Positions of up to `N` keys (positions below `u16::MAX`), found by key.
#[derive(Debug, Clone)]
pub struct HashIndex<const N: usize> {
    cells: [u16; N],
}

impl<const N: usize> Default for HashIndex<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// The home cell of `k` in an index of `n` cells (a multiplicative hash mapped onto `0..n`).
fn home_cell(k: u32, n: usize) -> usize {
    ((u64::from(k.wrapping_mul(0x9E37_79B1)) * n as u64) >> 32) as usize
}

impl<const N: usize> HashIndex<N> {
    /// An index of nothing.
    pub const fn new() -> Self {
        HashIndex { cells: [EMPTY; N] }
    }

    /// Indexes `keys`, each at its position in the iteration; what an earlier call indexed is
    /// forgotten (an insert into the sorted array moves the positions after it).
    pub fn rebuild(&mut self, keys: impl Iterator<Item = u32>) {
        self.cells = [EMPTY; N];
        if N == 0 {
            return;
        }
        for (pos, k) in keys.enumerate() {
            // A position that does not fit a cell is left to the caller's search.
            let Ok(pos) = u16::try_from(pos) else { break };
            if pos == EMPTY {
                break;
            }
            let mut cell = home_cell(k, N);
            for _ in 0..PROBES {
                if self.cells[cell] == EMPTY {
                    self.cells[cell] = pos;
                    break;
                }
                cell = if cell + 1 == N { 0 } else { cell + 1 };
            }
        }
    }

    /// The position of `k` in `items`, sorted by `key`, as `binary_search_by_key` answers it
    /// (`Err`: where `k` would go): from the index when it holds `k`, else by that search.
    #[inline]
    pub fn search<T>(&self, k: u32, items: &[T], key: impl Fn(&T) -> u32) -> Result<usize, usize> {
        match self.find(k, |p| items.get(p).map(&key)) {
            Some(p) => Ok(p),
            None => items.binary_search_by_key(&k, key),
        }
    }

    /// The position of `k`, where `key_at(pos)` is the key at a position; `None` when `k` is
    /// not indexed (absent, or its cells were taken: search the array then).
    #[inline]
    pub fn find(&self, k: u32, key_at: impl Fn(usize) -> Option<u32>) -> Option<usize> {
        if N == 0 {
            return None;
        }
        let mut cell = home_cell(k, N);
        for _ in 0..PROBES {
            let pos = *self.cells.get(cell)?;
            if pos == EMPTY {
                return None;
            }
            if key_at(usize::from(pos)) == Some(k) {
                return Some(usize::from(pos));
            }
            cell = if cell + 1 == N { 0 } else { cell + 1 };
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_every_indexed_key_and_nothing_else() {
        // Keys that collide on purpose (a small table) and keys spread out.
        let keys: [u32; 12] = [
            1,
            2,
            3,
            5,
            8,
            13,
            0x0060_4100,
            0x0060_6400,
            0x001A_0001,
            7,
            9,
            11,
        ];
        let mut sorted = keys;
        sorted.sort_unstable();
        let mut idx = HashIndex::<16>::default();
        idx.rebuild(sorted.iter().copied());
        let at = |p: usize| sorted.get(p).copied();
        let mut found = 0;
        for (pos, &k) in sorted.iter().enumerate() {
            // Found at its own position, or not indexed: never at another position.
            if let Some(p) = idx.find(k, at) {
                assert_eq!(p, pos);
                found += 1;
            }
        }
        assert!(found >= 10, "most keys fit their cells: {found}");
        for absent in [0u32, 4, 6, 100, 0x0060_4000] {
            assert_eq!(idx.find(absent, at), None);
        }
        // `search` answers as the binary search does, hit or miss.
        for k in [0u32, 1, 4, 13, 0x0060_4100, 0x0070_0000] {
            assert_eq!(idx.search(k, &sorted, |&k| k), sorted.binary_search(&k));
        }
        // An empty index finds nothing.
        let empty = HashIndex::<0>::default();
        assert_eq!(empty.find(1, at), None);
    }

    #[test]
    fn a_full_table_leaves_the_rest_to_the_search() {
        let keys: Vec<u32> = (0..40).map(|k| k * 7).collect();
        let mut idx = HashIndex::<8>::default();
        idx.rebuild(keys.iter().copied());
        let at = |p: usize| keys.get(p).copied();
        let found = keys.iter().filter(|&&k| idx.find(k, at).is_some()).count();
        assert_eq!(found, 8, "one key per cell");
        for (pos, &k) in keys.iter().enumerate() {
            if let Some(p) = idx.find(k, at) {
                assert_eq!(p, pos);
            }
        }
    }
}
