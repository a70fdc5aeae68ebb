//! Integration tests: golden fixtures, rule violations with their messages, atomic output, and
//! round trips through every format on generated streams.

use std::path::{Path, PathBuf};

use isostream_smesh::{
    ConvertOptions, Element, Format, Header, IndexedMesh, PlyEncoding, StreamReader, StreamWriter,
    convert, convert_with, read_indexed, validate,
};
use proptest::prelude::*;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// One call on a writer / one element of a stream.
#[derive(Debug, Clone, PartialEq)]
enum Op {
    V([f32; 3], Vec<f32>),
    T([u64; 3], [bool; 3]),
    X(u64),
}

fn write(path: &Path, header: &Header, ops: &[Op]) -> isostream_smesh::WriteStats {
    let mut w = StreamWriter::create(path, header).unwrap();
    for op in ops {
        match op {
            Op::V(p, a) => w.vertex(*p, a).unwrap(),
            Op::T(v, l) => w.triangle(*v, *l).unwrap(),
            Op::X(v) => w.finalize(*v).unwrap(),
        }
    }
    w.finish().unwrap()
}

fn read(path: &Path) -> Vec<Op> {
    StreamReader::open(path)
        .unwrap()
        .map(|e| match e.unwrap() {
            Element::Vertex { pos, attrs } => Op::V(pos, attrs),
            Element::Triangle { v, finalized } => Op::T(v, finalized),
            Element::Finalize(v) => Op::X(v),
        })
        .collect()
}

fn tetrahedron() -> Vec<Op> {
    let v = |x, y, z| Op::V([x, y, z], vec![]);
    vec![
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 1.0, 0.0),
        Op::T([0, 2, 1], [false; 3]),
        v(0.0, 0.0, 1.0),
        Op::T([0, 1, 3], [false; 3]),
        Op::T([0, 3, 2], [true, false, false]),
        Op::T([1, 2, 3], [true; 3]),
    ]
}

fn tetra_header() -> Header {
    Header {
        comments: vec!["tetrahedron".into()],
        attribute_names: vec![],
    }
}

/// The tetrahedron with attributes `t` and `grad` (the `_attrs` fixtures).
fn tetrahedron_attrs() -> Vec<Op> {
    let values = [[0.5, 1.0], [1.5, 2.0], [-2.5, 0.25], [3.0, 1024.0]];
    let mut k = 0;
    tetrahedron()
        .into_iter()
        .map(|op| match op {
            Op::V(p, _) => {
                k += 1;
                Op::V(p, values[k - 1].to_vec())
            }
            other => other,
        })
        .collect()
}

fn tetra_attrs_header() -> Header {
    Header {
        attribute_names: vec!["t".into(), "grad".into()],
        ..tetra_header()
    }
}

// ---------------------------------------------------------------- golden fixtures

#[test]
fn golden_fixtures_are_written_byte_for_byte_and_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let plain = (tetra_header(), tetrahedron());
    let attrs = (tetra_attrs_header(), tetrahedron_attrs());
    for (name, (header, ops)) in [
        ("tetrahedron.sma", &plain),
        ("tetrahedron.smb", &plain),
        ("tetrahedron_attrs.sma", &attrs),
        ("tetrahedron_attrs.smb", &attrs),
    ] {
        let out = dir.path().join(name);
        let stats = write(&out, header, ops);
        let golden = std::fs::read(data(name)).unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), golden, "{name}");
        assert_eq!(stats.bytes, golden.len() as u64);
        assert_eq!(
            (stats.vertices, stats.triangles, stats.max_active_vertices),
            (4, 4, 4)
        );
        assert_eq!(&read(&data(name)), ops, "{name}");
        let h = StreamReader::open(&data(name)).unwrap().header().clone();
        assert_eq!((h.nverts, h.nfaces), (Some(4), Some(4)));
        assert_eq!(h.bbox, Some(([0.0; 3], [1.0; 3])));
        assert_eq!(h.comments, vec!["tetrahedron".to_string()]);
        assert_eq!(h.attribute_names, header.attribute_names, "{name}");
        let report = validate(&data(name)).unwrap();
        assert_eq!((report.vertices, report.triangles), (4, 4));
        assert_eq!(report.max_active_vertices, 4);
        assert_eq!(report.max_triangle_skip, 3);
    }
}

#[test]
fn golden_ply_and_obj_are_what_conversion_writes() {
    let dir = tempfile::tempdir().unwrap();
    let opts = ConvertOptions {
        ply_encoding: PlyEncoding::Ascii,
        ..ConvertOptions::default()
    };
    for name in ["tetrahedron.ply", "tetrahedron.obj"] {
        let out = dir.path().join(name);
        convert_with(&data("tetrahedron.smb"), &out, &opts).unwrap();
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            std::fs::read_to_string(data(name)).unwrap()
        );
        let expected = corners(&read_indexed(&data("tetrahedron.smb")).unwrap());
        assert_eq!(corners(&read_indexed(&data(name)).unwrap()), expected);
    }
}

/// Attributes survive conversion of the SMB fixture to SMA and ASCII PLY (byte for byte the
/// hand-written fixtures) and back to SMB: byte for byte from SMA (a stream, piped as is), the
/// same triangles and values from PLY (re-emitted in first-use order).
#[test]
fn golden_attribute_fixtures_convert_into_each_other() {
    let dir = tempfile::tempdir().unwrap();
    let opts = ConvertOptions {
        ply_encoding: PlyEncoding::Ascii,
        ..ConvertOptions::default()
    };
    for name in ["tetrahedron_attrs.sma", "tetrahedron_attrs.ply"] {
        let out = dir.path().join(name);
        convert_with(&data("tetrahedron_attrs.smb"), &out, &opts).unwrap();
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            std::fs::read_to_string(data(name)).unwrap(),
            "{name}"
        );
        let back = dir.path().join(format!("{name}.smb"));
        convert(&data(name), &back).unwrap();
        assert_eq!(
            corners(&read_indexed(&back).unwrap()),
            corners(&read_indexed(&data("tetrahedron_attrs.smb")).unwrap()),
            "{name}"
        );
    }
    let back = dir.path().join("back.smb");
    convert(&data("tetrahedron_attrs.sma"), &back).unwrap();
    assert_eq!(
        std::fs::read(&back).unwrap(),
        std::fs::read(data("tetrahedron_attrs.smb")).unwrap()
    );
    let m = read_indexed(&data("tetrahedron_attrs.smb")).unwrap();
    assert_eq!(m.attribute_names, ["t", "grad"]);
    assert_eq!(m.attrs, [0.5, 1.0, 1.5, 2.0, -2.5, 0.25, 3.0, 1024.0]);
}

