//! Quadrics over position and attributes (Garland and Heckbert 1998; Hoppe 1999 uses the same
//! error with a sparser storage): a triangle with corners `P_i = (x_i, w_1 a_1i, ..., w_m a_mi)`
//! in R^(3+m) contributes `area * (squared distance from its plane in R^(3+m))`, i.e.
//! `v^T A v + 2 b^T v + c` with `A = I - e1 e1^T - e2 e2^T`,
//! `b = (p.e1) e1 + (p.e2) e2 - p`, `c = p.p - (p.e1)^2 - (p.e2)^2` for an orthonormal basis
//! `e1, e2` of the plane through `p = P_0`. A contraction minimises the sum over position and
//! attributes; the attributes of the new vertex come out of the same solve. Attributes that are
//! a linear function of position on a flat patch give a quadric that vanishes on that function,
//! so they are reproduced exactly.

use glam::DVec3;

use crate::store::Store;
use crate::topology;

/// A pivot below this fraction of the mean diagonal makes the system ill-conditioned.
const RELATIVE_PIVOT_MIN: f64 = 1e-9;

/// A dense symmetric quadric on R^n (`n = 3 + attributes`), in scaled attribute units.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct AttrQuadric {
    n: usize,
    /// Row-major n x n.
    a: Vec<f64>,
    b: Vec<f64>,
    c: f64,
}

impl AttrQuadric {
    fn zero(n: usize) -> Self {
        Self {
            n,
            a: vec![0.0; n * n],
            b: vec![0.0; n],
            c: 0.0,
        }
    }

    /// The area-weighted quadric of a triangle, corners given as (position, attributes).
    /// `None` for a degenerate triangle.
    pub(crate) fn triangle(corners: [(DVec3, &[f32]); 3], weights: &[f64]) -> Option<Self> {
        let n = 3 + weights.len();
        let point = |(x, attrs): (DVec3, &[f32])| -> Vec<f64> {
            let mut v = x.to_array().to_vec();
            v.extend(
                weights
                    .iter()
                    .enumerate()
                    .map(|(j, w)| w * f64::from(attrs.get(j).copied().unwrap_or(0.0))),
            );
            v
        };
        let [p, q, r] = corners.map(point);
        let area = 0.5
            * (corners[1].0 - corners[0].0)
                .cross(corners[2].0 - corners[0].0)
                .length();
        if area <= 0.0 {
            return None;
        }
        let sub =
            |u: &[f64], v: &[f64]| -> Vec<f64> { u.iter().zip(v).map(|(a, b)| a - b).collect() };
        let dot = |u: &[f64], v: &[f64]| -> f64 { u.iter().zip(v).map(|(a, b)| a * b).sum() };
        let mut e1 = sub(&q, &p);
        let l1 = dot(&e1, &e1).sqrt();
        if l1 <= 0.0 {
            return None;
        }
        e1.iter_mut().for_each(|x| *x /= l1);
        let mut e2 = sub(&r, &p);
        let k = dot(&e2, &e1);
        e2.iter_mut().zip(&e1).for_each(|(x, e)| *x -= k * e);
        let l2 = dot(&e2, &e2).sqrt();
        if l2 <= 1e-12 * l1 {
            return None;
        }
        e2.iter_mut().for_each(|x| *x /= l2);
        let (pe1, pe2) = (dot(&p, &e1), dot(&p, &e2));
        let mut out = Self::zero(n);
        for i in 0..n {
            for j in 0..n {
                let id = if i == j { 1.0 } else { 0.0 };
                out.a[i * n + j] = area * (id - e1[i] * e1[j] - e2[i] * e2[j]);
            }
            out.b[i] = area * (pe1 * e1[i] + pe2 * e2[i] - p[i]);
        }
        out.c = area * (dot(&p, &p) - pe1 * pe1 - pe2 * pe2);
        Some(out)
    }

    pub(crate) fn add(&mut self, other: &Self) {
        if self.n != other.n {
            return;
        }
        self.a.iter_mut().zip(&other.a).for_each(|(x, y)| *x += y);
        self.b.iter_mut().zip(&other.b).for_each(|(x, y)| *x += y);
        self.c += other.c;
    }

    pub(crate) fn sum(&self, other: &Self) -> Self {
        let mut s = self.clone();
        s.add(other);
        s
    }

    fn eval(&self, v: &[f64]) -> f64 {
        let n = self.n;
        let mut total = self.c;
        for i in 0..n {
            let row: f64 = (0..n).map(|j| self.a[i * n + j] * v[j]).sum();
            total += v[i] * (row + 2.0 * self.b[i]);
        }
        total
    }

    /// The unconstrained minimiser, `None` when ill-conditioned.
    fn minimizer(&self) -> Option<Vec<f64>> {
        let rhs: Vec<f64> = self.b.iter().map(|x| -x).collect();
        solve(self.a.clone(), rhs, self.n)
    }

