//! The guard's cell lists, kept in blocks of one pool rather than in two `Vec`s per cell.
//!
//! Why: a cell's list grows and shrinks with every record filed or unfiled there (on bonsai
//! upsampled to 511^3, about 270 k `Vec` growths and 95 k shrinks by heaptrack), and each change
//! of capacity was a `realloc` among the simplifier's long-lived small blocks. Its thread's
//! malloc arena fragmented: by glibc's `malloc_stats`, 7.8 MB mapped for 3.4 MB in use at the
//! end of that run's first stage, 11.3 for 5.6 in a one-stage run. Blocks of [`BLOCK`] entries
//! from one `Vec` with a free list reuse their room exactly: the pool is one large allocation,
//! its touched pages bounded by the peak number of blocks in use (peak RSS 1-2 MiB lower at
//! 256^3 and 511^3, docs/scale.md). A general-purpose pool or arena crate was passed over: what
//! is needed is a free list of one fixed-size block type with two links, a few lines here.
//!
//! A list is its blocks linked both ways, every block full but the last: appending fills the
//! last, removing moves the list's last entry into the hole (the order of a list is not
//! meaningful), and a search runs from the last block back (records filed last are the likeliest
//! to change again).

use serde::{Deserialize, Serialize};

/// Entries a block holds: a list's last block is half empty on average (192 bytes a cell,
/// about 1,000 cells on bonsai upsampled to 511^3), and a query hops from block to block. With
/// 16 the guard cost 0.4 % and 1.4 % more instructions than with a `Vec` per cell in bonsai's
/// two stages at R = 0.2, with 32 0.3 % and 0.8 % (`tools/instructions.py`, the same output).
const BLOCK: usize = 32;
const NONE: u32 = u32::MAX;

/// Entries of one list: each record's box clipped to the cell and quantized inline (its key,
/// `super::meets`), so a query scans keys contiguously and fetches the box and corners only of
/// the records whose key meets the fan's. 12 bytes an entry: with the box and its low cell in
/// `f32` and `i32` (40 bytes) the cells were the largest part of the index (12 MiB of a 47 MiB
/// heap on engine at R = 0.2, heaptrack). Keys and record numbers in two arrays rather than one
/// of entries: a query reads the keys and only the matches' numbers, and unfiling a record scans
/// the numbers alone (cells hold about 350 records on bonsai, and that scan was 12 % of a run
/// that made no contraction).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Block {
    keys: [u64; BLOCK],
    recs: [u32; BLOCK],
    prev: u32,
    next: u32,
}

/// One cell's list: a handle into [`Pool`] (12 bytes in the level's map).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub(super) struct CellList {
    head: u32,
    tail: u32,
    len: u32,
}

impl Default for CellList {
    fn default() -> Self {
        Self {
            head: NONE,
            tail: NONE,
            len: 0,
        }
    }
}

impl CellList {
    pub(super) fn len(&self) -> usize {
        self.len as usize
    }

    /// Entries in the last block (`BLOCK` when it is full; 0 for an empty list).
    fn in_tail(&self) -> usize {
        if self.len == 0 {
            0
        } else {
            (self.len as usize - 1) % BLOCK + 1
        }
    }
}

/// Where an entry is: its block and its place there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Place {
    block: u32,
    slot: usize,
}

/// The blocks of every list of an index.
#[derive(Debug, Default, Serialize, Deserialize)]
pub(super) struct Pool {
    blocks: Vec<Block>,
    free: Vec<u32>,
}

impl Pool {
    /// Appends record `r` with its key to `list`.
    pub(super) fn push(&mut self, list: &mut CellList, key: u64, r: u32) {
        let at = list.in_tail();
        if at == BLOCK || list.len == 0 {
            let b = self.take_block(list.tail);
            if list.len == 0 {
                list.head = b;
            } else {
                self.blocks[list.tail as usize].next = b;
            }
            list.tail = b;
        }
        let slot = list.len as usize % BLOCK;
        let block = &mut self.blocks[list.tail as usize];
        block.keys[slot] = key;
        block.recs[slot] = r;
        list.len += 1;
    }

    /// Where record `r` is last in `list`, searched from the end a block at a time: a compare
    /// over a block without an early exit compiles to vector instructions.
    pub(super) fn find(&self, list: &CellList, r: u32) -> Option<Place> {
        let (mut b, mut n) = (list.tail, list.in_tail());
        while b != NONE {
            let block = &self.blocks[b as usize];
            let recs = &block.recs[..n];
            if recs.iter().fold(false, |m, &x| m | (x == r))
                && let Some(slot) = recs.iter().rposition(|&x| x == r)
            {
                return Some(Place { block: b, slot });
            }
            (b, n) = (block.prev, BLOCK);
        }
        None
    }

    /// Rewrites the key of the entry at `p`.
    pub(super) fn set_key(&mut self, p: Place, key: u64) {
        self.blocks[p.block as usize].keys[p.slot] = key;
    }

