//! isostream-simplify: one streaming quadric edge-collapse simplifier.
//!
//! The detector feeds batches of vertices (stable, increasing `u64` ids), triangles and
//! "modifiable" notices (all triangles of the vertex exist). After each batch,
//! [`Simplifier::end_batch`] decimates as the [`Policy`] says, retires what fell behind the
//! sweep front and appends finished output in compact pre-order (see [`OutElement`]).
//!
//! Structure: [`Simplifier`] is a facade over one of two engines, chosen once from the complete
//! [`SimplifyConfig`] it is built from (validated there, once; no setter follows):
//! `passthrough` for policy `none` when streaming, and a contracting `stage` for everything
//! else. A stage owns the policy's schedule, the sweep front and the budget, and drives two
//! parts over its `band` (the resident mesh with the guard's index and the rank buckets): the
//! `decimate::Decimator` (evaluator and candidate queue: how to contract) and the
//! `retire::Retirer` (output numbering: how to leave). Each part owns its own state and borrows
//! the band; none reaches into another's fields.
//!
//! Modules, by role:
//! * `stage`: the detector's protocol, when and how far to decimate, what the front holds
//!   back, the memory budget (its share in a cascade);
//! * `sweep`: the sweep's rank planes and the front, which may move by rows within a slab
//!   ([`Sweep`], [`Front`]);
//! * `band`: the resident mesh and the two indexes that follow its every change;
//! * `quadric`: symmetric 4x4 quadrics (Garland and Heckbert 1997);
//! * `store`: the resident mesh band (vertices by `id - base`, triangle slab);
//! * `topology`: link condition, boundary rule, no-flip/no-degenerate checks;
//! * `cost`: cost and placement of one contraction: the one `Evaluator` (the mode's objective,
//!   re-ranked or re-placed by the priority; the policy hook);
//! * `policy`: the public [`Policy`] and when/how far to decimate (Hou and Chen 4.2, Tandem);
//! * `candidates`: the lazily invalidated edge queue (buckets of cost) and the time-lag queue;
//! * `decimate`: the decimator, the one contraction loop;
//! * `intersect`: spatial hash of the resident triangles; rejects contractions whose new fan
//!   would cross another sheet (thin structures, touching surfaces);
//! * `retire`: the retirer (behind the front or for the memory budget, oldest first) and
//!   emission in streaming order;
//! * `passthrough`: policy `none` when streaming: triangles leave as soon as their vertices are
//!   complete, without any of the contraction machinery.
//! * `cascade`: what two simplifiers in series exchange (vertex states, the first stage's rear)
//!   and why the pair is as safe as one.
//! * `seam`: the final decimation on two workers either side of a cut, and why their results
//!   merge exactly.
//!
//! Decisions (the why is at each item's definition):
//! * **Surface boundary** (an iso-surface's boundary is where the volume's box cuts it):
//!   boundary vertices never move off it. An interior vertex may merge into a boundary vertex's
//!   position; two boundary vertices only along a boundary edge, into one endpoint. With
//!   [`Boundary::Exact`] the removed one must sit on a straight piece of boundary, so the
//!   polyline keeps its exact shape (shards to be stitched need that; the default of
//!   [`SimplifyConfig::new`], which knows no box); with [`Boundary::Planar`] (the pipeline's
//!   default, given the grid's box as [`Domain`]) it may also lie on a curve, on one face of the box with both
//!   its boundary neighbours, costed by boundary quadrics, so the cut is simplified within the
//!   box's faces. Exact boundaries were the floor of every open surface at low rates: bonsai
//!   asked for 10,000 faces wrote 26,871 (its cut alone has 11 k edges).
//!   Closed surfaces are not restricted (`topology::sites`).
//! * **Tiny components**: the full link condition (vertices, edges and the boundary vertex `ω`)
//!   never lets a closed component drop below a tetrahedron (4 triangles) nor an open one lose
//!   its last triangle; such components count toward the face budget as they are.
//! * **Ill-conditioning**: when `|det A| < 1e-9 (trace A / 3)^3` or the optimum lies farther
//!   than 4 edge lengths from the midpoint, the best of the endpoints and the midpoint is taken;
//!   coincident endpoints are merged in place.
//! * **Rate policy: retirement by the memory budget.** The simplified surface stays resident, as
//!   in Hou and Chen 4.3 (R F + B faces), and vertices leave only when `max_resident_faces` is
//!   exceeded, oldest rank first, after a pass has decimated what they bound. Retiring a fixed
//!   `retire_lag` behind the front (the earlier design) ruined low rates (engine at R = 0.01: RMS
//!   0.71 % of the diagonal against 0.085 % in core) for two reasons. (1) Emitted faces are final,
//!   so every face that left above the rate had to be paid for by over-decimating whatever was
//!   still resident: a band of a few slabs squeezed to 1 % while its neighbours were fixed. (2)
//!   The initial phase holds the band at `initial_rate` until the standard target catches up;
//!   retirement right after such a pass emitted faces at R_i = 0.5, which is why `batch = 200000`
//!   wrote 13x the target (the first pass came at 200 k faces, all of them still in the initial
//!   phase), and why a longer lag made it worse instead of better (the overshoot of the first
//!   emitted slabs was charged to fewer, later passes). With the budget the rate is only ever
//!   reached by decimating, never by emitting.
//! * **Front-gated modifiability**: a vertex whose star reaches beyond the front becomes
//!   modifiable when the front has passed the star's highest corner (`set_modifiable`). Counting
//!   its faces as modifiable made the rate target ask for contractions that could only wait for
//!   the front; near a dense slab a pass then took edges costing a million times the in-core
//!   maximum (shape error 16 voxels on engine). A cascade's second stage holds slabs of input
//!   beyond its front (see `cascade`), and a single stage fed a slab in several batches holds the
//!   rest of that slab: either way a vertex's own ranks say nothing of whether it can contract.
//!   With rows the front moves within the slab too, and a vertex is let in once the rows past its
//!   star are extracted (`sweep`).
//! * **Coincident vertices** (marching cubes at value == iso): their edges sort before all
//!   others and are contracted even past the rate target, so zero-area triangles only survive
//!   where the link condition forbids the merge.
//! * **Retirement** only takes modifiable vertices (one that may still gain triangles could not
//!   be finalized); one due earlier retires as soon as it becomes modifiable.
//! * **Bounded band** (lag retirement: mode `error`, and `none` in core): the rank span of every
//!   preimage is at most `2 retire_lag + 2` slabs, so no vertex rides along with the front; stale
//!   heap entries are compacted away. Rate mode needs no span bound: the budget retires the oldest
//!   buckets whatever rides ahead, and a rider keeps only its own fan.
//! * **Handles**: vertices live in slots with generations (`store`): memory follows the live
//!   vertices, and a handle kept in the heap, a rank bucket or the intersection index never names
//!   the vertex that reuses its slot. The flags and stamp that say whether a queued candidate is
//!   still current sit beside the generation, so that test reads no vertex.
//!
//! Architecture invariants: no I/O, no threads; only modifiable, unretired vertices move; every
//! contraction passes the link condition and the geometry checks; memory is bounded by the
//! unretired band.
#![deny(unsafe_code)]

