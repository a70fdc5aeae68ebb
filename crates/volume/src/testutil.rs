//! Helpers shared by the readers' unit tests.

use crate::{OpenOptions, VolumeError, open_path};
use flate2::Compression;
use flate2::write::GzEncoder;
use std::io::Write;
use std::path::Path;

pub(crate) fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Opens `path` with `opts` and reads every slice in order.
pub(crate) fn read_all(path: &Path, opts: &OpenOptions) -> Result<Vec<f32>, VolumeError> {
    let mut v = open_path(path, opts)?;
    let g = v.grid();
    let mut all = Vec::new();
    let mut out = vec![0.0f32; g.slice_len()];
    for z in 0..g.dims[2] {
        v.read_slice(z, &mut out)?;
        all.extend_from_slice(&out);
    }
    Ok(all)
}

/// [`read_all`] with default options, as text: the one-line error message, or "Ok".
pub(crate) fn outcome(path: &Path) -> String {
    match read_all(path, &OpenOptions::default()) {
        Ok(_) => "Ok".to_string(),
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line message: {msg}");
            msg
        }
    }
}

/// Asserts every (got, want) pair is equal, listing all mismatches at once.
pub(crate) fn assert_all_equal(pairs: impl IntoIterator<Item = (String, String)>) {
    let wrong: Vec<String> = pairs
        .into_iter()
        .filter(|(got, want)| got != want)
        .map(|(got, want)| format!("got  {got}\nwant {want}"))
        .collect();
    assert!(wrong.is_empty(), "\n{}", wrong.join("\n"));
}

pub(crate) fn as_f32(v: &[f64]) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}
