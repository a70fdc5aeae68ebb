//! End-to-end properties of `isostream run` over many generated volumes: the streamed
//! full-resolution surface equals plain in-memory marching cubes, and the simplified surface is a
//! valid manifold with the same topology and no self-intersection, within the face budget, in a
//! valid streaming file.

mod common;

use common::{Mesh, TestVolume, random_blobs, random_levels, run_job};
use isostream_meshcheck::Report;
use isostream_pipeline::RunSummary;
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 48,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Runs `vol` with the `[simplify]` lines `simplify` and checks what every simplified output must
/// be: a valid streaming file holding a valid oriented manifold that crosses nothing, with the
/// full surface's Euler characteristic in every component, closed iff that surface is, its cut
/// on the box's faces. Returns the run summary and the output's report.
fn simplified_keeps_the_surface(
    vol: &TestVolume,
    simplify: &str,
) -> Result<(RunSummary, Report), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let job = vol.job(dir.path(), simplify, "out.smb");
    let summary = run_job(&job);
    let path = dir.path().join("out.smb");
    isostream_smesh::validate(&path).unwrap();
    let mesh = Mesh::read(&path);
    let got = mesh.check();
    let want = vol.reference().check();
    prop_assert!(got.is_valid_manifold(), "{got:?}");
    prop_assert_eq!(mesh.self_intersections(), 0);
    prop_assert_eq!(got.sorted_eulers(), want.sorted_eulers());
    prop_assert_eq!(
        got.closed_by_sign(),
        want.closed_by_sign(),
        "turned inside out"
    );
    prop_assert_eq!(got.boundary_edges == 0, want.boundary_edges == 0);
    prop_assert_eq!(mesh.boundary_off_the_box(vol.dims), 0);
    Ok((summary, got))
}

proptest! {
    #![proptest_config(config())]

    /// mode = "none": same triangles, same orientation, as the in-memory reference, written as a
    /// valid streaming mesh (every vertex finalized exactly once, never used after).
    #[test]
    fn unsimplified_stream_equals_in_memory_marching_cubes(
        nx in 2u64..9, ny in 2u64..9, nz in 2u64..9,
        levels in 2u32..5, iso_pick in 0usize..4, seed in any::<u64>(),
        smb in any::<bool>(),
    ) {
        let iso = [0.5f32, 1.0, 1.5, 2.0][iso_pick];
        let vol = random_levels([nx, ny, nz], levels, iso, seed);
        let dir = tempfile::tempdir().unwrap();
        let out = if smb { "out.smb" } else { "out.sma" };
        let job = vol.job(dir.path(), "mode = \"none\"", out);
        let summary = run_job(&job);
        let path = dir.path().join(out);
        isostream_smesh::validate(&path).unwrap();
        let got = Mesh::read(&path);
        let want = vol.reference();
        prop_assert_eq!(summary.faces_written as usize, want.triangles.len());
        prop_assert_eq!(got.canonical_triangles(), want.canonical_triangles());
    }

    /// mode = "rate" on random integer fields (isos on grid values, surfaces touching the box):
    /// valid, oriented, same Euler characteristic per component, closed iff the reference is.
    #[test]
    fn simplified_random_fields_keep_topology(
        nx in 3u64..12, ny in 3u64..12, nz in 3u64..12,
        levels in 2u32..5, iso_pick in 0usize..4, seed in any::<u64>(),
        rate in 0.05f64..1.0, batch in 1u64..400,
    ) {
        let iso = [0.5f32, 1.0, 1.5, 2.0][iso_pick];
        let vol = random_levels([nx, ny, nz], levels, iso, seed);
        let simplify = format!("mode = \"rate\"\nrate = {rate}\nbatch = {batch}\ninitial_rate = 0.5");
        simplified_keeps_the_surface(&vol, &simplify)?;
    }

    /// Rates far below what these small surfaces can reach: the last passes run at the topology
    /// floor, where every remaining contraction is refused (the link condition keeps each closed
    /// component at least a tetrahedron; the box's cut stays on its faces; flips and crossings
    /// are refused). The output keeps the full surface's topology, crosses nothing, and the run
    /// says why it missed the target.
    #[test]
    fn rates_below_the_topology_floor_refuse_and_keep_the_surface(
        nx in 3u64..10, ny in 3u64..10, nz in 3u64..10,
        levels in 2u32..4, iso_pick in 0usize..4, seed in any::<u64>(),
        rate in 1e-4f64..1e-2,
    ) {
        let iso = [0.5f32, 1.0, 1.5, 2.0][iso_pick];
        let vol = random_levels([nx, ny, nz], levels, iso, seed);
        let (summary, _) = simplified_keeps_the_surface(&vol, &format!("mode = \"rate\"\nrate = {rate}"))?;
        let target = summary.target_faces.expect("mode rate has a target");
        if summary.faces_written as f64 > 1.02 * target as f64 {
            prop_assert!(
                summary.warnings.iter().any(|w| w.contains("target missed")),
                "{:?}", summary.warnings
            );
        }
    }

    /// mode = "rate" on smooth blob fields: as above, plus no zero-area triangles and the face
    /// count within 10 % of R times the input.
    #[test]
    fn simplified_smooth_fields_meet_the_rate(
        n in 30u64..48, blobs in 1usize..4, seed in any::<u64>(),
        rate in 0.1f64..0.6, batch in 100u64..600,
    ) {
        let vol = random_blobs([n, n + 3, n + 1], blobs, seed);
        let simplify = format!("mode = \"rate\"\nrate = {rate}\nbatch = {batch}\ninitial_rate = 0.5");
        let (summary, got) = simplified_keeps_the_surface(&vol, &simplify)?;
        prop_assert_eq!(got.zero_area_triangles, 0);
        // Small surfaces cannot always reach the rate: each closed component keeps its topology
        // and at least 4 triangles, and contractions that would fold or cross a sheet are
        // refused. Faces retired during the initial phase keep its rate (Hou and Chen 4.3), so
        // batches must be small against the surface. The 10 % promise is checked where the
        // target and the batch leave room for that.
        let target = rate * summary.faces_extracted as f64;
        let faces = summary.faces_written as f64;
        prop_assume!(target >= 1000.0 && batch as f64 <= 0.05 * summary.faces_extracted as f64);
        prop_assert!((faces - target).abs() <= 0.1 * target,
            "{faces} faces for a target of {target} ({} extracted)", summary.faces_extracted);
    }
}
