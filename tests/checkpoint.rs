//! Checkpoint and resume (issue 11): a job stopped at any slab and resumed writes the same bytes
//! as a run that went through, in every mode and priority, with attributes, in every format; the
//! bytes do not depend on channel capacities nor on checkpointing; a damaged checkpoint is one
//! line and the output is left alone; `kill -9` of the binary followed by `--resume` gives the
//! same bytes too.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::{assert_one_line_error, isostream, stderr};
use isostream_pipeline::{JobConfig, Pass, Progress, RunError, Start, checkpoint_path, run_from};
use proptest::prelude::*;

const MODES: [&str; 4] = [
    "mode = \"none\"",
    "mode = \"rate\"\nrate = 0.15\nbatch = 2000",
    "mode = \"error\"\nerror = 0.02\nisotropy = 0.3",
    "mode = \"classical\"\nerror = 0.02",
];
const PRIORITIES: [&str; 3] = [
    "priority = \"geometric\"",
    "priority = \"data-dependent\"",
    "priority = \"attribute-quadric\"",
];
const SHAPES: [&str; 3] = ["gyroid", "link", "torus"];
const FORMATS: [&str; 6] = ["smb", "sma", "ply", "obj", "stl", "glb"];

/// A procedural job with a derived attribute (so the reader's look-behind slice is exercised
/// on resume).
fn job_text(shape: &str, n: u64, simplify: &str, output: &str, pipeline: &str) -> String {
    format!(
        "[input]\nshape = \"{shape}\"\nsize = [{n}, {n}, {}]\n\n[extract]\niso = 0.0\n\n[simplify]\n{simplify}\n\n[output]\npath = \"{output}\"\n\n[pipeline]\nbatch_triangles = 300\n{pipeline}\n\n[[attributes]]\nname = \"grad\"\nderive = \"gradient_magnitude\"\n",
        n + 5
    )
}

fn load(dir: &Path, name: &str, text: &str) -> (JobConfig, PathBuf) {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    (JobConfig::load(&path).unwrap(), path)
}

/// Runs in process; `stop_at`: raise the cancel flag once this many slabs are done.
fn run(
    job: &(JobConfig, PathBuf),
    start: Start,
    stop_at: Option<u64>,
) -> Result<isostream_pipeline::RunSummary, RunError> {
    run_until(job, start, |p| stop_at.is_some_and(|s| p.slabs_done >= s))
}

/// Runs in process, raising the cancel flag once `stop` says so. `stop` sees the run's slabs
/// only, not those of a first pass (`[output] faces`, a stage count decided by the largest slab).
fn run_until(
    job: &(JobConfig, PathBuf),
    start: Start,
    stop: impl Fn(&Progress) -> bool + Sync,
) -> Result<isostream_pipeline::RunSummary, RunError> {
    let cancel = AtomicBool::new(false);
    let observer = |p: &Progress| {
        if p.pass == Pass::Run && stop(p) {
            cancel.store(true, Ordering::Relaxed);
        }
    };
    run_from(&job.0, &job.1, start, &cancel, &observer)
}

/// [`run`], and whether it ran a first pass over the volume (its progress events say so).
fn run_seeing_first_pass(
    job: &(JobConfig, PathBuf),
    start: Start,
    stop_at: Option<u64>,
) -> (Result<isostream_pipeline::RunSummary, RunError>, bool) {
    let cancel = AtomicBool::new(false);
    let first = AtomicBool::new(false);
    let observer = |p: &Progress| match p.pass {
        Pass::First => first.store(true, Ordering::Relaxed),
        Pass::Run => {
            if stop_at.is_some_and(|s| p.slabs_done >= s) {
                cancel.store(true, Ordering::Relaxed);
            }
        }
    };
    let result = run_from(&job.0, &job.1, start, &cancel, &observer);
    (result, first.into_inner())
}

