//! Issue 10 (gigavoxel scale): what must not change the output. Parallel extraction gives the
//! same bytes for any number of threads.

mod common;

use std::path::Path;

use common::{TestVolume, random_blobs, random_levels, run_job};
use proptest::prelude::*;

/// Runs `vol` with `simplify` and extra `[pipeline]` lines in `dir` (the header names the input
/// path, so runs to compare share it); returns the output's bytes.
fn output_bytes(dir: &Path, vol: &TestVolume, simplify: &str, pipeline: &str) -> Vec<u8> {
    let job = vol.job(dir, simplify, "out.smb");
    let mut text = std::fs::read_to_string(&job).unwrap();
    text.push_str(pipeline);
    std::fs::write(&job, text).unwrap();
    run_job(&job);
    std::fs::read(dir.join("out.smb")).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 16, failure_persistence: None, ..ProptestConfig::default() })]

    /// Slabs extracted by 1, 2 or 4 workers reach the detector in the same order: same bytes.
    #[test]
    fn thread_count_does_not_change_the_output(
        n in 6u64..24, levels in 2u32..5, seed in any::<u64>(), smooth in any::<bool>(),
        rate in 0.05f64..1.0, batch in 50u64..400,
    ) {
        let vol = if smooth {
            random_blobs([n + 2, n, n + 1], 3, seed)
        } else {
            random_levels([n, n + 1, n / 2 + 2], levels, 1.0, seed)
        };
        let simplify = format!("mode = \"rate\"\nrate = {rate}\nbatch = {batch}");
        let dir = tempfile::tempdir().unwrap();
        let one = output_bytes(dir.path(), &vol, &simplify, "threads = 1\n");
        for threads in [2, 4] {
            let many = output_bytes(dir.path(), &vol, &simplify, &format!("threads = {threads}\n"));
            prop_assert!(one == many, "{threads} threads changed the output");
        }
    }
}
