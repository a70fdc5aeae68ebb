//! End-to-end properties of the Tandem simplification (`mode = "error"`, with and without the
//! time-lag, any isotropy) and of its in-core baseline (`mode = "classical"`), on random smooth
//! volumes and on the procedural pillow, link and torus: the output is a valid manifold with the
//! topology of the full-resolution surface, the run's shape error `max eps0` is at most E0, and
//! the time-lag never contracts an edge whose reach is beyond the front.

mod common;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use common::{Mesh, random_blobs, run_job};
use isostream_pipeline::{JobConfig, RunError, RunSummary};
use proptest::prelude::*;

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// The `[simplify]` table of a run: classical, or Tandem with or without the time-lag.
fn simplify_table(classical: bool, e0: f64, alpha: f64, time_lag: bool) -> String {
    if classical {
        format!("mode = \"classical\"\nerror = {e0}\nisotropy = {alpha}")
    } else {
        format!("mode = \"error\"\nerror = {e0}\nisotropy = {alpha}\ntime_lag = {time_lag}")
    }
}

/// A job file for a procedural shape (field > 0 inside, iso 0).
fn shape_job(dir: &Path, shape: &str, size: [u64; 3], simplify: &str, output: &str) -> PathBuf {
    let job = dir.join(format!("{output}.toml"));
    let text = format!(
        "[input]\nshape = \"{shape}\"\nsize = [{}, {}, {}]\n\n[extract]\niso = 0.0\n\n[simplify]\n{simplify}\n\n[output]\npath = \"{output}\"\n\n[pipeline]\nchannel_capacity = 2\nbatch_triangles = 256\n",
        size[0], size[1], size[2]
    );
    std::fs::write(&job, text).unwrap();
    job
}

/// What every simplified run must satisfy, against the full-resolution surface `full`.
fn check_run(summary: &RunSummary, path: &Path, full: &Mesh, e0: f64) -> Result<(), TestCaseError> {
    isostream_smesh::validate(path).unwrap();
    let mesh = Mesh::read(path);
    let got = mesh.check();
    let want = full.check();
    prop_assert!(got.is_valid_manifold(), "{got:?}");
    prop_assert_eq!(got.zero_area_triangles, 0);
    prop_assert_eq!(got.sorted_eulers(), want.sorted_eulers());
    prop_assert_eq!(
        got.closed_by_sign(),
        want.closed_by_sign(),
        "turned inside out"
    );
    prop_assert_eq!(got.boundary_edges == 0, want.boundary_edges == 0);
    prop_assert!(
        summary.shape_error <= e0 + 1e-9,
        "shape error {} above E0 = {e0}",
        summary.shape_error
    );
    prop_assert_eq!(summary.simplify.lag_violations, 0);
    prop_assert!(mesh.triangles.len() <= full.triangles.len());
    Ok(())
}

proptest! {
    #![proptest_config(config(24))]

    /// Random smooth blob fields (closed surfaces and surfaces cut by the box), any E0 and alpha,
    /// time-lag on or off, or classical.
    #[test]
    fn tandem_on_smooth_fields_bounds_eps0_and_keeps_topology(
        n in 12u64..26, blobs in 1usize..4, seed in any::<u64>(),
        e0 in 0.01f64..1.5, alpha in prop_oneof![Just(0.0), 0.0f64..1.0],
        time_lag in any::<bool>(), classical in prop::bool::weighted(0.25),
        lag in 2u32..10,
    ) {
        let vol = random_blobs([n, n + 2, n + 1], blobs, seed);
        let dir = tempfile::tempdir().unwrap();
        let simplify = format!(
            "{}\nretire_lag = {lag}",
            simplify_table(classical, e0, alpha, time_lag)
        );
        let job = vol.job(dir.path(), &simplify, "out.smb");
        let summary = run_job(&job);
        check_run(&summary, &dir.path().join("out.smb"), &vol.reference(), e0)?;
    }

    /// The procedural pillow (flat faces, rounded edges), link (two rings, genus 2 overall) and
    /// torus, against their own full-resolution surfaces.
    #[test]
    fn tandem_on_procedural_shapes_bounds_eps0_and_keeps_topology(
        shape in prop::sample::select(vec!["pillow", "link", "torus"]),
        n in 20u64..36, e0 in 0.02f64..1.0, alpha in prop_oneof![Just(0.0), 0.0f64..1.0],
        time_lag in any::<bool>(), classical in prop::bool::weighted(0.25),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let size = [n, n + 1, n + 2];
        let full_job = shape_job(dir.path(), shape, size, "mode = \"none\"", "full.smb");
        run_job(&full_job);
        let full = Mesh::read(&dir.path().join("full.smb"));
        let simplify = simplify_table(classical, e0, alpha, time_lag);
        let job = shape_job(dir.path(), shape, size, &simplify, "out.smb");
        let summary = run_job(&job);
        check_run(&summary, &dir.path().join("out.smb"), &full, e0)?;
        prop_assert!(summary.faces_written < summary.faces_extracted, "nothing was contracted");
    }
}

/// Classical keeps everything resident until the end, so it does not stream out early; the
/// streaming run with the same E0 does.
#[test]
fn classical_holds_the_whole_surface_and_tandem_streams() {
    let dir = tempfile::tempdir().unwrap();
    let size = [40, 40, 40];
    run_job(&shape_job(
        dir.path(),
        "link",
        size,
        "mode = \"none\"",
        "full.smb",
    ));
    let full = Mesh::read(&dir.path().join("full.smb"));
    let run = |simplify: &str, out: &str| {
        let summary = run_job(&shape_job(dir.path(), "link", size, simplify, out));
        check_run(&summary, &dir.path().join(out), &full, 0.3).unwrap();
        summary
    };
    let classical = run(&simplify_table(true, 0.3, 0.0, false), "classical.smb");
    let tandem = run(&simplify_table(false, 0.3, 0.0, true), "tandem.smb");
    assert_eq!(
        classical.peak_resident_faces, classical.faces_extracted,
        "classical holds the whole full-resolution surface"
    );
    assert!(tandem.peak_resident_faces < tandem.faces_extracted / 2);
    assert!(classical.faces_written < classical.faces_extracted / 2);
}

/// Classical above the memory budget stops with a one-line error naming the keys to change, and
/// leaves no output file.
#[test]
fn classical_above_the_memory_budget_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let simplify = simplify_table(true, 0.2, 0.0, false);
    let job = shape_job(dir.path(), "gyroid", [96, 96, 96], &simplify, "out.smb");
    let text = std::fs::read_to_string(&job).unwrap() + "memory_budget_mib = 16\n";
    std::fs::write(&job, text).unwrap();
    let config = JobConfig::load(&job).unwrap();
    config.validate(&job).unwrap();
    let cancel = AtomicBool::new(false);
    let err = isostream_pipeline::run(&config, &job, &cancel, &|_| {}).unwrap_err();
    assert!(
        matches!(err, RunError::ClassicalOverBudget { .. }),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(!msg.contains('\n'), "{msg}");
    for key in [
        "simplify.mode",
        "pipeline.memory_budget_mib",
        "mode = \"error\"",
    ] {
        assert!(msg.contains(key), "{msg}");
    }
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| !name.ends_with(".toml"))
        .collect();
    assert!(left.is_empty(), "files left behind: {left:?}");
}