/// Leftovers next to the output: temporary files, checkpoints, locks.
fn hidden_files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    names.sort();
    names
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20, ..ProptestConfig::default() })]

    /// Stopped at one or two random slabs (a checkpoint after every slab or every few), resumed,
    /// with random channel capacities and extraction threads: the same bytes as an
    /// uninterrupted run without checkpoints (one thread, default capacities).
    #[test]
    fn a_run_stopped_anywhere_resumes_to_the_same_bytes(
        mode in 0..MODES.len(),
        priority in 0..PRIORITIES.len(),
        shape in 0..SHAPES.len(),
        format in 0..FORMATS.len(),
        n in 16u64..28,
        every in 1u64..4,
        capacity in 1usize..12,
        threads in 1usize..4,
        stops in prop::collection::vec(0.0..1.0f64, 1..3),
    ) {
        let dir = tempfile::tempdir().unwrap();
        // Mode `none` contracts nothing and refuses a priority.
        let simplify = match mode {
            0 => MODES[0].to_string(),
            _ => format!("{}\n{}", MODES[mode], PRIORITIES[priority]),
        };
        let ext = FORMATS[format];
        let reference = load(
            dir.path(),
            "ref.toml",
            &job_text(SHAPES[shape], n, &simplify, &format!("ref.{ext}"), "threads = 1"),
        );
        run(&reference, Start::Fresh, None).unwrap();
        let expected = std::fs::read(dir.path().join(format!("ref.{ext}"))).unwrap();

        let pipeline = format!(
            "channel_capacity = {capacity}\nthreads = {threads}\ncheckpoint = {{ every_slabs = {every} }}"
        );
        let output = format!("out.{ext}");
        let job = load(
            dir.path(),
            "job.toml",
            &job_text(SHAPES[shape], n, &simplify, &output, &pipeline),
        );
        let slabs = n + 4;
        let mut stops: Vec<u64> = stops.iter().map(|f| (f * slabs as f64) as u64).collect();
        stops.sort_unstable();
        let mut start = Start::Fresh;
        for stop in stops {
            match run(&job, start, Some(stop)) {
                // Cancelled before its first checkpoint, interrupted after one, or done before
                // the flag was seen: all fine, the next run takes it from there.
                Err(RunError::Cancelled | RunError::Interrupted { .. }) => {}
                Ok(_) => break,
                Err(e) => panic!("stop at {stop}: {e}"),
            }
            start = Start::Resume;
        }
        let summary = run(&job, Start::Resume, None).unwrap();
        let got = std::fs::read(dir.path().join(&output)).unwrap();
        prop_assert!(
            got == expected,
            "{} vs {} bytes (resumed at {:?})",
            got.len(),
            expected.len(),
            summary.resumed_at_slab
        );
        // Counters cover the whole job, however many runs it took.
        let reference_summary: serde_json::Value = serde_json::from_slice(
            &std::fs::read(dir.path().join(format!("ref.{ext}.run.json"))).unwrap(),
        )
        .unwrap();
        prop_assert_eq!(
            reference_summary["faces_extracted"].as_u64(),
            Some(summary.faces_extracted)
        );
        prop_assert_eq!(
            reference_summary["simplify"]["contractions"].as_u64(),
            Some(summary.simplify.contractions)
        );
        // The checkpoint and every temporary file are gone.
        prop_assert!(!checkpoint_path(&dir.path().join(&output)).exists());
        prop_assert_eq!(hidden_files(dir.path()), Vec::<String>::new());
    }
}

/// Slices too large to decide the stage count by their size: the counting pass decides it, and
/// the checkpoint keeps what it found, so the resumed job does not run it again (it did, over
/// the whole volume, before continuing), has the same two stages and writes the bytes of one
/// that went through.
#[test]
fn a_cascade_decided_by_the_largest_slab_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let text = |out: &str, pipeline: &str| {
        format!(
            "[input]\nshape = \"sphere\"\nsize = [48, 48, 48]\nupsample = [3, 3, 3]\n\n\
             [extract]\niso = 0.0\n\n[simplify]\nrate = 0.05\n\n[output]\npath = \"{out}\"\n\n\
             [pipeline]\nmemory_budget_mib = 20\n{pipeline}\n"
        )
    };
    let reference = load(dir.path(), "ref.toml", &text("ref.smb", ""));
    let summary = run(&reference, Start::Fresh, None).unwrap();
    assert!(summary.simplify_stages.is_some(), "{summary:?}");
    let expected = std::fs::read(dir.path().join("ref.smb")).unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &text("out.smb", "checkpoint = { every_slabs = 10 }"),
    );
    match run_seeing_first_pass(&job, Start::Fresh, Some(70)) {
        (Err(RunError::Cancelled | RunError::Interrupted { .. }), true) => {}
        other => panic!("not stopped after a first pass: {other:?}"),
    }
    let (resumed, counted) = run_seeing_first_pass(&job, Start::Resume, None);
    let resumed = resumed.unwrap();
    assert!(!counted, "the resumed run counted again");
    // Stopped at slab 70 with a checkpoint every 10 slabs: one held back while two are being
    // saved fires later and the interval counts from there, so which one was saved last
    // depends on the threads' timing (53 in one run); it is one of the run's, past the start.
    assert_eq!(
        resumed.resumed_at_slab.map(|z| (1..70).contains(&z)),
        Some(true),
        "{resumed:?}"
    );
    assert!(resumed.simplify_stages.is_some(), "{resumed:?}");
    assert!(std::fs::read(dir.path().join("out.smb")).unwrap() == expected);
}

