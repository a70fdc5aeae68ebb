//! Cost and placement of one contraction `ab -> c`: the policy hook of the decimation loop.
//!
//! Every objective has the same shape: build a quadric `M` to minimise, pick `c` among the sites
//! the boundary rule admits ([`topology::sites`]), rank the edge by a function of `M(c)`, and
//! optionally refuse the edge (threshold policies). New objectives (data-dependent priority,
//! attribute-aware quadrics) are new variants here; the loop in `decimate` does not change.

use glam::DVec3;

use crate::priority::Priority;
use crate::quadric::Quadric;
use crate::store::Store;
use crate::topology::{self, Boundary, Domain, Sites};
use crate::{attribute_quadric, data_dependent};

/// An optimal placement farther than this many edge lengths from the edge midpoint is treated
/// like an ill-conditioned one: nearly flat neighbourhoods put the exact minimum far away.
const FAR_FACTOR: f64 = 4.0;

/// Priority of an edge between coincident vertices (marching cubes makes them when a voxel value
/// equals the iso value). Merging them changes no geometry, so they go before every other edge
/// (costs are never negative), and the rate policy contracts them even past its target so that
/// their zero-area triangles do not reach the output.
pub(crate) const COINCIDENT: f64 = -1.0;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) enum Objective {
    /// Garland and Heckbert: `M = Q_a + Q_b` (area-weighted plane quadrics), cost `M(c)`.
    Quadric,
    /// Tandem (seed 000, section 3): priority
    /// `eps_alpha(c) = sqrt(c^T [(1 - alpha) H_c / W_c + alpha G_c / W] c)`, placement at its
    /// minimum, and only edges with shape measure `eps0(c) = sqrt(c^T H_c c / W_c) <= e0`
    /// (multiplicity version `H_c = H_a + H_b`, `W_c = W_a + W_b`).
    Shape { e0: f64, alpha: f64 },
}

/// The outcome of evaluating a contraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Eval {
    pub(crate) pos: DVec3,
    /// Heap priority (lower first).
    pub(crate) cost: f64,
    /// `eps0(c)`, reported in the statistics for every objective.
    pub(crate) shape_error: f64,
    /// `reach(c)` of the Tandem time-lag, in ranks.
    pub(crate) reach: f64,
}

/// `p` rounded to the `f32` coordinates every output format stores. Positions are rounded where
/// they are made (input vertices and placements), so the flip, intersection and error checks
/// judge exactly the coordinates that are written: a placement 1e-4 voxel from a neighbour
/// (marching cubes near iso-valued corners) passed the checks in `f64` and crossed it after
/// rounding (19 crossing triangles in simplified bonsai).
pub(crate) fn output_precision(p: DVec3) -> DVec3 {
    p.as_vec3().as_dvec3()
}

/// The placement of `ab -> c` and its cost, for every priority: among the sites the boundary
/// rule admits, the minimiser of the quadric when both endpoints are free (unless it is
/// ill-conditioned, `None`, or farther than `FAR_FACTOR` edge lengths from the midpoint: then
/// the cheapest of the endpoints and the midpoint); coincident endpoints stay where they are.
/// Every candidate is rounded by [`output_precision`] before it is costed, so the cost and every
/// later check judge the coordinates that are written.
pub(crate) fn place(
    sites: Sites,
    (pa, pb): (DVec3, DVec3),
    minimizer: impl FnOnce() -> Option<DVec3>,
    cost: impl Fn(DVec3) -> f64,
) -> Option<(DVec3, f64)> {
    let mid = 0.5 * (pa + pb);
    // The first of the cheapest, over a slice of the length each case needs.
    let cheapest = |sites: &[Option<DVec3>]| {
        sites
            .iter()
            .flatten()
            .map(|&p| {
                let p = output_precision(p);
                (p, cost(p))
            })
            .min_by(|x, y| x.1.total_cmp(&y.1))
    };
    match sites {
        // Coincident vertices (marching cubes at value == iso): nothing to optimise.
        Sites::Free if pa == pb => cheapest(&[Some(pa)]),
        Sites::Free => {
            match minimizer().filter(|x| (*x - mid).length() <= FAR_FACTOR * (pa - pb).length()) {
                Some(x) => cheapest(&[Some(x)]),
                None => cheapest(&[Some(pa), Some(pb), Some(mid)]),
            }
        }
        Sites::Fixed(fixed) => cheapest(&fixed),
    }
}

