//! The contraction loop, shared by every policy: pop the cheapest candidate, drop it if stale,
//! check topology and geometry, contract, re-queue the new vertex's edges (Garland and Heckbert
//! 1997; incremental as in Hou and Chen section 3.2).

use glam::DVec3;

use crate::candidates::Candidate;
use crate::cost::{COINCIDENT, Eval};
use crate::intersect::Verdict;
use crate::store::Store;
use crate::topology::{self, Patch};
use crate::{Priority, Simplifier, data_dependent};

/// How far below its preimage's lowest rank a cascade's first stage may place a vertex (see
/// `Simplifier::outside_first_stage_room`): a slab, so most quadric optima pass.
const PREIMAGE_SLACK: f64 = 1.0;

/// Where a decimation run stops (besides running out of candidates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Until {
    /// When at most this many faces are resident (rate policy).
    Resident(usize),
    /// When no candidate is left (threshold policies: every queued edge passes the threshold).
    Exhausted,
}

impl Simplifier {
    /// Cost and placement of `ab -> c` (see [`crate::cost::Evaluator`]).
    fn evaluate(&self, a: u64, b: u64) -> Option<Eval> {
        self.evaluator.as_ref()?.evaluate(&self.store, a, b)
    }

    pub(crate) fn reached(&self, until: Until) -> bool {
        match until {
            Until::Resident(target) => self.store.resident() <= target,
            Until::Exhausted => false,
        }
    }

    pub(crate) fn decimate(&mut self, until: Until) {
        if self.evaluator.is_none() {
            return;
        }
        while !self.reached(until) || self.next_is_coincident() {
            let Some(c) = self.candidates.pop() else {
                break;
            };
            if !is_current(&self.store, &c) {
                continue;
            }
            // Re-evaluated: the placement is not stored in the heap, and objectives reading the
            // neighbourhood (isotropy) may have changed without a stamp change.
            let Some(eval) = self.evaluate(c.a, c.b) else {
                self.stats.rejected_other += 1;
                continue;
            };
            if self.outside_first_stage_room(c.a, c.b, eval.pos) {
                self.stats.rejected_other += 1;
                continue;
            }
            if eval.cost > c.cost {
                self.candidates.push(Candidate {
                    cost: eval.cost,
                    ..c
                });
                continue;
            }
            // The front first: it is the cheapest test, and what waits for the front is tested
            // again when it comes back (a cascade's second stage, whose front is the first
            // stage's rear, delayed one candidate in two before it gated vertices by their whole
            // star; it still delays more than one stage does).
            let patch = Patch::gather(&self.store, c.a, c.b);
            if let Some(reach) = self.beyond_front(&patch, eval.pos) {
                self.stats.delayed_front += 1;
                self.candidates.delay(c, reach);
            } else if !topology::link_ok(&self.store, c.a, c.b) {
                self.stats.rejected_link += 1;
            } else if !topology::geometry_ok(&patch, c.a, c.b, eval.pos) {
                self.stats.rejected_flip += 1;
            } else {
                // Merging coincident vertices moves nothing: any crossing of the new fan existed.
                let verdict = if eval.cost == COINCIDENT {
                    Verdict::Clear
                } else {
                    self.isect.would_intersect(&patch, c.a, c.b, c.b, eval.pos)
                };
                match verdict {
                    Verdict::Clear => self.contract(&patch, c.a, c.b, eval),
                    Verdict::Crosses => self.stats.rejected_intersection += 1,
                    Verdict::Unguarded => self.stats.rejected_unguarded += 1,
                }
            }
        }
    }

    /// The rank the front must reach before contracting `a`, `b` to `pos` is safe from the
    /// triangles still to come, when that is beyond the current front: the farthest rank of the
    /// corners of the new fan and of the `patch` it replaces (the fan lies in the convex hull of
    /// its corners; see [`crate::Sweep`]).
    fn beyond_front(&self, patch: &Patch, pos: DVec3) -> Option<f64> {
        let sweep = self.config.sweep?;
        let top = patch
            .tris
            .iter()
            .flat_map(|pt| pt.p)
            .fold(sweep.height(pos), |top, p| top.max(sweep.height(p)));
        let far = sweep.rank_at(top);
        (far > self.front).then_some(far)
    }

