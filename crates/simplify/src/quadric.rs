//! Symmetric 4x4 quadrics in f64 (Garland and Heckbert 1997).
//!
//! A quadric `Q` represents the function `x -> [x 1] Q [x 1]^T` on points of R^3. Summing
//! area-weighted plane quadrics gives the error quadric of Garland and Heckbert; the same sum is the
//! matrix `H_c` of the Tandem shape measure (seed 000, section 3, "Error threshold"), so one type
//! serves both. Coordinates of real volumes reach 10^4 and their squares 10^8: f32 would lose the
//! error entirely, hence f64 throughout.

use glam::{DMat3, DVec3};

/// A placement is rejected as ill-conditioned when `|det A|` is below this fraction of
/// `(trace A / 3)^3`, the determinant of the isotropic matrix with the same trace. The ratio is
/// scale invariant, so it means the same for grid units and millimetres.
const RELATIVE_DET_MIN: f64 = 1e-9;

/// Upper triangle of a symmetric 4x4 matrix, row by row:
/// `[a00, a01, a02, a03, a11, a12, a13, a22, a23, a33]`.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Quadric([f64; 10]);

impl Quadric {
    /// `w * (n . x + d)^2`: weighted squared distance from the plane with unit normal `n` and
    /// offset `d` (Garland and Heckbert 1997, section 5).
    pub(crate) fn plane(n: DVec3, d: f64, w: f64) -> Self {
        let (x, y, z) = (n.x, n.y, n.z);
        Self([
            w * x * x,
            w * x * y,
            w * x * z,
            w * x * d,
            w * y * y,
            w * y * z,
            w * y * d,
            w * z * z,
            w * z * d,
            w * d * d,
        ])
    }

    /// `w * (|x - center|^2 + extra)`: the quadric of three orthogonal planes through `center`
    /// with a constant added, i.e. the `G_t` of the isotropy term (seed 000, section 3, "Mesh
    /// isotropy"), where `extra = avg(t)`.
    pub(crate) fn point(center: DVec3, extra: f64, w: f64) -> Self {
        Self([
            w,
            0.0,
            0.0,
            -w * center.x,
            w,
            0.0,
            -w * center.y,
            w,
            -w * center.z,
            w * (center.length_squared() + extra),
        ])
    }

    pub(crate) fn scaled(&self, s: f64) -> Self {
        Self(self.0.map(|v| v * s))
    }

    /// Value of the quadric at `p`. May be a hair below zero from rounding; callers clamp.
    pub(crate) fn eval(&self, p: DVec3) -> f64 {
        let q = &self.0;
        let (x, y, z) = (p.x, p.y, p.z);
        x * (q[0] * x + 2.0 * (q[1] * y + q[2] * z + q[3]))
            + y * (q[4] * y + 2.0 * (q[5] * z + q[6]))
            + z * (q[7] * z + 2.0 * q[8])
            + q[9]
    }

    /// The point minimising the quadric, or `None` when the 3x3 system is ill-conditioned (flat
    /// or cylindrical neighbourhoods: the minimum is a plane or a line, not a point). Callers then
    /// fall back to a finite set of candidate positions.
    pub(crate) fn minimizer(&self) -> Option<DVec3> {
        let q = &self.0;
        let a = DMat3::from_cols(
            DVec3::new(q[0], q[1], q[2]),
            DVec3::new(q[1], q[4], q[5]),
            DVec3::new(q[2], q[5], q[7]),
        );
        let scale = (q[0] + q[4] + q[7]) / 3.0;
        let det = a.determinant();
        if !(scale > 0.0 && det.abs() > RELATIVE_DET_MIN * scale * scale * scale) {
            return None;
        }
        let x = a.inverse() * -DVec3::new(q[3], q[6], q[8]);
        x.is_finite().then_some(x)
    }
}

impl std::ops::Add for Quadric {
    type Output = Self;
    fn add(mut self, rhs: Self) -> Self {
        self += rhs;
        self
    }
}

impl std::ops::AddAssign for Quadric {
    fn add_assign(&mut self, rhs: Self) {
        for (a, b) in self.0.iter_mut().zip(rhs.0) {
            *a += b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane_through(p: DVec3, n: DVec3, w: f64) -> Quadric {
        let n = n.normalize();
        Quadric::plane(n, -n.dot(p), w)
    }

    #[test]
    fn plane_quadric_is_weighted_squared_distance() {
        let q = plane_through(DVec3::new(1.0, 2.0, 3.0), DVec3::new(1.0, 1.0, 0.0), 2.5);
        let p = DVec3::new(4.0, -1.0, 7.0);
        let dist = (p - DVec3::new(1.0, 2.0, 3.0)).dot(DVec3::new(1.0, 1.0, 0.0).normalize());
        assert!((q.eval(p) - 2.5 * dist * dist).abs() < 1e-12);
    }

    #[test]
    fn three_planes_meet_in_their_minimizer() {
        let corner = DVec3::new(1e4, -2e3, 5.5);
        let q = plane_through(corner, DVec3::X, 1.0)
            + plane_through(corner, DVec3::new(1.0, 1.0, 0.0), 2.0)
            + plane_through(corner, DVec3::new(0.0, 1.0, 3.0), 0.5);
        let x = q.minimizer().expect("well conditioned");
        assert!((x - corner).length() < 1e-6, "{x}");
        assert!(q.eval(x).abs() < 1e-6);
    }

    #[test]
    fn flat_and_cylindrical_neighbourhoods_are_ill_conditioned() {
        let p = DVec3::new(3.0, 4.0, 5.0);
        let flat = plane_through(p, DVec3::Z, 1.0) + plane_through(p + DVec3::X, DVec3::Z, 1.0);
        assert_eq!(flat.minimizer(), None);
        let cylinder = plane_through(p, DVec3::X, 1.0) + plane_through(p, DVec3::Y, 1.0);
        assert_eq!(cylinder.minimizer(), None);
    }

    #[test]
    fn point_quadric_is_squared_distance_plus_constant() {
        let c = DVec3::new(1.0, -2.0, 0.5);
        let g = Quadric::point(c, 0.25, 3.0);
        let p = DVec3::new(0.0, 1.0, 1.0);
        assert!((g.eval(p) - 3.0 * ((p - c).length_squared() + 0.25)).abs() < 1e-12);
        assert!((g.minimizer().unwrap() - c).length() < 1e-12);
        assert!((g.scaled(2.0).eval(p) - 2.0 * g.eval(p)).abs() < 1e-12);
    }
}
