//! Classifying voxel values and placing vertices on crossing edges.
//!
//! Both are defined here once, so the streaming extractor and the reference agree bit for bit.

use glam::DVec3;
use isostream_volume::Grid;

/// Whether a voxel value is inside the surface: strictly above `iso` and finite.
///
/// Values equal to iso are outside, so the classification is a plain deterministic comparison
/// (a vertex may then sit exactly on a corner, and stays an edge vertex). NaN and ±inf are
/// outside too: a hole or an infinite voxel in the data never produces an inside region (the
/// readers give finite values beyond f32's range as `±f32::MAX`, not infinite).
#[inline]
pub fn is_inside(value: f32, iso: f32) -> bool {
    // `>` is false for NaN; -inf is never above iso; +inf is excluded explicitly.
    value > iso && value != f32::INFINITY
}

/// Smallest distance (in edge fractions) a vertex keeps from a grid corner.
///
/// A voxel whose value equals iso counts as outside ([`is_inside`]): symbolically the surface is
/// at iso + delta for an infinitesimal delta, so it passes strictly between the voxel and its
/// inside neighbours and never through the voxel itself. Keeping `t` off the corner realises that
/// perturbation geometrically: the vertices of the (up to six) edges meeting at such a voxel stay
/// distinct instead of coinciding, so marching cubes emits no zero-area triangles and touching
/// sheets stay apart. The shift is 1e-4 of a voxel, or more where the mesh's `f32` coordinates
/// could not keep it ([`corner_clearance`]).
pub const CORNER_CLEARANCE: f64 = 1e-4;

/// Steps of the written `f32` coordinates that the corner clearance spans at the least: two,
/// so that a vertex shifted off a corner cannot round onto the corner's own `f32` value (one
/// step could, at a tie).
const CLEARANCE_STEPS: f64 = 2.0;

/// Largest clearance (in edge fractions): the job's position check refuses grids whose `f32`
/// steps pass an eighth of a voxel, where [`CLEARANCE_STEPS`] steps are a quarter; kept below
/// one half for any grid, so `t`'s range is never empty.
const MAX_CLEARANCE: f64 = 0.25;

/// The corner clearance along each axis of `grid`, in edge fractions: [`CORNER_CLEARANCE`], or
/// [`CLEARANCE_STEPS`] steps of the `f32` coordinates at the axis's farthest position where
/// that is more.
///
/// Meshes are written in `f32`. Far from the origin a step of those coordinates is more than
/// 1e-4 of a voxel (at 1e4 with spacing 1 it is 1e-3), so vertices kept 1e-4 off a voxel at iso
/// rounded back onto one position: zero-area triangles and coincident vertices again (a plateau
/// at the iso value, origin 1e4: 240 of 716 triangles). Uniform along an axis, so every vertex
/// of a grid is placed by the same rule wherever it lies; on grids near the origin (every volume
/// in `../shared/data`) it is 1e-4 and nothing moves.
pub fn corner_clearance(grid: &Grid) -> [f64; 3] {
    std::array::from_fn(|k| {
        let end = grid.origin[k] + grid.spacing[k] * grid.dims[k].saturating_sub(1) as f64;
        let far = grid.origin[k].abs().max(end.abs()) as f32;
        let step = f64::from(far.next_up() - far);
        (CLEARANCE_STEPS * step / grid.spacing[k]).clamp(CORNER_CLEARANCE, MAX_CLEARANCE)
    })
}

/// Fraction `t` in [`clearance`, 1 - `clearance`] of the way from value `va` to `vb` where the
/// field crosses `iso`.
///
/// Computed in f64 so that `vb - va` cannot overflow. When either value is non-finite the
/// linear model means nothing, so the vertex goes to the edge midpoint (t = 0.5).
#[inline]
pub fn crossing(va: f32, vb: f32, iso: f32, clearance: f64) -> f64 {
    if !(va.is_finite() && vb.is_finite()) {
        return 0.5;
    }
    let (va, vb) = (f64::from(va), f64::from(vb));
    let t = (f64::from(iso) - va) / (vb - va);
    // NaN only for va == vb == iso, which no crossing edge has; keep it deterministic anyway.
    if t.is_nan() {
        0.5
    } else {
        t.clamp(clearance, 1.0 - clearance)
    }
}

/// Where marching cubes places its vertices on one grid at one iso value: the grid, the iso
/// value and the grid's [`corner_clearance`], computed once. The streaming extractor, the
/// reference and the attributes' sampling all place through it, so they agree bit for bit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgePlacement {
    grid: Grid,
    iso: f32,
    clearance: [f64; 3],
}

impl EdgePlacement {
    pub fn new(grid: Grid, iso: f32) -> Self {
        EdgePlacement {
            grid,
            iso,
            clearance: corner_clearance(&grid),
        }
    }

    pub fn grid(&self) -> Grid {
        self.grid
    }

    pub fn iso(&self) -> f32 {
        self.iso
    }

    /// [`crossing`] on an edge along `axis` whose end values are `va` and `vb`.
    #[inline]
    pub fn crossing(&self, axis: u8, va: f32, vb: f32) -> f64 {
        crossing(va, vb, self.iso, self.clearance[usize::from(axis)])
    }

