//! Per-cube marching cubes for isostream: a watertight, edge-manifold case table generated at
//! start-up, vertices keyed by the grid edge they lie on, and a slab-at-a-time extractor whose
//! batches feed the detector.
//!
//! # Conventions
//!
//! - **Inside / outside.** A voxel is *inside* when its value is strictly greater than the iso
//!   value and finite ([`is_inside`]); values equal to iso, NaN and ±inf are *outside*. The
//!   rule is a plain comparison, so it is deterministic, and a value equal to iso puts a vertex
//!   exactly on the corner (it stays an edge vertex; the simplifier collapses such zero-length
//!   edges first).
//! - **Orientation.** Triangles are counter-clockwise seen from the outside region: normals point
//!   from inside (high values) to outside (low values), i.e. against the gradient. A blob of high
//!   values (a sphere with values decreasing outwards) therefore has outward normals and
//!   positive signed volume.
//! - **Numbering.** Corner `c` of a cube sits at offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`;
//!   edge `e` runs along axis `e / 4` from the corner whose other two coordinates are the bits of
//!   `e % 4` (see [`cube`]). A cube's case index has bit `c` set when corner `c` is inside.
//! - **Vertices.** A vertex lies on the grid edge from voxel (x, y, z) along an axis,
//!   identified by [`EdgeKey`]; it sits at `t = (iso - va) / (vb - va)` along the edge (clamped
//!   to [0, 1], 0.5 when a value is non-finite), mapped through the grid's spacing and origin.
//!
//! # Guarantees
//!
//! Ambiguous faces (two diagonal inside corners) are always resolved by separating the inside
//! corners, a rule that depends only on the face's four signs, so two cubes sharing a face draw
//! the same iso-segments on it. Together with triangulations that never put an interior diagonal
//! between two vertices of a common face (see [`table`]), the surface is watertight, edge- and
//! vertex-manifold, consistently oriented and free of duplicate triangles on every volume; it has
//! boundary only on the volume box, and is closed when the border voxels are all outside. The
//! tests check the table exhaustively and the surfaces on random volumes.
//!
//! # Example
//!
//! The pipeline feeds slices in z order and forwards each batch to the detector:
//!
//! ```
//! use isostream_extract::{Extractor, extract_indexed};
//! use isostream_volume::{Grid, MemoryVolume};
//!
//! let grid = Grid::new([3, 3, 3], [1.0; 3], [0.0; 3]).unwrap();
//! let mut data = vec![0.0f32; 27];
//! data[13] = 1.0; // only the centre voxel is inside at iso 0.5
//! let mut extractor = Extractor::new(grid, 0.5);
//! let mut triangles = 0;
//! for z in 0..2 {
//!     let (lower, upper) = (&data[z * 9..][..9], &data[(z + 1) * 9..][..9]);
//!     let sent = extractor.extract_slab(z as u64, lower, upper, 1024, |batch| {
//!         triangles += batch.triangle_count();
//!         Ok::<_, ()>(()) // a closed channel would be an Err here, stopping the slab
//!     });
//!     sent.unwrap();
//! }
//! assert_eq!(triangles, 8);
//!
//! // The in-memory reference builds the same surface, indexed (an octahedron).
//! let surface = extract_indexed(&mut MemoryVolume::new(grid, data).unwrap(), 0.5).unwrap();
//! assert_eq!((surface.positions.len(), surface.triangles.len()), (6, 8));
//! ```
//!
//! # Modules
//!
//! - [`cube`]: corner, edge and face numbering of one cube.
//! - [`table`]: the case table and how it is generated (the face rule, loops, triangulation).
//! - [`interp`]: inside test and vertex placement.
//! - `key`, `slab`, `reference`: [`EdgeKey`], the streaming [`Extractor`], and the in-memory
//!   reference [`extract_indexed`].
//!
//! Architecture invariant: no I/O beyond the [`isostream_volume::VolumeSource`] the reference
//! is handed, no threads.
#![deny(unsafe_code)]

pub mod attributes;
pub mod cube;
pub mod interp;
mod key;
mod reference;
mod slab;
pub mod table;

pub use interp::is_inside;
pub use key::EdgeKey;
pub use reference::{IndexedSurface, extract_indexed};
pub use slab::{Cube, CubeBatch, EdgeVertex, ExtractStats, Extractor, RowQuad, SlabRows};
