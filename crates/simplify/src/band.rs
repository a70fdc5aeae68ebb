//! The resident band: the mesh a stage holds and the two indexes over it that must follow every
//! change of it, the guard's spatial index of its triangles and the rank buckets of its
//! vertices.
//!
//! Why one struct: ingestion adds to all three, the decimator changes the mesh and refiles the
//! vertices a contraction raised, the retirer pops the buckets and tells the guard what it
//! wrote. Each of them borrows the band as a whole, so no part of the simplifier keeps an index
//! the others could forget to update.

use crate::intersect::TriIndex;
use crate::retire::RankBuckets;
use crate::store::Store;

#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Band {
    /// Vertices (by generational slot) and triangles.
    pub(crate) store: Store,
    /// Spatial hash of the resident (and latest emitted) triangles for the intersection guard
    /// (empty when nothing contracts).
    pub(crate) guard: TriIndex,
    /// Vertices by highest preimage rank, oldest first out (`retire`).
    pub(crate) buckets: RankBuckets,
}

impl Band {
    /// An empty band whose store keeps each vertex's `store::Extra` when `extras`.
    pub(crate) fn new(extras: bool) -> Self {
        Self {
            store: if extras {
                Store::keeping_extras()
            } else {
                Store::default()
            },
            ..Self::default()
        }
    }

    /// Files vertex `slot` under `rank` for retirement.
    pub(crate) fn file(&mut self, rank: u32, slot: u64) {
        self.buckets.push(rank, slot, &mut self.store);
    }

    /// Faces held.
    pub(crate) fn resident(&self) -> usize {
        self.store.resident()
    }
}
