//! isostream-simplify: one streaming quadric edge-collapse simplifier.
//!
//! The detector feeds batches of vertices (stable, increasing `u64` ids), triangles and
//! "modifiable" notices (all triangles of the vertex exist). After each batch,
//! [`Simplifier::end_batch`] decimates as the [`Policy`] says, retires what fell behind the
//! sweep front and appends finished output in compact pre-order (see [`OutElement`]).
//!
//! Modules, by role:
//! * `quadric`: symmetric 4x4 quadrics (Garland and Heckbert 1997);
//! * `store`: the resident mesh band (vertices by `id - base`, triangle slab);
//! * `topology`: link condition, boundary rule, no-flip/no-degenerate checks;
//! * `cost`: cost and placement of one contraction: the one `Evaluator` (the mode's objective,
//!   re-ranked or re-placed by the priority; the policy hook);
//! * `policy`: the public [`Policy`] and when/how far to decimate (Hou and Chen 4.2, Tandem);
//! * `candidates`: the lazily invalidated edge queue (buckets of cost) and the time-lag queue;
//! * `decimate`: the one contraction loop;
//! * `intersect`: spatial hash of the resident triangles; rejects contractions whose new fan
//!   would cross another sheet (thin structures, touching surfaces);
//! * `retire`: retirement behind the front or for the memory budget, and emission;
//! * `passthrough`: policy `none` when streaming: triangles leave as soon as their vertices are
//!   complete, without any of the contraction machinery.
//! * `cascade`: what two simplifiers in series exchange (vertex states, the first stage's rear)
//!   and why the pair is as safe as one.
//!
//! Decisions (the why is at each item's definition):
//! * **Surface boundary** (an iso-surface's boundary is where the volume's box cuts it):
//!   boundary vertices never move off it. An interior vertex may merge into a boundary vertex's
//!   position; two boundary vertices only along a boundary edge, into one endpoint. With
//!   [`Boundary::Exact`] the removed one must sit on a straight piece of boundary, so the
//!   polyline keeps its exact shape (shards to be stitched need that; the default of
//!   [`SimplifyConfig::new`], which knows no box); with [`Boundary::Planar`] (the pipeline's
//!   default, given the grid's box) it may also lie on a curve, on one face of the box with both
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
//! * **Front-gated modifiability**: a vertex whose rank is beyond the front becomes modifiable
//!   when the front reaches it (`set_modifiable`). Counting its faces as modifiable made the rate
//!   target ask for contractions that could only wait for the front; near a dense slab a pass then
//!   took edges costing a million times the in-core maximum (shape error 16 voxels on engine).
//!   A cascade's second stage gates by the highest corner of the vertex's star instead (see
//!   `cascade`): it holds slabs of input beyond its front, so a vertex's own ranks say nothing
//!   of whether it can contract.
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
mod candidates;
mod cascade;
mod cost;
mod data_dependent;
mod decimate;
mod intersect;
mod passthrough;
mod policy;
mod priority;
mod quadric;
mod retire;
mod store;
mod topology;

use glam::DVec3;
use serde::Serialize;

pub use cascade::{Cascade, Handoff, VertexState};
pub use policy::Policy;
pub use priority::Priority;
pub use topology::Boundary;

use candidates::Candidates;
use cost::Evaluator;
use decimate::Until;
use policy::{FaceCounts, Schedule};
use quadric::Quadric;
use retire::RankBuckets;
use store::{Store, Tri, Vertex};

/// A cascade's second stage keeps at least `1 / SECOND_STAGE_FLOOR` of the shared budget
/// however much the first holds (see [`Simplifier::budget`]).
const SECOND_STAGE_FLOOR: usize = 3;

/// Whatever the sweep front holds, `1 / FRONT_ROOM_SHARE` of the face budget stays for the
/// surface behind it (see [`Simplifier::budget`]).
const FRONT_ROOM_SHARE: usize = 2;

