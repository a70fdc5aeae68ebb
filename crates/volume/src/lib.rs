//! isostream-volume: scalar volumes read slice by slice in increasing z.
//!
//! Every source implements [`VolumeSource`]; the extractor only ever holds two slices, so a
//! source must not hold the whole volume either (raw files are memory-mapped with pages released
//! behind the front, procedural shapes are computed per slice). [`MemoryVolume`] is the exception
//! for tests and small inputs. Errors are [`VolumeError`] values whose message is one line naming
//! the file and what to check.
#![deny(unsafe_code)]

mod codec;
mod dtype;
mod error;
mod grid;
mod memory;
mod nifti;
mod nrrd;
mod open;
mod options;
mod procedural;
mod raw;
#[cfg(test)]
mod real_data;
#[cfg(test)]
mod robustness;
mod source;
mod stream;
#[cfg(test)]
mod testutil;
mod tiff;
mod vti;
mod vtk;
mod xml;

pub use dtype::{Dtype, Endian};
pub use error::VolumeError;
pub use grid::Grid;
pub use memory::MemoryVolume;
pub use open::open_path;
pub use options::OpenOptions;
pub use procedural::{Procedural, Shape};
pub use raw::{RawSpec, RawVolume};
pub use source::VolumeSource;
