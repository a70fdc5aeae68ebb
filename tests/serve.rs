//! `isostream serve` end to end: the built binary as a child process on an ephemeral loopback
//! port, driven by a real HTTP client. Every server is killed when its `Server` is dropped.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_isostream");

/// The example: a small procedural sphere.
const SPHERE: &str = "[input]\nshape = \"sphere\"\nsize = [32, 32, 32]\n\n[extract]\niso = 0.0\n\n[output]\npath = \"sphere.smb\"\n";

/// Runs long enough (a few seconds) to be cancelled or killed in the middle.
fn long_job(output: &str) -> String {
    format!(
        "[input]\nshape = \"gyroid\"\nsize = [96, 96, 96]\n\n[extract]\niso = 0.0\n\n[output]\npath = \"{output}\"\n"
    )
}

struct Server {
    child: Child,
    base: String,
    log: PathBuf,
}

impl Server {
    fn start(state: &Path, args: &[&str]) -> Server {
        let mut command = Command::new(BIN);
        // SIGHUP at its default disposition, whatever the test runner's: a runner started
        // under `nohup` hands its children SIGHUP ignored, which the service then keeps.
        #[cfg(unix)]
        {
            use std::os::unix::process::CommandExt;
            // SAFETY (why this test needs unsafe): `pre_exec` runs in the forked child before
            // exec, where only async-signal-safe calls are allowed; `signal` is one.
            #[allow(unsafe_code)]
            unsafe {
                command.pre_exec(|| {
                    libc::signal(libc::SIGHUP, libc::SIG_DFL);
                    Ok(())
                });
            }
        }
        Self::start_under(command, state, args, false)
    }

    /// Started through `nohup`: SIGHUP ignored from the start, as a terminal's user leaves it.
    fn start_nohup(state: &Path, args: &[&str]) -> Server {
        let mut nohup = Command::new("nohup");
        nohup.arg(BIN);
        Self::start_under(nohup, state, args, false)
    }

    /// Started in `cwd`, where a relative `state` is.
    fn start_in(cwd: &Path, state: &Path, args: &[&str]) -> Server {
        let mut command = Command::new(BIN);
        command.current_dir(cwd);
        Self::start_under(command, state, args, false)
    }

    /// Its stderr a pipe closed at once, as `isostream serve 2>&1 | head -1` leaves it once
    /// `head` is gone (its log is empty).
    fn start_with_stderr_closed(state: &Path) -> Server {
        Self::start_under(Command::new(BIN), state, &[], true)
    }

    fn start_under(
        mut command: Command,
        state: &Path,
        args: &[&str],
        stderr_closed: bool,
    ) -> Server {
        let log = match command.get_current_dir() {
            Some(cwd) => cwd.join(state),
            None => state.to_path_buf(),
        }
        .with_extension("log");
        let stderr = if stderr_closed {
            Stdio::piped()
        } else {
            Stdio::from(std::fs::File::create(&log).unwrap())
        };
        let mut child = command
            .arg("serve")
            .arg("--state")
            .arg(state)
            .args(["--listen", "127.0.0.1:0"])
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .unwrap();
        drop(child.stderr.take());
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let line = rx.recv_timeout(Duration::from_secs(30)).unwrap_or_default();
        let base = line
            .trim()
            .rsplit(' ')
            .next()
            .filter(|u| u.starts_with("http://"))
            .unwrap_or_else(|| {
                let _ = child.kill();
                panic!(
                    "no address in {line:?}; log: {}",
                    std::fs::read_to_string(&log).unwrap_or_default()
                )
            })
            .to_string();
        Server { child, base, log }
    }

    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn agent() -> ureq::Agent {
    ureq::AgentBuilder::new()
        .timeout_connect(Duration::from_secs(5))
        .timeout(Duration::from_secs(120))
        .build()
}

/// Status and body of any response, errors included.
fn send(req: ureq::Request, body: Option<&str>) -> (u16, String) {
    let res = match body {
        Some(b) => req.send_string(b),
        None => req.call(),
    };
    match res {
        Ok(r) => (r.status(), r.into_string().unwrap()),
        Err(ureq::Error::Status(code, r)) => (code, r.into_string().unwrap()),
        Err(e) => panic!("request failed: {e}"),
    }
}

fn json(body: &str) -> Value {
    serde_json::from_str(body).unwrap_or_else(|e| panic!("{e}: {body}"))
}

/// The reason of a refusal (`{"error": ...}`).
fn error_of(body: &str) -> String {
    json(body)["error"].as_str().unwrap_or_default().to_owned()
}

fn submit(s: &Server, job: &str) -> String {
    let (code, body) = send(agent().post(&s.url("/jobs")), Some(job));
    assert_eq!(code, 201, "{body}\n{}", s.log());
    let v = json(&body);
    assert_eq!(
        v["url"].as_str().unwrap(),
        format!("/jobs/{}", v["id"].as_str().unwrap())
    );
    v["id"].as_str().unwrap().to_string()
}

fn job(s: &Server, id: &str) -> Value {
    let (code, body) = send(agent().get(&s.url(&format!("/jobs/{id}"))), None);
    assert_eq!(code, 200, "{body}");
    json(&body)
}

/// Reads the job's Server-Sent Events until the stream ends; returns every event's JSON.
fn follow(s: &Server, id: &str) -> Vec<Value> {
    follow_live(s, id).iter().collect()
}

/// The job's Server-Sent Events as they come, read on a thread; the channel closes when the
/// stream ends.
fn follow_live(s: &Server, id: &str) -> mpsc::Receiver<Value> {
    let res = agent()
        .get(&s.url(&format!("/jobs/{id}/events")))
        .call()
        .unwrap();
    assert!(res.content_type().starts_with("text/event-stream"));
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(res.into_reader()).lines() {
            let line = line.unwrap();
            if let Some(data) = line.strip_prefix("data:")
                && tx.send(json(data.trim())).is_err()
            {
                return;
            }
        }
    });
    rx
}

