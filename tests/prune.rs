//! `[simplify] min_component_faces` (issue 9): on a volume of one large sphere among many small
//! blobs, the blobs are gone, the sphere is kept and the output stays valid (the referee:
//! manifold, oriented, Euler characteristic of the kept component, no crossings); without
//! simplification exactly the large component's triangles remain; 0 is the same bytes as no key;
//! a pruned job stopped at a checkpoint resumes to the same bytes; on random noisy fields, the
//! same holds for any size.

mod common;

use std::sync::atomic::{AtomicBool, Ordering};

use common::{Mesh, Rng, TestVolume, random_levels, run_job};
use isostream_pipeline::{JobConfig, Pass, Progress, RunError, Start, run_from};
use proptest::prelude::*;

/// One sphere of radius 9 at the centre and `blobs` spheres of radius 0.8 to 1.6 around it
/// (none touching it nor the box): `max` of signed distances, inside > 0.
fn speckled_sphere(blobs: usize, seed: u64) -> TestVolume {
    let dims = [36u64, 36, 44];
    let centre = [17.5, 17.5, 21.5];
    let mut rng = Rng(seed);
    let mut spheres = vec![(centre, 9.0)];
    while spheres.len() < blobs + 1 {
        let c = [0, 1, 2].map(|i| 3.0 + rng.unit() * (dims[i] as f64 - 7.0));
        let r = 0.8 + 0.8 * rng.unit();
        let dist = |a: [f64; 3], b: [f64; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>();
        if spheres
            .iter()
            .all(|&(o, s)| dist(c, o).sqrt() > r + s + 2.0)
        {
            spheres.push((c, r));
        }
    }
    let mut data = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = [x as f64, y as f64, z as f64];
                let v = spheres
                    .iter()
                    .map(|(c, r)| r - (0..3).map(|i| (p[i] - c[i]).powi(2)).sum::<f64>().sqrt())
                    .fold(f64::NEG_INFINITY, f64::max);
                data.push(v as f32);
            }
        }
    }
    TestVolume {
        dims,
        data,
        iso: 0.0,
    }
}

/// The full-resolution components' face counts, largest first.
fn reference_sizes(vol: &TestVolume) -> Vec<usize> {
    let mut sizes: Vec<usize> = vol
        .reference()
        .check()
        .components
        .iter()
        .map(|c| c.triangles)
        .collect();
    sizes.sort_unstable_by(|a, b| b.cmp(a));
    sizes
}

#[test]
fn small_components_are_pruned_and_the_large_one_is_kept_valid() {
    let vol = speckled_sphere(40, 7);
    let sizes = reference_sizes(&vol);
    let (big, small) = (sizes[0], &sizes[1..]);
    assert!(small.len() >= 40 && small.iter().all(|&s| s < 200) && big > 1000);
    let extracted: usize = sizes.iter().sum();

    for (simplify, rate) in [
        ("mode = \"rate\"\nrate = 0.05\nbatch = 500", Some(0.05)),
        ("mode = \"error\"\nerror = 0.3", None),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let job = vol.job(
            dir.path(),
            &format!("{simplify}\nmin_component_faces = 200"),
            "out.smb",
        );
        let summary = run_job(&job);
        let p = summary.prune.expect("pruning reported");
        assert_eq!(p.components_pruned as usize, small.len());
        assert_eq!(p.faces_pruned as usize, small.iter().sum::<usize>());
        assert_eq!(summary.faces_extracted as usize, extracted);
        assert_eq!(summary.faces_kept as usize, big);
        assert_eq!(
            summary.simplify.faces_in as usize, big,
            "the simplifier got the rest"
        );
        if let Some(rate) = rate {
            // R applies to the faces kept.
            let target = (rate * big as f64).round() as u64;
            assert_eq!(summary.target_faces, Some(target));
            assert!(
                summary.faces_written as f64 <= 1.02 * target as f64,
                "{} faces for {target}",
                summary.faces_written
            );
        }

        let mesh = Mesh::read(&dir.path().join("out.smb"));
        let report = mesh.check();
        assert!(report.is_closed_manifold(), "{simplify}: {report:?}");
        assert_eq!(report.misoriented_edges, 0);
        assert_eq!(report.components.len(), 1, "{simplify}");
        assert_eq!(report.sorted_eulers(), vec![2], "{simplify}");
        assert_eq!(mesh.self_intersections(), 0, "{simplify}");
    }
}

