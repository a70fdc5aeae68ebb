//! The data-dependent vertex weight of seed 001 (section 2.2):
//! `weight(v) = lambda curv(v) + (1 - lambda) grad(v)`.
//!
//! * `curv(v)`: the absolute angle deficit, `|2 pi - sum of the angles at v|` inside and
//!   `|pi - sum|` on the boundary (0 on flat and straight-boundary vertices; the signed deficits
//!   of a closed surface add up to `2 pi chi`, Gauss-Bonnet).
//! * `grad(v) = max_i |f_i - f|_1 / |x_i - x|_1` over the neighbours `v_i` (equation 2), with
//!   the L1 norm over all attributes and over the coordinates; 0 without attributes.

use std::f64::consts::PI;

use crate::store::Store;
use crate::topology;

/// `2 pi - total angle` (interior) or `pi - total angle` (boundary), signed.
pub(crate) fn angle_deficit(store: &Store, v: u64) -> f64 {
    let Some(x) = store.vertex(v) else {
        return 0.0;
    };
    let mut total = 0.0;
    for &t in &x.tris {
        let tri = store.tri(t);
        let i = tri.v.iter().position(|&id| id == v).unwrap_or(0);
        let p = store.corners(tri);
        let (u, w) = (p[(i + 1) % 3] - p[i], p[(i + 2) % 3] - p[i]);
        if u.length_squared() > 0.0 && w.length_squared() > 0.0 {
            total += u.angle_between(w);
        }
    }
    let full = if topology::on_boundary(store, v) {
        PI
    } else {
        2.0 * PI
    };
    full - total
}

/// Equation 2 of seed 001: the steepest L1 attribute change per L1 distance to a neighbour.
pub(crate) fn gradient(store: &Store, v: u64) -> f64 {
    let x = store.attrs(v);
    if x.is_empty() {
        return 0.0;
    }
    let mut g: f64 = 0.0;
    for (n, _) in topology::ring(store, v) {
        if store.vertex(n).is_none() {
            continue;
        }
        let d = (store.pos(n) - store.pos(v)).abs().element_sum();
        if d <= 0.0 {
            continue;
        }
        let df: f64 = x
            .iter()
            .zip(store.attrs(n))
            .map(|(a, b)| (f64::from(*a) - f64::from(*b)).abs())
            .sum();
        g = g.max(df / d);
    }
    g
}

/// `lambda |deficit| + (1 - lambda) grad`. Both terms are computed once per vertex until a
/// contraction changes its star or a neighbour ([`forget`]): every evaluation of an edge asks
/// for both endpoints' weights, an edge is evaluated about eleven times per contraction, and
/// recomputing them (an `acos` per triangle, two rings) made this priority 7x slower than the
/// geometric one (half of that is left: the terms of the ring around each contraction).
pub(crate) fn weight(store: &Store, v: u64, lambda: f64) -> f64 {
    let Some(cell) = store.extra(v).map(|x| &x.weight_terms) else {
        return 0.0;
    };
    let [mut curv, mut grad] = cell.get();
    if lambda > 0.0 && curv.is_nan() {
        curv = angle_deficit(store, v).abs();
    }
    if lambda < 1.0 && grad.is_nan() {
        grad = gradient(store, v);
    }
    cell.set([curv, grad]);
    let term = |w: f64, x: f64| if w > 0.0 { w * x } else { 0.0 };
    term(lambda, curv) + term(1.0 - lambda, grad)
}

/// The weights of `keep` and its neighbours `ring` are to be computed again: a contraction
/// into `keep` moved it and changed their stars (a weight reads a vertex's star and its
/// neighbours' positions and attributes, all within that set).
pub(crate) fn forget(store: &Store, keep: u64, ring: &topology::Ring) {
    for v in std::iter::once(keep).chain(ring.iter().map(|&(n, _)| n)) {
        if let Some(x) = store.extra(v) {
            x.weight_terms.set([f64::NAN; 2]);
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::store::{Tri, Vertex};

    fn mesh(pos: &[DVec3], attrs: &[f32], tris: &[[u64; 3]]) -> Store {
        let mut s = Store::keeping_extras();
        for (i, p) in pos.iter().enumerate() {
            let a = attrs.get(i).map(std::slice::from_ref).unwrap_or(&[]);
            s.insert_vertex(i as u64, *p, Vertex::new(0), a);
        }
        for t in tris {
            s.add_triangle(Tri {
                v: *t,
                unmodifiable: 0,
            });
        }
        s
    }

    /// A flat hexagonal fan (centre 0), optionally with the centre lifted.
    fn fan(lift: f64, attrs: &[f32]) -> Store {
        let mut pos = vec![DVec3::new(0.0, 0.0, lift)];
        for k in 0..6 {
            let a = f64::from(k) * PI / 3.0;
            pos.push(DVec3::new(a.cos(), a.sin(), 0.0));
        }
        let tris: Vec<[u64; 3]> = (0..6).map(|k| [0, 1 + k, 1 + (k + 1) % 6]).collect();
        mesh(&pos, attrs, &tris)
    }

    #[test]
    fn flat_interior_vertices_have_no_deficit() {
        let s = fan(0.0, &[]);
        // Within the f32 rounding of the positions, as every position in the store.
        assert!(angle_deficit(&s, 0).abs() < 1e-6);
        // Rim vertices are boundary vertices with two 60 degree angles: pi - 2 pi / 3.
        assert!((angle_deficit(&s, 1) - PI / 3.0).abs() < 1e-6);
        assert!(angle_deficit(&fan(0.5, &[]), 0) > 0.1, "a cone tip");
    }

    #[test]
    fn deficits_of_a_closed_genus_0_surface_add_up_to_4_pi() {
        // An octahedron, and a cube split into triangles.
        let o = [
            DVec3::X,
            DVec3::NEG_X,
            DVec3::Y,
            DVec3::NEG_Y,
            DVec3::Z,
            DVec3::NEG_Z,
        ];
        let tris = [
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        let s = mesh(&o, &[], &tris);
        let total: f64 = (0..6).map(|v| angle_deficit(&s, v)).sum();
        assert!((total - 4.0 * PI).abs() < 1e-9, "{total}");
    }

    #[test]
    fn gradient_is_the_steepest_l1_slope() {
        // f = 3x on the flat fan: neighbours at (1, 0) give 3 / 1, at (1/2, sqrt3/2) 1.5 / 1.37.
        let mut attrs = vec![0.0f32];
        for k in 0..6 {
            attrs.push(3.0 * (f64::from(k) * PI / 3.0).cos() as f32);
        }
        let s = fan(0.0, &attrs);
        assert!((gradient(&s, 0) - 3.0).abs() < 1e-6);
        assert_eq!(gradient(&fan(0.0, &[]), 0), 0.0);
        assert!((weight(&s, 0, 0.0) - 3.0).abs() < 1e-6);
        assert!(weight(&s, 0, 1.0).abs() < 1e-9);
    }
}