mod attribute_quadric;
mod band;
mod candidates;
mod cascade;
mod cost;
mod data_dependent;
mod decimate;
mod enclosure;
mod intersect;
mod passthrough;
mod policy;
mod priority;
mod quadric;
mod retire;
mod seam;
mod stage;
mod store;
mod sweep;
mod topology;

use glam::DVec3;
use serde::Serialize;

pub use cascade::{Cascade, Handoff, VertexState};
pub use intersect::GuardWork;
pub use policy::Policy;
pub use priority::Priority;
pub use seam::{Join, Serial};
pub use sweep::{Front, Rows, Sweep};
pub use topology::{Boundary, Domain};

use passthrough::PassThrough;
use stage::Stage;

/// Everything a [`Simplifier`] needs, given at once to [`Simplifier::new`], which validates it:
/// there is no setter that must come "before the first vertex".
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimplifyConfig {
    pub policy: Policy,
    /// Edge order and attribute merging, in every policy.
    pub priority: Priority,
    /// Mode `error` (and `none` in core): retire vertices whose highest preimage rank is below
    /// front - retire_lag (slabs). Rate mode retires by `max_resident_faces` only.
    pub retire_lag: u32,
    /// When more faces than this are resident, decimate (rate) and retire the oldest vertices
    /// (memory budget). A cascade's second stage is given the budget of both stages: the
    /// faces the first reports resident ([`Handoff::faces_resident`]) count against it.
    pub max_resident_faces: usize,
    /// Number of f32 attributes per vertex.
    pub attributes: usize,
    /// Where the sweep's planes are (see [`Sweep`]); `None`: no front rule, spacing 1.
    pub sweep: Option<Sweep>,
    /// Classical (in-core) simplification, the Tandem paper's baseline: `end_batch` neither
    /// decimates nor retires, so the whole full-resolution surface stays resident and `finish`
    /// simplifies it at once with the same policy, then emits it. Nothing bounds memory then: the
    /// caller checks [`Simplifier::in_core_overflow`].
    pub in_core: bool,
    /// Alone or a stage of a cascade (see [`Cascade`]).
    #[serde(default)]
    pub cascade: Cascade,
    /// What may happen to the surface's boundary (the volume box's cut; see [`Boundary`]).
    #[serde(default)]
    pub boundary: Boundary,
    /// The volume's box (see [`Domain`]), whose faces [`Boundary::Planar`] simplifies the cut
    /// within: it needs it.
    #[serde(default)]
    pub domain: Option<Domain>,
}

