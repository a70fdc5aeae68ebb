use super::*;
use crate::dtype::tests::{ALL, encode, sample_values};
use crate::open_path;
use crate::testutil::{as_f32, assert_all_equal, gzip, outcome, read_all};

fn type_name(d: Dtype) -> &'static str {
    match d {
        Dtype::U8 => "uint8",
        Dtype::I8 => "signed char",
        Dtype::U16 => "ushort",
        Dtype::I16 => "short",
        Dtype::U32 => "uint32_t",
        Dtype::I32 => "int",
        Dtype::F32 => "float",
        Dtype::F64 => "double",
    }
}

fn header(d: Dtype, e: Endian, encoding: &str, extra: &str) -> String {
    let endian = if e == Endian::Big { "big" } else { "little" };
    format!(
        "NRRD0004\n# a comment\ntype: {}\ndimension: 3\nsizes: 3 2 4\nendian: {endian}\nencoding: {encoding}\nkey:=value\n{extra}",
        type_name(d)
    )
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn attached_raw_and_gzip_every_type_and_endian() {
    let dir = tempfile::tempdir().unwrap();
    for d in ALL {
        for e in [Endian::Little, Endian::Big] {
            let values = sample_values(d, 24);
            let data = encode(d, e, &values);
            for (enc, payload) in [("raw", data.clone()), ("gzip", gzip(&data))] {
                let mut file = header(d, e, enc, "spacings: 0.5 1 2\n\n").into_bytes();
                file.extend(&payload);
                let p = write(dir.path(), "v.nrrd", &file);
                assert_eq!(
                    read_all(&p, &OpenOptions::default()).unwrap(),
                    as_f32(&values),
                    "{d} {e:?} {enc}"
                );
                let v = open_path(&p, &OpenOptions::default()).unwrap();
                assert_eq!(v.grid().spacing, [0.5, 1.0, 2.0]);
                assert_eq!(v.dtype(), Some(d));
            }
        }
    }
}

/// A 4-D header with an axis of size 1 first or last (`sizes: 1 X Y Z`, a one-component
/// vector) is read as the 3-D volume it is, every per-axis field without that axis.
#[test]
fn a_unit_axis_first_or_last_is_dropped() {
    let dir = tempfile::tempdir().unwrap();
    for (sizes, per_axis) in [
        (
            "1 3 2 4",
            "spacings: nan 0.5 1 2\naxis mins: nan 1 2 3\ncenterings: none node node node\n",
        ),
        (
            "3 2 4 1",
            "space directions: (0.5,0,0) (0,1,0) (0,0,2) none\nspace origin: (1,2,3)\n",
        ),
    ] {
        let text = header(Dtype::U8, Endian::Little, "raw", &format!("{per_axis}\n")).replace(
            "dimension: 3\nsizes: 3 2 4",
            &format!("dimension: 4\nsizes: {sizes}"),
        );
        let mut file = text.into_bytes();
        file.extend(0..24u8);
        let p = write(dir.path(), "v.nrrd", &file);
        let v = open_path(&p, &OpenOptions::default()).unwrap();
        assert_eq!(v.grid().dims, [3, 2, 4], "{sizes}");
        assert_eq!(v.grid().spacing, [0.5, 1.0, 2.0], "{sizes}");
        assert_eq!(v.grid().origin, [1.0, 2.0, 3.0], "{sizes}");
        let values: Vec<f32> = (0..24).map(|v| v as f32).collect();
        assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), values);
    }
}

#[test]
fn space_directions_and_origin() {
    let dir = tempfile::tempdir().unwrap();
    let extra = "space: left-posterior-superior\nspace directions: (0,2,0) (3,0,0) (0,0,0.5)\nspace origin: (1,-2,3.5)\n\n";
    let mut file = header(Dtype::U8, Endian::Little, "raw", extra).into_bytes();
    file.extend(0..24u8);
    let p = write(dir.path(), "v.nrrd", &file);
    let v = open_path(&p, &OpenOptions::default()).unwrap();
    assert_eq!(v.grid().spacing, [2.0, 3.0, 0.5]);
    assert_eq!(v.grid().origin, [1.0, -2.0, 3.5]);
    assert_eq!(v.orientation(), Orientation::Rotated, "x and y swapped");
}