/// The comments of a header.
fn comments(path: &Path) -> Vec<String> {
    StreamReader::open(path).unwrap().header().comments.clone()
}

/// Trial bug: `convert` from PLY, OBJ, STL or GLB dropped the header's comments (a run's
/// provenance: `isostream 0.1.0`, `input PATH iso VALUE`), so SMB -> PLY -> SMB had none
/// left. Now A -> B -> A keeps them through every format B, with or without attributes (whose
/// notes in OBJ and STL headers are not taken for comments), and B -> ASCII PLY writes them.
#[test]
fn comments_round_trip_through_every_format() {
    let dir = tempfile::tempdir().unwrap();
    let provenance = vec![
        "isostream 0.1.0".to_string(),
        "input ../data/head.nhdr iso 1150".to_string(),
    ];
    let ascii = ConvertOptions {
        ply_encoding: PlyEncoding::Ascii,
        ..ConvertOptions::default()
    };
    for (ops, attribute_names) in [
        (tetrahedron(), vec![]),
        (
            tetrahedron_attrs(),
            vec!["t".to_string(), "grad".to_string()],
        ),
    ] {
        let header = Header {
            comments: provenance.clone(),
            attribute_names,
        };
        let a = dir.path().join("a.smb");
        write(&a, &header, &ops);
        for name in ["b.sma", "b.ply", "b.obj", "b.stl", "b.glb"] {
            // STL's 80 bytes hold the note on dropped attributes and the first comment only.
            let kept = match (name, header.attribute_names.is_empty()) {
                ("b.stl", false) => &provenance[..1],
                _ => &provenance[..],
            };
            let b = dir.path().join(name);
            convert(&a, &b).unwrap();
            assert_eq!(read_indexed(&b).unwrap().comments, kept, "{b:?}");
            let back = dir.path().join("back.smb");
            convert(&b, &back).unwrap();
            assert_eq!(comments(&back), kept, "{b:?}");
            let ply = dir.path().join("back.ply");
            convert_with(&b, &ply, &ascii).unwrap();
            let text = String::from_utf8_lossy(&std::fs::read(&ply).unwrap()).into_owned();
            let lines: String = kept.iter().map(|c| format!("comment {c}\n")).collect();
            assert!(text.contains(&lines), "{b:?}: {text}");
        }
    }
}

/// `path`'s bytes with `from` (present once) replaced by `to`, of the same length.
fn patch(path: &Path, from: &[u8], to: &[u8]) {
    assert_eq!(from.len(), to.len());
    let mut bytes = std::fs::read(path).unwrap();
    let at = bytes.windows(from.len()).position(|w| w == from).unwrap();
    bytes[at..at + from.len()].copy_from_slice(to);
    std::fs::write(path, bytes).unwrap();
}

/// Only printable ASCII and line ends (`\n`).
fn printable(bytes: &[u8]) -> bool {
    bytes
        .iter()
        .all(|&b| b == b'\n' || (b' '..=b'~').contains(&b))
}

/// Trial bug: `convert` copied another tool's header comments into its output as they were: a
/// non-ASCII or control character went into a PLY header (which is ASCII), a NUL into an OBJ
/// our own reader then refused as binary, and a line break (in a GLB's extras or an SMB's
/// comment table) was dropped or failed the conversion. Now they are escaped to printable ASCII
/// (`é` as `\u{e9}`, a line break as `\u{a}`) as the comment naming a run's input is, and
/// every output reads back with them.
#[test]
fn foreign_comments_are_carried_as_printable_ascii() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("in.ply");
    let mut text = b"ply\nformat ascii 1.0\ncomment Scanner \xc3\xa9 2.0\n".to_vec();
    text.extend(b"comment bell\x07 nul\x00 esc\x1b[0m\n");
    text.extend(b"element vertex 4\nproperty float x\nproperty float y\nproperty float z\n");
    text.extend(b"element face 4\nproperty list uchar int vertex_indices\nend_header\n");
    text.extend(b"0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n");
    std::fs::write(&ply, text).unwrap();
    let obj = dir.path().join("in.obj");
    std::fs::write(
        &obj,
        b"# caf\xe9 (Latin-1)\n# form\x0cfeed\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n\
          f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    // Our writers refuse a line break: put one in the files they wrote.
    let placeholder = |n| Header {
        comments: vec!["X".repeat(n)],
        attribute_names: vec![],
    };
    let smb = dir.path().join("in.smb");
    write(&smb, &placeholder(9), &tetrahedron());
    patch(&smb, b"XXXXXXXXX", b"two\nlines");
    let glb = dir.path().join("in.glb");
    let tmp = dir.path().join("tmp.smb");
    write(&tmp, &placeholder(25), &tetrahedron());
    convert(&tmp, &glb).unwrap();
    patch(&glb, &[b'X'; 25], br"line one\nline two \u00e9");
    let ascii = ConvertOptions {
        ply_encoding: PlyEncoding::Ascii,
        ..ConvertOptions::default()
    };
    for (input, expected) in [
        (
            &ply,
            &[r"Scanner \u{e9} 2.0", r"bell\u{7} nul\u{0} esc\u{1b}[0m"][..],
        ),
        (&obj, &[r"caf\u{fffd} (Latin-1)", r"form\u{c}feed"]),
        (&smb, &[r"two\u{a}lines"]),
        (&glb, &[r"line one\u{a}line two \u{e9}"]),
    ] {
        for (name, options) in [
            ("out.sma", ConvertOptions::default()),
            ("out.smb", ConvertOptions::default()),
            ("out.ply", ConvertOptions::default()),
            ("ascii.ply", ascii),
            ("out.obj", ConvertOptions::default()),
            ("out.stl", ConvertOptions::default()),
            ("out.glb", ConvertOptions::default()),
        ] {
            let out = dir.path().join(name);
            let case = format!("{input:?} -> {name}");
            convert_with(input, &out, &options).unwrap_or_else(|e| panic!("{case}: {e}"));
            let mesh = read_indexed(&out).unwrap_or_else(|e| panic!("{case}: {e}"));
            assert_eq!(mesh.triangles.len(), 4, "{case}");
            let bytes = std::fs::read(&out).unwrap();
            let header = match name {
                "out.ply" | "ascii.ply" => {
                    let end = bytes
                        .windows(11)
                        .position(|w| w == b"end_header\n")
                        .unwrap();
                    &bytes[..end + 11]
                }
                "out.sma" | "out.obj" => &bytes[..],
                "out.stl" => &bytes[..80],
                _ => &[][..],
            };
            assert!(
                printable(header),
                "{case}: {}",
                String::from_utf8_lossy(header)
            );
            match name {
                // 80 bytes hold the comments that fit whole.
                "out.stl" => assert!(
                    mesh.comments.iter().all(|c| expected.contains(&c.as_str())),
                    "{case}: {:?}",
                    mesh.comments
                ),
                _ => assert_eq!(mesh.comments, expected, "{case}"),
            }
        }
    }
}

