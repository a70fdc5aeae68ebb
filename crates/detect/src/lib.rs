//! Per-cube vertex modifiability detection (Hou and Chen 2016, section 3.1 and Table 1).
//!
//! The extractor emits, cube by cube in traversal order (x fastest, then y, then z), the
//! triangles of each non-empty cube with their vertices named by grid edge ([`EdgeKey`]). This
//! stage turns that soup into indexed triangles with stable `u64` vertex ids and announces, after
//! each cube, which vertices have received *all* their triangles (are "modifiable"): a vertex on a
//! grid edge only appears in the four cubes around that edge, and Table 1 names, for each kind of
//! cube, the edges whose last adjacent cube it is. From then on the simplifier may move the vertex.
//!
//! The id map holds only the front: an entry leaves the map when its vertex becomes modifiable, so
//! memory is bounded by one slab of crossing edges, not by the surface.
//!
//! Architecture invariant: no I/O, no threads; one [`Detector`] per stream.
#![deny(unsafe_code)]

mod table1;

use glam::DVec3;
use isostream_extract::{CubeBatch, EdgeKey};
use rustc_hash::FxHashMap;

pub use table1::{CubeKind, modifiable_lines};

/// A vertex seen for the first time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewVertex {
    /// Stable id, assigned in order of first appearance (so roughly in sweep order).
    pub id: u64,
    pub pos: DVec3,
    /// The highest grid plane (z index) the vertex's edge touches: its layer in the Tandem sense.
    pub rank: u32,
}

/// What one [`CubeBatch`] adds to the indexed surface. Order matters to the consumer: add the
/// vertices, then the triangles, then mark `modifiable` (every triangle of those vertices is in
/// this or an earlier delta).
#[derive(Debug, Clone, Default)]
pub struct MeshDelta {
    pub vertices: Vec<NewVertex>,
    /// Attribute values of the new vertices, vertex-major, as many per vertex as the batch had
    /// (`CubeBatch::attrs`); empty without attributes.
    pub attrs: Vec<f32>,
    /// Counter-clockwise seen from outside, by vertex id.
    pub triangles: Vec<[u64; 3]>,
    pub modifiable: Vec<u64>,
    /// Number of slabs completely extracted after this delta.
    pub front: u32,
    /// Rows of cubes of the next slab (slab `front`) extracted after this delta: 0 at the end of
    /// a slab (`CubeBatch::rows_done`).
    pub rows: u32,
}

impl MeshDelta {
    pub fn clear(&mut self) {
        self.vertices.clear();
        self.attrs.clear();
        self.triangles.clear();
        self.modifiable.clear();
        self.front = 0;
        self.rows = 0;
    }
}

/// Counters for the run summary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct DetectStats {
    pub vertices: u64,
    pub triangles: u64,
    /// Most vertices waiting in the front map at once.
    pub peak_front: u64,
    /// Vertices Table 1 never released, freed by the end of the stream instead. Always 0 when
    /// the table is complete; kept as a diagnostic because a non-zero value means lost editing.
    pub released_at_end: u64,
}

/// A [`Detector`]'s complete state between two batches, for checkpoints: the front map (sorted
/// by edge key, so equal states encode to equal bytes), the next id and the counters.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct DetectorState {
    dims: [u64; 3],
    front: Vec<(u64, u64)>,
    next_id: u64,
    stats: DetectStats,
}

/// A saved state that belongs to a volume of other dimensions.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DimsMismatch {
    pub saved: [u64; 3],
    pub volume: [u64; 3],
}

impl std::fmt::Display for DimsMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the saved detector state is for a {:?} volume, not {:?}",
            self.saved, self.volume
        )
    }
}

impl std::error::Error for DimsMismatch {}

/// Streaming soup-to-indexed conversion with Table 1 modifiability.
#[derive(Debug)]
pub struct Detector {
    dims: [u64; 3],
    front: FxHashMap<EdgeKey, u64>,
    next_id: u64,
    stats: DetectStats,
}

impl Detector {
    /// `dims` are the voxel dimensions of the volume (at least 2 along each axis).
    pub fn new(dims: [u64; 3]) -> Self {
        Self {
            dims,
            front: FxHashMap::default(),
            next_id: 0,
            stats: DetectStats::default(),
        }
    }

