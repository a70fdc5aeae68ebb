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
    /// `block` cubes: those of its two slices ([`SlabBounds::of_slice`]) merged.
    ///
    /// # Panics
    /// If a slice does not hold `grid.slice_len()` values.
    pub fn from_slices(grid: &Grid, block: [u64; 2], lower: &[f32], upper: &[f32]) -> Self {
        Self::of_slice(grid, block, lower).merged(&Self::of_slice(grid, block, upper))
    }

    /// The bounds of one slice's voxels in each block of a slab it bounds (the block's
    /// footprint, its border row and column included): half of a slab's bounds, which a
    /// caller can compute once per slice and merge for the two slabs the slice belongs to
    /// ([`SlabBounds::merged`]).
    ///
    /// # Panics
    /// If `slice` does not hold `grid.slice_len()` values.
    pub fn of_slice(grid: &Grid, block: [u64; 2], slice: &[f32]) -> Self {
        let [nx, ny] = [grid.dims[0] as usize, grid.dims[1] as usize];
        assert_eq!(slice.len(), nx * ny, "slices must hold {} values", nx * ny);
        let block = block.map(|b| b.max(1));
        let [bx, by] = block.map(|b| b as usize);
        let count = [(nx - 1).div_ceil(bx), (ny - 1).div_ceil(by)];
        let mut bounds = Self::empty(block, count);
        // Each block row's voxel rows (its top border row included) are first reduced down the
        // columns, element by element, which vectorizes; then each block takes the bounds of
        // its columns (its right border column included). Bounds taken segment by segment along
        // each row cost about 17 instructions a voxel, 583 M of the 5.49 G of aneurism's whole
        // run at R = 0.2 by callgrind (segments of 17 values do not vectorize); this takes 5.
        let mut lo = vec![f32::INFINITY; nx];
        let mut hi = vec![f32::NEG_INFINITY; nx];
        let mut nan = vec![0.0f32; nx];
        for j in 0..count[1] {
            lo.fill(f32::INFINITY);
            hi.fill(f32::NEG_INFINITY);
            nan.fill(0.0);
            for y in j * by..=((j + 1) * by).min(ny - 1) {
                column_bounds(&slice[y * nx..(y + 1) * nx], &mut lo, &mut hi, &mut nan);
            }
            for i in 0..count[0] {
                let columns = i * bx..=((i + 1) * bx).min(nx - 1);
                let (l, h) = if nan[columns.clone()].iter().all(|n| *n == 0.0) {
                    let l = lo[columns.clone()]
                        .iter()
                        .fold(f32::INFINITY, |a, &b| a.min(b));
                    let h = hi[columns].iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
                    (l, h)
                } else {
                    (f32::NEG_INFINITY, f32::INFINITY)
                };
                bounds.include(i + count[0] * j, l, h);
            }
        }
        bounds
    }

    /// The bounds holding both `self` and `other` block by block (same blocks).
    ///
    /// # Panics
    /// If the two were made for different blocks.
    pub fn merged(&self, other: &Self) -> Self {
        assert!(
            self.block == other.block && self.count == other.count,
            "bounds of different blocks"
        );
        let mut out = self.clone();
        for i in 0..out.min.len() {
            out.include(i, other.min[i], other.max[i]);
        }
        out
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

/// Widens `lo` and `hi` element by element to hold `row`, and makes `nan` NaN in the columns
/// where `row` holds a non-finite value (`v * 0` is NaN for NaN and both infinities, and a NaN
/// stays in a sum). Compare-and-select and arithmetic only, so that the loop vectorizes (four
/// values in 16 instructions); a select per value for the non-finite ones instead cost a sixth
/// more (callgrind on aneurism: 207 M instructions in `from_slices` against 176 M).
fn column_bounds(row: &[f32], lo: &mut [f32], hi: &mut [f32], nan: &mut [f32]) {
    for (((&v, l), h), n) in row.iter().zip(lo.iter_mut()).zip(hi.iter_mut()).zip(nan) {
        *l = if v < *l { v } else { *l };
        *h = if v > *h { v } else { *h };
        *n += v * 0.0;
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
    use proptest::prelude::*;

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

    /// Every block's bounds voxel by voxel: the definition `from_slices` computes faster.
    fn reference(grid: &Grid, block: [u64; 2], slices: [&[f32]; 2]) -> SlabBounds {
        let [nx, ny] = [grid.dims[0] as usize, grid.dims[1] as usize];
        let [bx, by] = block.map(|b| b.max(1) as usize);
        let count = [(nx - 1).div_ceil(bx), (ny - 1).div_ceil(by)];
        let mut b = SlabBounds::empty(block, count);
        for j in 0..count[1] {
            for i in 0..count[0] {
                for slice in slices {
                    for y in j * by..=((j + 1) * by).min(ny - 1) {
                        for x in i * bx..=((i + 1) * bx).min(nx - 1) {
                            let v = slice[y * nx + x];
                            let (lo, hi) = match v.is_finite() {
                                true => (v, v),
                                false => (f32::NEG_INFINITY, f32::INFINITY),
                            };
                            b.include(i + count[0] * j, lo, hi);
                        }
                    }
                }
            }
        }
        b
    }

    fn voxel() -> impl Strategy<Value = f32> {
        prop_oneof![
            20 => -100.0f32..100.0,
            1 => Just(f32::NAN),
            1 => Just(f32::INFINITY),
            1 => Just(f32::NEG_INFINITY),
        ]
    }

    proptest! {
        #[test]
        fn bounds_are_those_of_the_blocks_voxels(
            (nx, ny, lower, upper) in (2usize..40, 2usize..30).prop_flat_map(|(nx, ny)| (
                Just(nx),
                Just(ny),
                proptest::collection::vec(voxel(), nx * ny),
                proptest::collection::vec(voxel(), nx * ny),
            )),
            block in [0u64..20, 0u64..20],
        ) {
            let grid = Grid::new([nx as u64, ny as u64, 2], [1.0; 3], [0.0; 3]).unwrap();
            let fast = SlabBounds::from_slices(&grid, block, &lower, &upper);
            prop_assert_eq!(&fast, &reference(&grid, block, [&lower, &upper]));
            let one = SlabBounds::of_slice(&grid, block, &upper);
            prop_assert_eq!(one, reference(&grid, block, [&upper, &upper]));
        }
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
