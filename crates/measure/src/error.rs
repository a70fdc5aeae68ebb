//! The crate's error type: one line per message, saying what to check.

use isostream_volume::VolumeError;

#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    /// Reading the volume failed; its message already names the file and the fix.
    #[error(transparent)]
    Volume(#[from] VolumeError),

    #[error("samples_per_area must be positive and finite, got {0}")]
    SamplesPerArea(f64),

    #[error("max_distance must be positive and finite, got {0}")]
    MaxDistance(f64),

    #[error(
        "triangle {triangle} uses vertex {vertex} but the mesh has {vertices} vertices; the mesh file is corrupt"
    )]
    VertexIndex {
        triangle: usize,
        vertex: u32,
        vertices: usize,
    },

    /// Reading the slices of the volume or its attributes failed (message from the reader).
    #[error("{0}")]
    Slices(String),

    /// The mesh's box is far outside the volume's, or a tiny fraction of a voxel: its samples'
    /// grid (cells of the search radius) was sized by the gap (a 93 GB allocation), or the
    /// full surface's sampling density by the mesh's area (a loop that never ended).
    #[error("the mesh does not lie on that volume: {0}; measure it against the job that wrote it")]
    OffVolume(String),

    /// The sampling the mesh calls for is out of range: a density past f64's range (a mesh of
    /// denormal area), a triangle taking more samples than any settled density gives one, or
    /// a full surface no power-of-four weight thins. Sampling it was a loop of up to 2^64
    /// draws, or a weight that overflowed.
    #[error(
        "the mesh cannot be sampled: {0}; check that its coordinates are in the volume's units (measure it against the job that wrote it)"
    )]
    Unsampleable(String),

    #[error("the output mesh has no area; distances need a surface to sample")]
    EmptyOutput,

    #[error(
        "the full-resolution iso-surface has no area; check the iso value against the volume's range"
    )]
    EmptySurface,
}
