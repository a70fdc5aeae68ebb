//! Directional bias, Tandem paper section 4 "Directional bias".
//!
//! `M_n = (1/area(K)) sum_t w_t n_t n_t^T` measures the spread of the normals (the surface's own
//! non-uniformity); `M_s = (2/area(K)) sum_t w_t M_abc / trace M_abc` the average triangle shape.
//! For an equilateral triangle, `2 M_abc / trace M_abc` is the projector onto its plane, so
//! `n n^T` plus it is the identity: `M = M_n + M_s` is the identity when all triangles are
//! equilateral, and what remains measures how the triangulation (not the surface) prefers
//! directions. `Bias(K) = 1 - 27 det M / (trace M)^3` is 0 for an isotropic `M` and at most 1.

use glam::DMat3;

use crate::triangle::{Triangle, cross, outer, shape_tensor, squared_edge_sum};

/// `Bias(K)` over the given triangles; 0 for a surface without area. Zero-area triangles carry
/// weight `w_t = 0` and no normal, so they are skipped.
pub(crate) fn directional_bias<'a>(triangles: impl Iterator<Item = &'a Triangle>) -> f64 {
    let mut m = DMat3::ZERO;
    let mut total_area = 0.0;
    for t in triangles {
        let n2 = cross(t); // |n2| = 2 w_t
        let double_area = n2.length();
        if double_area == 0.0 {
            continue;
        }
        let w = 0.5 * double_area;
        // w n n^T with n = n2 / |n2|.
        m += outer(n2, n2) * (w / (double_area * double_area));
        // 2 w M_abc / trace M_abc, with trace M_abc = (sum of squared edges) / 9.
        m += shape_tensor(t) * (2.0 * w * 9.0 / squared_edge_sum(t));
        total_area += w;
    }
    if total_area == 0.0 {
        return 0.0;
    }
    let m = m / total_area;
    let trace = m.x_axis.x + m.y_axis.y + m.z_axis.z;
    // Rounding can push an isotropic M a hair past the bound; the paper's range is [0, 1].
    (1.0 - 27.0 * m.determinant() / trace.powi(3)).clamp(0.0, 1.0)
}

#[cfg(test)]
pub(crate) mod tests {
    use glam::DVec3;

    use super::*;

    /// Regular icosahedron: 12 vertices, 20 equilateral faces, outward orientation.
    pub(crate) fn icosahedron() -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let g = (1.0 + 5f64.sqrt()) / 2.0;
        let v = [
            (-1.0, g, 0.0),
            (1.0, g, 0.0),
            (-1.0, -g, 0.0),
            (1.0, -g, 0.0),
            (0.0, -1.0, g),
            (0.0, 1.0, g),
            (0.0, -1.0, -g),
            (0.0, 1.0, -g),
            (g, 0.0, -1.0),
            (g, 0.0, 1.0),
            (-g, 0.0, -1.0),
            (-g, 0.0, 1.0),
        ]
        .map(|(x, y, z)| DVec3::new(x, y, z).normalize());
        let f = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        (v.to_vec(), f)
    }

    /// Geodesic sphere: the icosahedron with each face split into four, `levels` times,
    /// vertices pushed onto the unit sphere.
    pub(crate) fn geodesic_sphere(levels: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let (mut v, mut f) = icosahedron();
        for _ in 0..levels {
            let mut mid = std::collections::HashMap::new();
            let mut midpoint = |a: u32, b: u32, v: &mut Vec<DVec3>| -> u32 {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    v.push(((v[a as usize] + v[b as usize]) / 2.0).normalize());
                    (v.len() - 1) as u32
                })
            };
            let mut next = Vec::with_capacity(f.len() * 4);
            for [a, b, c] in f {
                let (ab, bc, ca) = (
                    midpoint(a, b, &mut v),
                    midpoint(b, c, &mut v),
                    midpoint(c, a, &mut v),
                );
                next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            f = next;
        }
        (v, f)
    }

    fn triangles(v: &[DVec3], f: &[[u32; 3]]) -> Vec<Triangle> {
        f.iter().map(|t| t.map(|i| v[i as usize])).collect()
    }

    #[test]
    fn platonic_solids_have_no_bias() {
        let s = 1.0 / 3f64.sqrt();
        let tet = [
            DVec3::new(s, s, s),
            DVec3::new(s, -s, -s),
            DVec3::new(-s, s, -s),
            DVec3::new(-s, -s, s),
        ];
        let tet_faces = [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]];
        assert!(directional_bias(triangles(&tet, &tet_faces).iter()) < 1e-9);
        let (v, f) = icosahedron();
        assert!(directional_bias(triangles(&v, &f).iter()) < 1e-9);
    }

    #[test]
    fn fine_sphere_has_little_bias() {
        let (v, f) = geodesic_sphere(4);
        let b = directional_bias(triangles(&v, &f).iter());
        assert!(b < 0.02, "{b}");
    }

    /// A flat strip of triangles stretched along x: M_n = z z^T, M_s concentrated on x.
    #[test]
    fn stretched_triangles_are_biased() {
        let strip: Vec<Triangle> = (0..50)
            .map(|i| {
                let x = 10.0 * i as f64;
                [
                    DVec3::new(x, 0.0, 0.0),
                    DVec3::new(x + 10.0, 0.0, 0.0),
                    DVec3::new(x, 1.0, 0.0),
                ]
            })
            .collect();
        let b = directional_bias(strip.iter());
        assert!(b > 0.5 && b <= 1.0, "{b}");
    }

    #[test]
    fn no_area_no_bias() {
        assert_eq!(
            directional_bias([[DVec3::ZERO, DVec3::X, DVec3::X]].iter()),
            0.0
        );
    }
}
