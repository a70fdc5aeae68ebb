//! A contracting stage: the detector's protocol in (vertices, triangles, "modifiable"
//! notices, or a first stage's batches), output out, and in between the one place that says
//! when to decimate and how far ([`Schedule`]), what the sweep front holds back, and how much of
//! the memory budget the stage may hold.
//!
//! Why split this way: the stage owns the policy and the sweep, the [`Decimator`] only how to
//! contract and the [`Retirer`] only how to leave, both over the stage's [`Band`], so each part
//! keeps its own state and none reaches into another's fields.

use glam::DVec3;

use crate::band::Band;
use crate::cost::Evaluator;
use crate::decimate::{At, Decimator, Until};
use crate::policy::{FaceCounts, HEDGE_BUDGET_SHARE, Schedule};
use crate::quadric::Quadric;
use crate::retire::Retirer;
use crate::seam::{self, Cut, Join};
use crate::store::{Store, Tri, Vertex};
use crate::sweep::Key;
use crate::{
    Cascade, Front, Handoff, Interrupted, OutBatch, OutElement, Policy, SimplifyConfig,
    SimplifyStats, Sweep, cascade, priority, topology,
};

/// A cascade's second stage keeps at least `1 / SECOND_STAGE_FLOOR` of the shared budget
/// however much the first holds (see [`Stage::budget`]).
const SECOND_STAGE_FLOOR: usize = 3;

/// Whatever the sweep front holds, `1 / FRONT_ROOM_SHARE` of the face budget stays for the
/// surface behind it (see [`Stage::budget`]).
const FRONT_ROOM_SHARE: usize = 2;

/// A boundary quadric's weight per squared edge length ([`crate::Boundary::Planar`]). The
/// boundary's edges keep their full-resolution lengths in the sum while faces grow, so with 1 the
/// cut became cheap to move late in a run: engine in core at R = 0.2 had a Hausdorff distance of
/// 0.099 % of the diagonal against 0.061 % with the exact rule. 10 brings it to 0.063 %, and at
/// R = 0.01 it is also closer than 1 (stent: RMS 0.50 -> 0.42 %, Hausdorff 6.8 -> 4.8 %;
/// engine Hausdorff 0.90 -> 0.83 %); 100 keeps 1.7x the boundary edges for no better RMS.
const BOUNDARY_WEIGHT: f64 = 10.0;

/// Slabs behind the front that retirement for memory leaves resident (see
/// [`Stage::retire_for_memory`]): the front's own slab is modifiable only as far as its rows
/// are extracted (`crate::Front`), and the one behind it is partly held back by the front (its
/// vertices' stars reach into the front's slab).
const BAND_SLABS: u32 = 2;

/// The corners of the triangles held in `store` that can hold a rear back
/// ([`cascade::rear_of`]): those of the vertices below the plane one slab above the lowest
/// vertex (each once per such corner). The others lie at or beyond that plane and count for
/// neither the rear's slabs nor its rows; reading only these keeps the hand-off's cost with the
/// few vertices near the rear (every held triangle read at every hand-off made the engine's
/// bench job 5 % slower). A vertex without triangles is a lowest like the others: that can
/// only lower the rear.
fn low_triangles(store: &Store, sweep: &Sweep) -> Vec<[DVec3; 3]> {
    // Positions only for the lowest (a vertex without triangles, if any, only lowers the rear):
    // they are read at every hand-off, and a vertex's record is many times larger.
    let low = store
        .positions()
        .map(|(_, p)| sweep.rank_of(p))
        .fold(f64::INFINITY, f64::min);
    let plane = low.floor() + 1.0;
    store
        .positions()
        .filter(|&(_, p)| sweep.rank_of(p) < plane)
        .flat_map(|(id, _)| store.tris_of(id))
        .map(|&t| store.corners(store.tri(t)))
        .collect()
}

#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct Stage {
    config: SimplifyConfig,
    schedule: Schedule,
    band: Band,
    /// `None` for policy `none` (in core): nothing is contracted, so no quadric, no guard, no
    /// candidates.
    decimator: Option<Decimator>,
    retirer: Retirer,
    /// Modifiable by the detector's word but beyond the front, by the key of their star
    /// (`set_modifiable`; [`Key`]).
    beyond_front: std::collections::BinaryHeap<std::cmp::Reverse<(Key, u64)>>,
    /// The front's key (`Sweep::front_key`: its rank, or with rows its rank and rows), `+inf`
    /// after `finish`. Its floor is the number of whole slabs.
    front: f64,
    /// First stage of a cascade: the rear announced last (its triangles stay clear of it).
    rear: Front,
    /// Second stage of a cascade: the faces the first stage held at its last hand-off.
    first_resident: usize,
    /// First stage of a cascade: the front's whole slabs at its last catch-up
    /// ([`Stage::catch_up_due`]).
    caught_up: u32,
    stats: SimplifyStats,
}

impl Stage {
    /// A stage for `config`, validated by [`crate::Simplifier::new`].
    pub(crate) fn new(config: SimplifyConfig) -> Self {
        // The Tandem time-lag and the two other priorities keep per-vertex state the default
        // job does not (`store::Extra`).
        let extras = config.policy.time_lag() || config.priority != crate::Priority::Geometric;
        let decimator = config.policy.objective().map(|objective| {
            let evaluator = Evaluator::new(
                objective,
                config.priority.clone(),
                (config.boundary, config.domain),
                config.sweep.map_or(1.0, |w| w.spacing),
            );
            Decimator::new(&config, evaluator)
        });
        Self {
            schedule: config.policy.schedule(),
            retirer: Retirer::new(config.cascade),
            decimator,
            config,
            band: Band::new(extras),
            beyond_front: std::collections::BinaryHeap::new(),
            front: 0.0,
            rear: Front::default(),
            first_resident: 0,
            caught_up: 0,
            stats: SimplifyStats::default(),
        }
    }

