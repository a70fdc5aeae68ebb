//! The decimator: the one contraction loop, shared by every policy. Pop the cheapest candidate,
//! drop it if stale, check topology and geometry, contract, re-queue the new vertex's edges
//! (Garland and Heckbert 1997; incremental as in Hou and Chen section 3.2).
//!
//! It owns what only contracting needs (the evaluator and the candidate queue) and works on the
//! stage's [`Band`]; when and how far to decimate is the stage's to say ([`Until`]).

use glam::DVec3;

use crate::band::Band;
use crate::candidates::{Candidate, Candidates};
use crate::cost::{COINCIDENT, Eval, Evaluator};
use crate::enclosure;
use crate::intersect::Verdict;
use crate::seam::HalfSpace;
use crate::store::Store;
use crate::topology::{self, Patch};
use crate::{
    Cascade, Front, Interrupted, Priority, SimplifyConfig, SimplifyStats, data_dependent, priority,
};

/// How far below its preimage's lowest rank a cascade's first stage may place a vertex (see
/// `outside_first_stage_room`): a slab, so most quadric optima pass.
const PREIMAGE_SLACK: f64 = 1.0;

/// Candidates popped between two looks at the caller's interrupt (see [`Decimator::decimate`]):
/// a few milliseconds of contractions, so a Ctrl-C is seen at once, while the look (a call and
/// an atomic load) costs nothing next to the contractions it waits for.
const LOOK_EVERY: u32 = 4096;

/// Where a decimation run stops (besides running out of candidates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Until {
    /// When at most this many faces are resident (rate policy).
    Resident(usize),
    /// When no candidate is left (threshold policies: every queued edge passes the threshold).
    Exhausted,
    /// When at most `resident` faces are held or the cheapest candidate costs more than `cost`:
    /// a round of two workers either side of a cut (`seam`), which contract in the cost order
    /// one queue would, up to the same cost.
    Cheaper { cost: f64, resident: usize },
}

impl Until {
    pub(crate) fn reached(self, band: &Band) -> bool {
        match self {
            Until::Resident(target)
            | Until::Cheaper {
                resident: target, ..
            } => band.resident() <= target,
            Until::Exhausted => false,
        }
    }
}

/// Where the stage stands when it asks the decimator: its configuration and its sweep.
#[derive(Debug, Clone, Copy)]
pub(crate) struct At<'a> {
    pub(crate) config: &'a SimplifyConfig,
    /// The front's key (`Sweep::front_key`), `+inf` after the end of the volume.
    pub(crate) front: f64,
    /// First stage of a cascade: the rear it announced last (its new fans stay clear of it).
    pub(crate) rear: Front,
    /// One of two workers on either side of a cut (`seam`): its placements stay on its side.
    pub(crate) half: Option<HalfSpace>,
}

impl At<'_> {
    /// The front key the time-lag waits for, for a contraction reaching rank `reach`
    /// (`Sweep::key_of_rank`).
    fn lag_key(&self, reach: f64) -> f64 {
        self.config.sweep.map_or(reach, |w| w.key_of_rank(reach))
    }
}

#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct Decimator {
    /// Cost and placement of contractions.
    evaluator: Evaluator,
    candidates: Candidates,
    /// Mode `error` with the Tandem time-lag: an edge reaching past the front waits for it.
    time_lag: bool,
    /// The rank span a preimage may reach (see `span_ok`); `None` when the stage retires by the
    /// memory budget, which needs no bound.
    max_span: Option<u32>,
    /// The popped candidate's patch, gathered into the same room each time (scratch, refilled
    /// for every candidate: a checkpoint need not hold it).
    #[serde(skip)]
    patch: Option<Box<Patch>>,
}

impl Decimator {
    /// The decimator for `config`, contracting by `evaluator`.
    pub(crate) fn new(config: &SimplifyConfig, evaluator: Evaluator) -> Self {
        let max_span = config.lag_retirement().then(|| match config.cascade {
            // Its output is not final, and the span is what its rear trails by (see
            // `outside_first_stage_room`).
            Cascade::First => config.retire_lag.saturating_add(1),
            _ => config.retire_lag.saturating_mul(2).saturating_add(2),
        });
        Self {
            evaluator,
            candidates: Candidates::default(),
            time_lag: config.policy.time_lag(),
            max_span,
            patch: None,
        }
    }

    /// A decimator like this one with an empty queue: for a second worker (`seam`), and for a
    /// queue built afresh after the workers' results are merged.
    pub(crate) fn fresh(&self) -> Decimator {
        Decimator {
            evaluator: self.evaluator.clone(),
            candidates: Candidates::default(),
            time_lag: self.time_lag,
            max_span: self.max_span,
            patch: None,
        }
    }

