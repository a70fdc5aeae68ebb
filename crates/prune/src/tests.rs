use std::num::NonZeroU64;

use glam::DVec3;
use isostream_detect::{MeshDelta, NewVertex};
use proptest::prelude::*;

use crate::{Census, Filter, FilterState};

fn vertex(id: u64) -> NewVertex {
    NewVertex {
        id,
        pos: DVec3::new(id as f64, 0.0, 0.0),
        rank: id as u32,
    }
}

fn delta(vertices: &[u64], triangles: &[[u64; 3]], modifiable: &[u64], front: u32) -> MeshDelta {
    MeshDelta {
        vertices: vertices.iter().map(|&id| vertex(id)).collect(),
        attrs: vertices.iter().map(|&id| id as f32).collect(),
        triangles: triangles.to_vec(),
        modifiable: modifiable.to_vec(),
        front,
        rows: 0,
    }
}

/// Both passes over the same deltas: the census, then the filter's output.
fn prune(n: u64, deltas: &[MeshDelta]) -> (Vec<MeshDelta>, Filter) {
    let mut census = Census::new(NonZeroU64::new(n).unwrap());
    for d in deltas {
        census.add(d);
    }
    let mut filter = Filter::new(census.finish());
    let out = deltas.iter().map(|d| filter.process(d.clone())).collect();
    (out, filter)
}

/// The four faces of a tetrahedron on `v`.
fn tetra(v: [u64; 4]) -> [[u64; 3]; 4] {
    [
        [v[0], v[2], v[1]],
        [v[0], v[1], v[3]],
        [v[1], v[2], v[3]],
        [v[0], v[3], v[2]],
    ]
}

fn ids(d: &MeshDelta) -> Vec<u64> {
    d.vertices.iter().map(|v| v.id).collect()
}

#[test]
fn a_small_closed_component_is_dropped_and_a_large_one_passes_in_order() {
    // Tetrahedron 0..4 (4 faces) and two tetrahedra glued at vertex 6: 4..11 (8 faces).
    let small = tetra([0, 1, 2, 3]);
    let big: Vec<[u64; 3]> = tetra([4, 5, 6, 7])
        .into_iter()
        .chain(tetra([6, 8, 9, 10]))
        .collect();
    let all: Vec<u64> = (0..11).collect();
    let tris: Vec<[u64; 3]> = small.iter().chain(&big).copied().collect();
    let (out, filter) = prune(5, &[delta(&all, &tris, &all, 1)]);
    assert_eq!(ids(&out[0]), (4..11).collect::<Vec<_>>());
    assert_eq!(out[0].attrs, (4..11).map(|i| i as f32).collect::<Vec<_>>());
    assert_eq!(out[0].triangles, big);
    assert_eq!(out[0].modifiable, (4..11).collect::<Vec<_>>());
    assert_eq!(out[0].front, 1);
    let st = filter.stats();
    assert_eq!(
        (st.components_pruned, st.faces_pruned, st.vertices_pruned),
        (1, 4, 4)
    );
    assert_eq!(filter.dropped_faces(), 4);
}

#[test]
fn pieces_that_merge_later_are_judged_as_one_component() {
    // Two single triangles (pieces 0 and 3), then one joining them: 3 faces. Size 3 keeps all,
    // size 4 drops all three, across the deltas they came in.
    let deltas = [
        delta(&[0, 1, 2], &[[0, 1, 2]], &[], 0),
        delta(&[3, 4, 5], &[[3, 4, 5]], &[0], 1),
        delta(&[], &[[1, 3, 2]], &[1, 2, 3, 4, 5], 2),
        delta(&[6, 7, 8], &[[6, 7, 8]], &[6, 7, 8], 3),
    ];
    let (kept, _) = prune(3, &deltas);
    let flat: Vec<[u64; 3]> = kept.iter().flat_map(|d| d.triangles.clone()).collect();
    assert_eq!(flat, vec![[0, 1, 2], [3, 4, 5], [1, 3, 2]]);
    let (none, filter) = prune(4, &deltas);
    assert!(
        none.iter()
            .all(|d| d.triangles.is_empty() && d.vertices.is_empty())
    );
    assert!(none.iter().all(|d| d.modifiable.is_empty()));
    assert_eq!(
        none.iter().map(|d| d.front).collect::<Vec<_>>(),
        vec![0, 1, 2, 3]
    );
    assert_eq!(filter.stats().components_pruned, 2);
    assert_eq!(filter.stats().faces_pruned, 4);
}

