//! Edge candidates: the priority queue `Q` and the Tandem waiting queue `W`.
//!
//! Entries are invalidated lazily: each carries the stamps of its endpoints at evaluation time and
//! is dropped when popped if either endpoint changed, retired or died since. Ties are broken by
//! vertex ids so the output is a deterministic function of the input sequence.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// A queued edge. Deliberately small (32 bytes): the heap is sifted on every push and pop and its
/// memory traffic dominates the loop, so the placement is recomputed when the edge is popped
/// instead of stored.
#[derive(Debug, Clone, Copy)]
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

/// Min-heap order by cost (the std heap is a max-heap, hence the reversal).
struct ByCost(Candidate);

/// Min-heap order by reach.
struct ByReach(f64, Candidate);

impl Ord for ByCost {
    fn cmp(&self, other: &Self) -> Ordering {
        ascending((other.0.cost, &other.0), (self.0.cost, &self.0))
    }
}

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
order_from_ord!(ByCost, ByReach);

#[derive(Default)]
pub(crate) struct Candidates {
    queue: BinaryHeap<ByCost>,
    waiting: BinaryHeap<ByReach>,
}

impl Candidates {
    /// Into `Q`.
    pub(crate) fn push(&mut self, c: Candidate) {
        self.queue.push(ByCost(c));
    }

    /// Into `W` until the front reaches `reach` (time-lag, DELAY).
    pub(crate) fn delay(&mut self, c: Candidate, reach: f64) {
        self.waiting.push(ByReach(reach, c));
    }

    /// ACTIVATE(front): moves the waiting edges with `reach <= front` to `Q`
    /// (seed 000, section 3, "Time-lag").
    pub(crate) fn activate(&mut self, front: f64) {
        while self.waiting.peek().is_some_and(|w| w.0 <= front) {
            if let Some(ByReach(_, c)) = self.waiting.pop() {
                self.queue.push(ByCost(c));
            }
        }
    }

    pub(crate) fn peek(&self) -> Option<&Candidate> {
        self.queue.peek().map(|c| &c.0)
    }

    pub(crate) fn pop(&mut self) -> Option<Candidate> {
        self.queue.pop().map(|c| c.0)
    }

    /// Keeps only the entries (queued or waiting) satisfying `keep`.
    pub(crate) fn retain(&mut self, keep: impl Fn(&Candidate) -> bool) {
        self.queue.retain(|c| keep(&c.0));
        self.waiting.retain(|c| keep(&c.1));
    }

    pub(crate) fn len(&self) -> usize {
        self.queue.len() + self.waiting.len()
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
    fn retain_filters_both_queues() {
        let mut c = Candidates::default();
        c.push(cand(1, 2, 0.0));
        c.delay(cand(3, 4, 0.0), 9.0);
        c.push(cand(5, 6, 0.0));
        c.retain(|x| x.a != 3 && x.a != 5);
        assert_eq!(c.len(), 1);
    }
}
