//! Numbering of the corners, edges and faces of one marching-cubes cell.
//!
//! Everything else in the crate (table generation, slab traversal, the reference extractor)
//! derives its geometry from these few functions, so there is exactly one numbering to get right:
//!
//! - **Corner** `c` in `0..8` sits at offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)` from the cube's
//!   minimum voxel. Bit `c` of a case index is set when corner `c` is inside.
//! - **Edge** `e` in `0..12` runs along axis `e / 4` (0 = x, 1 = y, 2 = z) from its minimum corner
//!   to the next corner along that axis. Bits 0 and 1 of `e % 4` are the minimum corner's
//!   coordinates on the two other axes, in increasing axis order: edges 0..4 are the x edges at
//!   (y, z) = (0,0), (1,0), (0,1), (1,1); edges 4..8 the y edges at (x, z) likewise; edges 8..12
//!   the z edges at (x, y). An edge is thus identified by (minimum corner offset, axis), exactly
//!   like the grid edge it stands for ([`crate::EdgeKey`]).
//! - **Face** `f` in `0..6` is the face where coordinate `f / 2` equals `f % 2`.

/// Offset of corner `c` from the cube's minimum voxel.
pub fn corner_offset(c: u8) -> [u8; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The corner at offset `o` (each coordinate 0 or 1).
fn corner_at(o: [u8; 3]) -> u8 {
    o[0] | (o[1] << 1) | (o[2] << 2)
}

/// The two axes other than `axis`, in increasing order.
fn other_axes(axis: u8) -> [u8; 2] {
    match axis {
        0 => [1, 2],
        1 => [0, 2],
        _ => [0, 1],
    }
}

/// Axis (0 = x, 1 = y, 2 = z) of edge `e`.
pub fn edge_axis(e: u8) -> u8 {
    e / 4
}

/// The corners at the two ends of edge `e`: (minimum corner, corner one step along the axis).
pub fn edge_corners(e: u8) -> (u8, u8) {
    let axis = edge_axis(e);
    let [u, v] = other_axes(axis);
    let low = ((e & 1) << u) | (((e >> 1) & 1) << v);
    (low, low | (1 << axis))
}

/// The edge joining corners `a` and `b`, which must differ in exactly one coordinate.
pub fn edge_between(a: u8, b: u8) -> u8 {
    let diff = a ^ b;
    assert!(diff.count_ones() == 1, "corners are not adjacent");
    let axis = diff.trailing_zeros() as u8;
    let low = a & b;
    let [u, v] = other_axes(axis);
    4 * axis + ((low >> u) & 1) + 2 * ((low >> v) & 1)
}

/// The two faces containing edge `e`, as `2 * axis + side`.
pub fn edge_faces(e: u8) -> [u8; 2] {
    let (low, _) = edge_corners(e);
    let [u, v] = other_axes(edge_axis(e));
    [2 * u + ((low >> u) & 1), 2 * v + ((low >> v) & 1)]
}

/// Whether edges `a` and `b` lie on a common face of the cube.
pub fn edges_share_face(a: u8, b: u8) -> bool {
    let (fa, fb) = (edge_faces(a), edge_faces(b));
    fa[0] == fb[0] || fa[0] == fb[1] || fa[1] == fb[0] || fa[1] == fb[1]
}

/// The four corners of face `f` in counter-clockwise order seen from outside the cube
/// (looking against the face's outward normal).
///
/// With (u, v) the two other axes in cyclic order after the face axis a, the walk
/// (0,0) -> (1,0) -> (1,1) -> (0,1) in (u, v) is counter-clockwise seen from +a, because
/// u x v = a. The face at side 1 has outward normal +a and uses that walk; the face at side 0 has
/// outward normal -a and walks it backwards.
pub fn face_cycle(f: u8) -> [u8; 4] {
    let (a, side) = ((f / 2) as usize, f % 2);
    let (u, v) = ((a + 1) % 3, (a + 2) % 3);
    let at = |du: u8, dv: u8| {
        let mut o = [0u8; 3];
        o[a] = side;
        o[u] = du;
        o[v] = dv;
        corner_at(o)
    };
    let ccw_from_plus = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)];
    if side == 1 {
        ccw_from_plus
    } else {
        let [c0, c1, c2, c3] = ccw_from_plus;
        [c0, c3, c2, c1]
    }
}

/// Midpoint of edge `e` in cube coordinates (each coordinate 0, 0.5 or 1): the vertex
/// position used to judge triangulation quality independently of the data.
pub fn edge_midpoint(e: u8) -> [f64; 3] {
    let (low, _) = edge_corners(e);
    let mut p = corner_offset(low).map(f64::from);
    p[edge_axis(e) as usize] = 0.5;
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_join_adjacent_corners_along_their_axis() {
        for e in 0..12u8 {
            let (a, b) = edge_corners(e);
            let (oa, ob) = (corner_offset(a), corner_offset(b));
            let axis = edge_axis(e) as usize;
            assert_eq!(oa[axis], 0);
            assert_eq!(ob[axis], 1);
            for k in 0..3 {
                if k != axis {
                    assert_eq!(oa[k], ob[k]);
                }
            }
            assert_eq!(edge_between(a, b), e);
            assert_eq!(edge_between(b, a), e);
        }
    }

    #[test]
    fn every_corner_pair_along_an_axis_is_one_edge() {
        let mut seen = [false; 12];
        for a in 0..8u8 {
            for axis in 0..3 {
                let b = a | (1 << axis);
                if b != a {
                    seen[edge_between(a, b) as usize] = true;
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
    }

    #[test]
    fn face_cycles_are_counter_clockwise_from_outside() {
        for f in 0..6u8 {
            let cycle = face_cycle(f);
            let (axis, side) = ((f / 2) as usize, f % 2);
            let p = cycle.map(|c| corner_offset(c).map(f64::from));
            let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
            let (d1, d2) = (sub(p[1], p[0]), sub(p[2], p[1]));
            let cross = [
                d1[1] * d2[2] - d1[2] * d2[1],
                d1[2] * d2[0] - d1[0] * d2[2],
                d1[0] * d2[1] - d1[1] * d2[0],
            ];
            let outward = if side == 1 { 1.0 } else { -1.0 };
            assert_eq!(cross[axis], outward, "face {f}");
            for c in cycle {
                assert_eq!(corner_offset(c)[axis], side);
            }
            // Consecutive corners are joined by an edge of the face.
            for i in 0..4 {
                let e = edge_between(cycle[i], cycle[(i + 1) % 4]);
                assert!(edge_faces(e).contains(&f));
            }
        }
    }

    #[test]
    fn each_edge_lies_on_two_faces_and_each_face_has_four_edges() {
        let mut per_face = [0; 6];
        for e in 0..12u8 {
            let [f0, f1] = edge_faces(e);
            assert_ne!(f0, f1);
            per_face[f0 as usize] += 1;
            per_face[f1 as usize] += 1;
            assert!(edges_share_face(e, e));
        }
        assert_eq!(per_face, [4; 6]);
        // Opposite edges (e.g. x edges at (0,0) and (1,1)) share no face.
        assert!(!edges_share_face(0, 3));
        assert!(edges_share_face(0, 1));
    }
}
