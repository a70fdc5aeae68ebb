use std::collections::{HashMap, HashSet};

use isostream_extract::{CubeBatch, Extractor, extract_indexed};
use isostream_volume::{Grid, MemoryVolume};
use proptest::prelude::*;

use super::*;

/// Streams a volume through the extractor and the detector, batch by batch.
fn stream(dims: [u64; 3], data: &[f32], iso: f32, max_tris: usize) -> (Vec<MeshDelta>, Detector) {
    let grid = Grid::new(dims, [1.0; 3], [0.0; 3]).unwrap();
    let mut extractor = Extractor::new(grid, iso);
    let mut detector = Detector::new(dims);
    let slice = (dims[0] * dims[1]) as usize;
    let mut deltas = Vec::new();
    for z in 0..dims[2] - 1 {
        let lower = &data[z as usize * slice..(z as usize + 1) * slice];
        let upper = &data[(z as usize + 1) * slice..(z as usize + 2) * slice];
        extractor
            .extract_slab(z, lower, upper, max_tris, |b: CubeBatch| {
                let mut d = MeshDelta::default();
                detector.process(&b, &mut d);
                deltas.push(d);
                Ok::<(), ()>(())
            })
            .unwrap();
    }
    if let Some(last) = deltas.last_mut() {
        detector.finish(last);
    }
    (deltas, detector)
}

fn field(dims: [u64; 3], levels: u32, seed: u64) -> Vec<f32> {
    let mut s = seed | 1;
    (0..dims[0] * dims[1] * dims[2])
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s % u64::from(levels)) as f32
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, failure_persistence: None, ..ProptestConfig::default() })]

    /// The stream contract the simplifier relies on: ids appear before use, every vertex is
    /// announced modifiable exactly once, no triangle uses a vertex after that, Table 1 alone
    /// releases every vertex, and the indexed surface is the reference marching cubes surface.
    #[test]
    fn stream_contract_holds(
        nx in 2u64..9, ny in 2u64..9, nz in 2u64..9,
        levels in 2u32..5, iso in prop::sample::select(vec![0.5f32, 1.0, 1.5]),
        seed in any::<u64>(), max_tris in 1usize..64,
    ) {
        let dims = [nx, ny, nz];
        let data = field(dims, levels, seed);
        let (deltas, detector) = stream(dims, &data, iso, max_tris);

        let mut positions = HashMap::new();
        let mut done = HashSet::new();
        let mut triangles = Vec::new();
        for d in &deltas {
            for v in &d.vertices {
                prop_assert!(positions.insert(v.id, v.pos).is_none(), "id {} reused", v.id);
            }
            for t in &d.triangles {
                for id in t {
                    prop_assert!(positions.contains_key(id), "{id} used before it appeared");
                    prop_assert!(!done.contains(id), "{id} used after it was modifiable");
                }
                triangles.push(*t);
            }
            for id in &d.modifiable {
                prop_assert!(done.insert(*id), "{id} announced twice");
            }
        }
        prop_assert_eq!(done.len(), positions.len());
        prop_assert_eq!(detector.stats().released_at_end, 0);

        let grid = Grid::new(dims, [1.0; 3], [0.0; 3]).unwrap();
        let reference = extract_indexed(&mut MemoryVolume::new(grid, data).unwrap(), iso).unwrap();
        let canon = |tris: Vec<[glam::DVec3; 3]>| {
            let mut v: Vec<[[u64; 3]; 3]> = tris
                .into_iter()
                .map(|t| {
                    let p = t.map(|q| q.to_array().map(f64::to_bits));
                    let k = (0..3).min_by_key(|&i| p[i]).unwrap();
                    [p[k], p[(k + 1) % 3], p[(k + 2) % 3]]
                })
                .collect();
            v.sort_unstable();
            v
        };
        let got = canon(triangles.iter().map(|t| t.map(|id| positions[&id])).collect());
        let want = canon(
            reference
                .triangles
                .iter()
                .map(|t| t.map(|i| reference.positions[i as usize]))
                .collect(),
        );
        prop_assert_eq!(got, want);
    }
}

/// The front map holds about one slab of crossing edges, never the surface.
#[test]
fn front_stays_within_a_slab() {
    let dims = [40u64, 40, 60];
    let c = [19.5f32, 19.5, 29.5];
    let data: Vec<f32> = (0..dims[2])
        .flat_map(|z| (0..dims[1]).flat_map(move |y| (0..dims[0]).map(move |x| (x, y, z))))
        .map(|(x, y, z)| {
            // A long capsule along z: the surface crosses every slab.
            let (dx, dy) = (x as f32 - c[0], y as f32 - c[1]);
            let dz = ((z as f32 - c[2]).abs() - 20.0).max(0.0);
            15.0 - (dx * dx + dy * dy + dz * dz).sqrt()
        })
        .collect();
    let (deltas, detector) = stream(dims, &data, 0.0, 256);
    let total: usize = deltas.iter().map(|d| d.vertices.len()).sum();
    let peak = detector.stats().peak_front as usize;
    assert!(peak * 10 < total, "front {peak} of {total} vertices");
    assert!(peak <= 3 * (dims[0] * dims[1]) as usize);
}

/// Attributes of new vertices travel with them, in the order of `vertices`.
#[test]
fn attributes_follow_new_vertices() {
    use isostream_extract::attributes::AttributeSlab;
    let grid = Grid::new([4, 4, 4], [1.0; 3], [0.0; 3]).unwrap();
    let mut data = vec![0.0f32; 64];
    data[21] = 1.0;
    data[22] = 1.0;
    let attr: Vec<f32> = (0..64).map(|i| i as f32).collect();
    let mut ex = Extractor::new(grid, 0.5);
    let mut det = Detector::new(grid.dims);
    let mut delta = MeshDelta::default();
    for z in 0..3 {
        let (lo, hi) = (&data[z * 16..][..16], &data[(z + 1) * 16..][..16]);
        let a = [AttributeSlab {
            lower: &attr[z * 16..][..16],
            upper: &attr[(z + 1) * 16..][..16],
        }];
        ex.extract_slab_with_attributes(z as u64, lo, hi, &a, None, 1000, |b| {
            det.process(&b, &mut delta);
            Ok::<_, ()>(())
        })
        .unwrap();
    }
    assert!(!delta.vertices.is_empty());
    assert_eq!(delta.attrs.len(), delta.vertices.len());
    // attr = x + 4y + 16z (grid units), linear: exact at every vertex.
    for (v, a) in delta.vertices.iter().zip(&delta.attrs) {
        let want = v.pos.x + 4.0 * v.pos.y + 16.0 * v.pos.z;
        assert!((f64::from(*a) - want).abs() < 1e-4, "{v:?} {a}");
    }
}
