//! A sink checkpointed mid-stream, "killed" (dropped after writing past the checkpoint) and
//! resumed from the checkpoint writes the same bytes as one that ran through, in every format.

use std::path::Path;

use isostream_smesh::{ConvertOptions, Header, MeshSink, PlyEncoding, create_sink, resume_sink};

/// A strip of `n` triangles in streaming order, with two attributes per vertex.
fn strip(n: u64) -> Vec<Element> {
    let mut out = Vec::new();
    for i in 0..n + 2 {
        let x = (i / 2) as f32;
        let y = (i % 2) as f32;
        out.push(Element::Vertex([x, y, 0.1 * x * x], [x, y]));
        if i >= 2 {
            let t = i - 2;
            // Vertex t is used for the last time by triangle t.
            let v = if t % 2 == 0 {
                [t, t + 1, t + 2]
            } else {
                [t, t + 2, t + 1]
            };
            let last = [true, i == n + 1, i == n + 1];
            out.push(Element::Triangle(v, last));
        }
    }
    out
}

#[derive(Clone, Copy)]
enum Element {
    Vertex([f32; 3], [f32; 2]),
    Triangle([u64; 3], [bool; 3]),
}

fn write(sink: &mut dyn MeshSink, elements: &[Element]) {
    for e in elements {
        match *e {
            Element::Vertex(p, a) => sink.vertex(p, &a).unwrap(),
            Element::Triangle(v, l) => sink.triangle(v, l).unwrap(),
        }
    }
}

fn header() -> Header {
    Header {
        comments: vec!["resume test".into()],
        attribute_names: vec!["a".into(), "b".into()],
    }
}

fn whole(path: &Path, options: &ConvertOptions, elements: &[Element]) -> Vec<u8> {
    let mut sink = create_sink(path, &header(), options).unwrap();
    write(sink.as_mut(), elements);
    sink.finish().unwrap();
    std::fs::read(path).unwrap()
}

fn interrupted(path: &Path, options: &ConvertOptions, elements: &[Element], at: usize) -> Vec<u8> {
    let mut sink = create_sink(path, &header(), options).unwrap();
    write(sink.as_mut(), &elements[..at]);
    let state = sink.checkpoint().unwrap();
    // Work done after the checkpoint is lost with the crash, and cut away on resume.
    write(sink.as_mut(), &elements[at..(at + 7).min(elements.len())]);
    drop(sink);
    for f in state.files() {
        assert!(f.exists(), "{} must survive the crash", f.display());
    }
    let mut sink = resume_sink(path, &header(), options, state.clone()).unwrap();
    write(sink.as_mut(), &elements[at..]);
    sink.finish().unwrap();
    for f in state.files() {
        assert!(
            !f.exists(),
            "{} must be gone once the output is complete",
            f.display()
        );
    }
    std::fs::read(path).unwrap()
}

#[test]
fn every_format_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let elements = strip(90);
    let options = [
        ("m.smb", ConvertOptions::default()),
        ("m.sma", ConvertOptions::default()),
        ("m.ply", ConvertOptions::default()),
        (
            "a.ply",
            ConvertOptions {
                ply_encoding: PlyEncoding::Ascii,
                ..ConvertOptions::default()
            },
        ),
        ("m.obj", ConvertOptions::default()),
        ("m.stl", ConvertOptions::default()),
        ("m.glb", ConvertOptions::default()),
        (
            "n.glb",
            ConvertOptions {
                normals: true,
                ..ConvertOptions::default()
            },
        ),
    ];
    for (name, opts) in options {
        let reference = whole(&dir.path().join(format!("ref-{name}")), &opts, &elements);
        // SMB packs 32 elements per block: cut inside a block, at its edge, and at both ends.
        for at in [0, 1, 17, 32, 33, 100, elements.len()] {
            let path = dir.path().join(format!("{at}-{name}"));
            let bytes = interrupted(&path, &opts, &elements, at);
            assert!(
                bytes == reference,
                "{name} resumed after {at} elements differs"
            );
        }
    }
    // Nothing but the outputs is left in the folder.
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn a_state_of_another_format_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.smb");
    let mut sink = create_sink(&path, &header(), &ConvertOptions::default()).unwrap();
    write(sink.as_mut(), &strip(4)[..5]);
    let state = sink.checkpoint().unwrap();
    drop(sink);
    let err = resume_sink(
        &dir.path().join("m.ply"),
        &header(),
        &ConvertOptions::default(),
        state,
    )
    .err()
    .unwrap();
    assert!(err.to_string().contains("does not fit"), "{err}");
}
