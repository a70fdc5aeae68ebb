//! Topology and validity checks for indexed triangle meshes.
//!
//! Every stage of isostream promises a valid surface: the extractor a watertight, edge-manifold
//! marching-cubes surface, the simplifier the same topology with fewer triangles. This crate is the
//! single referee those promises are tested against (unit, property and integration tests, and
//! `isostream measure`). It works on an in-memory indexed mesh, so it is meant for test-sized or
//! simplified meshes, not for the full-resolution stream.
//!
//! Architecture invariant: no dependencies, no I/O, cannot fail; it only reports.
#![deny(unsafe_code)]

mod intersect;
pub use intersect::{
    ORIENT_ERROR, certify, coplanar_segment_meets_triangle, crossing_triangles, folded, orient,
    segment_crosses_triangle, segment_meets_triangle, self_intersections, triangles_intersect,
    triangles_meet,
};

use std::collections::HashMap;

/// Per connected component (triangles connected through shared vertices).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Component {
    pub vertices: usize,
    pub edges: usize,
    pub triangles: usize,
    pub boundary_edges: usize,
    /// V - E + F of the component.
    pub euler: i64,
    /// Which way a closed component faces (`None` for an open one).
    pub enclosure: Option<Enclosure>,
}

/// The sign of a closed component's signed volume (`sum p0 . (p1 x p2) / 6`): positive when its
/// triangles face away from what it encloses (isostream's surfaces around high values),
/// negative when they face into it (a cavity's surface, or one turned inside out). A
/// simplification must keep each component's sign; [`Report::closed_by_sign`] counts them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Enclosure {
    Positive,
    Negative,
    /// Too small a volume for its sign to be told from rounding (a flat closed component).
    Flat,
}

/// What [`check`] found. A valid closed surface has every count except `triangles`, `vertices`
/// and `components` at zero.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Report {
    /// Vertices referenced by at least one triangle.
    pub vertices: usize,
    pub triangles: usize,
    pub edges: usize,
    /// Edges with exactly one incident triangle.
    pub boundary_edges: usize,
    /// Edges with three or more incident triangles.
    pub non_manifold_edges: usize,
    /// Manifold edges whose two triangles traverse them in the same direction.
    pub misoriented_edges: usize,
    /// Vertices whose link is not a single cycle or path (pinched surfaces, bow ties).
    pub non_manifold_vertices: usize,
    /// Triangles with a repeated vertex index.
    pub repeated_index_triangles: usize,
    /// Triangles with (near) zero area: |cross| <= 1e-12 * (longest edge)^2.
    pub zero_area_triangles: usize,
    /// Triangles whose vertex set appears more than once (counted once per extra copy).
    pub duplicate_triangles: usize,
    pub components: Vec<Component>,
}

impl Report {
    /// Edge-manifold, vertex-manifold, consistently oriented, no repeated or duplicate triangles.
    pub fn is_valid_manifold(&self) -> bool {
        self.non_manifold_edges == 0
            && self.misoriented_edges == 0
            && self.non_manifold_vertices == 0
            && self.repeated_index_triangles == 0
            && self.duplicate_triangles == 0
    }

    /// Valid and without boundary.
    pub fn is_closed_manifold(&self) -> bool {
        self.is_valid_manifold() && self.boundary_edges == 0
    }

    /// V - E + F over the whole mesh.
    pub fn euler(&self) -> i64 {
        self.components.iter().map(|c| c.euler).sum()
    }

    /// Closed components enclosing positive and negative volume (see [`Enclosure`]): the same
    /// for a surface and its simplification unless one was turned inside out, which leaves it
    /// manifold, oriented and without crossings.
    pub fn closed_by_sign(&self) -> [usize; 2] {
        let count = |e| {
            self.components
                .iter()
                .filter(|c| c.enclosure == Some(e))
                .count()
        };
        [count(Enclosure::Positive), count(Enclosure::Negative)]
    }

    /// Euler characteristics of the components, sorted, for comparing two meshes whose
    /// components are not matched one to one.
    pub fn sorted_eulers(&self) -> Vec<i64> {
        let mut e: Vec<i64> = self.components.iter().map(|c| c.euler).collect();
        e.sort_unstable();
        e
    }
}

/// A closed component's signed volume within this fraction of the sum of its terms'
/// magnitudes is [`Enclosure::Flat`]: rounding could give it either sign.
const FLAT_VOLUME: f64 = 1e-9;

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    if a < b { (a, b) } else { (b, a) }
}