/// Without simplification, exactly the large component's triangles remain.
#[test]
fn without_simplification_exactly_the_large_components_remain() {
    let vol = speckled_sphere(30, 11);
    let sizes = reference_sizes(&vol);
    // A size between two blobs' sizes: some blobs stay.
    let blobs = &sizes[1..];
    let size = blobs[blobs.len() / 2] + 1;
    let kept: usize = sizes.iter().filter(|&&s| s >= size).sum();
    let dir = tempfile::tempdir().unwrap();
    let job = vol.job(
        dir.path(),
        &format!("mode = \"none\"\nmin_component_faces = {size}"),
        "out.sma",
    );
    let summary = run_job(&job);
    let mesh = Mesh::read(&dir.path().join("out.sma"));
    assert_eq!(mesh.triangles.len(), kept);
    assert_eq!(summary.faces_written as usize, kept);
    let reference = vol.reference().canonical_triangles();
    let out = mesh.canonical_triangles();
    assert!(out.iter().all(|t| reference.binary_search(t).is_ok()));
    let report = mesh.check();
    assert!(report.components.iter().all(|c| c.triangles >= size));
    assert_eq!(
        report.components.len(),
        sizes.iter().filter(|&&s| s >= size).count()
    );
}

#[test]
fn zero_is_the_same_bytes_as_no_key() {
    let vol = speckled_sphere(20, 3);
    // One folder: the header names the input's path.
    let dir = tempfile::tempdir().unwrap();
    let bytes = |extra: &str| {
        let job = vol.job(
            dir.path(),
            &format!("rate = 0.1\nbatch = 400\n{extra}"),
            "out.smb",
        );
        let summary = run_job(&job);
        assert!(summary.prune.is_none());
        std::fs::read(dir.path().join("out.smb")).unwrap()
    };
    let (without, zero) = (bytes(""), bytes("min_component_faces = 0"));
    assert!(without == zero, "{} vs {} bytes", without.len(), zero.len());
}

/// Stopped after a checkpoint (every slab or every few), resumed: the same bytes as a run that
/// went through (with the default threads), and the same counts.
#[test]
fn a_pruned_job_resumes_to_the_same_bytes() {
    let vol = speckled_sphere(40, 5);
    let dir = tempfile::tempdir().unwrap();
    let simplify = "rate = 0.1\nbatch = 500\nmin_component_faces = 150";
    let reference = vol.job(dir.path(), simplify, "ref.smb");
    let expected_summary = run_job(&reference);
    let expected = std::fs::read(dir.path().join("ref.smb")).unwrap();
    for (every, stop) in [(1, 9), (3, 20), (2, 33)] {
        // The same folder (the header names the input's path), another output.
        let output = format!("out{stop}.smb");
        let path = vol.job(dir.path(), simplify, &output);
        let text = std::fs::read_to_string(&path).unwrap()
            + &format!(
                "checkpoint = {{ every_slabs = {every} }}\nthreads = {}\n",
                every + 1
            );
        std::fs::write(&path, text).unwrap();
        let job = JobConfig::load(&path).unwrap();
        let cancel = AtomicBool::new(false);
        // The run's slabs: the census pass before it reports its own.
        let stopping = |p: &Progress| {
            if p.pass == Pass::Run && p.slabs_done >= stop {
                cancel.store(true, Ordering::Relaxed);
            }
        };
        match run_from(&job, &path, Start::Fresh, &cancel, &stopping) {
            Err(RunError::Interrupted { .. }) => {}
            other => panic!("stop at {stop}: {:?}", other.map(|s| s.faces_written)),
        }
        let summary =
            run_from(&job, &path, Start::Resume, &AtomicBool::new(false), &|_| {}).unwrap();
        assert!(summary.resumed_at_slab.is_some());
        let got = std::fs::read(dir.path().join(&output)).unwrap();
        assert!(
            got == expected,
            "stop at {stop}: {} vs {} bytes",
            got.len(),
            expected.len()
        );
        assert_eq!(summary.prune, expected_summary.prune);
        assert_eq!(summary.faces_kept, expected_summary.faces_kept);
        assert!(!dir.path().join(format!(".{output}.ckpt")).exists());
    }
}