    pub(crate) fn config(&self) -> &SimplifyConfig {
        &self.config
    }

    /// In-core mode only: the resident face count once it exceeds `max_resident_faces`.
    pub(crate) fn in_core_overflow(&self) -> Option<usize> {
        let resident = self.band.resident();
        (self.config.in_core && resident > self.config.max_resident_faces).then_some(resident)
    }

    /// See [`crate::Simplifier::add_vertex`].
    pub(crate) fn add_vertex(&mut self, id: u64, pos: DVec3, rank: u32, attrs: &[f32]) {
        let (pos, values) = crate::vertex_input(pos, attrs, self.config.attributes);
        self.stats.vertices_in += 1;
        let slot = self
            .band
            .store
            .insert_vertex(id, pos, Vertex::new(rank), &values);
        self.band.file(rank, slot);
    }

    /// See [`crate::Simplifier::add_triangle`].
    pub(crate) fn add_triangle(&mut self, ids: [u64; 3]) {
        let store = &mut self.band.store;
        let v = ids.map(|id| {
            store
                .slot_of(id)
                .unwrap_or_else(|| panic!("triangle {ids:?} uses unknown or retired vertex {id}"))
        });
        let mut unmodifiable = 0;
        for slot in v {
            if store.vertex(slot).is_some() {
                unmodifiable += u8::from(!store.is_modifiable(slot));
            }
        }
        // Without an objective (policy `none`) nothing is ever contracted: no quadric, no
        // obstacle for the guard (half of a pass-through run's time went into them).
        let contracting = self.decimator.is_some();
        // A cascade's second stage receives its vertices' quadrics with them.
        let quadrics = contracting && self.config.cascade != Cascade::Second;
        let p = v.map(|id| store.pos(id));
        let cross = (p[1] - p[0]).cross(p[2] - p[0]);
        let len = cross.length();
        if quadrics && len > 0.0 {
            let n = cross / len;
            let area = 0.5 * len;
            let q = Quadric::plane(n, -n.dot(p[0]), area);
            for id in v {
                if let Some(x) = store.vertex_mut(id) {
                    x.quadric += q;
                    x.area += area;
                }
            }
        }
        let t = store.add_triangle(Tri { v, unmodifiable });
        if contracting {
            priority::add_attribute_quadric(store, &self.config.priority, v);
            self.band.guard.insert(t, v, p);
        }
        self.stats.faces_in += 1;
        self.stats.faces_unmodifiable += usize::from(unmodifiable > 0);
        self.note_resident();
    }

    /// See [`crate::Simplifier::set_modifiable`]. A vertex becomes modifiable only once the
    /// front has passed its whole star (see [`Stage::star_reach`]), in every stage.
    pub(crate) fn set_modifiable(&mut self, id: u64) {
        let store = &mut self.band.store;
        let Some(slot) = store.slot_of(id) else {
            return;
        };
        store.forget_id(id);
        let Some(rank_max) = store.vertex(slot).map(|v| v.rank_max) else {
            return;
        };
        if store.is_modifiable(slot) {
            return;
        }
        if let Some(sweep) = &self.config.sweep {
            let reach = self.star_reach(sweep, slot, rank_max);
            if reach > self.front {
                self.beyond_front
                    .push(std::cmp::Reverse((Key::of(reach), slot)));
                return;
            }
        }
        self.make_modifiable(slot);
    }

    /// The rank the front must reach before any contraction at `slot` can be made: the ceiling
    /// of the highest corner of its star (a first or single stage also waits, as it always did,
    /// for the highest rank of the vertex's preimage; a cascade's second stage takes the open
    /// key, `Sweep::key_inside`, as its fans do). Any contraction whose patch holds a corner
    /// beyond the front waits for it (`decimate::beyond_front`), so a vertex let in earlier
    /// could not contract, yet:
    /// - its faces counted as modifiable, so the rate target squeezed the others to make up
    ///   for them (a cascade's second stage, which holds about ten slabs of the first stage's
    ///   output beyond its front);
    /// - its candidates were queued, evaluated and gathered only to be delayed, again after
    ///   every contraction next to it: a first or single stage sees that where a slab arrives in
    ///   several batches (the extraction's chunks of large slices), the front moves only at the
    ///   slab's end, and the vertices on the slab's lower plane are let in while their stars
    ///   reach into the slab (bonsai upsampled to 511^3, one stage: 3.18 M delays for 1.73 M
    ///   contractions, 38.3 s, against 13 k and 34.4 s gated by the star; hydrogen at 4033^3:
    ///   17.97 M delays for 18.95 M contractions).
    ///
    /// With rows (`Sweep::rows`) that is the star's key (`Sweep::key_of`): a vertex of a slab
    /// crowded by a flat face across the sweep moves as soon as the rows past its star are
    /// extracted, not when the whole slab is. (The preimage's rank adds nothing there: the
    /// detector's vertices are their own preimage, a corner of their star.)
    fn star_reach(&self, sweep: &Sweep, slot: u64, rank_max: u32) -> f64 {
        let store = &self.band.store;
        let corners = store
            .tris_of(slot)
            .iter()
            .flat_map(|&t| store.corners(store.tri(t)));
        // A cascade's second stage keys its fans strictly inside the complete region
        // (`decimate::beyond_front`), so its stars are let in by the same key: by the closed one,
        // a vertex on the rear's plane was let in a slab before any contraction over it could run.
        if self.config.cascade == Cascade::Second {
            return sweep.key_inside(corners).unwrap_or(0.0);
        }
        if sweep.rows.is_some() {
            return sweep.key_of(corners).unwrap_or(0.0);
        }
        let far = corners.map(|p| sweep.rank_of(p)).fold(0.0, f64::max);
        far.ceil()
            .clamp(0.0, f64::from(u32::MAX))
            .max(f64::from(rank_max))
    }

