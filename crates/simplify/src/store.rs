//! The resident mesh: vertices of the unretired band and the triangles touching them.
//!
//! Vertex ids arrive in increasing order and retire roughly in that order, so vertices live in a
//! `VecDeque` indexed by `id - base`; freed slots at the front are popped, which keeps memory
//! proportional to the band between the oldest live vertex and the front, never to the surface.
//! Triangles live in a slab with a free list, so their storage is bounded by the peak number of
//! resident triangles.

use std::collections::VecDeque;

use glam::DVec3;
use smallvec::SmallVec;

use crate::quadric::Quadric;

/// Index of a triangle slot in the slab.
pub(crate) type TriId = u32;

/// The triangles around a vertex: about six on a marching-cubes surface, a few more after
/// contractions; stored inline to save an allocation per vertex.
pub(crate) type TriList = SmallVec<[TriId; 8]>;

#[derive(Debug, Clone)]
pub(crate) struct Vertex {
    pub(crate) pos: DVec3,
    /// Sum of the area-weighted plane quadrics of the triangles in the vertex's preimage patch:
    /// Garland and Heckbert's error quadric and the Tandem `H_u` (seed 000, section 3).
    pub(crate) quadric: Quadric,
    /// Sum of those triangle areas, `W_u` of the Tandem shape measure.
    pub(crate) area: f64,
    /// Lowest and highest rank (z plane) in the preimage. The highest decides when the vertex is
    /// behind the front; the span between them is bounded (see `Simplifier::rank_span`).
    pub(crate) rank_min: u32,
    pub(crate) rank_max: u32,
    /// Rank bucket the vertex is currently filed under (stale bucket entries are skipped).
    pub(crate) bucket: u32,
    /// Tandem time-lag estimate of the preimage patch: centre height and radius, in rank units
    /// (seed 000, section 3, "Time-lag").
    pub(crate) height: f64,
    pub(crate) rad: f64,
    /// All triangles of the vertex exist (detector's word); only then may it move.
    pub(crate) modifiable: bool,
    /// Behind the front: never moves again, its edges are no candidates.
    pub(crate) retired: bool,
    /// On the surface boundary. Known once the vertex is modifiable (its fan is complete) and
    /// inherited through contractions: the boundary rule only ever places a merged vertex on the
    /// boundary when an endpoint was on it, and the link condition keeps interior vertices
    /// interior.
    pub(crate) boundary: bool,
    /// Bumped whenever the vertex changes, to invalidate heap entries lazily.
    pub(crate) stamp: u32,
    /// Output number once emitted.
    pub(crate) out: Option<u64>,
    pub(crate) tris: TriList,
    pub(crate) attrs: Box<[f32]>,
    /// Position-and-attribute quadric of the preimage (attribute-quadric priority only).
    pub(crate) attr_quadric: Option<Box<crate::attribute_quadric::AttrQuadric>>,
}

impl Vertex {
    pub(crate) fn new(pos: DVec3, rank: u32, attrs: &[f32]) -> Self {
        Self {
            pos,
            quadric: Quadric::default(),
            area: 0.0,
            rank_min: rank,
            rank_max: rank,
            bucket: rank,
            height: f64::from(rank),
            rad: 1.0,
            modifiable: false,
            retired: false,
            boundary: false,
            stamp: 0,
            out: None,
            tris: TriList::new(),
            attrs: attrs.into(),
            attr_quadric: None,
        }
    }

    /// May be moved by a contraction.
    pub(crate) fn is_free(&self) -> bool {
        self.modifiable && !self.retired
    }

    /// Rank span of the preimage of the vertex replacing this one and `other`.
    pub(crate) fn merged_span(&self, other: &Vertex) -> u32 {
        self.rank_max.max(other.rank_max) - self.rank_min.min(other.rank_min)
    }

    /// Reach of the patch created by contracting this vertex with `other`:
    /// `height(c) + rad(c)` with `height(c) = (height(a) + height(b)) / 2` and
    /// `rad(c) = (|a - b| + rad(a) + rad(b)) / 2` (seed 000, section 3, "Time-lag").
    /// `rank_spacing` converts the physical edge length into rank units.
    pub(crate) fn merged_patch(&self, other: &Vertex, rank_spacing: f64) -> (f64, f64) {
        let height = 0.5 * (self.height + other.height);
        let rad = 0.5 * ((self.pos - other.pos).length() / rank_spacing + self.rad + other.rad);
        (height, rad)
    }
}

#[derive(Debug, Clone, Copy)]
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

    /// The vertex that is neither `a` nor `b`.
    pub(crate) fn third(&self, a: u64, b: u64) -> u64 {
        self.v
            .iter()
            .copied()
            .find(|&x| x != a && x != b)
            .unwrap_or(a)
    }
}

