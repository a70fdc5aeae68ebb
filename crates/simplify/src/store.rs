//! The resident mesh: vertices of the unretired band and the triangles touching them.
//!
//! Vertices live in slots (a `Vec` with a free list) and every handle inside the simplifier is a
//! slot number, so memory follows the live vertices: indexing by `id - base` kept a slot for every
//! vertex between the oldest live one and the front, which is the whole surface once the
//! simplified surface stays resident (rate mode, `retire`). The detector's ids are translated at
//! the door ([`Store::slot_of`]) and forgotten once a vertex can receive no more triangles, so the
//! map holds the front only. Slots are reused last-freed first: deterministic for a given input.
//! Triangles live in a slab with a free list, so their storage is bounded by the peak number of
//! resident triangles.

use std::cell::Cell;

use glam::{DVec3, Vec3};
use smallvec::SmallVec;

use crate::quadric::Quadric;

/// Index of a triangle slot in the slab.
pub(crate) type TriId = u32;

/// The triangles around a vertex: about six on a marching-cubes surface, a few more after
/// contractions; stored inline to save an allocation per vertex.
pub(crate) type TriList = SmallVec<[TriId; 8]>;

/// The output number of a vertex not written yet (here and in the pass-through band).
pub(crate) const UNWRITTEN: u64 = u64::MAX;

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct Vertex {
    /// Sum of the area-weighted plane quadrics of the triangles in the vertex's preimage patch:
    /// Garland and Heckbert's error quadric and the Tandem `H_u` (seed 000, section 3).
    pub(crate) quadric: Quadric,
    /// Sum of those triangle areas, `W_u` of the Tandem shape measure.
    pub(crate) area: f64,
    /// Lowest and highest rank (z plane) in the preimage. The highest decides when the vertex is
    /// behind the front; the span between them is bounded (see `Decimator::span_ok`).
    pub(crate) rank_min: u32,
    pub(crate) rank_max: u32,
    /// Rank bucket the vertex is currently filed under (stale bucket entries are skipped).
    pub(crate) bucket: u32,
    /// On the surface boundary. Known once the vertex is modifiable (its fan is complete) and
    /// inherited through contractions: the boundary rule only ever places a merged vertex on the
    /// boundary when an endpoint was on it, and the link condition keeps interior vertices
    /// interior.
    pub(crate) boundary: bool,
    /// Output number once emitted, [`UNWRITTEN`] before (8 bytes where an `Option` took 16).
    out: u64,
    pub(crate) tris: TriList,
}

/// What only some policies keep of a vertex, beside the vertices by slot ([`Store::extra`]):
/// the default job (mode `rate`, the geometric priority) has none of it, and its vertices were
/// 40 bytes larger while they carried it (152 bytes now, the attributes beside them too:
/// [`Store::attrs`]).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct Extra {
    /// Tandem time-lag estimate of the preimage patch: centre height and radius, in rank units
    /// (seed 000, section 3, "Time-lag").
    pub(crate) height: f64,
    pub(crate) rad: f64,
    /// Position-and-attribute quadric of the preimage (attribute-quadric priority only).
    pub(crate) attr_quadric: Option<Box<crate::attribute_quadric::AttrQuadric>>,
    /// The data-dependent priority's terms of this vertex once computed (absolute angle
    /// deficit, attribute gradient), NaN until then and again after a contraction changed its
    /// star or a neighbour (`data_dependent::weight`). A `Cell` because costs are evaluated on
    /// a shared store.
    pub(crate) weight_terms: Cell<[f64; 2]>,
}

impl Extra {
    /// A vertex's first state at rank `rank`: a patch of radius one around it.
    fn new(rank: u32) -> Self {
        Self {
            height: f64::from(rank),
            rad: 1.0,
            attr_quadric: None,
            weight_terms: Cell::new([f64::NAN; 2]),
        }
    }

    /// Reach of the patch created by contracting this vertex with `other`, `length` away:
    /// `height(c) + rad(c)` with `height(c) = (height(a) + height(b)) / 2` and
    /// `rad(c) = (|a - b| + rad(a) + rad(b)) / 2` (seed 000, section 3, "Time-lag").
    /// `rank_spacing` converts the physical edge length into rank units.
    pub(crate) fn merged_patch(&self, other: &Extra, length: f64, rank_spacing: f64) -> (f64, f64) {
        let height = 0.5 * (self.height + other.height);
        let rad = 0.5 * (length / rank_spacing + self.rad + other.rad);
        (height, rad)
    }
}

