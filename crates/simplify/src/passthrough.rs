//! Policy `none` in streaming mode: the full-resolution surface in streaming order, without the
//! contraction machinery.
//!
//! Why a path of its own: with nothing to contract, a triangle only has to wait until its three
//! vertices are complete (the detector's "modifiable": every triangle of the vertex exists) and a
//! vertex until its last triangle went out. The contraction band (quadric-carrying vertices,
//! fans, rank buckets, retirement `retire_lag` slabs behind the front) cost 2 s for bonsai's
//! 1.1 M faces, ten times the extraction; this costs a small slot per vertex and a list of
//! waiting triangles, and holds less (a triangle leaves as soon as it is complete, so
//! `retire_lag` does not apply).
//!
//! Order: after each batch the waiting triangles whose vertices are all complete leave in their
//! arrival order; each vertex goes out right before its first triangle and is finalized on its
//! last one. A deterministic function of the input sequence, like the contraction path.

use glam::DVec3;
use rustc_hash::FxHashMap;

use crate::store::UNWRITTEN;
use crate::{OutBatch, OutElement, SimplifyConfig, SimplifyStats};

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct Slot {
    pos: DVec3,
    /// Triangles of the vertex not written yet.
    pending: u32,
    /// Every triangle of the vertex exists.
    complete: bool,
    /// Output number, [`UNWRITTEN`] before the first triangle.
    out: u64,
}

#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct PassThrough {
    config: SimplifyConfig,
    stats: SimplifyStats,
    slots: Vec<Slot>,
    /// `attributes` values per slot.
    attrs: Vec<f32>,
    free: Vec<u32>,
    /// Detector id -> slot while the vertex may receive triangles (ids are reused after that).
    ids: FxHashMap<u64, u32>,
    /// Triangles with a vertex that is not complete yet, in arrival order.
    waiting: Vec<[u32; 3]>,
    next_out: u64,
    live: usize,
}

impl PassThrough {
    pub(crate) fn new(config: SimplifyConfig) -> Self {
        Self {
            config,
            stats: SimplifyStats::default(),
            slots: Vec::new(),
            attrs: Vec::new(),
            free: Vec::new(),
            ids: FxHashMap::default(),
            waiting: Vec::new(),
            next_out: 0,
            live: 0,
        }
    }

    pub(crate) fn config(&self) -> &SimplifyConfig {
        &self.config
    }

    /// See [`crate::Simplifier::add_vertex`].
    ///
    /// # Panics
    /// If a vertex that may still receive triangles already has this id.
    pub(crate) fn add_vertex(&mut self, id: u64, pos: DVec3, attrs: &[f32]) {
        let (pos, attrs) = crate::vertex_input(pos, attrs, self.config.attributes);
        self.stats.vertices_in += 1;
        let slot = Slot {
            pos,
            pending: 0,
            complete: false,
            out: UNWRITTEN,
        };
        let s = match self.free.pop() {
            Some(s) => {
                self.slots[s as usize] = slot;
                s
            }
            None => {
                self.slots.push(slot);
                self.attrs
                    .resize(self.slots.len() * self.config.attributes, 0.0);
                u32::try_from(self.slots.len() - 1).expect("fewer than 2^32 resident vertices")
            }
        };
        let range = attr_range(self.config.attributes, s);
        self.attrs[range].copy_from_slice(&attrs);
        let old = self.ids.insert(id, s);
        assert!(old.is_none(), "vertex id {id} added twice");
        self.live += 1;
    }

    /// # Panics
    /// If a vertex is unknown or already complete.
    pub(crate) fn add_triangle(&mut self, ids: [u64; 3]) {
        let v = ids.map(|id| {
            *self
                .ids
                .get(&id)
                .unwrap_or_else(|| panic!("triangle {ids:?} uses unknown or retired vertex {id}"))
        });
        for s in v {
            self.slots[s as usize].pending += 1;
        }
        self.waiting.push(v);
        self.stats.faces_in += 1;
        self.stats.peak_resident_faces = self.stats.peak_resident_faces.max(self.waiting.len());
    }

    pub(crate) fn set_modifiable(&mut self, id: u64) {
        let Some(s) = self.ids.remove(&id) else {
            return;
        };
        let slot = &mut self.slots[s as usize];
        slot.complete = true;
        if slot.pending == 0 {
            // No triangle at all: nothing refers to it, it is never written.
            self.release(s);
        }
    }

