//! Which edge goes first, and how vertex data merges: the data-aware priorities (issue 5).
//!
//! The mode ([`crate::Policy`]: rate, error, tandem time-lag) says how far to decimate; the
//! [`Priority`] says in which order and, for the attribute quadric, where. Both meet in the one
//! contraction evaluator, [`crate::cost::Evaluator`]; this module keeps what a contraction does
//! to the vertex data ([`merged_data`]). Every topology and geometry check stays
//! the same whatever the priority.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::attribute_quadric::AttrQuadric;
use crate::store::Store;
use crate::topology::Patch;
use crate::{SimplifyConfig, SimplifyError};

/// Order (and for the attribute quadric, placement) of contractions.
#[derive(Debug, Clone, PartialEq, Default, Deserialize, Serialize)]
pub enum Priority {
    /// The mode's own objective (Garland-Heckbert quadric error, or the Tandem measure).
    #[default]
    Geometric,
    /// Seed 001 (data-dependent reduction): vertex weight
    /// `lambda curv(v) + (1 - lambda) grad(v)`, `curv` the absolute angle deficit
    /// (`2 pi - total angle`, `pi - total angle` on the boundary) and `grad` the largest
    /// `|f_i - f|_1 / |x_i - x|_1` over the neighbours; an edge costs the sum of its endpoints'
    /// weights. The placement is the mode's objective's.
    DataDependent { lambda: f64 },
    /// Garland and Heckbert 1998 quadrics over position and attributes, attribute `j` scaled by
    /// `weights[j]`: placement and attributes minimise the summed squared distances to the
    /// triangles' planes in R^(3+m), the cost is that minimum.
    AttributeQuadric { weights: Vec<f64> },
}

impl Priority {
    pub(crate) fn validate(&self, attributes: usize) -> Result<(), SimplifyError> {
        let invalid = |why: String| Err(SimplifyError::InvalidPolicy(why));
        match self {
            Priority::Geometric => Ok(()),
            Priority::DataDependent { lambda } if !(0.0..=1.0).contains(lambda) => {
                invalid(format!("lambda must be in [0, 1], got {lambda}"))
            }
            Priority::DataDependent { .. } => Ok(()),
            Priority::AttributeQuadric { weights } if weights.len() != attributes => {
                invalid(format!(
                    "{} attribute weights for {attributes} attributes",
                    weights.len()
                ))
            }
            Priority::AttributeQuadric { weights }
                if weights.iter().any(|w| !(*w > 0.0 && w.is_finite())) =>
            {
                invalid("attribute weights must be positive and finite".into())
            }
            Priority::AttributeQuadric { .. } => Ok(()),
        }
    }
}

/// What a contraction gives the surviving vertex besides its position.
pub(crate) struct Merged {
    pub(crate) attrs: Box<[f32]>,
    pub(crate) attr_quadric: Option<Box<AttrQuadric>>,
}

/// Attributes (and attribute quadric) of the vertex replacing `gone` and `keep` at `pos`.
/// Called before the contraction changes the store.
pub(crate) fn merged_data(
    store: &Store,
    config: &SimplifyConfig,
    patch: &Patch,
    gone: u64,
    keep: u64,
    pos: DVec3,
) -> Merged {
    if store.vertex(gone).is_none() || store.vertex(keep).is_none() {
        return Merged {
            attrs: Box::default(),
            attr_quadric: None,
        };
    }
    let ends = [
        (store.pos(gone), store.attrs(gone)),
        (store.pos(keep), store.attrs(keep)),
    ];
    let quadric = |v| store.extra(v).and_then(|e| e.attr_quadric.as_deref());
    match (&config.priority, quadric(gone), quadric(keep)) {
        (Priority::AttributeQuadric { weights }, Some(qg), Some(qk)) => {
            let q = qg.sum(qk);
            let attrs = q
                .attributes_at(pos, weights)
                .map(|solved| within_patch(store, patch, [gone, keep], solved))
                .unwrap_or_else(|| interpolated(ends, pos));
            Merged {
                attrs,
                attr_quadric: Some(Box::new(q)),
            }
        }
        _ => Merged {
            attrs: interpolated_in_patch(store, config.attributes, patch, pos)
                .unwrap_or_else(|| interpolated(ends, pos)),
            attr_quadric: None,
        },
    }
}

