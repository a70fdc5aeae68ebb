//! The mesh readers (SMA, SMB, PLY, OBJ, STL, GLB) and the stream validator on arbitrary bytes.
#![no_main]

use std::io::Write;

use libfuzzer_sys::fuzz_target;

const EXTENSIONS: [&str; 6] = ["sma", "smb", "ply", "obj", "stl", "glb"];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, body)) = data.split_first() else {
        return;
    };
    let ext = EXTENSIONS[pick as usize % EXTENSIONS.len()];
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join(format!("input.{ext}"));
    std::fs::File::create(&path)
        .and_then(|mut f| f.write_all(body))
        .expect("write input");
    if matches!(ext, "sma" | "smb") {
        let _ = isostream_smesh::validate(&path);
    }
    let _ = isostream_smesh::read_indexed(&path);
});
