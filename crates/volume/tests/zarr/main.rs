//! Zarr v3 / OME-Zarr v0.5 stores written by hand (tests/zarr/store.rs), and Zarr v2 / OME-Zarr
//! v0.4 stores written by zarr-python 2 (tests/zarr/v2.rs), read back through
//! `open_path`: every type and byte order, both chunk key encodings, transpose, gzip, zstd,
//! crc32c, sharding with the index at either end, partial edge chunks, missing chunks; damaged
//! stores end in one-line errors; rows are decoded only when the front reaches them.

mod store;
mod v2;

use isostream_volume::{
    Dtype, MemoryVolume, OpenOptions, Procedural, Shape, VolumeSource, open_path,
};
use proptest::prelude::*;
use std::path::Path;
use store::{Compress, Shard, Spec, indices, write, write_json, write_ome_group};

/// A pattern every type holds exactly (signed types get negative values too).
fn pattern(dtype: &str) -> impl Fn(&[u64]) -> f64 {
    let signed = dtype.starts_with("int") || dtype.starts_with("float");
    move |i: &[u64]| {
        let r = i.len();
        let v = ((i[r - 3] * 31 + i[r - 2] * 7 + i[r - 1] * 3) % 101) as f64;
        if signed { v - 50.0 } else { v }
    }
}

fn keep_all(_: &[u64]) -> bool {
    true
}

/// Reads every slice of the store in order.
fn read_all(path: &Path, opts: &OpenOptions) -> Result<Vec<f32>, String> {
    let mut v = open_path(path, opts).map_err(|e| e.to_string())?;
    let g = v.grid();
    let mut all = Vec::new();
    let mut out = vec![0.0f32; g.slice_len()];
    for z in 0..g.dims[2] {
        v.read_slice(z, &mut out).map_err(|e| e.to_string())?;
        all.extend_from_slice(&out);
    }
    Ok(all)
}

/// What the store should read as: value() where the chunk was kept, else the fill value.
fn expected(spec: &Spec, value: &dyn Fn(&[u64]) -> f64, keep: &dyn Fn(&[u64]) -> bool) -> Vec<f32> {
    let r = spec.shape.len();
    let block = match &spec.shard {
        Some(s) => s.inner.clone(),
        None => spec.chunks.clone(),
    };
    let [nz, ny, nx] = [spec.shape[r - 3], spec.shape[r - 2], spec.shape[r - 1]];
    let mut out = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let mut idx = vec![0u64; r];
                idx[r - 3..].copy_from_slice(&[z, y, x]);
                let g: Vec<u64> = idx.iter().zip(&block).map(|(i, c)| i / c).collect();
                out.push(if keep(&g) { value(&idx) } else { spec.fill } as f32);
            }
        }
    }
    out
}

