//! Classifying voxel values and placing vertices on crossing edges.
//!
//! Both are defined here once, so the streaming extractor and the reference agree bit for bit.

use glam::DVec3;
use isostream_volume::Grid;

/// Whether a voxel value is inside the surface: strictly above `iso` and finite.
///
/// Values equal to iso are outside, so the classification is a plain deterministic comparison
/// (a vertex may then sit exactly on a corner, and stays an edge vertex). NaN and ±inf are
/// outside too: a hole or a saturated voxel in the data never produces an inside region.
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
/// sheets stay apart. The shift is at most 1e-4 of a voxel.
pub const CORNER_CLEARANCE: f64 = 1e-4;

/// Fraction `t` in [CORNER_CLEARANCE, 1 - CORNER_CLEARANCE] of the way from value `va` to `vb`
/// where the field crosses `iso`.
///
/// Computed in f64 so that `vb - va` cannot overflow. When either value is non-finite the
/// linear model means nothing, so the vertex goes to the edge midpoint (t = 0.5).
#[inline]
pub fn crossing(va: f32, vb: f32, iso: f32) -> f64 {
    if !(va.is_finite() && vb.is_finite()) {
        return 0.5;
    }
    let (va, vb) = (f64::from(va), f64::from(vb));
    let t = (f64::from(iso) - va) / (vb - va);
    // NaN only for va == vb == iso, which no crossing edge has; keep it deterministic anyway.
    if t.is_nan() {
        0.5
    } else {
        t.clamp(CORNER_CLEARANCE, 1.0 - CORNER_CLEARANCE)
    }
}

/// Position of the vertex on the grid edge from `voxel` along `axis` whose end values are
/// `va` (at `voxel`) and `vb`.
#[inline]
pub fn edge_position(grid: &Grid, voxel: [u64; 3], axis: u8, va: f32, vb: f32, iso: f32) -> DVec3 {
    let t = crossing(va, vb, iso);
    let [x, y, z] = voxel.map(|v| v as f64);
    // A match rather than `c[axis] += t`: indexing a stack array with a runtime axis made the
    // hot loop stall on store forwarding.
    match axis {
        0 => grid.position(x + t, y, z),
        1 => grid.position(x, y + t, z),
        _ => grid.position(x, y, z + t),
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
        assert_eq!(crossing(0.0, 2.0, 0.5), 0.25);
        assert_eq!(crossing(2.0, 0.0, 0.5), 0.75);
        // A voxel exactly at iso is outside: the vertex stays just off it, towards the inside.
        assert_eq!(crossing(2.0, 1.0, 1.0), 1.0 - CORNER_CLEARANCE);
        assert_eq!(crossing(1.0, 2.0, 1.0), CORNER_CLEARANCE);
        assert_eq!(crossing(f32::NAN, 2.0, 1.0), 0.5);
        assert_eq!(crossing(0.0, f32::INFINITY, 1.0), 0.5);
        assert_eq!(crossing(1.0, 1.0, 1.0), 0.5);
        assert_eq!(crossing(1.0, 1.0, 5.0), 1.0 - CORNER_CLEARANCE);
        // No overflow at the ends of the f32 range.
        assert_eq!(crossing(-f32::MAX, f32::MAX, 0.0), 0.5);
    }

    #[test]
    fn positions_use_spacing_and_origin() {
        let grid = Grid::new([4, 4, 4], [1.0, 2.0, 0.5], [10.0, 20.0, 30.0]).unwrap();
        let p = edge_position(&grid, [1, 2, 3], 1, 0.0, 4.0, 1.0);
        assert_eq!(p, DVec3::new(11.0, 20.0 + 2.0 * 2.25, 31.5));
    }
}
