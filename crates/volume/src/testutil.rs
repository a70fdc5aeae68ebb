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

/// [`read_all`], and the source's count of saturated voxels after it
/// ([`crate::VolumeSource::saturated_voxels`]).
pub(crate) fn read_all_saturated(
    path: &Path,
    opts: &OpenOptions,
) -> Result<(Vec<f32>, u64), VolumeError> {
    let mut v = open_path(path, opts)?;
    let g = v.grid();
    let mut all = Vec::new();
    let mut out = vec![0.0f32; g.slice_len()];
    for z in 0..g.dims[2] {
        v.read_slice(z, &mut out)?;
        all.extend_from_slice(&out);
    }
    Ok((all, v.saturated_voxels()))
}

/// 24 f64 values, five of them finite beyond f32's range, one infinite and one NaN; and what
/// they read as, saturated: the values every reader's saturation test stores.
pub(crate) fn beyond_f32() -> (Vec<f64>, Vec<f32>, u64) {
    let mut values: Vec<f64> = (0..24).map(|i| f64::from(i) - 7.5).collect();
    for (i, v) in [
        (1, 1e40),
        (4, -1e39),
        (9, 3e300),
        (10, f64::MAX),
        (17, -1e100),
    ] {
        values[i] = v;
    }
    values[20] = f64::INFINITY;
    values[22] = f64::NAN;
    let want = values
        .iter()
        .map(|&v| match v {
            v if v.is_finite() && v.abs() > 1e38 => f32::MAX.copysign(v as f32),
            v => v as f32,
        })
        .collect();
    (values, want, 5)
}

/// Equal as voxel values: NaN equals NaN.
pub(crate) fn same_values(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| x == y || (x.is_nan() && y.is_nan()))
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
