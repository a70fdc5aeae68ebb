//! `isostream report` end to end: a real run (with JSON progress lines), its measure report, the
//! HTML page and the SVG series in it; bad files give one line and no page.

mod common;

use std::path::Path;
use std::process::Command;

use common::{assert_one_line_error, isostream, stderr};
use serde_json::Value;

const JOB: &str = "[input]\nshape = \"gyroid\"\nsize = [40, 40, 40]\n[extract]\niso = 0.0\n[simplify]\nrate = 0.2\n[output]\npath = \"gyroid.smb\"\n[log]\nformat = \"json\"\nprogress_seconds = 0.000001\n";

/// The `<figure id=...>` element of the page, up to its end.
fn figure<'a>(page: &'a str, id: &str) -> &'a str {
    let start = page
        .find(&format!("<figure id=\"{id}\">"))
        .unwrap_or_else(|| panic!("no figure {id}"));
    let len = page[start..].find("</figure>").unwrap();
    &page[start..start + len]
}

/// Points of every `<polyline>` of an SVG.
fn polyline_lengths(svg: &str) -> Vec<usize> {
    svg.split("<polyline")
        .skip(1)
        .map(|p| {
            let attr = p.split("points=\"").nth(1).unwrap();
            attr[..attr.find('"').unwrap()].split_whitespace().count()
        })
        .collect()
}

fn texts(svg: &str) -> Vec<&str> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| Some(t[t.find('>')? + 1..t.find("</text>")?].trim()))
        .collect()
}