    /// The vertices held by [`Stage::set_modifiable`] that the front has reached.
    fn release_reached(&mut self) {
        while let Some(&std::cmp::Reverse((key, id))) = self.beyond_front.peek() {
            if key.value() > self.front {
                break;
            }
            self.beyond_front.pop();
            self.make_modifiable(id);
        }
    }

    fn make_modifiable(&mut self, id: u64) {
        let store = &self.band.store;
        if store.vertex(id).is_none() || store.is_modifiable(id) {
            return;
        }
        // One ring for the boundary test and the new candidates: nothing changes it between
        // (and neither is needed when nothing is contracted).
        let ring = if self.decimator.is_some() {
            topology::ring(store, id)
        } else {
            topology::Ring::new()
        };
        let boundary = topology::is_boundary(&ring);
        if boundary {
            self.add_boundary_quadrics(id, &ring);
        }
        let store = &mut self.band.store;
        store.set_modifiable(id);
        let Some(v) = store.vertex_mut(id) else {
            return;
        };
        v.boundary = boundary;
        let tris = v.tris.clone();
        for t in tris {
            let tri = store.tri_mut(t);
            tri.unmodifiable -= 1;
            if tri.unmodifiable == 0 {
                self.stats.faces_unmodifiable -= 1;
            }
        }
        self.with_decimator(|d, band, at, _| {
            d.push_ring_edges(&band.store, at, id, &ring, |_| true);
        });
    }

    /// With [`crate::Boundary::Planar`], the boundary quadric of each boundary edge of `id` (its
    /// fan complete, with `ring`) is added to `id`; the other end adds its own when its fan
    /// completes, so each edge counts once at each end, like a face. A cascade's second stage
    /// receives the quadrics with the vertices, as for faces.
    fn add_boundary_quadrics(&mut self, id: u64, ring: &topology::Ring) {
        if self.decimator.is_none()
            || self.config.cascade == Cascade::Second
            || !self.config.boundary.is_planar()
        {
            return;
        }
        let store = &self.band.store;
        let Some(v) = store.vertex(id) else {
            return;
        };
        let pv = store.pos(id);
        let mut q = Quadric::default();
        for &(x, _) in ring.iter().filter(|&&(_, n)| n == 1) {
            let Some(t) = v.tris.iter().map(|&t| store.tri(t)).find(|t| t.contains(x)) else {
                continue;
            };
            let p = store.corners(t);
            let edge = store.pos(x) - pv;
            let normal = (p[1] - p[0]).cross(p[2] - p[0]);
            let m = edge.cross(normal).normalize_or_zero();
            if m != DVec3::ZERO {
                q += Quadric::plane(m, -m.dot(pv), BOUNDARY_WEIGHT * edge.length_squared());
            }
        }
        if let Some(v) = self.band.store.vertex_mut(id) {
            v.quadric += q;
        }
    }

    /// See [`crate::Simplifier::end_batch_with`]. Interrupted, it returns as soon as the pass
    /// sees it, before anything is retired or handed off.
    pub(crate) fn end_batch(
        &mut self,
        front: Front,
        out: &mut OutBatch,
        interrupt: &dyn Fn() -> bool,
    ) -> Result<(), Interrupted> {
        let slabs = front.slabs;
        self.front = self
            .config
            .sweep
            .map_or(f64::from(slabs), |w| w.front_key(front));
        self.release_reached();
        if self.config.in_core {
            return Ok(());
        }
        if let Some(d) = &mut self.decimator {
            d.activate(self.front);
        }
        let counts = self.face_counts();
        let budget = self.budget();
        self.stats.peak_front_faces = self.stats.peak_front_faces.max(counts.unmodifiable);
        self.note_stretch(budget);
        // Over the memory budget, a pass runs before anything is retired for it, so that what
        // leaves has been decimated (a huge `batch` otherwise emitted raw faces). It stops where
        // the budget has room again (`RateSchedule::kept`), unless that is still over it: then
        // faces must leave, and it goes on to the rate target first (without the initial phase:
        // `RateSchedule::standard_target`), so that they leave at about the density the whole
        // output will have (a little more, `policy::HEDGE`, which the end takes back).
        // A cascade's first stage whose rear lags runs a pass too, once per slab of the front,
        // so that what it then writes has been offered to the heap (`Stage::catch_up_due`).
        let catching_up = self.config.cascade == Cascade::First && slabs > self.caught_up;
        let lagging = catching_up && self.rear < self.catch_up_target();
        let mut squeeze = None;
        let until = match &mut self.schedule {
            Schedule::Off => None,
            Schedule::Rate(rate) => {
                (rate.due(counts.generated) || counts.resident > budget || lagging).then(|| {
                    let target = rate.resident_target(counts);
                    squeeze = Some(Until::Resident(rate.standard_target(counts)));
                    Until::Resident(target.max(rate.kept(budget)))
                })
            }
            Schedule::Threshold => Some(Until::Exhausted),
        };
        if let Some(until) = until {
            self.decimate(until, interrupt)?;
        }
        if let Some(squeeze) = squeeze
            && self.band.resident() > budget
        {
            self.decimate(squeeze, interrupt)?;
        }
        // Rate: the simplified surface stays resident, as in Hou and Chen 4.3 (R F + B faces),
        // and leaves only when the memory budget says so, oldest first (see `retire`). Other
        // policies retire `retire_lag` slabs behind the front, after a decimation pass, so that
        // no vertex leaves without having been offered to the heap.
        if self.config.lag_retirement()
            && (until.is_some() || matches!(self.schedule, Schedule::Off))
        {
            let limit = slabs.saturating_sub(self.config.retire_lag);
            self.retirer
                .retire_below(&mut self.band, limit, out, &mut self.stats);
        }
        self.retire_for_memory(out);
        if catching_up {
            if until.is_some() {
                let due = self.catch_up_due();
                self.retirer
                    .retire_vertices(&mut self.band, due, out, &mut self.stats);
            }
            self.caught_up = slabs;
        }
        if let Some(d) = &mut self.decimator {
            d.compact(&self.band);
        }
        self.hand_off(out, false);
        Ok(())
    }