#[test]
fn a_small_piece_joining_a_large_component_is_kept() {
    // 0..4: two faces (kept at size 2); 4..7: one face, later joined to the first by [3, 2, 4].
    let deltas = [
        delta(&[0, 1, 2, 3], &[[0, 1, 2], [0, 2, 3]], &[], 0),
        delta(&[4, 5, 6], &[[4, 5, 6]], &[], 1),
        delta(&[], &[[3, 2, 4]], &[0, 1, 2, 3, 4, 5, 6], 2),
    ];
    let (out, filter) = prune(2, &deltas);
    for (o, d) in out.iter().zip(&deltas) {
        assert_eq!(o.triangles, d.triangles);
        assert_eq!(o.modifiable, d.modifiable);
    }
    assert_eq!(filter.stats().components_pruned, 0);
}

/// A random stream as the detector makes it: ids in order of first appearance, each vertex
/// introduced in the delta of its first triangle and noticed in or after the delta of its last,
/// a nondecreasing front.
#[derive(Debug, Clone)]
struct Stream {
    deltas: Vec<MeshDelta>,
    triangles: Vec<[u64; 3]>,
}

fn stream(raw: Vec<[u16; 3]>, cuts: Vec<usize>, delays: Vec<u8>) -> Stream {
    // Relabel vertices in order of first appearance; drop degenerate and repeated triangles.
    let mut label = std::collections::HashMap::new();
    let mut triangles = Vec::new();
    let mut distinct = std::collections::HashSet::new();
    for t in raw {
        let mut sorted = t;
        sorted.sort_unstable();
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || !distinct.insert(sorted) {
            continue;
        }
        triangles.push(t.map(|v| {
            let n = label.len() as u64;
            *label.entry(v).or_insert(n)
        }));
    }
    let n = label.len();
    let mut last = vec![0usize; n];
    for (i, t) in triangles.iter().enumerate() {
        for &v in t {
            last[v as usize] = i;
        }
    }
    let mut bounds: Vec<usize> = cuts
        .into_iter()
        .map(|c| c % (triangles.len() + 1))
        .collect();
    bounds.push(0);
    bounds.push(triangles.len());
    bounds.sort_unstable();
    bounds.dedup();
    let count = bounds.len() - 1;
    // The delta of each triangle, then of each vertex's notice (its last triangle's, delayed).
    let mut delta_of = vec![0usize; triangles.len()];
    for (k, w) in bounds.windows(2).enumerate() {
        delta_of[w[0]..w[1]].fill(k);
    }
    let mut deltas: Vec<MeshDelta> = (0..count)
        .map(|k| MeshDelta {
            front: (k / 2) as u32,
            ..MeshDelta::default()
        })
        .collect();
    let mut seen = 0u64;
    for (i, t) in triangles.iter().enumerate() {
        let d = &mut deltas[delta_of[i]];
        for &v in t {
            if v == seen {
                d.vertices.push(vertex(v));
                d.attrs.push(v as f32);
                seen += 1;
            }
        }
        d.triangles.push(*t);
    }
    for v in 0..n {
        let delay = usize::from(delays.get(v).copied().unwrap_or(0) % 3);
        let k = (delta_of[last[v]] + delay).min(count - 1);
        deltas[k].modifiable.push(v as u64);
    }
    Stream { deltas, triangles }
}

