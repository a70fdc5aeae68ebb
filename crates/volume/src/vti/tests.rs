use super::*;
use crate::codec::tests::compress;
use crate::dtype::tests::{encode, sample_values};
use crate::open_path;
use crate::testutil::{assert_all_equal, outcome, read_all};

/// Test-side base64 encoder (the inverse of `Base64Reader`).
fn b64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= c.len() {
                s.push(T[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

#[derive(Clone, Copy, Debug)]
struct Case {
    format: &'static str, // ascii, binary, appended-raw, appended-base64
    zlib: bool,
    u64_header: bool,
    endian: Endian,
}

fn words(values: &[u64], c: Case) -> Vec<u8> {
    values
        .iter()
        .flat_map(|&v| match (c.u64_header, c.endian) {
            (true, Endian::Little) => v.to_le_bytes().to_vec(),
            (true, Endian::Big) => v.to_be_bytes().to_vec(),
            (false, Endian::Little) => (v as u32).to_le_bytes().to_vec(),
            (false, Endian::Big) => (v as u32).to_be_bytes().to_vec(),
        })
        .collect()
}

/// Header bytes and data bytes of one array as VTK frames them.
fn framed(data: &[u8], c: Case) -> (Vec<u8>, Vec<u8>) {
    if c.zlib {
        let (layout, blocks) = compress(data, 40);
        let mut h = vec![
            layout.compressed.len() as u64,
            layout.block_size,
            layout.last_size,
        ];
        h.extend(&layout.compressed);
        (words(&h, c), blocks)
    } else {
        (words(&[data.len() as u64], c), data.to_vec())
    }
}

/// A VTI with a decoy array "first" before the array "v" holding `values` of `dtype`.
fn vti(dtype: Dtype, vti_type: &str, values: &[f64], c: Case) -> Vec<u8> {
    let data = encode(dtype, c.endian, values);
    let decoy = encode(Dtype::U8, c.endian, &[7.0; 24]);
    let order = if c.endian == Endian::Big {
        "BigEndian"
    } else {
        "LittleEndian"
    };
    let header = if c.u64_header { "UInt64" } else { "UInt32" };
    let comp = if c.zlib {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let mut doc = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"{order}\" header_type=\"{header}\"{comp}>\n<ImageData WholeExtent=\"1 3 0 1 2 5\" Origin=\"10 0 0\" Spacing=\"2 1 0.5\">\n<Piece Extent=\"1 3 0 1 2 5\">\n<PointData Scalars=\"v\">\n"
    );
    let mut appended = Vec::new();
    for (name, ty, bytes, vals) in [
        ("first", "UInt8", &decoy, vec![7.0; 24]),
        ("v", vti_type, &data, values.to_vec()),
    ] {
        let (h, d) = framed(bytes, c);
        match c.format {
            "ascii" => {
                // Large values as VTK writes them ("3e300"), not 300 digits.
                let text: Vec<String> = vals
                    .iter()
                    .map(|v| match v.abs() < 1e16 {
                        true => v.to_string(),
                        false => format!("{v:e}"),
                    })
                    .collect();
                doc += &format!(
                    "<DataArray type=\"{ty}\" Name=\"{name}\" format=\"ascii\">\n{}\n</DataArray>\n",
                    text.join(" ")
                );
            }
            "binary" => {
                doc += &format!(
                    "<DataArray type=\"{ty}\" Name=\"{name}\" format=\"binary\">\n  {}{}\n</DataArray>\n",
                    b64(&h),
                    b64(&d)
                );
            }
            "appended-raw" => {
                doc += &format!(
                    "<DataArray type=\"{ty}\" Name=\"{name}\" format=\"appended\" offset=\"{}\"/>\n",
                    appended.len()
                );
                appended.extend(h);
                appended.extend(d);
            }
            _ => {
                doc += &format!(
                    "<DataArray type=\"{ty}\" Name=\"{name}\" format=\"appended\" offset=\"{}\"/>\n",
                    appended.len()
                );
                appended.extend(b64(&h).into_bytes());
                appended.extend(b64(&d).into_bytes());
            }
        }
    }
    doc += "</PointData>\n</Piece>\n</ImageData>\n";
    let mut out = doc.into_bytes();
    if c.format.starts_with("appended") {
        let enc = if c.format == "appended-raw" {
            "raw"
        } else {
            "base64"
        };
        out.extend(format!("<AppendedData encoding=\"{enc}\">\n   _").into_bytes());
        out.extend(appended);
        out.extend(b"\n</AppendedData>\n");
    }
    out.extend(b"</VTKFile>\n");
    out
}

fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    for format in ["ascii", "binary", "appended-raw", "appended-base64"] {
        for zlib in [false, true] {
            for u64_header in [false, true] {
                for endian in [Endian::Little, Endian::Big] {
                    v.push(Case {
                        format,
                        zlib,
                        u64_header,
                        endian,
                    });
                }
            }
        }
    }
    v
}

#[test]
fn every_form_header_type_and_byte_order() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.vti");
    for (dtype, ty) in [
        (Dtype::I16, "Int16"),
        (Dtype::F64, "Float64"),
        (Dtype::U8, "UInt8"),
        (Dtype::U32, "UInt32"),
    ] {
        let values = sample_values(dtype, 24);
        for c in cases() {
            std::fs::write(&p, vti(dtype, ty, &values, c)).unwrap();
            let want: Vec<f32> = values.iter().map(|&x| x as f32).collect();
            assert_eq!(
                read_all(&p, &OpenOptions::default()).unwrap(),
                want,
                "{ty} {c:?}"
            );
            let v = open_path(&p, &OpenOptions::default()).unwrap();
            assert_eq!(v.grid().dims, [3, 2, 4]);
            assert_eq!(v.grid().spacing, [2.0, 1.0, 0.5]);
            assert_eq!(
                v.grid().origin,
                [12.0, 0.0, 1.0],
                "origin includes the extent start"
            );
            assert_eq!(v.dtype(), Some(dtype));
            let first = OpenOptions {
                array: Some("first".into()),
                ..Default::default()
            };
            assert_eq!(read_all(&p, &first).unwrap(), vec![7.0; 24], "{c:?}");
        }
    }
}

/// Finite Float64 values beyond f32's range read as ±f32::MAX and are counted, in every form.
#[test]
fn float64_beyond_f32_is_saturated_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.vti");
    let (values, want, n) = crate::testutil::beyond_f32();
    for c in cases() {
        std::fs::write(&p, vti(Dtype::F64, "Float64", &values, c)).unwrap();
        let (got, saturated) =
            crate::testutil::read_all_saturated(&p, &OpenOptions::default()).unwrap();
        assert!(crate::testutil::same_values(&got, &want), "{c:?}: {got:?}");
        assert_eq!(saturated, n, "{c:?}");
    }
}