    fn decimate(&mut self, until: Until, interrupt: &dyn Fn() -> bool) -> Result<(), Interrupted> {
        self.with_decimator(|d, band, at, stats| d.decimate(band, at, stats, until, interrupt))
            .unwrap_or(Ok(()))
    }

    /// The first part of the final decimation on two workers either side of a cut (`seam`),
    /// when `join` finds it worth it and the budget has room for the second worker's copies:
    /// this stage's band is the lower side's, a band split from it the upper's. They contract
    /// in rounds up to a rising cost ([`seam::ROUND_FACTOR`]), as one queue would, until the
    /// surface holds the plan's goal; the merged surface then gets one queue again for the rest.
    ///
    /// `interrupt` is asked between the steps over the whole surface (each a pass over millions
    /// of faces in core) and by both workers as they contract. Interrupted, it returns at once:
    /// the sides are not merged back (that too is a pass over the surface, and the caller only
    /// drops the simplifier then).
    fn decimate_in_halves(
        &mut self,
        target: usize,
        join: &dyn Join,
        interrupt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), Interrupted> {
        let held = self.band.resident();
        // The second worker copies the triangles and slots and refiles half of the guard's
        // records: about half again of what the surface takes (in core, engine at R = 0.01:
        // 243.5 -> 296.1 MiB peak).
        if !join.worth_cutting(held) || held.saturating_add(held / 2) > self.budget() {
            return Ok(());
        }
        let Some(d) = &mut self.decimator else {
            return Ok(());
        };
        let Some((cut, goal)) = Cut::plan(&self.band.store, target) else {
            return Ok(());
        };
        crate::asked(interrupt)?;
        self.stats.cut_faces = held;
        let mut upper_band = cut.split(&mut self.band);
        crate::asked(interrupt)?;
        d.drop_stale(&self.band);
        let mut upper = d.fresh();
        let mut upper_stats = SimplifyStats::default();
        let at = |half| At {
            config: &self.config,
            front: self.front,
            rear: self.rear,
            half: Some(half),
        };
        let (lower_at, upper_at) = (at(cut.lower()), at(cut.upper()));
        upper.requeue_all(&upper_band, &upper_at, interrupt)?;
        let mut cost = f64::NEG_INFINITY;
        loop {
            let held = [self.band.resident(), upper_band.resident()];
            let excess = (held[0] + held[1]).saturating_sub(goal);
            let cheapest = [d.cheapest(), upper.cheapest()];
            let Some(next) = cheapest.into_iter().flatten().min_by(f64::total_cmp) else {
                break;
            };
            if excess == 0 {
                break;
            }
            cost = (cost * seam::ROUND_FACTOR).max(next);
            // Each side may take half of what is left to take in this round, so that the last
            // round cannot take the pair far below the goal.
            let until = |h: usize| Until::Cheaper {
                cost,
                resident: h.saturating_sub(excess.div_ceil(2)),
            };
            let (lower_until, upper_until) = (until(held[0]), until(held[1]));
            let (band, stats) = (&mut self.band, &mut self.stats);
            let (mut lower_done, mut upper_done) = (Ok(()), Ok(()));
            join.join(
                &mut || lower_done = d.decimate(band, &lower_at, stats, lower_until, interrupt),
                &mut || {
                    upper_done = upper.decimate(
                        &mut upper_band,
                        &upper_at,
                        &mut upper_stats,
                        upper_until,
                        interrupt,
                    );
                },
            );
            lower_done.and(upper_done)?;
        }
        cut.merge(&mut self.band, upper_band);
        self.stats.add_worker(&upper_stats);
        crate::asked(interrupt)?;
        self.with_decimator(|d, band, at, _| {
            *d = d.fresh();
            d.requeue_all(band, at, interrupt)
        })
        .unwrap_or(Ok(()))
    }

    /// Runs `f` on the decimator (if anything contracts) with the band, where the stage stands
    /// and the counters; `None` when nothing contracts.
    fn with_decimator<T>(
        &mut self,
        f: impl FnOnce(&mut Decimator, &mut Band, &At, &mut SimplifyStats) -> T,
    ) -> Option<T> {
        let at = At {
            config: &self.config,
            front: self.front,
            rear: self.rear,
            half: None,
        };
        let d = self.decimator.as_mut()?;
        Some(f(d, &mut self.band, &at, &mut self.stats))
    }

    /// Over the memory budget: retires the oldest vertices until resident faces are at most 90%
    /// of it (or nothing is left to retire). The last [`BAND_SLABS`] slabs behind the front stay
    /// (but in a cascade's first stage, which hands them on): their contractions mostly wait
    /// for the front to pass, and retiring them wrote them undecimated; the budget is then
    /// exceeded by what they hold, which the run summary reports (`front_stretch_faces`).
    fn retire_for_memory(&mut self, out: &mut OutBatch) {
        let budget = self.budget();
        if self.band.resident() <= budget {
            return;
        }
        let limit = if self.holds_its_front() {
            (self.front.min(f64::from(u32::MAX)) as u32).saturating_sub(BAND_SLABS)
        } else {
            u32::MAX
        };
        self.retirer.retire_until(
            &mut self.band,
            budget - budget / 10,
            limit,
            out,
            &mut self.stats,
        );
        if self.holds_its_front() {
            self.note_stretch(self.band.resident());
        }
    }