/// Components of the whole stream: a root per vertex and the face count per root.
fn components(s: &Stream) -> (Vec<usize>, Vec<u64>) {
    let n = s.deltas.iter().map(|d| d.vertices.len()).sum::<usize>();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    for t in &s.triangles {
        let a = find(&mut parent, t[0] as usize);
        for &v in &t[1..] {
            let b = find(&mut parent, v as usize);
            let a = find(&mut parent, a);
            parent[b] = a;
        }
    }
    let roots: Vec<usize> = (0..n).map(|v| find(&mut parent, v)).collect();
    let mut faces = vec![0u64; n];
    for t in &s.triangles {
        faces[roots[t[0] as usize]] += 1;
    }
    (roots, faces)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// Each output delta is its input delta without the elements of the components below the
    /// size (same front, same order), exactly those are dropped, and a filter restored from a
    /// snapshot continues identically.
    #[test]
    fn the_output_is_the_input_without_the_small_components(
        raw in proptest::collection::vec([0u16..60, 0u16..60, 0u16..60], 1..120),
        cuts in proptest::collection::vec(0usize..200, 0..12),
        delays in proptest::collection::vec(any::<u8>(), 60),
        size in 1u64..12,
        at in 0usize..14,
    ) {
        let s = stream(raw, cuts, delays);
        let (roots, faces) = components(&s);
        let keep = |v: u64| faces[roots[v as usize]] >= size;
        let (out, filter) = prune(size, &s.deltas);
        prop_assert_eq!(out.len(), s.deltas.len());
        for (o, d) in out.iter().zip(&s.deltas) {
            let vertices: Vec<u64> = ids(d).into_iter().filter(|&v| keep(v)).collect();
            prop_assert_eq!(ids(o), vertices.clone());
            prop_assert_eq!(o.attrs.clone(), vertices.iter().map(|&v| v as f32).collect::<Vec<_>>());
            let tris: Vec<[u64; 3]> = d.triangles.iter().copied().filter(|t| keep(t[0])).collect();
            prop_assert_eq!(&o.triangles, &tris);
            let notices: Vec<u64> = d.modifiable.iter().copied().filter(|&v| keep(v)).collect();
            prop_assert_eq!(&o.modifiable, &notices);
            prop_assert_eq!(o.front, d.front);
        }
        let small: Vec<usize> = (0..faces.len()).filter(|&r| roots[r] == r && faces[r] < size).collect();
        let st = filter.stats();
        prop_assert_eq!(st.components_pruned, small.len() as u64);
        prop_assert_eq!(st.faces_pruned, small.iter().map(|&r| faces[r]).sum::<u64>());
        prop_assert_eq!(st.vertices_pruned, roots.iter().filter(|&&r| faces[r] < size).count() as u64);
        prop_assert_eq!(filter.dropped_faces(), st.faces_pruned);

        // Checkpoint: snapshot after `at` deltas, restore, continue: the same deltas.
        let at = at.min(s.deltas.len());
        let mut census = Census::new(NonZeroU64::new(size).unwrap());
        s.deltas.iter().for_each(|d| census.add(d));
        let mut first = Filter::new(census.finish());
        let head: Vec<MeshDelta> = s.deltas[..at].iter().map(|d| first.process(d.clone())).collect();
        let state: FilterState = first.snapshot();
        let mut second = Filter::restore(state.clone());
        prop_assert_eq!(second.snapshot(), state);
        let tail = s.deltas[at..].iter().map(|d| second.process(d.clone()));
        for (a, b) in head.into_iter().chain(tail).zip(&out) {
            prop_assert_eq!((ids(&a), a.triangles, a.modifiable), (ids(b), b.triangles.clone(), b.modifiable.clone()));
        }
        prop_assert_eq!(second.dropped_faces(), st.faces_pruned);
    }
}