/// A real volume (when `../shared/data` is present): stopped twice, resumed, same bytes.
/// Two simplifier stages (`simplify_stages = 2`): both stages' states ride the cut, so a run
/// stopped at any of several slabs resumes to the bytes of an uninterrupted one; the output is
/// valid, crossing-free, as close to the rate as one simplifier's, and both stages were busy.
#[test]
fn a_cascade_resumes_to_the_same_bytes_and_uses_both_stages() {
    let dir = tempfile::tempdir().unwrap();
    let simplify = "mode = \"rate\"\nrate = 0.1\nbatch = 2000";
    let reference = load(
        dir.path(),
        "ref.toml",
        &job_text("gyroid", 24, simplify, "ref.smb", "simplify_stages = 2"),
    );
    let summary = run(&reference, Start::Fresh, None).unwrap();
    assert!(summary.stage_seconds.simplify_second > 0.0, "{summary:?}");
    // This small gyroid's topology does not allow its target: as close as one simplifier gets.
    let single = load(
        dir.path(),
        "single.toml",
        &job_text("gyroid", 24, simplify, "single.smb", "simplify_stages = 1"),
    );
    let floor = run(&single, Start::Fresh, None).unwrap().faces_written;
    assert!(
        summary.faces_written <= floor + floor / 20,
        "{summary:?} vs {floor}"
    );
    let mesh = common::Mesh::read(&dir.path().join("ref.smb"));
    assert!(mesh.check().is_valid_manifold(), "{:?}", mesh.check());
    assert_eq!(mesh.self_intersections(), 0);
    let expected = std::fs::read(dir.path().join("ref.smb")).unwrap();
    for stop in [3, 11, 20] {
        let job = load(
            dir.path(),
            &format!("job{stop}.toml"),
            &job_text(
                "gyroid",
                24,
                simplify,
                &format!("out{stop}.smb"),
                "simplify_stages = 2\ncheckpoint = { every_slabs = 2 }",
            ),
        );
        match run(&job, Start::Fresh, Some(stop)) {
            Err(RunError::Cancelled | RunError::Interrupted { .. }) | Ok(_) => {}
            Err(e) => panic!("stop at {stop}: {e}"),
        }
        run(&job, Start::Resume, None).unwrap();
        let got = std::fs::read(dir.path().join(format!("out{stop}.smb"))).unwrap();
        assert!(
            got == expected,
            "stopped at {stop}: {} vs {} bytes",
            got.len(),
            expected.len()
        );
    }
}

#[test]
fn a_real_volume_resumes_to_the_same_bytes() {
    let Some(volume) = common::shared_volume("ironprot/ironProt.vtk") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let text = |output: &str, pipeline: &str| {
        format!(
            "[input]\npath = \"{}\"\n\n[extract]\niso = 86\n\n[simplify]\nmode = \"rate\"\nrate = 0.1\n\n[output]\npath = \"{output}\"\n\n[pipeline]\n{pipeline}\n",
            volume.display()
        )
    };
    let reference = load(dir.path(), "ref.toml", &text("ref.smb", ""));
    run(&reference, Start::Fresh, None).unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &text("out.smb", "checkpoint = { every_slabs = 4 }"),
    );
    // Stopped once past slab 20 with a checkpoint saved (when the writer saves one is up to
    // the machine's timing), then at slab 45 (or whatever the last checkpoint is then).
    let ckpt = checkpoint_path(&dir.path().join("out.smb"));
    let first = run_until(&job, Start::Fresh, |p| p.slabs_done >= 20 && ckpt.exists());
    assert!(
        matches!(first, Err(RunError::Interrupted { .. })),
        "{first:?}"
    );
    let second = run(&job, Start::Resume, Some(45));
    assert!(
        matches!(
            second,
            Err(RunError::Interrupted { .. } | RunError::Cancelled)
        ),
        "{second:?}"
    );
    let summary = run(&job, Start::Resume, None).unwrap();
    assert!(summary.resumed_at_slab.is_some());
    assert!(
        std::fs::read(dir.path().join("out.smb")).unwrap()
            == std::fs::read(dir.path().join("ref.smb")).unwrap()
    );
}