/// Byte-level `replace`/`replacen` for files with binary appended data.
struct Bytes(Vec<u8>);

impl Bytes {
    fn replacen(self, from: &str, to: &str, n: usize) -> Self {
        let (from, to) = (from.as_bytes(), to.as_bytes());
        let mut out = Vec::new();
        let (mut i, mut done) = (0, 0);
        while i < self.0.len() {
            if done < n && self.0[i..].starts_with(from) {
                out.extend_from_slice(to);
                i += from.len();
                done += 1;
            } else {
                out.push(self.0[i]);
                i += 1;
            }
        }
        Bytes(out)
    }
    fn replace(self, from: &str, to: &str) -> Self {
        self.replacen(from, to, usize::MAX)
    }
    fn into_bytes(self) -> Vec<u8> {
        self.0
    }
}

/// `Direction` is not applied to the grid, but its flips or rotation are reported.
#[test]
fn direction_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("d.vti");
    let c = Case {
        format: "binary",
        zlib: false,
        u64_header: false,
        endian: Endian::Little,
    };
    let base = vti(Dtype::U8, "UInt8", &sample_values(Dtype::U8, 24), c);
    // The extent starts at (1, 0, 2), Origin (10, 0, 0), Spacing (2, 1, 0.5): voxel (0, 0, 0)
    // is `Origin + Direction (Spacing * start)`, backwards on a flipped axis.
    for (direction, want, origin) in [
        (
            "-1 0 0 0 1 0 0 0 1",
            Orientation::Flipped([true, false, false]),
            [8.0, 0.0, 1.0],
        ),
        (
            "1 0 0 0 -1 0 0 0 -1",
            Orientation::Flipped([false, true, true]),
            [12.0, 0.0, -1.0],
        ),
        ("0 1 0 1 0 0 0 0 1", Orientation::Rotated, [10.0, 2.0, 1.0]),
        ("1 0 0 0 1 0 0 0 1", Orientation::Aligned, [12.0, 0.0, 1.0]),
    ] {
        let file = Bytes(base.clone())
            .replace("Spacing=", &format!("Direction=\"{direction}\" Spacing="))
            .into_bytes();
        std::fs::write(&p, file).unwrap();
        let v = open_path(&p, &OpenOptions::default()).unwrap();
        assert_eq!(v.orientation(), want, "{direction}");
        assert_eq!(v.grid().origin, origin, "{direction}");
    }
    // A negative Spacing (how VTK before 9 wrote a flip) flips its axis like a negative
    // Direction: the grid takes the length, voxel 0 steps back from Origin by the start.
    let file = Bytes(base.clone())
        .replace("Spacing=\"2 1 0.5\"", "Spacing=\"-2 1 0.5\"")
        .into_bytes();
    std::fs::write(&p, file).unwrap();
    let v = open_path(&p, &OpenOptions::default()).unwrap();
    assert_eq!(v.orientation(), Orientation::Flipped([true, false, false]));
    assert_eq!(v.grid().spacing, [2.0, 1.0, 0.5]);
    assert_eq!(v.grid().origin, [8.0, 0.0, 1.0]);
}