    /// A cascade's first stage never places a vertex below the rear it announced (`cascade`):
    /// the second stage edits the surface up to that plane. Nor more than [`PREIMAGE_SLACK`]
    /// ranks below the lowest rank of the new vertex's preimage: the rear is the lowest vertex
    /// the first stage holds, retired ones included (they stay until their last triangle is
    /// written), and quadric optima far outside their preimage (10 slabs below it, on bonsai
    /// upsampled to 511^3) kept it 15 to 20 slabs behind the front, where the second stage held
    /// everything above it as its front.
    fn outside_first_stage_room(&self, a: u64, b: u64, pos: DVec3) -> bool {
        if self.config.cascade != crate::Cascade::First {
            return false;
        }
        let Some(sweep) = self.config.sweep else {
            return false;
        };
        let rank = sweep.rank_of(pos);
        let preimage = [a, b]
            .iter()
            .filter_map(|&x| self.store.vertex(x))
            .map(|v| v.rank_min)
            .min();
        rank < f64::from(self.rear)
            || preimage.is_some_and(|low| rank < f64::from(low) - PREIMAGE_SLACK)
    }

    /// Whether the cheapest candidate joins two coincident vertices (see [`COINCIDENT`]).
    fn next_is_coincident(&mut self) -> bool {
        self.candidates.peek().is_some_and(|c| c.cost == COINCIDENT)
    }

    /// Queues every edge between free vertices once more (used at the end, when refused edges
    /// may pass in their changed neighbourhoods).
    pub(crate) fn requeue_all(&mut self) {
        let ids: Vec<u64> = self.store.ids().collect();
        for id in ids {
            let ring = topology::ring(&self.store, id);
            self.push_ring_edges(id, &ring, |n| n > id);
        }
    }

    /// Queues the edges from `v` to the free neighbours in its `ring` that `take` accepts.
    pub(crate) fn push_ring_edges(
        &mut self,
        v: u64,
        ring: &topology::Ring,
        take: impl Fn(u64) -> bool,
    ) {
        if self.evaluator.is_none() || !self.store.is_free(v) {
            return;
        }
        for &(n, _) in ring {
            if !take(n) || !self.store.is_free(n) {
                continue;
            }
            let (a, b) = (v.min(n), v.max(n));
            if !self.span_ok(a, b) {
                continue;
            }
            let Some(eval) = self.evaluate(a, b) else {
                continue;
            };
            let stamps = [a, b].map(|x| self.store.stamp(x));
            let c = Candidate {
                cost: eval.cost,
                a,
                b,
                stamps,
            };
            if self.time_lag && eval.reach > self.front {
                self.candidates.delay(c, eval.reach);
            } else {
                self.candidates.push(c);
            }
        }
    }

    /// Drops stale heap entries once they outnumber the live ones by far. Retired vertices'
    /// edges would otherwise stay in the heap for good (the costly ones are never popped), and the
    /// heap would grow with the surface instead of the band.
    pub(crate) fn compact_candidates(&mut self) {
        if self.candidates.len() > 2 * self.store.resident() + 1024 {
            let store = &self.store;
            self.candidates.retain(|c| is_current(store, c));
        }
    }

    /// A vertex that kept absorbing neighbours ahead of it would ride along with the front (its
    /// highest rank never falls behind), never retire, and keep ever more retired neighbours
    /// resident: on a straight tube along the sweep, contractions along the axis cost nothing.
    /// Bounding the rank span of every preimage to `2 * retire_lag + 2` slabs (`retire_lag + 1`
    /// in a cascade's first stage) bounds the life of every vertex, and so the resident band,
    /// independently of the surface. Coincident vertices are exempt: merging them moves nothing,
    /// and leaving them would leave zero-area triangles.
    /// Retirement by the memory budget alone (rate) needs no such bound: the oldest buckets leave
    /// first whatever rides ahead, and a rider's fan is all it keeps.
    fn span_ok(&self, a: u64, b: u64) -> bool {
        if !self.lag_retirement() {
            return true;
        }
        let max_span = match self.config.cascade {
            // Its output is not final, and the span is what its rear trails by (see
            // `outside_first_stage_room`).
            crate::Cascade::First => self.config.retire_lag.saturating_add(1),
            _ => self.config.retire_lag.saturating_mul(2).saturating_add(2),
        };
        match (self.store.vertex(a), self.store.vertex(b)) {
            (Some(va), Some(vb)) => va.pos() == vb.pos() || va.merged_span(vb) <= max_span,
            _ => false,
        }
    }