/// A boundary quadric's weight per squared edge length ([`Boundary::Planar`]). The boundary's
/// edges keep their full-resolution lengths in the sum while faces grow, so with 1 the cut
/// became cheap to move late in a run: engine in core at R = 0.2 had a Hausdorff distance of
/// 0.099 % of the diagonal against 0.061 % with the exact rule. 10 brings it to 0.063 %, and at
/// R = 0.01 it is also closer than 1 (stent: RMS 0.50 -> 0.42 %, Hausdorff 6.8 -> 4.8 %;
/// engine Hausdorff 0.90 -> 0.83 %); 100 keeps 1.7x the boundary edges for no better RMS.
const BOUNDARY_WEIGHT: f64 = 10.0;

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
}

impl SimplifyConfig {
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
        }
    }
}

/// The sweep's rank planes: rank `r` is the plane `p . direction = origin + r * spacing` (for
/// marching cubes along z: `direction = Z`, the grid's z origin and spacing).
///
/// `spacing` converts lengths into ranks for the time-lag radius (which adds edge lengths to
/// heights). The planes also keep contractions behind the front: triangles still to come lie
/// beyond it (a marching-cubes triangle stays in its cube), so a contraction whose new fan
/// reaches past the front waits (like a time-lag DELAY) until the front has passed the fan;
/// otherwise a later triangle could cross it, and no check would see that.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sweep {
    pub direction: DVec3,
    pub origin: f64,
    pub spacing: f64,
}

impl Sweep {
    /// The (fractional) rank of the plane through `p`.
    pub(crate) fn rank_of(&self, p: DVec3) -> f64 {
        self.rank_at(self.height(p))
    }

    /// How far along the sweep `p` lies (the rank is monotonic in it).
    pub(crate) fn height(&self, p: DVec3) -> f64 {
        p.dot(self.direction)
    }

    /// The rank at height `h`.
    pub(crate) fn rank_at(&self, h: f64) -> f64 {
        (h - self.origin) / self.spacing
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimplifyError {
    #[error("invalid simplification policy: {0}")]
    InvalidPolicy(String),
    #[error("max_resident_faces must be at least 1")]
    ZeroFaceBudget,
    #[error("the sweep needs a finite direction and origin and a positive spacing")]
    InvalidSweep,
    #[error("the saved simplifier state was made with another configuration")]
    ConfigChanged,
    #[error("a cascade stage needs the rate policy, the geometric priority and a sweep, streaming")]
    InvalidCascade,
    #[error(
        "a planar boundary needs a finite box with lo <= hi and a priority with boundary costs (not the attribute quadric)"
    )]
    InvalidBoundary,
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
    pub peak_resident_faces: usize,
    /// Vertices in memory.
    pub vertices_resident: usize,
    /// Faces in memory with a vertex that is not modifiable yet (`F_u`).
    pub faces_unmodifiable: usize,
    pub contractions: u64,
    /// Candidates refused by the link condition.
    pub rejected_link: u64,
    /// Candidates refused because a triangle would flip or degenerate.
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
    /// stage, a placement below its rear or more than a slab below the preimage).
    pub rejected_other: u64,
    /// Vertices retired early for the memory budget.
    pub forced_retirements: u64,
    /// Most faces the budget was stretched by to hold the sweep front with room behind it
    /// (0 when the front never took more than half of it; see `Simplifier::budget`).
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
}

impl SimplifyStats {
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
/// iterated, so a restored simplifier continues with exactly the same decisions.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Simplifier {
    config: SimplifyConfig,
    /// Cost and placement of contractions; `None` for policy `none`, which contracts nothing.
    evaluator: Option<Evaluator>,
    schedule: Schedule,
    time_lag: bool,
    store: Store,
    /// Spatial hash of the resident (and latest emitted) triangles for the intersection guard.
    isect: intersect::TriIndex,
    candidates: Candidates,
    buckets: RankBuckets,
    /// Policy `none` outside in-core mode: the band without contractions (`passthrough`);
    /// the fields above then stay empty.
    pass: Option<passthrough::PassThrough>,
    /// Vertices behind the front that could not retire because they were not modifiable yet.
    deferred: Vec<u64>,
    /// Modifiable by the detector's word but beyond the front, by rank (`set_modifiable`).
    beyond_front: std::collections::BinaryHeap<std::cmp::Reverse<(u32, u64)>>,
    /// Rank of the front, `+inf` after `finish`.
    front: f64,
    /// First stage of a cascade: the rear announced last (no vertex is placed below it).
    rear: u32,
    /// Second stage of a cascade: the faces the first stage held at its last hand-off.
    first_resident: usize,
    next_out: u64,
    stats: SimplifyStats,
}

