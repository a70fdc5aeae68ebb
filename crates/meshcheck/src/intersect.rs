//! Self-intersection count: triangles that cross another triangle of the same mesh.
//!
//! Broad phase: a uniform grid with cells of twice the mean edge length; every triangle is filed
//! in each cell its bounding box overlaps, and each pair met in a shared cell is tested once
//! (bounding boxes first). Narrow phase, in `f64` orientation determinants (exact enough for
//! marching-cubes coordinates; ties count as "no crossing"):
//! * **disjoint triangles** (no common vertex index): they intersect iff an edge of one strictly
//!   crosses the other (both endpoints strictly on opposite sides of its plane, the line strictly
//!   inside the three edge planes). Coplanar overlaps and contacts along an edge or at a point
//!   (touching) are not counted.
//! * **one common vertex** `x`: they meet at `x` anyway; they *cross* iff the edge opposite `x` in
//!   one strictly crosses the other triangle.
//! * **two or three common vertices** (neighbours across an edge, duplicates): skipped; folds
//!   there are normal flips, the topology checks' business.

/// `(b - a) . ((c - a) x (d - a))`: positive when `d` lies above the plane `abc` (CCW seen from
/// above).
fn orient(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3]) -> f64 {
    let u = sub(b, a);
    let v = sub(c, a);
    let w = sub(d, a);
    u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
        + u[2] * (v[0] * w[1] - v[1] * w[0])
}

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

/// Whether two triangles given by corner indices `ia`, `ib` and positions `a`, `b` cross (see the
/// module documentation for shared vertices).
pub fn triangles_intersect(ia: [u32; 3], a: [[f64; 3]; 3], ib: [u32; 3], b: [[f64; 3]; 3]) -> bool {
    let shared: Vec<(usize, usize)> = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .filter(|&(i, j)| ia[i] == ib[j])
        .collect();
    match shared.as_slice() {
        [] => (0..3).any(|i| {
            segment_crosses_triangle(a[i], a[(i + 1) % 3], b)
                || segment_crosses_triangle(b[i], b[(i + 1) % 3], a)
        }),
        [(i, j)] => {
            segment_crosses_triangle(a[(i + 1) % 3], a[(i + 2) % 3], b)
                || segment_crosses_triangle(b[(j + 1) % 3], b[(j + 2) % 3], a)
        }
        _ => false,
    }
}

/// Number of triangles that cross at least one other triangle (see the module documentation:
/// triangles sharing one vertex count when the opposite edge of one crosses the other; triangles
/// sharing an edge are not compared). Triangles with an out-of-range index are ignored.
pub fn self_intersections(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> usize {
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
                        if triangles_intersect(triangles[t], *p, triangles[s], q) {
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

    #[test]
    fn touching_at_a_vertex_is_not_counted() {
        // Shared index, and a separate vertex at the same position: neither crosses.
        let p = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 1.0],
            [0.0, 0.0, 0.0],
        ];
        assert_eq!(self_intersections(&p, &[[0, 1, 2], [0, 3, 4]]), 0);
        assert_eq!(self_intersections(&p, &[[0, 1, 2], [5, 3, 4]]), 0);
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
