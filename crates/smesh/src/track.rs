//! The streaming-mesh rules as one state machine, shared by every writer (so nothing invalid is
//! written), by the validator and by every reader-driven consumer (so the messages are the same
//! whichever side finds the fault).
//!
//! Memory is bounded by the stream width: only active (written, not yet finalized) vertices are
//! remembered, with their positions because some sinks (STL, normals) need them.

use rustc_hash::FxHashMap;

use crate::StreamFault;

#[derive(Debug, Default, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct Tracker {
    vertices: u64,
    triangles: u64,
    active: FxHashMap<u64, [f32; 3]>,
    max_active: u64,
    max_skip: u64,
    bbox: Option<([f32; 3], [f32; 3])>,
}

impl Tracker {
    pub(crate) fn vertices(&self) -> u64 {
        self.vertices
    }

    pub(crate) fn triangles(&self) -> u64 {
        self.triangles
    }

    /// Most vertices active at once: the stream width.
    pub(crate) fn max_active(&self) -> u64 {
        self.max_active
    }

    /// How far back the farthest-reaching triangle refers: vertices read so far minus one minus
    /// its oldest vertex (0 when every triangle only uses the latest vertices).
    pub(crate) fn max_skip(&self) -> u64 {
        self.max_skip
    }

    pub(crate) fn bbox(&self) -> Option<([f32; 3], [f32; 3])> {
        self.bbox
    }

    /// Registers the next vertex; returns its index.
    pub(crate) fn vertex(&mut self, pos: [f32; 3]) -> u64 {
        let v = self.vertices;
        self.vertices += 1;
        self.active.insert(v, pos);
        self.max_active = self.max_active.max(self.active.len() as u64);
        self.bbox = Some(match self.bbox {
            None => (pos, pos),
            Some((lo, hi)) => (
                std::array::from_fn(|i| lo[i].min(pos[i])),
                std::array::from_fn(|i| hi[i].max(pos[i])),
            ),
        });
        v
    }

    /// Checks a triangle (three distinct vertices, all written and still active) before
    /// changing anything, then finalizes the flagged ones. Returns the corner positions (sinks
    /// that store triangles as positions need them). A repeated vertex is refused: such a
    /// "triangle" has no area, and one of its corners would be finalized twice; `check` called
    /// a mesh holding one valid and `measure` missed it among the zero-area triangles.
    pub(crate) fn triangle(
        &mut self,
        v: [u64; 3],
        finalize: [bool; 3],
    ) -> Result<[[f32; 3]; 3], StreamFault> {
        if let Some(k) = (0..3).find(|&k| v[k] == v[(k + 1) % 3]) {
            return Err(StreamFault::RepeatedVertex { vertex: v[k] });
        }
        let mut corners = [[0.0; 3]; 3];
        for (c, &x) in corners.iter_mut().zip(&v) {
            *c = self.active_position(x)?;
        }
        let oldest = v.iter().copied().min().unwrap_or(0);
        self.max_skip = self.max_skip.max(self.vertices - 1 - oldest);
        self.triangles += 1;
        for (&x, &f) in v.iter().zip(&finalize) {
            if f {
                self.active.remove(&x);
            }
        }
        Ok(corners)
    }

    /// An explicit finalization (SMA `x` line).
    pub(crate) fn finalize(&mut self, v: u64) -> Result<(), StreamFault> {
        self.active_position(v)?;
        self.active.remove(&v);
        Ok(())
    }

    /// The end-of-stream rule: every vertex finalized.
    pub(crate) fn finish(&self) -> Result<(), StreamFault> {
        match self.active.keys().min() {
            None => Ok(()),
            Some(&vertex) => Err(StreamFault::NeverFinalized {
                vertex,
                others: self.active.len() as u64 - 1,
            }),
        }
    }

    fn active_position(&self, v: u64) -> Result<[f32; 3], StreamFault> {
        if v >= self.vertices {
            Err(StreamFault::Forward {
                vertex: v,
                available: self.vertices,
            })
        } else {
            self.active
                .get(&v)
                .copied()
                .ok_or(StreamFault::UseAfterFinalize { vertex: v })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn width_skip_and_faults() {
        let mut t = Tracker::default();
        for i in 0..4 {
            t.vertex([i as f32, 0.0, 0.0]);
        }
        t.triangle([0, 1, 3], [true, false, false]).unwrap();
        assert_eq!(t.max_skip(), 3);
        assert_eq!(t.max_active(), 4);
        assert_eq!(
            t.triangle([0, 1, 2], [false; 3]),
            Err(StreamFault::UseAfterFinalize { vertex: 0 })
        );
        assert_eq!(
            t.triangle([1, 2, 4], [false; 3]),
            Err(StreamFault::Forward {
                vertex: 4,
                available: 4
            })
        );
        assert_eq!(
            t.finish(),
            Err(StreamFault::NeverFinalized {
                vertex: 1,
                others: 2
            })
        );
        assert_eq!(
            t.triangle([1, 2, 3], [true; 3]).unwrap()[2],
            [3.0, 0.0, 0.0]
        );
        assert_eq!(
            t.triangle([1, 2, 1], [true; 3]),
            Err(StreamFault::RepeatedVertex { vertex: 1 })
        );
        assert_eq!(t.finish(), Ok(()));
        assert_eq!(t.triangles(), 2);
        assert_eq!(t.bbox(), Some(([0.0; 3], [3.0, 0.0, 0.0])));
    }
}