    /// Writes every waiting triangle whose vertices are complete.
    pub(crate) fn flush(&mut self, out: &mut OutBatch) {
        let mut waiting = std::mem::take(&mut self.waiting);
        waiting.retain(|&v| {
            let ready = v.iter().all(|&s| self.slots[s as usize].complete);
            if ready {
                self.write(v, out);
            }
            !ready
        });
        self.waiting = waiting;
    }

    /// End of the volume: every vertex is complete; writes everything.
    pub(crate) fn finish(&mut self, out: &mut OutBatch) {
        let ids: Vec<u64> = self.ids.keys().copied().collect();
        for id in ids {
            self.set_modifiable(id);
        }
        self.flush(out);
        debug_assert!(self.waiting.is_empty() && self.live == 0);
    }

    /// The run's counters: resident faces are the waiting triangles, unmodifiable those with a
    /// vertex that is not complete (the rest leave at the next flush).
    pub(crate) fn stats(&self) -> SimplifyStats {
        SimplifyStats {
            faces_resident: self.waiting.len(),
            faces_unmodifiable: self
                .waiting
                .iter()
                .filter(|v| v.iter().any(|&s| !self.slots[s as usize].complete))
                .count(),
            vertices_resident: self.live,
            ..self.stats.clone()
        }
    }

    fn write(&mut self, v: [u32; 3], out: &mut OutBatch) {
        let mut numbers = [0; 3];
        let mut last_use = [false; 3];
        for (i, &s) in v.iter().enumerate() {
            let slot = &mut self.slots[s as usize];
            if slot.out == UNWRITTEN {
                slot.out = self.next_out;
                self.next_out += 1;
                out.elements.push(OutElement::Vertex { pos: slot.pos });
                out.attrs
                    .extend_from_slice(&self.attrs[attr_range(self.config.attributes, s)]);
                self.stats.vertices_out += 1;
            }
            numbers[i] = slot.out;
            slot.pending -= 1;
            last_use[i] = slot.pending == 0;
        }
        out.elements.push(OutElement::Triangle {
            v: numbers,
            last_use,
        });
        self.stats.faces_out += 1;
        for (s, last) in v.into_iter().zip(last_use) {
            if last {
                self.release(s);
            }
        }
    }

    fn release(&mut self, s: u32) {
        self.free.push(s);
        self.live -= 1;
    }
}

/// Where slot `s`'s values lie in an array of `attributes` values per slot.
fn attr_range(attributes: usize, s: u32) -> std::ops::Range<usize> {
    s as usize * attributes..(s as usize + 1) * attributes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles sharing an edge; the detector reuses id 1 once its first vertex is
    /// complete. Output in pre-order, finalized on the last use, every slot freed.
    #[test]
    fn triangles_leave_once_complete_and_ids_may_be_reused() {
        let mut p = PassThrough::new(SimplifyConfig {
            attributes: 1,
            ..SimplifyConfig::new(crate::Policy::None)
        });
        let mut out = OutBatch::default();
        for (id, x) in [(0, 0.0), (1, 1.0), (2, 2.0)] {
            p.add_vertex(id, DVec3::X * x, &[x as f32]);
        }
        p.add_triangle([0, 1, 2]);
        p.set_modifiable(0);
        p.set_modifiable(1);
        p.flush(&mut out);
        assert!(out.elements.is_empty(), "vertex 2 may still gain triangles");
        p.add_vertex(1, DVec3::Y, &[9.0]); // id 1 names a new vertex now
        p.add_vertex(3, DVec3::Z, &[3.0]);
        p.add_triangle([2, 1, 3]);
        p.set_modifiable(2);
        p.flush(&mut out);
        assert_eq!(out.elements.len(), 4, "the first triangle and its vertices");
        assert_eq!(p.stats().faces_resident, 1);
        p.finish(&mut out);
        let tris: Vec<_> = out
            .elements
            .iter()
            .filter_map(|e| match e {
                OutElement::Triangle { v, last_use } => Some((*v, *last_use)),
                OutElement::Vertex { .. } => None,
            })
            .collect();
        assert_eq!(
            tris,
            vec![
                ([0, 1, 2], [true, true, false]),
                ([2, 3, 4], [true, true, true])
            ]
        );
        assert_eq!(out.attrs, vec![0.0, 1.0, 2.0, 9.0, 3.0]);
        let stats = p.stats();
        assert_eq!((stats.faces_out, stats.vertices_out), (2, 5));
        assert_eq!(stats.vertices_resident, 0);
        assert_eq!(p.free.len(), p.slots.len(), "every slot is free again");
    }
}