impl Simplifier {
    /// # Errors
    /// An invalid policy or priority (for the number of attributes), a zero face budget, or a
    /// sweep with a non-finite direction or origin or a spacing that is not positive.
    pub fn new(config: SimplifyConfig) -> Result<Self, SimplifyError> {
        config.policy.validate()?;
        config.priority.validate(config.attributes)?;
        if config.max_resident_faces == 0 {
            return Err(SimplifyError::ZeroFaceBudget);
        }
        if let Some(w) = config.sweep
            && !(w.spacing > 0.0
                && w.spacing.is_finite()
                && w.origin.is_finite()
                && w.direction.is_finite())
        {
            return Err(SimplifyError::InvalidSweep);
        }
        if config.cascade != Cascade::Single
            && !(matches!(config.policy, Policy::Rate { .. })
                && config.priority == Priority::Geometric
                && config.sweep.is_some()
                && !config.in_core)
        {
            return Err(SimplifyError::InvalidCascade);
        }
        if let Boundary::Planar { lo, hi } = config.boundary
            && (matches!(config.priority, Priority::AttributeQuadric { .. })
                || !(lo.is_finite() && hi.is_finite() && lo.cmple(hi).all()))
        {
            return Err(SimplifyError::InvalidBoundary);
        }
        let evaluator = config.policy.objective().map(|objective| {
            Evaluator::new(
                objective,
                config.priority.clone(),
                config.boundary,
                config.sweep.map_or(1.0, |w| w.spacing),
            )
        });
        let pass = (evaluator.is_none() && !config.in_core)
            .then(|| passthrough::PassThrough::new(config.attributes));
        Ok(Self {
            evaluator,
            pass,
            schedule: config.policy.schedule(),
            time_lag: config.policy.time_lag(),
            config,
            store: Store::default(),
            isect: intersect::TriIndex::default(),
            candidates: Candidates::default(),
            buckets: RankBuckets::default(),
            deferred: Vec::new(),
            beyond_front: std::collections::BinaryHeap::new(),
            front: 0.0,
            rear: 0,
            first_resident: 0,
            next_out: 0,
            stats: SimplifyStats::default(),
        })
    }

    /// A simplifier saved between two batches (through its `Serialize`, by a checkpoint) and
    /// deserialized again: it continues exactly where the saved one stood.
    ///
    /// # Errors
    /// [`SimplifyError::ConfigChanged`] when `saved` was made with another configuration than
    /// `config`: continuing it would not give the run `config` asks for.
    pub fn restore(config: &SimplifyConfig, saved: Simplifier) -> Result<Self, SimplifyError> {
        if saved.config == *config {
            Ok(saved)
        } else {
            Err(SimplifyError::ConfigChanged)
        }
    }

    /// In-core mode only: the resident face count once it exceeds `max_resident_faces`.
    pub fn in_core_overflow(&self) -> Option<usize> {
        let resident = self.store.resident();
        (self.config.in_core && resident > self.config.max_resident_faces).then_some(resident)
    }