fn check(spec: &Spec, keep: &dyn Fn(&[u64]) -> bool) {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("a.zarr");
    let value = pattern(spec.dtype);
    write(&store, spec, &value, keep);
    let got = read_all(&store, &OpenOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    let want = expected(spec, &value, keep);
    assert!(
        got.iter()
            .zip(&want)
            .all(|(a, b)| a == b || (a.is_nan() && b.is_nan()))
            && got.len() == want.len(),
        "{spec:?}\ngot  {got:?}\nwant {want:?}"
    );
}

/// Chunks with an odd coordinate sum are missing from the store.
fn checkerboard(g: &[u64]) -> bool {
    g.iter().sum::<u64>() % 2 == 0
}

const TYPES: [&str; 10] = [
    "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64",
];

#[test]
fn every_type_and_byte_order_with_edge_and_missing_chunks() {
    for dtype in TYPES {
        for endian in ["little", "big"] {
            let mut spec = Spec::new(&[5, 7, 9], &[2, 3, 4]);
            spec.dtype = dtype;
            spec.endian = endian;
            spec.fill = 9.0;
            check(&spec, &checkerboard);
        }
    }
}

/// Finite float64 values beyond f32's range, stored or as the fill value of missing chunks,
/// read as ±f32::MAX and are counted once per slice read.
#[test]
fn float64_beyond_f32_is_saturated_and_counted() {
    for endian in ["little", "big"] {
        let mut spec = Spec::new(&[5, 7, 9], &[2, 3, 4]);
        spec.dtype = "float64";
        spec.endian = endian;
        spec.fill = -1e40;
        let base = pattern("float64");
        let value = |i: &[u64]| match base(i) {
            v if v > 40.0 => 1e300,
            v => v,
        };
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("a.zarr");
        write(&store, &spec, &value, &checkerboard);
        // What `as f32` gives: infinite where f32 has no room.
        let cast = expected(&spec, &value, &checkerboard);
        let n = cast.iter().filter(|v| v.is_infinite()).count() as u64;
        assert!(n > 100, "{n}");
        let want: Vec<f32> = cast
            .iter()
            .map(|&v| {
                if v.is_infinite() {
                    f32::MAX.copysign(v)
                } else {
                    v
                }
            })
            .collect();
        let mut v = open_path(&store, &OpenOptions::default()).unwrap();
        let g = v.grid();
        let mut got = Vec::new();
        let mut out = vec![0.0f32; g.slice_len()];
        for z in 0..g.dims[2] {
            v.read_slice(z, &mut out).unwrap();
            got.extend_from_slice(&out);
        }
        assert_eq!(got, want, "{endian}");
        assert_eq!(v.saturated_voxels(), n, "{endian}");
    }
}

#[test]
fn key_encodings_and_compressors() {
    for keys in [("default", "/"), ("default", "."), ("v2", "."), ("v2", "/")] {
        for compress in [Compress::None, Compress::Gzip, Compress::Zstd] {
            let mut spec = Spec::new(&[6, 5, 7], &[4, 2, 3]);
            spec.dtype = "uint16";
            spec.keys = keys;
            spec.compress = compress;
            spec.crc = compress == Compress::Gzip;
            check(&spec, &checkerboard);
        }
    }
}

#[test]
fn transpose_big_endian_crc() {
    for order in [vec![2, 0, 1], vec![1, 2, 0], vec![2, 1, 0]] {
        let mut spec = Spec::new(&[5, 6, 7], &[3, 4, 2]);
        spec.dtype = "float32";
        spec.endian = "big";
        spec.transpose = Some(order);
        spec.crc = true;
        spec.compress = Compress::Zstd;
        spec.fill = f64::NAN;
        check(&spec, &checkerboard);
    }
}

#[test]
fn sharded_index_at_either_end_with_missing_inner_chunks() {
    for index_at_end in [true, false] {
        for compress in [Compress::None, Compress::Zstd] {
            let mut spec = Spec::new(&[9, 10, 11], &[4, 6, 8]);
            spec.dtype = "int16";
            spec.compress = compress;
            spec.shard = Some(Shard {
                inner: vec![2, 3, 4],
                index_at_end,
            });
            spec.fill = -7.0;
            check(&spec, &checkerboard);
            // Whole shards missing too: only inner chunks with z block 0 are stored.
            check(&spec, &|g: &[u64]| g[0] == 0);
        }
    }
}

#[test]
fn leading_singleton_axes_are_dropped() {
    let mut spec = Spec::new(&[1, 1, 4, 5, 6], &[1, 1, 3, 2, 4]);
    spec.dtype = "uint8";
    check(&spec, &keep_all);
    spec.shard = Some(Shard {
        inner: vec![1, 1, 1, 2, 2],
        index_at_end: true,
    });
    spec.chunks = vec![1, 1, 3, 4, 4];
    check(&spec, &checkerboard);
}

#[test]
fn ome_zarr_levels_spacing_and_origin() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("img.ome.zarr");
    let full = Spec::new(&[1, 4, 6, 8], &[1, 2, 4, 4]);
    let half = Spec::new(&[1, 2, 3, 4], &[1, 2, 3, 4]);
    write(&root.join("s0"), &full, &pattern("uint8"), &keep_all);
    write(&root.join("s1"), &half, &|_: &[u64]| 5.0, &keep_all);
    // Zarr order: scale (c, z, y, x).
    write_ome_group(
        &root,
        &[("s0", [2.0, 0.5, 0.25]), ("s1", [4.0, 1.0, 0.5])],
        [10.0, 20.0, 30.0],
        4,
    );
    let v = open_path(&root, &OpenOptions::default()).unwrap();
    let g = v.grid();
    assert_eq!(g.dims, [8, 6, 4]);
    assert_eq!(
        g.spacing,
        [0.25, 0.5, 2.0],
        "x, y, z: the last three scale values reversed"
    );
    assert_eq!(g.origin, [30.0, 20.0, 10.0]);
    assert_eq!(v.dtype(), Some(Dtype::U8));
    assert_eq!(
        read_all(&root, &OpenOptions::default()).unwrap(),
        expected(&full, &pattern("uint8"), &keep_all)
    );
    let level1 = OpenOptions {
        array: Some("s1".into()),
        ..Default::default()
    };
    let v1 = open_path(&root.join("zarr.json"), &level1).unwrap();
    assert_eq!(
        (v1.grid().dims, v1.grid().spacing),
        ([4, 3, 2], [0.5, 1.0, 4.0])
    );
    assert_eq!(read_all(&root, &level1).unwrap(), vec![5.0; 24]);
    // The job's spacing wins over the metadata.
    let over = OpenOptions {
        spacing: Some([1.0; 3]),
        ..Default::default()
    };
    assert_eq!(open_path(&root, &over).unwrap().grid().spacing, [1.0; 3]);
    let nope = OpenOptions {
        array: Some("s9".into()),
        ..Default::default()
    };
    assert_eq!(
        open_path(&root, &nope).err().unwrap().to_string(),
        format!(
            "{}: document: [input] array \"s9\" is not a level of this OME-Zarr image; levels are [s0, s1]",
            root.join("zarr.json").display()
        )
    );
}