/// Checks an indexed triangle mesh. Positions are only used for the zero-area count.
pub fn check(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> Report {
    let mut report = Report {
        triangles: triangles.len(),
        ..Report::default()
    };

    // Edge -> (count, signed direction sum). A consistently oriented manifold edge is traversed
    // once as (a,b) and once as (b,a): the signed sum is zero.
    let mut edges: HashMap<(u32, u32), (u32, i32)> = HashMap::with_capacity(triangles.len() * 2);
    let mut seen_tris: HashMap<[u32; 3], u32> = HashMap::with_capacity(triangles.len());
    for t in triangles {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            report.repeated_index_triangles += 1;
            continue;
        }
        let mut sorted = *t;
        sorted.sort_unstable();
        let copies = seen_tris.entry(sorted).or_insert(0);
        if *copies > 0 {
            report.duplicate_triangles += 1;
        }
        *copies += 1;
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            let e = edges.entry(edge_key(a, b)).or_insert((0, 0));
            e.0 += 1;
            e.1 += if a < b { 1 } else { -1 };
        }
        if is_zero_area(positions, t) {
            report.zero_area_triangles += 1;
        }
    }
    report.edges = edges.len();
    for &(count, dir) in edges.values() {
        match count {
            1 => report.boundary_edges += 1,
            2 if dir != 0 => report.misoriented_edges += 1,
            2 => {}
            _ => report.non_manifold_edges += 1,
        }
    }

    report.non_manifold_vertices = count_non_manifold_vertices(triangles);
    report.components = components(positions, triangles, &edges);
    report.vertices = report.components.iter().map(|c| c.vertices).sum();
    report
}

fn is_zero_area(positions: &[[f64; 3]], t: &[u32; 3]) -> bool {
    let p = |i: u32| positions.get(i as usize).copied().unwrap_or([0.0; 3]);
    let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
    let sub = |u: [f64; 3], v: [f64; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let (u, v, w) = (sub(b, a), sub(c, a), sub(c, b));
    let cross = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let len2 = |x: [f64; 3]| x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
    let longest = len2(u).max(len2(v)).max(len2(w));
    len2(cross).sqrt() <= 1e-12 * longest || longest == 0.0
}

/// A vertex is manifold when the edges opposite to it in its triangles (its link) form one
/// cycle or one path. Counted by walking the link graph of each vertex.
fn count_non_manifold_vertices(triangles: &[[u32; 3]]) -> usize {
    let mut links: HashMap<u32, Vec<(u32, u32)>> = HashMap::new();
    for t in triangles {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            continue;
        }
        for i in 0..3 {
            links
                .entry(t[i])
                .or_default()
                .push((t[(i + 1) % 3], t[(i + 2) % 3]));
        }
    }
    links
        .values()
        .filter(|link| !link_is_disk_or_half_disk(link))
        .count()
}

fn link_is_disk_or_half_disk(link: &[(u32, u32)]) -> bool {
    let mut degree: HashMap<u32, u32> = HashMap::new();
    let mut adj: HashMap<u32, Vec<u32>> = HashMap::new();
    for &(a, b) in link {
        *degree.entry(a).or_insert(0) += 1;
        *degree.entry(b).or_insert(0) += 1;
        adj.entry(a).or_default().push(b);
        adj.entry(b).or_default().push(a);
    }
    if degree.values().any(|&d| d > 2) {
        return false;
    }
    let ends = degree.values().filter(|&&d| d == 1).count();
    if ends != 0 && ends != 2 {
        return false;
    }
    // Connected?
    let start = link[0].0;
    let mut stack = vec![start];
    let mut seen = std::collections::HashSet::new();
    seen.insert(start);
    while let Some(v) = stack.pop() {
        for &n in &adj[&v] {
            if seen.insert(n) {
                stack.push(n);
            }
        }
    }
    seen.len() == degree.len()
}

fn components(
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    edges: &HashMap<(u32, u32), (u32, i32)>,
) -> Vec<Component> {
    let mut uf = UnionFind::default();
    for t in triangles {
        uf.union(t[0], t[1]);
        uf.union(t[1], t[2]);
    }
    let mut by_root: HashMap<u32, Component> = HashMap::new();
    let blank = Component {
        vertices: 0,
        edges: 0,
        triangles: 0,
        boundary_edges: 0,
        euler: 0,
        enclosure: None,
    };
    let verts: Vec<u32> = uf.parent.keys().copied().collect();
    for v in verts {
        let r = uf.find(v);
        by_root.entry(r).or_insert_with(|| blank.clone()).vertices += 1;
    }
    // Signed volume terms about the component's root vertex (its terms are then as small as the
    // component, wherever it lies), with the sum of their magnitudes for the rounding bound.
    let mut volumes: HashMap<u32, (f64, f64)> = HashMap::new();
    let p = |i: u32| positions.get(i as usize).copied().unwrap_or([0.0; 3]);
    for t in triangles {
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            continue;
        }
        let r = uf.find(t[0]);
        by_root.entry(r).or_insert_with(|| blank.clone()).triangles += 1;
        let o = p(r);
        let d = |i: usize| {
            let q = p(t[i]);
            [q[0] - o[0], q[1] - o[1], q[2] - o[2]]
        };
        let (a, b, c) = (d(0), d(1), d(2));
        let term = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]);
        let v = volumes.entry(r).or_insert((0.0, 0.0));
        v.0 += term;
        v.1 += term.abs();
    }
    for (&(a, _), &(count, _)) in edges {
        let r = uf.find(a);
        let c = by_root.entry(r).or_insert_with(|| blank.clone());
        c.edges += 1;
        if count == 1 {
            c.boundary_edges += 1;
        }
    }
    let mut out: Vec<Component> = by_root
        .into_iter()
        .map(|(r, mut c)| {
            c.euler = c.vertices as i64 - c.edges as i64 + c.triangles as i64;
            if c.boundary_edges == 0 && c.triangles > 0 {
                let (sum, magnitude) = volumes.get(&r).copied().unwrap_or_default();
                c.enclosure = Some(if sum.abs() <= FLAT_VOLUME * magnitude {
                    Enclosure::Flat
                } else if sum > 0.0 {
                    Enclosure::Positive
                } else {
                    Enclosure::Negative
                });
            }
            c
        })
        .collect();
    out.sort_by_key(|c| (c.triangles, c.vertices, c.euler));
    out
}