/// Without `--resume` a checkpoint is reported, not overwritten; `--restart` starts over; a
/// changed job or input is refused; a corrupt or truncated checkpoint is one line, and nothing
/// is touched. `validate` passes the job and notes which of the flags `run` needs.
#[test]
fn a_checkpoint_is_never_ignored_nor_trusted_blindly() {
    let dir = tempfile::tempdir().unwrap();
    let text = |iso: &str| {
        job_text(
            "gyroid",
            24,
            "mode = \"rate\"\nrate = 0.2",
            "out.smb",
            "checkpoint = { every_slabs = 2 }",
        )
        .replace("iso = 0.0", iso)
    };
    let job = load(dir.path(), "job.toml", &text("iso = 0.0"));
    let ckpt = checkpoint_path(&dir.path().join("out.smb"));
    let stopped = run_until(&job, Start::Fresh, |p| p.slabs_done >= 12 && ckpt.exists());
    assert!(
        matches!(stopped, Err(RunError::Interrupted { .. })),
        "{stopped:?}"
    );
    let saved = std::fs::read(&ckpt).unwrap();
    let before = hidden_files(dir.path());
    let job_arg = job.1.to_string_lossy().into_owned();

    let o = isostream(&["run", "--quiet", &job_arg]);
    assert_one_line_error(&o, 2, &["found a checkpoint at", "add --resume"]);
    assert_eq!(hidden_files(dir.path()), before);
    let validate_notes = |needles: &[&str]| {
        let o = isostream(&["validate", &job_arg]);
        assert!(o.status.success(), "{}", stderr(&o));
        let out = String::from_utf8_lossy(&o.stdout);
        let note =
            format!("{job_arg}: note: a checkpoint of an interrupted run of this output exists (");
        assert!(
            out.lines()
                .any(|l| l.starts_with(&note) && needles.iter().all(|n| l.contains(n))),
            "{needles:?} in {out}"
        );
        assert_eq!(hidden_files(dir.path()), before, "validate touched files");
    };
    validate_notes(&[
        " %, ",
        ".out.smb.ckpt",
        "`run` needs --resume to continue it",
        "--restart",
    ]);

    // Another iso value is another job.
    load(dir.path(), "job.toml", &text("iso = 0.1"));
    let o = isostream(&["run", "--quiet", "--resume", &job_arg]);
    assert_one_line_error(
        &o,
        2,
        &["the job file changed since the checkpoint", "--restart"],
    );
    validate_notes(&["but the job file changed since the checkpoint: `run` needs --restart"]);
    load(dir.path(), "job.toml", &text("iso = 0.0"));

    // Corrupt (one bit), truncated, of another version, not a checkpoint.
    let mut flipped = saved.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 1;
    let mut old_version = saved.clone();
    old_version[16] = 99;
    for (bytes, needle) in [
        (flipped, "corrupt checkpoint"),
        (saved[..saved.len() / 3].to_vec(), "truncated checkpoint"),
        (old_version, "checkpoint format 99"),
        (b"hello".to_vec(), "not an isostream checkpoint"),
    ] {
        std::fs::write(&ckpt, &bytes).unwrap();
        let o = isostream(&["run", "--quiet", "--resume", &job_arg]);
        assert_one_line_error(&o, 2, &[needle, ".out.smb.ckpt", "--restart"]);
        assert_eq!(hidden_files(dir.path()), before, "{needle}: files touched");
        validate_notes(&["but cannot be resumed (", needle, "`run` needs --restart"]);
        assert_eq!(std::fs::read(&ckpt).unwrap(), bytes, "{needle}");
        assert!(!dir.path().join("out.smb").exists());
    }

    // Its temporary output gone (removed by hand, a tmp cleaner) or cut short: named, with the
    // fix, and exit 2 as any other checkpoint that cannot be resumed (it was 1); `validate`
    // says so too (it said that --resume would continue it).
    std::fs::write(&ckpt, &saved).unwrap();
    let output_tmp = before
        .iter()
        .find(|f| f.starts_with(".out.smb.") && f.ends_with(".tmp") && !f.contains("ckpt"))
        .unwrap_or_else(|| panic!("a temporary output among {before:?}"));
    let kept = std::fs::read(dir.path().join(output_tmp)).unwrap();
    for (bytes, needle) in [
        (None, "No such file"),
        (Some(&kept[..kept.len() / 2]), "fewer than the"),
    ] {
        match bytes {
            None => std::fs::remove_file(dir.path().join(output_tmp)).unwrap(),
            Some(b) => std::fs::write(dir.path().join(output_tmp), b).unwrap(),
        }
        let o = isostream(&["run", "--quiet", "--resume", &job_arg]);
        assert_one_line_error(
            &o,
            2,
            &[
                ".out.smb.ckpt: ",
                "cannot reopen its checkpointed temporary output",
                output_tmp,
                needle,
                "; run with --restart to start over",
            ],
        );
        let o = isostream(&["validate", &job_arg]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success()
                && out.contains("but a file it needs cannot be used (")
                && out.contains(output_tmp)
                && out.contains(needle)
                && out.contains("`run` needs --restart (it starts over)"),
            "{out}"
        );
    }
    std::fs::write(dir.path().join(output_tmp), kept).unwrap();

    // --restart throws the checkpoint and its files away and runs from the beginning.
    std::fs::write(&ckpt, &saved).unwrap();
    let o = isostream(&["run", "--quiet", "--restart", &job_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!ckpt.exists());
    assert_eq!(hidden_files(dir.path()), Vec::<String>::new());
    let o = isostream(&["validate", &job_arg]);
    assert!(o.status.success() && !String::from_utf8_lossy(&o.stdout).contains("note:"));
}

/// Trial bug: `validate` while a run of the job was live said that a checkpoint of an
/// interrupted run was there and that `run` needed --resume. The live run holds the output's
/// lock (here this process does, over a checkpoint): `validate` says that a run is in progress.
#[test]
fn validate_during_a_live_run_says_it_is_in_progress() {
    let dir = tempfile::tempdir().unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &job_text(
            "gyroid",
            24,
            MODES[1],
            "out.smb",
            "checkpoint = { every_slabs = 2 }",
        ),
    );
    let output = dir.path().join("out.smb");
    let ckpt = checkpoint_path(&output);
    let stopped = run_until(&job, Start::Fresh, |p| p.slabs_done >= 8 && ckpt.exists());
    assert!(
        matches!(stopped, Err(RunError::Interrupted { .. })),
        "{stopped:?}"
    );
    let job_arg = job.1.to_string_lossy().into_owned();
    let note = || {
        let o = isostream(&["validate", &job_arg]);
        assert!(o.status.success(), "{}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let live = isostream_pipeline::lock_output(&output).unwrap();
    let out = note();
    assert!(
        out.contains("note: a run of this output is in progress (it holds ")
            && out.contains(".out.smb.lock); `run` is refused until it ends")
            && !out.contains("--resume"),
        "{out}"
    );
    drop(live);
    assert!(note().contains("`run` needs --resume to continue it"));
}

/// `kill -9` of `isostream run` at random moments, then `isostream run --resume` until done:
/// the same bytes as an uninterrupted run.
#[cfg(unix)]
#[test]
fn kill_9_then_resume_gives_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let pipeline = "checkpoint = { every_slabs = 3 }";
    let simplify = "mode = \"rate\"\nrate = 0.1";
    let reference = load(
        dir.path(),
        "ref.toml",
        &job_text("gyroid", 64, simplify, "ref.ply", ""),
    );
    run(&reference, Start::Fresh, None).unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &job_text("gyroid", 64, simplify, "out.ply", pipeline),
    );
    let job_arg = job.1.to_string_lossy().into_owned();
    let ckpt = checkpoint_path(&dir.path().join("out.ply"));
    let mut kills = 0;
    let mut rng = common::Rng(11);
    let output = dir.path().join("out.ply");
    for _ in 0..4 {
        let mut child = Command::new(env!("CARGO_BIN_EXE_isostream"))
            .args(["run", "--quiet", "--resume", &job_arg])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // Kill once a new checkpoint is there, plus a random delay that lands anywhere between
        // two checkpoints (or after the end).
        let seen = std::fs::metadata(&ckpt).and_then(|m| m.modified()).ok();
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(20)
            && std::fs::metadata(&ckpt).and_then(|m| m.modified()).ok() == seen
            && child.try_wait().unwrap().is_none()
        {
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(rng.next_u64() % 150));
        if child.try_wait().unwrap().is_none() {
            child.kill().unwrap();
            kills += 1;
        }
        child.wait().unwrap();
        if output.exists() {
            break;
        }
    }
    assert!(kills > 0, "the job ended before any kill");
    // Killed after the output's rename, the run is not over until a resume finishes it.
    if !output.exists() || ckpt.exists() {
        let o = isostream(&["run", "--quiet", "--resume", &job_arg]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert!(std::fs::read(&output).unwrap() == std::fs::read(dir.path().join("ref.ply")).unwrap());
    assert!(!ckpt.exists());
}

/// The simplification of the strace tests' gyroid jobs.
#[cfg(target_os = "linux")]
const REFERENCE_SIMPLIFY: &str = "mode = \"rate\"\nrate = 0.2";

/// For the tests that inject faults with strace: a folder holding `ref.ply`, an uninterrupted
/// run of the 24^3 gyroid job, and its bytes; `None` (the test skipped, saying so) without
/// strace.
#[cfg(target_os = "linux")]
fn strace_and_a_reference() -> Option<(tempfile::TempDir, Vec<u8>)> {
    if Command::new("strace").arg("-V").output().is_err() {
        println!("skipped: strace is not installed here");
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().canonicalize().unwrap();
    let reference = load(
        &d,
        "ref.toml",
        &job_text("gyroid", 24, REFERENCE_SIMPLIFY, "ref.ply", ""),
    );
    run(&reference, Start::Fresh, None).unwrap();
    let expected = std::fs::read(d.join("ref.ply")).unwrap();
    Some((dir, expected))
}

/// Trial bug: a kill between the output's rename and the checkpoint's removal left a complete
/// output and a checkpoint whose temporary output was gone; `run` and `validate` said to add
/// --resume, which then failed: only --restart, a whole run again, got out of it. Killed (with
/// strace's fault injection; skipped, saying so, without strace) at every step between the
/// output's completion and the end, the run is finished by `--resume` without computing anything
/// again (no slab, no checkpoint), after `run` and `validate` said so.
#[cfg(target_os = "linux")]
#[test]
fn a_kill_after_the_output_is_complete_is_finished_by_resume() {
    let Some((dir, expected)) = strace_and_a_reference() else {
        return;
    };
    let d = dir.path().canonicalize().unwrap();
    let simplify = REFERENCE_SIMPLIFY;
    let output = d.join("out.ply");
    let at = |name: &str| d.join(name).to_string_lossy().into_owned();
    let summary = at("out.ply.run.json");
    let ckpt = at(".out.ply.ckpt");
    // (checkpoints before the end, path strace watches, syscalls, what the kill leaves)
    let kills: [(bool, String, &str, &[&str]); 4] = [
        // No checkpoint before the end: the first fsync of the folder is the record's, right
        // after it took the checkpoint's place and before the output's rename.
        (false, at(""), "fsync", &[".out.ply.ckpt"]),
        // The earlier run's summary removed, after the output's rename.
        (
            true,
            summary.clone(),
            "unlink,unlinkat",
            &[".out.ply.ckpt", "out.ply"],
        ),
        // The summary renamed into place.
        (
            true,
            summary,
            "rename,renameat,renameat2",
            &[".out.ply.ckpt", "out.ply"],
        ),
        // The record removed, the last step (the trial's kill).
        (
            true,
            ckpt,
            "unlink,unlinkat",
            &[".out.ply.ckpt", "out.ply", "out.ply.run.json"],
        ),
    ];
    for (checkpoints, path, calls, left) in kills {
        for f in ["out.ply", "out.ply.run.json"] {
            let _ = std::fs::remove_file(d.join(f));
        }
        let every = if checkpoints { 3 } else { 1000 };
        let job = load(
            &d,
            "job.toml",
            &job_text(
                "gyroid",
                24,
                simplify,
                &output.to_string_lossy(),
                &format!("checkpoint = {{ every_slabs = {every} }}"),
            ),
        );
        let job_arg = job.1.to_string_lossy().into_owned();
        let killed = Command::new("strace")
            .args(["-f", "-qq", "-o", "/dev/null", "-P", &path])
            .args(["-e", &format!("trace={calls}")])
            .args(["-e", &format!("inject={calls}:signal=SIGKILL")])
            .args([env!("CARGO_BIN_EXE_isostream"), "run", "--quiet", &job_arg])
            .output()
            .unwrap();
        let files: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(".out.ply.ckpt") || n.starts_with("out.ply"))
            .filter(|n| !n.ends_with(".tmp"))
            .collect();
        let mut files = files;
        files.sort();
        assert_eq!(
            files,
            left,
            "killed at {calls} of {path}: {}",
            stderr(&killed)
        );

        let o = isostream(&["run", "--quiet", &job_arg]);
        assert_one_line_error(&o, 2, &["stopped before its last steps", "add --resume"]);
        let o = isostream(&["validate", &job_arg]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success()
                && out.contains("100 %: the output was written")
                && out
                    .contains("`run` needs --resume to finish it without computing anything again"),
            "{out}"
        );
        let o = Command::new(env!("CARGO_BIN_EXE_isostream"))
            .args(["run", "--quiet", "--resume", "--clean-stale", &job_arg])
            .env("RUST_LOG", "info")
            .output()
            .unwrap();
        let err = stderr(&o);
        assert!(o.status.success(), "{err}");
        assert!(
            err.contains("had written its output: finishing it")
                && !err.contains("checkpoint saved"),
            "{err}"
        );
        assert!(
            std::fs::read(&output).unwrap() == expected,
            "killed at {calls} of {path}"
        );
        assert!(d.join("out.ply.run.json").exists());
        assert_eq!(
            hidden_files(&d),
            Vec::<String>::new(),
            "killed at {calls} of {path}"
        );
    }
}

/// Review bug: a run whose output's rename failed (not a kill: an error, injected with strace;
/// skipped, saying so, without strace) removed its complete temporary output on the way out
/// but left the record naming it: `run` said `--resume` would finish it, and `--resume` said
/// the output was gone and to `--restart`. The temporary output is now kept before the record
/// is written, so `--resume` finishes the run once the rename can be made.
#[cfg(target_os = "linux")]
#[test]
fn a_failed_rename_of_the_output_is_finished_by_resume() {
    let Some((dir, expected)) = strace_and_a_reference() else {
        return;
    };
    let d = dir.path().canonicalize().unwrap();
    let simplify = REFERENCE_SIMPLIFY;
    let output = d.join("out.ply");
    let job = load(
        &d,
        "job.toml",
        &job_text(
            "gyroid",
            24,
            simplify,
            &output.to_string_lossy(),
            "checkpoint = { every_slabs = 1000 }",
        ),
    );
    let job_arg = job.1.to_string_lossy().into_owned();
    // The output's rename is the run's first `rename` call (the checkpoint record and the
    // summary are put in place with `renameat`).
    let failed = Command::new("strace")
        .args(["-f", "-qq", "-o", "/dev/null", "-e", "trace=rename"])
        .args(["-e", "inject=rename:error=EACCES:when=1"])
        .args([env!("CARGO_BIN_EXE_isostream"), "run", "--quiet", &job_arg])
        .output()
        .unwrap();
    assert_one_line_error(&failed, 1, &["cannot rename the temporary file"]);
    assert!(!output.exists());
    let o = isostream(&["run", "--quiet", &job_arg]);
    assert_one_line_error(&o, 2, &["stopped before its last steps", "add --resume"]);
    let o = isostream(&["run", "--quiet", "--resume", &job_arg]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read(&output).unwrap() == expected);
    assert_eq!(hidden_files(&d), Vec::<String>::new());
}

/// A resumed run's progress says where it started (the checkpoint's slab), so that its rate and
/// ETA count only the slabs it did: the progress lines of a run resumed at slab 320 of 765
/// promised the end in 3 s of 40, and the service's status page in 10 s.
#[test]
fn a_resumed_run_reports_where_it_started() {
    let dir = tempfile::tempdir().unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &job_text(
            "gyroid",
            24,
            MODES[1],
            "out.smb",
            "checkpoint = { every_slabs = 1 }",
        ),
    );
    let starts = std::sync::Mutex::new(Vec::new());
    let stop = |p: &Progress| {
        starts.lock().unwrap().push(p.slabs_at_start);
        p.slabs_done >= 12
    };
    assert!(matches!(
        run_until(&job, Start::Fresh, stop),
        Err(RunError::Interrupted { .. })
    ));
    assert!(starts.lock().unwrap().iter().all(|&s| s == 0));

    let seen = std::sync::Mutex::new(Vec::new());
    run_until(&job, Start::Resume, |p| {
        seen.lock().unwrap().push((p.slabs_at_start, p.slabs_done));
        false
    })
    .unwrap();
    let seen = seen.into_inner().unwrap();
    let at = seen[0].0;
    // The last checkpoint saved before the cancel took effect: a few slabs behind the front.
    assert!((1..=12).contains(&at), "{seen:?}");
    // The run is reported as it begins, nothing done yet, then after each slab.
    assert_eq!(seen[0], (at, at), "{seen:?}");
    assert!(
        seen[1..].iter().all(|&(s, done)| s == at && done > at),
        "{seen:?}"
    );
}

/// The voxels saturated to f32's range (an f64 volume's 1e40, in the iso volume and in an
/// attribute volume) are counted once however many runs the job took: the counts come with the
/// checkpoint, and the slices read again on resume (the checkpoint's carried slice, and the
/// look-behind of a derived gradient) are not counted again.
#[test]
fn saturated_voxels_are_counted_once_across_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let n = 14u64;
    // A rod of 1e40 along z inside a cylinder of positive values.
    let values: Vec<f64> = (0..n * n * n)
        .map(|i| {
            let (x, y) = ((i % n) as f64 - 6.5, (i / n % n) as f64 - 6.5);
            let r = (x * x + y * y).sqrt();
            if r < 2.0 { 1e40 } else { 5.0 - r }
        })
        .collect();
    let core = values.iter().filter(|&&v| v == 1e40).count() as u64;
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.path().join("rod.raw"), bytes).unwrap();
    let raw = format!("path = \"rod.raw\"\ndims = [{n}, {n}, {n}]\ndtype = \"f64\"\n");
    let text = |output: &str, pipeline: &str| {
        format!(
            "[input]\n{raw}\n[extract]\niso = 0.5\n\n[simplify]\nmode = \"none\"\n\n[output]\npath = \"{output}\"\n\n[pipeline]\n{pipeline}\n\n[[attributes]]\nname = \"grad\"\nderive = \"gradient_magnitude\"\n\n[[attributes]]\nname = \"same\"\n{raw}"
        )
    };
    let reference = load(dir.path(), "ref.toml", &text("ref.smb", "threads = 1"));
    let whole = run(&reference, Start::Fresh, None).unwrap();
    assert_eq!(whole.extract.saturated_voxels, core);
    assert_eq!(whole.extract.saturated_attribute_voxels, core);
    let job = load(
        dir.path(),
        "job.toml",
        &text("out.smb", "threads = 2\ncheckpoint = { every_slabs = 1 }"),
    );
    // Stopped only once a checkpoint exists: with two extraction threads the slabs reported
    // run ahead of the checkpoints, and a stop at slab 3 came before the first one in 3 of 8
    // runs (cancelled, nothing to resume).
    let ckpt = checkpoint_path(&dir.path().join("out.smb"));
    let mut start = Start::Fresh;
    for stop in [3, 8] {
        match run_until(&job, start, |p| p.slabs_done >= stop && ckpt.exists()) {
            Err(RunError::Interrupted { .. }) => {}
            other => panic!("stop at {stop}: {other:?}"),
        }
        start = Start::Resume;
    }
    let summary = run(&job, Start::Resume, None).unwrap();
    assert!(summary.resumed_at_slab.is_some_and(|z| z > 0));
    assert_eq!(summary.extract.saturated_voxels, core);
    assert_eq!(summary.extract.saturated_attribute_voxels, core);
    assert_eq!(
        std::fs::read(dir.path().join("out.smb")).unwrap(),
        std::fs::read(dir.path().join("ref.smb")).unwrap()
    );
}