    /// First stage of a cascade: announces the rear (see `cascade`) with the batch, raised to
    /// what its held triangles allow, at most its front (after the catch-up has written what
    /// held it back, [`Stage::catch_up_due`]). The rear only rises: every triangle held is
    /// clear of the last one announced, and so is every triangle still to come (extracted ones
    /// lie beyond the front; contractions whose new fan is not clear of it are refused,
    /// `decimate::crosses_rear`).
    fn hand_off(&mut self, out: &mut OutBatch, end: bool) {
        if self.config.cascade != Cascade::First {
            return;
        }
        if end {
            self.rear = Front::from(u32::MAX);
        } else if let Some(sweep) = self.config.sweep {
            let store = &self.band.store;
            let held = cascade::rear_of(&sweep, low_triangles(store, &sweep).into_iter());
            let next = sweep.front_at(self.front);
            self.rear = self.rear.max(held.map_or(next, |h| h.min(next)));
        }
        let rate = match self.config.policy {
            Policy::Rate { rate, .. } => rate,
            _ => 1.0,
        };
        out.handoff = Some(Handoff {
            rear: self.rear,
            rate,
            faces_in: self.stats.faces_in,
            faces_out: self.stats.faces_out,
            faces_resident: self.band.resident() as u64,
        });
    }

    /// First stage of a cascade: the front `retire_lag - 1` slabs behind its front (2 at the
    /// default lag; more where the pipeline deepened the lag for thin slabs), which the
    /// catch-up keeps its rear at or above ([`Stage::catch_up_due`]); the origin elsewhere.
    ///
    /// The rear announced last is exactly what the triangles held then allowed (or the front
    /// then), and what came since lies beyond that front: so the rear lags behind this target
    /// exactly when some triangle held is not clear of it (unless the front has moved more
    /// than that since, over empty slabs: then a pass runs that finds nothing to
    /// write). Asking this instead of scanning for such triangles removes one of the
    /// catch-up's two scans per slab.
    fn catch_up_target(&self) -> Front {
        let key = self.front - f64::from(self.config.retire_lag.saturating_sub(1).max(1));
        match self.config.sweep {
            Some(sweep)
                if self.config.cascade == Cascade::First && key > 0.0 && key.is_finite() =>
            {
                sweep.front_at(key)
            }
            _ => Front::default(),
        }
    }

    /// First stage of a cascade: the vertices of every triangle held that is not clear of
    /// [`Stage::catch_up_target`] (empty elsewhere), each once, in the order found. They are
    /// retired after the pass of the first batch of each slab of the front (a pass runs then
    /// when the rear lags behind the target), so that the rear follows the front. Vertices not
    /// modifiable yet are deferred by the retirer as always.
    ///
    /// The rear is held by the lowest triangle the first stage still holds: one whose other
    /// corners are young (a vertex contracted up the sweep, or not retired by the lag yet) kept
    /// it 5 to 6 slabs behind the front on bonsai upsampled to 511^3 while retirement by memory
    /// had written nearly everything below 3, and the second stage holds what the first wrote
    /// above the rear, unmodifiable (its front: 41 k faces there, 12 k of them past its
    /// budget). Where no face came (above the surface's top) no pass was due, nothing retired,
    /// and the first stage kept its last slabs to the end: engine upsampled to 511 x 511 x 255
    /// held the 10.8 k faces of its crowded slab for the 40 slabs above it.
    fn catch_up_due(&self) -> Vec<u64> {
        let target = self.catch_up_target();
        // Every triangle held is clear of the rear announced last, and so of any front below
        // it: nothing to scan.
        let Some(sweep) = self.config.sweep.filter(|_| self.rear < target) else {
            return Vec::new();
        };
        let store = &self.band.store;
        let plane = f64::from(target.slabs);
        let mut seen = rustc_hash::FxHashSet::default();
        let mut due = Vec::new();
        for (id, pos) in store.positions() {
            let rank = sweep.rank_of(pos);
            if rank >= plane + 1.0 {
                continue;
            }
            // A corner below the target's plane, or in its next slab short of its rows, keeps
            // every triangle of its star from being clear of the target (`Sweep::clear_of`):
            // their corners need not be read. (Reading every corner of the stars behind the
            // target put `catch_up_due` and its reads at about 7 % of the first stage's samples
            // on bonsai at R = 0.2.)
            let all = rank < plane
                || sweep
                    .row_of(pos)
                    .is_some_and(|r| r < f64::from(target.rows));
            for &t in store.tris_of(id) {
                let tri = store.tri(t);
                if all || !sweep.clear_of(target, &store.corners(tri)) {
                    due.extend(
                        tri.v
                            .iter()
                            .filter(|&&x| !store.is_retired(x) && seen.insert(x)),
                    );
                }
            }
        }
        due
    }

