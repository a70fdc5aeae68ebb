//! isostream-volume: scalar volumes read slice by slice in increasing z.
//!
//! Every source implements [`VolumeSource`]; the extractor only ever holds two slices, so a
//! source must not hold the whole volume either. [`open_path`] picks a reader from the file name
//! or its first bytes:
//!
//! | input | reader | memory |
//! |---|---|---|
//! | `.raw` (+ dims/dtype in [`OpenOptions`]) | [`RawVolume`], memory-mapped | pages behind the front are released |
//! | `.nrrd` / `.nhdr` (raw, gzip, ascii; `data file` lists) | NRRD | raw single file mapped, else two slices |
//! | `.vtk` legacy `STRUCTURED_POINTS` (binary, ascii) | VTK | binary mapped, ascii two slices |
//! | `.vti` (ascii, base64, appended; zlib) | VTK XML | appended raw mapped, else two slices + one 32 KiB block; the mapped file's pages are released as the stream passes them |
//! | `.nii` / `.nii.gz` / `.hdr`+`.img` / `.hdr.gz`+`.img.gz` | NIfTI-1 | `.nii` and `.img` mapped, gzip two slices |
//! | `.tif` / `.tiff` / a directory of them | TIFF stack | one page |
//! | a directory with `zarr.json`, `.zarray` or `.zgroup` (or that file): Zarr v3 / v2, OME-Zarr v0.5 / v0.4 | Zarr | one row of chunks |
//!
//! No reader decodes a whole array up front ([`VolumeSource::loads_whole_volume`] is false for
//! all of them). [`Procedural`] shapes are computed per slice; [`MemoryVolume`] holds everything
//! and is meant for tests and small inputs. [`Upsampled`] sees any source through trilinear
//! interpolation at a higher resolution without materialising it, and knows the value bounds of
//! its cells ([`SlabBounds`], for empty-space skipping). Errors are [`VolumeError`] values whose message is one
//! line naming the file, where in it the problem is, and what was expected.
//!
//! ```
//! use isostream_volume::{Procedural, Shape, VolumeSource};
//!
//! let mut sphere = Procedural::new(Shape::Sphere, [32, 32, 32], [1.0; 3], [0.0; 3]).unwrap();
//! let mut slice = vec![0.0f32; sphere.grid().slice_len()];
//! sphere.read_slice(16, &mut slice).unwrap();
//! assert!(slice[16 * 32 + 16] > 0.0, "the centre is inside");
//! ```
#![deny(unsafe_code)]

mod bounds;
mod codec;
mod dtype;
mod error;
mod grid;
mod memory;
mod nifti;
mod nrrd;
mod open;
mod options;
mod orientation;
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
mod upsample;
mod vti;
mod vtk;
mod xml;
mod zarr;

pub use bounds::SlabBounds;
pub use dtype::{Dtype, Endian};
pub use error::VolumeError;
pub use grid::Grid;
pub use memory::MemoryVolume;
pub use open::open_path;
pub use options::OpenOptions;
pub use orientation::Orientation;
pub use procedural::{Procedural, Shape};
pub use raw::{RawSpec, RawVolume};
pub use source::{SliceRows, VolumeSource};
pub use upsample::{FineSlice, Upsampled};
