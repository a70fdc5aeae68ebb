//! The marching-cubes case table, generated once at start-up instead of typed in.
//!
//! A pasted Lorensen/Bourke table resolves each ambiguous face (two diagonal inside corners)
//! differently depending on the rest of the cube, so two cubes sharing such a face can disagree
//! and leave a crack. Here every case is derived from one rule applied face by face:
//!
//! 1. **Face rule.** On each face, walk the four corners counter-clockwise seen from outside the
//!    cube ([`face_cycle`]). Every sign change is a crossing: *entering* when it goes from an
//!    outside to an inside corner, *leaving* otherwise. Each entering crossing is joined to the
//!    next crossing of the walk (always a leaving one). On an ambiguous face this cuts off each
//!    inside corner on its own: the inside corners are separated and the outside region is
//!    connected. The segments depend only on the face's four signs, and the neighbouring cube
//!    walks the shared face the other way round, so it builds the same segments reversed:
//!    watertight and consistently oriented.
//! 2. **Loops.** A crossing edge lies on exactly two faces of the cube; it is entered on one and
//!    left on the other, so following segments chains every crossing edge into exactly one
//!    closed loop.
//! 3. **Triangulation.** Each loop is triangulated without ever drawing an interior diagonal
//!    between two vertices on edges of a common face: the neighbouring cube across that face
//!    could draw the same segment, giving an edge with four triangles (it never can for
//!    vertices on no common face, as no other cube holds both edges). Among the allowed
//!    triangulations, the one maximising the minimum angle with vertices at edge midpoints wins
//!    (exact dynamic programming; loops have at most 12 vertices). Generation panics if a loop
//!    had no allowed triangulation; the tests show every one of the 256 cases has one.
//!
//! Orientation: the segment from an entering to a leaving crossing keeps the inside corners on
//! its right seen from outside the cube, which makes the loops, and the triangles that keep their
//! vertex order, counter-clockwise seen from the outside region: normals point from inside
//! (values above iso) to outside.

use std::sync::LazyLock;

use crate::cube::{edge_between, edge_corners, edge_midpoint, edges_share_face, face_cycle};

/// Most triangles in one case (a test checks the generated table reaches exactly this).
/// Consumers can size per-cube buffers with it; vertices per cube are at most 12.
pub const MAX_TRIANGLES: usize = 5;

/// One entry of the case table: the crossing edges of a sign configuration and its triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Case {
    edge_count: u8,
    edges: [u8; 12],
    triangle_count: u8,
    triangles: [[u8; 3]; MAX_TRIANGLES],
}

impl Case {
    /// The crossing edges (one corner inside, one outside) in increasing edge order. A vertex's
    /// local index in a cube is its position in this list.
    pub fn edges(&self) -> &[u8] {
        &self.edges[..self.edge_count as usize]
    }

    /// Triangles as local vertex indices into [`Case::edges`], counter-clockwise seen from
    /// outside. This is the form the slab extractor copies straight into its batches.
    pub fn triangles(&self) -> &[[u8; 3]] {
        &self.triangles[..self.triangle_count as usize]
    }

    /// Triangles as triples of cube-edge indices, counter-clockwise seen from outside.
    pub fn edge_triangles(&self) -> impl Iterator<Item = [u8; 3]> + '_ {
        self.triangles()
            .iter()
            .map(|t| t.map(|local| self.edges[local as usize]))
    }
}

static TABLE: LazyLock<[Case; 256]> = LazyLock::new(|| std::array::from_fn(build_case));

/// The case for a sign configuration: bit `c` of `index` set when corner `c` is inside.
pub fn case(index: u8) -> &'static Case {
    &TABLE[index as usize]
}

fn is_inside(index: usize, corner: u8) -> bool {
    (index >> corner) & 1 == 1
}

fn build_case(index: usize) -> Case {
    let mut case = Case {
        edge_count: 0,
        edges: [0; 12],
        triangle_count: 0,
        triangles: [[0; 3]; MAX_TRIANGLES],
    };
    let mut local = [u8::MAX; 12];
    for e in 0..12u8 {
        let (a, b) = edge_corners(e);
        if is_inside(index, a) != is_inside(index, b) {
            local[e as usize] = case.edge_count;
            case.edges[case.edge_count as usize] = e;
            case.edge_count += 1;
        }
    }
    for lp in loops(index) {
        for tri in triangulate(&lp) {
            case.triangles[case.triangle_count as usize] = tri.map(|e| local[e as usize]);
            case.triangle_count += 1;
        }
    }
    case
}