/// Attributes at `c` by the barycentric weights of its projection in the patch triangle
/// (around `gone` and `keep`) that contains it best (the largest smallest coordinate;
/// clamped when `c` is outside them all). Exact for attributes linear in position on flat
/// patches, wherever the placement went (isotropy moves it off the edge). `None` when the
/// vertices carry no attributes or the patch has no proper triangle.
fn interpolated_in_patch(store: &Store, m: usize, patch: &Patch, c: DVec3) -> Option<Box<[f32]>> {
    if m == 0 {
        return None;
    }
    let mut best: Option<(f64, [u64; 3], [f64; 3])> = None;
    for pt in &patch.tris {
        let [p0, p1, p2] = pt.p;
        let (e1, e2, d) = (p1 - p0, p2 - p0, c - p0);
        let (a11, a12, a22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let det = a11 * a22 - a12 * a12;
        if det.is_nan() || det <= 1e-12 * a11 * a22 {
            continue;
        }
        let (b1, b2) = (d.dot(e1), d.dot(e2));
        let u = (a22 * b1 - a12 * b2) / det;
        let v = (a11 * b2 - a12 * b1) / det;
        let w = [1.0 - u - v, u, v];
        let score = w[0].min(w[1]).min(w[2]);
        if best.is_none_or(|(s, _, _)| score > s) {
            best = Some((score, pt.v, w));
        }
    }
    let (score, ids, mut w) = best?;
    if score < 0.0 {
        w = w.map(|x| x.max(0.0));
        let sum: f64 = w.iter().sum();
        w = w.map(|x| x / sum);
    }
    let corners = ids.map(|id| store.vertex(id).map(|_| store.attrs(id)));
    let mut out = vec![0.0f64; m];
    for (wi, v) in w.iter().zip(corners) {
        for (o, a) in out.iter_mut().zip(v?) {
            *o += wi * f64::from(*a);
        }
    }
    Some(out.into_iter().map(|x| x as f32).collect())
}

/// `solved` (the attribute quadric's values for the new vertex) clamped, attribute by
/// attribute, to the range its replaced patch (the triangles around `ends`) takes. The solve is
/// a least-squares fit that extrapolates wherever the attribute is not linear (steps, labels):
/// a trial's values 0..5 came out -0.90..6.71. Every value the clamp allows is one the current
/// surface holds, so by induction every output value lies within the input's range. The patch's
/// range rather than the two ends' keeps the solve's one exact case: a linear attribute on a
/// flat patch, at a placement off the edge (where the quadric puts it), has a value between the
/// patch's corners' but not always between the ends'. On a curved surface a placement bulges
/// past the patch's corners and the clamp costs a little of that exactness (a linear attribute
/// on a sphere: 0.019 on values spanning 10, against 0.092 clamped to the ends' values;
/// `tests/attributes.rs`).
fn within_patch(
    store: &Store,
    patch: &Patch,
    ends: [u64; 2],
    mut solved: Box<[f32]>,
) -> Box<[f32]> {
    let corners = patch.tris.iter().flat_map(|t| t.v).chain(ends);
    for (j, a) in solved.iter_mut().enumerate() {
        let (lo, hi) = corners
            .clone()
            .filter_map(|v| store.attrs(v).get(j).copied())
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            });
        if lo <= hi {
            *a = a.clamp(lo, hi);
        }
    }
    solved
}

/// Adds triangle `v`'s attribute quadric to its corners (attribute-quadric priority only).
pub(crate) fn add_attribute_quadric(store: &mut Store, priority: &Priority, v: [u64; 3]) {
    let Priority::AttributeQuadric { weights } = priority else {
        return;
    };
    // Borrowed from the store: the quadric is made before the store is written.
    let corners = v.map(|id| store.vertex(id).map(|_| (store.pos(id), store.attrs(id))));
    let [Some(p0), Some(p1), Some(p2)] = corners else {
        return;
    };
    let Some(q) = AttrQuadric::triangle([p0, p1, p2], weights) else {
        return;
    };
    for id in v {
        if let Some(x) = store.extra_mut(id) {
            match &mut x.attr_quadric {
                Some(acc) => acc.add(&q),
                None => x.attr_quadric = Some(Box::new(q.clone())),
            }
        }
    }
}