impl SimplifyConfig {
    /// The one validation of a configuration, by [`Simplifier::new`].
    fn validate(&self) -> Result<(), SimplifyError> {
        self.policy.validate()?;
        self.priority.validate(self.attributes)?;
        if self.max_resident_faces == 0 {
            return Err(SimplifyError::ZeroFaceBudget);
        }
        if self.sweep.is_some_and(|w| !w.is_valid()) {
            return Err(SimplifyError::InvalidSweep);
        }
        if self.cascade != Cascade::Single
            && !(matches!(self.policy, Policy::Rate { .. })
                && self.priority == Priority::Geometric
                && self.sweep.is_some()
                && !self.in_core)
        {
            return Err(SimplifyError::InvalidCascade);
        }
        if self.domain.is_some_and(|d| !d.is_valid())
            || (self.boundary == Boundary::Planar
                && (matches!(self.priority, Priority::AttributeQuadric { .. })
                    || self.domain.is_none()))
        {
            return Err(SimplifyError::InvalidBoundary);
        }
        Ok(())
    }

    /// Whether vertices retire `retire_lag` slabs behind the front: every policy but rate, which
    /// retires by the memory budget only, unless in a cascade's first stage, whose output is not
    /// final.
    pub(crate) fn lag_retirement(&self) -> bool {
        !matches!(self.policy, Policy::Rate { .. }) || self.cascade == Cascade::First
    }

