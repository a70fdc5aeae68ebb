//! Whole-surface properties: the reference surface is a valid manifold on any volume, the
//! streaming extractor produces exactly the reference surface, and known shapes have the
//! expected topology and orientation.

use std::f64::consts::PI;

use glam::DVec3;
use isostream_extract::{
    CubeBatch, EdgeKey, ExtractStats, Extractor, IndexedSurface, extract_indexed,
};
use isostream_meshcheck::{Report, check};
use isostream_volume::{Grid, MemoryVolume};
use proptest::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};

fn reference(grid: Grid, data: &[f32], iso: f32) -> IndexedSurface {
    let mut volume = MemoryVolume::new(grid, data.to_vec()).unwrap();
    extract_indexed(&mut volume, iso).unwrap()
}

fn report(s: &IndexedSurface) -> Report {
    check(&s.position_arrays(), &s.triangles)
}

/// Rotates a triangle so its smallest key comes first: same triangle, same orientation.
fn canonical(t: [EdgeKey; 3]) -> [EdgeKey; 3] {
    let i = (0..3).min_by_key(|&i| t[i]).unwrap();
    [t[i], t[(i + 1) % 3], t[(i + 2) % 3]]
}

/// Everything the streaming extractor emitted over the whole volume, after checking the batch
/// contract (slab order, end flags, traversal order, cube ranges).
struct Streamed {
    positions: FxHashMap<EdgeKey, DVec3>,
    triangles: Vec<[EdgeKey; 3]>,
    batches: usize,
    stats: ExtractStats,
}

fn stream(grid: Grid, data: &[f32], iso: f32, max_triangles: usize) -> Streamed {
    let (batches, stats) = extract(Extractor::new(grid, iso), grid, data, max_triangles);
    let mut out = Streamed {
        positions: FxHashMap::default(),
        triangles: Vec::new(),
        batches: batches.len(),
        stats,
    };
    let mut previous_coord = None;
    let mut expected_slab = 0;
    for b in &batches {
        assert_eq!(b.slab, expected_slab);
        if b.end_of_slab {
            expected_slab += 1;
        } else {
            assert!(
                !b.cubes.is_empty(),
                "only the last batch of a slab may be empty"
            );
        }
        let mut next_vertex = 0;
        let mut next_triangle = 0;
        for cube in &b.cubes {
            assert_eq!(cube.coord[2], b.slab);
            let key = [cube.coord[2], cube.coord[1], cube.coord[0]];
            assert!(previous_coord < Some(key), "cubes out of traversal order");
            previous_coord = Some(key);
            assert_eq!(cube.first_vertex, next_vertex);
            assert_eq!(cube.first_triangle, next_triangle);
            assert!(cube.vertex_count >= 3 && cube.triangle_count >= 1);
            next_vertex += u32::from(cube.vertex_count);
            next_triangle += u32::from(cube.triangle_count);
            for t in b.cube_triangles(cube) {
                assert!(t.iter().all(|&i| i < cube.vertex_count));
            }
            for v in b.cube_vertices(cube) {
                // The same edge gets the same position in every cube that uses it.
                let p = *out.positions.entry(v.key).or_insert(v.pos);
                assert_eq!(p, v.pos, "{:?}", v.key);
            }
        }
        assert_eq!(next_vertex as usize, b.vertices.len());
        assert_eq!(next_triangle as usize, b.triangle_count());
        out.triangles.extend(b.keyed_triangles());
    }
    assert_eq!(expected_slab, grid.dims[2] - 1, "one end_of_slab per slab");
    out
}

/// Every slab's batches from `extractor`, in order, and its counters after the volume.
fn extract(
    mut extractor: Extractor,
    grid: Grid,
    data: &[f32],
    max_triangles: usize,
) -> (Vec<CubeBatch>, ExtractStats) {
    let n = grid.slice_len();
    let mut batches = Vec::new();
    for z in 0..grid.dims[2] - 1 {
        let z_ = z as usize;
        let (lower, upper) = (&data[z_ * n..][..n], &data[(z_ + 1) * n..][..n]);
        extractor
            .extract_slab(z, lower, upper, max_triangles, |b| {
                batches.push(b);
                Ok::<_, ()>(())
            })
            .unwrap();
    }
    (batches, extractor.stats())
}

