use super::*;
use crate::dtype::tests::{ALL, encode, sample_values};
use crate::open_path;
use crate::testutil::{as_f32, assert_all_equal, outcome, read_all};

fn type_name(d: Dtype) -> &'static str {
    match d {
        Dtype::U8 => "unsigned_char",
        Dtype::I8 => "char",
        Dtype::U16 => "unsigned_short",
        Dtype::I16 => "short",
        Dtype::U32 => "unsigned_int",
        Dtype::I32 => "int",
        Dtype::F32 => "float",
        Dtype::F64 => "double",
    }
}

fn head(mode: &str) -> String {
    format!(
        "# vtk DataFile Version 3.0\ntitle\n{mode}\nDATASET STRUCTURED_POINTS\nDIMENSIONS 3 2 4\nSPACING 1 2 0.5\nORIGIN -1 0 1\nPOINT_DATA 24\n"
    )
}

#[test]
fn binary_every_type_and_ascii() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.vtk");
    for d in ALL {
        let values = sample_values(d, 24);
        let mut file = format!(
            "{}SCALARS s {}\nLOOKUP_TABLE default\n",
            head("BINARY"),
            type_name(d)
        )
        .into_bytes();
        file.extend(encode(d, Endian::Big, &values));
        file.push(b'\n');
        std::fs::write(&p, &file).unwrap();
        assert_eq!(
            read_all(&p, &OpenOptions::default()).unwrap(),
            as_f32(&values),
            "{d}"
        );
        let v = open_path(&p, &OpenOptions::default()).unwrap();
        assert_eq!(
            (v.grid().spacing, v.grid().origin),
            ([1.0, 2.0, 0.5], [-1.0, 0.0, 1.0])
        );
        assert_eq!(v.dtype(), Some(d));

        let text: Vec<String> = values.iter().map(|v| v.to_string()).collect();
        let file = format!(
            "{}SCALARS s {} 1\nLOOKUP_TABLE default\n{}\n",
            head("ASCII"),
            type_name(d),
            text.join(" ")
        );
        std::fs::write(&p, file).unwrap();
        assert_eq!(
            read_all(&p, &OpenOptions::default()).unwrap(),
            as_f32(&values),
            "ascii {d}"
        );
    }
}

#[test]
fn picks_named_array() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.vtk");
    let a = sample_values(Dtype::I16, 24);
    let b: Vec<f64> = (0..24).map(|i| i as f64).collect();
    let mut file =
        format!("{}SCALARS a short\nLOOKUP_TABLE default\n", head("BINARY")).into_bytes();
    file.extend(encode(Dtype::I16, Endian::Big, &a));
    file.extend(b"\nSCALARS b float\n");
    file.extend(encode(Dtype::F32, Endian::Big, &b));
    std::fs::write(&p, &file).unwrap();
    let named = |n: &str| OpenOptions {
        array: Some(n.into()),
        ..Default::default()
    };
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), as_f32(&a));
    assert_eq!(read_all(&p, &named("b")).unwrap(), as_f32(&b));
    let e = read_all(&p, &named("c")).unwrap_err().to_string();
    assert!(
        e.ends_with(
            ": end of file: expected a SCALARS array named \"c\" (arrays: a, b), found \"none\""
        ),
        "{e}"
    );
    // The same in ASCII.
    let text = |v: &[f64]| {
        v.iter()
            .map(|x| x.to_string())
            .collect::<Vec<_>>()
            .join("\n")
    };
    let file = format!(
        "{}SCALARS a short\nLOOKUP_TABLE default\n{}\nSCALARS b float\nLOOKUP_TABLE default\n{}\n",
        head("ASCII"),
        text(&a),
        text(&b)
    );
    std::fs::write(&p, file).unwrap();
    assert_eq!(read_all(&p, &named("b")).unwrap(), as_f32(&b));
}

/// vtkStructuredPointsWriter writes unsigned char scalars as `COLOR_SCALARS name 1`: raw bytes
/// in binary files, v / 255 in ASCII ones (6 significant digits).
#[test]
fn one_component_color_scalars_are_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.vtk");
    let bytes: Vec<u8> = (0..24).map(|i| (i * 11) as u8).collect();
    let want: Vec<f32> = bytes.iter().map(|&b| f32::from(b)).collect();
    let mut file = format!("{}COLOR_SCALARS scalars 1\n", head("BINARY")).into_bytes();
    file.extend(&bytes);
    file.push(b'\n');
    std::fs::write(&p, &file).unwrap();
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want);
    assert_eq!(
        open_path(&p, &OpenOptions::default()).unwrap().dtype(),
        Some(Dtype::U8)
    );
    let text: Vec<String> = bytes
        .iter()
        .map(|&b| format!("{:.6}", f64::from(b) / 255.0))
        .collect();
    let file = format!(
        "{}COLOR_SCALARS scalars 1\n{}\n",
        head("ASCII"),
        text.join(" ")
    );
    std::fs::write(&p, file).unwrap();
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want);
    // A color array before the wanted one is skipped.
    let mut file = format!("{}COLOR_SCALARS c 1\n", head("BINARY")).into_bytes();
    file.extend([9u8; 24]);
    file.extend(b"\nSCALARS s unsigned_char\nLOOKUP_TABLE default\n");
    file.extend(&bytes);
    std::fs::write(&p, &file).unwrap();
    let named = OpenOptions {
        array: Some("s".into()),
        ..Default::default()
    };
    assert_eq!(read_all(&p, &named).unwrap(), want);
}