    /// `policy` with the geometric priority, `retire_lag` 8, no face budget, no attributes, no
    /// sweep, streaming.
    pub fn new(policy: Policy) -> Self {
        Self {
            policy,
            priority: Priority::default(),
            retire_lag: 8,
            max_resident_faces: usize::MAX,
            attributes: 0,
            sweep: None,
            in_core: false,
            cascade: Cascade::Single,
            boundary: Boundary::default(),
            domain: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimplifyError {
    #[error("invalid simplification policy: {0}")]
    InvalidPolicy(String),
    #[error("max_resident_faces must be at least 1")]
    ZeroFaceBudget,
    #[error("the sweep needs finite directions and origins, positive spacings and rows")]
    InvalidSweep,
    #[error("the saved simplifier state was made with another configuration")]
    ConfigChanged,
    #[error("a cascade stage needs the rate policy, the geometric priority and a sweep, streaming")]
    InvalidCascade,
    #[error(
        "the volume's box must be finite with lo <= hi, and a planar boundary needs it and a priority with boundary costs (not the attribute quadric)"
    )]
    InvalidBoundary,
}

/// A long call ([`Simplifier::end_batch_with`], [`Simplifier::finish_with`]) stopped because
/// its caller's interrupt asked it to, before it retired or emitted anything more. The
/// simplifier is then left mid-way (a final decimation cut in two stays cut: merging it back
/// would be one more pass over the surface) and is fit only to be dropped: a caller that stops
/// its run drops it, as it would between two batches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the simplification was interrupted")]
pub struct Interrupted;

/// [`Interrupted`] when `interrupt` says so: what the long loops ask between their steps.
fn asked(interrupt: &dyn Fn() -> bool) -> Result<(), Interrupted> {
    if interrupt() {
        Err(Interrupted)
    } else {
        Ok(())
    }
}

/// Counters for the run summary and the tests.
#[derive(Debug, Clone, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct SimplifyStats {
    /// Faces received (`F_g`).
    pub faces_in: u64,
    pub vertices_in: u64,
    pub faces_out: u64,
    pub vertices_out: u64,
    pub faces_resident: usize,
    /// The most faces held at a time. For a cascade, the sum of its two stages' peaks: an
    /// upper bound on what both held at once (their peaks come at different moments; a user
    /// trial found it beside a budget warning's one-stage figure and took them for one measure).
    pub peak_resident_faces: usize,
    /// Vertices in memory.
    pub vertices_resident: usize,
    /// Faces in memory with a vertex that is not modifiable yet (`F_u`).
    pub faces_unmodifiable: usize,
    pub contractions: u64,
    /// Candidates refused by the link condition.
    pub rejected_link: u64,
    /// Candidates refused because a triangle would flip or degenerate, or a closed component
    /// could turn inside out (`enclosure`).
    pub rejected_flip: u64,
    /// Candidates refused because the new fan would cross another triangle (`intersect`).
    pub rejected_intersection: u64,
    /// Candidates refused because the new fan would reach the region of emitted triangles the
    /// guard no longer holds (`intersect`, dropped ghosts), where it could not tell.
    pub rejected_unguarded: u64,
    /// Contractions postponed because their new fan reached past the front (see
    /// [`Sweep`]).
    pub delayed_front: u64,
    /// Candidates refused on re-evaluation (boundary rule, threshold; in a cascade's first
    /// stage, a placement below its rear or more than a slab below the preimage, or a new fan
    /// not clear of the rear's rows).
    pub rejected_other: u64,
    /// Vertices retired early for the memory budget.
    pub forced_retirements: u64,
    /// Most faces held past this stage's share of the budget: the sweep front's where it took
    /// more than half of it (`Stage::budget`), and the last two slabs behind the front, which
    /// are never retired for memory (`Stage::retire_for_memory`; a slab crowded with surface
    /// stretches it while the front itself is small).
    pub front_stretch_faces: usize,
    /// Most faces the sweep front held at the end of a batch (`faces_unmodifiable`).
    pub peak_front_faces: usize,
    /// Highest cost of a performed contraction (objective units; merging coincident vertices
    /// counts as -1).
    pub max_cost: f64,
    /// Highest shape measure `eps0` of a vertex created by a contraction (position units).
    pub max_shape_error: f64,
    /// Edges currently in the heap or the time-lag waiting queue (including stale entries).
    pub candidates: usize,
    /// Contractions performed while their reach was beyond the front. A self-check of the
    /// time-lag: always 0.
    pub lag_violations: u64,
    /// What the self-intersection guard's queries met.
    pub guard: GuardWork,
    /// Faces held when the final decimation was cut between two workers (`seam`), 0 when it
    /// was not.
    #[serde(default)]
    pub cut_faces: usize,
}

impl SimplifyStats {
    /// Adds what a second worker on the same stage did (`seam`): its contractions, refusals
    /// and largest cost and shape error.
    pub(crate) fn add_worker(&mut self, w: &Self) {
        self.contractions += w.contractions;
        self.rejected_link += w.rejected_link;
        self.rejected_flip += w.rejected_flip;
        self.rejected_intersection += w.rejected_intersection;
        self.rejected_unguarded += w.rejected_unguarded;
        self.rejected_other += w.rejected_other;
        self.delayed_front += w.delayed_front;
        self.lag_violations += w.lag_violations;
        self.max_cost = self.max_cost.max(w.max_cost);
        self.max_shape_error = self.max_shape_error.max(w.max_shape_error);
    }

