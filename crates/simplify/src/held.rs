//! A cascade's second stage holds back what lies wholly above its front.
//!
//! The second stage's front is the first stage's rear (`cascade`), and nearly everything the
//! first stage writes lies above it when it arrives: 97.5 % of the triangles on bonsai at
//! R = 0.2 (618,750 of 634,733 had every corner beyond the rear). Taken into the store at once,
//! each such triangle waited there with its vertices, its guard record and cells, unmodifiable,
//! as the stage's sweep front: 25 k faces of its 68 k peak on bonsai, and more than the whole
//! budget on slices of 1021^2 voxels, where two stages therefore did not fit the default memory.
//!
//! Held here instead, a triangle costs its three ids and a vertex its position, state and
//! attributes (about a fifth of a resident face), and nothing changes for the decisions: a
//! triangle wholly above the front can neither take part in a contraction (the second stage
//! contracts only vertices whose whole star lies at or below its front) nor be crossed by one
//! (every new fan lies at or below the front, and crossing needs points strictly on both sides
//! of the plane), so the guard does not need it. A triangle enters the store once the front
//! reaches its lowest corner, its vertices with it; a vertex becomes modifiable once its last
//! triangle has entered (the first stage's `last_use` says which is last; until then the stage
//! does not know the vertex's star, so it must not move it).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::DVec3;
use rustc_hash::FxHashMap;

use crate::cascade::VertexState;

/// A vertex of the first stage's output not yet in the store.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct HeldVertex {
    pub(crate) pos: DVec3,
    pub(crate) state: VertexState,
    pub(crate) attrs: Box<[f32]>,
}

/// A triangle waiting for the front: the rank its lowest corner needs (the ceiling), then its
/// arrival, so that triangles enter in a deterministic order.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
struct Waiting {
    rank: u32,
    seq: u64,
    v: [u64; 3],
}

/// How many of a vertex's triangles wait, and whether its last one has arrived.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
struct Pending {
    waiting: u32,
    last_arrived: bool,
}

/// What enters the store next: a vertex (before any triangle naming it) or a triangle, and the
/// vertices whose last triangle it is.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Entry {
    Vertex(u64, HeldVertex),
    Triangle([u64; 3]),
    Modifiable(u64),
}

#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Held {
    vertices: FxHashMap<u64, HeldVertex>,
    waiting: BinaryHeap<Reverse<Waiting>>,
    pending: FxHashMap<u64, Pending>,
    /// Ids given so far: the first stage numbers its output vertices 0, 1, 2, ...
    next_id: u64,
    next_seq: u64,
}

impl PartialEq for HeldVertex {
    fn eq(&self, o: &Self) -> bool {
        self.pos == o.pos && self.state == o.state && self.attrs == o.attrs
    }
}

impl Held {
    /// A vertex of the first stage's output arrives; returns its id.
    pub(crate) fn vertex(&mut self, v: HeldVertex) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        self.vertices.insert(id, v);
        id
    }

    /// A triangle arrives, with the rank its lowest corner needs and which corners it is the
    /// last triangle of. Corners already in the store are not known here: the caller gives
    /// `rank` from wherever each corner is ([`Held::position`] or the store).
    pub(crate) fn triangle(&mut self, v: [u64; 3], rank: u32, last_use: [bool; 3]) {
        for (&id, &last) in v.iter().zip(&last_use) {
            let p = self.pending.entry(id).or_default();
            p.waiting += 1;
            p.last_arrived |= last;
        }
        self.waiting.push(Reverse(Waiting {
            rank,
            seq: self.next_seq,
            v,
        }));
        self.next_seq += 1;
    }

    /// The position of a vertex still held.
    pub(crate) fn position(&self, id: u64) -> Option<DVec3> {
        self.vertices.get(&id).map(|v| v.pos)
    }

    /// Everything that may enter the store now that the front is `front`, in order: each
    /// triangle whose lowest corner it reached, preceded by those of its vertices still held
    /// and followed by the vertices it completes.
    pub(crate) fn release(&mut self, front: u32, into: &mut Vec<Entry>) {
        while let Some(&Reverse(w)) = self.waiting.peek() {
            if w.rank > front {
                break;
            }
            self.waiting.pop();
            for id in w.v {
                if let Some(v) = self.vertices.remove(&id) {
                    into.push(Entry::Vertex(id, v));
                }
            }
            into.push(Entry::Triangle(w.v));
            for id in w.v {
                if let Some(p) = self.pending.get_mut(&id) {
                    p.waiting -= 1;
                    if p.waiting == 0 && p.last_arrived {
                        self.pending.remove(&id);
                        into.push(Entry::Modifiable(id));
                    }
                }
            }
        }
    }

    /// The lowest rank a waiting triangle needs.
    pub(crate) fn next_rank(&self) -> Option<u32> {
        self.waiting.peek().map(|w| w.0.rank)
    }

    /// Faces waiting.
    pub(crate) fn faces(&self) -> usize {
        self.waiting.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadric::Quadric;

    fn vertex(z: f64) -> HeldVertex {
        HeldVertex {
            pos: DVec3::new(0.0, 0.0, z),
            state: VertexState {
                quadric: Quadric::default(),
                area: 0.0,
                rank_min: 0,
                rank_max: 0,
            },
            attrs: Box::default(),
        }
    }

    /// Triangles enter by the rank of their lowest corner, vertices just before their first
    /// triangle, and a vertex is modifiable only after its last triangle, even when that one
    /// arrived before others that still wait.
    #[test]
    fn triangles_enter_with_the_front_and_complete_their_vertices() {
        let mut h = Held::default();
        let ids: Vec<u64> = (0..4).map(|z| h.vertex(vertex(f64::from(z)))).collect();
        assert_eq!(ids, vec![0, 1, 2, 3]);
        h.triangle([0, 1, 2], 5, [false, true, false]);
        h.triangle([1, 3, 2], 2, [false, false, false]);
        h.triangle([0, 2, 3], 7, [true, true, true]);
        assert_eq!(h.faces(), 3);
        let mut out = Vec::new();
        h.release(1, &mut out);
        assert!(out.is_empty(), "nothing reached");
        h.release(5, &mut out);
        let kinds: Vec<String> = out
            .iter()
            .map(|e| match e {
                Entry::Vertex(id, _) => format!("v{id}"),
                Entry::Triangle(v) => format!("t{v:?}"),
                Entry::Modifiable(id) => format!("m{id}"),
            })
            .collect();
        assert_eq!(
            kinds,
            ["v1", "v3", "v2", "t[1, 3, 2]", "v0", "t[0, 1, 2]", "m1"],
            "vertex 1 is complete with [0, 1, 2]; 0, 2 and 3 wait for [0, 2, 3]"
        );
        out.clear();
        h.release(u32::MAX, &mut out);
        assert_eq!(out.len(), 4, "{out:?}");
        assert_eq!(h.faces(), 0);
        assert!(h.vertices.is_empty() && h.pending.is_empty());
    }
}