/// Polls until `pred` holds for the job, or panics after 60 s.
fn wait_for(s: &Server, id: &str, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        let v = job(s, id);
        if pred(&v) {
            return v;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "never {what}: {v}\n{}",
            s.log()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn output_bytes(s: &Server, id: &str) -> Vec<u8> {
    let res = agent()
        .get(&s.url(&format!("/jobs/{id}/output")))
        .call()
        .unwrap();
    let mut bytes = Vec::new();
    res.into_reader().read_to_end(&mut bytes).unwrap();
    bytes
}

fn isostream(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn a_job_is_submitted_followed_and_its_mesh_fetched() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let s = Server::start(&state, &[]);

    let (code, body) = send(agent().get(&s.url("/healthz")), None);
    assert_eq!((code, json(&body)["status"].as_str()), (200, Some("ok")));

    let id = submit(&s, SPHERE);
    let events = follow(&s, &id);
    let last = events.last().expect("at least one event");
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
    assert!(events.iter().any(|e| e["state"] == "running"), "{events:?}");

    let v = job(&s, &id);
    assert_eq!(v["state"], "done");
    assert!(v["summary"]["faces_written"].as_u64().unwrap() > 0, "{v}");
    assert_eq!(v["output"], "sphere.smb".replace("sphere", "output"));
    assert_eq!(
        v["output_url"].as_str().unwrap(),
        format!("/jobs/{id}/output")
    );

    let mesh = output_bytes(&s, &id);
    assert_eq!(&mesh[..4], &[0, 0, 0, 0], "SMB version-0 magic");
    let file = dir.path().join("fetched.smb");
    std::fs::write(&file, &mesh).unwrap();
    let check = isostream(&["check", &file.to_string_lossy()]);
    assert!(
        check.status.success(),
        "{}",
        String::from_utf8_lossy(&check.stderr)
    );
    assert_eq!(
        std::fs::read(state.join("jobs").join(&id).join("output.smb")).unwrap(),
        mesh
    );

    let (code, body) = send(agent().get(&s.url("/jobs")), None);
    assert_eq!(code, 200);
    assert_eq!(json(&body)["jobs"][0]["id"], id.as_str());

    let (code, metrics) = send(agent().get(&s.url("/metrics")), None);
    assert_eq!(code, 200);
    for needle in [
        "isostream_jobs{state=\"done\"} 1",
        "isostream_faces_in_total",
        "isostream_voxels_total 32768",
        "isostream_stage_busy_seconds_total{stage=\"simplify\"}",
        // A cascade's second simplifier (the default in mode rate), as the run summary names it.
        "isostream_stage_busy_seconds_total{stage=\"simplify_second\"}",
        "isostream_peak_rss_bytes",
        "isostream_resident_faces",
    ] {
        assert!(metrics.contains(needle), "{needle} missing:\n{metrics}");
    }

    let (code, page) = send(agent().get(&s.url("/")), None);
    assert_eq!(code, 200);
    assert!(page.contains("<html") && page.contains("/events"), "{page}");
    assert!(
        page.contains("report_url"),
        "the page links each job's plots"
    );

    // The report: the same page as `isostream report` on the job's run summary.
    assert_eq!(v["report_url"], format!("/jobs/{id}/report"));
    let (code, report) = send(agent().get(&s.url(&format!("/jobs/{id}/report"))), None);
    assert_eq!(code, 200, "{report}");
    for figure in ["memory", "faces", "stages"] {
        assert!(
            report.contains(&format!("<figure id=\"{figure}\">")),
            "{figure}"
        );
    }
    // The series lives in the summary file only, not in every view and event.
    assert!(v["summary"].get("series").is_none(), "{v}");
    let stored = std::fs::read_to_string(state.join("jobs").join(&id).join("output.smb.run.json"));
    assert!(json(&stored.unwrap())["series"]["points"].is_array());
}

#[test]
fn a_config_file_json_logs_with_the_job_id_and_reports_only_when_done() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("serve.toml");
    std::fs::write(&config, "log_format = \"json\"\nmax_parallel_jobs = 1\n").unwrap();
    let s = Server::start(
        &dir.path().join("state"),
        &["--config", config.to_str().unwrap()],
    );
    let running = submit(&s, &long_job("long.smb"));
    let queued = submit(&s, SPHERE);
    wait_for(&s, &running, "running", |v| v["state"] == "running");
    let (code, body) = send(agent().get(&s.url(&format!("/jobs/{queued}/report"))), None);
    assert_eq!(code, 409, "{body}");
    let reason = error_of(&body);
    assert!(
        reason.contains("queued") && reason.contains("once the job is done"),
        "{body}"
    );
    // A job asking for progress lines as often as the service allows (once a second): they come
    // from a stage thread.
    let chatty = submit(
        &s,
        &format!(
            "{}\n[log]\nprogress_seconds = 0.001\n",
            long_job("chatty.smb")
        ),
    );
    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{running}"))), None);
    assert_eq!(code, 202);
    assert_eq!(follow(&s, &chatty).pop().unwrap()["state"], "done");

    let lines: Vec<Value> = s
        .log()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: not JSON: {l}")))
        .collect();
    let progress: Vec<&Value> = lines
        .iter()
        .filter(|l| l["fields"]["message"] == "progress")
        .collect();
    assert!(!progress.is_empty(), "{}", s.log());
    for line in &progress {
        assert_eq!(line["spans"][0]["name"], "job", "{line}");
        let id = line["spans"][0]["id"].as_str().unwrap();
        assert!(id == chatty || id == running, "{line}");
        assert!(line["fields"]["eta_s"].is_number(), "{line}");
    }
    assert!(
        progress
            .iter()
            .any(|l| l["spans"][0]["id"] == chatty.as_str())
    );
}

#[test]
fn bad_jobs_and_foreign_inputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    std::fs::write(dir.path().join("secret.raw"), [0u8; 8]).unwrap();
    let s = Server::start(
        &dir.path().join("state"),
        &["--allow-input", data.to_str().unwrap()],
    );

    // The same one-line error as `isostream validate`, which names the file it read.
    let bad = SPHERE.replace("iso = 0.0", "iso = 0.0\nisovalue = 2");
    let (code, body) = send(agent().post(&s.url("/jobs")), Some(&bad));
    assert_eq!(code, 400, "{body}");
    let reason = json(&body)["error"].as_str().unwrap().to_string();
    assert!(reason.contains("isovalue"), "{reason}");
    let job_file = dir.path().join("job.toml");
    std::fs::write(&job_file, &bad).unwrap();
    let validate = isostream(&["validate", &job_file.to_string_lossy()]);
    let line = String::from_utf8_lossy(&validate.stderr).trim().to_string();
    let prefix = format!("error: {}/", dir.path().display());
    assert_eq!(line.strip_prefix(&prefix), Some(reason.as_str()));
    // `[log]` too, although the service logs its own way: the job is checked as submitted.
    let bad = format!("{SPHERE}\n[log]\nlevel = \"debugg\"\n");
    let (code, body) = send(agent().post(&s.url("/jobs")), Some(&bad));
    assert_eq!(code, 400, "{body}");
    std::fs::write(&job_file, &bad).unwrap();
    let validate = isostream(&["validate", &job_file.to_string_lossy()]);
    assert_eq!(validate.status.code(), Some(2));
    let line = String::from_utf8_lossy(&validate.stderr).trim().to_string();
    assert_eq!(line.strip_prefix(&prefix), Some(error_of(&body).as_str()));

    let (code, body) = send(
        agent().post(&s.url("/jobs")),
        Some(&SPHERE.replace("0.0", "\"high\"")),
    );
    assert_eq!(code, 400, "{body}");
    // A wrong type is reported with the line of the job, as `isostream validate` does.
    assert!(error_of(&body).starts_with("job.toml:6:"), "{body}");

    let raw = |path: &str| {
        format!(
            "[input]\npath = \"{path}\"\ndims = [2, 2, 2]\ndtype = \"u8\"\n[extract]\niso = 0.5\n[output]\npath = \"x.smb\"\n"
        )
    };
    for path in [
        format!("{}/../secret.raw", data.display()),
        dir.path().join("secret.raw").display().to_string(),
        "/etc/passwd".to_string(),
    ] {
        let (code, body) = send(agent().post(&s.url("/jobs")), Some(&raw(&path)));
        assert_eq!(code, 403, "{path}: {body}");
        assert!(
            json(&body)["error"]
                .as_str()
                .unwrap()
                .contains("input.path"),
            "{body}"
        );
    }

    // One byte over the limit: the server reads it all before refusing, so the client is never
    // cut off mid-write (a much larger body can end in a broken pipe instead of the 413).
    let too_big = "#".repeat((1 << 20) + 1);
    let (code, body) = send(agent().post(&s.url("/jobs")), Some(&too_big));
    assert_eq!(code, 413, "{body}");
    // Three times the limit, written whole by the client before it reads: still the 413 (the
    // server reads and drops such a body), not a reset connection.
    let (code, body) = send(agent().post(&s.url("/jobs")), Some(&too_big.repeat(3)));
    assert_eq!(code, 413, "{body}");
    let (code, _) = send(
        agent().get(&s.url("/jobs/0123456789abcdef0123456789abcdef")),
        None,
    );
    assert_eq!(code, 404);

    let (_, metrics) = send(agent().get(&s.url("/metrics")), None);
    assert!(
        metrics.contains("isostream_errors_total{kind=\"forbidden_input\"} 3"),
        "{metrics}"
    );
    assert!(
        metrics.contains("isostream_errors_total{kind=\"bad_job\"} 3"),
        "{metrics}"
    );
    // Nothing was queued.
    assert_eq!(
        files_in(&dir.path().join("state/jobs")),
        Vec::<String>::new()
    );
}