#[test]
fn bad_files_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.vti");
    let values = sample_values(Dtype::U8, 24);
    let base = |format, zlib| {
        vti(
            Dtype::U8,
            "UInt8",
            &values,
            Case {
                format,
                zlib,
                u64_header: false,
                endian: Endian::Little,
            },
        )
    };
    let s = |b: Vec<u8>| Bytes(b);
    let cut = |b: Vec<u8>, n: usize| b[..b.len() - n].to_vec();
    let corrupt = {
        let mut b = base("appended-raw", true);
        let at = b.len() - 60;
        b[at..at + 8].fill(0x55);
        b
    };
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (
            b"<html></html>".to_vec(),
            "first tag: expected <VTKFile ...> (a VTK XML file), found \"<html>\"",
        ),
        (
            s(base("binary", false))
                .replace("ImageData\" version", "PolyData\" version")
                .into_bytes(),
            "VTKFile tag: expected type=\"ImageData\", found \"PolyData\"",
        ),
        (
            s(base("binary", true))
                .replace("vtkZLib", "vtkLZ4")
                .into_bytes(),
            "VTKFile tag: expected no compressor or vtkZLibDataCompressor, found \"vtkLZ4DataCompressor\"",
        ),
        (
            s(base("binary", false))
                .replace("\"UInt8\" Name=\"v\"", "\"Int64\" Name=\"v\"")
                .into_bytes(),
            "DataArray \"v\": expected type Int8/UInt8/Int16/UInt16/Int32/UInt32/Float32/Float64, found \"Int64\"",
        ),
        (
            s(base("binary", false))
                .replace("Scalars=\"v\"", "Scalars=\"w\"")
                .into_bytes(),
            "PointData: expected a DataArray named \"w\", found \"arrays [first, v]\"",
        ),
        (
            s(base("ascii", false))
                .replace("<PointData Scalars=\"v\">", "<CellData Scalars=\"v\">")
                .replace("</PointData>", "</CellData>")
                .into_bytes(),
            "CellData: expected point data (isostream meshes values at the grid's points; convert the cells with VTK's vtkCellDataToPointData), found \"cell data arrays [first, v]\"",
        ),
        (
            s(base("binary", false))
                .replace("WholeExtent=\"1 3", "WholeExtent=\"1 1")
                .into_bytes(),
            "dims 1x2x4 need at least 2 voxels per axis; check the dims",
        ),
        (
            s(base("binary", false))
                .replace(
                    "WholeExtent=\"1 3 0 1 2 5\"",
                    "WholeExtent=\"0 4294967295 0 4294967295 0 9\"",
                )
                .into_bytes(),
            "dims 4294967296x4294967296x10 overflow a 64-bit voxel count; check the dims",
        ),
        (
            cut(base("appended-raw", false), 30),
            "file is 491 bytes but dims 3x2x4 of u8 plus 469 header bytes need 493; check WholeExtent, the DataArray type and offset",
        ),
        (
            s(base("appended-raw", false))
                .replace("WholeExtent=\"1 3", "WholeExtent=\"1 4")
                .into_bytes(),
            "DataArray \"v\" header: expected 32 bytes of data, found \"24\"",
        ),
        (
            corrupt,
            "zlib VTI array voxel 0 (slice 0): expected valid encoded data, found \"zlib block 0: corrupt deflate stream\"",
        ),
        (
            s(base("binary", false))
                .replace(
                    "Name=\"v\" format=\"binary\">\n  ",
                    "Name=\"v\" format=\"binary\">\n  *",
                )
                .into_bytes(),
            "DataArray \"v\" header: expected a 4-byte block header, found \"base64 text, found '*' at character 3\"",
        ),
    ];
    assert_all_equal(cases.into_iter().map(|(file, want)| {
        std::fs::write(&p, &file).unwrap();
        (outcome(&p), format!("{}: {want}", p.display()))
    }));
}

/// Valid small files for the robustness checks: one per array form, zlib where it applies.
pub(crate) fn samples() -> Vec<(&'static str, Vec<u8>)> {
    let values = sample_values(Dtype::I16, 24);
    ["ascii", "binary", "appended-raw", "appended-base64"]
        .into_iter()
        .flat_map(|format| [false, true].map(|zlib| (format, zlib)))
        .map(|(format, zlib)| {
            let c = Case {
                format,
                zlib,
                u64_header: zlib,
                endian: Endian::Little,
            };
            ("sample.vti", vti(Dtype::I16, "Int16", &values, c))
        })
        .collect()
}