/// The one contraction evaluator every candidate goes through: the mode's [`Objective`], then
/// the data-aware [`Priority`] re-ranking it (data-dependent weights) or re-placing it
/// (attribute quadric), under the boundary rule. Built once from the configuration; the
/// contraction loop, the queue and the checks never ask which priority runs.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Evaluator {
    objective: Objective,
    priority: Priority,
    /// The box whose faces a planar boundary is simplified within (`topology::sites`); `None`
    /// for an exact boundary.
    faces: Option<Domain>,
    /// Physical length of one rank, for the time-lag's patch radius (`Eval::reach`, and the
    /// merged vertex's in `contract`).
    pub(crate) rank_spacing: f64,
}

impl Evaluator {
    pub(crate) fn new(
        objective: Objective,
        priority: Priority,
        (boundary, domain): (Boundary, Option<Domain>),
        rank_spacing: f64,
    ) -> Self {
        Self {
            objective,
            priority,
            faces: domain.filter(|_| boundary.is_planar()),
            rank_spacing,
        }
    }

    /// Cost and placement of `ab -> c`; `None` when the edge is no candidate (no admissible
    /// site, above the error threshold, or no attribute placement within it).
    pub(crate) fn evaluate(&self, store: &Store, a: u64, b: u64) -> Option<Eval> {
        let mut eval =
            self.objective
                .evaluate(store, (a, b), self.faces.as_ref(), self.rank_spacing)?;
        if eval.cost == COINCIDENT {
            return Some(eval);
        }
        match &self.priority {
            Priority::Geometric => {}
            Priority::DataDependent { lambda } => {
                eval.cost = data_dependent::weight(store, a, *lambda)
                    + data_dependent::weight(store, b, *lambda);
            }
            Priority::AttributeQuadric { weights } => {
                let e0 = match self.objective {
                    Objective::Shape { e0, .. } => e0,
                    Objective::Quadric => f64::INFINITY,
                };
                let (pos, cost, shape) = attribute_quadric::place(store, a, b, weights)?;
                if shape > e0 {
                    return None;
                }
                eval.pos = pos;
                // The quadric's tie-break: on a plane with an even attribute every contraction
                // costs nothing here too (a 120 x 120 plane: 4,615 guard pairs a query without).
                let w = store.vertex(a)?.area + store.vertex(b)?.area;
                eval.cost = cost + TIE_BREAK * w * (store.pos(a) - store.pos(b)).length_squared();
                eval.shape_error = shape;
            }
        }
        Some(eval)
    }
}

impl Objective {
    /// `None` when the edge is no candidate: no admissible site under the boundary rule, or
    /// above the error threshold.
    pub(crate) fn evaluate(
        &self,
        store: &Store,
        (a, b): (u64, u64),
        faces: Option<&Domain>,
        rank_spacing: f64,
    ) -> Option<Eval> {
        let (va, vb) = (store.vertex(a)?, store.vertex(b)?);
        let sites = topology::sites(store, a, b, faces)?;
        let h = va.quadric + vb.quadric;
        let w = va.area + vb.area;
        let isotropic = self.isotropy_metric(store, a, b, h, w);
        let m = isotropic.unwrap_or(h);
        let (pos, value) = place(
            sites,
            (store.pos(a), store.pos(b)),
            || m.minimizer(),
            |p| m.eval(p).max(0.0),
        )?;
        let (pa, pb) = (store.pos(a), store.pos(b));
        // Without isotropy the metric is `H_c` itself and `value` is `H_c(pos)` clamped: the
        // shape measure and the cost come from it (the same bits as evaluating `H_c` again, two
        // quadric evaluations a candidate fewer).
        let shape_error = match isotropic {
            None => root_per_area(value, w),
            Some(_) => shape_measure(&h, w, pos),
        };
        let cost = match *self {
            Objective::Shape { e0, .. } if shape_error > e0 => return None,
            _ if pa == pb => COINCIDENT,
            Objective::Quadric => value + TIE_BREAK * w * (pa - pb).length_squared(),
            Objective::Shape { .. } => {
                let measure = isotropic.map_or(shape_error, |m| shape_measure(&m, w, pos));
                // The same tie-break under the root: the measure is `sqrt(H_c(c) / W_c)`.
                (measure * measure + TIE_BREAK * (pa - pb).length_squared()).sqrt()
            }
        };
        // Only the time-lag reads the reach, and only it keeps the patches' heights and radii.
        let (height, rad) = match (store.extra(a), store.extra(b)) {
            (Some(ea), Some(eb)) => ea.merged_patch(eb, (pa - pb).length(), rank_spacing),
            _ => (0.0, 0.0),
        };
        Some(Eval {
            pos,
            cost,
            shape_error,
            reach: height + rad,
        })
    }

