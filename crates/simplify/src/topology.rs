//! Checks that keep every contraction a valid manifold operation.
//!
//! * [`link_ok`]: the link condition of Dey, Edelsbrunner, Guha and Nekhayev,
//!   `Lk(a) ∩ Lk(b) = Lk(ab)`, on vertices *and* edges of the links, with the usual dummy vertex
//!   `ω` joined to every boundary edge so that surfaces with boundary are covered too.
//! * [`geometry_ok`]: no surviving triangle flips or becomes degenerate.
//! * [`sites`]: where the new vertex may go without changing the surface boundary.
//!
//! Only the fans of `a` and `b` are read. Both endpoints of a candidate are modifiable, so their
//! fans are complete even when some neighbours are not (yet).

use glam::DVec3;
use smallvec::SmallVec;

use crate::store::{Store, TriId};

/// A surviving triangle must keep `cos(angle(n_old, n_new)) > MIN_NORMAL_COS` (about 84 degrees).
const MIN_NORMAL_COS: f64 = 0.1;
/// A triangle is degenerate when `|cross|` is below this fraction of the largest `|cross|` in the
/// fans of `a` and `b`.
const DEGENERATE_FRACTION: f64 = 1e-6;
/// A triangle is collinear (zero area to any viewer: `isostream measure` and the referee in
/// `isostream-meshcheck` count `|cross| <= 1e-12 longest^2`) when `|cross|` is at most this
/// fraction of its longest edge squared; a little above the referee's bound so that what passes
/// here passes there.
const COLLINEAR_FRACTION: f64 = 1e-10;
/// The referee's zero-area bound (`isostream-meshcheck`): `|cross|` at most this fraction of
/// the longest edge squared.
const ZERO_AREA_FRACTION: f64 = 1e-12;
/// A boundary vertex lies on a straight boundary when the sine of its turning angle is below this.
const STRAIGHT_SINE: f64 = 1e-6;

/// Fans of at most this many triangles count their ring by linear search (see [`ring`]): a
/// marching-cubes vertex has about six, but a vertex of a coarse surface at a low rate may have
/// dozens, and searching those was quadratic (a third of a second stage's instructions at
/// R = 0.01).
const SMALL_FAN: usize = 8;

/// Neighbours with edge multiplicities, inline for the usual small degrees.
pub(crate) type Ring = SmallVec<[(u64, u8); 16]>;

/// Neighbours of `v` with the number of `v`'s triangles on edge `v-x` (1: boundary edge),
/// sorted by id.
pub(crate) fn ring(store: &Store, v: u64) -> Ring {
    let mut ring = Ring::new();
    let Some(vx) = store.vertex(v) else {
        return ring;
    };
    if vx.tris.len() <= SMALL_FAN {
        // Counted in place: for a small fan a linear search beats sorting the twice-as-long
        // list of corners first.
        for &t in &vx.tris {
            for x in store.tri(t).v {
                if x != v {
                    count(&mut ring, x);
                }
            }
        }
        ring.sort_unstable_by_key(|&(x, _)| x);
        return ring;
    }
    let mut all: SmallVec<[u64; 32]> = SmallVec::with_capacity(2 * vx.tris.len());
    for &t in &vx.tris {
        for x in store.tri(t).v {
            if x != v {
                all.push(x);
            }
        }
    }
    all.sort_unstable();
    for x in all {
        match ring.last_mut() {
            Some((y, n)) if *y == x => *n = n.saturating_add(1),
            _ => ring.push((x, 1)),
        }
    }
    ring
}

/// One more triangle of the fan on the edge to `x`: `x`'s count in `ring` up by one (a linear
/// search: fans are small, see [`SMALL_FAN`]).
#[inline]
fn count(ring: &mut Ring, x: u64) {
    match ring.iter_mut().find(|(y, _)| *y == x) {
        Some((_, n)) => *n = n.saturating_add(1),
        None => ring.push((x, 1)),
    }
}

fn boundary_neighbours(ring: &[(u64, u8)]) -> impl Iterator<Item = u64> + '_ {
    ring.iter().filter(|&&(_, n)| n == 1).map(|&(x, _)| x)
}

pub(crate) fn is_boundary(ring: &[(u64, u8)]) -> bool {
    boundary_neighbours(ring).next().is_some()
}