/// OME-Zarr axes that are not the spatial z, y, x are refused (a time axis was meshed as depth,
/// axes listed x, y, z had x and z swapped), with the axes named.
#[test]
fn ome_zarr_axes_must_be_spatial_z_y_x() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("img.ome.zarr");
    write(
        &root.join("0"),
        &Spec::new(&[3, 4, 5], &[2, 2, 2]),
        &pattern("uint8"),
        &keep_all,
    );
    write_ome_group(&root, &[("0", [1.0, 1.0, 1.0])], [0.0; 3], 3);
    assert!(open_path(&root, &OpenOptions::default()).is_ok());
    let file = root.join("zarr.json");
    let with_axes = |names: [(&str, &str); 3]| {
        let mut doc: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
        doc["attributes"]["ome"]["multiscales"][0]["axes"] = names
            .iter()
            .map(|(n, t)| serde_json::json!({"name": n, "type": t}))
            .collect();
        write_json(&file, &doc);
        open_path(&root, &OpenOptions::default())
            .err()
            .map(|e| e.to_string())
    };
    let e = with_axes([("t", "time"), ("y", "space"), ("x", "space")]).expect("refused");
    assert!(
        e.starts_with(&format!(
            "{}: key attributes.ome.multiscales[0].axes: the last three axes [t (time), y (space), x (space)] must be spatial",
            file.display()
        )),
        "{e}"
    );
    let e = with_axes([("x", "space"), ("y", "space"), ("z", "space")]).expect("refused");
    assert!(e.contains("only the order z, y, x"), "{e}");
    assert_eq!(
        with_axes([("z", "space"), ("y", "space"), ("x", "space")]),
        None
    );
}