    /// The counters of a cascade's two stages as one run's: faces and vertices in of the first,
    /// out of the second; work and refusals added up; resident and peak faces added (both stages
    /// hold their bands at the same time, so the sum bounds the peak); the largest cost and
    /// shape error of either.
    pub fn of_cascade(first: &Self, second: &Self) -> Self {
        Self {
            faces_in: first.faces_in,
            vertices_in: first.vertices_in,
            faces_out: second.faces_out,
            vertices_out: second.vertices_out,
            faces_resident: first.faces_resident + second.faces_resident,
            peak_resident_faces: first.peak_resident_faces + second.peak_resident_faces,
            vertices_resident: first.vertices_resident + second.vertices_resident,
            faces_unmodifiable: first.faces_unmodifiable + second.faces_unmodifiable,
            contractions: first.contractions + second.contractions,
            rejected_link: first.rejected_link + second.rejected_link,
            rejected_flip: first.rejected_flip + second.rejected_flip,
            rejected_intersection: first.rejected_intersection + second.rejected_intersection,
            rejected_unguarded: first.rejected_unguarded + second.rejected_unguarded,
            delayed_front: first.delayed_front + second.delayed_front,
            rejected_other: first.rejected_other + second.rejected_other,
            forced_retirements: first.forced_retirements + second.forced_retirements,
            front_stretch_faces: first.front_stretch_faces.max(second.front_stretch_faces),
            peak_front_faces: first.peak_front_faces + second.peak_front_faces,
            max_cost: first.max_cost.max(second.max_cost),
            max_shape_error: first.max_shape_error.max(second.max_shape_error),
            candidates: first.candidates + second.candidates,
            lag_violations: first.lag_violations + second.lag_violations,
            guard: first.guard + second.guard,
            cut_faces: first.cut_faces.max(second.cut_faces),
        }
    }
}

#[derive(Debug, Default, Clone, PartialEq)]
pub struct OutBatch {
    pub elements: Vec<OutElement>,
    /// attribute values, `attributes` per Vertex element, in order
    pub attrs: Vec<f32>,
    /// First stage of a cascade: the state of each Vertex element, in order.
    pub states: Vec<VertexState>,
    /// First stage of a cascade: its rear and counts after the batch.
    pub handoff: Option<Handoff>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum OutElement {
    /// Next output vertex; output vertices are numbered 0,1,2,... in emission order.
    Vertex { pos: DVec3 },
    /// Triangle by output vertex numbers, CCW; `last_use[i]`: this is the last triangle using `v[i]`
    /// (the writer finalizes it).
    Triangle { v: [u64; 3], last_use: [bool; 3] },
}

/// The streaming simplifier. See the crate documentation.
///
/// Serializable as a whole (checkpoints, see [`Simplifier::restore`]): between two calls the
/// state is complete, nothing refers outside it, and every map is looked up only, never
/// iterated where the order could change a decision (the guard's large queries walk its cells,
/// and a crossing is found in any order, though the work counters may differ), so a restored
/// simplifier continues with exactly the same decisions.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Simplifier {
    engine: Engine,
}

/// The two ways through: policy `none` when streaming has nothing to contract and takes its
/// own path (`passthrough`); every other run is a contracting [`Stage`].
#[derive(serde::Serialize, serde::Deserialize)]
enum Engine {
    PassThrough(Box<PassThrough>),
    Stage(Box<Stage>),
}

impl Simplifier {
    /// # Errors
    /// An invalid policy or priority (for the number of attributes), a zero face budget, or a
    /// sweep with a non-finite direction or origin or a spacing that is not positive.
    pub fn new(config: SimplifyConfig) -> Result<Self, SimplifyError> {
        config.validate()?;
        let engine = if config.policy.objective().is_none() && !config.in_core {
            Engine::PassThrough(Box::new(PassThrough::new(config)))
        } else {
            Engine::Stage(Box::new(Stage::new(config)))
        };
        Ok(Self { engine })
    }

    /// A simplifier saved between two batches (through its `Serialize`, by a checkpoint) and
    /// deserialized again: it continues exactly where the saved one stood.
    ///
    /// # Errors
    /// [`SimplifyError::ConfigChanged`] when `saved` was made with another configuration than
    /// `config`: continuing it would not give the run `config` asks for.
    pub fn restore(config: &SimplifyConfig, saved: Simplifier) -> Result<Self, SimplifyError> {
        if saved.config() == config {
            Ok(saved)
        } else {
            Err(SimplifyError::ConfigChanged)
        }
    }

    fn config(&self) -> &SimplifyConfig {
        match &self.engine {
            Engine::PassThrough(p) => p.config(),
            Engine::Stage(s) => s.config(),
        }
    }