/// Whether `v` has an edge with a single triangle (meaningful once its fan is complete).
pub(crate) fn on_boundary(store: &Store, v: u64) -> bool {
    is_boundary(&ring(store, v))
}

/// The link condition for contracting edge `ab` (Dey, Edelsbrunner, Guha, Nekhayev 1999).
///
/// * vertices: the common neighbours of `a` and `b` are exactly the vertices opposite `ab`;
/// * `ω`: an interior edge whose endpoints both lie on the boundary is rejected (`ω` would be a
///   common neighbour not in `Lk(ab)`); for a boundary edge, an opposite vertex `x` with `ax` and
///   `bx` both on the boundary is rejected (edge `ωx` in both links), so a lone triangle or a
///   boundary ear never disappears;
/// * edges: no edge `xy` of both links, i.e. not both triangles `axy` and `bxy`. With the vertex
///   rule `x` and `y` are the two opposite vertices. This is what stops a tetrahedron (and every
///   closed component, which can only shrink to one) from collapsing: a component is never
///   reduced below 4 triangles.
///
/// Read from `patch`, the patch of `a` and `b` ([`Patch::gather_into`]): its triangles are the
/// two fans, each triangle once, which is all the rule reads, and the decimator has gathered it
/// already. Built from the store (both rings, the edge's triangles and the edge test each
/// walking the fans and their triangle slots again) the test cost 2.55 k instructions a call,
/// read from the patch 2.14 k: bonsai at R = 0.2 by callgrind, the same decisions.
pub(crate) fn link_ok(patch: &Patch, a: u64, b: u64) -> bool {
    // The rings of `a` and `b` as `ring` gives them, unsorted: neighbours with the number of the
    // vertex's triangles on each edge (1: a boundary edge).
    let mut ra: Ring = Ring::new();
    let mut rb: Ring = Ring::new();
    let mut opposite: SmallVec<[u64; 2]> = SmallVec::new();
    for t in &patch.tris {
        let (has_a, has_b) = (t.v.contains(&a), t.v.contains(&b));
        if has_a && has_b {
            if opposite.len() == 2 {
                return false;
            }
            opposite.push(third(t.v, a, b));
        }
        for &x in &t.v {
            if has_a && x != a {
                count(&mut ra, x);
            }
            if has_b && x != b {
                count(&mut rb, x);
            }
        }
    }
    if opposite.is_empty() {
        return false;
    }
    opposite.sort_unstable();
    let mut common: SmallVec<[(u64, u8, u8); 8]> = ra
        .iter()
        .filter_map(|&(x, na)| {
            let &(_, nb) = rb.iter().find(|(y, _)| *y == x)?;
            Some((x, na, nb))
        })
        .collect();
    common.sort_unstable_by_key(|&(x, _, _)| x);
    if !common
        .iter()
        .map(|&(x, _, _)| x)
        .eq(opposite.iter().copied())
    {
        return false;
    }
    if opposite.len() == 2 {
        if is_boundary(&ra) && is_boundary(&rb) {
            return false;
        }
        let (x, y) = (opposite[0], opposite[1]);
        let has_triangle_with = |v: u64| {
            patch
                .tris
                .iter()
                .any(|t| t.v.contains(&v) && t.v.contains(&x) && t.v.contains(&y))
        };
        if has_triangle_with(a) && has_triangle_with(b) {
            return false;
        }
    } else if common.iter().any(|&(_, na, nb)| na == 1 && nb == 1) {
        return false;
    }
    true
}

/// The corner of `v` that is neither `a` nor `b`.
fn third(v: [u64; 3], a: u64, b: u64) -> u64 {
    v.into_iter().find(|&x| x != a && x != b).unwrap_or(a)
}