    /// See [`crate::Simplifier::ingest`].
    pub(crate) fn ingest(&mut self, batch: &OutBatch) -> Front {
        assert_eq!(
            self.config.cascade,
            Cascade::Second,
            "ingest is for a second stage"
        );
        let handoff = batch
            .handoff
            .expect("a first stage's batch carries its handoff");
        let stride = self.config.attributes;
        let mut states = batch.states.iter();
        let mut attrs = batch.attrs.chunks(stride.max(1));
        for e in &batch.elements {
            match *e {
                OutElement::Vertex { pos } => {
                    // The first stage numbers its output 0, 1, 2, ...: those numbers are the ids.
                    let id = self.stats.vertices_in;
                    let state = *states.next().expect("a state per vertex");
                    let values = if stride == 0 {
                        &[][..]
                    } else {
                        attrs.next().unwrap_or(&[])
                    };
                    self.add_vertex(id, pos, state.rank_max, values);
                    let store = &mut self.band.store;
                    if let Some(slot) = store.slot_of(id)
                        && let Some(v) = store.vertex_mut(slot)
                    {
                        v.quadric = state.quadric;
                        v.area = state.area;
                        v.rank_min = state.rank_min;
                    }
                }
                OutElement::Triangle { v, last_use } => {
                    self.add_triangle(v);
                    for (id, last) in v.into_iter().zip(last_use) {
                        if last {
                            self.set_modifiable(id);
                        }
                    }
                }
            }
        }
        if let Schedule::Rate(rate) = &mut self.schedule {
            rate.set_source_ratio(handoff.ratio());
        }
        self.first_resident = usize::try_from(handoff.faces_resident).unwrap_or(usize::MAX);
        handoff.rear
    }

    /// The resident faces this stage may hold before it decimates and retires for memory.
    /// A cascade's second stage has what the first does not hold of the budget of both
    /// (`max_resident_faces`) at its last hand-off, and at least `1 / SECOND_STAGE_FLOOR` of it:
    /// the first stage's unfinished band is as large as the extraction's slabs make it (engine:
    /// 35 k faces), and a fixed split either starved the second stage on dense slabs or left room
    /// unused on sparse ones (bonsai's first stage peaks at 13 k faces).
    ///
    /// The sweep front's faces (not modifiable yet) cannot leave, so where they take more than
    /// half of it the budget stretches to hold them and still `1 / FRONT_ROOM_SHARE` of it
    /// behind them: on slices large against the budget (bonsai upsampled to 2041^3, about 33 k
    /// faces a slab against 43.7 k) the front alone filled it, every face that became
    /// modifiable was retired before it could be contracted, and the job wrote 9 of its first 22
    /// M faces unsimplified. Memory then follows the front, as the mission says (`[pipeline]
    /// memory_budget_mib` bounds the rest; the run summary says by how much it stretched). Since
    /// the front moves by rows within a slab (`crate::Front`) it holds a few groups of rows and
    /// seldom stretches anything (that job: by 700 faces, against about 50 k with whole slabs).
    /// A cascade's first stage holds its share plus its band by design (its band is counted in
    /// the second stage's share), so it does not stretch.
    pub(crate) fn budget(&self) -> usize {
        let share = self.share();
        if self.holds_its_front() {
            share.max(self.stats.faces_unmodifiable + share / FRONT_ROOM_SHARE)
        } else {
            share
        }
    }

    /// Whether the sweep front's faces stay resident beyond the budget (see
    /// [`Stage::budget`] and [`Stage::retire_for_memory`]): all but a cascade's first stage,
    /// which hands its band on to the second.
    fn holds_its_front(&self) -> bool {
        self.config.cascade != Cascade::First
    }

    /// Records `resident` faces held against this stage's share (the run summary's
    /// `front_stretch_faces`).
    fn note_stretch(&mut self, resident: usize) {
        let over = resident.saturating_sub(self.share());
        self.stats.front_stretch_faces = self.stats.front_stretch_faces.max(over);
    }

    /// This stage's part of the job's face budget (see [`Stage::budget`]).
    fn share(&self) -> usize {
        let total = self.config.max_resident_faces;
        match self.config.cascade {
            Cascade::Second => total
                .saturating_sub(self.first_resident)
                .max(total / SECOND_STAGE_FLOOR),
            _ => total,
        }
    }

    /// See [`crate::Simplifier::finish_with`]. `interrupt` is asked first (a cancel raised as
    /// the sweep ended is seen even where nothing is left to contract), then as the final
    /// decimation goes; interrupted, it returns at once, before anything is retired.
    pub(crate) fn finish(
        &mut self,
        out: &mut OutBatch,
        join: &dyn Join,
        interrupt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), Interrupted> {
        crate::asked(interrupt)?;
        self.front = f64::INFINITY;
        self.release_reached();
        self.band.store.forget_all_ids();
        let pending: Vec<u64> = self.band.store.ids().collect();
        for id in pending {
            self.make_modifiable(id);
        }
        if let Some(d) = &mut self.decimator {
            d.activate(self.front);
        }
        let until = match &self.schedule {
            Schedule::Off => None,
            Schedule::Rate(rate) => Some(Until::Resident(rate.final_target(self.face_counts()))),
            Schedule::Threshold => Some(Until::Exhausted),
        };
        if let Some(until) = until {
            if let Until::Resident(target) = until {
                self.decimate_in_halves(target, join, interrupt)?;
            }
            self.decimate(until, interrupt)?;
            // Edges refused earlier (link, flips) may pass now that their neighbourhoods changed.
            if !until.reached(&self.band) {
                self.with_decimator(|d, band, at, _| d.requeue_all(band, at, interrupt))
                    .unwrap_or(Ok(()))?;
                self.decimate(until, interrupt)?;
            }
        }
        self.retirer
            .retire_below(&mut self.band, u32::MAX, out, &mut self.stats);
        debug_assert_eq!(self.band.resident(), 0, "everything emitted");
        self.hand_off(out, true);
        Ok(())
    }

    pub(crate) fn stats(&self) -> SimplifyStats {
        SimplifyStats {
            faces_resident: self.band.resident(),
            vertices_resident: self.band.store.live_vertices(),
            candidates: self.decimator.as_ref().map_or(0, Decimator::queued),
            guard: self.band.guard.work(),
            ..self.stats.clone()
        }
    }

