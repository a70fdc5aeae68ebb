//! Opt-in removal of small connected components (`[simplify] min_component_faces`): the one
//! option that changes the topology.
//!
//! Keeping the topology is what makes low rates unreachable on some volumes: every closed
//! component stays at least a tetrahedron, so aneurism's 988 components (mostly vessel fragments
//! of a few faces) keep it at 5,098 faces for a target of 1,629 at R = 0.01. Dropping the small
//! ones before the simplifier sees them (as meshoptimizer's `prune` option does in core) lets the
//! rate apply to what is left: 1,484 faces for 1,484 with 100 faces as the size
//! (docs/performance.md). A floor made by boundaries (bonsai) is not this crate's to lower.
//!
//! **Two passes over the detector's stream.** A component's size is known only once it is
//! complete, and it is complete once every one of its vertices is modifiable (the detector's
//! Table 1 notice: all triangles of the vertex exist; a later triangle joining the component
//! would have to use one of its vertices). The [`Census`] watches a first pass (extraction and
//! detection only, no simplification) and names the small components by their *pieces*: a piece
//! starts at a triangle whose three vertices are all new, and every other triangle touches a
//! vertex of an earlier one; pieces merge into components. The [`Filter`] then sits between the
//! detector and the simplifier in the real pass, which sees the same stream (the detector's ids
//! depend on the volume only): a triangle that starts a small piece, or touches a vertex of
//! one, is dropped with its new vertices and their notices.
//!
//! Why not one pass that holds each component back until it is complete: the simplifier's
//! self-intersection guard relies on every triangle still to come lying beyond the sweep front
//! it is told (`isostream_simplify::Sweep`), and a held component lies behind it, so the front
//! passed on would have to wait for the oldest held component, for the whole plane. On bonsai
//! (iso 40, R = 0.01, 100 faces) some small piece was always held, the front lagged 4 to 6 slabs,
//! 809 k contractions waited for it, the memory budget forced 18.7 k vertices out uncontracted,
//! and the output grew from 26,861 faces to 42,654. The filter passes the stream on with the
//! detector's front and order (a subsequence, each delta the filtered input delta): nothing the
//! simplifier relies on changes, at the cost of a first pass (extraction and detection: a few
//! percent of a run whose time is the simplifier's).
//!
//! Memory: the census holds the vertices not yet modifiable (the front, as the detector) and the
//! components below the size that the front touches (a component at the size is known to be
//! kept and forgotten); the list of small pieces it hands over, 8 bytes each, is the only thing
//! that grows, with the number of small components (not the surface), and the filter forgets each
//! entry once used.
//!
//! Architecture invariant: no I/O, no threads; the output depends only on the input streams.
#![deny(unsafe_code)]

mod census;
mod filter;

pub use census::Census;
pub use filter::{Filter, FilterState};

use serde::{Deserialize, Serialize};

/// What pruning removed, for the run summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PruneStats {
    /// The size below which a complete component is dropped (full-resolution faces).
    pub min_component_faces: u64,
    pub components_pruned: u64,
    pub faces_pruned: u64,
    pub vertices_pruned: u64,
}

/// What the census found: the pieces of the components below the size, by the smallest vertex
/// id of the triangle that starts each piece, sorted.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SmallPieces {
    pub starts: Vec<u64>,
    pub stats: PruneStats,
}

/// The id a piece is known by: the smallest vertex id of its first triangle.
fn piece_id(tri: [u64; 3]) -> u64 {
    tri[0].min(tri[1]).min(tri[2])
}

#[cfg(test)]
mod tests;