/// Where the vertex replacing `a` and `b` may be placed. This is the boundary rule:
///
/// * both endpoints interior: anywhere ([`Sites::Free`]);
/// * one endpoint on the surface boundary: exactly at that endpoint, so the boundary does not
///   move;
/// * both on the boundary: only along a boundary edge, into one endpoint's position, and only if
///   the removed endpoint lies on a straight piece of boundary (its two boundary neighbours and
///   itself collinear within `STRAIGHT_SINE`, or it coincides with the kept one), or, with
///   [`Boundary::Planar`] (`faces`: the box), on one face of the volume's box with both (see
///   [`Boundary`]). With
///   [`Boundary::Exact`] the boundary polyline therefore keeps its exact shape. Closed surfaces
///   have no boundary and are not restricted at all.
///
/// `None`: no admissible position.
pub(crate) fn sites(store: &Store, a: u64, b: u64, faces: Option<&Domain>) -> Option<Sites> {
    let (va, vb) = (store.vertex(a)?, store.vertex(b)?);
    let (pa, pb) = (store.pos(a), store.pos(b));
    match (va.boundary, vb.boundary) {
        (false, false) => Some(Sites::Free),
        (true, false) => Some(Sites::Fixed([Some(pa), None])),
        (false, true) => Some(Sites::Fixed([Some(pb), None])),
        (true, true) => {
            let (ra, rb) = (ring(store, a), ring(store, b));
            let boundary_edge = ra.iter().any(|&(x, n)| x == b && n == 1);
            if !boundary_edge {
                return None;
            }
            let keep_a = removable_onto(store, &rb, pb, pa, faces).then_some(pa);
            let keep_b = removable_onto(store, &ra, pa, pb, faces).then_some(pb);
            (keep_a.is_some() || keep_b.is_some()).then_some(Sites::Fixed([keep_a, keep_b]))
        }
    }
}

/// Whether boundary vertex `r` (at `pr`, with ring `ring`) can be merged into its boundary
/// neighbour at `pk`: without changing the boundary polyline, or keeping it in the face of the
/// box `faces` (planar boundaries) it runs on there.
fn removable_onto(
    store: &Store,
    ring: &[(u64, u8)],
    pr: DVec3,
    pk: DVec3,
    faces: Option<&Domain>,
) -> bool {
    if pr == pk {
        return true;
    }
    let bn: SmallVec<[u64; 4]> = boundary_neighbours(ring).collect();
    if bn.len() != 2 {
        return false;
    }
    let Some(po) = bn
        .iter()
        .filter_map(|&x| store.position(x))
        .find(|&p| p != pk)
    else {
        return false;
    };
    if faces.is_some_and(|d| d.on_one_face([pr, po, pk])) {
        return true;
    }
    let (to_r, to_k) = (pr - po, pk - pr);
    to_r.dot(to_k) >= 0.0
        && to_r.cross(to_k).length() <= STRAIGHT_SINE * to_r.length() * to_k.length()
}

/// What simplification may do to the surface's boundary, which on an iso-surface is where the
/// volume's box cuts it (`[simplify] boundary`).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub enum Boundary {
    /// Boundary vertices leave only from straight pieces: the cut keeps its exact polyline, so
    /// pieces of a volume simplified apart still meet along it. Its vertices are a floor for
    /// the face count (bonsai's cut has 11 k edges, a tenth of its output at R = 0.01).
    #[default]
    Exact,
    /// A boundary vertex may also be merged into a boundary neighbour when it lies on one face
    /// of the volume's box (`SimplifyConfig::domain`, which it needs) with both its boundary
    /// neighbours (coordinates as written, see `cost::output_precision`), so the shortened cut
    /// stays on that face; where the cut turns from one face to another it stays put. The
    /// removal is costed by boundary quadrics: for each boundary edge, the plane through it
    /// perpendicular to its triangle, weighted by `BOUNDARY_WEIGHT` times its squared length
    /// (Garland and Heckbert 1997, "preserving boundaries"), so straight and gently curved
    /// stretches of the cut go first.
    Planar,
}

impl Boundary {
    /// Whether boundary edges carry boundary quadrics (see [`Boundary::Planar`]).
    pub(crate) fn is_planar(&self) -> bool {
        *self == Boundary::Planar
    }
}

/// The volume's box `[lo, hi]`, in coordinates as written (`f32`-exact), where the
/// full-resolution surface lies and on whose faces its boundary (the box's cut) runs.
///
/// Placements are not kept within it: a quadric's minimiser near a face the surface nearly
/// touches may lie beyond it (bonsai at R = 0.2: 73 vertices up to 0.25 voxel outside). Moving
/// such minimisers onto the box (the fifty-ninth session) wrote every vertex inside, but took
/// bonsai's streamed RMS distance at R = 0.01 from 3.62 to 4.51 voxels and its Hausdorff
/// distance from 23.8 to 34.2 (at R = 0.2 and on engine the same): not kept.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Domain {
    pub lo: DVec3,
    pub hi: DVec3,
}

