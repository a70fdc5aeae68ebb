//! Geometry of one triangle: area, closest point, uniform sampling, angles and the shape tensor
//! `M_abc` of the Tandem paper (Attali, Cohen-Steiner, Edelsbrunner), Appendix A.
//!
//! Everything is f64: positions reach 10^4 and distances of 10^-3 must survive the subtraction.

use glam::{DMat3, DVec3};

/// A triangle by its three corners, counter-clockwise seen from outside.
pub(crate) type Triangle = [DVec3; 3];

/// Looks up the corners of an indexed triangle.
pub(crate) fn corners(positions: &[[f64; 3]], t: &[u32; 3]) -> Triangle {
    t.map(|i| DVec3::from_array(positions[i as usize]))
}

/// Twice the area vector: its length is twice the area, its direction the (unnormalised) normal.
pub(crate) fn cross(t: &Triangle) -> DVec3 {
    (t[1] - t[0]).cross(t[2] - t[0])
}

pub(crate) fn area(t: &Triangle) -> f64 {
    0.5 * cross(t).length()
}

/// Smallest interior angle in degrees; 0 for a degenerate triangle. `atan2(|u x v|, u . v)` is
/// accurate for angles near 0 and 180 degrees, where `acos` of the cosine is not.
pub(crate) fn min_angle_degrees(t: &Triangle) -> f64 {
    (0..3)
        .map(|i| {
            let u = t[(i + 1) % 3] - t[i];
            let v = t[(i + 2) % 3] - t[i];
            u.cross(v).length().atan2(u.dot(v)).to_degrees()
        })
        .fold(f64::INFINITY, f64::min)
}

/// `M_abc = 1/3 (a a^T + b b^T + c c^T)` with `a, b, c` the vectors from the centroid to the
/// corners (paper, section 4 "Mesh quality" and Appendix A "The shape of a triangle").
pub(crate) fn shape_tensor(t: &Triangle) -> DMat3 {
    let centroid = (t[0] + t[1] + t[2]) / 3.0;
    t.iter()
        .map(|&p| {
            let v = p - centroid;
            outer(v, v)
        })
        .fold(DMat3::ZERO, |acc, m| acc + m)
        / 3.0
}

/// Sum of the squared edge lengths. Appendix A, "Equivalent formulations": the edge vectors give
/// `M_pqr = 3 M_abc`, so `trace M_abc` is this sum divided by 9.
pub(crate) fn squared_edge_sum(t: &Triangle) -> f64 {
    (t[1] - t[0]).length_squared() + (t[2] - t[1]).length_squared() + (t[0] - t[2]).length_squared()
}

pub(crate) fn outer(u: DVec3, v: DVec3) -> DMat3 {
    DMat3::from_cols(u * v.x, u * v.y, u * v.z)
}

/// The point at barycentric-free coordinates `(r1, r2) in [0,1)^2` mapped uniformly onto the
/// triangle: `s = sqrt(r1)` makes the density constant per unit area (Osada et al. 2002).
pub(crate) fn uniform_point(t: &Triangle, r1: f64, r2: f64) -> DVec3 {
    let s = r1.sqrt();
    t[0] * (1.0 - s) + t[1] * (s * (1.0 - r2)) + t[2] * (s * r2)
}

/// Closest point of the triangle to `p`, by Voronoi regions of the corners, edges and face
/// (Ericson, Real-Time Collision Detection, 5.1.5). Exact up to rounding; degenerate triangles
/// (collinear corners) fall back to the closest point of their edges. So do those with two
/// coincident corners, first: other tools' outputs hold many (meshoptimizer's bonsai at R = 0.2
/// has 137 k zero-area triangles), the regions below assume a triangle with a plane, and for
/// them one region's ratio was 0 / 0: one NaN distance, as a search bound, made every later
/// query of `isostream measure` visit the whole hierarchy (over ten minutes instead of seconds).
pub(crate) fn closest_point(p: DVec3, t: &Triangle) -> DVec3 {
    let [a, b, c] = *t;
    if a == b || b == c || c == a {
        return closest_on_edges(p, t);
    }
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let sum = va + vb + vc;
    if sum <= 0.0 {
        return closest_on_edges(p, t);
    }
    a + ab * (vb / sum) + ac * (vc / sum)
}

/// Closest point of the triangle's three edges to `p`: that of a triangle without a plane.
fn closest_on_edges(p: DVec3, t: &Triangle) -> DVec3 {
    let [a, b, c] = *t;
    [(a, b), (b, c), (c, a)]
        .map(|(u, v)| closest_on_segment(p, u, v))
        .into_iter()
        .fold(a, |best, q| {
            if p.distance_squared(q) < p.distance_squared(best) {
                q
            } else {
                best
            }
        })
}