    /// In-core mode only: the resident face count once it exceeds `max_resident_faces`.
    pub fn in_core_overflow(&self) -> Option<usize> {
        match &self.engine {
            Engine::PassThrough(_) => None,
            Engine::Stage(s) => s.in_core_overflow(),
        }
    }

    /// A new vertex. `attrs` holds `attributes` values (missing ones are 0, extra ones dropped).
    ///
    /// Ids are the detector's: any `u64`, unique among the vertices that may still receive
    /// triangles (they are translated to store slots, see `store`).
    ///
    /// # Panics
    /// If a vertex that is not modifiable yet already has this id.
    pub fn add_vertex(&mut self, id: u64, pos: DVec3, rank: u32, attrs: &[f32]) {
        match &mut self.engine {
            Engine::PassThrough(p) => p.add_vertex(id, pos, attrs),
            Engine::Stage(s) => s.add_vertex(id, pos, rank, attrs),
        }
    }

    /// A new triangle (CCW seen from outside). Adds its area-weighted plane quadric to its
    /// vertices (Garland and Heckbert; Hou and Chen 4.1 "Adding face quadric").
    ///
    /// # Panics
    /// If a vertex is unknown or already retired, or the triangle repeats a vertex: the detector
    /// only adds triangles to vertices that are not modifiable yet.
    pub fn add_triangle(&mut self, ids: [u64; 3]) {
        assert!(
            ids[0] != ids[1] && ids[1] != ids[2] && ids[0] != ids[2],
            "triangle {ids:?} repeats a vertex"
        );
        match &mut self.engine {
            Engine::PassThrough(p) => p.add_triangle(ids),
            Engine::Stage(s) => s.add_triangle(ids),
        }
    }

    /// All triangles of `id` exist: it may move from now on, and its edges to other modifiable
    /// vertices become candidates (Hou and Chen 4.1, "Vertex modifiability detection").
    ///
    /// With a sweep (see [`Sweep`]), a vertex beyond the front (rank above it)
    /// waits until the front reaches it: every contraction it could take part in would wait
    /// for the front anyway, and counting its faces as unmodifiable keeps the rate target to
    /// what can be contracted now. (A target counting them made passes near a dense slab contract
    /// edges a million times costlier than the in-core run ever does, and ruined low rates.)
    pub fn set_modifiable(&mut self, id: u64) {
        match &mut self.engine {
            Engine::PassThrough(p) => p.set_modifiable(id),
            Engine::Stage(s) => s.set_modifiable(id),
        }
    }

    /// After each batch: decimate as the policy says, retire what is behind the front, append
    /// finished output. `front` is where the extraction stands: a number of whole slabs, or a
    /// [`Front`] with the rows of the next slab done as well (counted only with `Sweep::rows`).
    pub fn end_batch(&mut self, front: impl Into<Front>, out: &mut OutBatch) {
        if let Err(Interrupted) = self.end_batch_with(front, out, &|| false) {
            unreachable!("nothing asked it to stop");
        }
    }

    /// [`Simplifier::end_batch`], giving up when `interrupt` says so: it is asked every few
    /// thousand candidates of a pass. A pass over a full memory budget contracts a quarter of
    /// it, seconds on a large budget, and the run's Ctrl-C waited for it. Asking changes
    /// nothing else: a call it never stops gives the output it always gave.
    ///
    /// # Errors
    /// [`Interrupted`] when `interrupt` returned true (see there).
    pub fn end_batch_with(
        &mut self,
        front: impl Into<Front>,
        out: &mut OutBatch,
        interrupt: &dyn Fn() -> bool,
    ) -> Result<(), Interrupted> {
        match &mut self.engine {
            Engine::PassThrough(p) => {
                p.flush(out);
                Ok(())
            }
            Engine::Stage(s) => s.end_batch(front.into(), out, interrupt),
        }
    }

    /// Second stage of a cascade: takes one batch of the first stage's output (vertices with
    /// their states, triangles, and the end of each vertex as its modifiable notice) and
    /// returns the front to close it with (the first stage's rear, with rows when the sweep has
    /// them).
    ///
    /// # Panics
    /// If this simplifier is not a second stage, or the batch is not a first stage's.
    pub fn ingest(&mut self, batch: &OutBatch) -> Front {
        match &mut self.engine {
            Engine::PassThrough(_) => panic!("ingest is for a second stage"),
            Engine::Stage(s) => s.ingest(batch),
        }
    }