/// Runs `text` as a job in `dir` (it must succeed): its stderr and the JSON objects of its log.
fn run_logged(dir: &Path, text: &str) -> (String, Vec<Value>) {
    let job = dir.join("job.toml");
    std::fs::write(&job, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_isostream"))
        .args(["run", "--quiet"])
        .arg(&job)
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let log = stderr(&o);
    let lines = log
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .collect();
    (log, lines)
}

/// The fields of the one `job done` line of `lines` (`log` for the message).
fn job_done(log: &str, lines: &[Value]) -> Value {
    let done: Vec<&Value> = lines
        .iter()
        .filter(|v| v["fields"]["message"] == "job done")
        .collect();
    assert_eq!(done.len(), 1, "{log}");
    done[0]["fields"].clone()
}

fn run(dir: &Path) -> Value {
    let (log, lines) = run_logged(dir, JOB);
    // The periodic progress line: one JSON object with the rate and the ETA.
    let progress: Vec<&Value> = lines
        .iter()
        .filter(|v| v["fields"]["message"] == "progress" && v["fields"]["eta_s"].is_number())
        .collect();
    assert!(!progress.is_empty(), "{log}");
    // The stage's span names the stage under its own key: a field `name` beside the span's
    // name gave `"span":{"name":"simplify","name":"stage"}`, a duplicate key.
    assert_eq!(progress[0]["span"]["name"], "stage", "{}", progress[0]);
    let stage = progress[0]["span"]["stage"].as_str().unwrap_or_default();
    assert!(stage.starts_with("simplify"), "{}", progress[0]);
    assert!(!log.contains(r#""name":"simplify"#), "{log}");
    // The run's last line: numbers as JSON numbers, not strings ("seconds":"6.443").
    let done = job_done(&log, &lines);
    for key in [
        "seconds",
        "read_s",
        "extract_s",
        "detect_s",
        "simplify_s",
        "simplify_second_s",
        "write_s",
        "peak_rss_mib",
        "faces_written",
    ] {
        assert!(done[key].is_number(), "{key}: {done}");
    }
    // The job does not prune: no prune stage, no seconds of it.
    assert!(done.get("prune_s").is_none(), "{done}");
    for key in [
        "voxels_per_s",
        "percent",
        "resident_faces",
        "rss_mib",
        "slab",
    ] {
        assert!(
            progress[0]["fields"][key].is_number(),
            "{key}: {}",
            progress[0]
        );
    }
    let summary = std::fs::read_to_string(dir.join("gyroid.smb.run.json")).unwrap();
    let summary: Value = serde_json::from_str(&summary).unwrap();
    // The second simplifier's seconds, as the summary has them (it was left out of the line).
    let second = summary["stage_seconds"]["simplify_second"]
        .as_f64()
        .unwrap();
    assert!(second > 0.0, "the job runs a cascade: {summary}");
    let logged = done["simplify_second_s"].as_f64().unwrap();
    assert!((logged - second).abs() <= 5e-4, "{logged} vs {second}");
    summary
}

/// A job that prunes (`[simplify] min_component_faces`) logs its prune stage's seconds in `job
/// done` as the summary has them: the line had every other stage's but that one.
#[test]
fn job_done_logs_the_prune_stage_s_seconds() {
    let dir = tempfile::tempdir().unwrap();
    let (log, lines) = run_logged(
        dir.path(),
        &JOB.replace("rate = 0.2\n", "rate = 0.2\nmin_component_faces = 10\n"),
    );
    let done = job_done(&log, &lines);
    let summary: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("gyroid.smb.run.json")).unwrap())
            .unwrap();
    let seconds = summary["stage_seconds"]["prune"].as_f64().unwrap();
    let logged = done["prune_s"].as_f64();
    assert!(
        logged.is_some_and(|l| (l - seconds).abs() <= 5e-4),
        "{logged:?} vs {seconds}: {done}"
    );
}

/// A one-stage job logs no second simplifier's seconds in `job done` (a `0.0` read as a stage
/// that ran, in a user trial).
#[test]
fn a_one_stage_job_logs_no_second_stage_seconds() {
    let dir = tempfile::tempdir().unwrap();
    let (log, lines) = run_logged(
        dir.path(),
        &format!("{JOB}[pipeline]\nsimplify_stages = 1\n"),
    );
    let done = job_done(&log, &lines);
    assert!(done["simplify_s"].is_number(), "{done}");
    assert!(done.get("simplify_second_s").is_none(), "{done}");
}

/// A job with a first pass (`[output] faces`) reports its slabs too, in lines that say which
/// pass they are of; every clock counts from the job's start. The pass logged nothing before
/// (20 s and more at `upsample` 16), and the run's first line and series started after it
/// while `job done` counted it.
#[test]
fn a_first_pass_logs_its_progress_and_every_clock_counts_from_the_start() {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.toml");
    let text = JOB
        .replace("rate = 0.2\n", "")
        .replace("[log]", "faces = 5000\n[log]");
    std::fs::write(&job, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_isostream"))
        .args(["run", "--quiet"])
        .arg(&job)
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let lines: Vec<Value> = stderr(&o)
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .map(|v| v["fields"].clone())
        .collect();
    let progress = |pass: &str| -> Vec<&Value> {
        lines
            .iter()
            .filter(|f| f["message"] == "progress" && f["pass"] == pass)
            .collect()
    };
    let (first, run) = (progress("first"), progress("run"));
    // Every slab of the first pass (a line at most every microsecond), without faces: the pass
    // counts them at its end.
    let slabs: Vec<u64> = first.iter().map(|f| f["slab"].as_u64().unwrap()).collect();
    assert_eq!(slabs, (1..=39).collect::<Vec<_>>(), "{}", stderr(&o));
    assert!(
        first
            .iter()
            .all(|f| f.get("faces_in").is_none() && f["eta_s"].is_number())
    );
    assert!(!run.is_empty() && run.iter().all(|f| f["faces_in"].is_number()));
    let at = |f: &Value, key: &str| f[key].as_f64().unwrap();
    let (first_end, run_start) = (first.last().unwrap(), run[0]);
    assert!(at(run_start, "elapsed_s") >= at(first_end, "elapsed_s"));
    assert!(at(first_end, "percent") == 100.0 && at(run_start, "percent") < 100.0);
    let pass_seconds = lines
        .iter()
        .find(|f| {
            f["message"]
                .as_str()
                .unwrap_or("")
                .starts_with("first pass")
        })
        .map(|f| at(f, "seconds"))
        .unwrap();
    let summary: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("gyroid.smb.run.json")).unwrap())
            .unwrap();
    let series = summary["series"]["points"].as_array().unwrap();
    // The run's series only, from slab 1; its clock the job's, as the summary's seconds.
    assert_eq!(series[0]["slab"], 1);
    assert!(at(&series[0], "seconds") >= pass_seconds, "{pass_seconds}");
    assert!(at(series.last().unwrap(), "seconds") <= at(&summary, "seconds"));
}

/// `isostream report RUN -o OUT`.
fn report(run: &Path, out: &Path) -> std::process::Output {
    isostream(&[
        "report",
        &run.to_string_lossy(),
        "-o",
        &out.to_string_lossy(),
    ])
}