/// Fuzz crash: a dataset path of "" named the group itself and recursed until the stack
/// overflowed; paths that loop through other groups are cut off after a few groups.
#[test]
fn dataset_paths_that_lead_back_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("img.ome.zarr");
    let file = root.join("zarr.json");
    for path in ["", "."] {
        write_ome_group(&root, &[(path, [1.0, 1.0, 1.0])], [0.0; 3], 3);
        let e = open_path(&root, &OpenOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert_eq!(
            e,
            format!(
                "{}: key attributes.ome.multiscales[0].datasets[0].path: dataset path {path:?} names this group itself; it must name one of its arrays (such as \"0\")",
                file.display()
            )
        );
    }
    // A level inside the group whose own dataset leads back up to it.
    write_ome_group(&root, &[("sub", [1.0, 1.0, 1.0])], [0.0; 3], 3);
    write_ome_group(&root.join("sub"), &[("..", [1.0, 1.0, 1.0])], [0.0; 3], 3);
    let e = open_path(&root, &OpenOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("reached through more than 8 Zarr groups"), "{e}");
    assert!(!e.contains('\n'), "{e}");
}

#[test]
fn plain_group_needs_the_array_named() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("g");
    write(
        &root.join("density"),
        &Spec::new(&[2, 2, 2], &[2, 2, 2]),
        &|_: &[u64]| 3.0,
        &keep_all,
    );
    write_json(
        &root.join("zarr.json"),
        &serde_json::json!({"zarr_format": 3, "node_type": "group", "attributes": {}}),
    );
    assert_eq!(
        open_path(&root, &OpenOptions::default())
            .err()
            .unwrap()
            .to_string(),
        format!(
            "{}: document: a Zarr group without OME-Zarr multiscales; set [input] array to one of its arrays [density]",
            root.join("zarr.json").display()
        )
    );
    let named = OpenOptions {
        array: Some("density".into()),
        ..Default::default()
    };
    assert_eq!(read_all(&root, &named).unwrap(), vec![3.0; 8]);
    // An array takes no array name.
    let e = open_path(&root.join("density"), &named)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.ends_with(
            "array \"density\" was requested but this is a single Zarr array; remove [input] array"
        ),
        "{e}"
    );
}

#[test]
fn raw_only_keys_and_empty_zarr_v2_metadata_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("a.zarr");
    write(
        &store,
        &Spec::new(&[2, 2, 2], &[2, 2, 2]),
        &|_: &[u64]| 1.0,
        &keep_all,
    );
    let raw = OpenOptions {
        dtype: Some(Dtype::U8),
        ..Default::default()
    };
    assert_eq!(
        open_path(&store, &raw).err().unwrap().to_string(),
        format!(
            "{}: dtype applies only to .raw files but this is Zarr, whose header defines it; remove it from [input]",
            store.display()
        )
    );
    let v2 = dir.path().join("old.zarr");
    std::fs::create_dir_all(&v2).unwrap();
    std::fs::write(v2.join(".zarray"), "{}").unwrap();
    assert_eq!(
        open_path(&v2, &OpenOptions::default())
            .err()
            .unwrap()
            .to_string(),
        format!(
            "{}: key zarr_format: expected 2 (a Zarr v2 .zarray or .zgroup), found \"nothing\"",
            v2.join(".zarray").display()
        )
    );
}