/// `[output] faces` with pruning: the first pass (the count and the census) runs once, and a run
/// resumed from any of a few slabs takes the rate from the checkpoint's count, not from a pass
/// again, and writes the bytes of a run that went through.
#[test]
fn a_job_with_a_face_target_resumes_without_a_first_pass() {
    let dir = tempfile::tempdir().unwrap();
    let text = |output: &str, pipeline: &str| {
        format!(
            "[input]\nshape = \"gyroid\"\nsize = [24, 24, 29]\n\n[extract]\niso = 0.0\n\n\
             [simplify]\nmin_component_faces = 50\n\n[output]\npath = \"{output}\"\nfaces = 800\n\n\
             [pipeline]\n{pipeline}\n"
        )
    };
    let reference = load(dir.path(), "ref.toml", &text("ref.smb", ""));
    let (summary, counted) = run_seeing_first_pass(&reference, Start::Fresh, None);
    assert!(counted);
    let summary = summary.unwrap();
    let expected = std::fs::read(dir.path().join("ref.smb")).unwrap();
    for stop in [5, 17] {
        let output = format!("out{stop}.smb");
        let job = load(
            dir.path(),
            &format!("job{stop}.toml"),
            &text(&output, "checkpoint = { every_slabs = 2 }"),
        );
        let ckpt = checkpoint_path(&dir.path().join(&output));
        let cancel = AtomicBool::new(false);
        let stopped = run_from(&job.0, &job.1, Start::Fresh, &cancel, &|p: &Progress| {
            if p.pass == Pass::Run && p.slabs_done >= stop && ckpt.exists() {
                cancel.store(true, Ordering::Relaxed);
            }
        });
        assert!(
            matches!(stopped, Err(RunError::Interrupted { .. })),
            "stop at {stop}: {stopped:?}"
        );
        let (resumed, counted) = run_seeing_first_pass(&job, Start::Resume, None);
        let resumed = resumed.unwrap();
        assert!(!counted, "stop at {stop}: the resumed run counted again");
        assert!(
            resumed.resumed_at_slab.is_some_and(|z| z > 0),
            "{resumed:?}"
        );
        assert_eq!(resumed.rate, summary.rate);
        assert!(
            std::fs::read(dir.path().join(&output)).unwrap() == expected,
            "stop at {stop}"
        );
    }
}