/// Negative steps (LPS data written as RAS-flipped, or negative spacings) are reported as flips;
/// the spacing is their length and the origin the header's.
#[test]
fn flips_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "space directions: (-0.5,0,0) (0,-0.8,0) (0,0,1.2)\nspace origin: (10,-5,3)\n\n",
            [true, true, false],
        ),
        ("spacings: 0.5 0.8 -1.2\n\n", [false, false, true]),
        ("spacings: 0.5 0.8 1.2\n\n", [false; 3]),
    ];
    for (extra, flips) in cases {
        let mut file = header(Dtype::U8, Endian::Little, "raw", extra).into_bytes();
        file.extend(0..24u8);
        let p = write(dir.path(), "v.nrrd", &file);
        let v = open_path(&p, &OpenOptions::default()).unwrap();
        let g = v.grid();
        assert!(
            g.spacing
                .iter()
                .zip([0.5, 0.8, 1.2])
                .all(|(a, b)| (a - b).abs() < 1e-12),
            "{extra}: {:?}",
            g.spacing
        );
        assert_eq!(v.orientation(), Orientation::from_flips(flips), "{extra}");
    }
}

/// Without `space origin`, `axis mins` place the first sample: the min itself for node
/// centering (the default), half a spacing past it for cell centering.
#[test]
fn axis_mins_place_the_first_sample() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("axis mins: 10 -5 3\n", [10.0, -5.0, 3.0]),
        (
            "axis mins: 10 -5 nan\ncenterings: cell node ???\n",
            [10.25, -5.0, 0.0],
        ),
        (
            "axis mins: 10 -5 3\ncenters: cell cell cell\n",
            [10.25, -4.6, 3.6],
        ),
        (
            "axis mins: 10 -5 3\nspace origin: (1,2,3)\n",
            [1.0, 2.0, 3.0],
        ),
        ("", [0.0; 3]),
    ];
    for (extra, want) in cases {
        let extra = format!("spacings: 0.5 0.8 1.2\n{extra}\n");
        let mut file = header(Dtype::U8, Endian::Little, "raw", &extra).into_bytes();
        file.extend(0..24u8);
        let p = write(dir.path(), "v.nrrd", &file);
        let g = open_path(&p, &OpenOptions::default()).unwrap().grid();
        assert!(
            g.origin
                .iter()
                .zip(want)
                .all(|(a, b)| (a - b).abs() < 1e-12),
            "{extra}: {:?}",
            g.origin
        );
    }
    let mut file = header(
        Dtype::U8,
        Endian::Little,
        "raw",
        "centerings: cell edge node\n\n",
    )
    .into_bytes();
    file.extend(0..24u8);
    let e = error_of(&file);
    assert!(e.contains("three centerings among cell, node"), "{e}");
}

#[test]
fn ascii_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let mut file = header(Dtype::I16, Endian::Little, "ascii", "\n");
    for i in 0..24 {
        file.push_str(&format!("{}\n", i * 100 - 1000));
    }
    let p = write(dir.path(), "v.nrrd", file.as_bytes());
    let want: Vec<f32> = (0..24).map(|i| (i * 100 - 1000) as f32).collect();
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want);
}

/// Finite doubles beyond f32's range read as ±f32::MAX and are counted, in every encoding
/// (mapped raw, gzip stream, ASCII text, which is read as f64 whatever the type).
#[test]
fn doubles_beyond_f32_are_saturated_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let (values, want, n) = crate::testutil::beyond_f32();
    let text: String = values.iter().map(|v| format!("{v:e}\n")).collect();
    for e in [Endian::Little, Endian::Big] {
        let data = encode(Dtype::F64, e, &values);
        for (d, enc, payload) in [
            (Dtype::F64, "raw", data.clone()),
            (Dtype::F64, "gzip", gzip(&data)),
            (Dtype::F64, "ascii", text.clone().into_bytes()),
            (Dtype::F32, "ascii", text.clone().into_bytes()),
        ] {
            let mut file = header(d, e, enc, "\n").into_bytes();
            file.extend(&payload);
            let p = write(dir.path(), "v.nrrd", &file);
            let (got, saturated) =
                crate::testutil::read_all_saturated(&p, &OpenOptions::default()).unwrap();
            assert!(
                crate::testutil::same_values(&got, &want),
                "{d} {e:?} {enc}: {got:?}"
            );
            assert_eq!(saturated, n, "{d} {e:?} {enc}");
        }
    }
}

#[test]
fn detached_single_file_with_byte_skip() {
    let dir = tempfile::tempdir().unwrap();
    let values = sample_values(Dtype::U16, 24);
    let mut data = vec![9u8; 5];
    data.extend(encode(Dtype::U16, Endian::Big, &values));
    write(dir.path(), "v.raw", &data);
    for skip in ["5", "-1"] {
        let extra = format!("data file: v.raw\nbyte skip: {skip}\n");
        let h = header(Dtype::U16, Endian::Big, "raw", &extra);
        let p = write(dir.path(), "v.nhdr", h.as_bytes());
        assert_eq!(
            read_all(&p, &OpenOptions::default()).unwrap(),
            as_f32(&values),
            "byte skip {skip}"
        );
    }
    // Gzip detached, byte skip counted in decoded bytes.
    write(dir.path(), "v.raw.gz", &gzip(&data));
    let h = header(
        Dtype::U16,
        Endian::Big,
        "gzip",
        "data file: v.raw.gz\nbyte skip: 5\n",
    );
    let p = write(dir.path(), "v.nhdr", h.as_bytes());
    assert_eq!(
        read_all(&p, &OpenOptions::default()).unwrap(),
        as_f32(&values)
    );
}