/// Writes `bytes` on a new connection to `s` and reads until the server answers and closes, or
/// closes without an answer: what came back, and when.
fn raw_exchange(s: &Server, bytes: &[u8]) -> (String, Duration) {
    let address = s.base.trim_start_matches("http://");
    let mut stream = TcpStream::connect(address).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let started = Instant::now();
    stream.write_all(bytes).unwrap();
    let mut answer = Vec::new();
    let _ = stream.read_to_end(&mut answer);
    (
        String::from_utf8_lossy(&answer).into_owned(),
        started.elapsed(),
    )
}

/// A client that stops halfway through its request holds nothing for long: a head not
/// complete within 10 s loses its connection, a body not complete within 10 s of the head gets
/// a 408, and a body declared far past the limit gets its 413 before any of it is sent.
#[test]
fn stalled_and_oversized_requests_are_cut_off() {
    let dir = tempfile::tempdir().unwrap();
    let s = Server::start(&dir.path().join("state"), &[]);
    let (head, body) = std::thread::scope(|scope| {
        let head = scope.spawn(|| raw_exchange(&s, b"POST /jobs HTTP/1.1\r\nHost: 127.0.0.1\r\n"));
        let body = scope.spawn(|| {
            raw_exchange(
                &s,
                b"POST /jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\n[input]\n",
            )
        });
        // Meanwhile the service answers everyone else.
        let (code, _) = send(agent().get(&s.url("/healthz")), None);
        assert_eq!(code, 200);
        (head.join().unwrap(), body.join().unwrap())
    });
    assert_eq!(head.0, "", "a head never completed gets no answer");
    assert!(
        (Duration::from_secs(9)..Duration::from_secs(30)).contains(&head.1),
        "{head:?}"
    );
    assert!(body.0.starts_with("HTTP/1.1 408"), "{body:?}");
    assert!(body.0.contains("send the whole job file"), "{body:?}");
    assert!(
        (Duration::from_secs(9)..Duration::from_secs(30)).contains(&body.1),
        "{body:?}"
    );

    let (answer, took) = raw_exchange(
        &s,
        b"POST /jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000000000\r\n\r\n",
    );
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
    assert!(answer.contains("at most 1048576 bytes"), "{answer}");
    assert!(took < Duration::from_secs(5), "{took:?}");

    let (_, metrics) = send(agent().get(&s.url("/metrics")), None);
    assert!(
        metrics.contains("isostream_errors_total{kind=\"too_large\"} 1"),
        "{metrics}"
    );
}

#[test]
fn jobs_are_cancelled_queued_or_running() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let s = Server::start(&state, &[]);
    let first = submit(&s, &long_job("a.smb"));
    let second = submit(&s, &long_job("b.ply"));
    wait_for(&s, &first, "running", |v| v["state"] == "running");
    assert_eq!(
        job(&s, &second)["state"],
        "queued",
        "one job at a time by default"
    );

    let (code, body) = send(agent().delete(&s.url(&format!("/jobs/{second}"))), None);
    assert_eq!(
        (code, json(&body)["state"].as_str()),
        (200, Some("cancelled"))
    );

    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{first}"))), None);
    assert_eq!(code, 202);
    let last = follow(&s, &first).pop().unwrap();
    assert_eq!(last["state"], "cancelled", "{last}");
    let (code, body) = send(agent().get(&s.url(&format!("/jobs/{first}/output"))), None);
    assert_eq!(code, 409, "{body}");
    // A cancelled job will never have one: it says so, not "once it is done".
    assert!(error_of(&body).contains("it has none"), "{body}");
    // Nothing half-written kept; the log stays.
    assert_eq!(
        files_in(&state.join("jobs").join(&first)),
        ["job.log", "job.toml", "state.json"]
    );

    // A finished job is removed by a second DELETE, folder and all, and stays removed.
    let (code, body) = send(agent().delete(&s.url(&format!("/jobs/{first}"))), None);
    assert_eq!((code, json(&body)["removed"].as_bool()), (200, Some(true)));
    assert!(!state.join("jobs").join(&first).exists());
    let (code, _) = send(agent().get(&s.url(&format!("/jobs/{first}"))), None);
    assert_eq!(code, 404);
    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{first}"))), None);
    assert_eq!(code, 404);
    let done = submit(&s, SPHERE);
    let last = follow(&s, &done).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}");
    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{done}"))), None);
    assert_eq!(code, 200);
    let (_, list) = send(agent().get(&s.url("/jobs")), None);
    let listed: Vec<String> = json(&list)["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap().to_owned())
        .collect();
    assert_eq!(
        listed,
        [second.as_str()],
        "only the cancelled queued job is left"
    );
    drop(s);
    let s = Server::start(&state, &[]);
    let (code, _) = send(agent().get(&s.url(&format!("/jobs/{done}"))), None);
    assert_eq!(code, 404, "removed for good");
    assert_eq!(files_in(&state.join("jobs")), [second.as_str()]);
}

/// Makes the job's `state.json` impossible to rewrite, as a full disk would: a new state is
/// renamed over it, which fails on a folder. Returns the folder, to remove to undo it.
fn block_state(state: &Path, id: &str) -> PathBuf {
    let file = state.join("jobs").join(id).join("state.json");
    std::fs::remove_file(&file).unwrap();
    std::fs::create_dir(&file).unwrap();
    file
}

/// The job's state as `state.json` holds it.
fn stored_state(state: &Path, id: &str) -> Value {
    json(&std::fs::read_to_string(state.join("jobs").join(id).join("state.json")).unwrap())
}

/// Polls the service's log until it holds `text`, or panics after 60 s.
fn wait_for_log(s: &Server, text: &str) {
    let start = Instant::now();
    while !s.log().contains(text) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "never logged {text:?}:\n{}",
            s.log()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A job whose `running` state cannot be written when its turn comes is not started: it stays
/// queued, as its `state.json` says, and starts once the state can be written. It was failed in
/// memory while the disk still said queued: clients were told it failed, and a restart ran it.
#[test]
fn a_job_whose_start_cannot_be_written_stays_queued_and_starts_later() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let s = Server::start(&state, &[]);
    let first = submit(&s, &long_job("a.smb"));
    let second = submit(&s, SPHERE);
    wait_for(&s, &first, "running", |v| v["state"] == "running");
    let blocked = block_state(&state, &second);
    // Its turn comes once the first job is cancelled.
    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{first}"))), None);
    assert_eq!(code, 202);
    wait_for_log(&s, "it stays queued");
    let waiting = job(&s, &second);
    assert_eq!(
        (&waiting["state"], &waiting["attempts"], &waiting["error"]),
        (&"queued".into(), &0.into(), &Value::Null),
        "{waiting}"
    );
    let (_, metrics) = send(agent().get(&s.url("/metrics")), None);
    assert!(
        metrics.contains("isostream_errors_total{kind=\"state_io\"}"),
        "{metrics}"
    );

    std::fs::remove_dir(blocked).unwrap();
    let done = wait_for(&s, &second, "done", |v| v["state"] == "done");
    assert_eq!(done["attempts"], 1, "{done}");
    assert_eq!(stored_state(&state, &second)["state"], "done");
}