impl Vertex {
    /// A vertex first seen at rank `rank` (its position and attributes are the store's:
    /// [`Store::insert_vertex`]).
    pub(crate) fn new(rank: u32) -> Self {
        Self {
            quadric: Quadric::default(),
            area: 0.0,
            rank_min: rank,
            rank_max: rank,
            bucket: rank,
            boundary: false,
            out: UNWRITTEN,
            tris: TriList::new(),
        }
    }

    /// Its output number, once it has been written.
    pub(crate) fn out(&self) -> Option<u64> {
        (self.out != UNWRITTEN).then_some(self.out)
    }

    /// It is written as output number `o`.
    pub(crate) fn set_out(&mut self, o: u64) {
        debug_assert_ne!(o, UNWRITTEN, "fewer than 2^64 - 1 output vertices");
        self.out = o;
    }

    /// Rank span of the preimage of the vertex replacing this one and `other`.
    pub(crate) fn merged_span(&self, other: &Vertex) -> u32 {
        self.rank_max.max(other.rank_max) - self.rank_min.min(other.rank_min)
    }
}

#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub(crate) struct Tri {
    pub(crate) v: [u64; 3],
    /// How many of the three vertices are not yet modifiable; `> 0` counts toward Hou and Chen's
    /// `F_u` (section 4.2), kept per triangle so that `F_u` is maintained in O(1).
    pub(crate) unmodifiable: u8,
}

impl Tri {
    pub(crate) fn contains(&self, id: u64) -> bool {
        self.v.contains(&id)
    }
}

/// A vertex handle: slot in the low 32 bits, the slot's generation in the high ones, so that a
/// handle kept anywhere (heap entries, rank buckets, the intersection index's emitted triangles)
/// never names the vertex that reuses its slot later.
fn handle(slot: usize, generation: u32) -> u64 {
    (u64::from(generation) << 32) | slot as u64
}

/// What the hottest tests read of a slot, kept dense rather than in the [`Vertex`]:
/// whether a handle still names the slot's vertex (`generation`, bumped when the vertex leaves),
/// and that vertex's `state`: [`MODIFIABLE`] (all its triangles exist, the detector's word),
/// [`RETIRED`] (behind the front: it never moves again, its edges are no candidates) and its
/// stamp, bumped whenever it changes so that heap entries are invalidated lazily. A popped
/// candidate is stale about five times per contraction; read from the vertex, each test was a
/// cache miss (7 % of a run's last-level misses by cachegrind), from here mostly not.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
struct Slot {
    generation: u32,
    state: u32,
    /// The vertex's position, its only copy: reading a triangle's corners (the patch, the
    /// guard's updates, the second stage's star reach) from the vertices touched three vertices
    /// (of 248 bytes then), each a cache miss, for 12 bytes each. Here beside the generation that
    /// every read checks first, a corner is one cache line. [`Store::set_pos`] is its one
    /// writer. In `f32`, which loses nothing: every position is rounded to `f32` where it is
    /// made ([`crate::cost::output_precision`]).
    pos: Vec3,
}

const MODIFIABLE: u32 = 1;
const RETIRED: u32 = 2;
/// The stamp is `state >> 2`, wrapping in 30 bits.
const STAMP_ONE: u32 = 4;

#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Store {
    verts: Vec<Option<Vertex>>,
    slots: Vec<Slot>,
    free_verts: Vec<usize>,
    /// Detector id -> handle, for vertices that may still receive triangles.
    handles: rustc_hash::FxHashMap<u64, u64>,
    live_verts: usize,
    tris: Vec<Tri>,
    free_tris: Vec<TriId>,
    resident: usize,
    /// Each slot's [`Extra`], when the policy keeps them ([`Store::keeping_extras`]); empty
    /// otherwise.
    extras: Vec<Extra>,
    keeps_extras: bool,
    /// Each slot's attribute values (`[[attributes]]`), empty when the job has none: beside the
    /// vertices rather than in them, where an empty box cost every vertex 16 bytes (a tenth of
    /// it) in the jobs without attributes.
    attrs: Vec<Box<[f32]>>,
}

impl Store {
    /// A store that keeps each vertex's [`Extra`]: for the Tandem time-lag and the
    /// data-dependent and attribute-quadric priorities.
    pub(crate) fn keeping_extras() -> Self {
        Self {
            keeps_extras: true,
            ..Self::default()
        }
    }