/// One malformed store per case: (what to change, the exact one-line message after the path).
#[test]
fn malformed_stores_give_one_line_errors() {
    type Damage = Box<dyn Fn(&Path, &mut serde_json::Value)>;
    let meta = |f: fn(&mut serde_json::Value)| -> Damage {
        Box::new(move |_: &Path, m: &mut serde_json::Value| f(m))
    };
    let file = |key: &'static str, f: fn(&mut Vec<u8>)| -> Damage {
        Box::new(move |dir: &Path, _: &mut serde_json::Value| {
            let p = dir.join(key);
            let mut b = std::fs::read(&p).unwrap();
            f(&mut b);
            std::fs::write(&p, b).unwrap();
        })
    };
    let cases: Vec<(&str, Spec, Damage, &str)> = vec![
        (
            "bad json",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            Box::new(|d: &Path, _: &mut serde_json::Value| {
                std::fs::write(d.join("zarr.json"), "{\"shape\": [4,").unwrap()
            }),
            "zarr.json: line 1 column 13: expected valid JSON, found \"EOF while parsing a value at line 1 column 13\"",
        ),
        (
            "no shape",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m.as_object_mut().unwrap().remove("shape");
            }),
            "zarr.json: key shape: expected a list of sizes, found \"nothing\"",
        ),
        (
            "2-d",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["shape"] = serde_json::json!([4, 4])),
            "zarr.json: key shape: expected at least 3 axes (z, y, x), found \"[4,4]\"",
        ),
        (
            "channels",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["shape"] = serde_json::json!([3, 4, 4, 4]);
                m["dimension_names"] = serde_json::json!(["c", "z", "y", "x"]);
            }),
            "zarr.json: key shape: shape [3, 4, 4, 4]: axis 0 (c) has size 3 but only the last three axes (z, y, x) may exceed 1; write the volume to mesh as its own array",
        ),
        (
            "type",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["data_type"] = serde_json::json!("complex64")),
            "zarr.json: key data_type: expected int8, uint8, int16, uint16, int32, uint32, int64, uint64, float32 or float64, found \"complex64\"",
        ),
        (
            "chunk rank",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["chunk_grid"]["configuration"]["chunk_shape"] = serde_json::json!([2, 2])),
            "zarr.json: key chunk_grid.configuration.chunk_shape: expected 3 positive chunk sizes, one per axis, found \"[2,2]\"",
        ),
        (
            "grid",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["chunk_grid"]["name"] = serde_json::json!("rectilinear")),
            "zarr.json: key chunk_grid.name: expected \"regular\", found \"rectilinear\"",
        ),
        (
            "keys",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["chunk_key_encoding"]["configuration"]["separator"] = serde_json::json!("-")
            }),
            "zarr.json: key chunk_key_encoding.configuration.separator: expected \"/\" or \".\", found \"-\"",
        ),
        (
            "fill",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["fill_value"] = serde_json::json!("zero")),
            "zarr.json: key fill_value: expected an integer, found \"zero\"",
        ),
        (
            "blosc snappy",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["codecs"].as_array_mut().unwrap().push(
                    serde_json::json!({"name": "blosc", "configuration": {"cname": "snappy"}}),
                )
            }),
            "zarr.json: key codecs[1].configuration.cname: blosc compressor \"snappy\" unsupported: re-encode with cname lz4, zstd, zlib or blosclz",
        ),
        (
            "blosc shuffle",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["codecs"].as_array_mut().unwrap().push(
                    serde_json::json!({"name": "blosc", "configuration": {"cname": "lz4", "shuffle": 1}}),
                )
            }),
            "zarr.json: key codecs[1].configuration.shuffle: expected \"noshuffle\", \"shuffle\" or \"bitshuffle\", found \"1\"",
        ),
        (
            "unknown codec",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["codecs"]
                    .as_array_mut()
                    .unwrap()
                    .push(serde_json::json!({"name": "lzma"}))
            }),
            "zarr.json: key codecs[1]: codec \"lzma\" unsupported: supported are bytes, transpose, gzip, zstd, blosc, crc32c, sharding_indexed",
        ),
        (
            "endian",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["codecs"][0]["configuration"]["endian"] = serde_json::json!("middle")),
            "zarr.json: key codecs[0].configuration.endian: expected \"little\" or \"big\", found \"middle\"",
        ),
        (
            "no bytes codec",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["codecs"] = serde_json::json!([])),
            "zarr.json: key codecs: the codecs lack the bytes codec",
        ),
        (
            "transpose",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["codecs"].as_array_mut().unwrap().insert(
                    0,
                    serde_json::json!({"name": "transpose", "configuration": {"order": [0, 0, 1]}}),
                )
            }),
            "zarr.json: key codecs[0].configuration.order: expected a permutation of 0..3, found \"[0,0,1]\"",
        ),
        (
            "version",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| m["zarr_format"] = serde_json::json!(2)),
            "zarr.json: key zarr_format: expected 3 (a zarr.json is Zarr v3; Zarr v2 metadata is a .zarray or .zgroup), found \"2\"",
        ),
        (
            "huge chunk",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            meta(|m| {
                m["chunk_grid"]["configuration"]["chunk_shape"] =
                    serde_json::json!([1u64 << 20, 1u64 << 20, 1u64 << 20])
            }),
            "zarr.json: key codecs: chunks of shape [1048576, 1048576, 1048576] are larger than the 512 MiB this reader decodes at once; re-chunk the array",
        ),
        (
            "truncated chunk",
            Spec::new(&[4, 4, 4], &[2, 2, 2]),
            file("c/0/0/1", |b| b.truncate(5)),
            "c/0/0/1: decoded chunk: expected 8 bytes (shape [2, 2, 2] of 1-byte values), found \"5 bytes\"",
        ),
        (
            "long chunk",
            {
                let mut s = Spec::new(&[4, 4, 4], &[2, 2, 2]);
                s.dtype = "float64";
                s
            },
            file("c/1/0/0", |b| b.push(0)),
            "c/1/0/0: decoded chunk: expected 64 bytes (shape [2, 2, 2] of 8-byte values), found \"65 bytes\"",
        ),
        (
            "gzip garbage",
            {
                let mut s = Spec::new(&[4, 4, 4], &[2, 2, 2]);
                s.compress = Compress::Gzip;
                s
            },
            file("c/0/0/0", |b| b[0] = b'X'),
            "c/0/0/0: gzip chunk: expected valid gzip data, found \"invalid gzip header\"",
        ),
        (
            "zstd garbage",
            {
                let mut s = Spec::new(&[4, 4, 4], &[2, 2, 2]);
                s.compress = Compress::Zstd;
                s
            },
            file("c/0/0/0", |b| b[0] = b'X'),
            "c/0/0/0: zstd chunk: expected valid zstd data, found \"no zstd frame magic number\"",
        ),
        (
            "crc",
            {
                let mut s = Spec::new(&[4, 4, 4], &[2, 2, 2]);
                s.crc = true;
                s
            },
            file("c/0/1/0", |b| b[0] ^= 1),
            "c/0/1/0: chunk checksum: expected crc32c",
        ),
        (
            "shard truncated",
            {
                let mut s = Spec::new(&[4, 4, 4], &[4, 4, 4]);
                s.shard = Some(Shard {
                    inner: vec![2, 2, 2],
                    index_at_end: true,
                });
                s
            },
            file("c/0/0/0", |b| b.truncate(100)),
            "c/0/0/0: shard index: expected an index for 8 inner chunks, found \"a 100-byte file (truncated shard?)\"",
        ),
        (
            "shard index crc",
            {
                let mut s = Spec::new(&[4, 4, 4], &[4, 4, 4]);
                s.shard = Some(Shard {
                    inner: vec![2, 2, 2],
                    index_at_end: false,
                });
                s
            },
            file("c/0/0/0", |b| b[3] ^= 0x40),
            "c/0/0/0: shard index checksum: expected crc32c",
        ),
        (
            "shard inner shape",
            {
                let mut s = Spec::new(&[4, 4, 4], &[4, 4, 4]);
                s.shard = Some(Shard {
                    inner: vec![2, 2, 2],
                    index_at_end: true,
                });
                s
            },
            meta(|m| m["codecs"][0]["configuration"]["chunk_shape"] = serde_json::json!([3, 2, 2])),
            "zarr.json: key codecs[0].configuration.chunk_shape: expected one positive size per axis dividing the shard shape [4, 4, 4], found \"[3,2,2]\"",
        ),
        (
            "shard index codec",
            {
                let mut s = Spec::new(&[4, 4, 4], &[4, 4, 4]);
                s.shard = Some(Shard {
                    inner: vec![2, 2, 2],
                    index_at_end: true,
                });
                s
            },
            meta(|m| {
                m["codecs"][0]["configuration"]["index_codecs"]
                    .as_array_mut()
                    .unwrap()
                    .push(serde_json::json!({"name": "gzip"}))
            }),
            "zarr.json: key codecs[0].configuration.index_codecs[2]: index codec \"gzip\" unsupported: a shard index must be bytes (+ crc32c)",
        ),
        (
            "shard with others",
            {
                let mut s = Spec::new(&[4, 4, 4], &[4, 4, 4]);
                s.shard = Some(Shard {
                    inner: vec![2, 2, 2],
                    index_at_end: true,
                });
                s
            },
            meta(|m| {
                m["codecs"]
                    .as_array_mut()
                    .unwrap()
                    .push(serde_json::json!({"name": "crc32c"}))
            }),
            "zarr.json: key codecs[0]: sharding_indexed must be the array's only codec (put the others in its \"codecs\")",
        ),
    ];
    let mut wrong = Vec::new();
    for (name, spec, damage, want) in cases {
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("s");
        write(&store, &spec, &pattern(spec.dtype), &keep_all);
        let mut m = spec.metadata();
        damage(&store, &mut m);
        if m != spec.metadata() {
            write_json(&store.join("zarr.json"), &m);
        }
        let got = match read_all(&store, &OpenOptions::default()) {
            Ok(_) => "Ok".to_string(),
            Err(e) => e,
        };
        assert!(!got.contains('\n'), "{name}: {got}");
        let got = got
            .strip_prefix(&format!("{}/", store.display()))
            .unwrap_or(&got)
            .to_string();
        if !got.starts_with(want) {
            wrong.push(format!("{name}:\n  got  {got}\n  want {want}"));
        }
    }
    assert!(wrong.is_empty(), "\n{}", wrong.join("\n"));
}

