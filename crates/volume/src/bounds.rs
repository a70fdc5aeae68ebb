//! Value bounds per block of cubes of one slab: what empty-space skipping needs to know that no
//! cube of a block can cross the iso value, without looking at the block's voxels again.
//!
//! A *slab* is the layer of cubes between slices z and z + 1; its cubes are cut into blocks of
//! `block[0] x block[1]` cubes along x and y (the last ones may be smaller). A block's bounds
//! hold every voxel value of its cubes (both slices, the shared border voxels included). A
//! non-finite voxel makes its block unbounded (it can never be skipped), so a skipped block has
//! no NaN or infinity.

use crate::Grid;

/// Lower and upper value bounds of every block of a slab.
#[derive(Debug, Clone, PartialEq)]
pub struct SlabBounds {
    block: [u64; 2],
    count: [usize; 2],
    min: Vec<f32>,
    max: Vec<f32>,
}

impl SlabBounds {
    /// Bounds that hold nothing yet, for `count` blocks of `block` cubes (each at least 1).
    pub fn empty(block: [u64; 2], count: [usize; 2]) -> Self {
        let n = count[0] * count[1];
        Self {
            block: block.map(|b| b.max(1)),
            count,
            min: vec![f32::INFINITY; n],
            max: vec![f32::NEG_INFINITY; n],
        }
    }

    /// Bounds of slab (`lower`, `upper`) of a stored volume, from its voxels, in blocks of
    /// `block` cubes.
    ///
    /// # Panics
    /// If a slice does not hold `grid.slice_len()` values.
    pub fn from_slices(grid: &Grid, block: [u64; 2], lower: &[f32], upper: &[f32]) -> Self {
        let [nx, ny] = [grid.dims[0] as usize, grid.dims[1] as usize];
        let block = block.map(|b| b.max(1));
        let [bx, by] = block.map(|b| b as usize);
        let count = [(nx - 1).div_ceil(bx), (ny - 1).div_ceil(by)];
        let mut bounds = Self::empty(block, count);
        for slice in [lower, upper] {
            assert_eq!(slice.len(), nx * ny, "slices must hold {} values", nx * ny);
            for y in 0..ny {
                let row = &slice[y * nx..(y + 1) * nx];
                // The block row of this voxel row, and the one below when y is their border.
                let below = (y % by == 0 && y > 0).then(|| y / by - 1);
                let here = (y / by < count[1]).then_some(y / by);
                for i in 0..count[0] {
                    let segment = &row[i * bx..((i + 1) * bx + 1).min(nx)];
                    let (lo, hi) = segment_bounds(segment);
                    for j in [below, here].into_iter().flatten() {
                        bounds.include(i + count[0] * j, lo, hi);
                    }
                }
            }
        }
        bounds
    }

    /// Widens block `i` (x fastest) to hold [lo, hi]; a non-finite value makes it unbounded.
    pub fn include(&mut self, i: usize, lo: f32, hi: f32) {
        self.min[i] = self.min[i].min(lo);
        self.max[i] = self.max[i].max(hi);
    }

    /// Cubes per block along x and y.
    pub fn block(&self) -> [u64; 2] {
        self.block
    }

    /// Blocks along x and y.
    pub fn count(&self) -> [usize; 2] {
        self.count
    }

    /// Whether a cube of block (`bx`, `by`) may cross `iso`: false when every voxel is provably
    /// outside (<= iso) or provably inside (> iso and finite), as `extract::is_inside` decides.
    pub fn may_cross(&self, bx: usize, by: usize, iso: f32) -> bool {
        let i = bx + self.count[0] * by;
        !(self.max[i] <= iso || self.min[i] > iso)
    }

    /// Whether any cube of block row `by` may cross `iso` ([`Self::may_cross`]).
    pub fn row_may_cross(&self, by: usize, iso: f32) -> bool {
        (0..self.count[0]).any(|bx| self.may_cross(bx, by, iso))
    }

    /// The smallest lower and largest upper bound among the blocks with finite bounds (those
    /// holding a non-finite voxel are unbounded); `(inf, -inf)` when there is none.
    pub fn finite_range(&self) -> (f32, f32) {
        let finite = |v: &&f32| v.is_finite();
        (
            self.min
                .iter()
                .filter(finite)
                .copied()
                .fold(f32::INFINITY, f32::min),
            self.max
                .iter()
                .filter(finite)
                .copied()
                .fold(f32::NEG_INFINITY, f32::max),
        )
    }

    /// Whether some block holds a non-finite voxel (and so has no finite bounds).
    pub fn has_unbounded(&self) -> bool {
        // A finite voxel never widens a bound to an infinity: only a non-finite one does.
        self.min.contains(&f32::NEG_INFINITY) || self.max.contains(&f32::INFINITY)
    }

