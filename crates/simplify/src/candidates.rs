//! Edge candidates: the priority queue `Q` and the Tandem waiting queue `W`.
//!
//! Entries are invalidated lazily: each carries the stamps of its endpoints at evaluation time and
//! is dropped when popped if either endpoint changed, retired or died since. Ties are broken by
//! vertex ids so the output is a deterministic function of the input sequence.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// A queued edge. Deliberately small (32 bytes): the queue sifts it on pushes and pops and its
/// memory traffic dominates the loop, so the placement is recomputed when the edge is popped
/// instead of stored.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub(crate) struct Candidate {
    /// Priority at evaluation time (lower first).
    pub(crate) cost: f64,
    /// `a < b`.
    pub(crate) a: u64,
    pub(crate) b: u64,
    pub(crate) stamps: [u32; 2],
}

/// Ascending by `key`, then ids.
fn ascending(x: (f64, &Candidate), y: (f64, &Candidate)) -> Ordering {
    x.0.total_cmp(&y.0)
        .then(x.1.a.cmp(&y.1.a))
        .then(x.1.b.cmp(&y.1.b))
}

/// Min-heap order by reach (the std heap is a max-heap, hence the reversal).
#[derive(serde::Serialize, serde::Deserialize)]
struct ByReach(f64, Candidate);

impl Ord for ByReach {
    fn cmp(&self, other: &Self) -> Ordering {
        ascending((other.0, &other.1), (self.0, &self.1))
    }
}

macro_rules! order_from_ord {
    ($($t:ident),*) => {$(
        impl PartialOrd for $t {
            fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
                Some(self.cmp(other))
            }
        }
        impl PartialEq for $t {
            fn eq(&self, other: &Self) -> bool {
                self.cmp(other) == Ordering::Equal
            }
        }
        impl Eq for $t {}
    )*};
}
order_from_ord!(ByReach);

#[derive(Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Candidates {
    queue: CostHeap,
    waiting: BinaryHeap<ByReach>,
}

/// `cost` mapped to a `u64` with the order of `f64::total_cmp` (an involution on the bits, so the
/// cost comes back exactly).
fn cost_key(cost: f64) -> u64 {
    let bits = cost.to_bits();
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | (1 << 63)
    }
}

fn key_cost(key: u64) -> f64 {
    f64::from_bits(if key >> 63 == 1 {
        key & !(1 << 63)
    } else {
        !key
    })
}

/// A heap entry of `Q`: the candidate with its cost as an integer sort key, so that comparing
/// two entries is three integer comparisons (ascending cost, then ids).
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
struct Keyed {
    key: u64,
    a: u64,
    b: u64,
    stamps: [u32; 2],
}

impl Keyed {
    fn new(c: Candidate) -> Self {
        Self {
            key: cost_key(c.cost),
            a: c.a,
            b: c.b,
            stamps: c.stamps,
        }
    }

    fn candidate(&self) -> Candidate {
        Candidate {
            cost: key_cost(self.key),
            a: self.a,
            b: self.b,
            stamps: self.stamps,
        }
    }

    fn before(&self, other: &Self) -> bool {
        (self.key, self.a, self.b) < (other.key, other.a, other.b)
    }
}

/// `Q`: candidates in buckets of cost, each bucket an octave of the cost (the sign and exponent
/// bits of the sort key), and only the cheapest non-empty bucket kept as a 4-ary min-heap. Pops
/// come in ascending (cost, a, b), as from the single heap this replaced: the buckets' key ranges
/// are disjoint and ordered, and within the cheapest one the heap orders by the whole key.
///
/// Why: pops dominate (a popped candidate is stale about five times per contraction) and a pop
/// from one heap of every candidate (about 100 k) walked nine levels, the lower ones out of cache
/// (9 % of a one-stage run by `perf`). The cheapest bucket holds a small share of them, which
/// stays in cache; a push into a dearer bucket is an append, heaped only once that bucket becomes
/// the cheapest. (Quarter octaves were no faster within the noise and held 1 MiB more.)
#[derive(Default, serde::Serialize, serde::Deserialize)]
struct CostHeap {
    /// Entries by bucket (`key >> BUCKET_SHIFT`); allocated on the first push.
    buckets: Vec<Vec<Keyed>>,
    /// Bit `b`: bucket `b` holds entries.
    filled: Vec<u64>,
    /// Bit `b`: bucket `b` is a heap (the cheapest was, at some pop, and stays one).
    heaped: Vec<u64>,
    /// No bucket below this one holds entries.
    low: usize,
    len: usize,
}