/// Undirected edges used by exactly one triangle, as vertex keys.
fn boundary_edges(s: &IndexedSurface) -> Vec<[EdgeKey; 2]> {
    let mut count: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    for t in &s.triangles {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    count
        .into_iter()
        .filter(|&(_, c)| c == 1)
        .map(|((a, b), _)| [s.keys[a as usize], s.keys[b as usize]])
        .collect()
}

/// Whether the vertex on `key` lies on box face (axis, side) of a grid of `dims`.
fn on_box_face(key: EdgeKey, dims: [u64; 3], axis: usize, side: bool) -> bool {
    let (voxel, edge_axis) = key.decode(dims);
    let at = if side { dims[axis] - 1 } else { 0 };
    edge_axis as usize != axis && voxel[axis] == at
}

/// Signed volume enclosed by the triangles (positive when normals point away from the enclosed
/// region).
fn signed_volume(s: &IndexedSurface) -> f64 {
    s.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| s.positions[i as usize]);
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

/// Samples `f` at every voxel position of `grid`, x fastest.
fn sample(grid: Grid, f: impl Fn(DVec3) -> f64) -> Vec<f32> {
    let [nx, ny, nz] = grid.dims;
    let mut data = Vec::with_capacity((nx * ny * nz) as usize);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                data.push(f(grid.position(x as f64, y as f64, z as f64)) as f32);
            }
        }
    }
    data
}

fn value() -> impl Strategy<Value = f32> {
    prop_oneof![
        20 => (0u8..4).prop_map(f32::from),
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
    ]
}

fn iso() -> impl Strategy<Value = f32> {
    prop_oneof![Just(0.5f32), Just(1.0), Just(1.5), Just(2.0), -0.5f32..3.5,]
}