#[derive(Default)]
struct UnionFind {
    parent: HashMap<u32, u32>,
}

impl UnionFind {
    fn find(&mut self, v: u32) -> u32 {
        let p = *self.parent.entry(v).or_insert(v);
        if p == v {
            return v;
        }
        let r = self.find(p);
        self.parent.insert(v, r);
        r
    }

    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.parent.insert(ra, rb);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let p = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        let t = vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        (p, t)
    }

    /// Outward triangles enclose positive volume, the same turned inside out negative (the
    /// flip changes nothing else the report counts), far from the origin too; an open piece
    /// has no sign.
    #[test]
    fn closed_components_are_counted_by_the_sign_of_their_volume() {
        let (p, t) = tetrahedron();
        let far: Vec<[f64; 3]> = p.iter().map(|q| q.map(|x| x * 1e-3 + 1e6)).collect();
        let inverted: Vec<[u32; 3]> = t.iter().map(|&[a, b, c]| [a, c, b]).collect();
        let both: Vec<[u32; 3]> = t
            .iter()
            .copied()
            .chain(inverted.iter().map(|x| x.map(|i| i + 4)))
            .collect();
        let two: Vec<[f64; 3]> = far.iter().chain(&p).copied().collect();
        assert_eq!(check(&p, &t).closed_by_sign(), [1, 0]);
        assert_eq!(check(&far, &t).closed_by_sign(), [1, 0]);
        assert_eq!(check(&p, &inverted).closed_by_sign(), [0, 1]);
        assert_eq!(check(&two, &both).closed_by_sign(), [1, 1]);
        let (good, bad) = (check(&p, &t), check(&p, &inverted));
        assert!(bad.is_closed_manifold());
        assert_eq!(bad.sorted_eulers(), good.sorted_eulers());
        assert_eq!(check(&p, &t[..3]).closed_by_sign(), [0, 0], "open");
        let flat = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
        let r = check(&flat, &t);
        assert_eq!(r.components[0].enclosure, Some(Enclosure::Flat));
        assert_eq!(r.closed_by_sign(), [0, 0]);
    }

    #[test]
    fn tetrahedron_is_closed_sphere() {
        let (p, t) = tetrahedron();
        let r = check(&p, &t);
        assert!(r.is_closed_manifold(), "{r:?}");
        assert_eq!(r.euler(), 2);
        assert_eq!(r.components.len(), 1);
    }

    #[test]
    fn flipped_face_is_misoriented() {
        let (p, mut t) = tetrahedron();
        t[0] = [0, 1, 2];
        let r = check(&p, &t);
        assert_eq!(r.misoriented_edges, 3);
        assert!(!r.is_valid_manifold());
    }

    #[test]
    fn open_triangle_has_boundary() {
        let (p, _) = tetrahedron();
        let r = check(&p, &[[0, 1, 2]]);
        assert_eq!(r.boundary_edges, 3);
        assert!(r.is_valid_manifold());
        assert!(!r.is_closed_manifold());
        assert_eq!(r.euler(), 1);
    }

    #[test]
    fn three_triangles_on_an_edge_are_non_manifold() {
        let p = vec![[0.0; 3]; 5];
        let r = check(&p, &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]);
        assert_eq!(r.non_manifold_edges, 1);
    }

    #[test]
    fn bow_tie_vertex_is_non_manifold() {
        let p = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
            [-1.0, -1.0, 0.0],
        ];
        let r = check(&p, &[[0, 1, 2], [0, 3, 4]]);
        assert_eq!(r.non_manifold_vertices, 1);
        assert!(!r.is_valid_manifold());
    }

    #[test]
    fn zero_area_and_duplicates_are_counted() {
        let p = vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let r = check(&p, &[[0, 1, 2], [0, 1, 3], [1, 3, 0]]);
        assert_eq!(r.zero_area_triangles, 1);
        assert_eq!(r.duplicate_triangles, 1);
    }
}
