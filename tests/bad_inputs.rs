//! The bad-input corpus (`tests/data/bad/`, issue #13): one data-driven test runs the binary on
//! every entry of `MANIFEST.tsv` and checks the exit code, that the error is one line starting
//! with the expected words, and that nothing is left behind.

use std::path::Path;
use std::process::Command;

const CORPUS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/bad");

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn every_bad_input_ends_in_its_one_line_error() {
    // Work on a copy: runs create (and must remove) files next to their outputs.
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("bad");
    std::fs::create_dir(&dir).unwrap();
    for name in names(Path::new(CORPUS)) {
        std::fs::copy(Path::new(CORPUS).join(&name), dir.join(&name)).unwrap();
    }
    let before = names(&dir);
    let manifest = std::fs::read_to_string(dir.join("MANIFEST.tsv")).unwrap();
    let mut failures = Vec::new();
    let mut count = 0;
    for (n, line) in manifest.lines().enumerate() {
        if line.starts_with('#') || line.trim().is_empty() {
            continue;
        }
        let cols: Vec<&str> = line.split('\t').collect();
        assert_eq!(cols.len(), 4, "MANIFEST.tsv line {}: {line:?}", n + 1);
        let (cmd, args, code, want) = (cols[0], cols[1], cols[2], cols[3]);
        let mut c = Command::new(env!("CARGO_BIN_EXE_isostream"));
        c.arg(cmd).env("RUST_LOG", "warn");
        for a in args.split(' ') {
            c.arg(dir.join(a));
        }
        let o = c.output().unwrap();
        count += 1;
        let err = String::from_utf8_lossy(&o.stderr).replace(&*dir.to_string_lossy(), "DIR");
        let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        let code: i32 = code.parse().unwrap();
        let ok = o.status.code() == Some(code)
            && errors.len() == 1
            && errors[0].starts_with(&format!("error: {want}"));
        if !ok {
            failures.push(format!(
                "line {}: {cmd} {args}: exit {:?} (want {code}), stderr: {err}",
                n + 1,
                o.status.code()
            ));
        }
        let after = names(&dir);
        if after != before {
            failures.push(format!(
                "line {}: {cmd} {args} left {:?}",
                n + 1,
                after
                    .iter()
                    .filter(|a| !before.contains(a))
                    .collect::<Vec<_>>()
            ));
        }
    }
    assert!(count >= 20, "only {count} entries in MANIFEST.tsv");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
