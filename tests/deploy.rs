//! The deployment files: `deploy/isostream.service` must pass `systemd-analyze verify` with no
//! warning about it (skipped, saying why, where systemd is not installed), and both it and the
//! Containerfile must start the service the way `isostream serve` expects.

use std::path::Path;
use std::process::Command;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

#[test]
fn systemd_unit_verifies() {
    let unit = std::fs::read_to_string(Path::new(ROOT).join("deploy/isostream.service")).unwrap();
    assert!(unit.contains("StateDirectory=isostream") && unit.contains("Restart=on-failure"));
    if Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        println!("skipped: systemd-analyze is not installed here");
        return;
    }
    // verify also checks that ExecStart's binary exists: point it at the one just built.
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("isostream.service");
    std::fs::write(
        &copy,
        unit.replace("/usr/local/bin/isostream", env!("CARGO_BIN_EXE_isostream")),
    )
    .unwrap();
    let o = Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .arg(&copy)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    // systemd-analyze exits 0 on unknown keys and bad values; its warnings name the file.
    let about_us: Vec<&str> = err.lines().filter(|l| l.contains("isostream")).collect();
    assert!(o.status.success() && about_us.is_empty(), "{err}");
}

/// The unit's `Documentation=` files are put there by deploy/README.md's install steps, from
/// files of the repository: it named /usr/share/doc/isostream/service.md, which no step
/// installed.
#[test]
fn the_units_documentation_is_installed_by_the_steps() {
    let unit = std::fs::read_to_string(Path::new(ROOT).join("deploy/isostream.service")).unwrap();
    let steps = std::fs::read_to_string(Path::new(ROOT).join("deploy/README.md")).unwrap();
    let docs: Vec<&str> = unit
        .lines()
        .filter_map(|l| l.strip_prefix("Documentation="))
        .flat_map(str::split_whitespace)
        .filter_map(|uri| uri.strip_prefix("file://"))
        .collect();
    assert!(!docs.is_empty(), "{unit}");
    for doc in docs {
        let install = steps
            .lines()
            .find(|l| l.trim_start().starts_with("sudo install") && l.contains(doc))
            .unwrap_or_else(|| panic!("no install step puts {doc} in place"));
        let command = install.split('#').next().unwrap_or_default();
        let source = command.split_whitespace().rev().nth(1).unwrap();
        assert!(Path::new(ROOT).join(source).is_file(), "{install}");
    }
}

#[test]
fn containerfile_serves_with_a_token() {
    let text = std::fs::read_to_string(Path::new(ROOT).join("deploy/Containerfile")).unwrap();
    // Listening on every interface is refused without a token (see `isostream serve`).
    assert!(
        text.contains("\"0.0.0.0:8440\"") && text.contains("--token-file"),
        "{text}"
    );
    assert!(text.contains("USER isostream"), "{text}");
}