fn closest_on_segment(p: DVec3, u: DVec3, v: DVec3) -> DVec3 {
    let d = v - u;
    let len2 = d.length_squared();
    if len2 == 0.0 {
        return u;
    }
    u + d * ((p - u).dot(d) / len2).clamp(0.0, 1.0)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn equilateral(side: f64) -> Triangle {
        [
            DVec3::ZERO,
            DVec3::new(side, 0.0, 0.0),
            DVec3::new(0.5 * side, 0.5 * side * 3f64.sqrt(), 0.0),
        ]
    }

    #[test]
    fn closest_point_in_every_voronoi_region() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let cases = [
            (DVec3::new(0.2, 0.2, 3.0), DVec3::new(0.2, 0.2, 0.0)), // face
            (DVec3::new(-1.0, -1.0, 1.0), DVec3::ZERO),             // corner a
            (DVec3::new(2.0, -0.5, 0.0), DVec3::X),                 // corner b
            (DVec3::new(-0.5, 2.0, 0.0), DVec3::Y),                 // corner c
            (DVec3::new(0.5, -1.0, 0.0), DVec3::new(0.5, 0.0, 0.0)), // edge ab
            (DVec3::new(-1.0, 0.5, 0.0), DVec3::new(0.0, 0.5, 0.0)), // edge ac
            (DVec3::new(1.0, 1.0, -2.0), DVec3::new(0.5, 0.5, 0.0)), // edge bc
        ];
        for (p, want) in cases {
            let got = closest_point(p, &t);
            assert!(got.distance(want) < 1e-12, "{p}: got {got}, want {want}");
        }
    }

    #[test]
    fn closest_point_on_degenerate_triangles() {
        let collinear = [DVec3::ZERO, DVec3::new(2.0, 0.0, 0.0), DVec3::X];
        let got = closest_point(DVec3::new(1.5, 1.0, 0.0), &collinear);
        assert!(got.distance(DVec3::new(1.5, 0.0, 0.0)) < 1e-12, "{got}");
        let point = [DVec3::ONE; 3];
        assert_eq!(closest_point(DVec3::ZERO, &point), DVec3::ONE);
    }

    /// Two coincident corners, in each of the three places, probed from every side: the closest
    /// point of the segment between the distinct corners, never NaN (0 / 0 in the region of the
    /// zero-length edge before).
    #[test]
    fn closest_point_with_coincident_corners() {
        let (u, v) = (DVec3::new(1.0, 2.0, 3.0), DVec3::new(4.0, 0.0, 3.5));
        for t in [[u, u, v], [u, v, u], [v, u, u]] {
            for i in 0..125 {
                let p = DVec3::new((i % 5) as f64, (i / 5 % 5) as f64, (i / 25) as f64) * 1.5
                    - DVec3::splat(1.0);
                let got = closest_point(p, &t);
                let want = closest_on_segment(p, u, v);
                assert!(got.is_finite(), "{t:?} from {p}: {got}");
                assert!(
                    got.distance(want) < 1e-9,
                    "{t:?} from {p}: got {got}, want {want}"
                );
            }
        }
    }

    #[test]
    fn uniform_points_stay_inside() {
        let t = equilateral(2.0);
        for (r1, r2) in [(0.0, 0.0), (0.999, 0.999), (0.5, 0.1), (0.01, 0.7)] {
            let p = uniform_point(&t, r1, r2);
            assert!(closest_point(p, &t).distance(p) < 1e-12);
        }
    }

    #[test]
    fn angles_and_area() {
        let t = equilateral(2.0);
        assert!((min_angle_degrees(&t) - 60.0).abs() < 1e-12);
        assert!((area(&t) - 3f64.sqrt()).abs() < 1e-12);
        let right = [DVec3::ZERO, DVec3::X, DVec3::Y];
        assert!((min_angle_degrees(&right) - 45.0).abs() < 1e-12);
        assert_eq!(min_angle_degrees(&[DVec3::ZERO, DVec3::X, DVec3::X]), 0.0);
    }

    #[test]
    fn shape_tensor_trace_matches_edge_formula() {
        let t = [
            DVec3::new(0.3, -1.0, 2.0),
            DVec3::new(4.0, 0.5, 1.0),
            DVec3::new(-2.0, 1.0, 0.0),
        ];
        let m = shape_tensor(&t);
        let trace = m.x_axis.x + m.y_axis.y + m.z_axis.z;
        assert!((trace - squared_edge_sum(&t) / 9.0).abs() < 1e-12);
    }
}