    /// A value inside the bounds of block (`bx`, `by`) (its lower bound): on the same side of any
    /// iso value as every voxel of a block that cannot cross it.
    pub fn low(&self, bx: usize, by: usize) -> f32 {
        self.min[bx + self.count[0] * by]
    }

    /// Cubes in blocks that cannot cross `iso`.
    pub fn skipped_cubes(&self, grid: &Grid, iso: f32) -> u64 {
        let cubes = [grid.dims[0] - 1, grid.dims[1] - 1];
        let mut skipped = 0;
        for by in 0..self.count[1] {
            let h = (cubes[1] - by as u64 * self.block[1]).min(self.block[1]);
            for bx in 0..self.count[0] {
                if !self.may_cross(bx, by, iso) {
                    let w = (cubes[0] - bx as u64 * self.block[0]).min(self.block[0]);
                    skipped += w * h;
                }
            }
        }
        skipped
    }
}

/// (min, max) of finite values; (-inf, +inf) when one is not finite.
pub(crate) fn segment_bounds(values: &[f32]) -> (f32, f32) {
    let mut lo = f32::INFINITY;
    let mut hi = f32::NEG_INFINITY;
    let mut finite = true;
    // Compare-and-select rather than `f32::min`/`max`, whose NaN rule keeps the loop from
    // vectorizing (two thirds of the extraction thread's bounds time); a NaN is caught by
    // `finite` either way.
    for &v in values {
        finite &= v.is_finite();
        lo = if v < lo { v } else { lo };
        hi = if v > hi { v } else { hi };
    }
    if finite {
        (lo, hi)
    } else {
        (f32::NEG_INFINITY, f32::INFINITY)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_hold_their_voxels_borders_included() {
        // 5 x 4 voxels: 4 x 3 cubes in blocks of 2 x 2 -> 2 x 2 blocks, the top ones 1 cube high.
        let grid = Grid::new([5, 4, 2], [1.0; 3], [0.0; 3]).unwrap();
        let lower: Vec<f32> = (0..20).map(|i| i as f32).collect();
        let upper = vec![0.0f32; 20];
        let b = SlabBounds::from_slices(&grid, [2, 2], &lower, &upper);
        assert_eq!(b.count(), [2, 2]);
        // Block (1, 1): voxels x 2..=4, y 2..=3 of lower: 12..=19, and upper's zeros.
        assert_eq!((b.low(1, 1), b.max[3]), (0.0, 19.0));
        // Block (0, 0): x 0..=2, y 0..=2: up to 12.
        assert_eq!(b.max[0], 12.0);
        assert!(b.may_cross(0, 0, 5.0));
        assert!(!b.may_cross(0, 0, 12.0), "all <= iso is outside");
        assert!(!b.may_cross(0, 0, -1.0), "all > iso is inside");
        assert_eq!(b.skipped_cubes(&grid, 12.0), 4);
        assert_eq!(b.skipped_cubes(&grid, 50.0), 12);
        // Block row 1 (voxel rows 2 and 3) holds 0..=19, block row 0 (rows 0 to 2) 0..=14.
        assert!(b.row_may_cross(1, 15.0) && !b.row_may_cross(0, 15.0));
        assert!(!b.row_may_cross(1, 19.0));
        assert_eq!(b.finite_range(), (0.0, 19.0));
        assert!(!b.has_unbounded());
    }

    #[test]
    fn unbounded_blocks_stay_out_of_the_finite_range() {
        let grid = Grid::new([3, 2, 2], [1.0; 3], [0.0; 3]).unwrap();
        let b = SlabBounds::from_slices(
            &grid,
            [1, 1],
            &[1.0, 2.0, f32::NAN, 3.0, 4.0, 5.0],
            &[0.0; 6],
        );
        // Block 0 (x 0..=1) is 0..=4; block 1 (x 1..=2) holds the NaN.
        assert_eq!(b.finite_range(), (0.0, 4.0));
        assert!(b.has_unbounded());
        assert!(b.row_may_cross(0, 100.0));
        let none = SlabBounds::empty([1, 1], [1, 1]);
        assert!(none.finite_range().0 > none.finite_range().1);
    }

    #[test]
    fn non_finite_voxels_are_never_skipped() {
        let grid = Grid::new([3, 3, 2], [1.0; 3], [0.0; 3]).unwrap();
        let mut lower = vec![0.0f32; 9];
        lower[4] = f32::NAN;
        let b = SlabBounds::from_slices(&grid, [1, 1], &lower, &[0.0; 9]);
        for (bx, by) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            assert!(b.may_cross(bx, by, 0.5), "block {bx} {by}");
        }
    }
}