/// For every crossing edge, the edge that follows it on the oriented iso-curve drawn on the
/// cube's surface by the face rule (see the module docs).
fn successors(index: usize) -> [Option<u8>; 12] {
    let mut next = [None; 12];
    for f in 0..6 {
        let cycle = face_cycle(f);
        // Crossings in counter-clockwise order: (edge, entering).
        let crossings: Vec<(u8, bool)> = (0..4)
            .filter_map(|i| {
                let (a, b) = (cycle[i], cycle[(i + 1) % 4]);
                let (ia, ib) = (is_inside(index, a), is_inside(index, b));
                (ia != ib).then(|| (edge_between(a, b), ib))
            })
            .collect();
        for (j, &(e, entering)) in crossings.iter().enumerate() {
            if entering {
                let (partner, partner_entering) = crossings[(j + 1) % crossings.len()];
                assert!(
                    !partner_entering,
                    "face {f} of case {index}: two entries in a row"
                );
                let previous = next[e as usize].replace(partner);
                assert!(previous.is_none(), "edge {e} of case {index} entered twice");
            }
        }
    }
    next
}

/// The closed loops of crossing edges, each in its oriented order, starting from its smallest
/// edge (loops are found in increasing order of that edge, so generation is deterministic).
fn loops(index: usize) -> Vec<Vec<u8>> {
    let next = successors(index);
    let mut visited = [false; 12];
    let mut loops = Vec::new();
    for start in 0..12u8 {
        if visited[start as usize] || next[start as usize].is_none() {
            continue;
        }
        let mut lp = Vec::new();
        let mut e = start;
        while !visited[e as usize] {
            visited[e as usize] = true;
            lp.push(e);
            e = next[e as usize].expect("every crossing edge is left on one face");
        }
        assert_eq!(e, start, "case {index}: the iso-curve does not close");
        loops.push(lp);
    }
    loops
}

/// Triangulates one loop (cube-edge indices in oriented order) by exact dynamic programming
/// over the polygon's sub-chains: maximise the minimum angle, never using a diagonal between
/// edges on a common face. Triangles keep the loop's orientation.
fn triangulate(lp: &[u8]) -> Vec<[u8; 3]> {
    let n = lp.len();
    assert!(n >= 3, "a loop has at least three crossing edges");
    let allowed = |i: usize, j: usize| {
        j - i == 1 || (i == 0 && j == n - 1) || { !edges_share_face(lp[i], lp[j]) }
    };
    // best[i][j]: (quality, apex k) of the best triangulation of the chain i..=j closed by the
    // chord (i, j); None when the chord is forbidden or the chain cannot be triangulated.
    let mut best = vec![vec![None::<(f64, usize)>; n]; n];
    for len in 2..n {
        for i in 0..n - len {
            let j = i + len;
            if !allowed(i, j) {
                continue;
            }
            let side = |a: usize, b: usize| {
                if b - a < 2 {
                    Some(f64::INFINITY)
                } else {
                    best[a][b].map(|(q, _)| q)
                }
            };
            let mut choice: Option<(f64, usize)> = None;
            for k in i + 1..j {
                let (Some(left), Some(right)) = (side(i, k), side(k, j)) else {
                    continue;
                };
                let q = min_angle(lp[i], lp[k], lp[j]).min(left).min(right);
                if choice.is_none_or(|(bq, _)| q > bq) {
                    choice = Some((q, k));
                }
            }
            best[i][j] = choice;
        }
    }
    let mut triangles = Vec::with_capacity(n - 2);
    let mut stack = vec![(0, n - 1)];
    while let Some((i, j)) = stack.pop() {
        if j - i < 2 {
            continue;
        }
        let (_, k) = best[i][j].unwrap_or_else(|| {
            panic!("loop {lp:?} has no triangulation without a diagonal on a cube face")
        });
        triangles.push([lp[i], lp[k], lp[j]]);
        stack.push((i, k));
        stack.push((k, j));
    }
    triangles
}

