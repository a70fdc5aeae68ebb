//! Zarr v2 and OME-Zarr v0.4 stores written by zarr-python 2 and numcodecs
//! (`tools/make_zarr_fixtures.py`, committed under `tests/data/zarr/stores`), and Zarr v3 arrays
//! whose chunks are numcodecs' Blosc frames: read voxel for voxel, with the metadata's geometry;
//! damaged or unsupported stores end in one-line errors.

use super::read_all;
use crate::store::write_json;
use isostream_volume::{Dtype, OpenOptions, open_path};
use std::path::{Path, PathBuf};

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/zarr")
        .join(rel)
}

/// The generator's `value`: every store's voxels (before any chunk left out).
fn value(z: u64, y: u64, x: u64, signed: bool) -> f64 {
    let v = ((z * 31 + y * 7 + x * 3) % 101) as f64;
    if signed { v - 50.0 } else { v }
}

/// The full-resolution level of `ome_v04.zarr`: value() x 600 as uint16, chunk (1, 0, 0) of
/// 4 x 5 x 6 zero (and not written).
fn ome_s0(z: u64, y: u64, x: u64) -> f32 {
    if (z / 4, y / 5, x / 6) == (1, 0, 0) {
        0.0
    } else {
        (value(z, y, x, false) * 600.0) as f32
    }
}

/// The OME-Zarr v0.4 store (Blosc lz4 + byte shuffle, u16, two levels, anisotropic voxels) is
/// read voxel for voxel at both levels with each level's spacing and origin.
#[test]
fn ome_zarr_v04_store_reads_voxel_for_voxel() {
    let store = data("stores/ome_v04.zarr");
    assert!(
        !store.join("s0/1/0/0").exists(),
        "the zero chunk is left out"
    );
    let v = open_path(&store, &OpenOptions::default()).unwrap();
    let g = v.grid();
    assert_eq!(
        (g.dims, g.spacing, g.origin),
        ([14, 12, 10], [0.5, 0.5, 2.0], [0.0; 3])
    );
    assert_eq!(v.dtype(), Some(Dtype::U16));
    let want: Vec<f32> = (0..10)
        .flat_map(|z| (0..12).flat_map(move |y| (0..14).map(move |x| ome_s0(z, y, x))))
        .collect();
    assert_eq!(read_all(&store, &OpenOptions::default()).unwrap(), want);
    // The group's .zattrs names the same store.
    assert_eq!(
        read_all(&store.join(".zattrs"), &OpenOptions::default()).unwrap(),
        want
    );

    let s1 = OpenOptions {
        array: Some("s1".into()),
        ..Default::default()
    };
    let v1 = open_path(&store, &s1).unwrap();
    let g1 = v1.grid();
    assert_eq!(
        (g1.dims, g1.spacing, g1.origin),
        ([7, 6, 10], [1.0, 1.0, 2.0], [0.25, 0.25, 0.0])
    );
    let want1: Vec<f32> = (0..10)
        .flat_map(|z| (0..6).flat_map(move |y| (0..7).map(move |x| ome_s0(z, 2 * y, 2 * x))))
        .collect();
    assert_eq!(read_all(&store, &s1).unwrap(), want1);

    let nope = OpenOptions {
        array: Some("s9".into()),
        ..Default::default()
    };
    assert_eq!(
        open_path(&store, &nope).err().unwrap().to_string(),
        format!(
            "{}: document: [input] array \"s9\" is not a level of this OME-Zarr image; levels are [s0, s1]",
            store.join(".zattrs").display()
        )
    );
    // A level opened directly is a bare array: no geometry.
    let bare = open_path(&store.join("s0"), &OpenOptions::default()).unwrap();
    assert_eq!(bare.grid().spacing, [1.0; 3]);
}