impl Domain {
    /// Finite, `f32`-exact (as written: `on_one_face` compares coordinates), with `lo <= hi`.
    pub(crate) fn is_valid(&self) -> bool {
        let exact = |p: DVec3| crate::cost::output_precision(p) == p;
        self.lo.is_finite()
            && self.hi.is_finite()
            && exact(self.lo)
            && exact(self.hi)
            && self.lo.cmple(self.hi).all()
    }

    /// Whether the three points lie on one face of the box.
    fn on_one_face(&self, p: [DVec3; 3]) -> bool {
        let (lo, hi) = (self.lo, self.hi);
        (0..3).any(|i| [lo[i], hi[i]].iter().any(|&c| p.iter().all(|x| x[i] == c)))
    }
}

/// Admissible positions of the new vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Sites {
    /// Anywhere: minimise the objective, with a fallback when it is ill-conditioned.
    Free,
    /// Only these (boundary rule).
    Fixed([Option<DVec3>; 2]),
}

/// One triangle of a [`Patch`]: its corners' ids and positions.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PatchTri {
    pub(crate) v: [u64; 3],
    pub(crate) p: [DVec3; 3],
}

/// `T_ab`: the triangles containing `a` or `b` (each once, by slot), whose union is the patch
/// replaced by the contraction, with their corners. Gathered from the store once per popped
/// candidate and shared by the checks that follow (front, flips, guard, attributes), which
/// each read the same triangles and corners again before. That was about a hundred vertex
/// lookups a contraction where forty do, yet callgrind counts the same instructions either way
/// (engine crop, 5.37 G): the lookups were cheap; what one gather buys is one view of the patch.
///
/// The decimator keeps one and gathers every candidate's patch into it ([`Patch::gather_into`]):
/// returned by value, the patch (1.5 KB inline) was copied out at every candidate, and at low
/// rates, where fans grow past its inline room, both it and its list of triangle ids went to the
/// allocator each time (a tenth of the second stage's final decimation on bonsai at R = 0.01).
#[derive(Debug, Clone, Default)]
pub(crate) struct Patch {
    pub(crate) tris: SmallVec<[PatchTri; 16]>,
    /// The triangle ids being gathered (scratch, kept for its room).
    ids: SmallVec<[TriId; 32]>,
}

impl Patch {
    /// The patch of `a` and `b` (see [`Patch::gather_into`]).
    pub(crate) fn gather(store: &Store, a: u64, b: u64) -> Self {
        let mut patch = Self::default();
        patch.gather_into(store, a, b);
        patch
    }

    /// Makes this the patch of `a` and `b`: their triangles in the order of their ids.
    pub(crate) fn gather_into(&mut self, store: &Store, a: u64, b: u64) {
        let fan = |v: u64| {
            store
                .vertex(v)
                .into_iter()
                .flat_map(|x| x.tris.iter().copied())
        };
        self.ids.clear();
        self.ids.extend(fan(a).chain(fan(b)));
        self.ids.sort_unstable();
        self.ids.dedup();
        self.tris.clear();
        self.tris.extend(self.ids.iter().map(|&t| {
            let tri = store.tri(t);
            PatchTri {
                v: tri.v,
                p: store.corners(tri),
            }
        }));
    }

    /// Whether triangle `t` is one of the patch's (as gathered by [`Patch::gather_into`]).
    pub(crate) fn holds(&self, t: TriId) -> bool {
        self.ids.binary_search(&t).is_ok()
    }

    /// A patch of the given triangles.
    #[cfg(test)]
    pub(crate) fn of(tris: SmallVec<[PatchTri; 16]>) -> Self {
        Self {
            tris,
            ids: SmallVec::new(),
        }
    }
}