/// Bucket of a key: its sign and exponent.
const BUCKET_SHIFT: u32 = 52;
const BUCKETS: usize = 1 << (64 - BUCKET_SHIFT);
const ARITY: usize = 4;
/// A bucket emptied with more room than this gives it back, and one using less than a quarter
/// of its room gives back half (room kept in every bucket a run ever filled would grow with the
/// run, not the band).
const KEPT_ROOM: usize = 16;
/// The same for `W`, whose room is one block: past this many entries (160 KB) the allocator
/// maps it on its own, and a smaller block is given back to the OS when it shrinks.
const WAITING_KEPT_ROOM: usize = 1 << 12;

fn bit(bits: &[u64], b: usize) -> bool {
    bits[b / 64] >> (b % 64) & 1 == 1
}

fn set_bit(bits: &mut [u64], b: usize, on: bool) {
    let mask = 1 << (b % 64);
    if on {
        bits[b / 64] |= mask;
    } else {
        bits[b / 64] &= !mask;
    }
}

fn sift_up(h: &mut [Keyed], mut i: usize) {
    let e = h[i];
    while i > 0 {
        let p = (i - 1) / ARITY;
        if !e.before(&h[p]) {
            break;
        }
        h[i] = h[p];
        i = p;
    }
    h[i] = e;
}

fn sift_down(h: &mut [Keyed], mut i: usize) {
    let n = h.len();
    let e = h[i];
    loop {
        let first = ARITY * i + 1;
        if first >= n {
            break;
        }
        let mut m = first;
        for c in first + 1..(first + ARITY).min(n) {
            if h[c].before(&h[m]) {
                m = c;
            }
        }
        if !h[m].before(&e) {
            break;
        }
        h[i] = h[m];
        i = m;
    }
    h[i] = e;
}

fn heapify(h: &mut [Keyed]) {
    for i in (0..h.len() / ARITY + 1).rev() {
        if i < h.len() {
            sift_down(h, i);
        }
    }
}

impl CostHeap {
    fn push(&mut self, e: Keyed) {
        if self.buckets.is_empty() {
            self.buckets.resize_with(BUCKETS, Vec::new);
            self.filled = vec![0; BUCKETS / 64];
            self.heaped = vec![0; BUCKETS / 64];
            self.low = BUCKETS;
        }
        let b = (e.key >> BUCKET_SHIFT) as usize;
        let bucket = &mut self.buckets[b];
        bucket.push(e);
        if bit(&self.heaped, b) {
            let last = bucket.len() - 1;
            sift_up(bucket, last);
        }
        set_bit(&mut self.filled, b, true);
        self.low = self.low.min(b);
        self.len += 1;
    }

    /// The cheapest non-empty bucket, made a heap.
    fn cheapest(&mut self) -> Option<usize> {
        let mut word = self.low / 64;
        let mut bits = *self.filled.get(word)? & (!0u64 << (self.low % 64));
        while bits == 0 {
            word += 1;
            bits = *self.filled.get(word)?;
        }
        let b = 64 * word + bits.trailing_zeros() as usize;
        self.low = b;
        if !bit(&self.heaped, b) {
            heapify(&mut self.buckets[b]);
            set_bit(&mut self.heaped, b, true);
        }
        Some(b)
    }

    fn peek(&mut self) -> Option<Keyed> {
        let b = self.cheapest()?;
        self.buckets[b].first().copied()
    }

    fn pop(&mut self) -> Option<Keyed> {
        let b = self.cheapest()?;
        let bucket = &mut self.buckets[b];
        let last = bucket.pop()?;
        let top = if bucket.is_empty() {
            last
        } else {
            let top = std::mem::replace(&mut bucket[0], last);
            sift_down(bucket, 0);
            top
        };
        if bucket.is_empty() {
            self.empty(b);
        }
        self.len -= 1;
        Some(top)
    }

