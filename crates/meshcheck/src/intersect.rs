//! Self-intersection counts: triangles that cross another triangle of the same mesh, or meet it.
//!
//! Broad phase: a uniform grid with cells of twice the mean edge length; every triangle is filed
//! in each cell its bounding box overlaps, and each pair met in a shared cell is tested once
//! (bounding boxes first). Narrow phase, in exact orientation signs (Shewchuk's adaptive
//! predicates, the `robust` crate; ties count as "no crossing"). Plain `f64` determinants were
//! not enough: two triangles touching at coincident vertices with distinct indices (pinches,
//! common in iso-surfaces through iso-valued voxels) put a corner exactly on the other's plane,
//! and the rounding noise of `(v x w) . w` made the referee report crossings that exact
//! arithmetic rules out (a cascade property test failed on such a pair in CI):
//! * **disjoint triangles** (no common vertex index): they intersect iff an edge of one strictly
//!   crosses the other (both endpoints strictly on opposite sides of its plane, the line strictly
//!   inside the three edge planes). Coplanar overlaps and contacts along an edge or at a point
//!   (touching) are not counted.
//! * **one common vertex** `x`: they meet at `x` anyway; they *cross* iff the edge opposite `x` in
//!   one strictly crosses the other triangle.
//! * **two or three common vertices** (neighbours across an edge, duplicates): not crossing;
//!   duplicates are the topology report's business.
//!
//! [`self_intersections`], the count every guarantee is checked with, is stricter: it counts
//! triangles that *meet* another beyond their shared corners ([`triangles_meet`]), touching
//! included (a corner on another triangle, edges meeting, coplanar overlap, coincident corners
//! with distinct indices), by the rules above with closed segments and triangles, and
//! neighbours across an edge folded onto each other ([`folded`]: in one plane, their third
//! corners on one side of the edge), which no topology check sees. A simplifier that only
//! avoided crossings welded separate surfaces at a point on blocky volumes (a checkerboard of
//! 2-voxel blocks: two components' vertices at one position), which an STL writer turns into a
//! non-manifold vertex. [`crossing_triangles`] keeps the strict count, the one the peers'
//! crossings were compared by.

/// The sign of `(b - a) . ((c - a) x (d - a))`, exactly: positive when `d` lies above the plane
/// `abc` (CCW seen from above), zero when the four points are coplanar.
///
/// The determinant in `f64` first, certified by [`certify`]; only the near-coplanar rest goes to
/// the exact predicate.
#[inline]
pub fn orient(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]) -> f64 {
    let u = sub(b, a);
    let v = sub(c, a);
    let w = sub(d, a);
    let det = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
        + u[2] * (v[0] * w[1] - v[1] * w[0]);
    let norm = |x: [f64; 3]| x[0].abs() + x[1].abs() + x[2].abs();
    certify(det, norm(u) * norm(v) * norm(w), [a, b, c, d])
}

/// `det`, an `f64` evaluation of `orient(a, b, c, d)` as a triple product of the three
/// differences from one of the points (in any order), when its sign is certain; else the exact
/// value's sign. `norms` is the product of those differences' 1-norms: it bounds the
/// determinant's permanent, so `ORIENT_ERROR * norms` bounds the rounding error (Shewchuk's
/// `orient3d` error analysis). The exact fallback is Shewchuk's adaptive predicate from the
/// `robust` crate (exact arithmetic written by hand would duplicate a well-kept crate); the
/// filter keeps hot callers (the simplifier's guard) off it: calling it for every sign cost
/// 13 % more instructions on a whole run.
#[inline]
pub fn certify(det: f64, norms: f64, [a, b, c, d]: [[f64; 3]; 4]) -> f64 {
    let bound = ORIENT_ERROR * norms;
    if det > bound || -det > bound {
        det
    } else {
        exact_orient([a, b, c, d])
    }
}

/// [`orient`] in exact arithmetic, kept off the inlined path: [`orient_fixed`] where its
/// integers hold the points, else Shewchuk's adaptive predicate.
#[cold]
#[inline(never)]
fn exact_orient(points: [[f64; 3]; 4]) -> f64 {
    orient_fixed(points).unwrap_or_else(|| orient_adaptive(points))
}

/// [`orient`] by Shewchuk's adaptive predicate (the `robust` crate), for any finite points.
fn orient_adaptive(points: [[f64; 3]; 4]) -> f64 {
    let [a, b, c, d] = points.map(|x| robust::Coord3D {
        x: x[0],
        y: x[1],
        z: x[2],
    });
    // Shewchuk's sign convention is the opposite one.
    -robust::orient3d(a, b, c, d)
}