/// No surviving triangle of the fans of `a` and `b` may turn its normal by more than about 84
/// degrees or become degenerate when `a` and `b` move to `pos`. Triangles that were degenerate
/// already (coincident marching-cubes vertices) may stay so, but if they gain area they must face
/// the way the whole fan faces; and a small one (`|cross|` within `DEGENERATE_FRACTION` of the
/// fan's largest) may not become [`collinear`] unless it was: a sliver with an edge of two `f32`
/// steps (marching-cubes vertices either side of a corner valued almost exactly iso, on the
/// volume box where the boundary rule keeps both) counts as small, and moving its third corner
/// onto the line of that edge wrote a zero-area triangle (bonsai upsampled 4x, R = 0.0006). Nor
/// may any surviving triangle become zero-area by the referee's measure unless it was: a
/// sliver a voxel wide along an axis 10^8 times longer has a large `|cross|` next to its
/// neighbours and none to the referee.
pub(crate) fn geometry_ok(patch: &Patch, a: u64, b: u64, pos: DVec3) -> bool {
    let cross = |p: [DVec3; 3]| (p[1] - p[0]).cross(p[2] - p[0]);
    let mut max_old = 0.0_f64;
    let mut reference = DVec3::ZERO;
    // Old normal and its length per triangle, computed once.
    let normals: SmallVec<[(DVec3, f64); 16]> = patch
        .tris
        .iter()
        .map(|pt| {
            let n = cross(pt.p);
            let l = n.length();
            max_old = max_old.max(l);
            reference += n;
            (n, l)
        })
        .collect();
    let tiny = DEGENERATE_FRACTION * max_old;
    patch
        .tris
        .iter()
        .zip(&normals)
        .all(|(pt, &(n_old, l_old))| {
            if pt.v.contains(&a) && pt.v.contains(&b) {
                return true; // removed by the contraction
            }
            let old = pt.p;
            let mut new = old;
            for (p, &id) in new.iter_mut().zip(&pt.v) {
                if id == a || id == b {
                    *p = pos;
                }
            }
            if new == old {
                return true;
            }
            let n_new = cross(new);
            let l_new = n_new.length();
            // Never a zero-area triangle the referee would count where there was none: a
            // sliver collinear by `COLLINEAR_FRACTION` may stay collinear (below), but not
            // flatten past the referee's bound (spacings 10^8 apart between axes).
            if zero_area(new, l_new) && !zero_area(old, l_old) {
                return false;
            }
            if l_new <= tiny {
                return l_old <= tiny && (collinear(old, l_old) || !collinear(new, l_new));
            }
            if l_old <= tiny {
                return n_new.dot(reference) > 0.0;
            }
            n_old.dot(n_new) > MIN_NORMAL_COS * l_old * l_new
        })
}

/// `|cross|` (`l`) at most [`COLLINEAR_FRACTION`] of the longest edge squared: a sliver whose
/// corners are in a line, which the fan-relative `tiny` of [`geometry_ok`] cannot tell from a
/// small triangle. Coincident corners count as collinear.
fn collinear(p: [DVec3; 3], l: f64) -> bool {
    l <= COLLINEAR_FRACTION * longest_squared(p)
}

/// Zero-area by the referee's measure (`|cross| <= 1e-12 longest^2`, what `isostream measure`
/// counts as a zero-area triangle).
fn zero_area(p: [DVec3; 3], l: f64) -> bool {
    l <= ZERO_AREA_FRACTION * longest_squared(p)
}

fn longest_squared(p: [DVec3; 3]) -> f64 {
    (p[1] - p[0])
        .length_squared()
        .max((p[2] - p[0]).length_squared())
        .max((p[2] - p[1]).length_squared())
}