/// Later rows are not touched before the front reaches them, and a row is dropped once passed:
/// only the last slice of the previous row is kept, for a z - 1 re-read.
#[test]
fn rows_are_read_as_the_front_moves() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("a.zarr");
    let spec = Spec::new(&[9, 4, 5], &[3, 2, 3]);
    write(&store, &spec, &pattern("uint8"), &keep_all);
    std::fs::write(store.join("c/2/1/1"), b"bad").unwrap();
    let mut v = open_path(&store, &OpenOptions::default()).unwrap();
    assert!(!v.loads_whole_volume());
    let want = expected(&spec, &pattern("uint8"), &keep_all);
    let mut out = vec![0.0f32; 20];
    for z in 0..6u64 {
        v.read_slice(z, &mut out).unwrap();
        assert_eq!(out, want[z as usize * 20..][..20]);
        if z == 3 {
            // Row 0 is behind the front: its files may go; slice 2 is still at hand.
            std::fs::remove_dir_all(store.join("c/0")).unwrap();
            v.read_slice(2, &mut out).unwrap();
            assert_eq!(out, want[40..60]);
        }
    }
    // Going back decodes row 0 again, whose chunks are gone now: fill values.
    v.read_slice(1, &mut out).unwrap();
    assert_eq!(out, vec![0.0; 20]);
    let e = v.read_slice(6, &mut out).unwrap_err().to_string();
    assert!(e.ends_with("c/2/1/1: decoded chunk: expected 18 bytes (shape [3, 2, 3] of 1-byte values), found \"3 bytes\""), "{e}");
}