/// Bits of the integers [`orient_fixed`] turns coordinates into: differences then take 41 bits,
/// the 2x2 minors 83, their products with a difference 124, and the determinant (three of those)
/// stays below 2^126, within `i128`.
const FIXED_BITS: i32 = 40;

/// The sign of [`orient`] in `i128` arithmetic, exactly, when the twelve coordinates' set bits
/// span at most [`FIXED_BITS`] (then each is an integer times one power of two); `None` when they
/// do not (coordinates of very different magnitudes, non-finite or subnormal values), for the
/// general predicate. The positions this project writes are `f32` (24 bits) and the points of
/// one test lie close together, so nearly every call fits. Near-coplanar points are not rare on
/// smooth surfaces: on hydrogen upsampled 32x, Shewchuk's adaptive stages (the `robust` crate,
/// expansions in `f64`) took a fifth of a run's CPU samples, more than the guard's own code;
/// this is integer shifts and a dozen multiplications.
fn orient_fixed(points: [[f64; 3]; 4]) -> Option<f64> {
    // Each coordinate as `mantissa * 2^exp` with an odd (or zero) mantissa.
    let mut parts = [(0i64, 0i32); 12];
    let (mut low, mut high) = (i32::MAX, i32::MIN);
    for (part, &x) in parts.iter_mut().zip(points.as_flattened()) {
        if x == 0.0 {
            continue;
        }
        let bits = x.to_bits();
        let biased = ((bits >> 52) & 0x7ff) as i32;
        if biased == 0 || biased == 0x7ff {
            return None;
        }
        let mantissa = (bits & ((1 << 52) - 1)) | (1 << 52);
        let zeros = mantissa.trailing_zeros();
        let exp = biased - 1075 + zeros as i32;
        // x = ±(mantissa >> zeros) * 2^exp, below 2^(biased - 1022).
        let odd = (mantissa >> zeros) as i64;
        *part = (if x < 0.0 { -odd } else { odd }, exp);
        low = low.min(exp);
        high = high.max(biased - 1022);
    }
    if low == i32::MAX {
        return Some(0.0);
    }
    if high - low > FIXED_BITS {
        return None;
    }
    // Every coordinate an integer multiple of 2^low, below 2^FIXED_BITS in magnitude.
    let p = parts.map(|(m, exp)| if m == 0 { 0 } else { m << (exp - low) });
    let diff = |q: usize, k: usize| i128::from(p[3 * q + k] - p[k]);
    let (u, v, w) = (
        [diff(1, 0), diff(1, 1), diff(1, 2)],
        [diff(2, 0), diff(2, 1), diff(2, 2)],
        [diff(3, 0), diff(3, 1), diff(3, 2)],
    );
    let det = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
        + u[2] * (v[0] * w[1] - v[1] * w[0]);
    Some(det.signum() as f64)
}

/// Relative rounding error bound of an `f64` triple product of differences (see [`certify`]):
/// Shewchuk's is `(7 + 56 u) u` (unit roundoff `u = 2^-53`) for his expansion; twice that leaves
/// room for other evaluation orders and the rounding of the norms.
pub const ORIENT_ERROR: f64 = 8.0 * f64::EPSILON;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Segment `pq` strictly crosses triangle `t` (interior to interior).
pub fn segment_crosses_triangle(p: [f64; 3], q: [f64; 3], t: [[f64; 3]; 3]) -> bool {
    let [a, b, c] = t;
    let o1 = orient(a, b, c, p);
    let o2 = orient(a, b, c, q);
    if !((o1 > 0.0 && o2 < 0.0) || (o1 < 0.0 && o2 > 0.0)) {
        return false;
    }
    let s1 = orient(p, q, a, b);
    let s2 = orient(p, q, b, c);
    let s3 = orient(p, q, c, a);
    (s1 > 0.0 && s2 > 0.0 && s3 > 0.0) || (s1 < 0.0 && s2 < 0.0 && s3 < 0.0)
}

/// Whether the closed segment `pq` and the closed triangle `t` have a point in common:
/// crossing, or touching at an edge, a corner or along a segment in the triangle's plane. `false`
/// for a degenerate (zero-area) triangle, which the topology report counts on its own.
pub fn segment_meets_triangle(p: [f64; 3], q: [f64; 3], t: [[f64; 3]; 3]) -> bool {
    let [a, b, c] = t;
    let (o1, o2) = (sgn(orient(a, b, c, p)), sgn(orient(a, b, c, q)));
    if o1 * o2 > 0.0 {
        return false;
    }
    if o1 == 0.0 && o2 == 0.0 {
        return coplanar_segment_meets_triangle(p, q, t);
    }
    // The line meets the plane at one point of the segment; it lies in the closed triangle iff
    // the three edge planes through the line see it on one side or on them.
    let s = [orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)].map(sgn);
    !(s.contains(&1.0) && s.contains(&-1.0))
}