/// A run whose end cannot be written shows `running`, as its `state.json` says, until the
/// write, tried again, succeeds; nothing else starts meanwhile. It was shown done (or failed)
/// while the disk said running, so a restart ran the finished job again.
#[test]
fn the_end_of_a_run_is_shown_once_it_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let s = Server::start(&state, &[]);
    let first = submit(&s, &long_job("a.smb"));
    let second = submit(&s, SPHERE);
    wait_for(&s, &first, "running", |v| v["state"] == "running");
    let blocked = block_state(&state, &first);
    wait_for_log(&s, "cannot write the end of the run");
    let unwritten = job(&s, &first);
    assert_eq!(unwritten["state"], "running", "{unwritten}");
    let (code, _) = send(agent().get(&s.url(&format!("/jobs/{first}/output"))), None);
    assert_eq!(code, 409);
    assert_eq!(
        job(&s, &second)["state"],
        "queued",
        "its slot is still taken"
    );

    std::fs::remove_dir(blocked).unwrap();
    wait_for(&s, &first, "done", |v| v["state"] == "done");
    assert_eq!(stored_state(&state, &first)["state"], "done");
    wait_for(&s, &second, "done", |v| v["state"] == "done");
}

/// A service stopped while the end of a run cannot be written leaves the job `running` on
/// disk, and says so (an event stream ends with it as saved); its next start finds the run
/// completed (its output and run summary whole) and shows it done, not run again.
#[test]
fn a_completed_run_whose_end_was_not_written_is_done_at_the_next_start() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let mut s = Server::start(&state, &[]);
    let job_text = long_job("a.smb");
    let id = submit(&s, &job_text);
    wait_for(&s, &id, "running", |v| v["state"] == "running");
    let state_file = state.join("jobs").join(&id).join("state.json");
    let running = std::fs::read(&state_file).unwrap();
    let blocked = block_state(&state, &id);
    wait_for_log(&s, "cannot write the end of the run");
    let events = follow_live(&s, &id);
    let term = Command::new("kill")
        .args(["-TERM", &s.child.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    assert!(s.child.wait().unwrap().success(), "{}", s.log());
    let last = events.iter().last().unwrap();
    assert_eq!(
        (&last["state"], &last["shutdown"]),
        (&"running".into(), &true.into()),
        "{last}"
    );
    assert!(
        s.log()
            .contains("the service stops before the end of this run could be written")
    );
    // What the disk holds once the folder is gone: the job's last state written, and a
    // checkpoint's finished-run record if the run had been killed just before removing it.
    std::fs::remove_dir(blocked).unwrap();
    std::fs::write(&state_file, running).unwrap();
    let job_dir = state.join("jobs").join(&id);
    let record = job_dir.join(".output.smb.ckpt");
    std::fs::write(&record, b"a finished run's record").unwrap();

    let s = Server::start(&state, &[]);
    assert!(!record.exists(), "{:?}", files_in(&job_dir));
    let found = job(&s, &id);
    assert_eq!(
        (&found["state"], &found["attempts"], &found["crashes"]),
        (&"done".into(), &1.into(), &0.into()),
        "done, not run again: {found}\n{}",
        s.log()
    );
    assert!(
        found["summary"]["faces_written"].as_u64().unwrap() > 0,
        "{found}"
    );
    assert_eq!(stored_state(&state, &id)["state"], "done");
    assert_same_as_a_direct_run(dir.path(), &job_text, "a.smb", &output_bytes(&s, &id));
}

/// A file the service cannot delete, in a folder of its own (`held/`) planted in `dir`, as an
/// administrator's lock or a failing disk would leave one: immutable (`chattr +i`) where the
/// test may set that (root, whom permissions do not stop), else in a read-only folder. `None`
/// where neither holds (a file system without the attribute, and root). Undone when dropped.
#[cfg(unix)]
struct Undeletable {
    file: PathBuf,
}

#[cfg(unix)]
impl Undeletable {
    fn plant(dir: &Path) -> Option<Self> {
        use std::os::unix::fs::PermissionsExt;
        let folder = dir.join("held");
        std::fs::create_dir(&folder).unwrap();
        let file = folder.join("file");
        std::fs::write(&file, b"held").unwrap();
        let immutable = Command::new("chattr")
            .arg("+i")
            .arg(&file)
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        let held = Undeletable { file };
        if immutable {
            return Some(held);
        }
        std::fs::set_permissions(&folder, std::fs::Permissions::from_mode(0o555)).unwrap();
        // Root writes in a read-only folder, and would delete the file as well.
        let probe = folder.join("probe");
        match std::fs::write(&probe, b"") {
            Ok(()) => {
                std::fs::remove_file(probe).unwrap();
                None
            }
            Err(_) => Some(held),
        }
    }
}

#[cfg(unix)]
impl Drop for Undeletable {
    fn drop(&mut self) {
        use std::os::unix::fs::PermissionsExt;
        let _ = Command::new("chattr")
            .arg("-i")
            .arg(&self.file)
            .stderr(Stdio::null())
            .status();
        if let Some(folder) = self.file.parent() {
            let _ = std::fs::set_permissions(folder, std::fs::Permissions::from_mode(0o755));
        }
    }
}

/// A `DELETE` of a finished job tells the truth about what is left. Its state file decides:
/// when that cannot be removed, nothing is (`500`, the job as it was); once it is, the job is
/// gone (`200`, as a restart finds it), and the files that could not be deleted are named in
/// a `warning` and deleted at the next start. Such a removal answered "unchanged" and kept the
/// job listed, while a restart found it gone.
#[cfg(unix)]
#[test]
fn a_removal_that_fails_says_what_is_left() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let s = Server::start(&state, &[]);
    let id = submit(&s, SPHERE);
    wait_for(&s, &id, "done", |v| v["state"] == "done");
    let job_dir = state.join("jobs").join(&id);
    let remove = || send(agent().delete(&s.url(&format!("/jobs/{id}"))), None);

    let done = std::fs::read(job_dir.join("state.json")).unwrap();
    let blocked = block_state(&state, &id);
    let (code, body) = remove();
    assert_eq!(code, 500, "{body}");
    assert!(error_of(&body).contains("unchanged"), "{body}");
    assert_eq!(job(&s, &id)["state"], "done");
    assert!(!output_bytes(&s, &id).is_empty());
    std::fs::remove_dir(blocked).unwrap();
    std::fs::write(job_dir.join("state.json"), done).unwrap();

    let Some(held) = Undeletable::plant(&job_dir) else {
        eprintln!("skipped the second half: no file can be made undeletable here");
        return;
    };
    let (code, body) = remove();
    assert_eq!(code, 200, "{body}");
    let removed = json(&body);
    assert_eq!(removed["removed"], true, "{body}");
    let warning = removed["warning"].as_str().unwrap_or_default();
    assert!(
        warning.contains("not deleted whole") && warning.contains(&*job_dir.to_string_lossy()),
        "{body}"
    );
    let (code, _) = send(agent().get(&s.url(&format!("/jobs/{id}"))), None);
    assert_eq!(code, 404, "gone, as a restart finds it");
    assert!(!job_dir.join("state.json").exists());
    assert!(job_dir.join("held").exists());

    drop(s);
    drop(held);
    let s = Server::start(&state, &[]);
    let (code, _) = send(agent().get(&s.url(&format!("/jobs/{id}"))), None);
    assert_eq!(code, 404);
    assert!(
        files_in(&state.join("jobs")).is_empty(),
        "what was left is deleted"
    );
}