#[test]
fn a_run_and_its_measure_make_one_page_of_plots() {
    let dir = tempfile::tempdir().unwrap();
    let summary = run(dir.path());
    let points = summary["series"]["points"].as_array().unwrap();
    assert_eq!(summary["series"]["stride"], 1);
    // Slabs 1..=39 each once (a gyroid has triangles in every slab), the last one the totals.
    assert_eq!(points.len(), 39, "{}", summary["series"]);
    let last = points.last().unwrap();
    assert_eq!(last["faces_in"], summary["faces_extracted"]);
    assert_eq!(last["faces_out"], summary["faces_written"]);
    assert_eq!(last["voxels_done"], summary["voxels"]);
    assert!(points.iter().all(|p| p["rss_bytes"].as_u64().unwrap() > 0));
    // The peak is at least every sample: the kernel's high-water mark alone lags (a summary said
    // 42,266,624 bytes under a series reaching 42,348,544).
    let rss_peak = summary["peak_rss_bytes"].as_u64().unwrap();
    assert!(
        points
            .iter()
            .all(|p| p["rss_bytes"].as_u64().unwrap() <= rss_peak),
        "{rss_peak} {}",
        summary["series"]
    );
    // Taken at the end of each slab: at most the peak, which can fall inside a slab.
    let peak = points
        .iter()
        .map(|p| p["resident_faces"].as_u64().unwrap())
        .max();
    let in_run = summary["peak_resident_faces"].as_u64().unwrap();
    assert!(
        peak.unwrap() > 0 && peak.unwrap() <= in_run,
        "{peak:?} {in_run}"
    );

    let measure = dir.path().join("measure.json");
    let o = isostream(&[
        "measure",
        "--json",
        "--volume",
        &dir.path().join("job.toml").to_string_lossy(),
        &dir.path().join("gyroid.smb").to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::write(&measure, &o.stdout).unwrap();

    let page_path = dir.path().join("report.html");
    let o = isostream(&[
        "report",
        &dir.path().join("gyroid.smb.run.json").to_string_lossy(),
        "-o",
        &page_path.to_string_lossy(),
        "--measure",
        &measure.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let page = std::fs::read_to_string(&page_path).unwrap();
    assert!(page.starts_with("<!doctype html>"));

    // Memory: RSS and resident faces, one point per slab each.
    let memory = figure(&page, "memory");
    let labels = texts(memory);
    assert!(labels.contains(&"RSS (MiB)") && labels.contains(&"resident faces"));
    let lines = polyline_lengths(memory);
    assert_eq!(
        lines.iter().filter(|&&n| n == points.len()).count(),
        2,
        "{lines:?}"
    );
    // Faces: in, out, resident.
    let faces = figure(&page, "faces");
    for label in ["faces in per slab", "faces out per slab", "resident faces"] {
        assert!(texts(faces).contains(&label), "{label}");
    }
    assert_eq!(
        polyline_lengths(faces)
            .iter()
            .filter(|&&n| n == points.len())
            .count(),
        3
    );
    let stages = texts(figure(&page, "stages"));
    for stage in ["read", "extract", "detect", "simplify", "write"] {
        assert!(stages.contains(&stage), "{stage}: {stages:?}");
    }
    // Histograms: one bar per bin of the measure report (plus the background rectangle).
    let m: Value = serde_json::from_slice(&std::fs::read(&measure).unwrap()).unwrap();
    let angle_bins = m["quality"]["min_angle_histogram"]
        .as_array()
        .unwrap()
        .len();
    assert_eq!(
        figure(&page, "min-angles").matches("<rect").count(),
        1 + angle_bins
    );
    for (id, key) in [
        ("distances-full-to-output", "full_to_output"),
        ("distances-output-to-full", "output_to_full"),
    ] {
        let bins = m["distances"][key]["histogram"].as_array().unwrap();
        assert!(bins.len() > 1, "{key}: {bins:?}");
        let total: u64 = bins.iter().map(|b| b[1].as_u64().unwrap()).sum();
        assert_eq!(Some(total), m["distances"][key]["samples"].as_u64());
        assert_eq!(figure(&page, id).matches("<rect").count(), 1 + bins.len());
    }
    // The distance most samples are within, beside the one sample's Hausdorff distance.
    let p999 = m["distances"]["p999_pct"].as_f64().unwrap();
    assert!(p999 > 0.0 && p999 <= m["distances"]["hausdorff_pct"].as_f64().unwrap());
    let within = format!("99.9 % of the samples within {p999:.4} %");
    assert!(page.contains(&within), "{within} missing");
}

#[test]
fn bad_files_give_one_line_and_no_page() {
    let dir = tempfile::tempdir().unwrap();
    let page = dir.path().join("report.html");
    let out = page.to_string_lossy().into_owned();
    let missing = dir.path().join("missing.run.json");
    let o = isostream(&["report", &missing.to_string_lossy(), "-o", &out]);
    assert_one_line_error(&o, 2, &["missing.run.json", "cannot read"]);

    let not_run = dir.path().join("job.toml");
    std::fs::write(&not_run, JOB).unwrap();
    let o = isostream(&["report", &not_run.to_string_lossy(), "-o", &out]);
    assert_one_line_error(
        &o,
        2,
        &["job.toml", "not an isostream run summary", "run.json"],
    );

    let summary = run(dir.path());
    let run_json = dir.path().join("gyroid.smb.run.json");
    assert!(summary["series"].is_object());
    // The mesh itself given by mistake: binary, so "not a run summary", not a failed read.
    let mesh = dir.path().join("gyroid.smb");
    let o = isostream(&["report", &mesh.to_string_lossy(), "-o", &out]);
    assert_one_line_error(
        &o,
        2,
        &["gyroid.smb", "not an isostream run summary", "run.json"],
    );
    let with_measure = |measure: &std::path::Path| {
        isostream(&[
            "report",
            &run_json.to_string_lossy(),
            "-o",
            &out,
            "--measure",
            &measure.to_string_lossy(),
        ])
    };
    let o = with_measure(&run_json);
    assert_one_line_error(&o, 2, &["gyroid.smb.run.json", "not a measure report"]);
    // The measure of another mesh (one triangle) beside this run's: refused, naming both files
    // and both counts; the page showed "2016 written" beside "measured mesh 4348 triangles".
    let other = dir.path().join("other.obj");
    std::fs::write(&other, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let o = isostream(&["measure", "--json", &other.to_string_lossy()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let other_measure = dir.path().join("other.json");
    std::fs::write(&other_measure, &o.stdout).unwrap();
    let o = with_measure(&other_measure);
    let written = summary["faces_written"].to_string();
    assert_one_line_error(
        &o,
        2,
        &[
            "other.json",
            "1 triangles",
            "gyroid.smb.run.json",
            &format!("wrote {written}"),
        ],
    );
    assert!(!page.exists());

    // A missing folder is made, as `run` makes its output's; one that cannot be (a file stands
    // in its way) is a write error.
    let nested = dir.path().join("no/such/folder/r.html");
    let o = report(&run_json, &nested);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(nested.exists());
    let o = report(&run_json, &mesh.join("r.html"));
    assert_one_line_error(&o, 1, &["r.html", "cannot write the report"]);
}

#[test]
fn a_long_sweep_keeps_a_bounded_series_that_still_ends_on_the_totals() {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.toml");
    // 2,099 slabs of 12 x 12 voxels: more slabs than the series holds points.
    std::fs::write(
        &job,
        "[input]\nshape = \"gyroid\"\nsize = [12, 12, 2100]\n[extract]\niso = 0.0\n[simplify]\nrate = 0.5\n[output]\npath = \"long.smb\"\n",
    )
    .unwrap();
    let o = isostream(&["run", "--quiet", &job.to_string_lossy()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let run = dir.path().join("long.smb.run.json");
    let summary: Value = serde_json::from_slice(&std::fs::read(&run).unwrap()).unwrap();
    let series = &summary["series"];
    let points = series["points"].as_array().unwrap();
    let max = isostream_pipeline::MAX_SERIES_POINTS;
    assert!(
        points.len() <= max && points.len() > max / 2,
        "{}",
        points.len()
    );
    assert!(series["stride"].as_u64().unwrap() >= 2);
    let slabs: u64 = points.iter().map(|p| p["slabs"].as_u64().unwrap()).sum();
    assert_eq!(slabs, 2099);
    let last = points.last().unwrap();
    assert_eq!(last["faces_in"], summary["faces_extracted"]);
    assert_eq!(last["faces_out"], summary["faces_written"]);

    let page = dir.path().join("long.html");
    let o = report(&run, &page);
    assert!(o.status.success(), "{}", stderr(&o));
    let page = std::fs::read_to_string(&page).unwrap();
    let memory = figure(&page, "memory");
    // Merged points: the resident faces' range drawn as a band, and the caption says so.
    assert!(memory.contains("<polygon"), "no band");
    assert!(memory.contains("Each point stands for"));
    assert!(polyline_lengths(memory).contains(&points.len()));
}