    /// Optimal scaled attributes at a fixed position `x`: `A_ss s = -(b_s + A_sx x)`.
    fn scaled_attributes_at(&self, x: DVec3) -> Option<Vec<f64>> {
        let (n, m) = (self.n, self.n - 3);
        let x = x.to_array();
        let mut a = vec![0.0; m * m];
        let mut rhs = vec![0.0; m];
        for i in 0..m {
            for j in 0..m {
                a[i * m + j] = self.a[(3 + i) * n + 3 + j];
            }
            rhs[i] = -self.b[3 + i] - (0..3).map(|k| self.a[(3 + i) * n + k] * x[k]).sum::<f64>();
        }
        solve(a, rhs, m)
    }

    /// Optimal (unscaled) attributes at `x`, `None` when the attribute block is singular.
    pub(crate) fn attributes_at(&self, x: DVec3, weights: &[f64]) -> Option<Box<[f32]>> {
        let s = self.scaled_attributes_at(x)?;
        Some(s.iter().zip(weights).map(|(s, w)| (s / w) as f32).collect())
    }

    /// The error of position `x` with its optimal attributes.
    fn cost_at(&self, x: DVec3) -> Option<f64> {
        let mut v = x.to_array().to_vec();
        v.extend(self.scaled_attributes_at(x)?);
        Some(self.eval(&v).max(0.0))
    }
}

/// Gaussian elimination with partial pivoting on a row-major `n x n` system.
fn solve(mut a: Vec<f64>, mut b: Vec<f64>, n: usize) -> Option<Vec<f64>> {
    if n == 0 {
        return Some(Vec::new());
    }
    let scale = (0..n).map(|i| a[i * n + i].abs()).sum::<f64>() / n as f64;
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for col in 0..n {
        let piv =
            (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[piv * n + col].abs() <= RELATIVE_PIVOT_MIN * scale {
            return None;
        }
        if piv != col {
            for k in 0..n {
                a.swap(piv * n + k, col * n + k);
            }
            b.swap(piv, col);
        }
        for row in col + 1..n {
            let f = a[row * n + col] / a[col * n + col];
            if f != 0.0 {
                for k in col..n {
                    a[row * n + k] -= f * a[col * n + k];
                }
                b[row] -= f * b[col];
            }
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row * n + k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row * n + row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Placement of `ab -> c` under the attribute quadric: `(position, cost, shape measure eps0)`.
/// `None` when the boundary rule admits no site.
pub(crate) fn place(store: &Store, a: u64, b: u64, weights: &[f64]) -> Option<(DVec3, f64, f64)> {
    let (va, vb) = (store.vertex(a)?, store.vertex(b)?);
    // The attribute quadric has no boundary term: its boundary stays exact (`Simplifier::new`).
    let sites = topology::sites(store, a, b, None)?;
    let n = 3 + weights.len();
    let quadric = |v| store.extra(v).and_then(|e| e.attr_quadric.as_deref());
    let q = match (quadric(a), quadric(b)) {
        (Some(x), Some(y)) => x.sum(y),
        (Some(x), None) | (None, Some(x)) => x.clone(),
        (None, None) => AttrQuadric::zero(n),
    };
    let (pos, cost) = crate::cost::place(
        sites,
        (store.pos(a), store.pos(b)),
        || q.minimizer().map(|v| DVec3::new(v[0], v[1], v[2])),
        |p| q.cost_at(p).unwrap_or(f64::INFINITY),
    )?;
    let h = va.quadric + vb.quadric;
    let w = va.area + vb.area;
    let shape = if w > 0.0 {
        (h.eval(pos).max(0.0) / w).sqrt()
    } else {
        0.0
    };
    Some((pos, cost, shape))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corner(x: DVec3, f: f32) -> (DVec3, Box<[f32]>) {
        (x, vec![f].into_boxed_slice())
    }

    #[test]
    fn a_triangle_quadric_vanishes_on_its_plane_and_grows_off_it() {
        let f = |x: DVec3| (2.0 * x.x - x.y + 0.5) as f32;
        let ps = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let c = ps.map(|p| corner(p, f(p)));
        let q = AttrQuadric::triangle(c.each_ref().map(|(x, a)| (*x, &a[..])), &[1.0]).unwrap();
        let x = DVec3::new(0.3, 0.2, 0.0);
        let s = q.scaled_attributes_at(x).unwrap();
        assert!((s[0] - f64::from(f(x))).abs() < 1e-6);
        assert!(q.cost_at(x).unwrap() < 1e-12);
        assert!(q.eval(&[0.3, 0.2, 0.0, 5.0]) > 1.0);
        assert!(q.eval(&[0.3, 0.2, 1.0, f64::from(f(x))]) > 0.1);
    }

    #[test]
    fn solve_solves_and_refuses_singular_systems() {
        let x = solve(vec![2.0, 1.0, 1.0, 3.0], vec![3.0, 5.0], 2).unwrap();
        assert!((x[0] - 0.8).abs() < 1e-12 && (x[1] - 1.4).abs() < 1e-12);
        assert!(solve(vec![1.0, 2.0, 2.0, 4.0], vec![1.0, 2.0], 2).is_none());
    }
}