    fn face_counts(&self) -> FaceCounts {
        FaceCounts {
            generated: self.stats.faces_in,
            unmodifiable: self.stats.faces_unmodifiable,
            emitted: self.stats.faces_out,
            resident: self.band.resident(),
            hedge: match self.config.cascade {
                Cascade::First => 0,
                _ => (self.budget() as f64 * HEDGE_BUDGET_SHARE) as u64,
            },
        }
    }

    fn note_resident(&mut self) {
        let resident = self.band.resident();
        self.stats.peak_resident_faces = self.stats.peak_resident_faces.max(resident);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::VertexState;

    /// A cascade's second stage at rate 0.5, sweeping along z, with a budget of `faces`.
    fn second_stage(faces: usize) -> Stage {
        swept(Cascade::Second, faces)
    }

    fn swept(cascade: Cascade, faces: usize) -> Stage {
        Stage::new(crate::tests::swept(cascade, faces))
    }

    /// A stage alone at `rate` (initial rate 0.5), decimating every `batch` faces, with a budget
    /// of `faces`.
    fn rate_stage(faces: usize, rate: f64, batch: u64) -> Stage {
        Stage::new(SimplifyConfig {
            max_resident_faces: faces,
            ..SimplifyConfig::new(Policy::Rate {
                rate,
                batch,
                initial_rate: 0.5,
            })
        })
    }

    /// The faces a second stage counts unmodifiable after each rear of `rears`, for one
    /// triangle from rank 0.5 up to rank `top`.
    fn second_stage_unmodifiable(top: f64, rears: &[u32]) -> Vec<usize> {
        let mut s = second_stage(usize::MAX);
        let state = VertexState {
            quadric: Quadric::default(),
            area: 0.0,
            rank_min: 0,
            rank_max: 0,
        };
        let handoff = |rear: u32| Handoff {
            rear: Front::from(rear),
            rate: 0.5,
            faces_in: 2,
            faces_out: 1,
            faces_resident: 1,
        };
        let mut batch = OutBatch {
            elements: vec![
                OutElement::Vertex {
                    pos: DVec3::new(0.0, 0.0, 0.5),
                },
                OutElement::Vertex {
                    pos: DVec3::new(1.0, 0.0, 0.5),
                },
                OutElement::Vertex {
                    pos: DVec3::new(0.0, 1.0, top),
                },
                OutElement::Triangle {
                    v: [0, 1, 2],
                    last_use: [true; 3],
                },
            ],
            states: vec![state; 3],
            ..OutBatch::default()
        };
        let mut out = OutBatch::default();
        rears
            .iter()
            .map(|&rear| {
                batch.handoff = Some(handoff(rear));
                let rear = s.ingest(&batch);
                s.end_batch(rear, &mut out, &|| false).unwrap();
                batch = OutBatch::default();
                s.stats().faces_unmodifiable
            })
            .collect()
    }

    /// A second stage lets a vertex move only once its front (the first stage's rear) has
    /// passed its whole star: a vertex below the rear whose triangle reaches far beyond it could
    /// not contract, so its face must count as unmodifiable for the rate target.
    #[test]
    fn a_second_stage_gates_vertices_by_their_star() {
        assert_eq!(
            second_stage_unmodifiable(3.5, &[1, 4]),
            [1, 0],
            "the star reaches rank 3.5: past the rear 1, behind the rear 4"
        );
    }

    /// A second stage's fans must lie strictly inside the region its rear completes
    /// (`decimate::beyond_front` keys them with `Sweep::key_inside`), so a star with a corner on
    /// the rear's plane is let in a slab later: let in at once, its candidates were evaluated
    /// only to be delayed (bonsai at R = 0.2: 97,166 delays, 933 with the open key) and its face
    /// counted modifiable for the rate target.
    #[test]
    fn a_second_stage_lets_a_star_on_its_rear_in_a_slab_later() {
        assert_eq!(
            second_stage_unmodifiable(3.0, &[3, 4]),
            [1, 0],
            "the star's top corner lies on the rear's plane at rank 3"
        );
    }

    /// A cascade's first stage writes what holds its rear back: a low triangle (ranks 0.5 to 1)
    /// one of whose corners has a preimage reaching rank 9 (contracted from up the sweep)
    /// would be held, and the rear with it, until the lag retires that corner (front 9 + lag);
    /// it goes out as soon as the corner is modifiable (front 9), and the rear is the front.
    #[test]
    fn a_first_stage_rear_follows_its_front() {
        let mut s = swept(Cascade::First, usize::MAX);
        assert!(s.config.retire_lag >= 1);
        s.add_vertex(0, DVec3::new(0.0, 0.0, 0.5), 0, &[]);
        s.add_vertex(1, DVec3::new(1.0, 0.0, 0.5), 0, &[]);
        s.add_vertex(2, DVec3::new(0.0, 1.0, 1.0), 9, &[]);
        s.add_triangle([0, 1, 2]);
        for v in 0..3 {
            s.set_modifiable(v);
        }
        let mut rears = Vec::new();
        for front in 1..=10 {
            let mut out = OutBatch::default();
            s.end_batch(Front::from(front), &mut out, &|| false)
                .unwrap();
            rears.push(out.handoff.expect("a first stage hands off").rear.slabs);
        }
        assert_eq!(s.stats().faces_out, 1);
        assert_eq!(rears, [0, 0, 0, 0, 0, 0, 0, 0, 9, 10]);
    }

    /// A single stage too lets a vertex in only once the front has passed its whole star, not
    /// just its own rank: a vertex of the lower plane of a slab that arrives in several batches
    /// is final before the slab's other vertices are behind the front.
    #[test]
    fn a_single_stage_gates_vertices_by_their_star() {
        let mut s = swept(Cascade::Single, usize::MAX);
        s.add_vertex(0, DVec3::new(0.0, 0.0, 1.0), 1, &[]);
        s.add_vertex(1, DVec3::new(1.0, 0.0, 1.0), 1, &[]);
        s.add_vertex(2, DVec3::new(0.0, 1.0, 1.5), 2, &[]);
        s.add_vertex(3, DVec3::new(1.0, -1.0, 1.0), 1, &[]);
        s.add_triangle([0, 1, 2]);
        s.add_triangle([1, 0, 3]);
        for v in [0, 1, 3] {
            s.set_modifiable(v);
        }
        let mut out = OutBatch::default();
        s.end_batch(Front::from(1), &mut out, &|| false).unwrap();
        assert_eq!(
            s.stats().faces_unmodifiable,
            2,
            "0 and 1 are at rank 1, yet their stars reach rank 1.5, past the front 1"
        );
        s.set_modifiable(2);
        s.end_batch(Front::from(2), &mut out, &|| false).unwrap();
        assert_eq!(s.stats().faces_unmodifiable, 0);
    }

    /// A second stage's budget is the shared one less what the first stage reported resident,
    /// and never below a third of it.
    #[test]
    fn a_second_stage_budget_is_what_the_first_leaves() {
        let mut s = second_stage(900);
        assert_eq!(s.budget(), 900, "nothing reported yet");
        let handoff = |faces_resident| OutBatch {
            handoff: Some(Handoff {
                rear: Front::default(),
                rate: 0.5,
                faces_in: 0,
                faces_out: 0,
                faces_resident,
            }),
            ..OutBatch::default()
        };
        s.ingest(&handoff(200));
        assert_eq!(s.budget(), 700);
        s.ingest(&handoff(800));
        assert_eq!(s.budget(), 300, "the floor");
        let single = Stage::new(SimplifyConfig {
            max_resident_faces: 900,
            ..SimplifyConfig::new(Policy::None)
        });
        assert_eq!(single.budget(), 900);
    }

    /// Faces of the sweep front cannot leave: where they take more than half of the budget it
    /// stretches to hold them with half of it behind them, and the run summary says by how much.
    #[test]
    fn the_sweep_front_stretches_the_budget() {
        let mut s = rate_stage(10, 0.5, 1);
        // A fan of `n` triangles around vertex 0, nothing modifiable yet.
        let fan = |s: &mut Stage, n: u64| {
            s.add_vertex(0, DVec3::ZERO, 0, &[]);
            for i in 1..=n {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                s.add_vertex(i, DVec3::new(a.cos(), a.sin(), 0.0), 0, &[]);
            }
            for i in 1..=n {
                s.add_triangle([0, i, i % n + 1]);
            }
        };
        fan(&mut s, 5);
        assert_eq!(s.budget(), 10, "5 front faces are half of it");
        let mut s2 = Stage::new(s.config.clone());
        fan(&mut s2, 12);
        assert_eq!(s2.budget(), 12 + 5);
        s2.end_batch(Front::from(0), &mut OutBatch::default(), &|| false)
            .unwrap();
        assert_eq!(s2.stats().front_stretch_faces, 7);
        assert_eq!(s2.stats().peak_front_faces, 12);
    }

    /// A large front met before anything was written (the initial phase): the faces behind it
    /// that no longer fit are decimated to the rate target before any of them leaves, not
    /// written at the initial phase's density (which then left the rest of the output almost
    /// nothing: hydrogen upsampled to 2017^3).
    #[test]
    fn faces_leave_at_the_rate_target_even_in_the_initial_phase() {
        let mut s = rate_stage(100, 0.1, u64::MAX);
        // A flat 10 x 20 grid of 400 triangles behind the front, every vertex modifiable.
        let (nx, ny) = (10u64, 20u64);
        let id = |i: u64, j: u64| j * (nx + 1) + i;
        for j in 0..=ny {
            for i in 0..=nx {
                s.add_vertex(id(i, j), DVec3::new(i as f64, j as f64, 0.0), 0, &[]);
            }
        }
        for j in 0..ny {
            for i in 0..nx {
                s.add_triangle([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                s.add_triangle([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        for v in 0..id(nx, ny) + 1 {
            s.set_modifiable(v);
        }
        // A front of 150 triangles far above it, none modifiable yet.
        let centre = id(nx, ny) + 1;
        s.add_vertex(centre, DVec3::new(5.0, 10.0, 50.0), 9, &[]);
        for k in 1..=150u64 {
            let a = std::f64::consts::TAU * k as f64 / 150.0;
            s.add_vertex(
                centre + k,
                DVec3::new(5.0 + a.cos(), 10.0 + a.sin(), 50.0),
                9,
                &[],
            );
        }
        for k in 1..=150u64 {
            s.add_triangle([centre, centre + k, centre + k % 150 + 1]);
        }
        // Budget 150 + 100 / 2 = 200; the initial phase alone would keep 400 / 2 + 150 = 350,
        // the rate target (400 * 0.1 + 150 = 190, and its hedge: 5 % of 40 faces) fits.
        assert_eq!(s.budget(), 200);
        let mut out = OutBatch::default();
        s.end_batch(Front::from(9), &mut out, &|| false).unwrap();
        let written = out
            .elements
            .iter()
            .filter(|e| matches!(e, OutElement::Triangle { .. }))
            .count();
        assert_eq!(
            written, 0,
            "nothing had to leave once decimated to the target"
        );
        let target = 190 + (40.0 * crate::policy::HEDGE).ceil() as usize;
        assert!(s.band.resident() <= target, "{}", s.band.resident());
    }
}