#[test]
fn detached_file_lists() {
    let dir = tempfile::tempdir().unwrap();
    let values = sample_values(Dtype::I16, 24);
    let data = encode(Dtype::I16, Endian::Little, &values);
    for (k, chunk) in data.chunks(12).enumerate() {
        write(dir.path(), &format!("s{:03}.bin", 2 * k + 1), chunk);
        write(dir.path(), &format!("g{k}.gz"), &gzip(chunk));
    }
    let cases = [
        ("raw", "data file: s%03d.bin 1 7 2\n".to_string()),
        ("gzip", "data file: g%d.gz 0 3 1 2\n".to_string()),
        (
            "raw",
            "data file: LIST\ns001.bin\ns003.bin\ns005.bin\ns007.bin\n".to_string(),
        ),
    ];
    for (enc, extra) in cases {
        let h = header(Dtype::I16, Endian::Little, enc, &extra);
        let p = write(dir.path(), "v.nhdr", h.as_bytes());
        assert_eq!(
            read_all(&p, &OpenOptions::default()).unwrap(),
            as_f32(&values),
            "{extra}"
        );
    }
}

#[test]
fn printf_forms() {
    assert_eq!(printf_d("a.%d", 7).as_deref(), Some("a.7"));
    assert_eq!(printf_d("a%03d.raw", 7).as_deref(), Some("a007.raw"));
    assert_eq!(printf_d("a%3d", 7).as_deref(), Some("a  7"));
    assert_eq!(printf_d("nopattern", 7), None);
    assert_eq!(printf_d("a%0255d", 7).map(|n| n.len()), Some(256));
    // Widths past what `format!` takes panicked ("Formatting argument out of range").
    for width in [
        "256",
        "100000000",
        "2147483648",
        "4294967296",
        "99999999999999999999",
    ] {
        assert_eq!(printf_d(&format!("a.%{width}d"), 7), None, "{width}");
        assert_eq!(printf_d(&format!("a.%0{width}d"), 7), None, "{width}");
    }
}

/// Writes `file` as an attached NRRD and returns the outcome with the temp path replaced by DIR.
fn error_of(file: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "bad.nrrd", file);
    outcome(&p).replace(&dir.path().display().to_string(), "DIR")
}