#[test]
fn bad_files_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.vtk");
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (
            format!("{}COLOR_SCALARS rgb 3\n", head("BINARY")).into_bytes(),
            "line 9: expected COLOR_SCALARS with 1 component (isostream meshes one scalar; save one component of the colors as SCALARS), found \"COLOR_SCALARS rgb 3\"",
        ),
        (
            b"hello\n".to_vec(),
            "line 1: expected \"# vtk DataFile Version x.x\", found \"hello\"",
        ),
        (
            b"# vtk DataFile Version 3.0\nt\nBINARY\nDATASET POLYDATA\n".to_vec(),
            "line 4: expected DATASET STRUCTURED_POINTS (a regular grid), found \"DATASET POLYDATA\"",
        ),
        (
            format!("{}SCALARS s long\n", head("BINARY")).into_bytes(),
            "line 9: expected a type among unsigned_char/char/unsigned_short/short/unsigned_int/int/float/double, found \"long\"",
        ),
        (
            head("BINARY")
                .replace("POINT_DATA 24", "POINT_DATA 25")
                .into_bytes()
                .into_iter()
                .chain(b"SCALARS s float\n".iter().copied())
                .collect(),
            "line 9: expected POINT_DATA equal to dims 3x2x4, found \"25\"",
        ),
        (
            {
                let mut f = format!("{}SCALARS s short\nLOOKUP_TABLE default\n", head("BINARY"))
                    .into_bytes();
                f.extend([0u8; 47]);
                f
            },
            "file is 211 bytes but dims 3x2x4 of i16 plus 164 header bytes need 212; check the DIMENSIONS and SCALARS lines against the data",
        ),
        (
            format!(
                "{}SCALARS s short\nLOOKUP_TABLE default\n1 2 3\n",
                head("ASCII")
            )
            .into_bytes(),
            "ascii VTK scalars voxel 3 (slice 0): expected 24 voxels of i16 for dims 3x2x4, found \"end of data (truncated file?)\"",
        ),
        (
            head("BINARY")
                .replace("DIMENSIONS 3 2 4", "DIMENSIONS 3 0 4")
                .replace("POINT_DATA 24", "POINT_DATA 0")
                .into_bytes()
                .into_iter()
                .chain(b"SCALARS s float\n".iter().copied())
                .collect(),
            "dims 3x0x4 need at least 2 voxels per axis; check the dims",
        ),
    ];
    assert_all_equal(cases.into_iter().map(|(file, want)| {
        std::fs::write(&p, &file).unwrap();
        (outcome(&p), format!("{}: {want}", p.display()))
    }));
}

/// Valid small files for the robustness checks: binary and ASCII.
pub(crate) fn samples() -> Vec<(&'static str, Vec<u8>)> {
    let values = sample_values(Dtype::F32, 24);
    let mut binary =
        format!("{}SCALARS s float\nLOOKUP_TABLE default\n", head("BINARY")).into_bytes();
    binary.extend(encode(Dtype::F32, Endian::Big, &values));
    let text: Vec<String> = values.iter().map(|v| v.to_string()).collect();
    let ascii = format!("{}SCALARS s float\n{}\n", head("ASCII"), text.join(" "));
    vec![("sample.vtk", binary), ("sample.vtk", ascii.into_bytes())]
}

/// A negative SPACING (how VTK before 9 wrote a flipped axis) is a flip: the grid takes its
/// length, the source reports the flip, in binary and ASCII files alike.
#[test]
fn negative_spacing_is_a_flip() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("f.vtk");
    let values = sample_values(Dtype::F32, 24);
    for mode in ["BINARY", "ASCII"] {
        let mut file = format!("{}SCALARS s float\nLOOKUP_TABLE default\n", head(mode))
            .replace("SPACING 1 2 0.5", "SPACING -1 2 -0.5")
            .into_bytes();
        match mode {
            "BINARY" => file.extend(encode(Dtype::F32, Endian::Big, &values)),
            _ => file.extend(
                values
                    .iter()
                    .map(|v| format!("{v} "))
                    .collect::<String>()
                    .bytes(),
            ),
        }
        std::fs::write(&p, &file).unwrap();
        let v = open_path(&p, &OpenOptions::default()).unwrap();
        assert_eq!(v.grid().spacing, [1.0, 2.0, 0.5], "{mode}");
        assert_eq!(v.grid().origin, [-1.0, 0.0, 1.0], "{mode}");
        assert_eq!(
            v.orientation(),
            Orientation::Flipped([true, false, true]),
            "{mode}"
        );
    }
}
