//! Writes a grid surface of about N triangles as a compact stream in every format, validates or
//! reloads it, and prints the rates: `cargo run --release -p isostream-smesh --example smesh_throughput -- 2000000`.

use std::path::Path;
use std::time::Instant;

use isostream_smesh::{ConvertOptions, Header, MeshSink, create_sink, validate};

/// A (w+1) x (h+1) vertex grid streamed row by row: each vertex right before its first triangle,
/// finalized on its last one, so the stream width is about one row.
fn grid(sink: &mut dyn MeshSink, w: u64, h: u64) {
    let id = |x: u64, y: u64| y * (w + 1) + x;
    for x in 0..=w {
        sink.vertex([x as f32, 0.0, 0.0], &[]).unwrap();
    }
    for y in 0..h {
        for x in 0..=w {
            sink.vertex([x as f32, (y + 1) as f32, (x * y % 7) as f32 * 0.1], &[])
                .unwrap();
            if x == 0 {
                continue;
            }
            let (a, b, c, d) = (id(x - 1, y), id(x, y), id(x - 1, y + 1), id(x, y + 1));
            let last_row = y + 1 == h;
            sink.triangle([a, b, c], [true, false, false]).unwrap();
            sink.triangle([b, d, c], [x == w, last_row && x == w, last_row])
                .unwrap();
        }
    }
}

fn main() {
    let n: u64 = std::env::args()
        .nth(1)
        .map_or(1_000_000, |a| a.parse().unwrap());
    let w = 1000u64;
    let h = (n / (2 * w)).max(1);
    let dir = tempfile::tempdir().unwrap();
    for ext in ["smb", "sma", "ply", "obj", "stl", "glb"] {
        let path = dir.path().join(format!("grid.{ext}"));
        let t = Instant::now();
        let mut sink = create_sink(&path, &Header::default(), &ConvertOptions::default()).unwrap();
        grid(sink.as_mut(), w, h);
        let stats = sink.finish().unwrap();
        let write = t.elapsed().as_secs_f64();
        let t = Instant::now();
        check(&path);
        let read = t.elapsed().as_secs_f64();
        println!(
            "{ext}: {} triangles, {:.1} MB, width {}; write {:.2} M tri/s, read {:.2} M tri/s",
            stats.triangles,
            stats.bytes as f64 / 1e6,
            stats.max_active_vertices,
            stats.triangles as f64 / write / 1e6,
            stats.triangles as f64 / read / 1e6,
        );
    }
}

fn check(path: &Path) {
    if path.extension().is_some_and(|e| e == "smb" || e == "sma") {
        validate(path).unwrap();
    } else {
        isostream_smesh::read_indexed(path).unwrap();
    }
}