/// Smallest angle (radians) of the triangle through the midpoints of three cube edges.
fn min_angle(a: u8, b: u8, c: u8) -> f64 {
    let p = [a, b, c].map(edge_midpoint);
    let sub = |u: [f64; 3], v: [f64; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let angle = |at: usize| {
        let u = sub(p[(at + 1) % 3], p[at]);
        let v = sub(p[(at + 2) % 3], p[at]);
        let dot = u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let len = |w: [f64; 3]| (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
        (dot / (len(u) * len(v))).clamp(-1.0, 1.0).acos()
    };
    angle(0).min(angle(1)).min(angle(2))
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use super::*;
    use crate::cube::{corner_offset, edge_axis};

    /// Directed triangle edges of a case, counted.
    fn directed_edges(case: &Case) -> HashMap<(u8, u8), u32> {
        let mut edges = HashMap::new();
        for t in case.edge_triangles() {
            for i in 0..3 {
                *edges.entry((t[i], t[(i + 1) % 3])).or_default() += 1;
            }
        }
        edges
    }

    /// The loop segments of a case (its triangles' boundary): directed edges with no reverse.
    fn segments(case: &Case) -> Vec<(u8, u8)> {
        let edges = directed_edges(case);
        let mut s: Vec<_> = edges
            .keys()
            .copied()
            .filter(|&(a, b)| !edges.contains_key(&(b, a)))
            .collect();
        s.sort_unstable();
        s
    }

    #[test]
    fn empty_and_full_cubes_have_no_triangles() {
        assert!(case(0).edges().is_empty() && case(0).triangles().is_empty());
        assert!(case(255).edges().is_empty() && case(255).triangles().is_empty());
    }

    #[test]
    fn single_inside_corner_is_cut_off_by_one_outward_triangle() {
        // Corner 0 inside: one triangle on the x, y and z edges at the origin, its normal
        // pointing to the outside region (towards the cube centre).
        let c = case(1);
        assert_eq!(c.edges(), &[0, 4, 8]);
        let tris: Vec<_> = c.edge_triangles().collect();
        assert_eq!(tris.len(), 1);
        let p = tris[0].map(edge_midpoint);
        let (u, v) = (
            [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]],
            [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]],
        );
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        assert!(n.iter().all(|&x| x > 0.0), "{n:?}");
    }

    #[test]
    fn every_case_uses_each_crossing_edge_with_distinct_vertices() {
        for index in 0..=255u8 {
            let c = case(index);
            let mut used = [false; 12];
            for t in c.edge_triangles() {
                assert!(t[0] != t[1] && t[1] != t[2] && t[0] != t[2], "case {index}");
                for e in t {
                    assert!(
                        c.edges().contains(&e),
                        "case {index}: edge {e} does not cross"
                    );
                    used[e as usize] = true;
                }
            }
            for &e in c.edges() {
                assert!(used[e as usize], "case {index}: crossing edge {e} unused");
                let (a, b) = edge_corners(e);
                assert_ne!((index >> a) & 1, (index >> b) & 1);
            }
            for e in 0..12u8 {
                let (a, b) = edge_corners(e);
                if (index >> a) & 1 != (index >> b) & 1 {
                    assert!(c.edges().contains(&e), "case {index}: edge {e} missing");
                }
            }
        }
    }

    #[test]
    fn every_case_is_an_oriented_disk_per_loop_with_diagonals_off_the_faces() {
        for index in 0..=255u8 {
            let c = case(index);
            let edges = directed_edges(c);
            let mut in_degree = [0; 12];
            let mut out_degree = [0; 12];
            for (&(a, b), &count) in &edges {
                assert_eq!(
                    count, 1,
                    "case {index}: edge {a}->{b} used twice the same way"
                );
                if edges.contains_key(&(b, a)) {
                    // Interior diagonal: its two vertices must share no cube face.
                    assert!(!edges_share_face(a, b), "case {index}: diagonal {a}-{b}");
                } else {
                    // Loop segment: lies on a cube face.
                    assert!(edges_share_face(a, b), "case {index}: segment {a}-{b}");
                    out_degree[a as usize] += 1;
                    in_degree[b as usize] += 1;
                }
            }
            for &e in c.edges() {
                assert_eq!((in_degree[e as usize], out_degree[e as usize]), (1, 1));
            }
            // Triangles per loop: E - 2L, with L the number of loops (Euler of disks).
            let loops = loops(index as usize).len();
            assert_eq!(c.triangles().len() + 2 * loops, c.edges().len());
        }
    }

    /// Segments of `case` on face (axis, side), with their edges moved onto side 0.
    fn face_segments(index: u8, axis: u8, side: u8) -> Vec<(u8, u8)> {
        let on_face = |e: u8| {
            let o = corner_offset(edge_corners(e).0);
            edge_axis(e) != axis && o[axis as usize] == side
        };
        let to_side0 = |e: u8| {
            let (a, b) = edge_corners(e);
            let clear = !(1u8 << axis);
            edge_between(a & clear, b & clear)
        };
        let mut s: Vec<_> = segments(case(index))
            .into_iter()
            .filter(|&(a, b)| on_face(a) && on_face(b))
            .map(|(a, b)| (to_side0(a), to_side0(b)))
            .collect();
        s.sort_unstable();
        s
    }

    #[test]
    fn face_adjacent_cubes_agree_on_every_shared_face() {
        // Exhaustive over every pair of face-adjacent cubes whose signs agree on the shared
        // face: the low cube's segments on its side-1 face are exactly the reversed segments of
        // the high cube on its side-0 face. No cracks, consistent orientation.
        for axis in 0..3u8 {
            for low in 0..=255u8 {
                let mut shared = face_segments(low, axis, 1);
                shared.iter_mut().for_each(|s| *s = (s.1, s.0));
                shared.sort_unstable();
                // The high cube's side-0 corners are the low cube's side-1 corners.
                let mut face_bits = 0u8;
                for c in 0..8u8 {
                    if corner_offset(c)[axis as usize] == 1 && (low >> c) & 1 == 1 {
                        face_bits |= 1 << (c & !(1 << axis));
                    }
                }
                for rest in 0..16u8 {
                    let mut high = face_bits;
                    let far: Vec<u8> = (0..8u8)
                        .filter(|&c| corner_offset(c)[axis as usize] == 1)
                        .collect();
                    for (bit, &c) in far.iter().enumerate() {
                        if (rest >> bit) & 1 == 1 {
                            high |= 1 << c;
                        }
                    }
                    assert_eq!(
                        face_segments(high, axis, 0),
                        shared,
                        "axis {axis}, cubes {low:#010b} / {high:#010b}"
                    );
                }
            }
        }
    }

    #[test]
    fn ambiguous_faces_separate_the_inside_corners() {
        // Corners 0 and 3 inside (diagonal on face z = 0), the rest outside: two separate
        // corner triangles, never a band joining them.
        let c = case(0b0000_1001);
        assert_eq!(c.triangles().len(), 2);
        // Complement: outside corners 0 and 3 are connected by the outside region, so the
        // inside is one band of six vertices (four triangles).
        let c = case(!0b0000_1001);
        assert_eq!(c.triangles().len(), 4);
        assert_eq!(loops(!0b0000_1001usize & 0xff).len(), 1);
    }

    /// Every triangulation of the chain i..=j closed by the chord (i, j), as index triples.
    fn all_triangulations(i: usize, j: usize) -> Vec<Vec<[usize; 3]>> {
        if j - i < 2 {
            return vec![Vec::new()];
        }
        let mut all = Vec::new();
        for k in i + 1..j {
            for left in all_triangulations(i, k) {
                for right in all_triangulations(k, j) {
                    let mut t = left.clone();
                    t.extend(&right);
                    t.push([i, k, j]);
                    all.push(t);
                }
            }
        }
        all
    }

    #[test]
    fn every_loop_gets_the_best_allowed_triangulation() {
        // Brute force over all triangulations of every loop of every case: at least one avoids
        // diagonals on cube faces, and the generated one has the largest minimum angle of those.
        let mut longest = 0;
        for index in 0..256 {
            for lp in loops(index) {
                let n = lp.len();
                longest = longest.max(n);
                let allowed = |t: &[[usize; 3]]| {
                    t.iter()
                        .flat_map(|&[a, b, c]| [(a, b), (b, c), (a, c)])
                        .all(|(a, b)| {
                            b - a == 1 || (a == 0 && b == n - 1) || !edges_share_face(lp[a], lp[b])
                        })
                };
                let quality = |t: &[[usize; 3]]| {
                    t.iter()
                        .map(|&[a, b, c]| min_angle(lp[a], lp[b], lp[c]))
                        .fold(f64::INFINITY, f64::min)
                };
                let best = all_triangulations(0, n - 1)
                    .iter()
                    .filter(|t| allowed(t))
                    .map(|t| quality(t))
                    .fold(f64::NEG_INFINITY, f64::max);
                assert!(
                    best > 0.0,
                    "case {index}: loop {lp:?} has no allowed triangulation"
                );
                let chosen = triangulate(&lp);
                assert_eq!(chosen.len(), n - 2);
                let q = chosen
                    .iter()
                    .map(|&[a, b, c]| min_angle(a, b, c))
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(q, best, "case {index}: loop {lp:?}");
            }
        }
        // The face rule keeps loops short: a hexagon-plus-one at most, as in classic MC.
        assert_eq!(longest, 7);
    }

    #[test]
    fn max_triangles_is_tight() {
        let most = (0..=255u8).map(|i| case(i).triangles().len()).max();
        assert_eq!(most, Some(MAX_TRIANGLES));
    }

    #[test]
    fn generation_is_deterministic() {
        let again: [Case; 256] = std::array::from_fn(build_case);
        assert_eq!(&again, &*TABLE);
    }
}
