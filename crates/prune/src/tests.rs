use std::num::NonZeroU64;

use glam::DVec3;
use isostream_detect::{MeshDelta, NewVertex};
use proptest::prelude::*;

use crate::{Pruner, PrunerState};

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
    }
}

fn pruner(n: u64) -> Pruner {
    Pruner::new(NonZeroU64::new(n).unwrap())
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
    let mut p = pruner(5);
    // Tetrahedron 0..4 (4 faces) and two tetrahedra glued at vertex 6: 4..11 (8 faces).
    let small = tetra([0, 1, 2, 3]);
    let big: Vec<[u64; 3]> = tetra([4, 5, 6, 7])
        .into_iter()
        .chain(tetra([6, 8, 9, 10]))
        .collect();
    let all: Vec<u64> = (0..11).collect();
    let tris: Vec<[u64; 3]> = small.iter().chain(&big).copied().collect();
    let out = p.process(delta(&all, &tris, &all, 1));
    assert_eq!(ids(&out), (4..11).collect::<Vec<_>>());
    assert_eq!(out.attrs, (4..11).map(|i| i as f32).collect::<Vec<_>>());
    assert_eq!(out.triangles, big);
    assert_eq!(out.modifiable, (4..11).collect::<Vec<_>>());
    assert_eq!(out.front, 1);
    let st = p.stats();
    assert_eq!(
        (st.components_pruned, st.faces_pruned, st.vertices_pruned),
        (1, 4, 4)
    );
}

#[test]
fn a_held_component_holds_the_front_until_it_is_decided() {
    let mut p = pruner(4);
    let t = tetra([0, 1, 2, 3]);
    // Three faces at front 0..2: held (3 < 4), the front passed on stays at 0.
    let out = p.process(delta(&[0, 1, 2, 3], &t[..2], &[], 2));
    assert!(out.triangles.is_empty() && out.vertices.is_empty());
    assert_eq!(out.front, 0);
    let out = p.process(delta(&[], &t[2..3], &[], 5));
    assert_eq!(out.front, 0);
    // The fourth face releases it, in input order, and the front catches up.
    let out = p.process(delta(&[], &t[3..], &[0, 1, 2, 3], 6));
    assert_eq!(ids(&out), vec![0, 1, 2, 3]);
    assert_eq!(out.triangles, t.to_vec());
    assert_eq!(out.modifiable, vec![0, 1, 2, 3]);
    assert_eq!(out.front, 6);
    // A later component that completes below the size lets the front go once dropped.
    let small = [[4, 5, 6]];
    let out = p.process(delta(&[4, 5, 6], &small, &[4], 7));
    assert_eq!(out.front, 6, "held at the front in force when it began");
    let out = p.process(delta(&[], &[], &[5, 6], 8));
    assert_eq!((out.front, out.triangles.len()), (8, 0));
    assert_eq!(p.stats().faces_pruned, 1);
    assert_eq!(p.stats().peak_held_faces, 3);
}

#[test]
fn components_merged_by_a_triangle_are_released_together_in_input_order() {
    let mut p = pruner(3);
    // Two single triangles (held), then a triangle joining them: 3 faces, released at once.
    let out = p.process(delta(&[0, 1, 2], &[[0, 1, 2]], &[], 0));
    assert!(out.triangles.is_empty());
    let out = p.process(delta(&[3, 4, 5], &[[3, 4, 5]], &[0], 1));
    assert!(out.triangles.is_empty());
    let out = p.process(delta(&[], &[[1, 3, 2]], &[1, 2, 3, 4, 5], 2));
    assert_eq!(ids(&out), vec![0, 1, 2, 3, 4, 5]);
    assert_eq!(out.triangles, vec![[0, 1, 2], [3, 4, 5], [1, 3, 2]]);
    assert_eq!(out.modifiable, vec![0, 1, 2, 3, 4, 5]);
    assert_eq!(p.stats().components_pruned, 0);
}