/// A random volume (dims 2..=12 per axis, small integer values so the iso value often hits
/// voxel values exactly, a few non-finite values) with spacing and origin.
fn volume() -> impl Strategy<Value = (Grid, Vec<f32>)> {
    (
        prop::array::uniform3(2u64..=12),
        prop::array::uniform3(0.25f64..2.0),
        prop::array::uniform3(-10.0f64..10.0),
    )
        .prop_flat_map(|(dims, spacing, origin)| {
            let grid = Grid::new(dims, spacing, origin).unwrap();
            let n = grid.voxel_count() as usize;
            (Just(grid), prop::collection::vec(value(), n))
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn reference_is_a_valid_manifold_bounded_by_the_box((grid, data) in volume(), iso in iso()) {
        let s = reference(grid, &data, iso);
        let r = report(&s);
        prop_assert!(r.is_valid_manifold(), "{:?}", r);
        prop_assert_eq!(r.repeated_index_triangles, 0);
        // Every vertex lies on its grid edge.
        for (key, pos) in s.keys.iter().zip(&s.positions) {
            let (start, axis) = key.decode(grid.dims);
            let mut end = start;
            end[axis as usize] += 1;
            let p = |v: [u64; 3]| grid.position(v[0] as f64, v[1] as f64, v[2] as f64);
            let (a, b) = (p(start), p(end));
            let t = (*pos - a).dot(b - a) / (b - a).length_squared();
            prop_assert!((-1e-12..=1.0 + 1e-12).contains(&t), "{:?} at t = {}", key, t);
            prop_assert!((*pos - a.lerp(b, t)).length() < 1e-9 * (1.0 + a.length()), "{:?} off its edge", key);
        }
        for [a, b] in boundary_edges(&s) {
            let shared = (0..3).any(|axis| {
                [false, true].into_iter().any(|side| {
                    on_box_face(a, grid.dims, axis, side) && on_box_face(b, grid.dims, axis, side)
                })
            });
            prop_assert!(shared, "boundary edge {:?}-{:?} inside the box", a, b);
        }
    }

    #[test]
    fn surface_is_closed_when_the_border_is_outside(
        (grid, mut data) in volume(),
        iso in iso(),
        border in prop_oneof![Just(0), Just(1), Just(2)],
    ) {
        let border = [iso, f32::NAN, iso - 1.0][border];
        let [nx, ny, nz] = grid.dims;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    if x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1 {
                        data[(x + nx * (y + ny * z)) as usize] = border;
                    }
                }
            }
        }
        let r = report(&reference(grid, &data, iso));
        prop_assert!(r.is_closed_manifold(), "{:?}", r);
        // Every component of a closed orientable surface has an even Euler characteristic.
        prop_assert!(r.components.iter().all(|c| c.euler % 2 == 0 && c.euler <= 2), "{:?}", r);
    }

    #[test]
    fn streaming_equals_reference(
        (grid, data) in volume(),
        iso in iso(),
        max_triangles in prop_oneof![Just(0usize), 1usize..40, Just(usize::MAX)],
    ) {
        let s = reference(grid, &data, iso);
        let streamed = stream(grid, &data, iso, max_triangles);

        let mut want: Vec<_> = s.triangles.iter().map(|t| canonical(t.map(|i| s.keys[i as usize]))).collect();
        let mut got: Vec<_> = streamed.triangles.iter().copied().map(canonical).collect();
        want.sort_unstable();
        got.sort_unstable();
        prop_assert_eq!(got, want);

        prop_assert_eq!(streamed.positions.len(), s.keys.len());
        for (key, pos) in s.keys.iter().zip(&s.positions) {
            prop_assert_eq!(streamed.positions.get(key), Some(pos));
        }

        let [nx, ny, nz] = grid.dims;
        let stats = streamed.stats;
        prop_assert_eq!(stats.cubes, (nx - 1) * (ny - 1) * (nz - 1));
        prop_assert_eq!(stats.triangles, s.triangles.len() as u64);
        prop_assert_eq!(stats.non_finite_voxels, data.iter().filter(|v| !v.is_finite()).count() as u64);
        prop_assert!(stats.active_cubes <= stats.cubes && stats.active_cubes <= stats.triangles);
        if max_triangles == usize::MAX {
            prop_assert_eq!(streamed.batches as u64, nz - 1);
        }
    }
}

/// A group of batches (see `CubeBatch::ends_group`) as one: its slab, its cubes' coordinates,
/// its triangles by key and whether it ends the slab.
type Group = (u64, Vec<[u64; 3]>, Vec<[EdgeKey; 3]>, bool);

fn groups(batches: &[CubeBatch]) -> Vec<Group> {
    let mut out = Vec::new();
    let mut open: Option<Group> = None;
    for b in batches {
        let g = open.get_or_insert_with(|| (b.slab, Vec::new(), Vec::new(), false));
        assert_eq!(g.0, b.slab, "a group within one slab");
        g.1.extend(b.cubes.iter().map(|c| c.coord));
        g.2.extend(b.keyed_triangles());
        g.3 = b.end_of_slab;
        assert!(
            !b.end_of_slab || b.ends_group,
            "the end of a slab ends its group"
        );
        if b.ends_group {
            out.extend(open.take());
        }
    }
    assert!(open.is_none(), "every group ends");
    out
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Chunking cuts groups into smaller batches and changes nothing else: joined, the chunks
    /// of each group are the batch an unchunked extractor sends, group by group.
    #[test]
    fn chunked_batches_join_into_the_same_groups(
        (grid, data) in volume(),
        iso in iso(),
        max_triangles in prop_oneof![Just(0usize), 1usize..40, Just(usize::MAX)],
        chunk in 1usize..12,
    ) {
        let (whole, _) = extract(Extractor::new(grid, iso), grid, &data, max_triangles);
        prop_assert!(whole.iter().all(|b| b.ends_group));
        let (chunked, _) = extract(Extractor::new(grid, iso).chunked(chunk), grid, &data, max_triangles);
        prop_assert!(chunked.iter().all(|b| b.triangle_count() < chunk + grid.dims[0] as usize * 5));
        prop_assert_eq!(groups(&chunked), groups(&whole));
    }
}