    /// End of volume: everything is modifiable; final decimation, retire all, emit all.
    pub fn finish(&mut self, out: &mut OutBatch) {
        if let Err(Interrupted) = self.finish_with(out, &Serial, &|| false) {
            unreachable!("nothing asked it to stop");
        }
    }

    /// [`Simplifier::finish`], with the first part of a large final decimation on two workers
    /// either side of a cut that `join` may run at once (`seam`); the output does not depend on
    /// how it runs them. It gives up when `interrupt` says so, asked at the start, between the
    /// passes over the whole surface and every few thousand candidates by each worker: the
    /// final decimation of a classical run simplifies the whole surface (engine: 4 to 7 s; 38 s
    /// upsampled to 511 x 511 x 255), and the run's Ctrl-C waited for it, only to throw its
    /// result away.
    /// Asking changes nothing else: a call it never stops gives the output it always gave. (The
    /// pass-through of policy `none` has nothing long to stop, and does not ask.)
    ///
    /// # Errors
    /// [`Interrupted`] when `interrupt` returned true (see there).
    pub fn finish_with(
        &mut self,
        out: &mut OutBatch,
        join: &dyn Join,
        interrupt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), Interrupted> {
        match &mut self.engine {
            Engine::PassThrough(p) => {
                p.finish(out);
                Ok(())
            }
            Engine::Stage(s) => s.finish(out, join, interrupt),
        }
    }

    pub fn stats(&self) -> SimplifyStats {
        match &self.engine {
            Engine::PassThrough(p) => p.stats(),
            Engine::Stage(s) => s.stats(),
        }
    }
}