/// A checkpoint after every slab, with two simplifier stages (the second, the slowest stage,
/// holds the cuts back): at most two checkpoints are being written at a time. The first stage
/// began a temporary file with its state at every cut, and those waiting for the second stage
/// and the writer piled up (13 of 2 MB at once). Two: one saved by the writer while the next is
/// encoded.
#[test]
fn at_most_two_checkpoints_are_being_written_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &job_text(
            "gyroid",
            64,
            MODES[1],
            "out.smb",
            "simplify_stages = 2\nchannel_capacity = 12\ncheckpoint = { every_slabs = 1 }",
        ),
    );
    let temporary = || {
        std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                name.starts_with(".out.smb.ckpt.") && name.ends_with(".tmp")
            })
            .count()
    };
    let ckpt = checkpoint_path(&dir.path().join("out.smb"));
    let most = std::sync::atomic::AtomicUsize::new(0);
    let saved = AtomicBool::new(false);
    let summary = run_until(&job, Start::Fresh, |_| {
        most.fetch_max(temporary(), Ordering::Relaxed);
        saved.fetch_or(ckpt.exists(), Ordering::Relaxed);
        false
    })
    .unwrap();
    assert!(summary.faces_written > 0);
    assert!(saved.into_inner(), "no checkpoint was saved");
    let most = most.into_inner();
    assert!(
        most <= 2,
        "{most} checkpoint files were being written at once"
    );
    assert_eq!(hidden_files(dir.path()), Vec::<String>::new());
}

