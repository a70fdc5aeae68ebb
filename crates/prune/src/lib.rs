//! Opt-in removal of small connected components, in the stream (`[simplify]
//! min_component_faces`): the one option that changes the topology.
//!
//! Keeping the topology is what makes low rates unreachable on some volumes: every closed
//! component stays at least a tetrahedron, so bonsai's ~760 specks of noise keep its output
//! above 26 k faces whatever the rate. Pruning them before the simplifier sees them (as
//! meshoptimizer's `prune` option does in core) lets the rate apply to what is left.
//!
//! **Streaming.** A component is only known to be small once it is complete, and it is complete
//! once every one of its vertices is modifiable (the detector's Table 1 notice: all triangles of
//! the vertex exist). Any later triangle that joined the component would have to use one of its
//! vertices, so none can. The [`Pruner`] sits between the detector and the simplifier and holds
//! back the elements (vertices with their attributes, triangles, modifiable notices) of every
//! component below the size; when a component reaches the size, its elements are released, in
//! their input order, with the delta that made it reach the size, and everything later that joins
//! it passes straight on; a component that
//! completes below the size is dropped and counted ([`PruneStats`]). Memory: the vertices not yet
//! modifiable (the front, as in the detector) and the components below the size that the front
//! still touches, each fewer than the size in faces.
//!
//! **The sweep front passed on.** The simplifier contracts only where its new fan stays behind the
//! front it is told, because every triangle still to come lies beyond it (`simplify::Sweep`). A
//! held component's triangles come later but lie behind the detector's front, so the front passed
//! on is held at the lowest front in force when any held component began (its triangles all
//! arrived after that front, so they lie beyond it), and never moves back.
//!
//! **Order and ids.** What is passed on is the detector's stream without the dropped components,
//! each output delta in input order (a component released late comes after elements that
//! followed it in the input, so the whole is not a subsequence): a vertex still precedes its
//! triangles (within a delta the
//! simplifier adds vertices, then triangles, then notices) and a notice still follows all the
//! triangles of its vertex (they belong to the same component, so they were released with it or
//! before). Ids are the detector's; the ones of dropped vertices are never seen downstream.
//!
//! Architecture invariant: no I/O, no threads; the output depends only on the input stream.
#![deny(unsafe_code)]

use std::collections::BTreeSet;
use std::num::NonZeroU64;

use glam::DVec3;
use isostream_detect::{MeshDelta, NewVertex};
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// What pruning removed, for the run summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PruneStats {
    /// The size below which a complete component is dropped (full-resolution faces).
    pub min_component_faces: u64,
    pub components_pruned: u64,
    pub faces_pruned: u64,
    pub vertices_pruned: u64,
    /// Most faces held back at once (components below the size that the front still touches).
    pub peak_held_faces: u64,
}

/// Where an open (not yet modifiable) vertex's component stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
enum Slot {
    /// Held in the component with this key.
    Held(u64),
    /// In a component that reached the size: its elements pass straight on.
    Released,
}

/// A vertex held back, with its place in the input stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct HeldVertex {
    seq: u64,
    id: u64,
    pos: DVec3,
    rank: u32,
    attrs: Vec<f32>,
}

/// A component below the size, not yet complete: its elements, held back in input order.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
struct Component {
    faces: u64,
    /// Vertices not yet modifiable; 0 means complete.
    open: u64,
    /// The front in force when its first element arrived: all its triangles lie beyond it.
    low: u32,
    /// Its vertices that were open when they joined (some may be modifiable since).
    open_ids: Vec<u64>,
    vertices: Vec<HeldVertex>,
    triangles: Vec<(u64, [u64; 3])>,
    notices: Vec<(u64, u64)>,
}

impl Component {
    fn elements(&self) -> usize {
        self.vertices.len() + self.triangles.len() + self.notices.len()
    }
}