/// A vertex as the simplifier keeps it: `pos` rounded to the output precision (so every check
/// judges the written coordinates) and exactly `attributes` values (missing ones 0, extra ones
/// dropped).
fn vertex_input(pos: DVec3, attrs: &[f32], attributes: usize) -> (DVec3, Vec<f32>) {
    let mut values = vec![0.0; attributes];
    for (v, a) in values.iter_mut().zip(attrs) {
        *v = *a;
    }
    (cost::output_precision(pos), values)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(policy: Policy) -> SimplifyConfig {
        SimplifyConfig {
            retire_lag: 1,
            max_resident_faces: 100,
            attributes: 2,
            ..SimplifyConfig::new(policy)
        }
    }

    #[test]
    fn configuration_is_validated() {
        assert!(Simplifier::new(config(Policy::None)).is_ok());
        let bad = Policy::Rate {
            rate: 0.0,
            batch: 1,
            initial_rate: 1.0,
        };
        assert!(matches!(
            Simplifier::new(config(bad)),
            Err(SimplifyError::InvalidPolicy(_))
        ));
        let zero = SimplifyConfig {
            max_resident_faces: 0,
            ..config(Policy::None)
        };
        assert!(matches!(
            Simplifier::new(zero),
            Err(SimplifyError::ZeroFaceBudget)
        ));
        let flat = SimplifyConfig {
            sweep: Some(Sweep {
                direction: DVec3::Z,
                origin: 0.0,
                spacing: 0.0,
                rows: None,
            }),
            ..config(Policy::None)
        };
        assert!(matches!(
            Simplifier::new(flat),
            Err(SimplifyError::InvalidSweep)
        ));
        let weights = SimplifyConfig {
            priority: Priority::AttributeQuadric { weights: vec![1.0] },
            ..config(Policy::None)
        };
        assert!(matches!(
            Simplifier::new(weights),
            Err(SimplifyError::InvalidPolicy(_))
        ));
        // A planar boundary needs the volume's box; a box must be finite, f32-exact and ordered.
        let planar = SimplifyConfig {
            boundary: Boundary::Planar,
            ..config(Policy::None)
        };
        assert!(matches!(
            Simplifier::new(planar.clone()),
            Err(SimplifyError::InvalidBoundary)
        ));
        let boxed = |lo: f64, hi: f64| SimplifyConfig {
            domain: Some(Domain {
                lo: DVec3::splat(lo),
                hi: DVec3::splat(hi),
            }),
            ..planar.clone()
        };
        assert!(Simplifier::new(boxed(0.0, 1.5)).is_ok());
        for (lo, hi) in [(0.0, f64::NAN), (1.0, 0.0), (0.1, 1.0)] {
            assert!(
                matches!(
                    Simplifier::new(boxed(lo, hi)),
                    Err(SimplifyError::InvalidBoundary)
                ),
                "[{lo}, {hi}]"
            );
        }
    }

    /// One triangle, pass-through: vertices right before it, all finalized by it, attributes
    /// padded to `attributes` per vertex.
    #[test]
    fn a_lone_triangle_streams_out_in_pre_order() {
        let mut s = Simplifier::new(config(Policy::None)).unwrap();
        s.add_vertex(7, DVec3::ZERO, 0, &[1.0]);
        s.add_vertex(8, DVec3::X, 0, &[2.0, 3.0, 4.0]);
        s.add_vertex(9, DVec3::Y, 1, &[]);
        s.add_triangle([7, 8, 9]);
        let mut out = OutBatch::default();
        s.end_batch(1, &mut out);
        assert!(
            out.elements.is_empty(),
            "nothing modifiable, nothing retired"
        );
        assert_eq!(s.stats().faces_unmodifiable, 1);
        for id in [7, 8, 9] {
            s.set_modifiable(id);
        }
        assert_eq!(s.stats().faces_unmodifiable, 0);
        s.end_batch(3, &mut out);
        let vertex = |pos| OutElement::Vertex { pos };
        assert_eq!(
            out.elements,
            vec![
                vertex(DVec3::ZERO),
                vertex(DVec3::X),
                vertex(DVec3::Y),
                OutElement::Triangle {
                    v: [0, 1, 2],
                    last_use: [true; 3]
                },
            ]
        );
        assert_eq!(out.attrs, vec![1.0, 0.0, 2.0, 3.0, 0.0, 0.0]);
        let st = s.stats();
        assert_eq!(
            (
                st.faces_out,
                st.vertices_out,
                st.faces_resident,
                st.vertices_resident
            ),
            (1, 3, 0, 0)
        );
    }

    /// In-core (classical) mode holds everything until `finish`, and reports when the surface
    /// outgrows the face budget.
    #[test]
    fn in_core_mode_defers_everything_to_finish() {
        let mut s = Simplifier::new(SimplifyConfig {
            max_resident_faces: 1,
            in_core: true,
            ..config(Policy::None)
        })
        .unwrap();
        for (id, pos) in [
            (0, DVec3::ZERO),
            (1, DVec3::X),
            (2, DVec3::Y),
            (3, DVec3::ONE),
        ] {
            s.add_vertex(id, pos, 0, &[]);
        }
        s.add_triangle([0, 1, 2]);
        s.set_modifiable(0);
        let mut out = OutBatch::default();
        s.end_batch(10, &mut out);
        assert!(out.elements.is_empty(), "nothing retires in core");
        assert_eq!(s.in_core_overflow(), None);
        s.add_triangle([1, 3, 2]);
        s.end_batch(11, &mut out);
        assert!(out.elements.is_empty());
        assert_eq!(s.in_core_overflow(), Some(2));
        s.finish(&mut out);
        assert_eq!(s.stats().faces_out, 2);
    }

    /// A configuration in place `cascade` at rate 0.5, sweeping along z (rank = z), with a
    /// budget of `faces`.
    pub(crate) fn swept(cascade: Cascade, faces: usize) -> SimplifyConfig {
        SimplifyConfig {
            cascade,
            max_resident_faces: faces,
            sweep: Some(Sweep {
                direction: DVec3::Z,
                origin: 0.0,
                spacing: 1.0,
                rows: None,
            }),
            ..SimplifyConfig::new(Policy::Rate {
                rate: 0.5,
                batch: 1,
                initial_rate: 0.5,
            })
        }
    }

    #[test]
    #[should_panic(expected = "unknown or retired vertex")]
    fn triangles_on_unknown_vertices_are_a_contract_violation() {
        let mut s = Simplifier::new(config(Policy::None)).unwrap();
        s.add_vertex(0, DVec3::ZERO, 0, &[]);
        s.add_triangle([0, 1, 2]);
    }
}