/// STL's header holds 80 bytes: a comment that does not fit is left out whole (it came back cut
/// short, as another comment), and those that fit come back.
#[test]
fn stl_keeps_the_comments_that_fit_whole() {
    let dir = tempfile::tempdir().unwrap();
    let long = format!("input /{} iso 1", "d/".repeat(40));
    let header = Header {
        comments: vec!["isostream 0.1.0".into(), long, "iso 1".into()],
        attribute_names: vec![],
    };
    let (a, b) = (dir.path().join("a.smb"), dir.path().join("b.stl"));
    write(&a, &header, &tetrahedron());
    convert(&a, &b).unwrap();
    assert_eq!(
        read_indexed(&b).unwrap().comments,
        ["isostream 0.1.0", "iso 1"]
    );
}

/// An ASCII STL shorter than the 80 bytes of a binary header reads (an empty one failed with
/// "failed to fill whole buffer" once the header was read for comments).
#[test]
fn a_short_ascii_stl_reads() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("tiny.stl");
    std::fs::write(&p, "solid t\nendsolid t\n").unwrap();
    let mesh = read_indexed(&p).unwrap();
    assert!(mesh.triangles.is_empty() && mesh.comments.is_empty());
}

/// A foreign OBJ's leading `#` lines are its comments; `#` lines after the first statement are
/// not, and nothing in a comment is read as anything else (a key SMA readers interpret is left
/// out, since the SMA writer refuses it).
#[test]
fn foreign_obj_comments_are_its_leading_lines() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("f.obj");
    std::fs::write(
        &obj,
        "# Blender 4.1\n#\n# nverts 7\n\nmtllib f.mtl\n# 4 vertices\nv 0 0 0\nv 1 0 0\n\
         v 0 1 0\nv 0 0 1\n# f 9 9 9\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    let m = read_indexed(&obj).unwrap();
    assert_eq!(m.comments, ["Blender 4.1"]);
    assert_eq!(m.triangles.len(), 4);
    let sma = dir.path().join("f.sma");
    convert(&obj, &sma).unwrap();
    assert_eq!(comments(&sma), ["Blender 4.1"]);
}

/// OBJ and STL have no per-vertex values: converting a mesh with attributes to them succeeds,
/// keeps the triangles, and says in the file which attributes were dropped.
#[test]
fn obj_and_stl_drop_attributes_and_say_so() {
    let dir = tempfile::tempdir().unwrap();
    let src = data("tetrahedron_attrs.smb");
    let expected: Vec<_> = corners(&read_indexed(&data("tetrahedron.smb")).unwrap());
    for name in ["t.obj", "t.stl"] {
        let out = dir.path().join(name);
        let stats = convert(&src, &out).unwrap();
        assert_eq!((stats.written.vertices, stats.written.triangles), (4, 4));
        let m = read_indexed(&out).unwrap();
        assert!(m.attribute_names.is_empty() && m.attrs.is_empty(), "{name}");
        assert_eq!(corners(&m), expected, "{name}");
    }
    let obj = std::fs::read_to_string(dir.path().join("t.obj")).unwrap();
    assert!(
        obj.contains("# per-vertex attributes not stored (OBJ has none): t grad\n"),
        "{obj}"
    );
    let stl = std::fs::read(dir.path().join("t.stl")).unwrap();
    let head = String::from_utf8_lossy(&stl[..80]);
    assert!(
        head.starts_with("binary STL by isostream; attributes dropped: t grad; tetrahedron"),
        "{head}"
    );
}

#[test]
fn sinks_can_move_to_another_thread() {
    fn send<T: Send>(_: &T) {}
    let dir = tempfile::tempdir().unwrap();
    let sink = isostream_smesh::create_sink(
        &dir.path().join("a.glb"),
        &Header::default(),
        &ConvertOptions::default(),
    )
    .unwrap();
    send(&sink);
    send(&StreamReader::open(&data("tetrahedron.smb")).unwrap());
}