/// [`segment_meets_triangle`] for a segment in the triangle's plane (the caller knows both
/// ends are on it), exactly, in the projection onto the coordinate plane where the triangle
/// keeps an area. Boxes first: flat parts of a surface put many such pairs side by side.
pub fn coplanar_segment_meets_triangle(p: [f64; 3], q: [f64; 3], t: [[f64; 3]; 3]) -> bool {
    let apart = (0..3).any(|k| {
        let (lo, hi) = (p[k].min(q[k]), p[k].max(q[k]));
        let tlo = t[0][k].min(t[1][k]).min(t[2][k]);
        let thi = t[0][k].max(t[1][k]).max(t[2][k]);
        hi < tlo || lo > thi
    });
    if apart {
        return false;
    }
    let Some(axes) = [[0, 1], [1, 2], [2, 0]].into_iter().find(|&[i, j]| {
        orient2d([t[0][i], t[0][j]], [t[1][i], t[1][j]], [t[2][i], t[2][j]]) != 0.0
    }) else {
        return false;
    };
    let flat = |x: [f64; 3]| [x[axes[0]], x[axes[1]]];
    let (p, q, t) = (flat(p), flat(q), t.map(flat));
    let inside = |x: [f64; 2]| {
        let s = [
            orient2d(t[0], t[1], x),
            orient2d(t[1], t[2], x),
            orient2d(t[2], t[0], x),
        ]
        .map(sgn);
        !(s.contains(&1.0) && s.contains(&-1.0))
    };
    inside(p) || inside(q) || (0..3).any(|i| segments_meet_2d(p, q, t[i], t[(i + 1) % 3]))
}

/// Whether the closed segments `pq` and `rs` of a plane have a point in common.
fn segments_meet_2d(p: [f64; 2], q: [f64; 2], r: [f64; 2], s: [f64; 2]) -> bool {
    let (o1, o2) = (sgn(orient2d(p, q, r)), sgn(orient2d(p, q, s)));
    let (o3, o4) = (sgn(orient2d(r, s, p)), sgn(orient2d(r, s, q)));
    let span = |a: [f64; 2], b: [f64; 2], k: usize| (a[k].min(b[k]), a[k].max(b[k]));
    // Boxes along both axes: for points on one line this is the overlap of the segments (a
    // zero-length segment, whose orientations are all 0, included).
    let boxes_meet = (0..2).all(|k| {
        let ((lo1, hi1), (lo2, hi2)) = (span(p, q, k), span(r, s, k));
        lo1 <= hi2 && lo2 <= hi1
    });
    if o1 == 0.0 && o2 == 0.0 && o3 == 0.0 && o4 == 0.0 {
        return boxes_meet;
    }
    if p == q {
        return o3 == 0.0 && boxes_meet;
    }
    if r == s {
        return o1 == 0.0 && boxes_meet;
    }
    o1 * o2 <= 0.0 && o3 * o4 <= 0.0
}

/// The sign of the 2-D orientation of `c` from the line `ab`, exactly (Shewchuk's adaptive
/// predicate; only its sign is used).
fn orient2d(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    let p = |x: [f64; 2]| robust::Coord { x: x[0], y: x[1] };
    robust::orient2d(p(a), p(b), p(c))
}

