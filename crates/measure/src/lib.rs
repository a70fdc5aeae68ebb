//! Quality measures of a simplified iso-surface, after the Tandem paper (Attali, Cohen-Steiner,
//! Edelsbrunner, "Extraction and Simplification of Iso-surfaces in Tandem", section 4):
//!
//! * [`mesh_quality`]: topology (via `isostream-meshcheck`), minimum angles, anisotropy and
//!   directional bias of the in-memory output mesh;
//! * [`surface_distances`]: Metro-style mean / RMS / Hausdorff distances (and the distance 99.9 %
//!   of the samples are within) in both directions between
//!   the output mesh and the full-resolution iso-surface, which is regenerated from the volume slab
//!   by slab and never held whole (a second time for the output samples farther from it than the
//!   first pass's search radius); [`FullSurfaceDistances`] takes that surface from the caller's
//!   own extraction (`isostream measure` lends it the pipeline's parallel one);
//! * [`MeasureReport`]: both, plus the run's shape error, as JSON or text.
//!
//! Modules: `triangle` (one triangle's geometry), `bvh` (nearest-point queries), `sampling`
//! (seeded area-proportional samples), `anisotropy`, `bias`, `quality`, `distances` (the streamed
//! two-way distance), `far` (its second pass), `quantile` (its 99.9th percentile in bounded
//! memory), `full_surface` (the
//! volume -> slab stream), `halves` (a batch's queries on two threads the caller lends), `report`.
#![deny(unsafe_code)]

mod anisotropy;
mod attribute_error;
mod bias;
mod bvh;
mod distances;
mod error;
mod far;
mod full_surface;
mod halves;
mod quality;
mod quantile;
mod report;
mod sampling;
mod triangle;

pub use attribute_error::{AttributeError, SliceSet, attribute_errors};
pub use distances::{
    DEFAULT_SAMPLES_PER_AREA, DEFAULT_SEARCH_VOXEL_DIAGONALS, DEFAULT_SEED, DirectedDistance,
    Distances, MAX_SAMPLES, MIN_SAMPLES, MeasureOptions,
};
pub use error::MeasureError;
pub use full_surface::{FirstPass, FullSurfaceDistances, SecondPass, surface_distances};
pub use halves::{Halves, InTurn};
pub use quality::{MeshQuality, mesh_quality};
pub use report::MeasureReport;