/// The output delta being built, each element with its place in the input stream.
#[derive(Default)]
struct Outgoing {
    vertices: Vec<HeldVertex>,
    triangles: Vec<(u64, [u64; 3])>,
    notices: Vec<(u64, u64)>,
}

/// A [`Pruner`]'s complete state between two deltas, for checkpoints (maps sorted by key, so
/// equal states encode to equal bytes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrunerState {
    min_faces: u64,
    open: Vec<(u64, Slot)>,
    components: Vec<(u64, Component)>,
    next_component: u64,
    seq: u64,
    front_in: u32,
    front_out: u32,
    held_faces: u64,
    stats: PruneStats,
}

/// Drops the connected components of fewer than `min_faces` faces from a detector's stream.
#[derive(Debug)]
pub struct Pruner {
    min_faces: u64,
    /// Open vertices by detector id.
    open: FxHashMap<u64, Slot>,
    components: FxHashMap<u64, Component>,
    /// `(low, key)` of every held component: the first is the front passed on.
    lows: BTreeSet<(u32, u64)>,
    next_component: u64,
    /// Elements seen so far (their place in the input stream).
    seq: u64,
    /// The detector's front after the last delta.
    front_in: u32,
    /// The front passed on with the last delta.
    front_out: u32,
    held_faces: u64,
    stats: PruneStats,
}

impl Pruner {
    /// A pruner at the start of a stream (front 0).
    pub fn new(min_faces: NonZeroU64) -> Self {
        Self {
            min_faces: min_faces.get(),
            open: FxHashMap::default(),
            components: FxHashMap::default(),
            lows: BTreeSet::new(),
            next_component: 0,
            seq: 0,
            front_in: 0,
            front_out: 0,
            held_faces: 0,
            stats: PruneStats {
                min_component_faces: min_faces.get(),
                ..PruneStats::default()
            },
        }
    }

    /// Takes the detector's next delta and returns the one to pass on: the elements of the
    /// components at or above the size (those released now included), and the front held behind
    /// every held component.
    ///
    /// # Panics
    /// If a triangle uses a vertex that is unknown or already modifiable: the detector never
    /// sends one.
    pub fn process(&mut self, delta: MeshDelta) -> MeshDelta {
        let stride = delta
            .attrs
            .len()
            .checked_div(delta.vertices.len())
            .unwrap_or(0);
        let first_tri = self.seq + delta.vertices.len() as u64;
        let first_notice = first_tri + delta.triangles.len() as u64;
        let mut out = Outgoing::default();
        // A new vertex starts as a component of its own; its first triangle merges it.
        let mut fresh: FxHashMap<u64, HeldVertex> = FxHashMap::default();
        for (i, v) in delta.vertices.iter().enumerate() {
            let attrs = delta.attrs.get(i * stride..(i + 1) * stride).unwrap_or(&[]);
            fresh.insert(
                v.id,
                HeldVertex {
                    seq: self.seq + i as u64,
                    id: v.id,
                    pos: v.pos,
                    rank: v.rank,
                    attrs: attrs.to_vec(),
                },
            );
        }
        for (i, &tri) in delta.triangles.iter().enumerate() {
            self.triangle(first_tri + i as u64, tri, &mut fresh, &mut out);
        }
        // A vertex without triangles (the detector makes none) is a component of no faces.
        let mut faceless: Vec<HeldVertex> = fresh.into_values().collect();
        faceless.sort_unstable_by_key(|v| v.seq);
        for v in faceless {
            let key = self.new_component();
            self.hold_vertex(key, v);
        }
        for (i, &id) in delta.modifiable.iter().enumerate() {
            self.notice(first_notice + i as u64, id, &mut out);
        }
        self.seq = first_notice + delta.modifiable.len() as u64;
        self.front_in = delta.front;
        let held = self.lows.first().map_or(u32::MAX, |&(low, _)| low);
        self.front_out = self.front_out.max(delta.front.min(held));
        self.stats.peak_held_faces = self.stats.peak_held_faces.max(self.held_faces);
        out.into_delta(self.front_out)
    }