#[test]
fn golden_smb_matches_the_spec_layout() {
    // Built field by field from ../shared/DESIGN.md section 3, independently of the fixture script.
    let mut b = vec![0u8, 0, 0, 0];
    b.extend(1i32.to_le_bytes());
    b.extend(11i32.to_le_bytes());
    b.extend(b"tetrahedron");
    b.extend(4i32.to_le_bytes());
    b.extend(4i32.to_le_bytes());
    b.push(1);
    for x in [0f32, 0.0, 0.0, 1.0, 1.0, 1.0] {
        b.extend(x.to_le_bytes());
    }
    b.extend(0b0001_0111u32.to_le_bytes());
    let f = |b: &mut Vec<u8>, p: [f32; 3]| p.iter().for_each(|x| b.extend(x.to_le_bytes()));
    let t = |b: &mut Vec<u8>, i: [i32; 3]| i.iter().for_each(|x| b.extend(x.to_le_bytes()));
    f(&mut b, [0.0, 0.0, 0.0]);
    f(&mut b, [1.0, 0.0, 0.0]);
    f(&mut b, [0.0, 1.0, 0.0]);
    t(&mut b, [1, 3, 2]);
    f(&mut b, [0.0, 0.0, 1.0]);
    t(&mut b, [1, 2, 4]);
    t(&mut b, [-4, 4, 3]);
    t(&mut b, [-3, -2, -1]);
    assert_eq!(std::fs::read(data("tetrahedron.smb")).unwrap(), b);
}