/// Bare Zarr v2 arrays of every compressor, both byte orders, order "F", both key separators,
/// fill values (NaN, numbers, null) where a chunk was left out, and a leading axis of size 1.
#[test]
fn bare_v2_arrays_of_every_compressor() {
    // (store, shape z y x, signed values, fill, chunk shape, chunk left out, dtype)
    type Case = (
        &'static str,
        [u64; 3],
        bool,
        f32,
        [u64; 3],
        Option<[u64; 3]>,
        Dtype,
    );
    let cases: [Case; 7] = [
        (
            "v2_zlib_be_f4",
            [6, 7, 8],
            true,
            f32::NAN,
            [3, 4, 5],
            Some([0, 1, 0]),
            Dtype::F32,
        ),
        (
            "v2_gzip_order_f_i2",
            [6, 7, 8],
            true,
            0.0,
            [3, 4, 5],
            None,
            Dtype::I16,
        ),
        (
            "v2_zstd_u1",
            [5, 6, 7],
            false,
            7.0,
            [2, 3, 4],
            Some([1, 1, 1]),
            Dtype::U8,
        ),
        (
            "v2_lz4_u8",
            [5, 6, 7],
            false,
            0.0,
            [2, 3, 4],
            None,
            Dtype::U8,
        ),
        (
            "v2_raw_i4_4d",
            [5, 6, 7],
            true,
            0.0,
            [2, 3, 4],
            None,
            Dtype::I32,
        ),
        (
            "v2_blosc_zstd_bitshuffle_f8",
            [5, 6, 7],
            true,
            -1.5,
            [2, 3, 4],
            Some([0, 0, 1]),
            Dtype::F64,
        ),
        (
            "v2_blosc_blosclz_shuffle_be_u2",
            [5, 6, 7],
            false,
            0.0,
            [2, 3, 4],
            None,
            Dtype::U16,
        ),
    ];
    for (name, [nz, ny, nx], signed, fill, chunk, missing, dtype) in cases {
        let store = data(&format!("stores/{name}.zarr"));
        let v = open_path(&store, &OpenOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(v.grid().dims, [nx, ny, nz], "{name}");
        // uint64 has no crate dtype.
        if name != "v2_lz4_u8" {
            assert_eq!(v.dtype(), Some(dtype), "{name}");
        }
        let got = read_all(&store, &OpenOptions::default()).unwrap();
        let mut i = 0;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let left_out = missing == Some([z / chunk[0], y / chunk[1], x / chunk[2]]);
                    let want = if left_out {
                        fill
                    } else {
                        value(z, y, x, signed) as f32
                    };
                    let g = got[i];
                    assert!(
                        g == want || (g.is_nan() && want.is_nan()),
                        "{name} at z {z} y {y} x {x}: {g} != {want}"
                    );
                    i += 1;
                }
            }
        }
    }
}

/// A copy of a committed store in a temporary directory, to damage.
fn copy_store(rel: &str, to: &Path) -> PathBuf {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let e = e.unwrap();
            let t = to.join(e.file_name());
            if e.file_type().unwrap().is_dir() {
                copy(&e.path(), &t);
            } else {
                std::fs::copy(e.path(), &t).unwrap();
            }
        }
    }
    let dest = to.join(Path::new(rel).file_name().unwrap());
    copy(&data(rel), &dest);
    dest
}

/// A truncated or corrupt Blosc chunk fails the read with the chunk's path and what to do.
#[test]
fn a_damaged_blosc_chunk_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let store = copy_store("stores/ome_v04.zarr", dir.path());
    let chunk = store.join("s0/0/0/0");
    let bytes = std::fs::read(&chunk).unwrap();
    std::fs::write(&chunk, &bytes[..bytes.len() - 10]).unwrap();
    let e = read_all(&store, &OpenOptions::default()).unwrap_err();
    assert_eq!(
        e,
        format!(
            "{}: blosc chunk: header says the frame is {} bytes but the chunk file has {}; the chunk file is damaged or truncated; write it again from the source data",
            chunk.display(),
            bytes.len(),
            bytes.len() - 10
        )
    );
    // A header claiming more than a chunk holds (4 x 5 x 6 u16 = 240 bytes).
    let mut big = bytes.clone();
    big[4..8].copy_from_slice(&1_000_000u32.to_le_bytes());
    std::fs::write(&chunk, &big).unwrap();
    assert_eq!(
        read_all(&store, &OpenOptions::default()).unwrap_err(),
        format!(
            "{}: blosc chunk: header says 1000000 decoded bytes but a chunk of this array holds at most 240; the chunk does not match the chunk shape and dtype in the array metadata; check them",
            chunk.display()
        )
    );
}