    /// End of the stream: whatever is still held can grow no more and is below the size. The
    /// detector's final release makes every vertex modifiable, so this finds nothing on a
    /// complete stream; it drops defensively, so that nothing held is ever passed on late.
    pub fn finish(&mut self) {
        let mut keys: Vec<u64> = self.components.keys().copied().collect();
        keys.sort_unstable();
        for key in keys {
            self.drop_component(key);
        }
        self.open.clear();
    }

    pub fn stats(&self) -> PruneStats {
        self.stats
    }

    /// The state between two deltas (see [`PrunerState`]).
    pub fn snapshot(&self) -> PrunerState {
        let mut open: Vec<(u64, Slot)> = self.open.iter().map(|(&k, &s)| (k, s)).collect();
        open.sort_unstable_by_key(|&(k, _)| k);
        let mut components: Vec<(u64, Component)> = self
            .components
            .iter()
            .map(|(&k, c)| (k, c.clone()))
            .collect();
        components.sort_unstable_by_key(|&(k, _)| k);
        PrunerState {
            min_faces: self.min_faces,
            open,
            components,
            next_component: self.next_component,
            seq: self.seq,
            front_in: self.front_in,
            front_out: self.front_out,
            held_faces: self.held_faces,
            stats: self.stats,
        }
    }

    /// A pruner continuing from `state`. Maps are only looked up (never iterated for output), so
    /// it behaves exactly as the one that was saved.
    pub fn restore(state: PrunerState) -> Self {
        let lows = state
            .components
            .iter()
            .map(|(k, c)| (c.low, *k))
            .collect();
        Self {
            min_faces: state.min_faces,
            open: state.open.into_iter().collect(),
            components: state.components.into_iter().collect(),
            lows,
            next_component: state.next_component,
            seq: state.seq,
            front_in: state.front_in,
            front_out: state.front_out,
            held_faces: state.held_faces,
            stats: state.stats,
        }
    }

    fn triangle(
        &mut self,
        seq: u64,
        tri: [u64; 3],
        fresh: &mut FxHashMap<u64, HeldVertex>,
        out: &mut Outgoing,
    ) {
        let slots = tri.map(|id| {
            if fresh.contains_key(&id) {
                None
            } else {
                Some(*self.open.get(&id).unwrap_or_else(|| {
                    panic!("triangle {tri:?} uses vertex {id}, unknown or already modifiable")
                }))
            }
        });
        if slots.contains(&Some(Slot::Released)) {
            for (id, slot) in tri.iter().zip(slots) {
                match slot {
                    None => {
                        if let Some(v) = fresh.remove(id) {
                            self.open.insert(v.id, Slot::Released);
                            out.vertices.push(v);
                        }
                    }
                    Some(Slot::Held(key)) => self.release(key, out),
                    Some(Slot::Released) => {}
                }
            }
            out.triangles.push((seq, tri));
            return;
        }
        let mut held: Vec<u64> = slots
            .iter()
            .filter_map(|s| match s {
                Some(Slot::Held(key)) => Some(*key),
                _ => None,
            })
            .collect();
        held.sort_unstable();
        held.dedup();
        // The largest absorbs the others (its open vertices need no relabelling).
        let key = match held
            .iter()
            .copied()
            .max_by_key(|k| (self.components[k].elements(), std::cmp::Reverse(*k)))
        {
            Some(key) => {
                for &other in held.iter().filter(|&&k| k != key) {
                    self.merge(key, other);
                }
                key
            }
            None => self.new_component(),
        };
        for (id, slot) in tri.iter().zip(slots) {
            if slot.is_none()
                && let Some(v) = fresh.remove(id)
            {
                self.hold_vertex(key, v);
            }
        }
        let c = self.component(key);
        c.triangles.push((seq, tri));
        c.faces += 1;
        let faces = c.faces;
        self.held_faces += 1;
        if faces >= self.min_faces {
            self.release(key, out);
        }
    }