    /// The quadric to minimise when mesh isotropy weighs in (`alpha > 0`), scaled by `W_c`;
    /// `None` when it is `H_c` itself, so that the placement is bit for bit the plain
    /// shape-measure (and Garland-Heckbert) placement.
    fn isotropy_metric(
        &self,
        store: &Store,
        a: u64,
        b: u64,
        h: Quadric,
        w: f64,
    ) -> Option<Quadric> {
        match *self {
            Objective::Shape { e0, alpha } if alpha > 0.0 => {
                let (g, area) = isotropy_quadric(store, a, b);
                // W = 3 area(S_ab) W_c^(1/2) / E0 (seed 000, section 3, "Mesh isotropy").
                let norm = 3.0 * area * w.sqrt() / e0;
                (norm > 0.0).then(|| h.scaled(1.0 - alpha) + g.scaled(alpha * w / norm))
            }
            _ => None,
        }
    }
}

/// Share of `W_c |a - b|^2` added to a quadric cost (both are area times squared length, so the
/// share has no unit): far below the difference of most real costs, it decides where many
/// contractions cost (almost) nothing, a planar region or a straight tube's sides: there the
/// shortest edges go first. Without it their order was the queue's, and a 12 x 12 x 600 voxel
/// tube along z came out as slivers spanning up to its whole length, 1,344 of them across one
/// height: every guard query along the tube met them (15,600 fan/record pairs a query, 4.6 s;
/// 2,100 voxels long: 241 s and 176 MiB; a plane across a 300 x 300 x 16 volume: 96 s). With
/// 1e-6 on the 300-voxel tube: 118 across one height (1e-9: 598; 1e-4: 56), 121 pairs a query;
/// the 2,100-voxel tube 0.9 s and 37 MiB, the plane 0.44 s. On the real volumes, RMS distance
/// against none at R = 0.2 within 0.3 % (1e-4: +2.4 % on engine, -5 % on mni152), at R = 0.01
/// -7 % to +2.8 % (1e-4: up to +17 %), the spread any change of contraction order gives there
/// (docs/performance.md, "Fifty-second session"). The shape measure of modes `error` and
/// `classical` gets the same share under its root, `sqrt(eps0^2 + 1e-6 |a - b|^2)`: `classical`
/// took a plane across a 300 x 300 x 16 volume to 2 faces in 73 s, now 0.68 s. The attribute
/// quadric's cost gets it as the quadric does.
const TIE_BREAK: f64 = 1e-6;

/// `sqrt(q(c) / W)`, 0 for a patch without area.
fn shape_measure(q: &Quadric, w: f64, c: DVec3) -> f64 {
    root_per_area(q.eval(c).max(0.0), w)
}

/// `sqrt(value / W)`, 0 for a patch without area.
fn root_per_area(value: f64, w: f64) -> f64 {
    if w > 0.0 { (value / w).sqrt() } else { 0.0 }
}