    /// `ab -> c` at `pos`. The younger id `b` survives as `c` (its slot is nearer the front, so the
    /// store's front slot frees sooner); `a` dies. Triangles on `ab` disappear, `a`'s others are
    /// relinked to `b`; orientation is preserved because only the id is replaced.
    fn contract(&mut self, patch: &Patch, a: u64, b: u64, eval: Eval) {
        let (gone, keep, pos) = (a, b, eval.pos);
        if self.time_lag && eval.reach > self.front {
            self.stats.lag_violations += 1;
        }
        let merged = self.merged_data(patch, gone, keep, pos);
        let tris = self
            .store
            .vertex(gone)
            .map(|v| v.tris.clone())
            .unwrap_or_default();
        for t in tris {
            if self.store.tri(t).contains(keep) {
                self.isect.remove(t);
                let removed = self.store.remove_triangle(t);
                self.stats.faces_unmodifiable -= usize::from(removed.unmodifiable > 0);
            } else {
                let tri = self.store.tri_mut(t);
                for id in &mut tri.v {
                    if *id == gone {
                        *id = keep;
                    }
                }
                if let Some(k) = self.store.vertex_mut(keep) {
                    k.tris.push(t);
                }
            }
        }
        let Some(g) = self.store.remove_vertex(gone) else {
            return;
        };
        // Contractions only happen with an evaluator.
        let rank_spacing = self.evaluator.as_ref().map_or(1.0, |e| e.rank_spacing);
        let Some(k) = self.store.vertex_mut(keep) else {
            return;
        };
        (k.height, k.rad) = k.merged_patch(&g, rank_spacing);
        k.attrs = merged.attrs;
        k.attr_quadric = merged.attr_quadric;
        k.quadric += g.quadric;
        k.area += g.area;
        k.boundary |= g.boundary;
        let rank_moved = g.rank_max > k.rank_max;
        k.rank_max = k.rank_max.max(g.rank_max);
        k.rank_min = k.rank_min.min(g.rank_min);
        let rank = k.rank_max;
        self.store.set_pos(keep, pos);
        self.store.bump_stamp(keep);
        if rank_moved {
            self.buckets.push(rank, keep, &mut self.store);
        }
        self.stats.contractions += 1;
        self.stats.max_cost = self.stats.max_cost.max(eval.cost);
        self.stats.max_shape_error = self.stats.max_shape_error.max(eval.shape_error);
        if let Some(k) = self.store.vertex(keep) {
            self.isect.warm(&k.tris);
            for &t in &k.tris {
                let tri = self.store.tri(t);
                self.isect.update(t, tri.v, self.store.corners(tri));
            }
        }
        let ring = topology::ring(&self.store, keep);
        if matches!(self.config.priority, Priority::DataDependent { .. }) {
            data_dependent::forget(&self.store, keep, &ring);
        }
        self.push_ring_edges(keep, &ring, |_| true);
    }
}

/// Both endpoints unchanged since the candidate was evaluated, and still free to move.
fn is_current(store: &Store, c: &Candidate) -> bool {
    store.is_current(c.a, c.stamps[0]) && store.is_current(c.b, c.stamps[1])
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use crate::{Cascade, Simplifier};

    /// A simplifier at rate 0.5 sweeping along z (rank = z), holding an edge from rank 5 to 6.
    fn edge(cascade: Cascade) -> (Simplifier, u64, u64) {
        let mut s = crate::tests::swept(cascade, usize::MAX);
        s.add_vertex(0, DVec3::new(0.0, 0.0, 5.5), 5, &[]);
        s.add_vertex(1, DVec3::new(1.0, 0.0, 6.5), 6, &[]);
        let slot = |id| s.store.slot_of(id).unwrap();
        let (a, b) = (slot(0), slot(1));
        (s, a, b)
    }

    /// The first stage's rear trails its front by how far below their preimages it places
    /// vertices, so it keeps them within a slab of it; other stages place them freely.
    #[test]
    fn a_first_stage_places_no_vertex_far_below_its_preimage() {
        let (first, a, b) = edge(Cascade::First);
        let at = |z| DVec3::new(0.5, 0.0, z);
        assert!(
            !first.outside_first_stage_room(a, b, at(4.5)),
            "a slab below"
        );
        assert!(
            first.outside_first_stage_room(a, b, at(3.5)),
            "two slabs below"
        );
        let (single, a, b) = edge(Cascade::Single);
        assert!(!single.outside_first_stage_room(a, b, at(3.5)));
    }
}