#[test]
fn at_most_max_parallel_jobs_run_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let s = Server::start(&dir.path().join("state"), &["--max-parallel-jobs", "2"]);
    let ids: Vec<String> = (0..3)
        .map(|i| submit(&s, &long_job(&format!("{i}.smb"))))
        .collect();
    wait_for(&s, &ids[1], "running", |v| v["state"] == "running");
    assert_eq!(job(&s, &ids[0])["state"], "running");
    assert_eq!(job(&s, &ids[2])["state"], "queued");
    let (_, metrics) = send(agent().get(&s.url("/metrics")), None);
    assert!(
        metrics.contains("isostream_jobs{state=\"running\"} 2"),
        "{metrics}"
    );
}

/// Past `--max-queued-jobs` waiting jobs a submission is refused with 429 and nothing is
/// stored; once one has left the queue, submissions are taken again.
#[test]
fn a_full_queue_refuses_submissions() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let s = Server::start(&state, &["--max-queued-jobs", "1"]);
    let running = submit(&s, &long_job("a.smb"));
    wait_for(&s, &running, "running", |v| v["state"] == "running");
    let waiting = submit(&s, SPHERE);
    match agent().post(&s.url("/jobs")).send_string(SPHERE) {
        Err(ureq::Error::Status(429, r)) => {
            assert_eq!(r.header("retry-after"), Some("10"));
            let body = r.into_string().unwrap();
            assert!(error_of(&body).contains("--max-queued-jobs"), "{body}");
        }
        other => panic!("expected 429: {other:?}"),
    }
    assert_eq!(files_in(&state.join("jobs")).len(), 2, "nothing stored");
    let (_, metrics) = send(agent().get(&s.url("/metrics")), None);
    assert!(
        metrics.contains("isostream_errors_total{kind=\"queue_full\"} 1"),
        "{metrics}"
    );
    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{waiting}"))), None);
    assert_eq!(code, 200);
    submit(&s, SPHERE);
}

#[test]
fn an_open_address_without_token_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(BIN)
        .args(["serve", "--listen", "0.0.0.0:0", "--state"])
        .arg(dir.path().join("state"))
        .output()
        .unwrap();
    // 2: a configuration to fix (the systemd unit does not restart on it).
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains("0.0.0.0") && lines[0].contains("--token"),
        "{err}"
    );
}

/// A token file that cannot be read is a configuration to fix, as an empty token is: exit
/// code 2 (the systemd unit does not restart on it), one line saying what to give.
#[test]
fn a_missing_token_file_is_a_bad_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("serve.toml");
    std::fs::write(&config, "token_file = \"no-token\"\n").unwrap();
    let missing = dir.path().join("nonexistent");
    for args in [
        vec!["--token-file", missing.to_str().unwrap()],
        vec!["--config", config.to_str().unwrap()],
    ] {
        let o = Command::new(BIN)
            .arg("serve")
            .args(&args)
            .arg("--state")
            .arg(dir.path().join("state"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        assert_eq!(lines.len(), 1, "{err}");
        assert!(
            lines[0].contains("--token-file")
                && (lines[0].contains("nonexistent") || lines[0].contains("no-token"))
                && lines[0].contains("give a readable file"),
            "{err}"
        );
    }
}

/// What a web page on another site can make a browser send is refused: a cross-site `POST`
/// (a form or `fetch` with `text/plain` needs no preflight) and, without a token, a request
/// under a name that is not loopback (DNS rebinding). Unknown routes and methods answer JSON.
#[test]
fn requests_from_other_sites_are_refused_and_every_refusal_is_json() {
    let dir = tempfile::tempdir().unwrap();
    let s = Server::start(&dir.path().join("state"), &[]);
    let (code, body) = send(
        agent()
            .post(&s.url("/jobs"))
            .set("Origin", "http://evil.example")
            .set("Content-Type", "text/plain"),
        Some(SPHERE),
    );
    assert_eq!(code, 403, "{body}");
    assert!(
        error_of(&body).contains("Origin http://evil.example"),
        "{body}"
    );
    let address = s.base.trim_start_matches("http://").to_string();
    let port = address.rsplit(':').next().unwrap();
    // A GET under another `Host` name, as a raw request (a client library sets its own).
    let get_as = |path: &str, host: &str| {
        let head =
            format!("GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nConnection: close\r\n\r\n");
        raw_exchange(&s, head.as_bytes()).0
    };
    let answer = get_as("/jobs", "evil.example");
    assert!(answer.starts_with("HTTP/1.1 403"), "{answer}");
    assert!(answer.contains("not a loopback name"), "{answer}");
    // The service's own page posts with its own origin; programs send none.
    let (code, body) = send(
        agent()
            .post(&s.url("/jobs"))
            .set("Origin", &format!("http://{address}")),
        Some(SPHERE),
    );
    assert_eq!(code, 201, "{body}");
    let answer = get_as("/healthz", "localhost");
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");

    let (code, body) = send(agent().get(&s.url("/nothing/here")), None);
    assert_eq!(code, 404, "{body}");
    assert!(error_of(&body).contains("no such route"), "{body}");
    let (code, body) = send(agent().put(&s.url("/jobs")), Some("x"));
    assert_eq!(code, 405, "{body}");
    assert!(error_of(&body).contains("PUT is not allowed"), "{body}");
    // A job id that is not UTF-8 once decoded: axum's plain-text rejection, now JSON, on every
    // route that takes an id.
    for path in ["/jobs/%ff%fe", "/jobs/%ff%fe/log"] {
        let (code, body) = send(agent().get(&s.url(path)), None);
        assert_eq!(code, 400, "{body}");
        let reason = error_of(&body);
        assert!(
            reason.contains("Invalid UTF-8") && reason.contains("POST /jobs answered"),
            "{body}"
        );
    }
}

#[test]
fn with_a_token_every_request_needs_it() {
    let dir = tempfile::tempdir().unwrap();
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, "s3cret-token\n").unwrap();
    let s = Server::start(
        &dir.path().join("state"),
        &["--token-file", token_file.to_str().unwrap()],
    );
    for path in ["/jobs", "/healthz", "/metrics"] {
        let (code, body) = send(agent().get(&s.url(path)), None);
        assert_eq!(code, 401, "{path}: {body}");
        assert!(json(&body)["error"].as_str().unwrap().contains("Bearer"));
        let (code, _) = send(
            agent()
                .get(&s.url(path))
                .set("Authorization", "Bearer wrong-token!"),
            None,
        );
        assert_eq!(code, 401, "{path}");
    }
    let (code, _) = send(agent().post(&s.url("/jobs")), Some(SPHERE));
    assert_eq!(code, 401);
    let (code, body) = send(
        agent()
            .get(&s.url("/jobs"))
            .set("Authorization", "Bearer s3cret-token"),
        None,
    );
    assert_eq!(code, 200, "{body}");
    // The scheme's name is case-insensitive; behind a reverse proxy, the public name and the
    // browser's origin are not refused when the token comes with them.
    let (code, body) = send(
        agent()
            .get(&s.url("/jobs"))
            .set("Authorization", "bearer s3cret-token")
            .set("Host", "isostream.example.org")
            .set("Origin", "https://isostream.example.org"),
        None,
    );
    assert_eq!(code, 200, "{body}");
    // The status page itself holds no data; its script sends the token.
    let (code, _) = send(agent().get(&s.url("/")), None);
    assert_eq!(code, 200);
}

#[cfg(unix)]
#[test]
fn sigterm_interrupts_a_run_cleanly_and_the_next_start_runs_it() {
    stop_with_a_signal_and_restart("-TERM");
}

/// SIGHUP (the terminal closed) killed the service on the spot, leaving its running job's
/// temporary output behind; it now stops as SIGTERM does.
#[cfg(unix)]
#[test]
fn sighup_stops_the_service_as_sigterm_does() {
    stop_with_a_signal_and_restart("-HUP");
}

