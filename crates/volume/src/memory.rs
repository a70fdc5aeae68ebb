//! An in-memory volume for tests and small cases (the one source allowed to hold everything).

use crate::source::check_request;
use crate::{Grid, VolumeError, VolumeSource, grid::dims_text};

/// A whole volume held in a `Vec<f32>`, x fastest, then y, then z.
#[derive(Debug, Clone)]
pub struct MemoryVolume {
    grid: Grid,
    data: Vec<f32>,
}

impl MemoryVolume {
    /// Wraps `data`; its length must equal the grid's voxel count.
    pub fn new(grid: Grid, data: Vec<f32>) -> Result<Self, VolumeError> {
        if data.len() as u64 != grid.voxel_count() {
            return Err(VolumeError::Grid {
                origin: "in-memory volume".to_string(),
                problem: format!(
                    "data has {} values but dims {} need {}; pass one value per voxel",
                    data.len(),
                    dims_text(grid.dims),
                    grid.voxel_count()
                ),
            });
        }
        Ok(MemoryVolume { grid, data })
    }

    /// All voxels, x fastest, then y, then z.
    pub fn data(&self) -> &[f32] {
        &self.data
    }
}

impl VolumeSource for MemoryVolume {
    fn grid(&self) -> Grid {
        self.grid
    }

    fn describe(&self) -> String {
        format!("in-memory volume {}", dims_text(self.grid.dims))
    }

    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        check_request(self, z, out)?;
        let n = self.grid.slice_len();
        // z < dims[2] and the whole array is in memory, so the offset fits usize.
        let start = z as usize * n;
        out.copy_from_slice(&self.data[start..start + n]);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Grid {
        Grid::new([2, 3, 2], [1.0; 3], [0.0; 3]).unwrap()
    }

    #[test]
    fn reads_slices_in_order() {
        let data: Vec<f32> = (0..12).map(|v| v as f32).collect();
        let mut v = MemoryVolume::new(grid(), data.clone()).unwrap();
        assert_eq!(v.data(), &data[..]);
        let mut out = [0.0f32; 6];
        v.read_slice(1, &mut out).unwrap();
        assert_eq!(out, [6.0, 7.0, 8.0, 9.0, 10.0, 11.0]);
        let boxed: Box<dyn VolumeSource> = Box::new(v);
        let mut boxed = boxed;
        boxed.read_slice(0, &mut out).unwrap();
        assert_eq!(out[5], 5.0);
        assert_eq!(boxed.describe(), "in-memory volume 2x3x2");
    }

    #[test]
    fn rejects_wrong_length_and_bad_requests() {
        let e = MemoryVolume::new(grid(), vec![0.0; 11]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "in-memory volume: data has 11 values but dims 2x3x2 need 12; pass one value per voxel"
        );
        let mut v = MemoryVolume::new(grid(), vec![0.0; 12]).unwrap();
        let e = v.read_slice(2, &mut [0.0; 6]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "in-memory volume 2x3x2: slice 2 requested but the volume has 2 slices; this is a bug in the caller of read_slice"
        );
        assert!(v.read_slice(0, &mut [0.0; 5]).is_err());
    }
}