fn sgn(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// What two triangles share, by index, with the places in each.
enum Shared {
    Nothing,
    /// One corner: its place in the first and in the second.
    Corner(usize, usize),
    /// An edge: the places of its two corners in the first, and of each triangle's third
    /// corner (the topology report's neighbours, [`folded`] in [`triangles_meet`]).
    Edge {
        ends: [usize; 2],
        off: [usize; 2],
    },
    /// Duplicates and repeated indices: the topology report's business.
    More,
}

fn shared(ia: [u32; 3], ib: [u32; 3]) -> Shared {
    let mut pairs = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .filter(|&(i, j)| ia[i] == ib[j]);
    match (pairs.next(), pairs.next(), pairs.next()) {
        (None, _, _) => Shared::Nothing,
        (Some((i, j)), None, _) => Shared::Corner(i, j),
        (Some((i, j)), Some((k, l)), None) if i != k && j != l => Shared::Edge {
            ends: [i, k],
            off: [3 - i - k, 3 - j - l],
        },
        _ => Shared::More,
    }
}

/// Whether two triangles given by corner indices `ia`, `ib` and positions `a`, `b` cross (see the
/// module documentation for shared vertices).
pub fn triangles_intersect(ia: [u32; 3], a: [[f64; 3]; 3], ib: [u32; 3], b: [[f64; 3]; 3]) -> bool {
    pair_test(shared(ia, ib), a, b, segment_crosses_triangle)
}

/// Whether two triangles meet beyond the corners they share: they cross, or touch (a corner
/// on the other, edges meeting, coplanar overlap, coincident corners with distinct indices). A
/// surface meant to be embedded has no such pair: an STL welds touching corners into
/// non-manifold vertices, and booleans or 3-D printing see the contact.
///
/// With no common corner, the closed triangles meet iff an edge of one meets the other. With
/// one common corner `x`, they meet elsewhere iff the edge opposite `x` in one meets the other:
/// their intersection is convex and holds `x`, so any other point of it puts one of its
/// extreme points on an opposite edge (both coplanar and not).
///
/// Neighbours across an edge meet beyond it when they are folded onto each other
/// ([`folded`]): in one plane, their third corners on one side of the edge.
pub fn triangles_meet(ia: [u32; 3], a: [[f64; 3]; 3], ib: [u32; 3], b: [[f64; 3]; 3]) -> bool {
    match shared(ia, ib) {
        Shared::Edge { ends: [i, k], off } => folded(a[i], a[k], a[off[0]], b[off[1]]),
        other => pair_test(other, a, b, segment_meets_triangle),
    }
}

/// Whether triangles `(u, v, p)` and `(u, v, w)`, neighbours across the edge `uv`, are folded
/// onto each other: in one plane, `p` and `w` strictly on one side of the edge, so that one
/// covers part of the other. (Facing opposite ways with a dihedral angle of 0: the flip test,
/// which compares a triangle with its own former self, did not see a triangle folded onto a
/// neighbour that did not move, and the referee skipped pairs sharing an edge: a helper's
/// trial found 3,606 such folds on blocky volumes, most on the box's cut.) `false` when either
/// is degenerate (counted on its own).
pub fn folded(u: [f64; 3], v: [f64; 3], p: [f64; 3], w: [f64; 3]) -> bool {
    if orient(u, v, p, w) != 0.0 {
        return false;
    }
    let Some([x, y]) = [[0, 1], [1, 2], [2, 0]]
        .into_iter()
        .find(|&[x, y]| orient2d([u[x], u[y]], [v[x], v[y]], [p[x], p[y]]) != 0.0)
    else {
        return false;
    };
    let side = |q: [f64; 3]| sgn(orient2d([u[x], u[y]], [v[x], v[y]], [q[x], q[y]]));
    let sw = side(w);
    sw != 0.0 && sw == side(p)
}

/// A segment against a triangle: [`segment_crosses_triangle`] or [`segment_meets_triangle`].
type SegmentTest = fn([f64; 3], [f64; 3], [[f64; 3]; 3]) -> bool;

/// A pair of triangles by corner indices and positions: [`triangles_intersect`] or
/// [`triangles_meet`].
type PairTest = fn([u32; 3], [[f64; 3]; 3], [u32; 3], [[f64; 3]; 3]) -> bool;

/// The pair rule shared by [`triangles_intersect`] and [`triangles_meet`] (see the module
/// documentation), with `edge` the segment test.
fn pair_test(shared: Shared, a: [[f64; 3]; 3], b: [[f64; 3]; 3], edge: SegmentTest) -> bool {
    match shared {
        Shared::Nothing => {
            (0..3).any(|i| edge(a[i], a[(i + 1) % 3], b) || edge(b[i], b[(i + 1) % 3], a))
        }
        Shared::Corner(i, j) => {
            edge(a[(i + 1) % 3], a[(i + 2) % 3], b) || edge(b[(j + 1) % 3], b[(j + 2) % 3], a)
        }
        Shared::Edge { .. } | Shared::More => false,
    }
}

/// Number of triangles that cross at least one other triangle (see the module documentation:
/// triangles sharing one vertex count when the opposite edge of one crosses the other; triangles
/// sharing an edge are not compared). Triangles with an out-of-range index are ignored.
pub fn crossing_triangles(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> usize {
    count_pairs(positions, triangles, triangles_intersect)
}

/// Number of triangles that meet at least one other beyond their shared corners, crossing or
/// touching ([`triangles_meet`]): the referee's count of a surface that is not embedded.
/// Triangles with an out-of-range index are ignored.
pub fn self_intersections(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> usize {
    count_pairs(positions, triangles, triangles_meet)
}

/// Triangles of which `bad` holds for at least one pair, the pairs found by a uniform grid.
fn count_pairs(positions: &[[f64; 3]], triangles: &[[u32; 3]], bad_pair: PairTest) -> usize {
    let corners = |t: &[u32; 3]| -> Option<[[f64; 3]; 3]> {
        let p = |i: u32| positions.get(i as usize).copied();
        Some([p(t[0])?, p(t[1])?, p(t[2])?])
    };
    let tris: Vec<Option<[[f64; 3]; 3]>> = triangles.iter().map(corners).collect();
    let (mut sum, mut n) = (0.0, 0usize);
    for p in tris.iter().flatten() {
        for i in 0..3 {
            let d = sub(p[(i + 1) % 3], p[i]);
            sum += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            n += 1;
        }
    }
    let mut cell = if n > 0 { 2.0 * sum / n as f64 } else { 1.0 };
    if !(cell.is_finite() && cell > 0.0) {
        cell = 1.0;
    }
    let bbox = |p: &[[f64; 3]; 3]| {
        let mut lo = p[0];
        let mut hi = p[0];
        for q in &p[1..] {
            for k in 0..3 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
        (lo, hi)
    };
    let key = |x: f64| (x / cell).floor() as i64;
    let mut grid: std::collections::HashMap<[i64; 3], Vec<u32>> = std::collections::HashMap::new();
    let mut boxes = Vec::with_capacity(tris.len());
    for (t, p) in tris.iter().enumerate() {
        let Some(p) = p else {
            boxes.push(None);
            continue;
        };
        let (lo, hi) = bbox(p);
        boxes.push(Some((lo, hi)));
        for x in key(lo[0])..=key(hi[0]) {
            for y in key(lo[1])..=key(hi[1]) {
                for z in key(lo[2])..=key(hi[2]) {
                    grid.entry([x, y, z]).or_default().push(t as u32);
                }
            }
        }
    }
    let mut bad = vec![false; tris.len()];
    let mut seen = vec![u32::MAX; tris.len()];
    for (t, p) in tris.iter().enumerate() {
        let (Some(p), Some((lo, hi))) = (p, boxes[t]) else {
            continue;
        };
        for x in key(lo[0])..=key(hi[0]) {
            for y in key(lo[1])..=key(hi[1]) {
                for z in key(lo[2])..=key(hi[2]) {
                    for &s in grid.get(&[x, y, z]).map_or(&[][..], Vec::as_slice) {
                        let s = s as usize;
                        if s <= t || seen[s] == t as u32 {
                            continue;
                        }
                        seen[s] = t as u32;
                        let (Some(q), Some((slo, shi))) = (tris[s], boxes[s]) else {
                            continue;
                        };
                        if (0..3).any(|k| slo[k] > hi[k] || shi[k] < lo[k]) {
                            continue;
                        }
                        if bad_pair(triangles[t], *p, triangles[s], q) {
                            bad[t] = true;
                            bad[s] = true;
                        }
                    }
                }
            }
        }
    }
    bad.iter().filter(|&&b| b).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Shewchuk's sign, in this module's convention.
    fn shewchuk(points: [[f64; 3]; 4]) -> f64 {
        sgn(orient_adaptive(points))
    }

    fn sgn(x: f64) -> f64 {
        f64::from(i8::from(x > 0.0) - i8::from(x < 0.0))
    }

    /// `f32` coordinates near `origin` at the scale `2^exp`: what the simplifier's points are.
    fn near(origin: [f32; 3], offsets: [[f32; 3]; 4], exp: i32) -> [[f64; 3]; 4] {
        let unit = 2f32.powi(exp);
        offsets.map(|o| std::array::from_fn(|k| f64::from(origin[k] + o[k] * unit)))
    }

    proptest! {
        /// Wherever the integer path answers, it gives Shewchuk's sign: for points in general
        /// position, on a common plane up to `f32` rounding (the near-coplanar case it is for),
        /// and with repeated points.
        #[test]
        fn the_integer_path_agrees_with_shewchuk(
            origin in prop::array::uniform3(-3000.0f32..3000.0),
            offsets in prop::array::uniform4(prop::array::uniform3(-4.0f32..4.0)),
            exp in -12i32..4,
            mode in 0u8..5,
        ) {
            let mut points = near(origin, offsets, exp);
            match mode {
                // The fourth point on the plane of the first three, rounded to `f32`.
                1 => {
                    let [a, b, c, _] = points;
                    let (s, t) = (f64::from(offsets[3][0]) / 4.0, f64::from(offsets[3][1]) / 4.0);
                    points[3] = std::array::from_fn(|k| {
                        f64::from((a[k] + s * (b[k] - a[k]) + t * (c[k] - a[k])) as f32)
                    });
                }
                // All four on an axis plane.
                2 => points.iter_mut().for_each(|p| p[2] = f64::from(origin[2])),
                // A repeated point.
                3 => points[3] = points[1],
                // Two edges parallel to the x axis (exactly coplanar: what symmetric or
                // upsampled data makes most of).
                4 => {
                    points[2] = [points[2][0], points[0][1], points[0][2]];
                    points[3] = [points[3][0], points[1][1], points[1][2]];
                }
                _ => {}
            }
            let expected = shewchuk(points);
            if let Some(sign) = orient_fixed(points) {
                prop_assert_eq!(sign, expected, "{:?}", points);
            }
            prop_assert_eq!(sgn(exact_orient(points)), expected);
        }
    }

    /// The cases the integer path leaves to the general predicate, and one it takes: `f32`
    /// points a few voxels apart, nearly coplanar.
    #[test]
    fn wide_spans_go_to_the_general_predicate() {
        let f = |x: f32, y: f32, z: f32| [f64::from(x), f64::from(y), f64::from(z)];
        let flat = [
            f(1201.25, 733.5, 95.125),
            f(1203.0625, 733.875, 95.12501),
            f(1202.5, 735.25, 95.12499),
            f(1202.0, 734.0, 95.125),
        ];
        assert_eq!(orient_fixed(flat), Some(shewchuk(flat)));
        // The largest integers taken, 2^40 - 1, in the largest determinants they make.
        let m = (1u64 << FIXED_BITS) as f64 - 1.0;
        for d in [[m, m, m], [-m, m, -m], [m, -m, m], [-m, -m, -m + 1.0]] {
            let extreme = [[-m, -m, -m], [m, -m, m], [-m, m, m], d];
            assert_eq!(orient_fixed(extreme), Some(shewchuk(extreme)), "{d:?}");
        }
        let (a, b, c) = ([0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(orient_fixed([a, b, c, [0.25, 0.5, 0.0]]), Some(0.0));
        assert_eq!(orient_fixed([a, b, c, [0.25, 0.5, 1.0]]), Some(1.0));
        assert_eq!(
            orient_fixed([a, b, c, [0.0, 0.0, -1e-30]]),
            None,
            "a span of 100 bits"
        );
        assert_eq!(
            orient_fixed([a, b, c, [0.1, 0.2, 0.0]]),
            None,
            "53-bit mantissas"
        );
        assert_eq!(orient_fixed([a, b, c, [f64::NAN, 0.0, 0.0]]), None);
        assert_eq!(orient_fixed([a; 4]), Some(0.0), "all zero");
        assert_eq!(orient_fixed([[f64::NAN; 3]; 4]), None, "all NaN");
        assert_eq!(sgn(exact_orient([a, b, c, [0.0, 0.0, -1e-30]])), -1.0);
    }

    #[test]
    fn two_crossing_triangles_count_both() {
        let p = [
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 2.0, 0.0],
            [0.5, 0.5, -1.0],
            [0.5, 0.5, 1.0],
            [3.0, 3.0, 0.5],
        ];
        assert_eq!(self_intersections(&p, &[[0, 1, 2], [3, 4, 5]]), 2);
        // Moved aside: no crossing.
        let mut q = p;
        for v in &mut q[3..] {
            v[0] += 10.0;
        }
        assert_eq!(self_intersections(&q, &[[0, 1, 2], [3, 4, 5]]), 0);
    }

    /// A shared corner is not a contact; the same position under another index is (a pinch),
    /// though it crosses nothing.
    #[test]
    fn touching_at_a_vertex_is_a_contact_unless_the_vertex_is_shared() {
        let p = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 1.0],
            [0.0, 0.0, 0.0],
        ];
        assert_eq!(self_intersections(&p, &[[0, 1, 2], [0, 3, 4]]), 0);
        assert_eq!(self_intersections(&p, &[[0, 1, 2], [5, 3, 4]]), 2);
        assert_eq!(crossing_triangles(&p, &[[0, 1, 2], [5, 3, 4]]), 0);
        // Sharing a vertex and folding through each other: the opposite edge crosses.
        let f = [
            [0.0, 0.0, 0.0],
            [2.0, -1.0, 0.0],
            [2.0, 1.0, 0.0],
            [1.0, 0.0, -1.0],
            [1.0, 0.0, 1.0],
        ];
        assert_eq!(self_intersections(&f, &[[0, 1, 2], [0, 3, 4]]), 2);
    }

    /// Every kind of contact without a crossing meets, by the closed rule, and only in contact:
    /// a corner on a face, a corner on an edge, edges meeting at a point, an edge lying on a
    /// face, coplanar triangles overlapping or touching at a corner, and a shared corner with a
    /// contact elsewhere; each pair moved a little apart does not meet.
    #[test]
    fn contacts_meet_and_separated_pairs_do_not() {
        let t = [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0]];
        let contacts: [(&str, [[f64; 3]; 3]); 7] = [
            (
                "corner on the face",
                [[1.0, 1.0, 0.0], [1.0, 2.0, 3.0], [2.0, 1.0, 3.0]],
            ),
            (
                "corner on an edge",
                [[2.0, 0.0, 0.0], [2.0, -1.0, 3.0], [3.0, -1.0, 2.0]],
            ),
            (
                "edges crossing at a point inside both",
                [[2.0, -1.0, 1.0], [2.0, 1.0, -1.0], [2.0, -1.0, -3.0]],
            ),
            (
                "an edge on the face",
                [[1.0, 1.0, 0.0], [2.0, 1.0, 0.0], [1.5, 1.0, 2.0]],
            ),
            (
                "coplanar overlap",
                [[1.0, 1.0, 0.0], [5.0, 1.0, 0.0], [1.0, 5.0, 0.0]],
            ),
            (
                "coplanar corners touching",
                [[4.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, -2.0, 0.0]],
            ),
            (
                "coplanar corner on an edge",
                [[2.0, 0.0, 0.0], [3.0, -2.0, 0.0], [1.0, -2.0, 0.0]],
            ),
        ];
        for (name, u) in contacts {
            assert!(triangles_meet([0, 1, 2], t, [3, 4, 5], u), "{name}");
            assert!(
                !triangles_intersect([0, 1, 2], t, [3, 4, 5], u),
                "{name} crosses"
            );
            // Lifted off the plane, or the crossing edge moved off the face's edge.
            let shift = if name.starts_with("edges crossing") {
                [0.0, -0.01, 0.0]
            } else {
                [0.0, 0.0, 0.01]
            };
            let apart = u.map(|x| [x[0] + shift[0], x[1] + shift[1], x[2] + shift[2]]);
            assert!(
                !triangles_meet([0, 1, 2], t, [3, 4, 5], apart),
                "{name} apart"
            );
        }
        // One shared corner (index 0), and the far edge of the other on the face.
        let fan = [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 0.5, 0.0]];
        assert!(triangles_meet([0, 1, 2], t, [0, 7, 8], fan));
        assert!(!triangles_intersect([0, 1, 2], t, [0, 7, 8], fan));
        // Coplanar, one shared corner, the wedges apart: no contact.
        let beside = [[0.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [-1.0, -1.0, 0.0]];
        assert!(!triangles_meet([0, 1, 2], t, [0, 7, 8], beside));
        // Standing on the shared corner only.
        let up = [[0.0, 0.0, 0.0], [-1.0, 0.0, 1.0], [0.0, -1.0, 1.0]];
        assert!(!triangles_meet([0, 1, 2], t, [0, 7, 8], up));
    }

    /// Neighbours across an edge meet when folded onto each other in one plane, not when they
    /// lie side by side in it or at any angle off it.
    #[test]
    fn a_fold_across_an_edge_meets() {
        let (u, v) = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        let a = [u, v, [1.0, 1.0, 0.0]];
        let folded_b = [v, u, [1.5, 0.5, 0.0]];
        let flat_b = [v, u, [1.0, -1.0, 0.0]];
        let bent_b = [v, u, [1.0, 1.0, 0.5]];
        assert!(triangles_meet([0, 1, 2], a, [1, 0, 3], folded_b));
        assert!(!triangles_meet([0, 1, 2], a, [1, 0, 3], flat_b));
        assert!(!triangles_meet([0, 1, 2], a, [1, 0, 3], bent_b));
        assert_eq!(
            self_intersections(&[u, v, a[2], folded_b[2]], &[[0, 1, 2], [1, 0, 3]]),
            2
        );
        assert_eq!(
            crossing_triangles(&[u, v, a[2], folded_b[2]], &[[0, 1, 2], [1, 0, 3]]),
            0
        );
    }

    proptest! {
        /// A crossing pair meets; the closed rule is the strict one and more.
        #[test]
        fn crossing_pairs_meet(
            a in prop::array::uniform3(prop::array::uniform3(-4i8..=4)),
            b in prop::array::uniform3(prop::array::uniform3(-4i8..=4)),
            shared in 0usize..2,
        ) {
            let a = a.map(|p| p.map(f64::from));
            let mut b = b.map(|p| p.map(f64::from));
            let ib = if shared == 1 { b[0] = a[0]; [0, 4, 5] } else { [3, 4, 5] };
            if triangles_intersect([0, 1, 2], a, ib, b) {
                prop_assert!(triangles_meet([0, 1, 2], a, ib, b));
            }
        }
    }

    /// Two triangles touching at coincident vertices with distinct indices (a pinch) put a
    /// corner exactly on the other's plane; in `f64` the determinant `(v x w) . w` rounds to a
    /// few 1e-17 and this pair, from a failed property test, counted as crossing.
    #[test]
    fn a_pinch_does_not_cross_whatever_the_rounding() {
        let a = [10.036419868469238, 8.607321739196777, 12.027900695800781];
        let b = [9.964315414428711, 8.444059371948242, 12.837347030639648];
        let p = [9.0, 9.0, 12.0];
        let c = [9.823773384094238, 8.801894187927246, 11.685136795043945];
        let d = [9.000000953674316, 9.299999237060547, 11.300000190734863];
        assert!(!triangles_intersect(
            [0, 1, 2],
            [a, b, p],
            [3, 4, 5],
            [c, p, d]
        ));
        assert_eq!(orient(c, p, d, p), 0.0, "a corner is on its own plane");
        // Its corner moved through the other triangle's centroid, the pair crosses.
        let g: [f64; 3] = std::array::from_fn(|k| (c[k] + p[k] + d[k]) / 3.0);
        let deep: [f64; 3] = std::array::from_fn(|k| 2.0 * g[k] - a[k]);
        assert!(triangles_intersect(
            [0, 1, 2],
            [a, b, deep],
            [3, 4, 5],
            [c, p, d]
        ));
    }

    /// The filter and the exact fallback agree in sign with plain arithmetic far from the plane,
    /// and give exact zeros on it.
    #[test]
    fn orient_is_exact_on_the_plane() {
        let (a, b, c) = ([0.1, 0.2, 0.3], [1.7, 0.2, 0.3], [0.1, 2.9, 0.3]);
        assert!(orient(a, b, c, [0.5, 0.5, 1.0]) > 0.0);
        assert!(orient(a, b, c, [0.5, 0.5, -1.0]) < 0.0);
        // On the plane z = 0.3, at coordinates that make the f64 determinant round.
        for x in [0.1, 1.7, 0.3, 1e-3, 12345.678] {
            assert_eq!(orient(a, b, c, [x, 0.7 * x, 0.3]), 0.0);
        }
    }

    /// A closed UV sphere: neighbours only, no crossing.
    #[test]
    fn a_closed_sphere_has_none() {
        let (nu, nv) = (24u32, 12u32);
        let mut p = vec![[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
        for j in 1..nv {
            let th = std::f64::consts::PI * f64::from(j) / f64::from(nv);
            for i in 0..nu {
                let ph = 2.0 * std::f64::consts::PI * f64::from(i) / f64::from(nu);
                p.push([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]);
            }
        }
        let ring = |j: u32, i: u32| 2 + (j - 1) * nu + i % nu;
        let mut t = Vec::new();
        for i in 0..nu {
            t.push([0, ring(1, i), ring(1, i + 1)]);
            t.push([1, ring(nv - 1, i + 1), ring(nv - 1, i)]);
            for j in 1..nv - 1 {
                t.push([ring(j, i), ring(j + 1, i), ring(j + 1, i + 1)]);
                t.push([ring(j, i), ring(j + 1, i + 1), ring(j, i + 1)]);
            }
        }
        assert_eq!(self_intersections(&p, &t), 0);
        // Two copies, the second shrunk by 5 %: nested, disjoint. Shifted: they cross.
        let off = p.len() as u32;
        let mut p2 = p.clone();
        p2.extend(p.iter().map(|v| v.map(|x| 0.95 * x)));
        let mut t2 = t.clone();
        t2.extend(t.iter().map(|v| v.map(|i| i + off)));
        assert_eq!(self_intersections(&p2, &t2), 0);
        for v in &mut p2[off as usize..] {
            v[0] += 0.5;
        }
        assert!(self_intersections(&p2, &t2) > 0);
    }
}
