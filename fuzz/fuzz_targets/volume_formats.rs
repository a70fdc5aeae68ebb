//! Every volume reader on arbitrary bytes: the first byte picks the format (by file extension),
//! the rest is the file. Readers must return an error, never panic, hang or over-allocate.
//! A Zarr store is a directory: the rest up to the first NUL byte is its `zarr.json`, what follows
//! is written as chunk (0, 0, 0) under every key encoding.
#![no_main]

use std::io::Write;

use isostream_volume::{Dtype, OpenOptions, open_path};
use libfuzzer_sys::fuzz_target;

const EXTENSIONS: [&str; 8] = ["nrrd", "vtk", "vti", "nii", "nii.gz", "tif", "raw", "zarr"];

/// Chunk (0, 0, 0) of a 3-D array under the `default` and `v2` key encodings, both separators.
const ZARR_KEYS: [&str; 4] = ["c/0/0/0", "c.0.0.0", "0.0.0", "0/0/0"];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, body)) = data.split_first() else {
        return;
    };
    let ext = EXTENSIONS[pick as usize % EXTENSIONS.len()];
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join(format!("input.{ext}"));
    if ext == "zarr" {
        write_zarr(&path, body);
    } else {
        std::fs::File::create(&path)
            .and_then(|mut f| f.write_all(body))
            .expect("write input");
    }
    let opts = if ext == "raw" {
        OpenOptions {
            dims: Some([4, 4, 2]),
            dtype: Some(Dtype::U8),
            ..OpenOptions::default()
        }
    } else {
        OpenOptions::default()
    };
    if let Ok(mut source) = open_path(&path, &opts) {
        let grid = source.grid();
        // Bound the work on huge claimed dims: read a few slices of a bounded size only.
        if grid.slice_len() <= 1 << 20 {
            let mut slice = vec![0f32; grid.slice_len()];
            for z in 0..grid.dims[2].min(4) {
                if source.read_slice(z, &mut slice).is_err() {
                    break;
                }
            }
        }
    }
});

fn write_zarr(dir: &std::path::Path, body: &[u8]) {
    let split = body.iter().position(|&b| b == 0).unwrap_or(body.len());
    let (meta, chunk) = (&body[..split], body.get(split + 1..).unwrap_or_default());
    std::fs::create_dir_all(dir.join("c/0/0")).expect("store dirs");
    std::fs::create_dir_all(dir.join("0/0")).expect("store dirs");
    std::fs::write(dir.join("zarr.json"), meta).expect("write zarr.json");
    for key in ZARR_KEYS {
        std::fs::write(dir.join(key), chunk).expect("write chunk");
    }
}