    /// A new vertex. `attrs` holds `attributes` values (missing ones are 0, extra ones dropped).
    ///
    /// Ids are the detector's: any `u64`, unique among the vertices that may still receive
    /// triangles (they are translated to store slots, see `store`).
    ///
    /// # Panics
    /// If a vertex that is not modifiable yet already has this id.
    pub fn add_vertex(&mut self, id: u64, pos: DVec3, rank: u32, attrs: &[f32]) {
        let mut values = vec![0.0; self.config.attributes];
        for (v, a) in values.iter_mut().zip(attrs) {
            *v = *a;
        }
        let pos = cost::output_precision(pos);
        self.stats.vertices_in += 1;
        if let Some(pass) = &mut self.pass {
            pass.add_vertex(id, pos, &values);
            return;
        }
        let slot = self
            .store
            .insert_vertex(id, Vertex::new(pos, rank, &values));
        self.buckets.push(rank, slot, &mut self.store);
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
        if let Some(pass) = &mut self.pass {
            pass.add_triangle(ids);
            self.stats.faces_in += 1;
            self.note_resident();
            return;
        }
        let v = ids.map(|id| {
            self.store
                .slot_of(id)
                .unwrap_or_else(|| panic!("triangle {ids:?} uses unknown or retired vertex {id}"))
        });
        let mut unmodifiable = 0;
        for slot in v {
            if self.store.vertex(slot).is_some() {
                unmodifiable += u8::from(!self.store.is_modifiable(slot));
            }
        }
        // Without an objective (policy `none`) nothing is ever contracted: no quadric, no
        // obstacle for the guard (half of a pass-through run's time went into them).
        let contracting = self.evaluator.is_some();
        // A cascade's second stage receives its vertices' quadrics with them.
        let quadrics = contracting && self.config.cascade != Cascade::Second;
        let p = v.map(|id| self.store.pos(id));
        let cross = (p[1] - p[0]).cross(p[2] - p[0]);
        let len = cross.length();
        if quadrics && len > 0.0 {
            let n = cross / len;
            let area = 0.5 * len;
            let q = Quadric::plane(n, -n.dot(p[0]), area);
            for id in v {
                if let Some(x) = self.store.vertex_mut(id) {
                    x.quadric += q;
                    x.area += area;
                }
            }
        }
        let t = self.store.add_triangle(Tri { v, unmodifiable });
        if contracting {
            self.add_attribute_quadric(v);
            self.isect.insert(t, v, p);
        }
        self.stats.faces_in += 1;
        self.stats.faces_unmodifiable += usize::from(unmodifiable > 0);
        self.note_resident();
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
        if let Some(pass) = &mut self.pass {
            pass.set_modifiable(id);
            return;
        }
        let Some(slot) = self.store.slot_of(id) else {
            return;
        };
        self.store.forget_id(id);
        let Some(v) = self.store.vertex(slot) else {
            return;
        };
        if self.store.is_modifiable(slot) {
            return;
        }
        if let Some(sweep) = &self.config.sweep {
            let reach = match self.config.cascade {
                Cascade::Second => self.star_reach(sweep, slot),
                _ => v.rank_max,
            };
            if f64::from(reach) > self.front {
                self.beyond_front.push(std::cmp::Reverse((reach, slot)));
                return;
            }
        }
        self.make_modifiable(slot);
    }

    /// A cascade's second stage: the rank its front (the first stage's rear) must reach before
    /// any contraction at `slot` can be made, the ceiling of the highest corner of its star.
    /// Its preimage's highest rank (what gates a first or single stage, whose front is the
    /// extraction front and where nothing lies far beyond it) is no measure here: the second
    /// stage holds about ten slabs of the first stage's output beyond its front, and a
    /// vertex let in with a star reaching into them could not contract, yet its faces counted as
    /// modifiable, so the rate target squeezed the others to make up for them.
    fn star_reach(&self, sweep: &Sweep, slot: u64) -> u32 {
        let store = &self.store;
        let far = store
            .vertex(slot)
            .map_or(&[][..], |v| &v.tris[..])
            .iter()
            .flat_map(|&t| store.corners(store.tri(t)))
            .map(|p| sweep.rank_of(p))
            .fold(0.0, f64::max);
        far.ceil().clamp(0.0, f64::from(u32::MAX)) as u32
    }

    /// The vertices held by [`Simplifier::set_modifiable`] that the front has reached.
    fn release_reached(&mut self) {
        while let Some(&std::cmp::Reverse((rank, id))) = self.beyond_front.peek() {
            if f64::from(rank) > self.front {
                break;
            }
            self.beyond_front.pop();
            self.make_modifiable(id);
        }
    }

