//! Damaged inputs end in one-line errors, never panics, and every format is recognised from its
//! first bytes when the file name has no known extension.

use crate::testutil::{outcome, read_all};
use crate::{OpenOptions, nifti, nrrd, tiff, vti, vtk};
use proptest::prelude::*;

fn samples() -> Vec<(&'static str, Vec<u8>)> {
    [
        nrrd::tests::samples(),
        vtk::tests::samples(),
        vti::tests::samples(),
        nifti::tests::samples(),
        tiff::tests::samples(),
    ]
    .concat()
}

#[test]
fn samples_are_valid_and_found_by_magic() {
    let dir = tempfile::tempdir().unwrap();
    for (i, (name, bytes)) in samples().into_iter().enumerate() {
        let named = dir.path().join(name);
        std::fs::write(&named, &bytes).unwrap();
        let want = read_all(&named, &OpenOptions::default()).unwrap();
        assert_eq!(want.len(), 24, "{name} #{i}");
        if name.ends_with(".gz") {
            continue; // a gzip stream says nothing about what it holds
        }
        let bare = dir.path().join(format!("noext{i}"));
        std::fs::write(&bare, &bytes).unwrap();
        assert_eq!(
            read_all(&bare, &OpenOptions::default()).unwrap(),
            want,
            "{name} #{i}"
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Truncate a valid file and overwrite a few bytes: opening and reading must return (Ok or a
    /// one-line error) without panicking, whatever was hit.
    #[test]
    fn damaged_files_never_panic(
        pick in any::<prop::sample::Index>(),
        cut in 0.0f64..=1.0,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..4),
    ) {
        let all = samples();
        let (name, mut bytes) = all[pick.index(all.len())].clone();
        bytes.truncate((bytes.len() as f64 * cut) as usize);
        if !bytes.is_empty() {
            for (at, v) in edits {
                let i = at.index(bytes.len());
                bytes[i] = v;
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(name);
        std::fs::write(&p, &bytes).unwrap();
        // `outcome` asserts the message is one line.
        let _ = outcome(&p);
    }
}