/// Test support: marks every vertex modifiable, with its boundary flag, as `set_modifiable`
/// does once all triangles are in.
#[cfg(test)]
pub(crate) fn complete(store: &mut Store) {
    let ids: Vec<u64> = store.ids().collect();
    for id in ids {
        let boundary = on_boundary(store, id);
        store.set_modifiable(id);
        if let Some(v) = store.vertex_mut(id) {
            v.boundary = boundary;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{Tri, Vertex};

    fn store(pos: &[[f64; 3]], tris: &[[u64; 3]]) -> Store {
        let mut s = Store::default();
        for (i, p) in pos.iter().enumerate() {
            s.insert_vertex(i as u64, DVec3::from_array(*p), Vertex::new(0), &[]);
        }
        for &v in tris {
            s.add_triangle(Tri { v, unmodifiable: 0 });
        }
        complete(&mut s);
        s
    }

    fn tetrahedron() -> Store {
        store(
            &[
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            &[[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
        )
    }

    /// Octahedron: vertices +-x (0, 1), +-y (2, 3), +-z (4, 5).
    fn octahedron() -> Store {
        let p = [
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ];
        let mut t = Vec::new();
        for (x, y) in [(0, 2), (2, 1), (1, 3), (3, 0)] {
            t.push([x, y, 4]);
            t.push([y, x, 5]);
        }
        store(&p, &t)
    }

    /// 3x3 vertex grid in the xy plane, ids row by row; centre is 4.
    fn grid() -> Store {
        let mut p = Vec::new();
        for y in 0..3 {
            for x in 0..3 {
                p.push([f64::from(x), f64::from(y), 0.0]);
            }
        }
        let mut t = Vec::new();
        for y in 0..2u64 {
            for x in 0..2u64 {
                let v = y * 3 + x;
                t.push([v, v + 1, v + 4]);
                t.push([v, v + 4, v + 3]);
            }
        }
        store(&p, &t)
    }

    /// The link condition on the patch of `a` and `b`, checked against its definition on the
    /// two rings read from the store.
    fn link(s: &Store, a: u64, b: u64) -> bool {
        let ok = link_ok(&Patch::gather(s, a, b), a, b);
        assert_eq!(ok, link_by_rings(s, a, b), "edge {a}{b}");
        ok
    }

    /// The link condition as the rings of `a` and `b` in the store define it (see [`link_ok`]).
    fn link_by_rings(s: &Store, a: u64, b: u64) -> bool {
        let fan = |v: u64| s.vertex(v).map(|x| x.tris.to_vec()).unwrap_or_default();
        let on_edge: Vec<_> = fan(a)
            .into_iter()
            .map(|t| *s.tri(t))
            .filter(|t| t.contains(b))
            .collect();
        if on_edge.is_empty() || on_edge.len() > 2 {
            return false;
        }
        let mut opposite: Vec<u64> = on_edge.iter().map(|t| third(t.v, a, b)).collect();
        opposite.sort_unstable();
        let (ra, rb) = (ring(s, a), ring(s, b));
        let common: Vec<(u64, u8, u8)> = ra
            .iter()
            .filter_map(|&(x, na)| rb.iter().find(|(y, _)| *y == x).map(|&(_, nb)| (x, na, nb)))
            .collect();
        if !common.iter().map(|c| c.0).eq(opposite.iter().copied()) {
            return false;
        }
        let with = |v: u64, x: u64, y: u64| {
            fan(v)
                .iter()
                .any(|&t| s.tri(t).contains(x) && s.tri(t).contains(y))
        };
        if on_edge.len() == 2 {
            let (x, y) = (opposite[0], opposite[1]);
            !((is_boundary(&ra) && is_boundary(&rb)) || (with(a, x, y) && with(b, x, y)))
        } else {
            !common.iter().any(|&(_, na, nb)| na == 1 && nb == 1)
        }
    }

    #[test]
    fn the_patch_link_is_the_rings_link_for_every_pair() {
        for s in [tetrahedron(), octahedron(), grid()] {
            let ids: Vec<u64> = s.ids().collect();
            for &a in &ids {
                for &b in &ids {
                    if a != b {
                        link(&s, a, b);
                    }
                }
            }
        }
    }

    #[test]
    fn tetrahedron_never_collapses() {
        let s = tetrahedron();
        for (a, b) in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)] {
            assert!(!link(&s, a, b), "edge {a}{b}");
        }
    }

    #[test]
    fn octahedron_edges_pass_but_non_edges_fail() {
        let s = octahedron();
        assert!(link(&s, 0, 2));
        assert!(!link(&s, 0, 1), "not an edge");
    }

    #[test]
    fn boundary_rules() {
        let s = grid();
        let p = |i: u64| s.pos(i);
        assert!(link(&s, 4, 0), "interior vertex to corner");
        assert_eq!(
            sites(&s, 4, 0, None),
            Some(Sites::Fixed([Some(p(0)), None]))
        );
        assert_eq!(
            sites(&s, 4, 5, None),
            Some(Sites::Fixed([Some(p(5)), None]))
        );
        // 1 lies on the straight bottom side 0-2 and may merge into corner 0; the corner turns
        // and may not merge into anything.
        assert!(link(&s, 0, 1));
        assert_eq!(
            sites(&s, 0, 1, None),
            Some(Sites::Fixed([Some(p(0)), None]))
        );
        assert_eq!(
            sites(&s, 0, 3, None),
            Some(Sites::Fixed([Some(p(0)), None]))
        );
        assert_eq!(
            sites(&s, 1, 2, None),
            Some(Sites::Fixed([None, Some(p(2))]))
        );
    }

    /// The grid with its bottom side (y = 0) bent at vertex 1: a curved cut on the box face
    /// y = 0 of the box [0, 2] x [0, 2] x [-1, 1].
    #[test]
    fn a_planar_boundary_simplifies_the_cut_within_a_box_face() {
        let mut s = grid();
        let bent = crate::cost::output_precision(s.pos(1).with_z(0.3));
        s.set_pos(1, bent);
        let p = |i: u64| s.pos(i);
        let planar = Some(&Domain {
            lo: DVec3::new(0.0, 0.0, -1.0),
            hi: DVec3::new(2.0, 2.0, 1.0),
        });
        // Exact: 1 is not on a straight piece, and the corners turn.
        assert_eq!(sites(&s, 0, 1, None), None);
        assert_eq!(sites(&s, 1, 2, None), None);
        // Planar: 1 lies on the face y = 0 with both boundary neighbours, and goes into either;
        // corner 0's boundary neighbours (1 on y = 0, 3 on x = 0) share no face with it.
        assert_eq!(
            sites(&s, 0, 1, planar),
            Some(Sites::Fixed([Some(p(0)), None]))
        );
        assert_eq!(
            sites(&s, 1, 2, planar),
            Some(Sites::Fixed([None, Some(p(2))]))
        );
        assert_eq!(sites(&s, 0, 3, planar), sites(&s, 0, 3, None));
        // Off the box's faces (a box larger than the grid), nothing changes.
        let far = Domain {
            lo: DVec3::splat(-5.0),
            hi: DVec3::splat(5.0),
        };
        assert_eq!(sites(&s, 0, 1, Some(&far)), None);
    }

    #[test]
    fn lone_triangle_keeps_its_edges() {
        let s = store(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], &[[0, 1, 2]]);
        assert!(!link(&s, 0, 1));
    }

    #[test]
    fn interior_edge_between_boundary_vertices_is_rejected() {
        // A strip of two triangles: edge 1-2 is interior, both ends on the boundary.
        let s = store(
            &[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]],
            &[[0, 1, 2], [1, 3, 2]],
        );
        assert!(!link(&s, 1, 2));
        assert!(link(&s, 0, 1), "boundary edge of the strip");
    }

    fn flips_ok(s: &Store, a: u64, b: u64, pos: DVec3) -> bool {
        geometry_ok(&Patch::gather(s, a, b), a, b, pos)
    }

    #[test]
    fn flips_and_degenerates_are_detected() {
        let s = grid();
        assert!(flips_ok(&s, 4, 0, DVec3::ZERO));
        // Past the left side: triangle 3-4-7 turns over.
        assert!(!flips_ok(&s, 4, 5, DVec3::new(-5.0, 1.0, 0.0)));
        // Far above the plane: normals turn by almost 90 degrees.
        assert!(!flips_ok(&s, 4, 5, DVec3::new(1.0, 1.0, 50.0)));
        // Onto vertex 1: triangle 0-1-4 (which survives contracting 4-3) becomes degenerate.
        assert!(!flips_ok(&s, 4, 3, DVec3::new(1.0, 0.0, 0.0)));
    }

    /// The zero-area triangle of bonsai upsampled 4x (`docs/scale.md`): two marching-cubes
    /// vertices two `f32` steps either side of a corner valued almost iso (A, B: an edge of
    /// 4e-5 voxel, both kept by the boundary rule), and a third corner (C) on the line of that
    /// edge. Triangle A-B-X is small next to its fan, so the fan-relative test alone let X move
    /// onto C, which wrote A-B-C with corners exactly in a line.
    #[test]
    fn small_slivers_may_not_become_collinear() {
        let step = 2.0 * 2f64.powi(-16); // two f32 steps at 128..256
        let s = store(
            &[
                [213.0 - step, 0.0, 139.0], // 0: A
                [213.0, 0.0, 139.0 - step], // 1: B
                [214.0 - step, 0.0, 138.0], // 2: C
                [212.5, 0.3, 137.5],        // 3: X
                [220.0, 0.0, 125.0],
                [205.0, 0.0, 125.0],
            ],
            &[[0, 1, 3], [1, 2, 3], [3, 2, 4], [3, 4, 5]],
        );
        let c = s.pos(2);
        assert!(!flips_ok(&s, 3, 2, c), "A-B-X onto the line of A-B");
        // Off that line the sliver stays a small, non-collinear triangle: still allowed.
        assert!(flips_ok(&s, 3, 2, c + DVec3::new(0.0, 0.5, 0.0)));
    }
}
