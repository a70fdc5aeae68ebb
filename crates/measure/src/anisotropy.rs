//! Aspect ratio and anisotropy, Tandem paper section 4 "Mesh quality" and Appendix A.
//!
//! `rho(t) = sqrt(lambda_2 / lambda_1)` with `lambda_1 >= lambda_2` the eigenvalues of
//! `M_abc = 1/3 (a a^T + b b^T + c c^T)` in the triangle's plane, and
//! `Anisotropy(K) = 1 - (1/n) sum_t rho(t)`: 0 iff every triangle is equilateral, near 1 for
//! long skinny triangles.

use crate::triangle::{Triangle, cross, squared_edge_sum};

/// The aspect ratio `rho(t)` of section 4; 0 for a degenerate triangle.
///
/// The in-plane eigenvalues come from closed forms, each free of cancellation where it matters:
/// * writing the centroid-relative corners as complex numbers `z_k` in an orthonormal basis of the
///   plane, `M_abc = [[p, q], [q, r]]` has `(lambda_1 - lambda_2)^2 = (p - r)^2 + 4 q^2
///   = |sum z_k^2|^2 / 9`, which vanishes exactly for an equilateral triangle (the sum of the
///   squared cube roots of unity), so near-equilateral triangles keep full precision;
/// * `lambda_1 + lambda_2 = trace M_abc = (sum of squared edges) / 9` (Appendix A,
///   `M_pqr = 3 M_abc`);
/// * `lambda_1 lambda_2 = 4 area^2 / 27`: with `M_abc = 1/3 U U^T`, `U = [a b c]`, Cauchy-Binet
///   gives `det(U U^T) = det(a,b)^2 + det(b,c)^2 + det(c,a)^2 = 3 (2 area / 3)^2`, as the centroid
///   splits the triangle into three of equal area. `lambda_2 = det / lambda_1` stays accurate for
///   skinny triangles, where `lambda_1 - (lambda_1 - lambda_2)` would not.
pub(crate) fn aspect_ratio(t: &Triangle) -> f64 {
    let double_area = cross(t).length();
    if double_area == 0.0 {
        return 0.0;
    }
    let centroid = (t[0] + t[1] + t[2]) / 3.0;
    let e1 = (t[0] - centroid).normalize();
    let e2 = cross(t).cross(e1) / double_area;
    let (mut re, mut im) = (0.0, 0.0);
    for &p in t {
        let v = p - centroid;
        let (x, y) = (v.dot(e1), v.dot(e2));
        re += x * x - y * y;
        im += 2.0 * x * y;
    }
    let trace = squared_edge_sum(t) / 9.0;
    let difference = re.hypot(im) / 3.0;
    let lambda1 = 0.5 * (trace + difference);
    let lambda2 = double_area * double_area / 27.0 / lambda1; // 4 area^2 / 27 / lambda_1
    (lambda2 / lambda1).sqrt().min(1.0)
}

/// `Anisotropy(K)` over the given triangles; 0 for an empty set (nothing is anisotropic).
pub(crate) fn anisotropy<'a>(triangles: impl ExactSizeIterator<Item = &'a Triangle>) -> f64 {
    let n = triangles.len();
    if n == 0 {
        return 0.0;
    }
    let sum: f64 = triangles.map(aspect_ratio).sum();
    1.0 - sum / n as f64
}

#[cfg(test)]
mod tests {
    use glam::{DMat3, DVec3};

    use super::*;
    use crate::triangle::shape_tensor;
    use crate::triangle::tests::equilateral;

    #[test]
    fn equilateral_triangles_have_anisotropy_zero() {
        let tris = [equilateral(1.0), equilateral(1e-3), equilateral(1e4)];
        for t in &tris {
            assert!((aspect_ratio(t) - 1.0).abs() < 1e-9);
        }
        assert!(anisotropy(tris.iter()).abs() < 1e-9);
    }

    #[test]
    fn skinny_triangles_have_anisotropy_near_one() {
        let strip: Vec<Triangle> = (0..100)
            .map(|i| {
                let x = i as f64;
                [
                    DVec3::new(x, 0.0, 0.0),
                    DVec3::new(x + 1.0, 0.0, 0.0),
                    DVec3::new(x, 1e-4, 0.0),
                ]
            })
            .collect();
        assert!(anisotropy(strip.iter()) > 0.999);
        let collinear = [DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
        assert_eq!(aspect_ratio(&collinear), 0.0);
        assert_eq!(aspect_ratio(&[DVec3::ONE; 3]), 0.0);
    }

    /// The closed form must agree with the eigenvalues of `M_abc` itself (paper's definition).
    #[test]
    fn closed_form_matches_eigenvalues_of_shape_tensor() {
        let t = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(3.0, 1.0, 2.0),
            DVec3::new(1.0, 2.0, -1.0),
        ];
        let m = shape_tensor(&t);
        // Characteristic polynomial of a rank-2 symmetric matrix: x^2 - tr x + I2 with
        // I2 = (tr^2 - tr(M^2)) / 2.
        let tr = m.x_axis.x + m.y_axis.y + m.z_axis.z;
        let m2: DMat3 = m * m;
        let i2 = 0.5 * (tr * tr - (m2.x_axis.x + m2.y_axis.y + m2.z_axis.z));
        let root = (tr * tr / 4.0 - i2).sqrt();
        let (l1, l2) = (tr / 2.0 + root, tr / 2.0 - root);
        assert!((aspect_ratio(&t) - (l2 / l1).sqrt()).abs() < 1e-12);
        assert!(m.determinant().abs() < 1e-9, "M_abc is planar");
    }

    #[test]
    fn right_isosceles_value() {
        // Legs 1: trace = (1 + 1 + 2)/9, det = 4 (1/2)^2 / 27 = 1/27.
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let tr = 4.0 / 9.0;
        let l1 = tr / 2.0 + (tr * tr / 4.0 - 1.0 / 27.0f64).sqrt();
        let l2 = tr - l1;
        assert!((aspect_ratio(&t) - (l2 / l1).sqrt()).abs() < 1e-12);
    }
}