    /// Bucket `b` has just been emptied (its room stays until [`CostHeap::trim`]).
    fn empty(&mut self, b: usize) {
        set_bit(&mut self.filled, b, false);
        set_bit(&mut self.heaped, b, false);
    }

    /// Gives back the room of buckets emptied, and half the room of buckets using less than a
    /// quarter of it. Called once a pass, not at every pop: the cheapest bucket is drained and
    /// refilled all pass long (the costs of the re-evaluated neighbours fall in it or next to
    /// it), and giving its room back as it drained, then growing it again, was a `mremap` each
    /// time on a large bucket, with the TLB shootdowns reaching the other stage's core (2 % of a
    /// one-stage run on bonsai at R = 0.2).
    fn trim(&mut self) {
        for bucket in &mut self.buckets {
            if bucket.capacity() <= KEPT_ROOM {
                continue;
            }
            if bucket.is_empty() {
                *bucket = Vec::new();
            } else if 4 * bucket.len() < bucket.capacity() {
                bucket.shrink_to(2 * bucket.len());
            }
        }
    }

    fn retain(&mut self, keep: impl Fn(&Keyed) -> bool) {
        for b in 0..self.buckets.len() {
            if !bit(&self.filled, b) {
                continue;
            }
            let bucket = &mut self.buckets[b];
            let before = bucket.len();
            bucket.retain(&keep);
            self.len -= before - bucket.len();
            if bucket.is_empty() {
                self.empty(b);
            } else if bit(&self.heaped, b) {
                heapify(bucket);
            }
        }
    }
}

impl Candidates {
    /// Into `Q`.
    pub(crate) fn push(&mut self, c: Candidate) {
        self.queue.push(Keyed::new(c));
    }

    /// Into `W` until the front reaches `reach` (time-lag, DELAY).
    pub(crate) fn delay(&mut self, c: Candidate, reach: f64) {
        self.waiting.push(ByReach(reach, c));
    }

    /// ACTIVATE(front): moves the waiting edges with `reach <= front` to `Q`
    /// (seed 000, section 3, "Time-lag").
    ///
    /// `W` gives back room it no longer uses, as `Q`'s buckets do: on large slices it holds the
    /// candidates that met the front, up to about two per resident face, and that room was held
    /// for the rest of the run beside the queue they moved to (bonsai upsampled to 2041^3: 5.8
    /// MB touched for 1.7 MB of entries at slab 500). Only large room is given back
    /// ([`WAITING_KEPT_ROOM`]): shrinking the small `W` of a 256^3 volume at every slab raised
    /// bonsai's peak by about 1 MiB.
    pub(crate) fn activate(&mut self, front: f64) {
        while self.waiting.peek().is_some_and(|w| w.0 <= front) {
            if let Some(ByReach(_, c)) = self.waiting.pop() {
                self.queue.push(Keyed::new(c));
            }
        }
        if self.waiting.capacity() > WAITING_KEPT_ROOM
            && 4 * self.waiting.len() < self.waiting.capacity()
        {
            self.waiting
                .shrink_to((2 * self.waiting.len()).max(WAITING_KEPT_ROOM));
        }
    }

    pub(crate) fn peek(&mut self) -> Option<Candidate> {
        self.queue.peek().map(|c| c.candidate())
    }

    pub(crate) fn pop(&mut self) -> Option<Candidate> {
        self.queue.pop().map(|c| c.candidate())
    }

    /// Keeps only the entries (queued or waiting) satisfying `keep`.
    pub(crate) fn retain(&mut self, keep: impl Fn(&Candidate) -> bool) {
        self.queue.retain(|c| keep(&c.candidate()));
        self.waiting.retain(|c| keep(&c.1));
    }

    /// The end of a pass: gives back room the queue no longer uses ([`CostHeap::trim`]).
    pub(crate) fn trim(&mut self) {
        self.queue.trim();
    }