#[test]
fn golden_smb_with_attributes_matches_the_superset_layout() {
    // Built field by field from FORMATS.md (version 1), independently of the fixture script.
    let mut b = vec![1u8, 0, 0, 0];
    for (len, text) in [(1i32, &b""[..]), (11, b"tetrahedron")] {
        b.extend(len.to_le_bytes());
        b.extend(text);
    }
    for (len, text) in [(2i32, &b""[..]), (1, b"t"), (4, b"grad")] {
        b.extend(len.to_le_bytes());
        b.extend(text);
    }
    b.extend(4i32.to_le_bytes());
    b.extend(4i32.to_le_bytes());
    b.push(1);
    let f = |b: &mut Vec<u8>, p: &[f32]| p.iter().for_each(|x| b.extend(x.to_le_bytes()));
    let t = |b: &mut Vec<u8>, i: [i32; 3]| i.iter().for_each(|x| b.extend(x.to_le_bytes()));
    f(&mut b, &[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
    b.extend(0b0001_0111u32.to_le_bytes());
    f(&mut b, &[0.0, 0.0, 0.0, 0.5, 1.0]);
    f(&mut b, &[1.0, 0.0, 0.0, 1.5, 2.0]);
    f(&mut b, &[0.0, 1.0, 0.0, -2.5, 0.25]);
    t(&mut b, [1, 3, 2]);
    f(&mut b, &[0.0, 0.0, 1.0, 3.0, 1024.0]);
    t(&mut b, [1, 2, 4]);
    t(&mut b, [-4, 4, 3]);
    t(&mut b, [-3, -2, -1]);
    assert_eq!(b.len(), 205);
    assert_eq!(std::fs::read(data("tetrahedron_attrs.smb")).unwrap(), b);
}

#[test]
fn smb_byte_order_is_sanity_checked() {
    let le = std::fs::read(data("tetrahedron.smb")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Declares big-endian but holds little-endian data, like reference writers on x86_64.
    let mut lying = le.clone();
    lying[1] = 1;
    let p = dir.path().join("lying.smb");
    std::fs::write(&p, &lying).unwrap();
    assert_eq!(read(&p), tetrahedron());
    // A genuine big-endian file: every 4-byte word after the magic swapped, except the comment
    // text and the has_bbox byte.
    let mut be = le.clone();
    be[1] = 1;
    let swap = |b: &mut [u8], at: usize| b[at..at + 4].reverse();
    for at in [4, 8, 23, 27] {
        swap(&mut be, at);
    }
    for at in (32..le.len()).step_by(4) {
        swap(&mut be, at);
    }
    let p = dir.path().join("big.smb");
    std::fs::write(&p, &be).unwrap();
    assert_eq!(read(&p), tetrahedron());
    validate(&p).unwrap();

    // The same with attributes: words swapped except the comment, the names and has_bbox.
    let le = std::fs::read(data("tetrahedron_attrs.smb")).unwrap();
    let mut be = le.clone();
    be[1] = 1;
    for at in [4, 8, 23, 27, 32, 40, 44] {
        swap(&mut be, at);
    }
    for at in (49..le.len()).step_by(4) {
        swap(&mut be, at);
    }
    let p = dir.path().join("big_attrs.smb");
    std::fs::write(&p, &be).unwrap();
    assert_eq!(read(&p), tetrahedron_attrs());
    assert_eq!(read_indexed(&p).unwrap().attribute_names, ["t", "grad"]);
}

// ---------------------------------------------------------------- rule violations

/// Writes `body` after a header-less SMA start and returns validate's message.
fn sma_error(dir: &Path, body: &str) -> String {
    let p = dir.join("broken.sma");
    std::fs::write(&p, body).unwrap();
    validate(&p).unwrap_err().to_string()
}

const TRIANGLE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";

#[test]
fn validate_rejects_broken_streams_with_one_line_messages() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let p = d.join("broken.sma");
    let p = p.display();
    let cases = [
        (
            format!("{TRIANGLE}f -3 2 3\nf 1 2 3\n"),
            format!("{p}: triangle 1 on line 5 uses vertex 0, which was already finalized"),
        ),
        (
            format!("{TRIANGLE}f 1 2 3\n"),
            format!(
                "{p}: at end of stream, vertex 0 was never finalized (2 other vertices neither)"
            ),
        ),
        (
            format!("{TRIANGLE}f 1 2 4\nv 0 0 1\n"),
            format!(
                "{p}: triangle 0 on line 4 references vertex 3 (counting from 0) but only 3 vertices precede it"
            ),
        ),
        (
            format!("{TRIANGLE}f -4 2 3\n"),
            format!(
                "{p}: triangle 0 on line 4 uses relative index -4 but only 3 vertices precede it"
            ),
        ),
        (
            format!("# nverts 4\n{TRIANGLE}f -3 -2 -1\n"),
            format!(
                "{p}: at end of stream, the header declares 4 vertices but the stream holds 3 (truncated file?)"
            ),
        ),
        (
            format!("{TRIANGLE}f 0 2 3\n"),
            format!(
                "{p}: line 4: expected nonzero indices (1-based, or negative relative), found f 0 2 3"
            ),
        ),
        (
            format!("{TRIANGLE}q 1\n"),
            format!("{p}: line 4: expected a `v`, `f`, `x` or `#` line, found q 1"),
        ),
        (
            format!("{TRIANGLE}x 1\nf 1 2 3\n"),
            format!("{p}: triangle 0 on line 5 uses vertex 0, which was already finalized"),
        ),
    ];
    for (body, expected) in cases {
        let msg = sma_error(d, &body);
        assert_eq!(msg, expected);
        assert!(!msg.contains('\n'));
    }
}

#[test]
fn validate_rejects_truncated_and_foreign_smb() {
    let dir = tempfile::tempdir().unwrap();
    let golden = std::fs::read(data("tetrahedron.smb")).unwrap();
    let p = dir.path().join("cut.smb");
    // Cut in the middle of the last triangle: the declared counts no longer fit the size, so
    // neither byte order is plausible; the file is shorter than its counts say: truncated.
    std::fs::write(&p, &golden[..golden.len() - 5]).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert!(
        msg.starts_with(&format!(
            "{}: truncated at byte {} of {}",
            p.display(),
            golden.len() - 5,
            golden.len()
        )),
        "{msg}"
    );
    // Unknown counts: the reader has to find the cut itself.
    let mut unknown = golden.clone();
    unknown[23..31].copy_from_slice(&[0xff; 8]);
    std::fs::write(&p, &unknown[..unknown.len() - 5]).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert_eq!(
        msg,
        format!(
            "{}: file ends at byte 151 in the middle of a triangle (12 bytes)",
            p.display()
        )
    );
    std::fs::write(&p, &unknown[..unknown.len() - 12]).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert_eq!(
        msg,
        format!(
            "{}: at end of stream, vertex 1 was never finalized (2 other vertices neither)",
            p.display()
        )
    );
    // Counts that fit the size but not the stream: 3 vertices and 5 triangles declared.
    let mut wrong = golden.clone();
    wrong[23..31].copy_from_slice(&[3, 0, 0, 0, 5, 0, 0, 0]);
    std::fs::write(&p, &wrong).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert_eq!(
        msg,
        format!(
            "{}: vertex 3 at byte 108 exceeds the 3 vertices the header declares",
            p.display()
        )
    );
    // A vertex with attributes is 20 bytes; a version-1 file cut inside one says so.
    let mut unknown = std::fs::read(data("tetrahedron_attrs.smb")).unwrap();
    unknown[40..48].copy_from_slice(&[0xff; 8]);
    std::fs::write(&p, &unknown[..77 + 30]).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert_eq!(
        msg,
        format!(
            "{}: file ends at byte 107 in the middle of a vertex (20 bytes)",
            p.display()
        )
    );
    // Version 2 is not ours.
    let mut v2 = golden.clone();
    v2[0] = 2;
    std::fs::write(&p, &v2).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert!(
        msg.contains("not an SMB file: first bytes are [02, 00, 00, 00]"),
        "{msg}"
    );
    let p = dir.path().join("magic.smb");
    std::fs::write(&p, b"ply\nformat ascii 1.0\n").unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert!(
        msg.starts_with(&format!(
            "{}: not an SMB file: first bytes are [70, 6c, 79, 0a]",
            p.display()
        )),
        "{msg}"
    );
}

/// A bad index in the first block was reported as a header whose counts do not fit the file
/// (the byte-order check needed the first block to decode); the same fault later in the file was
/// named. Now it is named wherever it is, in either byte order.
#[test]
fn bad_index_in_the_first_block_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let golden = std::fs::read(data("tetrahedron.smb")).unwrap();
    let p = dir.path().join("first.smb");
    let cases: [(i32, &str); 3] = [
        (
            9999,
            "triangle 0 at byte 96 references vertex 9998 (counting from 0) but only 3 vertices precede it",
        ),
        (
            0,
            "byte 96: expected nonzero triangle indices (1-based, or negative relative), found [0, 3, 2]",
        ),
        (
            -99999,
            "triangle 0 at byte 96 uses relative index -99999 but only 3 vertices precede it",
        ),
    ];
    for (index, message) in cases {
        for unknown_counts in [false, true] {
            let mut bytes = golden.clone();
            bytes[96..100].copy_from_slice(&index.to_le_bytes());
            if unknown_counts {
                bytes[23..31].copy_from_slice(&[0xff; 8]);
            }
            std::fs::write(&p, &bytes).unwrap();
            let msg = validate(&p).unwrap_err().to_string();
            assert_eq!(msg, format!("{}: {message}", p.display()));
        }
    }
}

/// A NaN compares false with every coordinate, so a NaN in the header's box held every vertex
/// and the file passed; an infinite bound is as meaningless.
#[test]
fn non_finite_bounding_box_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let golden = std::fs::read(data("tetrahedron.smb")).unwrap();
    let p = dir.path().join("box.smb");
    for (at, x) in [(32, f32::NAN), (52, f32::INFINITY)] {
        let mut bytes = golden.clone();
        bytes[at..at + 4].copy_from_slice(&x.to_le_bytes());
        std::fs::write(&p, &bytes).unwrap();
        let msg = validate(&p).unwrap_err().to_string();
        assert!(
            msg.starts_with(&format!(
                "{}: byte 32: expected a bounding box of six finite numbers, found [",
                p.display()
            )) && msg.contains(&format!("{x:?}")),
            "{msg}"
        );
    }
    let text = std::fs::read_to_string(data("tetrahedron.sma")).unwrap();
    let p = dir.path().join("box.sma");
    std::fs::write(&p, text.replace("bb_min 0e0 0e0 0e0", "bb_min 0e0 NaN 0e0")).unwrap();
    let msg = validate(&p).unwrap_err().to_string();
    assert_eq!(
        msg,
        format!(
            "{}: line 3: expected three finite floats, found 0e0 NaN 0e0",
            p.display()
        )
    );
}