    fn notice(&mut self, seq: u64, id: u64, out: &mut Outgoing) {
        match self.open.remove(&id) {
            Some(Slot::Held(key)) => {
                let c = self.component(key);
                c.notices.push((seq, id));
                c.open -= 1;
                if c.open == 0 {
                    self.drop_component(key);
                }
            }
            // Released, or a vertex this stage never saw (the simplifier ignores those too).
            _ => out.notices.push((seq, id)),
        }
    }

    fn new_component(&mut self) -> u64 {
        let key = self.next_component;
        self.next_component += 1;
        let low = self.front_in;
        self.components.insert(
            key,
            Component {
                low,
                ..Component::default()
            },
        );
        self.lows.insert((low, key));
        key
    }

    fn component(&mut self, key: u64) -> &mut Component {
        self.components
            .get_mut(&key)
            .unwrap_or_else(|| unreachable!("held component {key} is tracked"))
    }

    fn hold_vertex(&mut self, key: u64, v: HeldVertex) {
        self.open.insert(v.id, Slot::Held(key));
        let c = self.component(key);
        c.open += 1;
        c.open_ids.push(v.id);
        c.vertices.push(v);
    }

    /// Moves component `other` into `key`.
    fn merge(&mut self, key: u64, other: u64) {
        let Some(o) = self.components.remove(&other) else {
            return;
        };
        self.lows.remove(&(o.low, other));
        for id in &o.open_ids {
            if let Some(slot) = self.open.get_mut(id) {
                *slot = Slot::Held(key);
            }
        }
        let c = self.component(key);
        let old_low = c.low;
        c.faces += o.faces;
        c.open += o.open;
        c.low = c.low.min(o.low);
        c.open_ids.extend(o.open_ids);
        c.vertices.extend(o.vertices);
        c.triangles.extend(o.triangles);
        c.notices.extend(o.notices);
        let low = c.low;
        if low != old_low {
            self.lows.remove(&(old_low, key));
            self.lows.insert((low, key));
        }
    }

    /// The component reached the size: its elements go out, and its open vertices pass on
    /// whatever joins them from now on.
    fn release(&mut self, key: u64, out: &mut Outgoing) {
        let Some(c) = self.components.remove(&key) else {
            return;
        };
        self.lows.remove(&(c.low, key));
        self.held_faces -= c.faces;
        for id in &c.open_ids {
            if let Some(slot) = self.open.get_mut(id) {
                *slot = Slot::Released;
            }
        }
        out.vertices.extend(c.vertices);
        out.triangles.extend(c.triangles);
        out.notices.extend(c.notices);
    }

    /// The component is complete below the size: forgotten, and counted.
    fn drop_component(&mut self, key: u64) {
        let Some(c) = self.components.remove(&key) else {
            return;
        };
        self.lows.remove(&(c.low, key));
        self.held_faces -= c.faces;
        for id in &c.open_ids {
            self.open.remove(id);
        }
        self.stats.components_pruned += 1;
        self.stats.faces_pruned += c.faces;
        self.stats.vertices_pruned += c.vertices.len() as u64;
    }
}

impl Outgoing {
    /// The delta in input order, with `front`.
    fn into_delta(mut self, front: u32) -> MeshDelta {
        self.vertices.sort_by_key(|v| v.seq);
        self.triangles.sort_by_key(|&(seq, _)| seq);
        self.notices.sort_by_key(|&(seq, _)| seq);
        let mut delta = MeshDelta {
            front,
            ..MeshDelta::default()
        };
        for v in self.vertices {
            delta.vertices.push(NewVertex {
                id: v.id,
                pos: v.pos,
                rank: v.rank,
            });
            delta.attrs.extend(v.attrs);
        }
        delta.triangles = self.triangles.into_iter().map(|(_, t)| t).collect();
        delta.modifiable = self.notices.into_iter().map(|(_, id)| id).collect();
        delta
    }
}

#[cfg(test)]
mod tests;