    pub(crate) fn len(&self) -> usize {
        self.queue.len + self.waiting.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cand(a: u64, b: u64, cost: f64) -> Candidate {
        Candidate {
            cost,
            a,
            b,
            stamps: [0, 0],
        }
    }

    #[test]
    fn cheapest_first_ties_by_ids() {
        let mut c = Candidates::default();
        for x in [cand(5, 6, 1.0), cand(1, 9, 0.5), cand(1, 2, 1.0)] {
            c.push(x);
        }
        let order: Vec<(u64, u64)> = std::iter::from_fn(|| c.pop()).map(|x| (x.a, x.b)).collect();
        assert_eq!(order, vec![(1, 9), (1, 2), (5, 6)]);
    }

    #[test]
    fn waiting_edges_are_activated_by_reach() {
        let mut c = Candidates::default();
        c.delay(cand(1, 2, 0.0), 3.5);
        c.delay(cand(3, 4, 1.0), 5.0);
        c.push(cand(5, 6, 2.0));
        assert_eq!(c.len(), 3);
        assert_eq!(c.pop().map(|x| x.a), Some(5));
        assert!(c.pop().is_none());
        c.activate(4.0);
        assert_eq!(c.pop().map(|x| x.a), Some(1));
        assert!(c.pop().is_none());
        c.activate(f64::INFINITY);
        assert_eq!(c.pop().map(|x| x.a), Some(3));
    }

    #[test]
    fn the_waiting_queue_gives_back_large_room_once_drained() {
        let mut c = Candidates::default();
        for i in 0..20_000 {
            c.delay(cand(i, i + 1, 0.0), 1.0);
        }
        for i in 0..10 {
            c.delay(cand(i, i + 2, 0.0), 5.0);
        }
        assert!(c.waiting.capacity() >= 20_010);
        c.activate(2.0);
        assert_eq!(c.waiting.len(), 10);
        assert!(
            c.waiting.capacity() < 2 * WAITING_KEPT_ROOM,
            "{}",
            c.waiting.capacity()
        );
        assert_eq!(c.len(), 20_010, "every entry kept, in Q or in W");
    }

    #[test]
    fn cost_keys_sort_like_total_cmp_and_round_trip() {
        let costs = [-1.0, -0.0, 0.0, 1e-300, 0.5, 1.0, 3e8, f64::INFINITY];
        for w in costs.windows(2) {
            assert!(cost_key(w[0]) < cost_key(w[1]), "{w:?}");
        }
        for c in costs {
            assert_eq!(key_cost(cost_key(c)).to_bits(), c.to_bits());
        }
    }

    #[test]
    fn the_heap_pops_in_sorted_order_after_pushes_pops_and_retain() {
        let mut c = Candidates::default();
        let mut reference = Vec::new();
        let mut x = 12345_u64;
        for i in 0..500_u64 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let cost = if x.is_multiple_of(7) {
                -1.0
            } else {
                (x >> 40) as f64 / 64.0
            };
            c.push(cand(i % 37, i, cost));
            reference.push((cost, i % 37, i));
            if i % 5 == 0 {
                reference.sort_by(|p, q| p.0.total_cmp(&q.0).then((p.1, p.2).cmp(&(q.1, q.2))));
                let top = reference.remove(0);
                let got = c.pop().unwrap();
                assert_eq!((got.cost, got.a, got.b), top);
            }
        }
        c.retain(|x| x.b % 3 != 0);
        reference.retain(|x| x.2 % 3 != 0);
        reference.sort_by(|p, q| p.0.total_cmp(&q.0).then((p.1, p.2).cmp(&(q.1, q.2))));
        let order: Vec<(f64, u64, u64)> = std::iter::from_fn(|| c.pop())
            .map(|x| (x.cost, x.a, x.b))
            .collect();
        assert_eq!(order, reference);
    }

    #[test]
    fn retain_filters_both_queues() {
        let mut c = Candidates::default();
        c.push(cand(1, 2, 0.0));
        c.delay(cand(3, 4, 0.0), 9.0);
        c.push(cand(5, 6, 0.0));
        c.retain(|x| x.a != 3 && x.a != 5);
        assert_eq!(c.len(), 1);
    }
}