    /// What the policy keeps of vertex `v` besides the vertex (`None` when it keeps nothing,
    /// or for a handle that names no vertex).
    pub(crate) fn extra(&self, v: u64) -> Option<&Extra> {
        let slot = self.slot(v)?;
        self.verts[slot].as_ref()?;
        self.extras.get(slot)
    }

    pub(crate) fn extra_mut(&mut self, v: u64) -> Option<&mut Extra> {
        let slot = self.slot(v)?;
        self.verts[slot].as_ref()?;
        self.extras.get_mut(slot)
    }

    /// The attribute values of vertex `v` (empty without `[[attributes]]`, or for a handle that
    /// names no vertex).
    pub(crate) fn attrs(&self, v: u64) -> &[f32] {
        self.slot(v)
            .filter(|&slot| self.verts[slot].is_some())
            .and_then(|slot| self.attrs.get(slot))
            .map_or(&[], |a| a)
    }

    /// Vertex `v` now carries `attrs` (a contraction's merged values).
    pub(crate) fn set_attrs(&mut self, v: u64, attrs: Box<[f32]>) {
        if let Some(slot) = self.slot(v)
            && let Some(a) = self.attrs.get_mut(slot)
        {
            *a = attrs;
        }
    }

    /// The slot `v` names and its entry, while the handle is current.
    fn entry(&self, v: u64) -> Option<(usize, &Slot)> {
        let slot = (v & u64::from(u32::MAX)) as usize;
        let s = self.slots.get(slot)?;
        (s.generation == (v >> 32) as u32).then_some((slot, s))
    }

    fn slot(&self, v: u64) -> Option<usize> {
        self.entry(v).map(|(slot, _)| slot)
    }

    pub(crate) fn vertex(&self, v: u64) -> Option<&Vertex> {
        self.verts[self.slot(v)?].as_ref()
    }

    pub(crate) fn vertex_mut(&mut self, v: u64) -> Option<&mut Vertex> {
        let slot = self.slot(v)?;
        self.verts[slot].as_mut()
    }