#[test]
fn header_is_checked_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.sma");
    let bad = [
        (vec!["two\nlines".to_string()], vec![]),
        (vec!["nverts 12".to_string()], vec![]),
        (vec![], vec!["has space".to_string()]),
        (vec![], vec!["x".to_string()]),
        (vec![], vec!["t".to_string(), "t".to_string()]),
    ];
    for (comments, attribute_names) in bad {
        let h = Header {
            comments,
            attribute_names,
        };
        let e = StreamWriter::create(&p, &h).err().unwrap().to_string();
        assert!(
            e.starts_with(&format!("{}: ", p.display())) && !e.contains('\n'),
            "{e}"
        );
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn writer_rejects_invalid_calls() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("w.smb");
    let mut w = StreamWriter::create(&p, &Header::default()).unwrap();
    for i in 0..3 {
        w.vertex([i as f32, 0.0, 0.0], &[]).unwrap();
    }
    let e = w.triangle([0, 1, 3], [false; 3]).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: triangle 0 references vertex 3 (counting from 0) but only 3 vertices precede it",
            p.display()
        )
    );
    w.triangle([0, 1, 2], [true, false, false]).unwrap();
    let e = w.triangle([0, 1, 2], [false; 3]).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: triangle 1 uses vertex 0, which was already finalized",
            p.display()
        )
    );
    let e = w.vertex([0.0; 3], &[1.0]).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: vertex 3 has 1 attribute values but the header names 0 attributes",
            p.display()
        )
    );
    let e = w.finalize(1).unwrap_err().to_string();
    assert!(
        e.contains("finalization of vertex 1 cannot be stored in SMB"),
        "{e}"
    );
    let e = w.finish().unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: at end of stream, vertex 1 was never finalized (1 other vertices neither)",
            p.display()
        )
    );
    assert!(!p.exists());
}

// ---------------------------------------------------------------- atomic output

#[test]
fn unfinished_writer_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["a.sma", "a.smb", "a.ply", "a.obj", "a.stl", "a.glb"] {
        let p = dir.path().join(name);
        let mut w =
            isostream_smesh::create_sink(&p, &Header::default(), &ConvertOptions::default())
                .unwrap();
        w.vertex([0.0; 3], &[]).unwrap();
        assert!(!p.exists());
        drop(w);
        assert!(!p.exists());
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn missing_directory_gives_one_line_error_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["a.smb", "a.sma", "a.ply", "a.obj", "a.stl", "a.glb"] {
        let p = dir.path().join("missing").join(name);
        let e = isostream_smesh::create_sink(&p, &Header::default(), &ConvertOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.starts_with(&format!(
                "{}: cannot create a temporary file in ",
                p.display()
            )),
            "{e}"
        );
        assert!(!e.contains('\n'));
    }
}

#[test]
fn empty_mesh_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["e.sma", "e.smb"] {
        let p = dir.path().join(name);
        write(&p, &Header::default(), &[]);
        let r = validate(&p).unwrap();
        assert_eq!((r.vertices, r.triangles, r.header.bbox), (0, 0, None));
        assert_eq!(r.header.nverts, Some(0));
        for out in ["e.ply", "e.obj", "e.stl", "e.glb"] {
            let out = dir.path().join(out);
            convert(&p, &out).unwrap();
            assert_eq!(
                read_indexed(&out).unwrap(),
                IndexedMesh::default(),
                "{}",
                out.display()
            );
        }
    }
}

#[test]
fn stl_and_glb_layouts() {
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("t.stl");
    let stats = convert(&data("tetrahedron.smb"), &stl).unwrap();
    let bytes = std::fs::read(&stl).unwrap();
    assert_eq!(stats.written.bytes, 84 + 4 * 50);
    assert_eq!(bytes.len(), 84 + 4 * 50);
    assert!(!bytes.starts_with(b"solid"));
    assert_eq!(u32::from_le_bytes(bytes[80..84].try_into().unwrap()), 4);
    // First facet (0,2,1) faces -z.
    let f = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!([f(84), f(88), f(92)], [0.0, 0.0, -1.0]);
    assert_eq!(read_indexed(&stl).unwrap().positions.len(), 4);

    let glb = dir.path().join("t.glb");
    let opts = ConvertOptions {
        normals: true,
        ..ConvertOptions::default()
    };
    convert_with(&data("tetrahedron.sma"), &glb, &opts).unwrap();
    let bytes = std::fs::read(&glb).unwrap();
    assert_eq!(&bytes[..4], b"glTF");
    assert_eq!(
        u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
        bytes.len()
    );
    let doc = gltf::Gltf::from_slice(&bytes).unwrap();
    let normals = glb_normals(&glb);
    // Vertex 0 at the origin touches three right triangles of equal area facing -x, -y, -z.
    let s = -(1.0f32 / 3.0).sqrt();
    for (a, b) in normals[0].iter().zip([s, s, s]) {
        assert!((a - b).abs() < 1e-6, "{normals:?}");
    }
    for n in &normals {
        assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-6);
    }
    let comments = doc.document.as_json().asset.extras.as_ref().unwrap().get();
    assert!(comments.contains("tetrahedron"), "{comments}");
}

// ---------------------------------------------------------------- generated streams