    fn make_modifiable(&mut self, id: u64) {
        if self.store.vertex(id).is_none() || self.store.is_modifiable(id) {
            return;
        }
        // One ring for the boundary test and the new candidates: nothing changes it between
        // (and neither is needed when nothing is contracted).
        let ring = if self.evaluator.is_some() {
            topology::ring(&self.store, id)
        } else {
            topology::Ring::new()
        };
        let boundary = topology::is_boundary(&ring);
        if boundary {
            self.add_boundary_quadrics(id, &ring);
        }
        self.store.set_modifiable(id);
        let Some(v) = self.store.vertex_mut(id) else {
            return;
        };
        v.boundary = boundary;
        let tris = v.tris.clone();
        for t in tris {
            let tri = self.store.tri_mut(t);
            tri.unmodifiable -= 1;
            if tri.unmodifiable == 0 {
                self.stats.faces_unmodifiable -= 1;
            }
        }
        self.push_ring_edges(id, &ring, |_| true);
    }

    /// With [`Boundary::Planar`], the boundary quadric of each boundary edge of `id` (its fan
    /// complete, with `ring`) is added to `id`; the other end adds its own when its fan
    /// completes, so each edge counts once at each end, like a face. A cascade's second stage
    /// receives the quadrics with the vertices, as for faces.
    fn add_boundary_quadrics(&mut self, id: u64, ring: &topology::Ring) {
        if self.evaluator.is_none()
            || self.config.cascade == Cascade::Second
            || !self.config.boundary.is_planar()
        {
            return;
        }
        let store = &self.store;
        let Some(v) = store.vertex(id) else {
            return;
        };
        let mut q = Quadric::default();
        for &(x, _) in ring.iter().filter(|&&(_, n)| n == 1) {
            let Some(t) = v.tris.iter().map(|&t| store.tri(t)).find(|t| t.contains(x)) else {
                continue;
            };
            let p = store.corners(t);
            let edge = store.pos(x) - v.pos();
            let normal = (p[1] - p[0]).cross(p[2] - p[0]);
            let m = edge.cross(normal).normalize_or_zero();
            if m != DVec3::ZERO {
                q += Quadric::plane(m, -m.dot(v.pos()), BOUNDARY_WEIGHT * edge.length_squared());
            }
        }
        if let Some(v) = self.store.vertex_mut(id) {
            v.quadric += q;
        }
    }

    /// After each batch: decimate as the policy says, retire what is behind the front, append
    /// finished output.
    pub fn end_batch(&mut self, front: u32, out: &mut OutBatch) {
        if let Some(pass) = &mut self.pass {
            pass.flush(out, &mut self.stats);
            return;
        }
        self.front = f64::from(front);
        self.release_reached();
        if self.config.in_core {
            return;
        }
        self.candidates.activate(self.front);
        let counts = self.face_counts();
        let budget = self.budget();
        self.stats.peak_front_faces = self.stats.peak_front_faces.max(counts.unmodifiable);
        self.note_stretch(budget);
        let until = match &mut self.schedule {
            Schedule::Off => None,
            // Over the memory budget, a pass runs before anything is retired for it, so that what
            // leaves has been decimated (a huge `batch` otherwise emitted raw faces).
            Schedule::Rate(rate) => (rate.due(counts.generated) || counts.resident > budget)
                .then(|| Until::Resident(rate.resident_target(counts))),
            Schedule::Threshold => Some(Until::Exhausted),
        };
        if let Some(until) = until {
            self.decimate(until);
        }
        // Rate: the simplified surface stays resident, as in Hou and Chen 4.3 (R F + B faces),
        // and leaves only when the memory budget says so, oldest first (see `retire`). Other
        // policies retire `retire_lag` slabs behind the front, after a decimation pass, so that
        // no vertex leaves without having been offered to the heap.
        if self.lag_retirement() && (until.is_some() || matches!(self.schedule, Schedule::Off)) {
            self.retire_behind(front, out);
        }
        self.retire_for_memory(out);
        self.compact_candidates();
        self.hand_off(out, false);
    }