/// Started with SIGHUP ignored (`nohup`), the service keeps running through a hangup.
#[cfg(unix)]
#[test]
fn under_nohup_a_hangup_does_not_stop_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = Server::start_nohup(&dir.path().join("state"), &[]);
    let hup = Command::new("kill")
        .args(["-HUP", &s.child.id().to_string()])
        .status()
        .unwrap();
    assert!(hup.success());
    std::thread::sleep(Duration::from_millis(300));
    assert!(s.child.try_wait().unwrap().is_none(), "{}", s.log());
    let (code, _) = send(agent().get(&s.url("/healthz")), None);
    assert_eq!(code, 200);
}

#[cfg(unix)]
fn stop_with_a_signal_and_restart(signal: &str) {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let mut s = Server::start(&state, &[]);
    let id = submit(&s, &long_job("g.smb"));
    wait_for(&s, &id, "running", |v| v["state"] == "running");
    // A client stalled halfway through a request head does not hold the stopping service (it
    // did for as long as the client kept its connection).
    let mut stalled = TcpStream::connect(s.base.trim_start_matches("http://")).unwrap();
    stalled
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        .unwrap();
    let events = follow_live(&s, &id);
    let first = events.recv_timeout(Duration::from_secs(10)).unwrap();
    assert_eq!(first["state"], "running", "{first}");
    let term = Command::new("kill")
        .args([signal, &s.child.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    let stopping = Instant::now();
    let status = s.child.wait().unwrap();
    assert!(status.success(), "{status:?}\n{}", s.log());
    assert!(
        stopping.elapsed() < Duration::from_secs(25),
        "{:?}",
        stopping.elapsed()
    );
    drop(stalled);
    let job_dir = state.join("jobs").join(&id);
    assert_eq!(
        files_in(&job_dir),
        ["job.log", "job.toml", "state.json"],
        "no partial output"
    );
    let stored = json(&std::fs::read_to_string(job_dir.join("state.json")).unwrap());
    assert_eq!(stored["state"], "queued", "{stored}");
    // An event stream open at the stop ends with the job as saved, saying why it ends.
    let last = events.iter().last().unwrap_or(first);
    assert_eq!(
        (&last["state"], &last["shutdown"]),
        (&"queued".into(), &true.into()),
        "{last}"
    );

    let s = Server::start(&state, &[]);
    let last = follow(&s, &id).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
}

#[test]
fn a_job_killed_with_the_service_restarts_and_gives_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let job_text = long_job("gyroid.smb");
    let (id, queued, done_progress) = {
        let s = Server::start(&state, &[]);
        let queued = submit(&s, SPHERE);
        let id = submit(&s, &job_text);
        let done = wait_for(&s, &queued, "done", |v| v["state"] == "done");
        wait_for(&s, &id, "half-way", |v| {
            v["state"] == "running" && v["progress"]["slabs_done"].as_u64().unwrap_or(0) > 20
        });
        let third = submit(&s, SPHERE);
        // Drop sends SIGKILL: no chance to clean up.
        drop(s);
        std::fs::write(dir.path().join("third"), third).unwrap();
        (id, queued, done["progress"].clone())
    };
    let third = std::fs::read_to_string(dir.path().join("third")).unwrap();
    let stored = std::fs::read_to_string(state.join("jobs").join(&id).join("state.json")).unwrap();
    assert_eq!(json(&stored)["state"], "running");

    let s = Server::start(&state, &[]);
    // A job done before the restart shows the progress it ended with, not zeros.
    assert_eq!(job(&s, &queued)["progress"], done_progress);
    assert!(
        done_progress["faces_out"].as_u64().unwrap() > 0,
        "{done_progress}"
    );
    let last = follow(&s, &id).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
    assert_eq!(last["attempts"], 2);
    wait_for(&s, &third, "done after a restart", |v| v["state"] == "done");
    let served = output_bytes(&s, &id);

    assert_same_as_a_direct_run(dir.path(), &job_text, "gyroid.smb", &served);
}

/// A job the service keeps dying in (a run that aborts the process would) is failed once the
/// service has died in it three times, rather than run again at every start with every job
/// behind it stuck; the jobs behind it run.
#[test]
fn a_job_the_service_keeps_dying_in_is_failed_not_run_again() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let (id, behind) = {
        let s = Server::start(&state, &[]);
        let id = submit(&s, &long_job("g.smb"));
        wait_for(&s, &id, "running", |v| v["state"] == "running");
        let behind = submit(&s, SPHERE);
        // Drop sends SIGKILL.
        drop(s);
        (id, behind)
    };
    let job_dir = state.join("jobs").join(&id);
    let stored_path = job_dir.join("state.json");
    let mut stored = json(&std::fs::read_to_string(&stored_path).unwrap());
    assert_eq!(stored["state"], "running", "{stored}");
    assert_eq!(stored["crashes"], 0, "{stored}");
    // Two earlier deaths, as starts that died in this job again would have counted them.
    stored["crashes"] = 2.into();
    std::fs::write(&stored_path, stored.to_string()).unwrap();

    let s = Server::start(&state, &[]);
    let failed = job(&s, &id);
    assert_eq!(failed["state"], "failed", "{failed}");
    let error = failed["error"].as_str().unwrap_or_default();
    assert!(
        error.contains("during 3 runs") && error.contains("resubmit"),
        "{error}"
    );
    assert_eq!(
        files_in(&job_dir),
        ["job.log", "job.toml", "state.json"],
        "no partial output"
    );
    wait_for(&s, &behind, "done", |v| v["state"] == "done");
}

