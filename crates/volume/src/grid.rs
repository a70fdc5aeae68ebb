//! Voxel grid geometry shared by every source and by the extractor (positions of edge vertices).

use crate::VolumeError;
use glam::DVec3;

/// Geometry of the voxel grid. Voxel (i,j,k) is at origin + spacing * (i,j,k).
///
/// Construct with [`Grid::new`] so the invariants hold: at least two voxels per axis (marching
/// cubes needs one cube), a voxel count that fits `u64`, a slice that fits `usize`, and finite
/// positive spacing.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Grid {
    pub dims: [u64; 3],
    pub spacing: [f64; 3],
    pub origin: [f64; 3],
}

impl Grid {
    /// Validates and builds a grid. Errors name "grid"; readers re-label them with their file.
    pub fn new(dims: [u64; 3], spacing: [f64; 3], origin: [f64; 3]) -> Result<Grid, VolumeError> {
        let bad = |problem: String| VolumeError::Grid {
            origin: "grid".to_string(),
            problem,
        };
        let d = dims_text(dims);
        if dims.iter().any(|&n| n < 2) {
            return Err(bad(format!(
                "dims {d} need at least 2 voxels per axis; check the dims"
            )));
        }
        let slice = dims[0].checked_mul(dims[1]);
        let count = slice.and_then(|s| s.checked_mul(dims[2]));
        if count.is_none() || slice.and_then(|s| usize::try_from(s).ok()).is_none() {
            return Err(bad(format!(
                "dims {d} overflow a 64-bit voxel count; check the dims"
            )));
        }
        if let Some(problem) = spacing_problem(spacing, "check the spacing") {
            return Err(bad(problem));
        }
        if origin.iter().any(|o| !o.is_finite()) {
            return Err(bad(format!(
                "origin {:?} must be finite; check the origin",
                origin
            )));
        }
        Ok(Grid {
            dims,
            spacing,
            origin,
        })
    }

    /// Number of voxels in one z-slice (x fastest, then y).
    pub fn slice_len(&self) -> usize {
        // Grid::new checked that this fits usize; a hand-built Grid saturates instead of wrapping.
        usize::try_from(self.dims[0].saturating_mul(self.dims[1])).unwrap_or(usize::MAX)
    }

    /// Total number of voxels.
    pub fn voxel_count(&self) -> u64 {
        self.dims[0]
            .saturating_mul(self.dims[1])
            .saturating_mul(self.dims[2])
    }

    /// Physical position of a (possibly fractional) voxel coordinate.
    pub fn position(&self, x: f64, y: f64, z: f64) -> DVec3 {
        DVec3::from(self.origin) + DVec3::from(self.spacing) * DVec3::new(x, y, z)
    }

    /// Length of the bounding box diagonal in physical units (the usual scale for error bounds).
    pub fn diagonal(&self) -> f64 {
        let extent = DVec3::from(self.spacing)
            * DVec3::new(
                self.dims[0].saturating_sub(1) as f64,
                self.dims[1].saturating_sub(1) as f64,
                self.dims[2].saturating_sub(1) as f64,
            );
        extent.length()
    }
}

/// Why `spacing` cannot be a grid's (not finite and > 0 on every axis), ending with `fix`.
pub(crate) fn spacing_problem(spacing: [f64; 3], fix: &str) -> Option<String> {
    spacing
        .iter()
        .any(|s| !s.is_finite() || *s <= 0.0)
        .then(|| format!("spacing {spacing:?} must be finite and > 0 on every axis; {fix}"))
}

/// "256x256x128": how dims appear in every message.
pub(crate) fn dims_text(dims: [u64; 3]) -> String {
    format!("{}x{}x{}", dims[0], dims[1], dims[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accessors() {
        let g = Grid::new([3, 4, 5], [1.0, 2.0, 0.5], [10.0, 0.0, -1.0]).unwrap();
        assert_eq!(g.slice_len(), 12);
        assert_eq!(g.voxel_count(), 60);
        assert_eq!(g.position(1.0, 1.0, 2.0), DVec3::new(11.0, 2.0, 0.0));
        let want = (2.0f64 * 2.0 + 6.0 * 6.0 + 2.0 * 2.0).sqrt();
        assert!((g.diagonal() - want).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_grids() {
        let e = Grid::new([1, 4, 5], [1.0; 3], [0.0; 3]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "grid: dims 1x4x5 need at least 2 voxels per axis; check the dims"
        );
        let e = Grid::new([u64::MAX, 4, 5], [1.0; 3], [0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("overflow"), "{e}");
        let e = Grid::new([2, 2, 2], [1.0, 0.0, 1.0], [0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("spacing"), "{e}");
        let e = Grid::new([2, 2, 2], [1.0, f64::NAN, 1.0], [0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("spacing"), "{e}");
        let e = Grid::new([2, 2, 2], [1.0; 3], [f64::INFINITY, 0.0, 0.0]).unwrap_err();
        assert!(e.to_string().contains("origin"), "{e}");
    }

    #[test]
    fn relabels_origin() {
        let e = Grid::new([0, 4, 5], [1.0; 3], [0.0; 3])
            .unwrap_err()
            .in_origin("x.nrrd");
        assert!(e.to_string().starts_with("x.nrrd: dims 0x4x5"), "{e}");
    }
}