#[test]
fn sphere_is_closed_genus_zero_and_outward() {
    let grid = Grid::new([24, 20, 22], [0.5, 0.6, 0.55], [-6.0, -5.5, -5.8]).unwrap();
    let (centre, radius) = (DVec3::new(0.2, -0.1, 0.3), 4.0);
    let data = sample(grid, |p| radius - (p - centre).length());
    let s = reference(grid, &data, 0.0);
    let r = report(&s);
    assert!(r.is_closed_manifold(), "{r:?}");
    assert_eq!((r.components.len(), r.euler()), (1, 2), "{r:?}");
    assert_eq!(r.zero_area_triangles, 0);
    let v = signed_volume(&s);
    let exact = 4.0 / 3.0 * PI * radius.powi(3);
    assert!(
        v > 0.0 && (v - exact).abs() < 0.03 * exact,
        "{v} vs {exact}"
    );
    // Vertices lie close to the sphere.
    for p in &s.positions {
        assert!(((*p - centre).length() - radius).abs() < 0.1, "{p}");
    }
}

#[test]
fn hollow_shell_has_two_spheres_enclosing_the_shell_volume() {
    let grid = Grid::new([26, 26, 26], [0.4; 3], [-5.0; 3]).unwrap();
    let (inner, outer) = (2.0, 4.0);
    // Inside between the radii: high values in the shell.
    let data = sample(grid, |p| 1.0 - (p.length() - 3.0).abs());
    let s = reference(grid, &data, 0.0);
    let r = report(&s);
    assert!(r.is_closed_manifold(), "{r:?}");
    assert_eq!(r.sorted_eulers(), [2, 2]);
    let exact = 4.0 / 3.0 * PI * (outer * outer * outer - inner * inner * inner);
    let v = signed_volume(&s);
    assert!((v - exact).abs() < 0.03 * exact, "{v} vs {exact}");
}

#[test]
fn torus_is_closed_genus_one() {
    let grid = Grid::new([40, 40, 16], [0.3; 3], [-6.0, -6.0, -2.4]).unwrap();
    let (major, minor) = (3.5, 1.2);
    let data = sample(grid, |p| {
        let ring = (p.x * p.x + p.y * p.y).sqrt() - major;
        minor - (ring * ring + p.z * p.z).sqrt()
    });
    let s = reference(grid, &data, 0.0);
    let r = report(&s);
    assert!(r.is_closed_manifold(), "{r:?}");
    assert_eq!((r.components.len(), r.euler()), (1, 0), "{r:?}");
    let exact = 2.0 * PI * PI * major * minor * minor;
    let v = signed_volume(&s);
    assert!(
        v > 0.0 && (v - exact).abs() < 0.05 * exact,
        "{v} vs {exact}"
    );
}

#[test]
fn streaming_matches_reference_on_a_smooth_field() {
    let grid = Grid::new([30, 26, 20], [1.0, 0.8, 1.2], [0.0; 3]).unwrap();
    // A gyroid-like field: many ambiguous faces and saddles.
    let data = sample(grid, |p| {
        let q = p * 0.7;
        q.x.sin() * q.y.cos() + q.y.sin() * q.z.cos() + q.z.sin() * q.x.cos()
    });
    for iso in [0.0, 0.3] {
        let s = reference(grid, &data, iso);
        let r = report(&s);
        assert!(r.is_valid_manifold(), "{r:?}");
        let streamed = stream(grid, &data, iso, 64);
        assert!(streamed.batches > (grid.dims[2] - 1) as usize);
        let want: FxHashSet<_> = s
            .triangles
            .iter()
            .map(|t| canonical(t.map(|i| s.keys[i as usize])))
            .collect();
        let got: FxHashSet<_> = streamed.triangles.iter().copied().map(canonical).collect();
        assert_eq!(got.len(), streamed.triangles.len());
        assert_eq!(got, want);
    }
}