/// A random triangle soup over `n` vertices turned into a valid stream: triangles in order,
/// every vertex emitted before its first triangle, some of them early (so the stream is not
/// always compact), and finalized either on its last triangle or, when `explicit`, sometimes by
/// a later `x` element. `choices` drives the random decisions.
fn stream(
    positions: &[[f32; 3]],
    attrs: usize,
    tris: &[[usize; 3]],
    choices: &[u8],
    explicit: bool,
) -> Vec<Op> {
    let mut choice = choices.iter().cycle().copied();
    let n = positions.len();
    let mut last = vec![usize::MAX; n];
    for (t, tri) in tris.iter().enumerate() {
        tri.iter().for_each(|&v| last[v] = t);
    }
    let mut id = vec![u64::MAX; n];
    let mut next = 0u64;
    let mut ops = Vec::new();
    let mut pending_x = Vec::new();
    let mut emit = |v: usize, ops: &mut Vec<Op>, id: &mut Vec<u64>| {
        if id[v] == u64::MAX {
            id[v] = next;
            next += 1;
            let a = (0..attrs).map(|k| (v * 10 + k) as f32 * 0.5).collect();
            ops.push(Op::V(positions[v], a));
        }
    };
    for (t, tri) in tris.iter().enumerate() {
        // Sometimes emit a later triangle's vertex early.
        let early = tris[t..].iter().flatten().find(|&&v| id[v] == u64::MAX);
        if let Some(&v) = early.filter(|_| choice.next().unwrap() % 4 == 0) {
            emit(v, &mut ops, &mut id);
        }
        tri.iter().for_each(|&v| emit(v, &mut ops, &mut id));
        let mut fin = [false; 3];
        for (i, &v) in tri.iter().enumerate() {
            if last[v] == t && !tri[..i].contains(&v) {
                if explicit && choice.next().unwrap() % 3 == 0 {
                    pending_x.push(id[v]);
                } else {
                    fin[i] = true;
                }
            }
        }
        ops.push(Op::T(tri.map(|v| id[v]), fin));
        if choice.next().unwrap() % 2 == 0 {
            ops.extend(pending_x.drain(..).map(Op::X));
        }
    }
    ops.extend(pending_x.drain(..).map(Op::X));
    ops
}

/// Per triangle, its corner positions (and attributes): equal for meshes that differ only in
/// vertex numbering.
fn corners(m: &IndexedMesh) -> Vec<[([f64; 3], Vec<f32>); 3]> {
    let k = m.attribute_names.len();
    m.triangles
        .iter()
        .map(|t| {
            t.map(|v| {
                (
                    m.positions[v as usize],
                    m.attrs[v as usize * k..(v as usize + 1) * k].to_vec(),
                )
            })
        })
        .collect()
}

/// Area-weighted vertex normals of an in-memory mesh, +z where undefined: what the GLB sink
/// computes in a stream.
fn brute_force_normals(m: &IndexedMesh) -> Vec<[f32; 3]> {
    let mut sum = vec![[0f64; 3]; m.positions.len()];
    for t in &m.triangles {
        let p = t.map(|v| m.positions[v as usize]);
        let u = [0, 1, 2].map(|i| p[1][i] - p[0][i]);
        let w = [0, 1, 2].map(|i| p[2][i] - p[0][i]);
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        for &v in t {
            (0..3).for_each(|i| sum[v as usize][i] += n[i]);
        }
    }
    sum.iter()
        .map(|s| {
            let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            if len > 0.0 {
                s.map(|x| (x / len) as f32)
            } else {
                [0.0, 0.0, 1.0]
            }
        })
        .collect()
}

fn glb_normals(path: &Path) -> Vec<[f32; 3]> {
    let doc = gltf::Gltf::open(path).unwrap();
    let blob = doc.blob.as_deref();
    let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
    prim.reader(|_| blob).read_normals().unwrap().collect()
}

fn soup() -> impl Strategy<Value = (Vec<[f32; 3]>, Vec<[usize; 3]>, Vec<u8>)> {
    (3usize..30).prop_flat_map(|n| {
        let pos = proptest::collection::vec(proptest::array::uniform3(-1e4f32..1e4), n);
        let tri = proptest::array::uniform3(0..n).prop_filter("distinct corners", |t| {
            t[0] != t[1] && t[1] != t[2] && t[0] != t[2]
        });
        let tris = proptest::collection::vec(tri, 1..80);
        (pos, tris, proptest::collection::vec(any::<u8>(), 1..64))
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn streams_round_trip_through_sma_and_smb((pos, tris, choices) in soup(), explicit in any::<bool>()) {
        let dir = tempfile::tempdir().unwrap();
        let names = vec!["temperature".to_string(), "grad".to_string()];
        let sma_ops = stream(&pos, 2, &tris, &choices, explicit);
        let sma = dir.path().join("m.sma");
        let header = Header { comments: vec!["generated".into()], attribute_names: names.clone() };
        let stats = write(&sma, &header, &sma_ops);
        prop_assert_eq!(read(&sma), sma_ops.clone());
        let report = validate(&sma).unwrap();
        prop_assert_eq!(report.max_active_vertices, stats.max_active_vertices);
        prop_assert_eq!(&report.header.attribute_names, &names);

        // SMB has no explicit finalization; with and without attributes (versions 1 and 0).
        for attrs in [0, 2] {
            let smb_ops = stream(&pos, attrs, &tris, &choices, false);
            let smb = dir.path().join("m.smb");
            let header = Header { comments: vec![], attribute_names: names[..attrs].to_vec() };
            let stats = write(&smb, &header, &smb_ops);
            prop_assert_eq!(read(&smb), smb_ops);
            let report = validate(&smb).unwrap();
            prop_assert_eq!(report.max_active_vertices, stats.max_active_vertices);
            prop_assert_eq!(&report.header.attribute_names, &header.attribute_names);
        }
    }

    #[test]
    fn conversions_preserve_triangles_and_attributes((pos, tris, choices) in soup()) {
        let dir = tempfile::tempdir().unwrap();
        let names = vec!["a".to_string()];
        let src = dir.path().join("src.sma");
        let header = Header { comments: vec![], attribute_names: names };
        write(&src, &header, &stream(&pos, 1, &tris, &choices, true));
        let original = corners(&read_indexed(&src).unwrap());
        let strip = |c: &Vec<[([f64; 3], Vec<f32>); 3]>| {
            c.iter().map(|t| t.clone().map(|(p, _)| p)).collect::<Vec<_>>()
        };

        // Attributes survive SMA -> PLY (binary and ascii) / GLB -> SMA and SMB, and SMB -> SMA.
        let outputs = [
            ("a.ply", PlyEncoding::BinaryLittleEndian, false),
            ("b.ply", PlyEncoding::Ascii, false),
            ("c.glb", PlyEncoding::default(), false),
            ("d.glb", PlyEncoding::default(), true),
        ];
        for (i, (name, ply_encoding, normals)) in outputs.into_iter().enumerate() {
            let mut ply = dir.path().join(name);
            convert_with(&src, &ply, &ConvertOptions { ply_encoding, normals }).unwrap();
            prop_assert_eq!(&corners(&read_indexed(&ply).unwrap()), &original);
            if normals {
                let expected = brute_force_normals(&read_indexed(&src).unwrap());
                for (a, b) in glb_normals(&ply).iter().zip(&expected) {
                    prop_assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "{:?} vs {:?}", a, b);
                }
            }
            for back in [format!("b{i}.sma"), format!("b{i}.smb"), format!("c{i}.sma")] {
                let back = dir.path().join(back);
                convert(&ply, &back).unwrap();
                validate(&back).unwrap();
                prop_assert_eq!(&corners(&read_indexed(&back).unwrap()), &original);
                ply = back;
            }
        }

        // Positions survive every chain of formats, streaming or not.
        let chain = [
            "c.obj", "d.smb", "e.ply", "f.smb", "g.obj", "h.sma", "i.ply", "j.obj", "k.stl", "l.sma",
            "m.stl", "n.glb", "o.smb", "p.glb", "q.stl", "r.ply", "s.glb", "t.obj", "u.sma",
        ];
        let mut prev = src.clone();
        for name in chain {
            let next = dir.path().join(name);
            convert(&prev, &next).unwrap();
            prop_assert_eq!(strip(&corners(&read_indexed(&next).unwrap())), strip(&original));
            if Format::from_path(&next).unwrap().is_streaming() {
                validate(&next).unwrap();
            }
            prev = next;
        }
    }
}

#[test]
fn sma_attributes_are_declared_or_ignored() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.sma");
    std::fs::write(&p, "v 0 0 0 7\nv 1 0 0 8\nv 0 1 0 9\nf -3 -2 -1\n").unwrap();
    let m = read_indexed(&p).unwrap();
    assert!(m.attribute_names.is_empty() && m.attrs.is_empty());
    std::fs::write(&p, "# vertex_attributes t u\nv 0 0 0 7\n").unwrap();
    let e = validate(&p).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: line 2: expected `v x y z` with 2 attribute values, found v 0 0 0 7",
            p.display()
        )
    );
}

