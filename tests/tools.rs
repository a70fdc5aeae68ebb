//! The Python tools' promises: `tools/open3d_open.py` says why it fails. The Rust suite does not
//! need the tools' packages: what needs Open3D is `#[ignore]`d, and run with `cargo test --test
//! tools -- --ignored` after `pip install -r tools/requirements.txt`.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::{isostream, stderr};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// Whether `python3` runs and imports `module`.
fn python_with(module: &str) -> bool {
    Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn open3d_open(args: &[&str]) -> Output {
    Command::new("python3")
        .arg(Path::new(ROOT).join("tools/open3d_open.py"))
        .args(args)
        .output()
        .unwrap()
}

/// The JSON lines of the tool's answer.
fn lines(o: &Output) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// A small closed mesh written by a run, as SMB.
fn torus(dir: &Path) -> String {
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        "[input]\nshape = \"torus\"\nsize = [24, 24, 24]\n[extract]\niso = 0.0\n[output]\npath = \"t.smb\"\n",
    )
    .unwrap();
    let o = isostream(&["run", &job.to_string_lossy()]);
    assert!(o.status.success(), "{}", stderr(&o));
    dir.join("t.smb").to_string_lossy().into_owned()
}

/// Given an SMB, Open3D only warned of an unknown extension and the tool printed `vertices 0`:
/// it now says to convert the file first, and how.
#[test]
fn open3d_open_says_to_convert_smb_first() {
    if !python_with("json") {
        println!("skipped: python3 is not installed here");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let smb = torus(dir.path());
    let o = open3d_open(&[&smb]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let error = lines(&o)[0]["error"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    let ply = smb.replace(".smb", ".ply");
    assert!(
        error.contains(&format!("isostream convert {smb} {ply}")),
        "{error}"
    );
}

/// A triangle count other than `--expect-faces` exited 1 without a word; the line says so now.
/// The docstring promised per-vertex colours and attributes it never printed: it prints what
/// Open3D reads (normals, colours).
#[test]
#[ignore = "needs Open3D: pip install -r tools/requirements.txt, then cargo test --test tools -- --ignored"]
fn open3d_open_says_why_a_count_fails() {
    assert!(
        python_with("open3d"),
        "Open3D is not installed here: pip install -r tools/requirements.txt"
    );
    let dir = tempfile::tempdir().unwrap();
    let smb = torus(dir.path());
    let ply = dir.path().join("t.ply").to_string_lossy().into_owned();
    let o = isostream(&["convert", &smb, &ply]);
    assert!(o.status.success(), "{}", stderr(&o));

    let o = open3d_open(&[&ply]);
    assert!(o.status.success(), "{}", stderr(&o));
    let seen = &lines(&o)[0];
    let triangles = seen["triangles"].as_u64().unwrap();
    assert!(triangles > 0 && seen.get("error").is_none(), "{seen}");
    assert!(
        seen["vertex_normals"].is_boolean() && seen["vertex_colors"].is_boolean(),
        "{seen}"
    );

    let o = open3d_open(&[&ply, "--expect-faces", "5"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(
        lines(&o)[0]["error"],
        format!("{triangles} triangles, --expect-faces 5"),
    );
}

/// `tools/fuzz.sh` with `PATH` holding only a `cargo` that records being called: what it was
/// asked to do before anything ran.
#[cfg(unix)]
fn fuzz_sh(args: &[&str]) -> (Output, bool) {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let called = dir.path().join("cargo-called");
    let cargo = dir.path().join("cargo");
    std::fs::write(
        &cargo,
        format!("#!/bin/sh\necho \"$@\" >> '{}'\nexit 1\n", called.display()),
    )
    .unwrap();
    std::fs::set_permissions(&cargo, std::fs::Permissions::from_mode(0o755)).unwrap();
    let path = format!("{}:/usr/bin:/bin", dir.path().display());
    let o = Command::new("bash")
        .arg(Path::new(ROOT).join("tools/fuzz.sh"))
        .args(args)
        .env("PATH", path)
        .output()
        .unwrap();
    (o, called.exists())
}

/// `tools/fuzz.sh --help` ran `cargo install cargo-fuzz` and then handed `--help` to libFuzzer
/// as the seconds: it prints its usage and exits 0 before anything runs, and a seconds argument
/// that is not a whole number is a one-line usage error (exit 2), also before anything runs.
#[cfg(unix)]
#[test]
fn fuzz_sh_help_and_bad_seconds_run_nothing() {
    for help in ["--help", "-h"] {
        let (o, cargo) = fuzz_sh(&[help]);
        assert_eq!(o.status.code(), Some(0), "{help}: {}", stderr(&o));
        assert!(
            String::from_utf8_lossy(&o.stdout).starts_with("usage: tools/fuzz.sh"),
            "{help}: {}",
            String::from_utf8_lossy(&o.stdout)
        );
        assert!(!cargo, "{help} ran cargo");
    }
    for bad in ["abc", "10s", "0", "-5", ""] {
        let (o, cargo) = fuzz_sh(&[bad]);
        assert_eq!(o.status.code(), Some(2), "{bad:?}: {}", stderr(&o));
        let err = stderr(&o);
        assert_eq!(err.trim_end().lines().count(), 1, "{bad:?}: {err}");
        assert!(err.contains("usage: tools/fuzz.sh"), "{bad:?}: {err}");
        assert!(!cargo, "{bad:?} ran cargo");
    }
    // A good number goes on to cargo (here the recording one, which fails).
    let (o, cargo) = fuzz_sh(&["5"]);
    assert_ne!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(cargo, "5 s did not reach cargo: {}", stderr(&o));
}

/// `tools/tandem_experiment.py --quick`, the smoke run tools/README.md suggests, rewrote the
/// committed docs/tandem.md: it writes to its work folder unless `--doc` is given.
#[test]
fn tandem_quick_leaves_docs_tandem_md_alone() {
    if !python_with("argparse") {
        println!("skipped: python3 is not installed here");
        return;
    }
    let doc_of = |args: &[&str]| -> String {
        let script = format!(
            "import sys; sys.path.insert(0, {tools:?}); import tandem_experiment as t; \
             print(t.parse_args({args:?}).doc)",
            tools = Path::new(ROOT).join("tools").to_string_lossy(),
        );
        let o = Command::new("python3")
            .args(["-c", &script])
            .output()
            .unwrap();
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    };
    let committed = Path::new(ROOT).join("docs/tandem.md");
    assert_eq!(doc_of(&[]), committed.to_string_lossy());
    assert_eq!(
        doc_of(&["--quick", "--work", "/tmp/w"]),
        "/tmp/w/tandem-quick.md"
    );
    assert!(
        doc_of(&["--quick"]).ends_with("out/tandem-experiment/tandem-quick.md"),
        "{}",
        doc_of(&["--quick"])
    );
    assert_eq!(
        doc_of(&["--quick", "--doc", "docs/tandem.md"]),
        "docs/tandem.md"
    );
}