#[test]
fn a_chunk_as_deep_as_the_volume_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("a.zarr");
    write(
        &store,
        &Spec::new(&[4, 4, 4], &[4, 2, 2]),
        &|_: &[u64]| 1.0,
        &keep_all,
    );
    assert!(
        open_path(&store, &OpenOptions::default())
            .unwrap()
            .loads_whole_volume()
    );
}

/// A procedural sphere stored as sharded zstd float32 reads back bit for bit, so every stage
/// downstream (extraction, simplification) sees the same input as from the raw twin.
#[test]
fn sphere_store_equals_the_procedural_and_raw_twin() {
    let n = [24u64, 20, 18];
    let mut sphere = Procedural::new(Shape::Sphere, n, [1.0; 3], [0.0; 3]).unwrap();
    let g = sphere.grid();
    let mut all = Vec::new();
    let mut s = vec![0.0f32; g.slice_len()];
    for z in 0..n[2] {
        sphere.read_slice(z, &mut s).unwrap();
        all.extend_from_slice(&s);
    }
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("sphere.zarr");
    let mut spec = Spec::new(&[n[2], n[1], n[0]], &[8, 8, 8]);
    spec.dtype = "float32";
    spec.compress = Compress::Zstd;
    spec.shard = Some(Shard {
        inner: vec![4, 4, 8],
        index_at_end: true,
    });
    let idx = |i: &[u64]| (i[2] + n[0] * (i[1] + n[1] * i[0])) as usize;
    write(
        &store,
        &spec,
        &|i: &[u64]| f64::from(all[idx(i)]),
        &keep_all,
    );
    let raw = dir.path().join("sphere.raw");
    std::fs::write(
        &raw,
        all.iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let raw_opts = OpenOptions {
        dims: Some(n),
        dtype: Some(Dtype::F32),
        ..Default::default()
    };
    let from_zarr = read_all(&store, &OpenOptions::default()).unwrap();
    assert_eq!(from_zarr, all);
    assert_eq!(read_all(&raw, &raw_opts).unwrap(), from_zarr);
    let mem = MemoryVolume::new(g, all.clone()).unwrap();
    assert_eq!(
        mem.grid(),
        open_path(&store, &OpenOptions::default()).unwrap().grid()
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Random shapes, chunkings and codec chains read back what was written.
    #[test]
    fn random_stores_round_trip(
        shape in proptest::array::uniform3(2u64..9),
        chunks in proptest::array::uniform3(1u64..6),
        dtype in prop::sample::select(TYPES.to_vec()),
        big in any::<bool>(),
        compress in prop::sample::select(vec![Compress::None, Compress::Gzip, Compress::Zstd]),
        crc in any::<bool>(),
        transpose in any::<bool>(),
        v2 in any::<bool>(),
        shard in 0u64..3,
        keep_mask in any::<u64>(),
    ) {
        let mut spec = Spec::new(&shape, &chunks);
        spec.dtype = dtype;
        spec.endian = if big { "big" } else { "little" };
        spec.compress = compress;
        spec.crc = crc;
        spec.keys = if v2 { ("v2", ".") } else { ("default", "/") };
        spec.transpose = transpose.then(|| vec![1, 2, 0]);
        spec.fill = 3.0;
        if shard > 0 {
            spec.shard = Some(Shard { inner: chunks.to_vec(), index_at_end: shard == 1 });
            spec.chunks = chunks.iter().map(|c| c * 2).collect();
        }
        let keep = move |g: &[u64]| keep_mask >> ((g[0] * 7 + g[1] * 3 + g[2]) % 64) & 1 == 1;
        check(&spec, &keep);
    }

    /// Damaged bytes anywhere (metadata or chunks) end in Ok or a one-line error, never a panic.
    #[test]
    fn damaged_stores_never_panic(
        file_pick in any::<prop::sample::Index>(),
        cut in 0.0f64..=1.0,
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..4),
        sharded in any::<bool>(),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("a.zarr");
        let mut spec = Spec::new(&[5, 4, 6], &[2, 4, 4]);
        spec.dtype = "uint16";
        spec.compress = Compress::Zstd;
        spec.crc = !sharded;
        if sharded {
            spec.shard = Some(Shard { inner: vec![2, 2, 2], index_at_end: true });
        }
        write(&store, &spec, &pattern("uint16"), &keep_all);
        let mut files: Vec<_> = walk(&store);
        files.sort();
        let f = &files[file_pick.index(files.len())];
        let mut bytes = std::fs::read(f).unwrap();
        bytes.truncate((bytes.len() as f64 * cut) as usize);
        if !bytes.is_empty() {
            for (at, v) in edits {
                let i = at.index(bytes.len());
                bytes[i] = v;
            }
        }
        std::fs::write(f, bytes).unwrap();
        if let Err(e) = read_all(&store, &OpenOptions::default()) {
            prop_assert!(!e.contains('\n'), "{}", e);
        }
    }
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(walk(&p))
        } else {
            out.push(p)
        }
    }
    out
}

#[test]
fn indices_are_c_order() {
    assert_eq!(
        indices(&[2, 2]),
        vec![vec![0, 0], vec![0, 1], vec![1, 0], vec![1, 1]]
    );
}