    /// Removes the entry at `p` from `list`, moving the list's last entry there.
    pub(super) fn swap_remove(&mut self, list: &mut CellList, p: Place) {
        let last = list.in_tail() - 1;
        let tail = list.tail as usize;
        let (key, r) = (self.blocks[tail].keys[last], self.blocks[tail].recs[last]);
        let hole = &mut self.blocks[p.block as usize];
        hole.keys[p.slot] = key;
        hole.recs[p.slot] = r;
        list.len -= 1;
        if last == 0 {
            let prev = self.blocks[tail].prev;
            self.free.push(list.tail);
            if prev == NONE {
                *list = CellList::default();
            } else {
                self.blocks[prev as usize].next = NONE;
                list.tail = prev;
            }
        }
    }

    /// Calls `f` with the keys and record numbers of each block of `list` in turn.
    pub(super) fn scan(&self, list: &CellList, mut f: impl FnMut(&[u64], &[u32])) {
        let (mut b, mut left) = (list.head, list.len as usize);
        while left > 0 {
            let block = &self.blocks[b as usize];
            let n = left.min(BLOCK);
            f(&block.keys[..n], &block.recs[..n]);
            left -= n;
            b = block.next;
        }
    }

    /// The first key of `list` (0 when empty): read to bring its first block into the cache.
    pub(super) fn first_key(&self, list: &CellList) -> u64 {
        if list.len == 0 {
            0
        } else {
            self.blocks[list.head as usize].keys[0]
        }
    }

    /// Blocks allocated, in use or free (for tests and the summary of where memory goes).
    #[cfg(test)]
    pub(super) fn blocks(&self) -> usize {
        self.blocks.len()
    }

    /// A block for the end of a list whose last block is `prev`.
    fn take_block(&mut self, prev: u32) -> u32 {
        let block = Block {
            keys: [0; BLOCK],
            recs: [0; BLOCK],
            prev,
            next: NONE,
        };
        match self.free.pop() {
            Some(b) => {
                self.blocks[b as usize] = block;
                b
            }
            None => {
                self.blocks.push(block);
                u32::try_from(self.blocks.len() - 1).expect("fewer than 2^32 cell blocks")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn entries(pool: &Pool, list: &CellList) -> Vec<(u64, u32)> {
        let mut out = Vec::new();
        pool.scan(list, |keys, recs| {
            out.extend(keys.iter().copied().zip(recs.iter().copied()));
        });
        out
    }

    #[derive(Debug, Clone)]
    enum Op {
        Push(usize, u32),
        Remove(usize, u32),
        Rekey(usize, u32, u64),
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            3 => (0usize..3, 0u32..50).prop_map(|(l, r)| Op::Push(l, r)),
            2 => (0usize..3, 0u32..50).prop_map(|(l, r)| Op::Remove(l, r)),
            1 => (0usize..3, 0u32..50, any::<u64>()).prop_map(|(l, r, k)| Op::Rekey(l, r, k)),
        ]
    }

    proptest! {
        /// Three lists sharing a pool behave as three `Vec`s with swap-removal, their search
        /// finds the last place of a record, and freed blocks are used again.
        #[test]
        fn lists_in_a_pool_behave_as_vecs(ops in prop::collection::vec(op(), 0..400)) {
            let mut pool = Pool::default();
            let mut lists = [CellList::default(); 3];
            let mut model: [Vec<(u64, u32)>; 3] = Default::default();
            let mut peak = 0;
            for op in ops {
                match op {
                    Op::Push(l, r) => {
                        pool.push(&mut lists[l], u64::from(r) * 7, r);
                        model[l].push((u64::from(r) * 7, r));
                    }
                    Op::Remove(l, r) => {
                        let found = pool.find(&lists[l], r);
                        let want = model[l].iter().rposition(|&(_, x)| x == r);
                        prop_assert_eq!(found.is_some(), want.is_some());
                        if let (Some(p), Some(i)) = (found, want) {
                            pool.swap_remove(&mut lists[l], p);
                            model[l].swap_remove(i);
                        }
                    }
                    Op::Rekey(l, r, k) => {
                        if let Some(p) = pool.find(&lists[l], r) {
                            pool.set_key(p, k);
                            let i = model[l].iter().rposition(|&(_, x)| x == r).unwrap();
                            model[l][i].0 = k;
                        }
                    }
                }
                for l in 0..3 {
                    prop_assert_eq!(lists[l].len(), model[l].len());
                    prop_assert_eq!(&entries(&pool, &lists[l]), &model[l]);
                    prop_assert_eq!(pool.first_key(&lists[l]), model[l].first().map_or(0, |e| e.0));
                }
                let in_use: usize = model.iter().map(|m| m.len().div_ceil(BLOCK)).sum();
                peak = peak.max(in_use);
                prop_assert!(pool.blocks() <= peak, "freed blocks are used again");
            }
        }
    }
}