#[test]
fn bad_files_give_one_line_errors() {
    let ok = |extra: &str, enc: &str| header(Dtype::U8, Endian::Little, enc, extra);
    let with_data = |h: String, data: &[u8]| {
        let mut f = h.into_bytes();
        f.extend_from_slice(data);
        f
    };
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (
            b"PNG\nsizes: 1\n".to_vec(),
            "DIR/bad.nrrd: header line 1: expected the NRRD magic \"NRRD0001\"..\"NRRD0005\", found \"PNG\"",
        ),
        (
            b"NRRD0004\ntype: int64\n".to_vec(),
            "DIR/bad.nrrd: header line 2: expected a type among int8/uint8/int16/uint16/int32/uint32/float/double, found \"int64\"",
        ),
        (
            b"NRRD0004\ntype: uint8\nencoding: bzip2\n".to_vec(),
            "DIR/bad.nrrd: header line 3: expected encoding raw, gzip or ascii, found \"bzip2\"",
        ),
        (
            b"NRRD0004\ntype: uint8\nencoding: raw\n\n".to_vec(),
            "DIR/bad.nrrd: header: expected a \"sizes:\" line, found \"none\"",
        ),
        (
            b"NRRD0004\ndimension: 4\n".to_vec(),
            "DIR/bad.nrrd: header line 2: expected dimension: 3 (a scalar volume), or 4 with a first or last axis of size 1 (save other 4-D data as one 3-D volume per component or time point, e.g. with unu slice), found \"4\"",
        ),
        (
            b"NRRD0004\ndimension: 4\nsizes: 3 2 2 4\n".to_vec(),
            "DIR/bad.nrrd: header line 2: expected dimension: 3 (a scalar volume), or 4 with a first or last axis of size 1 (save other 4-D data as one 3-D volume per component or time point, e.g. with unu slice), found \"4\"",
        ),
        (
            b"NRRD0004\nsizes 3 2 4\n".to_vec(),
            "DIR/bad.nrrd: header line 2: expected \"field: value\", found \"sizes 3 2 4\"",
        ),
        (
            with_data(ok("\n", "raw"), &[0; 23]),
            "DIR/bad.nrrd: file is 123 bytes but dims 3x2x4 of u8 plus 100 header bytes need 124; check the NRRD header's sizes, type, byte skip and data file",
        ),
        (
            with_data(ok("\n", "gzip"), &gzip(&[0; 23])),
            "DIR/bad.nrrd: gzip NRRD payload voxel 23 (slice 3): expected 24 voxels of u8 for dims 3x2x4, found \"end of data (truncated file?)\"",
        ),
        (
            with_data(ok("\n", "gzip"), b"\x1f\x8b\x08\x00garbage-garbage-garbage"),
            "DIR/bad.nrrd: gzip NRRD payload voxel 0 (slice 0): expected valid encoded data, found \"corrupt deflate stream\"",
        ),
        (
            with_data(ok("\n", "gzip"), &gzip(&[0; 29])),
            "DIR/bad.nrrd: gzip NRRD payload after the last slice: expected the end of the data for dims 3x2x4 (24 voxels of u8), found \"more data (check the header's sizes)\"",
        ),
        (
            with_data(
                ok("\n", "gzip"),
                &[gzip(&[0; 24]), b"\ngarbage".to_vec()].concat(),
            ),
            "DIR/bad.nrrd: gzip NRRD payload after the last slice: expected the end of the data, found \"more bytes, not decodable: unexpected end of file\"",
        ),
        // A newline after the stream (pynrrd, teem) is not data.
        (
            with_data(
                ok("\n", "gzip"),
                &[gzip(&[0; 24]), b"\r\n\n".to_vec()].concat(),
            ),
            "Ok",
        ),
        (
            with_data(ok("\n", "ascii"), b"1 2 3 x"),
            "DIR/bad.nrrd: ascii NRRD payload voxel 3 (slice 0): expected valid encoded data, found \"a number as value 3, found \\\"x\\\"\"",
        ),
        (
            ok("data file: missing.raw\n", "raw").into_bytes(),
            "DIR/missing.raw: no such file; check the input path",
        ),
        (
            header(Dtype::U16, Endian::Little, "raw", "\n")
                .replace("endian: little\n", "")
                .into_bytes(),
            "DIR/bad.nrrd: header: expected an \"endian: little|big\" line for type u16, found \"none\"",
        ),
        (
            ok("\n", "raw")
                .replace("sizes: 3 2 4", "sizes: 0 2 4")
                .into_bytes(),
            "DIR/bad.nrrd: dims 0x2x4 need at least 2 voxels per axis; check the dims",
        ),
        (
            ok("\n", "raw")
                .replace("sizes: 3 2 4", "sizes: 4294967296 4294967296 2")
                .into_bytes(),
            "DIR/bad.nrrd: dims 4294967296x4294967296x2 overflow a 64-bit voxel count; check the dims",
        ),
        (
            header(Dtype::F64, Endian::Little, "raw", "\n")
                .replace("sizes: 3 2 4", "sizes: 4294967296 1048576 1024")
                .into_bytes(),
            "DIR/bad.nrrd: dims 4294967296x1048576x1024 of f64 need more than 2^64 bytes; check the sizes line",
        ),
        (
            // Fits u64 but no machine can hold one slice of it: must be an error, not an abort,
            // and the 8 bytes of data disprove the claim before anything is allocated for it.
            with_data(
                ok("\n", "gzip").replace("sizes: 3 2 4", "sizes: 2147483648 2147483648 2"),
                &gzip(&[0; 8]),
            ),
            "DIR/bad.nrrd: gzip NRRD payload voxel 8 (slice 0): expected 9223372036854775808 voxels of u8 for dims 2147483648x2147483648x2, found \"end of data (truncated file?)\"",
        ),
    ];
    assert_all_equal(
        cases
            .into_iter()
            .map(|(file, want)| (error_of(&file), want.to_string())),
    );
}

/// Valid small files for the robustness checks: attached raw and gzip.
pub(crate) fn samples() -> Vec<(&'static str, Vec<u8>)> {
    let values = sample_values(Dtype::I16, 24);
    let data = encode(Dtype::I16, Endian::Big, &values);
    ["raw", "gzip"]
        .into_iter()
        .map(|enc| {
            let mut f = header(Dtype::I16, Endian::Big, enc, "spacings: 1 1 1\n\n").into_bytes();
            f.extend(if enc == "raw" {
                data.clone()
            } else {
                gzip(&data)
            });
            ("sample.nrrd", f)
        })
        .collect()
}