#[test]
fn a_triangle_joining_a_released_component_releases_the_held_one() {
    let mut p = pruner(2);
    let out = p.process(delta(&[0, 1, 2, 3], &[[0, 1, 2], [0, 2, 3]], &[], 0));
    assert_eq!(out.triangles.len(), 2, "two faces: released");
    let out = p.process(delta(&[4, 5, 6], &[[4, 5, 6]], &[], 1));
    assert!(out.triangles.is_empty(), "one face: held");
    let out = p.process(delta(&[], &[[3, 2, 4]], &[0, 1, 2, 3, 4, 5, 6], 2));
    assert_eq!(ids(&out), vec![4, 5, 6]);
    assert_eq!(out.triangles, vec![[4, 5, 6], [3, 2, 4]]);
    assert_eq!(out.modifiable, vec![0, 1, 2, 3, 4, 5, 6]);
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
    let mut bounds: Vec<usize> = cuts.into_iter().map(|c| c % (triangles.len() + 1)).collect();
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

fn run(p: &mut Pruner, deltas: &[MeshDelta]) -> Vec<MeshDelta> {
    deltas.iter().map(|d| p.process(d.clone())).collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// What comes out is exactly the input's components of at least the size, in input order,
    /// as a valid stream (vertex before its triangles, notice after them), with a front that
    /// never passes a triangle still to come; a restored snapshot continues identically.
    #[test]
    fn the_output_is_the_large_components_as_a_valid_stream(
        raw in proptest::collection::vec([0u16..60, 0u16..60, 0u16..60], 1..120),
        cuts in proptest::collection::vec(0usize..200, 0..12),
        delays in proptest::collection::vec(any::<u8>(), 60),
        size in 1u64..12,
        at in 0usize..14,
    ) {
        let s = stream(raw, cuts, delays);
        let (roots, faces) = components(&s);

        let mut p = pruner(size);
        let out = run(&mut p, &s.deltas);
        p.finish();

        let flat = |ds: &[MeshDelta]| {
            let v: Vec<u64> = ds.iter().flat_map(ids).collect();
            let a: Vec<f32> = ds.iter().flat_map(|d| d.attrs.clone()).collect();
            let t: Vec<[u64; 3]> = ds.iter().flat_map(|d| d.triangles.clone()).collect();
            let m: Vec<u64> = ds.iter().flat_map(|d| d.modifiable.clone()).collect();
            (v, a, t, m)
        };
        // Per kept component, its elements (in the order of the parts they were released with,
        // so compared sorted); nothing of the others.
        let by_root = |(v, a, t, m): (Vec<u64>, Vec<f32>, Vec<[u64; 3]>, Vec<u64>)| {
            let mut g = std::collections::BTreeMap::<usize, (Vec<u64>, Vec<f32>, Vec<[u64; 3]>, Vec<u64>)>::new();
            for (&v, &a) in v.iter().zip(&a) {
                let e = g.entry(roots[v as usize]).or_default();
                e.0.push(v);
                e.1.push(a);
            }
            for t in t {
                g.entry(roots[t[0] as usize]).or_default().2.push(t);
            }
            for m in m {
                g.entry(roots[m as usize]).or_default().3.push(m);
            }
            for e in g.values_mut() {
                let mut va: Vec<(u64, u32)> = e.0.iter().zip(&e.1).map(|(&v, a)| (v, a.to_bits())).collect();
                va.sort_unstable();
                e.0 = va.iter().map(|p| p.0).collect();
                e.1 = va.iter().map(|p| f32::from_bits(p.1)).collect();
                e.2.sort_unstable();
                e.3.sort_unstable();
            }
            g
        };
        let mut want = by_root(flat(&s.deltas));
        want.retain(|&r, _| faces[r] >= size);
        prop_assert_eq!(by_root(flat(&out)), want);

        let dropped: u64 = (0..faces.len()).filter(|&r| roots[r] == r && faces[r] < size)
            .map(|r| faces[r]).sum();
        prop_assert_eq!(p.stats().faces_pruned, dropped);

        // Stream order per delta, and the front rule: a triangle passed on lies beyond the
        // front passed on before it (it arrived after the input front `arrival`).
        let arrival: std::collections::HashMap<[u64; 3], u32> = s.deltas.iter()
            .scan(0u32, |front, d| {
                let f = *front;
                *front = d.front;
                Some(d.triangles.iter().map(move |&t| (t, f)).collect::<Vec<_>>())
            })
            .flatten()
            .collect();
        let mut present = std::collections::HashSet::new();
        let mut noticed = std::collections::HashSet::new();
        let mut front = 0u32;
        let position: std::collections::HashMap<[u64; 3], usize> =
            s.triangles.iter().enumerate().map(|(i, &t)| (t, i)).collect();
        for (d, input) in out.iter().zip(&s.deltas) {
            prop_assert!(d.front >= front && d.front <= input.front);
            // Each delta in input order (vertex ids and notices are in it too, by construction).
            prop_assert!(ids(d).is_sorted());
            prop_assert!(d.triangles.iter().map(|t| position[t]).is_sorted());
            present.extend(ids(d));
            for t in &d.triangles {
                prop_assert!(t.iter().all(|v| present.contains(v) && !noticed.contains(v)));
                prop_assert!(arrival[t] >= front, "triangle {:?} behind front {}", t, front);
            }
            noticed.extend(d.modifiable.iter().copied());
            front = d.front;
        }

        // Checkpoint: snapshot after `at` deltas, restore, continue: the same deltas.
        let at = at.min(s.deltas.len());
        let mut first = pruner(size);
        let head = run(&mut first, &s.deltas[..at]);
        let state: PrunerState = first.snapshot();
        let mut second = Pruner::restore(state.clone());
        prop_assert_eq!(second.snapshot(), state);
        let tail = run(&mut second, &s.deltas[at..]);
        let again: Vec<MeshDelta> = head.into_iter().chain(tail).collect();
        prop_assert_eq!(flat(&again), flat(&out));
        prop_assert_eq!(
            again.iter().map(|d| d.front).collect::<Vec<_>>(),
            out.iter().map(|d| d.front).collect::<Vec<_>>()
        );
        second.finish();
        prop_assert_eq!(second.stats(), p.stats());
    }
}
