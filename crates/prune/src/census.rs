//! The first pass: which components stay below the size (see the crate's doc).

use std::num::NonZeroU64;

use isostream_detect::MeshDelta;
use rustc_hash::FxHashMap;

use crate::{PruneStats, SmallPieces, piece_id};

/// Where a vertex that is not modifiable yet stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slot {
    /// In the component with this key, still below the size.
    Small(u64),
    /// In a component at or above the size: kept, whatever joins it.
    Kept,
}

/// A component below the size that the front still touches.
#[derive(Debug, Default)]
struct Component {
    faces: u64,
    vertices: u64,
    /// Vertices not yet modifiable; 0 means complete.
    open: u64,
    /// Its vertices that were open when they joined (some may be modifiable since).
    open_ids: Vec<u64>,
    /// The pieces it was made of.
    starts: Vec<u64>,
}

/// Follows a detector's stream and lists the pieces of every component with fewer than the
/// size's faces.
#[derive(Debug)]
pub struct Census {
    min_faces: u64,
    open: FxHashMap<u64, Slot>,
    components: FxHashMap<u64, Component>,
    next_component: u64,
    small: SmallPieces,
}

impl Census {
    pub fn new(min_faces: NonZeroU64) -> Self {
        Self {
            min_faces: min_faces.get(),
            open: FxHashMap::default(),
            components: FxHashMap::default(),
            next_component: 0,
            small: SmallPieces {
                starts: Vec::new(),
                stats: PruneStats {
                    min_component_faces: min_faces.get(),
                    ..PruneStats::default()
                },
            },
        }
    }

    /// Takes the detector's next delta (vertices, then triangles, then notices).
    ///
    /// # Panics
    /// If a triangle uses a vertex already modifiable: the detector never sends one.
    pub fn add(&mut self, delta: &MeshDelta) {
        for &tri in &delta.triangles {
            self.triangle(tri);
        }
        for &id in &delta.modifiable {
            self.notice(id);
        }
    }

    /// End of the stream: the small pieces, sorted. The detector's final release makes every
    /// vertex modifiable, so every component has been decided; any left (an incomplete stream)
    /// can grow no more and is counted like the others.
    pub fn finish(mut self) -> SmallPieces {
        let mut keys: Vec<u64> = self.components.keys().copied().collect();
        keys.sort_unstable();
        for key in keys {
            self.complete(key);
        }
        self.small.starts.sort_unstable();
        self.small
    }

    fn triangle(&mut self, tri: [u64; 3]) {
        let slots = tri.map(|id| self.open.get(&id).copied());
        if slots.contains(&Some(Slot::Kept)) {
            for (&id, slot) in tri.iter().zip(slots) {
                match slot {
                    Some(Slot::Small(key)) => self.keep(key),
                    _ => {
                        self.open.insert(id, Slot::Kept);
                    }
                }
            }
            return;
        }
        let mut keys: Vec<u64> = slots
            .iter()
            .filter_map(|s| match s {
                Some(Slot::Small(key)) => Some(*key),
                _ => None,
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        // The largest absorbs the others (its open vertices need no relabelling).
        let key = match keys.iter().copied().max_by_key(|k| {
            let c = &self.components[k];
            (c.open_ids.len() + c.starts.len(), std::cmp::Reverse(*k))
        }) {
            Some(key) => {
                for &other in keys.iter().filter(|&&k| k != key) {
                    self.merge(key, other);
                }
                key
            }
            None => {
                let key = self.next_component;
                self.next_component += 1;
                let c = Component {
                    starts: vec![piece_id(tri)],
                    ..Component::default()
                };
                self.components.insert(key, c);
                key
            }
        };
        let c = self.component(key);
        c.faces += 1;
        let mut new = Vec::new();
        for (&id, slot) in tri.iter().zip(slots) {
            if slot.is_none() {
                c.vertices += 1;
                c.open += 1;
                c.open_ids.push(id);
                new.push(id);
            }
        }
        let faces = c.faces;
        for id in new {
            self.open.insert(id, Slot::Small(key));
        }
        if faces >= self.min_faces {
            self.keep(key);
        }
    }

    fn notice(&mut self, id: u64) {
        if let Some(Slot::Small(key)) = self.open.remove(&id) {
            let c = self.component(key);
            c.open -= 1;
            if c.open == 0 {
                self.complete(key);
            }
        }
    }

    fn component(&mut self, key: u64) -> &mut Component {
        self.components
            .get_mut(&key)
            .unwrap_or_else(|| unreachable!("component {key} is tracked"))
    }

    /// Moves component `other` into `key`.
    fn merge(&mut self, key: u64, other: u64) {
        let Some(o) = self.components.remove(&other) else {
            return;
        };
        for id in &o.open_ids {
            if let Some(slot) = self.open.get_mut(id) {
                *slot = Slot::Small(key);
            }
        }
        let c = self.component(key);
        c.faces += o.faces;
        c.vertices += o.vertices;
        c.open += o.open;
        c.open_ids.extend(o.open_ids);
        c.starts.extend(o.starts);
    }

    /// The component reached the size: its open vertices say so to whatever joins them.
    fn keep(&mut self, key: u64) {
        let Some(c) = self.components.remove(&key) else {
            return;
        };
        for id in &c.open_ids {
            if let Some(slot) = self.open.get_mut(id) {
                *slot = Slot::Kept;
            }
        }
    }

    /// The component can grow no more and is below the size: its pieces are listed.
    fn complete(&mut self, key: u64) {
        let Some(c) = self.components.remove(&key) else {
            return;
        };
        for id in &c.open_ids {
            self.open.remove(id);
        }
        let st = &mut self.small.stats;
        st.components_pruned += 1;
        st.faces_pruned += c.faces;
        st.vertices_pruned += c.vertices;
        self.small.starts.extend(c.starts);
    }
}