    /// Handles of the live vertices, by slot.
    pub(crate) fn ids(&self) -> impl Iterator<Item = u64> + '_ {
        self.verts
            .iter()
            .zip(&self.slots)
            .enumerate()
            .filter_map(|(slot, (x, s))| x.as_ref().map(|_| handle(slot, s.generation)))
    }

    /// Stores a vertex known to the detector as `id`, at `pos` (rounded to `f32`), and returns
    /// its handle.
    ///
    /// # Panics
    /// If a vertex that may still receive triangles already has this id.
    pub(crate) fn insert_vertex(&mut self, id: u64, pos: DVec3, v: Vertex, attrs: &[f32]) -> u64 {
        // A no-op for the stream's vertices, rounded at the door by `vertex_input`: every
        // position in the store is `f32`-exact.
        let pos = crate::cost::output_precision(pos).as_vec3();
        let rank = v.rank_min;
        let slot = match self.free_verts.pop() {
            Some(slot) => {
                self.slots[slot].pos = pos;
                self.verts[slot] = Some(v);
                self.slots[slot].state = 0;
                slot
            }
            None => {
                assert!(
                    self.verts.len() < u32::MAX as usize,
                    "fewer than 2^32 resident vertices"
                );
                self.verts.push(Some(v));
                self.slots.push(Slot {
                    pos,
                    ..Slot::default()
                });
                self.verts.len() - 1
            }
        };
        if self.keeps_extras {
            let extra = Extra::new(rank);
            match self.extras.get_mut(slot) {
                Some(e) => *e = extra,
                None => self.extras.push(extra),
            }
        }
        if !attrs.is_empty() {
            if self.attrs.len() <= slot {
                self.attrs.resize_with(slot + 1, Box::default);
            }
            self.attrs[slot] = attrs.into();
        }
        let h = handle(slot, self.slots[slot].generation);
        let old = self.handles.insert(id, h);
        assert!(old.is_none(), "vertex id {id} added twice");
        self.live_verts += 1;
        h
    }

    /// The handle of detector id `id`, while the vertex may still receive triangles.
    pub(crate) fn slot_of(&self, id: u64) -> Option<u64> {
        self.handles.get(&id).copied()
    }

    /// Detector id `id` will name no more triangles.
    pub(crate) fn forget_id(&mut self, id: u64) {
        self.handles.remove(&id);
    }

    /// Every detector id is forgotten (end of the volume).
    pub(crate) fn forget_all_ids(&mut self) {
        self.handles.clear();
    }

    pub(crate) fn remove_vertex(&mut self, v: u64) -> Option<Vertex> {
        let slot = self.slot(v)?;
        let x = self.verts[slot].take()?;
        if let Some(e) = self.extras.get_mut(slot) {
            e.attr_quadric = None;
        }
        if let Some(a) = self.attrs.get_mut(slot) {
            *a = Box::default();
        }
        self.slots[slot].generation = self.slots[slot].generation.wrapping_add(1);
        // A free slot's position is NaN (`Store::positions` skips it).
        self.slots[slot].pos = Vec3::NAN;
        self.free_verts.push(slot);
        self.live_verts -= 1;
        Some(x)
    }

    fn state(&self, v: u64) -> u32 {
        self.slot(v).map_or(0, |slot| self.slots[slot].state)
    }

    fn set_state(&mut self, v: u64, f: impl FnOnce(u32) -> u32) {
        if let Some(slot) = self.slot(v) {
            self.slots[slot].state = f(self.slots[slot].state);
        }
    }

    /// All of `v`'s triangles exist (false for a handle that names no vertex).
    pub(crate) fn is_modifiable(&self, v: u64) -> bool {
        self.state(v) & MODIFIABLE != 0
    }

    pub(crate) fn set_modifiable(&mut self, v: u64) {
        self.set_state(v, |s| s | MODIFIABLE);
    }

    /// `v` never moves again (false for a handle that names no vertex).
    pub(crate) fn is_retired(&self, v: u64) -> bool {
        self.state(v) & RETIRED != 0
    }

    pub(crate) fn retire(&mut self, v: u64) {
        self.set_state(v, |s| s | RETIRED);
    }

    /// `v` may be moved by a contraction.
    pub(crate) fn is_free(&self, v: u64) -> bool {
        self.state(v) & (MODIFIABLE | RETIRED) == MODIFIABLE
    }

    /// `v`'s stamp (0 for a handle that names no vertex).
    pub(crate) fn stamp(&self, v: u64) -> u32 {
        self.state(v) / STAMP_ONE
    }

    pub(crate) fn bump_stamp(&mut self, v: u64) {
        self.set_state(v, |s| s.wrapping_add(STAMP_ONE));
    }

    /// `v` is free and still has stamp `stamp`.
    pub(crate) fn is_current(&self, v: u64, stamp: u32) -> bool {
        let s = self.state(v);
        s & (MODIFIABLE | RETIRED) == MODIFIABLE && s / STAMP_ONE == stamp
    }

    pub(crate) fn tri(&self, t: TriId) -> &Tri {
        &self.tris[t as usize]
    }

    pub(crate) fn tri_mut(&mut self, t: TriId) -> &mut Tri {
        &mut self.tris[t as usize]
    }

    pub(crate) fn resident(&self) -> usize {
        self.resident
    }

    /// Vertices held (free slots are bounded by the peak of this).
    pub(crate) fn live_vertices(&self) -> usize {
        self.live_verts
    }

    /// Adds a triangle and links it into its vertices' lists. The vertices must exist.
    pub(crate) fn add_triangle(&mut self, tri: Tri) -> TriId {
        let t = match self.free_tris.pop() {
            Some(t) => {
                self.tris[t as usize] = tri;
                t
            }
            None => {
                self.tris.push(tri);
                TriId::try_from(self.tris.len() - 1).expect("fewer than 2^32 resident triangles")
            }
        };
        for id in tri.v {
            if let Some(v) = self.vertex_mut(id) {
                v.tris.push(t);
            }
        }
        self.resident += 1;
        t
    }

    /// Unlinks a triangle from its vertices and frees its slot.
    ///
    /// A vertex's list that spilled to the heap (more than its inline room, as a contraction's
    /// survivor briefly has) goes back inline once it fits again: `SmallVec` keeps a spilled
    /// list on the heap for good otherwise, and with the simplified surface resident the
    /// vertices that ever had nine triangles piled up (bonsai upsampled to 511^3 at a 128 MiB
    /// budget: 52 k heap lists after 448 slabs, 4.5 k with this; peak RSS 110.7 -> 108.1 MiB,
    /// the same output).
    pub(crate) fn remove_triangle(&mut self, t: TriId) -> Tri {
        let tri = self.tris[t as usize];
        for id in tri.v {
            if let Some(v) = self.vertex_mut(id)
                && let Some(i) = v.tris.iter().position(|&x| x == t)
            {
                v.tris.swap_remove(i);
                if v.tris.spilled() && v.tris.len() <= v.tris.inline_size() {
                    v.tris.shrink_to_fit();
                }
            }
        }
        self.free_tris.push(t);
        self.resident -= 1;
        tri
    }

    /// Position of vertex `v`, if the handle names one.
    pub(crate) fn position(&self, v: u64) -> Option<DVec3> {
        self.entry(v).map(|(_, s)| s.pos.as_dvec3())
    }

    /// Position of vertex `v` (zero for a handle that names no vertex).
    pub(crate) fn pos(&self, v: u64) -> DVec3 {
        self.position(v).unwrap_or(DVec3::ZERO)
    }

    /// The triangles of vertex `v` (none for a handle that names no vertex).
    pub(crate) fn tris_of(&self, v: u64) -> &[TriId] {
        self.vertex(v).map_or(&[], |x| &x.tris[..])
    }

    /// Handles and positions of the live vertices, by slot: the dense scan for what needs only
    /// where the vertices are (a cascade's rear and catch-up, at every hand-off). Walking
    /// [`Store::ids`] reads every vertex record, many times larger than its slot: on hydrogen
    /// upsampled to 4033^3 that walk was about 5 % of the first stage's samples.
    pub(crate) fn positions(&self) -> impl Iterator<Item = (u64, DVec3)> + '_ {
        self.slots
            .iter()
            .enumerate()
            .filter(|(_, s)| !s.pos.x.is_nan())
            .map(|(slot, s)| (handle(slot, s.generation), s.pos.as_dvec3()))
    }

    /// Moves vertex `v` to `pos`.
    pub(crate) fn set_pos(&mut self, v: u64, pos: DVec3) {
        if let Some(slot) = self.slot(v)
            && self.verts[slot].is_some()
        {
            debug_assert_eq!(pos.as_vec3().as_dvec3(), pos, "positions are f32-exact");
            self.slots[slot].pos = pos.as_vec3();
        }
    }

    /// Positions of a triangle's corners.
    pub(crate) fn corners(&self, tri: &Tri) -> [DVec3; 3] {
        tri.v.map(|id| self.pos(id))
    }

    /// The slot handle `v` names (current or not): a store split from this one
    /// ([`Store::split_off`]) has the same slots.
    pub(crate) fn slot_index(v: u64) -> usize {
        (v & u64::from(u32::MAX)) as usize
    }

    /// The handle of the vertex in `slot`, if one lives there.
    pub(crate) fn handle_at(&self, slot: usize) -> Option<u64> {
        let live = self.verts.get(slot)?.is_some();
        live.then(|| handle(slot, self.slots[slot].generation))
    }

    /// Vertex `v` may not move until [`Store::thaw`] (a seam corner while two workers
    /// decimate either side of it, `seam`): it reads as retired, so no candidate names it.
    pub(crate) fn freeze(&mut self, v: u64) {
        self.set_state(v, |s| s | RETIRED);
    }

    pub(crate) fn thaw(&mut self, v: u64) {
        self.set_state(v, |s| s & !RETIRED);
    }

    /// Moves the vertices in `slots` and the triangles `tris` (the other side of a cut:
    /// `seam`) into a store of the same slots and handles for a second worker, which then
    /// holds the vertices' data and counts those triangles as its own. This store keeps the
    /// slots, marked retired so that none of its candidates names them, and the triangles'
    /// last values, until [`Store::absorb`] takes back what the other made of them. Positions,
    /// slots and triangles are copied (the seam's corners and triangles are read on both
    /// sides), the vertex records are moved: they are most of the memory.
    pub(crate) fn split_off(&mut self, slots: &[usize], tris: &[TriId]) -> Store {
        let mut other = Store {
            verts: (0..self.verts.len()).map(|_| None).collect(),
            slots: self.slots.clone(),
            free_verts: Vec::new(),
            handles: rustc_hash::FxHashMap::default(),
            live_verts: slots.len(),
            tris: self.tris.clone(),
            free_tris: Vec::new(),
            resident: tris.len(),
            extras: self.extras.clone(),
            keeps_extras: self.keeps_extras,
            attrs: self.attrs.clone(),
        };
        for &slot in slots {
            other.verts[slot] = self.verts[slot].take();
            self.slots[slot].state |= RETIRED;
        }
        self.live_verts -= slots.len();
        self.resident -= tris.len();
        other
    }

    /// Takes back the vertices in `slots` and the triangles `tris` from the store
    /// [`Store::split_off`] gave them to, as its worker left them (moved, merged away, freed):
    /// that worker changed no other slot, and this store changed none of these.
    pub(crate) fn absorb(&mut self, mut other: Store, slots: &[usize], tris: &[TriId]) {
        for &slot in slots {
            self.verts[slot] = other.verts[slot].take();
            self.slots[slot] = other.slots[slot];
            if let (Some(e), Some(mine)) = (other.extras.get(slot), self.extras.get_mut(slot)) {
                *mine = e.clone();
            }
            if let (Some(a), Some(mine)) = (other.attrs.get_mut(slot), self.attrs.get_mut(slot)) {
                *mine = std::mem::take(a);
            }
        }
        for &t in tris {
            self.tris[t as usize] = other.tris[t as usize];
        }
        self.free_verts.extend(other.free_verts);
        self.free_tris.extend(other.free_tris);
        self.live_verts += other.live_verts;
        self.resident += other.resident;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_are_reused_under_new_handles() {
        let mut s = Store::default();
        let slots: Vec<u64> = [10, 11, 13]
            .map(|id| s.insert_vertex(id, DVec3::ZERO, Vertex::new(0), &[]))
            .to_vec();
        assert_eq!(slots, vec![0, 1, 2]);
        assert_eq!(s.slot_of(13), Some(2));
        assert_eq!(s.slot_of(12), None);
        let t = s.add_triangle(Tri {
            v: [0, 1, 2],
            unmodifiable: 3,
        });
        assert_eq!(s.vertex(2).unwrap().tris.as_slice(), &[t]);
        s.remove_triangle(t);
        assert_eq!(s.resident(), 0);
        assert!(s.vertex(1).unwrap().tris.is_empty());
        let t2 = s.add_triangle(Tri {
            v: [2, 1, 0],
            unmodifiable: 0,
        });
        assert_eq!(t, t2, "freed slot is reused");
        s.forget_id(10);
        assert_eq!(s.slot_of(10), None);
        s.set_pos(2, DVec3::new(1.0, 2.0, 3.0));
        s.remove_vertex(0);
        assert_eq!(s.ids().collect::<Vec<_>>(), vec![1, 2]);
        let dense: Vec<(u64, DVec3)> = s.positions().collect();
        assert_eq!(
            dense,
            vec![(1, DVec3::ZERO), (2, DVec3::new(1.0, 2.0, 3.0))]
        );
        assert!(s.vertex(0).is_none());
        let reused = s.insert_vertex(20, DVec3::ZERO, Vertex::new(0), &[]);
        assert_eq!(
            s.positions().map(|(h, _)| h).collect::<Vec<_>>(),
            vec![reused, 1, 2]
        );
        assert_eq!(reused & 0xffff_ffff, 0, "slot 0 is reused");
        assert_ne!(reused, 0, "under a new handle");
        assert!(s.vertex(0).is_none(), "the old handle names nothing");
        assert_eq!(s.verts.len(), 3, "no slot for a gap");
        assert_eq!(s.live_vertices(), 3);
    }

    /// A list that spilled past its inline room goes back inline when triangles leave it.
    #[test]
    fn triangle_lists_go_back_inline_when_they_fit() {
        let mut s = Store::default();
        let hub = s.insert_vertex(0, DVec3::ZERO, Vertex::new(0), &[]);
        let room = s.vertex(hub).unwrap().tris.inline_size();
        let rim: Vec<u64> = (1..=room as u64 + 2)
            .map(|id| s.insert_vertex(id, DVec3::ZERO, Vertex::new(0), &[]))
            .collect();
        let fan: Vec<TriId> = rim
            .windows(2)
            .map(|w| {
                s.add_triangle(Tri {
                    v: [hub, w[0], w[1]],
                    unmodifiable: 0,
                })
            })
            .collect();
        assert_eq!(fan.len(), room + 1);
        assert!(s.vertex(hub).unwrap().tris.spilled());
        s.remove_triangle(fan[0]);
        let tris = &s.vertex(hub).unwrap().tris;
        assert!(!tris.spilled(), "back inline");
        assert_eq!(tris.len(), room);
        assert!(tris.iter().all(|t| fan[1..].contains(t)));
    }

    /// The flags and stamp follow the vertex through its life, a stale stamp or a dead handle is
    /// never current, and a reused slot starts unmodifiable with stamp 0.
    #[test]
    fn slot_state_follows_the_vertex() {
        let mut s = Store::default();
        let v = s.insert_vertex(1, DVec3::ZERO, Vertex::new(0), &[]);
        assert!(!s.is_free(v) && !s.is_modifiable(v) && !s.is_retired(v));
        s.set_modifiable(v);
        assert!(s.is_free(v) && s.is_current(v, 0));
        s.bump_stamp(v);
        assert_eq!(s.stamp(v), 1);
        assert!(!s.is_current(v, 0) && s.is_current(v, 1));
        s.retire(v);
        assert!(s.is_retired(v) && s.is_modifiable(v) && !s.is_free(v) && !s.is_current(v, 1));
        s.remove_vertex(v);
        assert!(!s.is_retired(v) && !s.is_current(v, 1), "a dead handle");
        let w = s.insert_vertex(2, DVec3::ZERO, Vertex::new(0), &[]);
        assert_eq!(w & 0xffff_ffff, v & 0xffff_ffff, "the slot is reused");
        assert!(!s.is_modifiable(w) && !s.is_retired(w) && s.stamp(w) == 0);
    }

    /// Only a store that keeps extras has them, and a reused slot starts its vertex's afresh.
    #[test]
    fn extras_are_kept_only_when_asked_and_start_afresh() {
        let mut plain = Store::default();
        let v = plain.insert_vertex(1, DVec3::ZERO, Vertex::new(3), &[]);
        assert!(plain.extra(v).is_none());
        let mut s = Store::keeping_extras();
        let v = s.insert_vertex(1, DVec3::ZERO, Vertex::new(3), &[]);
        let e = s.extra(v).expect("kept");
        assert_eq!((e.height, e.rad), (3.0, 1.0));
        s.extra_mut(v).unwrap().height = 9.0;
        s.forget_id(1);
        s.remove_vertex(v);
        assert!(s.extra(v).is_none(), "a dead handle has none");
        let w = s.insert_vertex(2, DVec3::ZERO, Vertex::new(5), &[]);
        assert_eq!(w & 0xffff_ffff, v & 0xffff_ffff, "the slot is reused");
        assert_eq!(s.extra(w).map(|e| e.height), Some(5.0));
    }

    /// Attributes live beside the vertices: a job without them gives no vertex room for them,
    /// a dead handle has none, and a reused slot starts with the new vertex's.
    #[test]
    fn attributes_follow_their_vertex_beside_it() {
        assert_eq!(std::mem::size_of::<Vertex>(), 152);
        assert_eq!(
            std::mem::size_of::<Option<Vertex>>(),
            152,
            "a niche, no tag"
        );
        let mut plain = Store::default();
        let v = plain.insert_vertex(1, DVec3::ZERO, Vertex::new(0), &[]);
        assert!(plain.attrs(v).is_empty());
        assert!(plain.attrs.is_empty(), "no room without attributes");
        let mut s = Store::default();
        let a = s.insert_vertex(1, DVec3::ZERO, Vertex::new(0), &[1.0, 2.0]);
        let b = s.insert_vertex(2, DVec3::ZERO, Vertex::new(0), &[3.0, 4.0]);
        assert_eq!((s.attrs(a), s.attrs(b)), (&[1.0, 2.0][..], &[3.0, 4.0][..]));
        s.set_attrs(b, Box::new([5.0, 6.0]));
        assert_eq!(s.attrs(b), &[5.0, 6.0]);
        s.forget_id(1);
        s.remove_vertex(a);
        assert!(s.attrs(a).is_empty(), "a dead handle has none");
        let c = s.insert_vertex(3, DVec3::ZERO, Vertex::new(0), &[7.0, 8.0]);
        assert_eq!(c & 0xffff_ffff, a & 0xffff_ffff, "the slot is reused");
        assert_eq!(s.attrs(c), &[7.0, 8.0]);
    }

    #[test]
    #[should_panic(expected = "added twice")]
    fn ids_are_unique() {
        let mut s = Store::default();
        s.insert_vertex(5, DVec3::ZERO, Vertex::new(0), &[]);
        s.insert_vertex(5, DVec3::ZERO, Vertex::new(0), &[]);
    }
}