    /// Position of the vertex on the grid edge from `voxel` along `axis` whose end values are
    /// `va` (at `voxel`) and `vb`.
    #[inline]
    pub fn position(&self, voxel: [u64; 3], axis: u8, va: f32, vb: f32) -> DVec3 {
        let t = self.crossing(axis, va, vb);
        let [x, y, z] = voxel.map(|v| v as f64);
        // A match rather than `c[axis] += t`: indexing a stack array with a runtime axis made
        // the hot loop stall on store forwarding.
        match axis {
            0 => self.grid.position(x + t, y, z),
            1 => self.grid.position(x, y + t, z),
            _ => self.grid.position(x, y, z + t),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inside_is_strictly_above_iso_and_finite() {
        assert!(is_inside(1.5, 1.0));
        assert!(!is_inside(1.0, 1.0));
        assert!(!is_inside(0.5, 1.0));
        assert!(!is_inside(f32::NAN, 1.0));
        assert!(!is_inside(f32::INFINITY, 1.0));
        assert!(!is_inside(f32::NEG_INFINITY, 1.0));
        assert!(is_inside(f32::MAX, 1.0));
    }

    #[test]
    fn crossing_interpolates_linearly_and_clamps() {
        let c = CORNER_CLEARANCE;
        assert_eq!(crossing(0.0, 2.0, 0.5, c), 0.25);
        assert_eq!(crossing(2.0, 0.0, 0.5, c), 0.75);
        // A voxel exactly at iso is outside: the vertex stays just off it, towards the inside.
        assert_eq!(crossing(2.0, 1.0, 1.0, c), 1.0 - CORNER_CLEARANCE);
        assert_eq!(crossing(1.0, 2.0, 1.0, c), CORNER_CLEARANCE);
        assert_eq!(crossing(f32::NAN, 2.0, 1.0, c), 0.5);
        assert_eq!(crossing(0.0, f32::INFINITY, 1.0, c), 0.5);
        assert_eq!(crossing(1.0, 1.0, 1.0, c), 0.5);
        assert_eq!(crossing(1.0, 1.0, 5.0, c), 1.0 - CORNER_CLEARANCE);
        // No overflow at the ends of the f32 range.
        assert_eq!(crossing(-f32::MAX, f32::MAX, 0.0, c), 0.5);
    }

    #[test]
    fn positions_use_spacing_and_origin() {
        let grid = Grid::new([4, 4, 4], [1.0, 2.0, 0.5], [10.0, 20.0, 30.0]).unwrap();
        let p = EdgePlacement::new(grid, 1.0).position([1, 2, 3], 1, 0.0, 4.0);
        assert_eq!(p, DVec3::new(11.0, 20.0 + 2.0 * 2.25, 31.5));
    }

    #[test]
    fn the_clearance_is_the_constant_near_the_origin_and_spans_two_f32_steps_far_from_it() {
        let near = Grid::new([512, 512, 512], [1.0; 3], [-255.0, 0.0, 0.0]).unwrap();
        assert_eq!(corner_clearance(&near), [CORNER_CLEARANCE; 3]);
        // x at 1e4 (f32 steps of 2^-10), y at 1e4 with spacing 0.1, z near 0.
        let far = Grid::new([10, 10, 10], [1.0, 0.1, 1.0], [1e4, 1e4, 0.0]).unwrap();
        let step = 2f64.powi(-10);
        let c = corner_clearance(&far);
        assert_eq!(c[0], 2.0 * step);
        assert!((c[1] - 2.0 * step / 0.1).abs() < 1e-12, "{c:?}");
        assert_eq!(c[2], CORNER_CLEARANCE);
        // A grid the job check would refuse still gets a range of t that is not empty.
        let refused = Grid::new([10, 10, 10], [1e-6, 1.0, 1.0], [1e9, 0.0, 0.0]).unwrap();
        assert_eq!(corner_clearance(&refused)[0], MAX_CLEARANCE);
    }

    /// Voxels exactly at iso beside inside voxels, far from the origin: no triangle has zero
    /// area once written in `f32`. With the fixed 1e-4 clearance, 240 of 716 triangles had no
    /// area on a user's plateaus at an origin of 1e4.
    #[test]
    fn far_from_the_origin_voxels_at_iso_give_no_zero_area_triangle_in_f32() {
        use crate::extract_indexed;
        use isostream_volume::MemoryVolume;
        for origin in [0.0, 1e4, 3e4, 5e4] {
            let dims = [9u64, 8, 7];
            // 0, 5 (the iso value) and 9 scattered by a fixed hash.
            let values: Vec<f32> = (0..dims.iter().product::<u64>())
                .map(|i| [0.0, 5.0, 9.0][(i.wrapping_mul(2_654_435_761) >> 7) as usize % 3])
                .collect();
            let grid = Grid::new(dims, [1.0; 3], [origin; 3]).unwrap();
            let mut volume = MemoryVolume::new(grid, values).unwrap();
            let surface = extract_indexed(&mut volume, 5.0).unwrap();
            assert!(!surface.triangles.is_empty());
            let written: Vec<DVec3> = surface
                .positions
                .iter()
                .map(|p| p.as_vec3().as_dvec3())
                .collect();
            for t in &surface.triangles {
                let [a, b, c] = t.map(|v| written[v as usize]);
                assert!(
                    (b - a).cross(c - a).length() > 0.0,
                    "origin {origin}: {t:?}"
                );
            }
        }
    }
}
