//! Edge candidates: the priority queue `Q` and the Tandem waiting queue `W`.
//!
//! Entries are invalidated lazily: each carries the stamps of its endpoints at evaluation time and
//! is dropped when popped if either endpoint changed, retired or died since. Ties are broken by
//! vertex ids so the output is a deterministic function of the input sequence.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use crate::cost::Eval;

#[derive(Debug, Clone, Copy)]
pub(crate) struct Candidate {
    /// `a < b`.
    pub(crate) a: u64,
    pub(crate) b: u64,
    pub(crate) stamps: [u32; 2],
    pub(crate) eval: Eval,
}

impl Candidate {
    fn key(&self, primary: f64) -> (f64, u64, u64) {
        (primary, self.a, self.b)
    }
}

fn ascending(x: (f64, u64, u64), y: (f64, u64, u64)) -> Ordering {
    x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2))
}

/// Min-heap order by cost (the std heap is a max-heap, hence the reversal).
struct ByCost(Candidate);
/// Min-heap order by reach.
struct ByReach(Candidate);

macro_rules! min_heap_order {
    ($t:ident, $field:ident) => {
        impl Ord for $t {
            fn cmp(&self, other: &Self) -> Ordering {
                ascending(
                    other.0.key(other.0.eval.$field),
                    self.0.key(self.0.eval.$field),
                )
            }
        }
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
    };
}
min_heap_order!(ByCost, cost);
min_heap_order!(ByReach, reach);

#[derive(Default)]
pub(crate) struct Candidates {
    queue: BinaryHeap<ByCost>,
    waiting: BinaryHeap<ByReach>,
}

impl Candidates {
    /// Into `Q`, or into `W` when its patch reaches beyond `front` (time-lag).
    pub(crate) fn push(&mut self, c: Candidate, front: Option<f64>) {
        match front {
            Some(front) if c.eval.reach > front => self.waiting.push(ByReach(c)),
            _ => self.queue.push(ByCost(c)),
        }
    }

    /// ACTIVATE(front): moves the waiting edges with `reach <= front` to `Q`
    /// (seed 000, section 3, "Time-lag").
    pub(crate) fn activate(&mut self, front: f64) {
        while self.waiting.peek().is_some_and(|w| w.0.eval.reach <= front) {
            if let Some(ByReach(c)) = self.waiting.pop() {
                self.queue.push(ByCost(c));
            }
        }
    }

    pub(crate) fn pop(&mut self) -> Option<Candidate> {
        self.queue.pop().map(|c| c.0)
    }

    /// Keeps only the entries (queued or waiting) satisfying `keep`.
    pub(crate) fn retain(&mut self, keep: impl Fn(&Candidate) -> bool) {
        self.queue.retain(|c| keep(&c.0));
        self.waiting.retain(|c| keep(&c.0));
    }

    pub(crate) fn len(&self) -> usize {
        self.queue.len() + self.waiting.len()
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;

    fn cand(a: u64, b: u64, cost: f64, reach: f64) -> Candidate {
        let eval = Eval {
            pos: DVec3::ZERO,
            cost,
            shape_error: 0.0,
            reach,
        };
        Candidate {
            a,
            b,
            stamps: [0, 0],
            eval,
        }
    }

    #[test]
    fn cheapest_first_ties_by_ids() {
        let mut c = Candidates::default();
        for x in [
            cand(5, 6, 1.0, 0.0),
            cand(1, 9, 0.5, 0.0),
            cand(1, 2, 1.0, 0.0),
        ] {
            c.push(x, None);
        }
        let order: Vec<(u64, u64)> = std::iter::from_fn(|| c.pop()).map(|x| (x.a, x.b)).collect();
        assert_eq!(order, vec![(1, 9), (1, 2), (5, 6)]);
    }

    #[test]
    fn waiting_edges_are_activated_by_reach() {
        let mut c = Candidates::default();
        c.push(cand(1, 2, 0.0, 3.5), Some(3.0));
        c.push(cand(3, 4, 1.0, 5.0), Some(3.0));
        c.push(cand(5, 6, 2.0, 2.0), Some(3.0));
        assert_eq!(c.len(), 3);
        assert_eq!(c.pop().map(|x| x.a), Some(5));
        assert!(c.pop().is_none());
        c.activate(4.0);
        assert_eq!(c.pop().map(|x| x.a), Some(1));
        assert!(c.pop().is_none());
        c.activate(f64::INFINITY);
        assert_eq!(c.pop().map(|x| x.a), Some(3));
    }
}
