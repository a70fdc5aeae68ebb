//! Repository rules, enforced as ordinary tests (rust-analyzer's "tidy" idea): the architecture
//! invariants of ARCHITECTURE.md that the compiler does not check.

use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// Crates that must stay pure: no I/O, no threads, no async runtime.
const ALGORITHM_CRATES: [&str; 5] = ["extract", "detect", "prune", "simplify", "meshcheck"];

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let p = entry.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    out
}

fn manifest_dependencies(krate: &str) -> String {
    let text = std::fs::read_to_string(
        Path::new(ROOT)
            .join("crates")
            .join(krate)
            .join("Cargo.toml"),
    )
    .unwrap();
    // Only [dependencies], not dev-dependencies.
    let start = text.find("[dependencies]").map_or(text.len(), |i| i);
    let rest = &text[start..];
    let end = rest[1..].find("\n[").map_or(rest.len(), |i| i + 1);
    rest[..end].to_string()
}

#[test]
fn algorithm_crates_do_no_io_threads_or_async() {
    for krate in ALGORITHM_CRATES {
        let deps = manifest_dependencies(krate);
        for forbidden in ["tokio", "crossbeam", "memmap2", "tracing", "rayon"] {
            assert!(
                !deps.contains(forbidden),
                "crates/{krate} depends on {forbidden}"
            );
        }
        for file in rust_files(&Path::new(ROOT).join("crates").join(krate).join("src")) {
            let text = std::fs::read_to_string(&file).unwrap();
            for forbidden in [
                "std::thread",
                "std::fs",
                "File::open",
                "File::create",
                "tokio::",
            ] {
                assert!(
                    !text.contains(forbidden),
                    "{} uses {forbidden}",
                    file.display()
                );
            }
        }
    }
}

#[test]
fn only_the_pipeline_spawns_threads() {
    for entry in std::fs::read_dir(Path::new(ROOT).join("crates")).unwrap() {
        let krate = entry.unwrap().path();
        if krate.ends_with("pipeline") {
            continue;
        }
        for file in rust_files(&krate.join("src")) {
            let text = std::fs::read_to_string(&file).unwrap();
            assert!(
                !text.contains("thread::spawn") && !text.contains("thread::scope"),
                "{} spawns threads",
                file.display()
            );
        }
    }
}

#[test]
fn every_library_denies_unsafe_code() {
    for entry in std::fs::read_dir(Path::new(ROOT).join("crates")).unwrap() {
        let lib = entry.unwrap().path().join("src/lib.rs");
        let text = std::fs::read_to_string(&lib).unwrap();
        assert!(
            text.contains("#![deny(unsafe_code)]"),
            "{} lacks #![deny(unsafe_code)]",
            lib.display()
        );
    }
}

#[test]
fn every_job_key_is_documented() {
    let config =
        std::fs::read_to_string(Path::new(ROOT).join("crates/pipeline/src/config.rs")).unwrap();
    let readme = std::fs::read_to_string(Path::new(ROOT).join("config/README.md")).unwrap();
    let mut in_struct = false;
    for line in config.lines() {
        let t = line.trim();
        if t.starts_with("pub struct ") && t.ends_with("Config {") {
            in_struct = true;
            continue;
        }
        if in_struct && t == "}" {
            in_struct = false;
        }
        let field = t.strip_prefix("pub ").and_then(|f| f.split(':').next());
        if let (true, Some(field)) = (in_struct, field) {
            let key = format!("`{field}`");
            let section = matches!(
                field,
                "input" | "extract" | "simplify" | "output" | "pipeline" | "log" | "attributes"
            );
            assert!(
                section || readme.contains(&key),
                "job key {field} is not documented in config/README.md"
            );
        }
    }
}

#[test]
fn only_the_service_has_an_async_runtime_or_a_network() {
    for entry in std::fs::read_dir(Path::new(ROOT).join("crates")).unwrap() {
        let krate = entry.unwrap().path();
        let name = krate.file_name().unwrap().to_string_lossy().into_owned();
        if name == "service" {
            continue;
        }
        let deps = manifest_dependencies(&name);
        for forbidden in ["tokio", "axum", "hyper"] {
            assert!(
                !deps.contains(forbidden),
                "crates/{name} depends on {forbidden}"
            );
        }
    }
}