/// `[output] faces`: the first pass counts the faces kept, and the rate is set from them.
#[test]
fn output_faces_apply_to_the_faces_kept() {
    let vol = speckled_sphere(40, 9);
    let big = reference_sizes(&vol)[0];
    let dir = tempfile::tempdir().unwrap();
    let job = vol.job(
        dir.path(),
        "batch = 500\nmin_component_faces = 200",
        "out.smb",
    );
    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace("allow_empty = true\n", "allow_empty = true\nfaces = 300\n");
    std::fs::write(&job, text).unwrap();
    let summary = run_job(&job);
    assert_eq!(summary.faces_kept as usize, big);
    assert_eq!(summary.rate, Some(300.0 / big as f64));
    assert_eq!(summary.target_faces, Some(300));
    assert!(summary.faces_written <= 306, "{}", summary.faces_written);
    assert!(summary.warnings.is_empty(), "{:?}", summary.warnings);
}

/// The reference surface's components of at least `n` triangles, compacted.
fn reference_kept(vol: &TestVolume, n: usize) -> Mesh {
    let full = vol.reference();
    let mut parent: Vec<usize> = (0..full.positions.len()).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    for t in &full.triangles {
        for k in 1..3 {
            let (a, b) = (
                find(&mut parent, t[0] as usize),
                find(&mut parent, t[k] as usize),
            );
            parent[b] = a;
        }
    }
    let root: Vec<usize> = full
        .triangles
        .iter()
        .map(|t| find(&mut parent, t[0] as usize))
        .collect();
    let mut faces = vec![0usize; full.positions.len()];
    root.iter().for_each(|&r| faces[r] += 1);
    let mut index = vec![u32::MAX; full.positions.len()];
    let mut mesh = Mesh {
        positions: Vec::new(),
        triangles: Vec::new(),
    };
    for (t, &r) in full.triangles.iter().zip(&root) {
        if faces[r] >= n {
            let t = t.map(|v| {
                if index[v as usize] == u32::MAX {
                    index[v as usize] = mesh.positions.len() as u32;
                    mesh.positions.push(full.positions[v as usize]);
                }
                index[v as usize]
            });
            mesh.triangles.push(t);
        }
    }
    mesh
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    /// Random integer fields (many small components, surfaces cut by the box), any size: without
    /// simplification exactly the reference's components of at least that size; simplified, a
    /// valid surface with their Euler characteristics and no crossing.
    #[test]
    fn any_size_keeps_exactly_the_large_components(
        nx in 4u64..14, ny in 4u64..14, nz in 4u64..14,
        levels in 2u32..5, iso_pick in 0usize..4, seed in any::<u64>(),
        size in 1u64..40, rate in 0.05f64..0.6,
    ) {
        let iso = [0.5f32, 1.0, 1.5, 2.0][iso_pick];
        let vol = random_levels([nx, ny, nz], levels, iso, seed);
        let want = reference_kept(&vol, size as usize);
        let dir = tempfile::tempdir().unwrap();
        let job = vol.job(dir.path(), &format!("mode = \"none\"\nmin_component_faces = {size}"), "none.smb");
        let summary = run_job(&job);
        let got = Mesh::read(&dir.path().join("none.smb"));
        prop_assert_eq!(got.canonical_triangles(), want.canonical_triangles());
        prop_assert_eq!(summary.faces_kept as usize, want.triangles.len());

        let simplify = format!("rate = {rate}\nbatch = 200\nmin_component_faces = {size}");
        let job = vol.job(dir.path(), &simplify, "rate.smb");
        let summary = run_job(&job);
        prop_assert_eq!(summary.simplify.faces_in as usize, want.triangles.len());
        let path = dir.path().join("rate.smb");
        isostream_smesh::validate(&path).unwrap();
        let mesh = Mesh::read(&path);
        let report = mesh.check();
        prop_assert!(report.is_valid_manifold(), "{report:?}");
        prop_assert_eq!(mesh.self_intersections(), 0);
        let want = want.check();
        prop_assert_eq!(report.sorted_eulers(), want.sorted_eulers());
        prop_assert_eq!(report.closed_by_sign(), want.closed_by_sign());
    }
}
