//! More room never gives a worse surface (issue "Quality at low rates"): in mode `rate`, a larger
//! `batch` or a larger memory budget may only bring the output closer to the in-core result, so
//! its RMS distance to the full-resolution surface must not rise beyond noise.

mod common;

use common::{Mesh, random_blobs, run_job};
use isostream_measure::{MeasureOptions, surface_distances};
use isostream_volume::{Grid, MemoryVolume};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// RMS distance (both directions) between the job's output and the full-resolution surface.
/// Also the faces written and the peak of resident faces.
fn rms(vol: &common::TestVolume, simplify: &str, pipeline: &str) -> (f64, u64, u64) {
    let dir = tempfile::tempdir().unwrap();
    let job = vol.job(dir.path(), simplify, "out.smb");
    let text = std::fs::read_to_string(&job).unwrap() + pipeline;
    std::fs::write(&job, text).unwrap();
    let summary = run_job(&job);
    let mesh = Mesh::read(&dir.path().join("out.smb"));
    let grid = Grid::new(vol.dims, [1.0; 3], [0.0; 3]).unwrap();
    let source = MemoryVolume::new(grid, vol.data.clone()).unwrap();
    let opts = MeasureOptions {
        samples_per_area: 20.0,
        seed: 7,
        max_distance: None,
    };
    let d = surface_distances(
        || Ok(source.clone()),
        vol.iso,
        &mesh.positions,
        &mesh.triangles,
        &opts,
    )
    .unwrap();
    (d.rms, summary.faces_written, summary.peak_resident_faces)
}

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 10,
        // The RMS comparisons hold up to chance (see `within_noise`), so CI draws the same ten
        // cases every run; set ROOM_SEED to another number to explore others.
        rng_seed: RngSeed::Fixed(
            std::env::var("ROOM_SEED")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(20261127),
        ),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// Noise: the two runs contract different edges in a different order, so their RMS differ by
/// chance, and the fewer faces the output keeps the larger that chance: each face's error is a
/// sample, and the spread of a mean of `faces` samples shrinks as one over its square root. 15 %
/// plus two over the square root of the faces written, plus a hundredth of a voxel, covers that
/// on these volumes (a 92-face output once came out 18 % apart between two batches, the larger
/// one within 2 % of the budget-bound default's RMS; over 800 drawn comparisons the largest used
/// 38 % of this bound), while retiring by a fixed lag (the old design) raised the RMS by 2x to
/// 10x.
fn within_noise(more_room: f64, less_room: f64, faces: u64) -> bool {
    let chance = 0.15 + 2.0 / (faces.max(1) as f64).sqrt();
    more_room <= (1.0 + chance) * less_room + 0.01
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn a_larger_batch_never_raises_the_rms(
        n in 40u64..52, blobs in 2usize..4, seed in any::<u64>(),
        rate in 0.02f64..0.2, batch in 100u64..400,
    ) {
        let vol = random_blobs([n, n + 2, n + 1], blobs, seed);
        let simplify = |b: u64| format!("mode = \"rate\"\nrate = {rate}\nbatch = {b}");
        let (base, faces, _) = rms(&vol, &simplify(batch), "");
        let (bigger, faces_b, _) = rms(&vol, &simplify(4 * batch), "");
        prop_assert!(within_noise(bigger, base, faces), "batch {batch}: {base}, 4x: {bigger}");
        prop_assert!(faces_b.abs_diff(faces) * 50 <= faces.max(50), "{faces} vs {faces_b}");
        // Unset (the default): decimation waits for the memory budget, the most room of all.
        let (unset, faces_u, _) = rms(&vol, &format!("mode = \"rate\"\nrate = {rate}"), "");
        prop_assert!(within_noise(unset, base, faces), "batch {batch}: {base}, unset: {unset}");
        prop_assert!(faces_u.abs_diff(faces) * 50 <= faces.max(50), "{faces} vs {faces_u}");
    }

    /// The smallest budget (16 MiB: about 6,000 resident faces) binds on these surfaces (about
    /// 10,000 output faces); the default does not.
    #[test]
    fn a_larger_memory_budget_never_raises_the_rms(
        n in 60u64..68, blobs in 2usize..4, seed in any::<u64>(),
        rate in 0.3f64..0.5,
    ) {
        let vol = random_blobs([n, n + 2, n + 1], blobs, seed);
        let simplify = format!("mode = \"rate\"\nrate = {rate}\nbatch = 1000");
        let (default, faces, peak) = rms(&vol, &simplify, "");
        let (tight, _, tight_peak) = rms(&vol, &simplify, "memory_budget_mib = 16\n");
        prop_assume!(faces > 6000);
        prop_assert!(within_noise(default, tight, faces), "budget 16 MiB: {tight}, default: {default}");
        prop_assert!(tight_peak < peak, "the tight budget did not bind: {tight_peak} vs {peak} faces");
    }
}

/// The case CI drew on 2026-11-26: 92 faces written, batch 148 gave an RMS of 0.398 and four
/// times that batch 0.471 (the budget-bound default 0.479): chance between two orders, not lost
/// room, and the noise bound above must say so.
#[test]
fn a_tiny_output_is_judged_with_its_chance() {
    let vol = random_blobs([43, 45, 44], 2, 1995461111622762899);
    let simplify = |b: u64| format!("mode = \"rate\"\nrate = 0.02570385863371718\nbatch = {b}");
    let (base, faces, _) = rms(&vol, &simplify(148), "");
    let (bigger, _, _) = rms(&vol, &simplify(4 * 148), "");
    assert!(
        within_noise(bigger, base, faces),
        "{base} vs {bigger} at {faces} faces"
    );
}