#[derive(Debug, Default)]
pub(crate) struct Store {
    verts: VecDeque<Option<Vertex>>,
    base: u64,
    tris: Vec<Tri>,
    free_tris: Vec<TriId>,
    resident: usize,
}

impl Store {
    pub(crate) fn vertex(&self, id: u64) -> Option<&Vertex> {
        let i = usize::try_from(id.checked_sub(self.base)?).ok()?;
        self.verts.get(i)?.as_ref()
    }

    pub(crate) fn vertex_mut(&mut self, id: u64) -> Option<&mut Vertex> {
        let i = usize::try_from(id.checked_sub(self.base)?).ok()?;
        self.verts.get_mut(i)?.as_mut()
    }

    /// Ids of the live vertices, ascending.
    pub(crate) fn ids(&self) -> impl Iterator<Item = u64> + '_ {
        (self.base..)
            .zip(&self.verts)
            .filter_map(|(id, v)| v.as_ref().map(|_| id))
    }

    /// Stores a vertex under `id`. Ids normally arrive in increasing order (then this is a push at
    /// the back); an id below the band or into a hole is accepted too, at the cost of slots.
    ///
    /// # Panics
    /// If a live vertex already has this id.
    pub(crate) fn insert_vertex(&mut self, id: u64, v: Vertex) {
        if self.verts.is_empty() {
            self.base = id;
        }
        while id < self.base {
            self.verts.push_front(None);
            self.base -= 1;
        }
        let i = usize::try_from(id - self.base).expect("vertex band fits in memory");
        if i >= self.verts.len() {
            self.verts.resize_with(i + 1, || None);
        }
        let slot = &mut self.verts[i];
        assert!(slot.is_none(), "vertex id {id} added twice");
        *slot = Some(v);
    }

    pub(crate) fn remove_vertex(&mut self, id: u64) -> Option<Vertex> {
        let i = usize::try_from(id.checked_sub(self.base)?).ok()?;
        let v = self.verts.get_mut(i)?.take();
        while matches!(self.verts.front(), Some(None)) {
            self.verts.pop_front();
            self.base += 1;
        }
        v
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

    /// Vertex slots held: live vertices and the holes between them.
    pub(crate) fn vertex_slots(&self) -> usize {
        self.verts.len()
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
    pub(crate) fn remove_triangle(&mut self, t: TriId) -> Tri {
        let tri = self.tris[t as usize];
        for id in tri.v {
            if let Some(v) = self.vertex_mut(id)
                && let Some(i) = v.tris.iter().position(|&x| x == t)
            {
                v.tris.swap_remove(i);
            }
        }
        self.free_tris.push(t);
        self.resident -= 1;
        tri
    }

    /// Positions of a triangle's corners.
    pub(crate) fn corners(&self, tri: &Tri) -> [DVec3; 3] {
        tri.v
            .map(|id| self.vertex(id).map_or(DVec3::ZERO, |v| v.pos))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_are_reused_and_the_front_is_popped() {
        let mut s = Store::default();
        for id in [10, 11, 13] {
            s.insert_vertex(id, Vertex::new(DVec3::ZERO, 0, &[]));
        }
        assert!(s.vertex(12).is_none());
        let t = s.add_triangle(Tri {
            v: [10, 11, 13],
            unmodifiable: 3,
        });
        assert_eq!(s.vertex(13).unwrap().tris.as_slice(), &[t]);
        s.remove_triangle(t);
        assert_eq!(s.resident(), 0);
        assert!(s.vertex(11).unwrap().tris.is_empty());
        let t2 = s.add_triangle(Tri {
            v: [13, 11, 10],
            unmodifiable: 0,
        });
        assert_eq!(t, t2, "freed slot is reused");
        s.remove_vertex(10);
        s.remove_vertex(11);
        assert_eq!(s.ids().collect::<Vec<_>>(), vec![13]);
        assert_eq!(s.verts.len(), 1, "gap and freed slots popped");
    }

    #[test]
    fn ids_out_of_order_are_accepted() {
        let mut s = Store::default();
        for id in [5, 8, 3, 6] {
            s.insert_vertex(id, Vertex::new(DVec3::ZERO, 0, &[]));
        }
        assert_eq!(s.ids().collect::<Vec<_>>(), vec![3, 5, 6, 8]);
    }

    #[test]
    #[should_panic(expected = "added twice")]
    fn ids_are_unique() {
        let mut s = Store::default();
        s.insert_vertex(5, Vertex::new(DVec3::ZERO, 0, &[]));
        s.insert_vertex(5, Vertex::new(DVec3::ZERO, 0, &[]));
    }
}