#[test]
fn explicit_finalization_cannot_become_smb() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("x.sma");
    std::fs::write(&src, format!("{TRIANGLE}f 1 2 3\nx 1\nx 2\nx 3\n")).unwrap();
    validate(&src).unwrap();
    let out = dir.path().join("x.smb");
    let e = convert(&src, &out).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: finalization of vertex 0 cannot be stored in SMB, which only finalizes a vertex on its last triangle",
            out.display()
        )
    );
    assert!(!out.exists());
    convert(&src, &dir.path().join("x.ply")).unwrap();
}

#[test]
fn foreign_ply_with_quads_and_doubles_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("quad.ply");
    std::fs::write(
        &p,
        "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 5\nproperty double x\nproperty double y\n\
         property double z\nproperty uchar quality\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
         0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n9 9 9 5\n4 0 1 2 3\n",
    )
    .unwrap();
    let m = read_indexed(&p).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.attribute_names, vec!["quality".to_string()]);
    assert_eq!(m.attrs, vec![1.0, 2.0, 3.0, 4.0, 5.0]);
    let out = dir.path().join("quad.smb");
    let stats = convert(&p, &out).unwrap();
    assert_eq!(stats.dropped_vertices, 1);
    assert_eq!((stats.written.vertices, stats.written.triangles), (4, 2));
}

/// A foreign mesh with a NaN or infinite coordinate is refused with the vertex named, as a
/// streaming one is, by loading and by conversion (which then writes nothing); a negative index
/// and a PLY face of fewer than three vertices are named as such.
#[test]
fn foreign_meshes_with_bad_coordinates_or_faces_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Binary: the ASCII parser refuses `nan` as a number already.
    let ply = |coord: f32, index: i32| {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
                      property float y\nproperty float z\nelement face 1\n\
                      property list uchar int vertex_indices\nend_header\n"
            .to_vec();
        for c in [0.0, 0.0, 0.0, 1.0, coord, 0.0, 0.0, 1.0, 0.0f32] {
            b.extend(c.to_le_bytes());
        }
        b.push(3);
        for i in [0, 1, index] {
            b.extend(i.to_le_bytes());
        }
        b
    };
    let cases = [
        (
            "nan.ply",
            ply(f32::NAN, 2),
            "vertex 1 has a non-finite coordinate (1, NaN, 0); the mesh is corrupt",
        ),
        (
            "inf.ply",
            ply(f32::INFINITY, 2),
            "vertex 1 has a non-finite coordinate (1, inf, 0); the mesh is corrupt",
        ),
        (
            "nan.obj",
            b"v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n".to_vec(),
            "vertex 1 has a non-finite coordinate (1, 0, NaN); the mesh is corrupt",
        ),
        (
            "big.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
              property double z\nelement face 1\nproperty list uchar int vertex_indices\n\
              end_header\n0 0 0\n1e300 0 0\n0 1 0\n3 0 1 2\n"
                .to_vec(),
            "vertex 1 has a coordinate beyond the range of f32 (about ±3.4e38) that meshes are held in (1e300, 0e0, 0e0); rescale the mesh",
        ),
        (
            "neg.ply",
            ply(0.0, -1),
            "face 0 has no list `vertex_indices` of non-negative integers",
        ),
        (
            "two.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
              property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
              end_header\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n"
                .to_vec(),
            "face 0 has 2 vertices; a face needs at least 3",
        ),
    ];
    for (name, text, message) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        let e = read_indexed(&p).unwrap_err().to_string();
        assert_eq!(e, format!("{}: {message}", p.display()));
        let out = dir.path().join("out.smb");
        let e = convert(&p, &out).unwrap_err().to_string();
        assert_eq!(e, format!("{}: {message}", p.display()));
        assert!(!out.exists());
    }
}
