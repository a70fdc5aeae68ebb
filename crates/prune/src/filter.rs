//! The second pass: the detector's stream without the small components (see the crate's doc).

use isostream_detect::MeshDelta;
use rustc_hash::FxHashSet;
use serde::{Deserialize, Serialize};

use crate::{PruneStats, SmallPieces, piece_id};

/// Drops the pieces the [`Census`](crate::Census) listed from the same stream.
#[derive(Debug)]
pub struct Filter {
    /// Small pieces not reached yet.
    starts: FxHashSet<u64>,
    /// Vertices of dropped pieces that are not modifiable yet.
    dropped: FxHashSet<u64>,
    /// Vertices that have had a triangle and are not modifiable yet (a triangle of three vertices
    /// outside it starts a piece).
    seen: FxHashSet<u64>,
    /// The census's counts.
    stats: PruneStats,
    dropped_faces: u64,
}

/// A [`Filter`]'s state between two deltas, for checkpoints (sets sorted, so equal states
/// encode to equal bytes).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FilterState {
    starts: Vec<u64>,
    dropped: Vec<u64>,
    seen: Vec<u64>,
    stats: PruneStats,
    dropped_faces: u64,
}

impl Filter {
    pub fn new(small: SmallPieces) -> Self {
        Self {
            starts: small.starts.into_iter().collect(),
            dropped: FxHashSet::default(),
            seen: FxHashSet::default(),
            stats: small.stats,
            dropped_faces: 0,
        }
    }

    /// The delta to pass on: `delta` without the elements of the small components, same front.
    pub fn process(&mut self, delta: MeshDelta) -> MeshDelta {
        let MeshDelta {
            vertices,
            attrs,
            triangles,
            modifiable,
            front,
            rows,
        } = delta;
        let mut out = MeshDelta {
            front,
            rows,
            ..MeshDelta::default()
        };
        out.triangles.reserve(triangles.len());
        for tri in triangles {
            let small = tri.iter().any(|id| self.dropped.contains(id))
                || (!tri.iter().any(|id| self.seen.contains(id))
                    && self.starts.remove(&piece_id(tri)));
            if small {
                self.dropped_faces += 1;
                self.dropped.extend(tri);
            } else {
                self.seen.extend(tri);
                out.triangles.push(tri);
            }
        }
        // A vertex arrives with its first triangle, so its fate is known by now.
        let stride = attrs.len().checked_div(vertices.len()).unwrap_or(0);
        out.vertices.reserve(vertices.len());
        for (i, v) in vertices.into_iter().enumerate() {
            if !self.dropped.contains(&v.id) {
                out.vertices.push(v);
                out.attrs
                    .extend_from_slice(&attrs[i * stride..(i + 1) * stride]);
            }
        }
        for id in modifiable {
            self.seen.remove(&id);
            if !self.dropped.remove(&id) {
                out.modifiable.push(id);
            }
        }
        out
    }

    /// The census's counts (what the whole stream loses).
    pub fn stats(&self) -> PruneStats {
        self.stats
    }

    /// Faces dropped so far: the census's `faces_pruned` at the end of the same stream.
    pub fn dropped_faces(&self) -> u64 {
        self.dropped_faces
    }

    /// The state between two deltas (see [`FilterState`]).
    pub fn snapshot(&self) -> FilterState {
        let sorted = |set: &FxHashSet<u64>| {
            let mut v: Vec<u64> = set.iter().copied().collect();
            v.sort_unstable();
            v
        };
        FilterState {
            starts: sorted(&self.starts),
            dropped: sorted(&self.dropped),
            seen: sorted(&self.seen),
            stats: self.stats,
            dropped_faces: self.dropped_faces,
        }
    }

    /// A filter continuing from `state` (sets are only looked up, so it behaves as the saved one).
    pub fn restore(state: FilterState) -> Self {
        Self {
            starts: state.starts.into_iter().collect(),
            dropped: state.dropped.into_iter().collect(),
            seen: state.seen.into_iter().collect(),
            stats: state.stats,
            dropped_faces: state.dropped_faces,
        }
    }
}