/// A resume of a changed job is refused before the first pass of `[output] faces` (which ran to
/// its end first): with the cancel flag already raised, the refusal comes, not a cancellation.
#[test]
fn a_changed_job_is_refused_before_the_first_pass() {
    let dir = tempfile::tempdir().unwrap();
    let text = |faces: u32| {
        format!(
            "[input]\nshape = \"gyroid\"\nsize = [24, 24, 29]\n\n[extract]\niso = 0.0\n\n[output]\npath = \"out.smb\"\nfaces = {faces}\n\n[pipeline]\ncheckpoint = {{ every_slabs = 1 }}\n"
        )
    };
    let job = load(dir.path(), "job.toml", &text(800));
    assert!(matches!(
        run_until(&job, Start::Fresh, |p| p.slabs_done >= 12),
        Err(RunError::Interrupted { .. })
    ));
    let changed = load(dir.path(), "job.toml", &text(900));
    let cancel = AtomicBool::new(true);
    let refused = run_from(&changed.0, &changed.1, Start::Resume, &cancel, &|_| {});
    assert!(
        matches!(refused, Err(RunError::ResumeMismatch { .. })),
        "{refused:?}"
    );
}

/// A resumed cascade reports the output its second stage restored from the checkpoint: the
/// first stage reports progress before the second has taken a batch, and from zeroed counters a
/// run resumed at slab 1600 of 2200 said 0 faces written and 800 resident (of 180 k and 72 k)
/// for its first slabs, in its progress lines, its summary's series and the service's events.
#[test]
fn a_resumed_cascade_reports_the_faces_written_before_the_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        &format!(
            "[input]\nshape = \"gyroid\"\nsize = [40, 40, 400]\n\n[extract]\niso = 0.0\n\n\
             [simplify]\n{}\n\n[output]\npath = \"out.smb\"\n\n[pipeline]\n\
             memory_budget_mib = 16\nsimplify_stages = 2\ncheckpoint = {{ every_slabs = 20 }}\n",
            MODES[1]
        ),
    );
    let before = std::sync::Mutex::new(Vec::new());
    let stop = |p: &Progress| {
        before.lock().unwrap().push((p.slabs_done, p.faces_out));
        p.slabs_done >= 300
    };
    assert!(matches!(
        run_until(&job, Start::Fresh, stop),
        Err(RunError::Interrupted { .. })
    ));
    let after = std::sync::Mutex::new(Vec::new());
    run_until(&job, Start::Resume, |p| {
        after
            .lock()
            .unwrap()
            .push((p.slabs_at_start, p.slabs_done, p.faces_out));
        false
    })
    .unwrap();
    let (before, after) = (before.into_inner().unwrap(), after.into_inner().unwrap());
    let at = after[0].0;
    // What the second stage had written when the first reported a slab before the checkpoint's
    // was in the checkpoint: the resumed run reports at least that from its first slab on.
    let written = before
        .iter()
        .filter(|&&(slab, _)| slab < at)
        .map(|&(_, out)| out)
        .max()
        .unwrap();
    assert!(written > 0, "{before:?}");
    assert!(
        after.iter().all(|&(_, _, out)| out >= written),
        "{written} written before slab {at}: {after:?}"
    );
}

/// A run that fails at its end for what a resume would meet again (here an empty surface, found
/// once every slab is read) removes its checkpoint and temporary files: they were left, and the
/// next run refused to start without `--resume`, which failed the same way.
#[test]
fn a_run_failing_for_an_empty_surface_leaves_no_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let job = load(
        dir.path(),
        "job.toml",
        "[input]\nshape = \"pillow\"\nsize = [12, 12, 12]\n\n[extract]\niso = 2\n\n[output]\npath = \"out.stl\"\n\n[pipeline]\ncheckpoint = { every_slabs = 2 }\n",
    );
    for _ in 0..2 {
        let failed = run(&job, Start::Fresh, None);
        assert!(
            matches!(failed, Err(RunError::EmptySurface { .. })),
            "{failed:?}"
        );
        assert_eq!(hidden_files(dir.path()), Vec::<String>::new());
    }
}