    /// First stage of a cascade: announces the rear (see `cascade`) with the batch. The rear
    /// only rises: every vertex held lies at or above the last one announced, and so does every
    /// vertex still to come (new ones start at the front's slab, contractions below the rear are
    /// refused).
    fn hand_off(&mut self, out: &mut OutBatch, end: bool) {
        if self.config.cascade != Cascade::First {
            return;
        }
        if end {
            self.rear = u32::MAX;
        } else if let Some(sweep) = &self.config.sweep {
            let store = &self.store;
            let held = cascade::rear_of(sweep, store.ids().map(|id| store.pos(id)));
            let next = (self.front as u32).saturating_sub(1);
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
            faces_resident: self.store.resident() as u64,
        });
    }

    /// Second stage of a cascade: takes one batch of the first stage's output (vertices with
    /// their states, triangles, and the end of each vertex as its modifiable notice) and
    /// returns the front to close it with (the first stage's rear).
    ///
    /// # Panics
    /// If this simplifier is not a second stage, or the batch is not a first stage's.
    pub fn ingest(&mut self, batch: &OutBatch) -> u32 {
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
                    if let Some(slot) = self.store.slot_of(id)
                        && let Some(v) = self.store.vertex_mut(slot)
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

    /// The resident faces this simplifier may hold before it decimates and retires for memory.
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
    /// memory_budget_mib` bounds the rest; the run summary says by how much it stretched). A
    /// cascade's first stage holds its share plus its band by design (its band is counted in
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
    /// [`Simplifier::budget`] and `retire_for_memory`): all but a cascade's first stage, which
    /// hands its band on to the second.
    fn holds_its_front(&self) -> bool {
        self.config.cascade != Cascade::First
    }

    /// Records `resident` faces held against this simplifier's share (the run summary's
    /// `front_stretch_faces`).
    fn note_stretch(&mut self, resident: usize) {
        let over = resident.saturating_sub(self.share());
        self.stats.front_stretch_faces = self.stats.front_stretch_faces.max(over);
    }

    /// This simplifier's part of the job's face budget (see [`Simplifier::budget`]).
    fn share(&self) -> usize {
        let total = self.config.max_resident_faces;
        match self.config.cascade {
            Cascade::Second => total
                .saturating_sub(self.first_resident)
                .max(total / SECOND_STAGE_FLOOR),
            _ => total,
        }
    }

    /// End of volume: everything is modifiable; final decimation, retire all, emit all.
    pub fn finish(&mut self, out: &mut OutBatch) {
        if let Some(pass) = &mut self.pass {
            pass.finish(out, &mut self.stats);
            return;
        }
        self.front = f64::INFINITY;
        self.release_reached();
        self.store.forget_all_ids();
        let pending: Vec<u64> = self.store.ids().collect();
        for id in pending {
            self.make_modifiable(id);
        }
        self.candidates.activate(self.front);
        let until = match &self.schedule {
            Schedule::Off => None,
            Schedule::Rate(rate) => Some(Until::Resident(rate.final_target(self.face_counts()))),
            Schedule::Threshold => Some(Until::Exhausted),
        };
        if let Some(until) = until {
            self.decimate(until);
            // Edges refused earlier (link, flips) may pass now that their neighbourhoods changed.
            if !self.reached(until) {
                self.requeue_all();
                self.decimate(until);
            }
        }
        self.retire_all(out);
        self.hand_off(out, true);
    }

    pub fn stats(&self) -> SimplifyStats {
        if let Some(pass) = &self.pass {
            return SimplifyStats {
                faces_resident: pass.resident_faces(),
                faces_unmodifiable: pass.unmodifiable_faces(),
                vertices_resident: pass.resident_vertices(),
                ..self.stats.clone()
            };
        }
        SimplifyStats {
            faces_resident: self.store.resident(),
            vertices_resident: self.store.live_vertices(),
            candidates: self.candidates.len(),
            ..self.stats.clone()
        }
    }

    /// Whether vertices retire `retire_lag` slabs behind the front (every policy but rate, which
    /// retires by the memory budget only, unless it is a cascade's first stage, whose output is
    /// not final).
    pub(crate) fn lag_retirement(&self) -> bool {
        !matches!(self.schedule, Schedule::Rate(_)) || self.config.cascade == Cascade::First
    }

    fn face_counts(&self) -> FaceCounts {
        FaceCounts {
            generated: self.stats.faces_in,
            unmodifiable: self.stats.faces_unmodifiable,
            emitted: self.stats.faces_out,
            resident: self.store.resident(),
        }
    }

    fn note_resident(&mut self) {
        let resident = self.pass.as_ref().map_or(
            self.store.resident(),
            passthrough::PassThrough::resident_faces,
        );
        self.stats.peak_resident_faces = self.stats.peak_resident_faces.max(resident);
    }
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

    /// A cascade's second stage at rate 0.5, sweeping along z, with a budget of `faces`.
    fn second_stage(faces: usize) -> Simplifier {
        swept(Cascade::Second, faces)
    }

    /// A simplifier in place `cascade` at rate 0.5, sweeping along z (rank = z), with a budget
    /// of `faces`.
    pub(crate) fn swept(cascade: Cascade, faces: usize) -> Simplifier {
        Simplifier::new(SimplifyConfig {
            cascade,
            max_resident_faces: faces,
            sweep: Some(Sweep {
                direction: DVec3::Z,
                origin: 0.0,
                spacing: 1.0,
            }),
            ..SimplifyConfig::new(Policy::Rate {
                rate: 0.5,
                batch: 1,
                initial_rate: 0.5,
            })
        })
        .unwrap()
    }

    /// A second stage lets a vertex move only once its front (the first stage's rear) has
    /// passed its whole star: a vertex below the rear whose triangle reaches far beyond it could
    /// not contract, so its face must count as unmodifiable for the rate target.
    #[test]
    fn a_second_stage_gates_vertices_by_their_star() {
        let mut s = second_stage(usize::MAX);
        let state = VertexState {
            quadric: Quadric::default(),
            area: 0.0,
            rank_min: 0,
            rank_max: 0,
        };
        let handoff = |rear| Handoff {
            rear,
            rate: 0.5,
            faces_in: 2,
            faces_out: 1,
            faces_resident: 1,
        };
        let batch = OutBatch {
            elements: vec![
                OutElement::Vertex {
                    pos: DVec3::new(0.0, 0.0, 0.5),
                },
                OutElement::Vertex {
                    pos: DVec3::new(1.0, 0.0, 0.5),
                },
                OutElement::Vertex {
                    pos: DVec3::new(0.0, 1.0, 3.5),
                },
                OutElement::Triangle {
                    v: [0, 1, 2],
                    last_use: [true; 3],
                },
            ],
            states: vec![state; 3],
            handoff: Some(handoff(1)),
            ..OutBatch::default()
        };
        let mut out = OutBatch::default();
        let rear = s.ingest(&batch);
        s.end_batch(rear, &mut out);
        assert_eq!(
            s.stats().faces_unmodifiable,
            1,
            "the star reaches rank 3.5, past the rear 1"
        );
        let rear = s.ingest(&OutBatch {
            handoff: Some(handoff(4)),
            ..OutBatch::default()
        });
        s.end_batch(rear, &mut out);
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
                rear: 0,
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
        let single = Simplifier::new(SimplifyConfig {
            max_resident_faces: 900,
            ..SimplifyConfig::new(Policy::None)
        })
        .unwrap();
        assert_eq!(single.budget(), 900);
    }

    /// Faces of the sweep front cannot leave: where they take more than half of the budget it
    /// stretches to hold them with half of it behind them, and the run summary says by how much.
    #[test]
    fn the_sweep_front_stretches_the_budget() {
        let mut s = Simplifier::new(SimplifyConfig {
            max_resident_faces: 10,
            ..config(Policy::Rate {
                rate: 0.5,
                batch: 1,
                initial_rate: 0.5,
            })
        })
        .unwrap();
        // A fan of `n` triangles around vertex 0, nothing modifiable yet.
        let fan = |s: &mut Simplifier, n: u64| {
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
        let mut s2 = Simplifier::new(s.config.clone()).unwrap();
        fan(&mut s2, 12);
        assert_eq!(s2.budget(), 12 + 5);
        s2.end_batch(0, &mut OutBatch::default());
        assert_eq!(s2.stats().front_stretch_faces, 7);
        assert_eq!(s2.stats().peak_front_faces, 12);
    }

    #[test]
    #[should_panic(expected = "unknown or retired vertex")]
    fn triangles_on_unknown_vertices_are_a_contract_violation() {
        let mut s = Simplifier::new(config(Policy::None)).unwrap();
        s.add_vertex(0, DVec3::ZERO, 0, &[]);
        s.add_triangle([0, 1, 2]);
    }
}