/// `G_c = sum_{t in T_ab} w_t G_t`, `G_t(x) = |x - centroid(t)|^2 + avg(t)`,
/// `avg(t) = (|p|^2 + |q|^2 + |r|^2) / 12` with `p, q, r` relative to the centroid
/// (seed 000, section 3 and appendix A), and `area(S_ab)`.
fn isotropy_quadric(store: &Store, a: u64, b: u64) -> (Quadric, f64) {
    let mut g = Quadric::default();
    let mut area = 0.0;
    for pt in &topology::Patch::gather(store, a, b).tris {
        let p = pt.p;
        let w = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
        let centroid = (p[0] + p[1] + p[2]) / 3.0;
        let avg = p
            .iter()
            .map(|x| (*x - centroid).length_squared())
            .sum::<f64>()
            / 12.0;
        g += Quadric::point(centroid, avg, w);
        area += w;
    }
    (g, area)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{Tri, Vertex};

    /// A bumpy closed surface's worth of interior vertices: a 6x6 grid with heights, all fans
    /// complete, quadrics accumulated as the simplifier does.
    fn bumpy() -> Store {
        let mut s = Store::keeping_extras();
        let n = 6u64;
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (i as f64, j as f64);
                let z = 0.3 * (1.3 * x).sin() * (0.7 * y).cos() + 0.05 * x * y;
                s.insert_vertex(j * n + i, DVec3::new(x, y, z), Vertex::new(j as u32), &[]);
            }
        }
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let v = j * n + i;
                for t in [[v, v + 1, v + n + 1], [v, v + n + 1, v + n]] {
                    let p = t.map(|id| s.pos(id));
                    let cross = (p[1] - p[0]).cross(p[2] - p[0]);
                    let normal = cross.normalize();
                    let q = Quadric::plane(normal, -normal.dot(p[0]), 0.5 * cross.length());
                    for id in t {
                        let x = s.vertex_mut(id).unwrap();
                        x.quadric += q;
                        x.area += 0.5 * cross.length();
                    }
                    s.add_triangle(Tri {
                        v: t,
                        unmodifiable: 0,
                    });
                }
            }
        }
        s
    }

    /// Edges whose endpoints are both interior (free placement).
    fn interior_edges(s: &Store) -> Vec<(u64, u64)> {
        let interior = |v: u64| topology::ring(s, v).iter().all(|&(_, n)| n == 2);
        let mut edges = Vec::new();
        for a in s.ids().filter(|&a| interior(a)) {
            for (b, _) in topology::ring(s, a) {
                if a < b && interior(b) {
                    edges.push((a, b));
                }
            }
        }
        edges
    }

    #[test]
    fn zero_isotropy_is_the_plain_shape_measure_placement_bit_for_bit() {
        let s = bumpy();
        let plain = Objective::Shape {
            e0: f64::INFINITY,
            alpha: 0.0,
        };
        let mut compared = 0;
        for (a, b) in interior_edges(&s) {
            let gh = Objective::Quadric.evaluate(&s, (a, b), None, 1.0).unwrap();
            let e = plain.evaluate(&s, (a, b), None, 1.0).unwrap();
            assert_eq!(e.pos, gh.pos, "edge {a}-{b}");
            let w = s.vertex(a).unwrap().area + s.vertex(b).unwrap().area;
            let tie = TIE_BREAK * (s.pos(a) - s.pos(b)).length_squared();
            assert_eq!(e.cost, (e.shape_error * e.shape_error + tie).sqrt());
            assert!((e.cost * e.cost * w - gh.cost).abs() <= 1e-9 * (1.0 + gh.cost));
            compared += 1;
        }
        assert!(compared > 20, "{compared}");
    }

    #[test]
    fn isotropy_pulls_the_placement_towards_the_patch_centroid() {
        let s = bumpy();
        let (a, b) = (14, 15);
        let eps = |alpha| {
            Objective::Shape { e0: 1.0, alpha }
                .evaluate(&s, (a, b), None, 1.0)
                .unwrap()
        };
        let centroid: DVec3 = {
            let (mut sum, mut area) = (DVec3::ZERO, 0.0);
            for pt in &topology::Patch::gather(&s, a, b).tris {
                let p = pt.p;
                let w = (p[1] - p[0]).cross(p[2] - p[0]).length();
                sum += w * (p[0] + p[1] + p[2]) / 3.0;
                area += w;
            }
            sum / area
        };
        let (p0, p1) = (eps(0.0).pos, eps(1.0).pos);
        assert!(
            (p1 - output_precision(centroid)).length() < 1e-9,
            "alpha = 1 minimises g: the centroid (rounded to f32)"
        );
        assert!((p0 - centroid).length() > (eps(0.5).pos - centroid).length());
    }

    #[test]
    fn threshold_refuses_and_reach_follows_the_time_lag_formula() {
        let s = bumpy();
        let (a, b) = (14, 15);
        let tight = Objective::Shape {
            e0: 1e-12,
            alpha: 0.0,
        };
        assert!(tight.evaluate(&s, (a, b), None, 1.0).is_none());
        let e = Objective::Quadric.evaluate(&s, (a, b), None, 2.0).unwrap();
        // heights 2 and 2 (rank = row), rads 1: reach = 2 + (|a - b| / 2 + 2) / 2.
        let len = (s.pos(a) - s.pos(b)).length();
        assert!((e.reach - (2.0 + (len / 2.0 + 2.0) / 2.0)).abs() < 1e-12);
    }

    /// Every priority places through `place`, and whatever the minimiser says, the chosen site
    /// is an `f32` point (the attribute quadric's placement used to skip the rounding).
    #[test]
    fn placements_are_rounded_and_the_cheapest_site_wins() {
        let (pa, pb) = (DVec3::new(0.1, 0.2, 0.3), DVec3::new(1.1, 0.2, 0.3));
        let odd = DVec3::new(0.123_456_789_012_3, 0.2, 0.3);
        let (p, _) = place(Sites::Free, (pa, pb), || Some(odd), |_| 0.0).unwrap();
        assert_eq!(p, output_precision(p));
        assert_ne!(p, odd);
        // Far minimiser: the best of the endpoints and the midpoint.
        let far = DVec3::splat(100.0);
        let (p, c) = place(Sites::Free, (pa, pb), || Some(far), |x| (x - pb).length()).unwrap();
        assert_eq!(
            (p, c),
            (output_precision(pb), (output_precision(pb) - pb).length())
        );
        // Coincident endpoints stay; the minimiser is not even asked.
        let (p, _) = place(Sites::Free, (pa, pa), || panic!("asked"), |_| 0.0).unwrap();
        assert_eq!(p, output_precision(pa));
        assert!(place(Sites::Fixed([None, None]), (pa, pb), || None, |_| 0.0).is_none());
    }
}