/// Unsupported or malformed `.zarray` keys: one line naming the file, the key and the fix.
#[test]
fn unsupported_v2_metadata_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let store = copy_store("stores/v2_zstd_u1.zarr", dir.path());
    let meta_file = store.join(".zarray");
    let orig: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&meta_file).unwrap()).unwrap();
    let cases: [(&str, serde_json::Value, &str); 7] = [
        (
            "filters",
            serde_json::json!("delta"),
            "key filters: filters [\"delta\"] unsupported: write the array without filters (a compressor alone)",
        ),
        (
            "filters",
            serde_json::json!([{"id": "delta", "dtype": "<u2"}]),
            "key filters: filters [delta] unsupported: write the array without filters (a compressor alone)",
        ),
        (
            "compressor",
            serde_json::json!({"id": "bz2", "level": 1}),
            "key compressor.id: compressor \"bz2\" unsupported: supported are blosc, zlib, gzip, zstd, lz4 (or null); re-encode with one of them",
        ),
        (
            "compressor",
            serde_json::json!({"id": "blosc", "cname": "snappy"}),
            "key compressor.cname: blosc compressor \"snappy\" unsupported: re-encode with cname lz4, zstd, zlib or blosclz",
        ),
        (
            "order",
            serde_json::json!("K"),
            "expected \"C\" or \"F\", found \"K\"",
        ),
        (
            "dtype",
            serde_json::json!("<c8"),
            "key dtype: expected a numpy type string of a number: <, > or | then i1..i8, u1..u8, f4 or f8 (such as \"<u2\"), found \"<c8\"",
        ),
        (
            "dimension_separator",
            serde_json::json!("-"),
            "key dimension_separator: expected \".\" or \"/\", found \"-\"",
        ),
    ];
    for (key, bad, want) in cases {
        let mut m = orig.clone();
        m[key] = bad;
        write_json(&meta_file, &m);
        let e = open_path(&store, &OpenOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.starts_with(&format!("{}: ", meta_file.display())) && e.ends_with(want),
            "{key}: {e}"
        );
    }
}

/// A Zarr v3 array with the `blosc` codec (as zarr-python 3 writes it) whose chunks are
/// numcodecs' frames, for every internal compressor and shuffle.
#[test]
fn zarr_v3_blosc_codec_reads_reference_frames() {
    let raw = std::fs::read(data("blosc/data_t2.raw")).unwrap();
    let want: Vec<f32> = raw
        .chunks_exact(2)
        .map(|b| f32::from(u16::from_le_bytes([b[0], b[1]])))
        .collect();
    for cname in ["blosclz", "lz4", "lz4hc", "zlib", "zstd"] {
        for shuffle in ["noshuffle", "shuffle", "bitshuffle"] {
            let dir = tempfile::tempdir().unwrap();
            let store = dir.path().join("a.zarr");
            std::fs::create_dir_all(store.join("c/0/0")).unwrap();
            write_json(
                &store.join("zarr.json"),
                &serde_json::json!({
                    "zarr_format": 3,
                    "node_type": "array",
                    "shape": [10, 10, 20],
                    "data_type": "uint16",
                    "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": [10, 10, 20]}},
                    "chunk_key_encoding": {"name": "default"},
                    "fill_value": 0,
                    "codecs": [
                        {"name": "bytes", "configuration": {"endian": "little"}},
                        {"name": "blosc", "configuration": {
                            "cname": cname, "clevel": 5, "shuffle": shuffle, "typesize": 2,
                            "blocksize": 0}}
                    ]
                }),
            );
            let frame = data(&format!("blosc/{cname}_{shuffle}_t2.blosc"));
            std::fs::copy(frame, store.join("c/0/0/0")).unwrap();
            assert_eq!(
                read_all(&store, &OpenOptions::default()).unwrap(),
                want,
                "{cname} {shuffle}"
            );
        }
    }
}