    /// The state between two batches (see [`DetectorState`]).
    pub fn snapshot(&self) -> DetectorState {
        let mut front: Vec<(u64, u64)> = self.front.iter().map(|(k, &id)| (k.0, id)).collect();
        front.sort_unstable();
        DetectorState {
            dims: self.dims,
            front,
            next_id: self.next_id,
            stats: self.stats,
        }
    }

    /// A detector continuing from `state` on a volume of `dims`. Lookups never depend on the
    /// map's iteration order (the end-of-volume drain is sorted), so it behaves exactly as the
    /// one that was saved.
    ///
    /// # Errors
    /// `state` was saved for a volume of other dimensions.
    pub fn restore(dims: [u64; 3], state: DetectorState) -> Result<Self, DimsMismatch> {
        if state.dims != dims {
            return Err(DimsMismatch {
                saved: state.dims,
                volume: dims,
            });
        }
        Ok(Self {
            dims,
            front: state
                .front
                .into_iter()
                .map(|(k, id)| (EdgeKey(k), id))
                .collect(),
            next_id: state.next_id,
            stats: state.stats,
        })
    }

    /// Converts one batch, appending to `out` (which the caller clears or reuses).
    pub fn process(&mut self, batch: &CubeBatch, out: &mut MeshDelta) {
        let stride = batch
            .attrs
            .len()
            .checked_div(batch.vertices.len())
            .unwrap_or(0);
        for cube in &batch.cubes {
            let first = cube.first_vertex as usize;
            let verts = &batch.vertices[first..first + cube.vertex_count as usize];
            let mut ids = [0u64; 12];
            for (k, (slot, v)) in ids.iter_mut().zip(verts).enumerate() {
                *slot = match self.front.get(&v.key) {
                    Some(&id) => id,
                    None => {
                        let id = self.next_id;
                        self.next_id += 1;
                        self.front.insert(v.key, id);
                        let ([_, _, z], axis) = v.key.decode(self.dims);
                        let rank = z + u64::from(axis == 2);
                        out.vertices.push(NewVertex {
                            id,
                            pos: v.pos,
                            rank: u32::try_from(rank).unwrap_or(u32::MAX),
                        });
                        if stride > 0 {
                            let at = (first + k) * stride;
                            out.attrs.extend_from_slice(&batch.attrs[at..at + stride]);
                        }
                        id
                    }
                };
            }
            let first_tri = cube.first_triangle as usize;
            for t in &batch.triangles[first_tri..first_tri + cube.triangle_count as usize] {
                out.triangles
                    .push([ids[t[0] as usize], ids[t[1] as usize], ids[t[2] as usize]]);
            }
            self.stats.peak_front = self.stats.peak_front.max(self.front.len() as u64);

            let [x, y, z] = cube.coord;
            for &(offset, axis) in modifiable_lines(CubeKind::of(cube.coord, self.dims)) {
                let key =
                    EdgeKey::new(x + offset[0], y + offset[1], z + offset[2], axis, self.dims);
                if let Some(id) = self.front.remove(&key) {
                    out.modifiable.push(id);
                }
            }
        }
        self.stats.vertices = self.next_id;
        self.stats.triangles += batch.triangles.len() as u64;
        out.front = u32::try_from(batch.slab + u64::from(batch.end_of_slab)).unwrap_or(u32::MAX);
        out.rows = match batch.end_of_slab {
            true => 0,
            false => u32::try_from(batch.rows_done).unwrap_or(u32::MAX),
        };
    }

    /// End of the stream: every vertex still waiting becomes modifiable, appended to `out`
    /// (the delta of the last batch, so the consumer sees one final delta). Table 1's "last
    /// traversed" cube releases everything, so this is empty on a complete stream; it drains
    /// defensively so that no vertex can stay unmodifiable.
    pub fn finish(&mut self, out: &mut MeshDelta) {
        let mut rest: Vec<u64> = self.front.drain().map(|(_, id)| id).collect();
        rest.sort_unstable();
        self.stats.released_at_end += rest.len() as u64;
        out.modifiable.extend(rest);
    }

    /// Vertices currently waiting for their last cube.
    pub fn front_len(&self) -> usize {
        self.front.len()
    }

    pub fn stats(&self) -> DetectStats {
        self.stats
    }
}

#[cfg(test)]
mod tests;