    /// Drops the queued candidates that name a vertex no longer free or changed since (the
    /// other side of a cut, once its vertices are moved out).
    pub(crate) fn drop_stale(&mut self, band: &Band) {
        let store = &band.store;
        self.candidates.retain(|c| is_current(store, c));
    }

    /// The new front: delayed candidates it has passed come back.
    pub(crate) fn activate(&mut self, front: f64) {
        self.candidates.activate(front);
    }

    /// Queued candidates, stale ones included (the run summary's `candidates`).
    pub(crate) fn queued(&self) -> usize {
        self.candidates.len()
    }

    /// Cost and placement of `ab -> c` (see [`crate::cost::Evaluator`]).
    fn evaluate(&self, store: &Store, a: u64, b: u64) -> Option<Eval> {
        self.evaluator.evaluate(store, a, b)
    }

    /// Contracts the cheapest candidates until `until` (and past it while the cheapest merges
    /// coincident vertices).
    ///
    /// `interrupt` is asked before the first candidate and then every [`LOOK_EVERY`]: a final
    /// decimation in core simplifies the whole surface (engine upsampled to 511 x 511 x 255 in
    /// mode classical: 38 s), and the run's Ctrl-C waited for all of it. Interrupted, the band
    /// is as the last contraction left it (every index in step), short of `until`. Asking
    /// changes nothing else: a run never interrupted contracts exactly what it did before.
    pub(crate) fn decimate(
        &mut self,
        band: &mut Band,
        at: &At,
        stats: &mut SimplifyStats,
        until: Until,
        interrupt: &dyn Fn() -> bool,
    ) -> Result<(), Interrupted> {
        let mut popped = 0u32;
        while !(until.reached(band) || self.next_costs_more(until)) || self.next_is_coincident() {
            if popped.is_multiple_of(LOOK_EVERY) {
                crate::asked(interrupt)?;
            }
            popped = popped.wrapping_add(1);
            let Some(c) = self.candidates.pop() else {
                break;
            };
            if !is_current(&band.store, &c) {
                continue;
            }
            // Re-evaluated: the placement is not stored in the heap, and objectives reading the
            // neighbourhood (isotropy) may have changed without a stamp change.
            let Some(eval) = self.evaluate(&band.store, c.a, c.b) else {
                stats.rejected_other += 1;
                continue;
            };
            if outside_first_stage_room(&band.store, at, c.a, c.b, eval.pos)
                || at.half.is_some_and(|h| !h.holds(eval.pos))
            {
                stats.rejected_other += 1;
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
            // again when it comes back. Rare since vertices are let in by their whole star
            // (`Stage::set_modifiable`): what is left are placements past the front.
            // Taken out while the checks and the contraction borrow the decimator (a box, so
            // that taking it moves a pointer, not the patch's inline room).
            let mut patch = self.patch.take().unwrap_or_default();
            patch.gather_into(&band.store, c.a, c.b);
            if let Some(reach) = beyond_front(at, &patch, eval.pos) {
                stats.delayed_front += 1;
                self.candidates.delay(c, reach);
            } else if crosses_rear(at, &patch, c.a, c.b, eval.pos) {
                stats.rejected_other += 1;
            } else if !topology::link_ok(&patch, c.a, c.b) {
                stats.rejected_link += 1;
            } else if !topology::geometry_ok(&patch, c.a, c.b, eval.pos)
                || !enclosure::keeps_enclosure(&band.store, &patch, c.a, c.b, eval.pos)
            {
                stats.rejected_flip += 1;
            } else {
                // Merging coincident vertices moves nothing: any crossing of the new fan existed.
                let verdict = if eval.cost == COINCIDENT {
                    Verdict::Clear
                } else {
                    band.guard.would_intersect(&patch, c.a, c.b, c.b, eval.pos)
                };
                match verdict {
                    Verdict::Clear => self.contract(band, at, stats, &patch, (c.a, c.b), eval),
                    Verdict::Crosses => stats.rejected_intersection += 1,
                    Verdict::Unguarded => stats.rejected_unguarded += 1,
                }
            }
            self.patch = Some(patch);
        }
        self.candidates.trim();
        Ok(())
    }

    /// Whether the cheapest candidate costs more than an [`Until::Cheaper`] allows.
    fn next_costs_more(&mut self, until: Until) -> bool {
        let Until::Cheaper { cost, .. } = until else {
            return false;
        };
        self.candidates.peek().is_some_and(|c| c.cost > cost)
    }

    /// The cheapest queued candidate's cost (as queued: it may be stale).
    pub(crate) fn cheapest(&mut self) -> Option<f64> {
        self.candidates.peek().map(|c| c.cost)
    }

    /// Whether the cheapest candidate joins two coincident vertices (see [`COINCIDENT`]).
    fn next_is_coincident(&mut self) -> bool {
        self.candidates.peek().is_some_and(|c| c.cost == COINCIDENT)
    }

    /// Queues every edge between free vertices once more (used at the end, when refused edges
    /// may pass in their changed neighbourhoods). It evaluates every edge of the surface, as
    /// long as a good part of a decimation in core: `interrupt` is asked every [`LOOK_EVERY`]
    /// vertices (see [`Decimator::decimate`]).
    pub(crate) fn requeue_all(
        &mut self,
        band: &Band,
        at: &At,
        interrupt: &dyn Fn() -> bool,
    ) -> Result<(), Interrupted> {
        for (i, id) in band.store.ids().enumerate() {
            if i.is_multiple_of(LOOK_EVERY as usize) {
                crate::asked(interrupt)?;
            }
            let ring = topology::ring(&band.store, id);
            self.push_ring_edges(&band.store, at, id, &ring, |n| n > id);
        }
        Ok(())
    }

    /// Queues the edges from `v` to the free neighbours in its `ring` that `take` accepts.
    pub(crate) fn push_ring_edges(
        &mut self,
        store: &Store,
        at: &At,
        v: u64,
        ring: &topology::Ring,
        take: impl Fn(u64) -> bool,
    ) {
        if !store.is_free(v) {
            return;
        }
        for &(n, _) in ring {
            if !take(n) || !store.is_free(n) {
                continue;
            }
            let (a, b) = (v.min(n), v.max(n));
            if !self.span_ok(store, a, b) {
                continue;
            }
            let Some(eval) = self.evaluate(store, a, b) else {
                continue;
            };
            let stamps = [a, b].map(|x| store.stamp(x));
            let c = Candidate {
                cost: eval.cost,
                a,
                b,
                stamps,
            };
            let reach = at.lag_key(eval.reach);
            if self.time_lag && reach > at.front {
                self.candidates.delay(c, reach);
            } else {
                self.candidates.push(c);
            }
        }
    }

    /// Drops stale heap entries once they outnumber the live ones by far. Retired vertices'
    /// edges would otherwise stay in the heap for good (the costly ones are never popped), and the
    /// heap would grow with the surface instead of the band.
    pub(crate) fn compact(&mut self, band: &Band) {
        if self.candidates.len() > 2 * band.resident() + 1024 {
            let store = &band.store;
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
    fn span_ok(&self, store: &Store, a: u64, b: u64) -> bool {
        let Some(max_span) = self.max_span else {
            return true;
        };
        match (store.vertex(a), store.vertex(b)) {
            (Some(va), Some(vb)) => store.pos(a) == store.pos(b) || va.merged_span(vb) <= max_span,
            _ => false,
        }
    }

    /// `ab -> c` at `pos`. The younger id `b` survives as `c` (its slot is nearer the front, so the
    /// store's front slot frees sooner); `a` dies. Triangles on `ab` disappear, `a`'s others are
    /// relinked to `b`; orientation is preserved because only the id is replaced.
    fn contract(
        &mut self,
        band: &mut Band,
        at: &At,
        stats: &mut SimplifyStats,
        patch: &Patch,
        (a, b): (u64, u64),
        eval: Eval,
    ) {
        let (gone, keep, pos) = (a, b, eval.pos);
        if self.time_lag && at.lag_key(eval.reach) > at.front {
            stats.lag_violations += 1;
        }
        let merged = priority::merged_data(&band.store, at.config, patch, gone, keep, pos);
        let store = &mut band.store;
        let tris = store
            .vertex(gone)
            .map(|v| v.tris.clone())
            .unwrap_or_default();
        for t in tris {
            if store.tri(t).contains(keep) {
                band.guard.remove(t);
                let removed = store.remove_triangle(t);
                stats.faces_unmodifiable -= usize::from(removed.unmodifiable > 0);
            } else {
                let tri = store.tri_mut(t);
                for id in &mut tri.v {
                    if *id == gone {
                        *id = keep;
                    }
                }
                if let Some(k) = store.vertex_mut(keep) {
                    k.tris.push(t);
                }
            }
        }
        let patch_reach = match (store.extra(gone), store.extra(keep)) {
            (Some(eg), Some(ek)) => {
                let length = (store.pos(gone) - store.pos(keep)).length();
                Some(ek.merged_patch(eg, length, self.evaluator.rank_spacing))
            }
            _ => None,
        };
        let Some(g) = store.remove_vertex(gone) else {
            return;
        };
        if let Some(e) = store.extra_mut(keep) {
            if let Some((height, rad)) = patch_reach {
                (e.height, e.rad) = (height, rad);
            }
            e.attr_quadric = merged.attr_quadric;
        }
        store.set_attrs(keep, merged.attrs);
        let Some(k) = store.vertex_mut(keep) else {
            return;
        };
        k.quadric += g.quadric;
        k.area += g.area;
        k.boundary |= g.boundary;
        let rank_moved = g.rank_max > k.rank_max;
        k.rank_max = k.rank_max.max(g.rank_max);
        k.rank_min = k.rank_min.min(g.rank_min);
        let rank = k.rank_max;
        store.set_pos(keep, pos);
        store.bump_stamp(keep);
        if rank_moved {
            band.file(rank, keep);
        }
        stats.contractions += 1;
        stats.max_cost = stats.max_cost.max(eval.cost);
        stats.max_shape_error = stats.max_shape_error.max(eval.shape_error);
        let store = &band.store;
        if let Some(k) = store.vertex(keep) {
            band.guard.warm(&k.tris);
            for &t in &k.tris {
                let tri = store.tri(t);
                band.guard.update(t, tri.v, store.corners(tri));
            }
        }
        let ring = topology::ring(store, keep);
        if matches!(at.config.priority, Priority::DataDependent { .. }) {
            data_dependent::forget(store, keep, &ring);
        }
        self.push_ring_edges(store, at, keep, &ring, |_| true);
    }
}

/// The front the extraction must reach before contracting to `pos` is safe from the triangles
/// still to come, when that is beyond the current front: the key (`Sweep::key_of`) of the
/// corners of the new fan and of the `patch` it replaces (the fan lies in the convex hull of
/// its corners; see [`crate::Sweep`]).
fn beyond_front(at: &At, patch: &Patch, pos: DVec3) -> Option<f64> {
    // Past the end of the volume nothing is beyond the front, and the final decimation need not
    // key every patch's corners (3 % of bonsai's at R = 0.01).
    if at.front == f64::INFINITY {
        return None;
    }
    let sweep = at.config.sweep?;
    let corners = patch.tris.iter().flat_map(|pt| pt.p);
    let points = std::iter::once(pos).chain(corners);
    let far = match at.config.cascade {
        Cascade::Second => sweep.key_inside(points),
        _ => sweep.key_of(points),
    }?;
    (far > at.front).then_some(far)
}

/// A cascade's first stage never places a vertex below the rear it announced (`cascade`): the
/// second stage edits the surface up to that plane. Nor more than [`PREIMAGE_SLACK`] ranks below
/// the lowest rank of the new vertex's preimage: the rear is the lowest vertex the first stage
/// holds, retired ones included (they stay until their last triangle is written), and quadric
/// optima far outside their preimage (10 slabs below it, on bonsai upsampled to 511^3) kept it
/// 15 to 20 slabs behind the front, where the second stage held everything above it as its
/// front.
fn outside_first_stage_room(store: &Store, at: &At, a: u64, b: u64, pos: DVec3) -> bool {
    if at.config.cascade != Cascade::First {
        return false;
    }
    let Some(sweep) = at.config.sweep else {
        return false;
    };
    let rank = sweep.rank_of(pos);
    let preimage = [a, b]
        .iter()
        .filter_map(|&x| store.vertex(x))
        .map(|v| v.rank_min)
        .min();
    rank < f64::from(at.rear.slabs)
        || preimage.is_some_and(|low| rank < f64::from(low) - PREIMAGE_SLACK)
}

/// With rows, a cascade's first stage also keeps each triangle of a new fan clear of its rear
/// (`Sweep::clear_of`): its ring vertices are each clear of it through their own triangles,
/// but a fan triangle joining a corner beyond the rear's rows to one above its next slab may
/// cut through the rows the second stage edits. (Without rows the rear is a plane, and the new
/// vertex at or above it, `outside_first_stage_room`, is enough.)
fn crosses_rear(at: &At, patch: &Patch, a: u64, b: u64, pos: DVec3) -> bool {
    if at.config.cascade != Cascade::First {
        return false;
    }
    let Some(sweep) = at.config.sweep.filter(|w| w.rows.is_some()) else {
        return false;
    };
    // Most fans lie wholly above the rear's next slab (the first stage contracts near its
    // front): one pass over the heights tells, before any fan triangle is formed.
    let corners = patch.tris.iter().flat_map(|pt| pt.p);
    let low = std::iter::once(pos)
        .chain(corners)
        .map(|p| sweep.height(p))
        .fold(f64::INFINITY, f64::min);
    if sweep.rank_at(low) >= f64::from(at.rear.slabs) + 1.0 {
        return false;
    }
    patch
        .tris
        .iter()
        .filter(|pt| !(pt.v.contains(&a) && pt.v.contains(&b)))
        .any(|pt| {
            let mut p = pt.p;
            if let Some(i) = pt.v.iter().position(|&x| x == a || x == b) {
                p[i] = pos;
            }
            !sweep.clear_of(at.rear, &p)
        })
}

/// Both endpoints unchanged since the candidate was evaluated, and still free to move.
fn is_current(store: &Store, c: &Candidate) -> bool {
    store.is_current(c.a, c.stamps[0]) && store.is_current(c.b, c.stamps[1])
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::store::Vertex;

    /// A stage in place `cascade` at rate 0.5 sweeping along z (rank = z), holding an edge from
    /// rank 5 to 6.
    fn edge(cascade: Cascade) -> (SimplifyConfig, Store, u64, u64) {
        let config = crate::tests::swept(cascade, usize::MAX);
        let mut store = Store::default();
        let a = store.insert_vertex(0, DVec3::new(0.0, 0.0, 5.5), Vertex::new(5), &[]);
        let b = store.insert_vertex(1, DVec3::new(1.0, 0.0, 6.5), Vertex::new(6), &[]);
        (config, store, a, b)
    }

    /// The first stage's rear trails its front by how far below their preimages it places
    /// vertices, so it keeps them within a slab of it; other stages place them freely.
    #[test]
    fn a_first_stage_places_no_vertex_far_below_its_preimage() {
        let at = |z| DVec3::new(0.5, 0.0, z);
        let (config, store, a, b) = edge(Cascade::First);
        let first = At {
            config: &config,
            front: 7.0,
            rear: Front::default(),
            half: None,
        };
        assert!(
            !outside_first_stage_room(&store, &first, a, b, at(4.5)),
            "a slab below"
        );
        assert!(
            outside_first_stage_room(&store, &first, a, b, at(3.5)),
            "two slabs below"
        );
        let (config, store, a, b) = edge(Cascade::Single);
        let single = At {
            config: &config,
            front: 7.0,
            rear: Front::default(),
            half: None,
        };
        assert!(!outside_first_stage_room(&store, &single, a, b, at(3.5)));
    }
    /// With rows, each triangle of a first stage's new fan stays clear of the rear: the new
    /// vertex above the rear's plane is not enough when a fan triangle reaches down into the
    /// rows the second stage may edit.
    #[test]
    fn a_first_stage_keeps_its_fans_clear_of_the_rows_of_its_rear() {
        let mut config = crate::tests::swept(Cascade::First, usize::MAX);
        config.sweep = Some(crate::sweep::tests::along_z(0.0, 1.0, Some(10)));
        // The rear: slabs 0..5 and rows up to 4 of slab 5 (ranks 5..6).
        let at = At {
            config: &config,
            front: 8.0,
            rear: Front { slabs: 5, rows: 4 },
            half: None,
        };
        let p = |x, y, z| DVec3::new(x, y, z);
        // Triangle [a, b, c]: `a` at rank 6.5 row 4.5, `b` at rank 5.5 row 6, `c` at rank 6.5
        // row 6: clear of the rear (all at row 4 or beyond).
        let mut patch = Patch::default();
        patch.tris.push(crate::topology::PatchTri {
            v: [0, 1, 2],
            p: [p(0.0, 4.5, 6.5), p(0.0, 6.0, 5.5), p(1.0, 6.0, 6.5)],
        });
        // Contracting `c` (with some `d` outside the triangle) beyond row 4 keeps it clear; to
        // row 3 of slab 5 does not, though that point is above the rear's plane (rank 5).
        assert!(!crosses_rear(&at, &patch, 2, 3, p(1.0, 6.0, 6.2)));
        assert!(crosses_rear(&at, &patch, 2, 3, p(1.0, 3.0, 5.8)));
        // Contracting `a` to row 2 above slab 5 (rank 6.2): the new vertex is clear of both
        // boxes, but its edge to `b` (rank 5.5) cuts the rows of slab 5 below 4.
        assert!(crosses_rear(&at, &patch, 0, 3, p(0.0, 2.0, 6.2)));
        // Other stages, or no rows: no such test.
        let single = crate::tests::swept(Cascade::Single, usize::MAX);
        let at_single = At {
            config: &single,
            ..at
        };
        assert!(!crosses_rear(&at_single, &patch, 2, 3, p(1.0, 3.0, 5.8)));
    }
}