/// A gyroid sampled into a raw `f32` file of `n`^3 voxels (a file input that runs a few
/// seconds, for checkpoints and swaps under `--allow-input`).
fn gyroid_raw(path: &Path, n: usize) {
    let mut bytes = Vec::with_capacity(n * n * n * 4);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let [x, y, z] = [x, y, z].map(|c| c as f32 * 0.2);
                let f = x.sin() * y.cos() + y.sin() * z.cos() + z.sin() * x.cos();
                bytes.extend_from_slice(&f.to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

fn raw_job(path: &Path, n: usize, output: &str) -> String {
    format!(
        "[input]\npath = \"{}\"\ndims = [{n}, {n}, {n}]\ndtype = \"f32\"\n[extract]\niso = 0.0\n[output]\npath = \"{output}\"\n",
        path.display()
    )
}

/// An input swapped for a link out of the allowed folders after its job was admitted is not
/// followed: the job fails when it starts, naming the key.
#[cfg(unix)]
#[test]
fn an_input_replaced_by_a_link_after_submission_is_not_read() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    let input = data.join("v.raw");
    gyroid_raw(&input, 8);
    gyroid_raw(&dir.path().join("secret.raw"), 8);
    let s = Server::start(
        &dir.path().join("state"),
        &[
            "--allow-input",
            data.to_str().unwrap(),
            "--max-parallel-jobs",
            "1",
        ],
    );
    let blocker = submit(&s, &long_job("g.smb"));
    wait_for(&s, &blocker, "running", |v| v["state"] == "running");
    let id = submit(&s, &raw_job(&input, 8, "v.smb"));
    std::fs::remove_file(&input).unwrap();
    std::os::unix::fs::symlink(dir.path().join("secret.raw"), &input).unwrap();
    let (code, _) = send(agent().delete(&s.url(&format!("/jobs/{blocker}"))), None);
    assert_eq!(code, 202);
    let last = follow(&s, &id).pop().unwrap();
    assert_eq!(last["state"], "failed", "{last}");
    let error = last["error"].as_str().unwrap_or_default();
    assert!(
        error.contains("input.path") && error.contains("secret.raw") && error.contains("resubmit"),
        "{error}"
    );
}

/// A checkpoint that cannot be resumed (the input was touched after the service died) is
/// thrown away and the job starts over: a client cannot pass `--restart` to a service.
#[test]
fn a_checkpoint_of_a_touched_input_is_dropped_and_the_job_starts_over() {
    let dir = tempfile::tempdir().unwrap();
    let killed = KilledPastACheckpoint::new(dir.path(), "", |_| true);
    let (input, state, id) = (&killed.input, &killed.state, &killed.id);
    let allow = killed.allow();
    let later = std::time::SystemTime::now() + Duration::from_secs(60);
    std::fs::File::options()
        .write(true)
        .open(input)
        .unwrap()
        .set_modified(later)
        .unwrap();

    let s = Server::start(state, &allow);
    let last = follow(&s, id).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
    let view = job(&s, id);
    assert!(view["summary"]["resumed_at_slab"].is_null(), "{view}");
    assert!(s.log().contains("starting the job over"), "{}", s.log());
    let served = output_bytes(&s, id);
    assert_same_as_a_direct_run(
        dir.path(),
        &raw_job(input, 96, "gyroid.smb"),
        "gyroid.smb",
        &served,
    );
}

/// A job with a first pass (`[output] faces`) whose checkpoint cannot be resumed (its temporary
/// output is gone) also starts over: that failure comes after the first pass, whose progress
/// events are not slabs of the run.
#[test]
fn a_checkpoint_that_fails_after_a_first_pass_is_dropped_and_the_job_starts_over() {
    let dir = tempfile::tempdir().unwrap();
    let killed = KilledPastACheckpoint::new(dir.path(), "faces = 20000\n", |v| {
        v["progress"]["pass"] == "run"
    });
    let (state, id) = (&killed.state, &killed.id);
    let allow = killed.allow();
    let job_dir = state.join("jobs").join(id);
    for f in files_in(&job_dir) {
        if f.ends_with(".tmp") && !f.contains(".ckpt") {
            std::fs::remove_file(job_dir.join(f)).unwrap();
        }
    }

    let s = Server::start(state, &allow);
    let last = follow(&s, id).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
    assert!(s.log().contains("starting the job over"), "{}", s.log());
}

/// A job resumed from its checkpoint after the service died counts in `faces_in` and
/// `faces_out` only the faces its run made: the faces it restored from the checkpoint were the
/// dead service's work (its progress reports carry them in their totals, and they were
/// counted again, as if new).
#[test]
fn a_resumed_job_counts_only_the_faces_it_made() {
    let dir = tempfile::tempdir().unwrap();
    // Mode `error` writes faces as the sweep goes (from about slab 10 of this gyroid's 95): the
    // checkpoint of slab 15 or 20 holds some of both.
    let keys = "[simplify]\nmode = \"error\"\nerror = 0.5\n";
    let killed = KilledPastACheckpoint::new(dir.path(), keys, |v| {
        v["progress"]["slabs_done"].as_u64() >= Some(22)
    });
    let s = Server::start(&killed.state, &killed.allow());
    let last = follow(&s, &killed.id).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
    let summary = &job(&s, &killed.id)["summary"];
    assert!(
        summary["resumed_at_slab"].as_u64().is_some_and(|z| z > 0),
        "{summary}"
    );
    let (_, metrics) = send(agent().get(&s.url("/metrics")), None);
    let counted = |name: &str| -> u64 {
        let line = metrics
            .lines()
            .find(|l| l.starts_with(&format!("isostream_{name}_total ")))
            .unwrap_or_else(|| panic!("{name} missing:\n{metrics}"));
        line.rsplit(' ').next().unwrap().parse().unwrap()
    };
    for (name, total) in [
        ("faces_in", "faces_extracted"),
        ("faces_out", "faces_written"),
    ] {
        let total = summary[total].as_u64().unwrap();
        let counted = counted(name);
        assert!(
            counted > 0 && counted < total,
            "{name}: {counted} counted of the run's {total}\n{metrics}"
        );
    }
}

/// A service killed (SIGKILL) while running a checkpointed gyroid job (96^3, a checkpoint every
/// 5 slabs) once a checkpoint was saved and `also` holds of the job's view.
struct KilledPastACheckpoint {
    data: PathBuf,
    input: PathBuf,
    state: PathBuf,
    id: String,
}

impl KilledPastACheckpoint {
    /// `output_keys`: lines added to the job's `[output]` table.
    fn new(dir: &Path, output_keys: &str, also: impl Fn(&Value) -> bool) -> Self {
        let data = dir.join("data");
        std::fs::create_dir(&data).unwrap();
        let input = data.join("gyroid.raw");
        gyroid_raw(&input, 96);
        let state = dir.join("state");
        let job_text = format!(
            "{}{output_keys}[pipeline]\ncheckpoint = {{ every_slabs = 5 }}\n",
            raw_job(&input, 96, "gyroid.smb")
        );
        let s = Server::start(&state, &["--allow-input", data.to_str().unwrap()]);
        let id = submit(&s, &job_text);
        let job_dir = state.join("jobs").join(&id);
        let saved = || files_in(&job_dir).iter().any(|f| f.ends_with(".ckpt"));
        wait_for(&s, &id, "past a checkpoint", |v| {
            v["state"] == "running" && also(v) && saved()
        });
        // Drop sends SIGKILL.
        drop(s);
        KilledPastACheckpoint {
            data,
            input,
            state,
            id,
        }
    }

    fn allow(&self) -> [&str; 2] {
        ["--allow-input", self.data.to_str().unwrap()]
    }
}

/// After the service died with two jobs running, both count the death and run one at a time,
/// so a job that brings the service down again is the only one blamed.
#[test]
fn jobs_running_when_the_service_died_run_alone_afterwards() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let two = ["--max-parallel-jobs", "2"];
    let ids = {
        let s = Server::start(&state, &two);
        let ids = [
            submit(&s, &long_job("a.smb")),
            submit(&s, &long_job("b.smb")),
        ];
        for id in &ids {
            wait_for(&s, id, "running", |v| v["state"] == "running");
        }
        // Drop sends SIGKILL.
        drop(s);
        ids
    };
    let s = Server::start(&state, &two);
    let started = Instant::now();
    loop {
        // One snapshot of both (two requests one after the other saw the first job still
        // running and the second already started, when the first ended between them).
        let (status, body) = send(agent().get(&s.url("/jobs")), None);
        assert_eq!(status, 200, "{body}");
        let listed = json(&body);
        let views = ids.clone().map(|id| {
            listed["jobs"]
                .as_array()
                .and_then(|jobs| jobs.iter().find(|j| j["id"] == id.as_str()))
                .cloned()
                .unwrap_or_else(|| panic!("{id} not listed: {body}"))
        });
        assert!(views.iter().all(|v| v["crashes"] == 1), "{views:?}");
        let running = views.iter().filter(|v| v["state"] == "running").count();
        assert!(running <= 1, "both ran at once: {views:?}");
        if views.iter().all(|v| v["state"] == "done") {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(120), "{views:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Runs `job_text` with `isostream run` in `dir` and compares its output `name` with `served`.
fn assert_same_as_a_direct_run(dir: &Path, job_text: &str, name: &str, served: &[u8]) {
    let job_file = dir.join("direct.toml");
    std::fs::write(&job_file, job_text).unwrap();
    let run = isostream(&["run", "--quiet", &job_file.to_string_lossy()]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let direct = std::fs::read(dir.join(name)).unwrap();
    assert!(
        served == direct,
        "{} vs {} bytes",
        served.len(),
        direct.len()
    );
}

/// Issue 12 with issue 11: a job that saves checkpoints, killed with the service mid-run,
/// continues from its last checkpoint on the next start (not from the beginning) and writes the
/// same bytes as an uninterrupted run.
#[test]
fn a_job_killed_with_the_service_resumes_from_its_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let job_text = format!(
        "{}\n[pipeline]\ncheckpoint = {{ every_slabs = 5 }}\n",
        long_job("gyroid.ply")
    );
    let id = {
        let s = Server::start(&state, &[]);
        let id = submit(&s, &job_text);
        let job_dir = state.join("jobs").join(&id);
        let saved = || files_in(&job_dir).iter().any(|f| f.ends_with(".ckpt"));
        wait_for(&s, &id, "past a few checkpoints", |v| {
            v["state"] == "running"
                && v["progress"]["slabs_done"].as_u64().unwrap_or(0) > 30
                && saved()
        });
        // Drop sends SIGKILL: no chance to clean up.
        drop(s);
        id
    };
    let job_dir = state.join("jobs").join(&id);
    assert!(
        files_in(&job_dir).iter().any(|f| f.ends_with(".ckpt")),
        "{:?}",
        files_in(&job_dir)
    );

    let s = Server::start(&state, &[]);
    let last = follow(&s, &id).pop().unwrap();
    assert_eq!(last["state"], "done", "{last}\n{}", s.log());
    assert_eq!(last["attempts"], 2);
    let view = job(&s, &id);
    let resumed = view["summary"]["resumed_at_slab"].as_u64();
    assert!(resumed.is_some_and(|z| z >= 5), "{view}\n{}", s.log());
    assert!(
        !files_in(&job_dir).iter().any(|f| f.starts_with('.')),
        "{:?}",
        files_in(&job_dir)
    );
    let served = output_bytes(&s, &id);
    // Without checkpoints: the bytes do not depend on them either.
    assert_same_as_a_direct_run(dir.path(), &long_job("gyroid.ply"), "gyroid.ply", &served);
}

/// A relative `--state` (the default `./isostream-state` is one) is made absolute at start:
/// the outputs stored in the jobs stay in their job folders when the service is restarted from
/// another working directory, and a job stored by an older service with an output relative to
/// its working directory is put back into its folder too.
#[test]
fn a_relative_state_folder_survives_a_restart_from_another_folder() {
    let dir = tempfile::tempdir().unwrap();
    let (first_cwd, second_cwd) = (dir.path().join("a"), dir.path().join("b"));
    std::fs::create_dir(&first_cwd).unwrap();
    std::fs::create_dir(&second_cwd).unwrap();
    let (running, queued) = {
        let s = Server::start_in(&first_cwd, Path::new("st"), &[]);
        let running = submit(&s, &long_job("g.smb"));
        wait_for(&s, &running, "running", |v| v["state"] == "running");
        let queued = submit(&s, SPHERE);
        // Drop sends SIGKILL: the running job runs again at the next start.
        drop(s);
        (running, queued)
    };
    let state = first_cwd.join("st").canonicalize().unwrap();
    let job_file = |id: &str| state.join("jobs").join(id).join("job.toml");
    let stored = std::fs::read_to_string(job_file(&running)).unwrap();
    let absolute = state.join("jobs").join(&running).join("output.smb");
    assert!(
        stored.contains(&format!("path = \"{}\"", absolute.display())),
        "{stored}"
    );
    // What an older service stored: the output relative to its working directory.
    let stored = std::fs::read_to_string(job_file(&queued)).unwrap();
    let absolute = state.join("jobs").join(&queued).join("output.smb");
    let relative = format!("st/jobs/{queued}/output.smb");
    std::fs::write(
        job_file(&queued),
        stored.replace(&absolute.display().to_string(), &relative),
    )
    .unwrap();
    assert!(
        std::fs::read_to_string(job_file(&queued))
            .unwrap()
            .contains(&relative)
    );

    let s = Server::start_in(&second_cwd, &state, &[]);
    for id in [&running, &queued] {
        let done = wait_for(&s, id, "done", |v| v["state"] == "done");
        let output = state.join("jobs").join(id).join("output.smb");
        assert_eq!(
            done["summary"]["output"].as_str(),
            Some(output.to_str().unwrap()),
            "{done}"
        );
        assert_eq!(output_bytes(&s, id), std::fs::read(&output).unwrap());
        let (code, body) = send(agent().get(&s.url(&format!("/jobs/{id}/report"))), None);
        assert_eq!(code, 200, "{body}");
    }
    assert_eq!(
        files_in(&second_cwd),
        Vec::<String>::new(),
        "nothing written elsewhere"
    );
}

/// After a first pass (`[output] faces`), the view says when the run's first slab came, and
/// its ETA (`eta_s`) paces from there: from the job's start, a 78 s job with a first pass
/// promised 15 minutes. A job without a first pass has no such field (its run starts with the
/// job). The service works the ETA out (the status page computed its own, by the slabs alone):
/// absent in the first pass and once the job is done, there once the run has slabs to pace by.
#[test]
fn after_a_first_pass_the_view_says_when_the_run_began() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    let input = data.join("gyroid.raw");
    gyroid_raw(&input, 96);
    let state = dir.path().join("state");
    let s = Server::start(&state, &["--allow-input", data.to_str().unwrap()]);
    let with_pass = submit(
        &s,
        &format!("{}faces = 20000\n", raw_job(&input, 96, "gyroid.smb")),
    );
    let seen = wait_for(&s, &with_pass, "the run's slabs", |v| {
        let p = &v["progress"];
        if v["state"] == "running" && p["pass"] == "first" {
            assert!(p.get("eta_s").is_none(), "{v}");
        }
        // Past the run's first reported slab: one to pace by.
        let began = p["run_started_slab"].as_u64();
        v["state"] == "done" || began.is_some_and(|b| p["slabs_done"].as_u64() > Some(b))
    });
    if seen["state"] == "running" {
        let p = &seen["progress"];
        let began = p["run_started_unix_ms"]
            .as_u64()
            .unwrap_or_else(|| panic!("{seen}"));
        assert!(began >= seen["started_unix_ms"].as_u64().unwrap(), "{seen}");
        assert!(p["run_started_slab"].as_u64().unwrap() < p["slabs_done"].as_u64().unwrap());
        assert!(p["eta_s"].as_f64().is_some_and(|s| s >= 0.0), "{seen}");
    }
    let done = wait_for(&s, &with_pass, "done", |v| v["state"] == "done");
    assert!(done["progress"].get("eta_s").is_none(), "{done}");
    let without = submit(&s, &long_job("a.smb"));
    let running = wait_for(&s, &without, "running slabs", |v| {
        v["state"] == "done" || v["progress"]["slabs_done"].as_u64().unwrap_or(0) > 0
    });
    assert!(
        running["progress"].get("run_started_unix_ms").is_none(),
        "{running}"
    );
    if running["state"] == "running" {
        assert!(running["progress"]["eta_s"].as_f64().is_some(), "{running}");
    }
}

/// With its stderr a closed pipe (`isostream serve 2>&1 | head -1`, `head` gone), the service
/// still runs jobs and stops on SIGTERM: tracing-subscriber's report of the failed log write
/// panicked (`eprintln!` on the closed pipe), and the service then ignored SIGTERM for good.
#[test]
fn a_service_whose_stderr_is_gone_runs_jobs_and_stops_on_sigterm() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = Server::start_with_stderr_closed(&dir.path().join("state"));
    let id = submit(&s, SPHERE);
    wait_for(&s, &id, "done", |v| v["state"] == "done");
    let term = Command::new("kill")
        .args(["-TERM", &s.child.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = s.child.try_wait().unwrap() {
            break status;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "still running 20 s after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status}");
}
