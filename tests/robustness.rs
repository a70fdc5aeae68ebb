//! Issue #13: the binary under hostile conditions, as real child processes. Every failure is one
//! `error:` line, a non-zero exit code, and nothing left behind next to the output.

mod common;

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The error is one line starting with `error:` holding every needle (any of the `|`-separated
/// alternatives).
fn assert_one_line_error(o: &Output, code: i32, needles: &[&str]) {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(code), "stderr: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "stderr: {err}");
    for n in needles {
        assert!(
            n.split('|').any(|alt| lines[0].contains(alt)),
            "{n:?} missing from: {}",
            lines[0]
        );
    }
}

fn write_job(dir: &Path, body: &str) -> String {
    let job = dir.join("job.toml");
    std::fs::write(&job, body).unwrap();
    job.to_string_lossy().into_owned()
}

/// Files in `dir` other than the inputs a test put there.
fn leftovers(dir: &Path, inputs: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "job.toml" && !inputs.contains(&n.as_str()))
        .collect()
}

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_isostream"));
    c.env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    c
}

/// Waits for a child at most `secs`; a hang (the bug this file guards against) fails the test
/// instead of hanging CI.
fn wait_at_most(mut child: Child, secs: u64) -> Output {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let o = child.wait_with_output().unwrap();
            panic!(
                "isostream still running after {secs} s (deadlock?); stderr: {}",
                stderr(&o)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A job big enough to take a few seconds and write megabytes (full-resolution gyroid as SMA).
fn big_job(dir: &Path, output: &str) -> String {
    write_job(
        dir,
        &format!(
            "[input]\nshape = \"gyroid\"\nsize = [160, 160, 160]\n[extract]\niso = 0.0\n[simplify]\nmode = \"none\"\n[output]\npath = \"{output}\"\n[pipeline]\nchannel_capacity = 1\n"
        ),
    )
}

#[cfg(unix)]
fn kill(child: &Child, signal: &str) {
    let ok = Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
}

/// A full disk mid-run (here: a file-size limit, which makes `write` fail with EFBIG like ENOSPC
/// would) used to deadlock every stage: the writer stopped receiving while the simplifier blocked
/// on its full channel. Now the first error stops every stage and is reported.
#[cfg(target_os = "linux")]
#[test]
fn write_error_mid_run_is_reported_not_a_deadlock() {
    use std::os::unix::process::CommandExt;
    let dir = tempfile::tempdir().unwrap();
    let job = big_job(dir.path(), "out.sma");
    let mut cmd = bin();
    cmd.args(["run", &job]);
    // SAFETY (why this test needs unsafe): `pre_exec` runs in the forked child before exec, where
    // only async-signal-safe calls are allowed; setrlimit and signal are. The file-size limit
    // (64 KiB) makes the output's writes fail with EFBIG once SIGXFSZ is ignored (it would
    // otherwise kill the child, which is not what a full disk does).
    #[allow(unsafe_code)]
    unsafe {
        cmd.pre_exec(|| {
            let lim = libc::rlimit {
                rlim_cur: 64 * 1024,
                rlim_max: 64 * 1024,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let o = wait_at_most(cmd.spawn().unwrap(), 60);
    assert_one_line_error(&o, 1, &["out.sma", "File too large|No space left"]);
    assert!(
        leftovers(dir.path(), &[]).is_empty(),
        "{:?}",
        leftovers(dir.path(), &[])
    );
}

/// A long job (seconds) for the signal tests: its temporary output appears early.
fn long_job(dir: &Path) -> String {
    write_job(
        dir,
        "[input]\nshape = \"gyroid\"\nsize = [400, 400, 400]\n[extract]\niso = 0.0\n[simplify]\nrate = 0.1\n[output]\npath = \"big.smb\"\n",
    )
}

/// SIGTERM and SIGHUP stop a run like Ctrl-C: exit 130, one line, no file left behind.
#[cfg(unix)]
#[test]
fn term_and_hup_stop_like_ctrl_c() {
    for signal in ["TERM", "HUP"] {
        let dir = tempfile::tempdir().unwrap();
        let job = long_job(dir.path());
        let child = bin().args(["run", &job]).spawn().unwrap();
        // Wait until the run is writing (its temporary file exists), then signal it.
        let deadline = Instant::now() + Duration::from_secs(30);
        while !leftovers(dir.path(), &[])
            .iter()
            .any(|n| n.ends_with(".tmp"))
        {
            assert!(Instant::now() < deadline, "no temporary output appeared");
            std::thread::sleep(Duration::from_millis(10));
        }
        kill(&child, signal);
        let o = wait_at_most(child, 30);
        assert_one_line_error(&o, 130, &["interrupted"]);
        assert!(
            leftovers(dir.path(), &[]).is_empty(),
            "{signal}: {:?}",
            leftovers(dir.path(), &[])
        );
    }
}

fn small_job(dir: &Path, output: &str) -> String {
    write_job(
        dir,
        &format!(
            "[input]\nshape = \"sphere\"\nsize = [12, 12, 12]\n[extract]\niso = 0.0\n[output]\npath = \"{output}\"\n"
        ),
    )
}

/// Temporary files a killed run left are reported at start, and removed by `--clean-stale`.
#[test]
fn stale_temporary_files_are_reported_then_cleaned() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), "out/m.smb");
    std::fs::create_dir(dir.path().join("out")).unwrap();
    let stale = dir.path().join("out/.m.smb.Ab12cD.tmp");
    std::fs::write(&stale, b"partial").unwrap();
    let o = bin().args(["run", &job]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("stale") && err.contains(".m.smb.Ab12cD.tmp") && err.contains("--clean-stale"),
        "{err}"
    );
    assert!(stale.exists(), "reported only, not removed");
    let o = bin().args(["run", "--clean-stale", &job]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stale.exists());
    let mut left = leftovers(&dir.path().join("out"), &[]);
    left.sort();
    assert_eq!(left, ["m.smb", "m.smb.run.json"]);
}

/// Two jobs on one output: the second is refused while the first holds the output's lock.
#[test]
fn second_job_on_the_same_output_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), "m.smb");
    let lock = isostream_pipeline::lock_output(&dir.path().join("m.smb")).unwrap();
    let o = bin().args(["run", &job]).output().unwrap();
    assert_one_line_error(&o, 1, &["m.smb", "another isostream job"]);
    drop(lock);
    assert!(leftovers(dir.path(), &[]).is_empty());
    let o = bin().args(["run", &job]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let mut left = leftovers(dir.path(), &[]);
    left.sort();
    assert_eq!(left, ["m.smb", "m.smb.run.json"], "no lock file left");
}