/// Attributes by linear interpolation along the edge, at the projection of `c` onto it: the
/// fallback when the patch has no proper triangle.
/// `ends` are the position and attributes of the vertex that goes, then of the one kept.
fn interpolated(ends: [(DVec3, &[f32]); 2], c: DVec3) -> Box<[f32]> {
    let [(gone, gone_attrs), (keep, keep_attrs)] = ends;
    let d = keep - gone;
    let len2 = d.length_squared();
    let t = if len2 > 0.0 {
        ((c - gone).dot(d) / len2).clamp(0.0, 1.0)
    } else {
        0.5
    };
    keep_attrs
        .iter()
        .zip(gone_attrs.iter())
        .map(|(k, g)| (f64::from(*g) + t * (f64::from(*k) - f64::from(*g))) as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn attributes_interpolate_at_the_projection_onto_the_edge() {
        let edge = [
            (DVec3::ZERO, &[0.0, 4.0][..]),
            (DVec3::new(2.0, 0.0, 0.0), &[10.0, 0.0][..]),
        ];
        assert_eq!(&*interpolated(edge, DVec3::new(0.5, 3.0, 0.0)), &[2.5, 3.0]);
        assert_eq!(
            &*interpolated(edge, DVec3::new(9.0, 0.0, 0.0)),
            &[10.0, 0.0]
        );
        let coincident = [(DVec3::ZERO, &[3.0][..]), (DVec3::ZERO, &[1.0][..])];
        assert_eq!(
            &*interpolated(coincident, DVec3::ZERO),
            &[2.0],
            "coincident: the mean"
        );
    }

    /// The solve's values are clamped to the patch's range, not the two ends': on a hexagonal
    /// fan around vertex 0 the ends of edge 0-1 hold 2 and 0, the patch 0..5.
    #[test]
    fn solved_attributes_are_clamped_to_the_patch_range() {
        use crate::store::{Tri, Vertex};
        let mut store = Store::keeping_extras();
        store.insert_vertex(0, DVec3::ZERO, Vertex::new(0), &[2.0, 10.0]);
        for (k, a) in [0.0, 1.0, 5.0, 3.0, 4.0, 2.0].into_iter().enumerate() {
            let t = k as f64 * std::f64::consts::PI / 3.0;
            let p = DVec3::new(t.cos(), t.sin(), 0.0);
            store.insert_vertex(1 + k as u64, p, Vertex::new(0), &[a, 10.0]);
        }
        for k in 0..6 {
            let v = [0, 1 + k, 1 + (k + 1) % 6];
            store.add_triangle(Tri { v, unmodifiable: 0 });
        }
        let patch = Patch::gather(&store, 0, 1);
        let clamp = |a: f32, b: f32| within_patch(&store, &patch, [0, 1], Box::new([a, b]));
        assert_eq!(&*clamp(7.0, 10.5), &[5.0, 10.0]);
        assert_eq!(&*clamp(-1.0, 9.0), &[0.0, 10.0]);
        assert_eq!(
            &*clamp(4.0, 10.0),
            &[4.0, 10.0],
            "past the ends, within the patch"
        );
    }

    #[test]
    fn priorities_are_validated() {
        assert!(Priority::DataDependent { lambda: 0.5 }.validate(0).is_ok());
        assert!(Priority::DataDependent { lambda: 1.5 }.validate(0).is_err());
        let w = |weights: Vec<f64>| Priority::AttributeQuadric { weights };
        assert!(w(vec![1.0]).validate(1).is_ok());
        assert!(w(vec![1.0]).validate(2).is_err());
        assert!(w(vec![0.0]).validate(1).is_err());
    }
}
