//! The slice-streaming contract between volume readers and the extractor.

use std::sync::Arc;

use crate::{Dtype, Grid, Orientation, SlabBounds, VolumeError};

/// A volume read slice by slice in increasing z. Implementations never hold the whole volume
/// (an encoding that forces it says so in its docs), because the memory bound of the whole
/// pipeline starts here.
pub trait VolumeSource: Send {
    /// Geometry of the whole volume; constant for the life of the source.
    fn grid(&self) -> Grid;
    /// Human-readable origin for logs and errors: the file path, or e.g. "procedural sphere 64x64x64".
    fn describe(&self) -> String;
    /// Fill `out` (len == grid.slice_len(), x fastest then y) with slice z converted to f32.
    /// Callers ask for z = 0,1,2,... in order (a source may re-read a slice, e.g. z-1, too).
    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError>;
    /// The voxel type stored in the file, when there is one (for logs and format checks).
    fn dtype(&self) -> Option<Dtype> {
        None
    }
    /// The range every finite voxel lies in, known before any is read: its stored integer
    /// type's ([`Dtype::integer_range`]) by default. The pipeline refuses an iso outside it up
    /// front, where otherwise a run read the whole volume to find its surface empty and
    /// `validate` passed the job. A reader that rescales its stored values (NIfTI's
    /// `scl_slope`) says `None`, and a source computed from another gives the other's.
    fn stored_range(&self) -> Option<(f32, f32)> {
        self.dtype().and_then(Dtype::integer_range)
    }
    /// What of the header's axis directions the grid dropped (flips, a rotation): the grid is
    /// axis-aligned, so the pipeline warns that the mesh is not where the header puts the
    /// volume. Sources without a header say [`Orientation::Aligned`].
    fn orientation(&self) -> Orientation {
        Orientation::Aligned
    }
    /// Voxels read so far whose stored values were finite but beyond f32's range (1e40 in an
    /// f64 volume), saturated to `±f32::MAX` rather than made infinite. Every read counts (a
    /// slice read twice, twice): a caller wanting each voxel once takes the difference around
    /// its first read of each slice. 0 for sources whose values always fit f32.
    fn saturated_voxels(&self) -> u64 {
        0
    }
    /// True when the encoding forces the reader to decode the whole volume up front, so the
    /// pipeline can warn that its memory bound does not hold for this input.
    fn loads_whole_volume(&self) -> bool {
        false
    }
    /// Value bounds per block of cubes of slab z (between slices z and z + 1) when the source
    /// knows them without computing the voxels (a virtual source such as
    /// [`crate::Upsampled`]); `None` (the default) when only the voxels can tell, and the
    /// caller computes them from the slices ([`SlabBounds::from_slices`]).
    fn slab_bounds(&mut self, _z: u64) -> Result<Option<Arc<SlabBounds>>, VolumeError> {
        Ok(None)
    }
    /// Slice z for extraction at `iso`: exact wherever a cube of slab z - 1 or z may cross
    /// `iso` (by [`Self::slab_bounds`]), elsewhere any value on the same side of `iso` as the
    /// exact one, so the same cubes are empty and the same triangles come out. A virtual source
    /// skips computing those voxels; the default reads the exact slice.
    fn read_slice_near(&mut self, z: u64, _iso: f32, out: &mut [f32]) -> Result<(), VolumeError> {
        self.read_slice(z, out)
    }
    /// The stored values that decide slice z, to tell whether the input changed (a checkpoint's
    /// input identity): slice z itself by default. A virtual source computed from another gives
    /// the source slices it interpolates, so the check costs a pass over stored data, not over
    /// a slice that upsampling made up to `k^2` times larger (days of hashing, before any stage
    /// started, for a large factor).
    fn identity_values(&mut self, z: u64) -> Result<Vec<f32>, VolumeError> {
        let mut out = vec![0f32; self.grid().slice_len()];
        self.read_slice(z, &mut out)?;
        Ok(out)
    }
    /// Slice z as rows computed on demand, when the source can give them without computing the
    /// whole slice (a virtual source): `read_slice_near(z, iso)` (or `read_slice(z)` for `None`)
    /// row by row. `None` (the default) for sources that can only give whole slices.
    fn slice_rows(
        &mut self,
        _z: u64,
        _iso: Option<f32>,
    ) -> Result<Option<Arc<dyn SliceRows>>, VolumeError> {
        Ok(None)
    }
}

/// One slice whose rows are computed on demand ([`VolumeSource::slice_rows`]): the extractor
/// can work on strips of rows of a gigavoxel slice without the slice existing whole. Shared
/// between threads (slabs are extracted in parallel).
pub trait SliceRows: Send + Sync {
    /// Fills `out` (whole rows of `grid.dims[0]` values, x fastest) with rows `y0..` of the
    /// slice, the values `read_slice_near` (or `read_slice`) gives there.
    fn fill_rows(&self, y0: u64, out: &mut [f32]);
}

/// Lets pipelines hold `Box<dyn VolumeSource>` wherever a source is expected.
impl VolumeSource for Box<dyn VolumeSource> {
    fn grid(&self) -> Grid {
        (**self).grid()
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        (**self).read_slice(z, out)
    }
    fn dtype(&self) -> Option<Dtype> {
        (**self).dtype()
    }
    fn stored_range(&self) -> Option<(f32, f32)> {
        (**self).stored_range()
    }
    fn orientation(&self) -> Orientation {
        (**self).orientation()
    }
    fn saturated_voxels(&self) -> u64 {
        (**self).saturated_voxels()
    }
    fn loads_whole_volume(&self) -> bool {
        (**self).loads_whole_volume()
    }
    fn slab_bounds(&mut self, z: u64) -> Result<Option<Arc<SlabBounds>>, VolumeError> {
        (**self).slab_bounds(z)
    }
    fn read_slice_near(&mut self, z: u64, iso: f32, out: &mut [f32]) -> Result<(), VolumeError> {
        (**self).read_slice_near(z, iso, out)
    }
    fn slice_rows(
        &mut self,
        z: u64,
        iso: Option<f32>,
    ) -> Result<Option<Arc<dyn SliceRows>>, VolumeError> {
        (**self).slice_rows(z, iso)
    }
    fn identity_values(&mut self, z: u64) -> Result<Vec<f32>, VolumeError> {
        (**self).identity_values(z)
    }
}

/// Checks the `read_slice` preconditions every source shares (z in range, buffer length).
pub(crate) fn check_request(
    src: &dyn VolumeSource,
    z: u64,
    out: &[f32],
) -> Result<(), VolumeError> {
    let grid = src.grid();
    VolumeError::check_slice_request(
        || src.describe(),
        z,
        grid.dims[2],
        out.len(),
        grid.slice_len(),
    )
}
