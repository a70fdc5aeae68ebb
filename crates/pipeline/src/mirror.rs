//! Axis flips of the input, applied exactly. A header whose axis steps backwards (an LPS NRRD's
//! `space directions: (-0.5,0,0) ...`, a LAS NIfTI's sform as FSL writes it, VTI
//! `Direction="-1 0 0 ..."`) puts voxel `i` at `origin - spacing * i` on that axis. The grid
//! the pipeline extracts from is axis-aligned with positive steps, so on a flipped axis it
//! works on the negated coordinate `u = -x` (origin `-origin`, step `+spacing`: the same voxels
//! in the same order, the same slabs and sweep), and the writer negates it back. Negating is
//! exact in `f32`, so every guarantee of the mesh (no crossing triangles, the error bound) holds
//! in physical space as in the extraction's; a reflection reverses orientation, so with an odd
//! number of flips each triangle's winding is swapped to keep its normal from high to low values.

use isostream_volume::{Grid, Orientation, VolumeSource};

/// The flipped axes (x, y, z) between the extraction's coordinates and the physical ones.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Mirror {
    axes: [bool; 3],
}

impl Mirror {
    /// The flips `source`'s header gives (none for a rotated or aligned volume: a rotation is
    /// not applied, and warned about).
    pub fn of(source: &dyn VolumeSource) -> Mirror {
        match source.orientation() {
            Orientation::Flipped(axes) => Mirror { axes },
            Orientation::Aligned | Orientation::Rotated => Mirror::default(),
        }
    }

    /// The grid of the extraction's coordinates for a reader's `grid` (positions `origin +
    /// spacing * i` with the header's origin and step lengths): the origin negated on each
    /// flipped axis. The same map takes extraction positions to physical ones and back.
    pub(crate) fn grid(&self, grid: Grid) -> Grid {
        Grid {
            origin: std::array::from_fn(|k| self.coordinate(k, grid.origin[k])),
            ..grid
        }
    }

    fn coordinate(&self, k: usize, x: f64) -> f64 {
        if self.axes[k] { -x } else { x }
    }

    /// A position moved between the extraction's coordinates and the physical ones (either
    /// way: the map is its own inverse).
    pub fn position(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| self.coordinate(k, p[k]))
    }

    /// A triangle's corners (and anything kept per corner) in the order that keeps its
    /// orientation through the map.
    pub(crate) fn corners<T: Copy>(&self, t: [T; 3]) -> [T; 3] {
        match self.axes.iter().filter(|&&f| f).count() % 2 {
            1 => [t[0], t[2], t[1]],
            _ => t,
        }
    }
}

/// A volume seen in the extraction's coordinates of its flips ([`Mirror::grid`]); its voxels
/// are the reader's, in the reader's order.
pub(crate) struct Mirrored {
    inner: Box<dyn VolumeSource>,
    mirror: Mirror,
}

impl Mirrored {
    /// `source` itself when its header flips no axis.
    pub(crate) fn wrap(source: Box<dyn VolumeSource>) -> Box<dyn VolumeSource> {
        let mirror = Mirror::of(source.as_ref());
        match mirror == Mirror::default() {
            true => source,
            false => Box::new(Mirrored {
                inner: source,
                mirror,
            }),
        }
    }
}

impl VolumeSource for Mirrored {
    fn grid(&self) -> Grid {
        self.mirror.grid(self.inner.grid())
    }
    fn describe(&self) -> String {
        self.inner.describe()
    }
    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), isostream_volume::VolumeError> {
        self.inner.read_slice(z, out)
    }
    fn dtype(&self) -> Option<isostream_volume::Dtype> {
        self.inner.dtype()
    }
    fn stored_range(&self) -> Option<(f32, f32)> {
        self.inner.stored_range()
    }
    fn orientation(&self) -> Orientation {
        self.inner.orientation()
    }
    fn loads_whole_volume(&self) -> bool {
        self.inner.loads_whole_volume()
    }
    fn saturated_voxels(&self) -> u64 {
        self.inner.saturated_voxels()
    }
    fn slab_bounds(
        &mut self,
        z: u64,
    ) -> Result<Option<std::sync::Arc<isostream_volume::SlabBounds>>, isostream_volume::VolumeError>
    {
        self.inner.slab_bounds(z)
    }
    fn read_slice_near(
        &mut self,
        z: u64,
        iso: f32,
        out: &mut [f32],
    ) -> Result<(), isostream_volume::VolumeError> {
        self.inner.read_slice_near(z, iso, out)
    }
    fn slice_rows(
        &mut self,
        z: u64,
        iso: Option<f32>,
    ) -> Result<
        Option<std::sync::Arc<dyn isostream_volume::SliceRows>>,
        isostream_volume::VolumeError,
    > {
        self.inner.slice_rows(z, iso)
    }
    fn identity_values(&mut self, z: u64) -> Result<Vec<f32>, isostream_volume::VolumeError> {
        self.inner.identity_values(z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flip_negates_its_axis_and_rewinds_odd_flips_only() {
        let m = Mirror {
            axes: [true, false, false],
        };
        assert_eq!(m.position([1.5, 2.0, -3.0]), [-1.5, 2.0, -3.0]);
        assert_eq!(m.position(m.position([1.5, 2.0, -3.0])), [1.5, 2.0, -3.0]);
        assert_eq!(m.corners([0, 1, 2]), [0, 2, 1]);
        let two = Mirror {
            axes: [true, true, false],
        };
        assert_eq!(two.corners([0, 1, 2]), [0, 1, 2]);
        let grid = Grid::new([4, 4, 4], [0.5, 1.0, 1.0], [10.0, -5.0, 3.0]).unwrap();
        assert_eq!(two.grid(grid).origin, [-10.0, 5.0, 3.0]);
        assert_eq!(two.grid(grid).spacing, grid.spacing);
    }
}
