//! The durable part of the queue: one folder per job under `STATE/jobs/`.
//!
//! `job.toml` is written once at submission; `state.json` is rewritten at every change of state,
//! always through a temporary file, fsync and rename, so a crash leaves either the old or the new
//! state, never a torn one. A folder without `state.json` is a submission that never completed
//! (its 201 was never sent) and is removed at start-up.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use tracing::warn;

use crate::error::ServiceError;

const JOB_FILE: &str = "job.toml";
const STATE_FILE: &str = "state.json";

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum JobState {
    Queued,
    Running,
    Done,
    Failed,
    Cancelled,
}

impl JobState {
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Done,
        JobState::Failed,
        JobState::Cancelled,
    ];

    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobState::Done | JobState::Failed | JobState::Cancelled
        )
    }

    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }
}

/// What `state.json` holds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct JobRecord {
    pub id: String,
    /// Submission order; the queue runs jobs in this order.
    pub seq: u64,
    pub state: JobState,
    pub submitted_unix_ms: u64,
    pub started_unix_ms: Option<u64>,
    pub finished_unix_ms: Option<u64>,
    /// How many times a run was started (more than 1 after a restart interrupted one).
    pub attempts: u32,
    /// Runs of this job found still running at a start of the service: the service died
    /// during them (a crash, `kill -9`, a power cut) rather than stopping them itself.
    #[serde(default)]
    pub crashes: u32,
    /// A `DELETE` asked this running job to stop. Written before its run is told to, so that
    /// a restart finds the job cancelled, as its client was told, even if the end of the run
    /// could not be recorded (the service died, or the disk was full).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub cancel_requested: bool,
    /// The output's file name in the job folder (`output.smb`, ...).
    pub output: String,
    /// The one-line error of a failed run.
    pub error: Option<String>,
    /// The pipeline's run summary of a finished run.
    pub summary: Option<serde_json::Value>,
}

impl JobRecord {
    /// A job just submitted, waiting in the queue.
    pub(crate) fn queued(id: String, seq: u64, output: String) -> Self {
        Self {
            id,
            seq,
            state: JobState::Queued,
            submitted_unix_ms: now_ms(),
            started_unix_ms: None,
            finished_unix_ms: None,
            attempts: 0,
            crashes: 0,
            cancel_requested: false,
            output,
            error: None,
            summary: None,
        }
    }
}

pub(crate) fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

#[derive(Debug)]
pub(crate) struct Store {
    /// The state folder, canonical (see [`Store::open`]).
    root: PathBuf,
    jobs: PathBuf,
    /// Held for the store's life: two services on one state folder would run the same jobs and
    /// overwrite each other's states. The OS drops the lock when the process dies, even by
    /// `kill -9`, so a restart is never blocked by a stale lock.
    _lock: std::fs::File,
}

impl Store {
    /// Opens (creating it when missing) and locks the state folder, made canonical once here:
    /// every path the service stores or uses (the output in each `job.toml`, the run summary's)
    /// is then absolute. A relative `--state` (the default `./isostream-state`) was stored as
    /// given, so a service restarted from another working directory wrote the outputs of the
    /// jobs it resumed under that directory, outside their job folders.
    pub fn open(state_dir: &Path) -> Result<Self, ServiceError> {
        let fail = |e: std::io::Error| ServiceError::State {
            path: state_dir.to_path_buf(),
            reason: e.to_string(),
        };
        std::fs::create_dir_all(state_dir.join("jobs")).map_err(fail)?;
        let root = state_dir.canonicalize().map_err(fail)?;
        let jobs = root.join("jobs");
        // Probe writability now rather than at the first submission, with a file without a
        // name (see `pipeline`'s output probe): a named one was left in `jobs/` by a `kill -9`.
        tempfile::tempfile_in(&jobs).map_err(fail)?;
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(root.join("lock"))
            .map_err(fail)?;
        // `flock` (std's `File::try_lock`, as the run's output lock): the OS drops it when the
        // process dies, even by `kill -9`.
        match lock.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(ServiceError::StateInUse {
                    path: state_dir.to_path_buf(),
                });
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(fail(e)),
        }
        Ok(Self {
            root,
            jobs,
            _lock: lock,
        })
    }

    /// The state folder, absolute and canonical.
    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn job_dir(&self, id: &str) -> PathBuf {
        self.jobs.join(id)
    }

    /// Creates the job's folder with its job file and first state.
    /// A submission that cannot be stored whole (a full disk) leaves no folder behind.
    pub fn create(&self, record: &JobRecord, job_toml: &str) -> std::io::Result<()> {
        let dir = self.job_dir(&record.id);
        std::fs::create_dir_all(&dir)?;
        write_atomic(&dir.join(JOB_FILE), job_toml.as_bytes())
            .and_then(|()| self.save(record))
            .inspect_err(|_| {
                let _ = std::fs::remove_dir_all(&dir);
            })
    }

    pub fn save(&self, record: &JobRecord) -> std::io::Result<()> {
        let bytes = serde_json::to_vec_pretty(record).map_err(std::io::Error::other)?;
        write_atomic(&self.job_dir(&record.id).join(STATE_FILE), &bytes)
    }

    /// Removes the job's folder. Its state goes first, and decides: a folder without one is not
    /// a job, and [`Store::load_all`] removes it at the next start, so a crash or a failure in
    /// the middle of the removal never brings the job back, and the error says which side of
    /// that step it happened on. A state already gone (by hand) keeps nothing from going.
    pub fn remove(&self, id: &str) -> Result<(), RemoveError> {
        let dir = self.job_dir(id);
        match std::fs::remove_file(dir.join(STATE_FILE)) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(RemoveError::Kept(e)),
            _ => {}
        }
        std::fs::remove_dir_all(&dir).map_err(|source| RemoveError::Leftover { dir, source })
    }

    /// Removes everything but the job file, the state, the log and `keep` (a checkpoint and its
    /// files, which the next run resumes from): the output, its summary and any temporary file a
    /// killed run left behind.
    pub fn clear_outputs(&self, id: &str, keep: &[PathBuf]) -> std::io::Result<()> {
        for entry in std::fs::read_dir(self.job_dir(id))? {
            let entry = entry?;
            let name = entry.file_name();
            let kept = keep.iter().any(|k| k.file_name() == Some(name.as_os_str()));
            if name != JOB_FILE && name != STATE_FILE && name != crate::joblog::LOG_FILE && !kept {
                std::fs::remove_file(entry.path())?;
            }
        }
        Ok(())
    }

    /// Every stored job (record and job file), in submission order. Unreadable folders are
    /// logged and skipped so that one damaged job does not keep the service down.
    pub fn load_all(&self) -> Vec<(JobRecord, String)> {
        let mut out = Vec::new();
        let entries = match std::fs::read_dir(&self.jobs) {
            Ok(e) => e,
            Err(e) => {
                warn!(dir = %self.jobs.display(), error = %e, "cannot list stored jobs");
                return out;
            }
        };
        for entry in entries.flatten() {
            let dir = entry.path();
            if !dir.is_dir() {
                continue;
            }
            let state = dir.join(STATE_FILE);
            if !dir
                .file_name()
                .and_then(|n| n.to_str())
                .is_some_and(is_job_id)
            {
                // Not a folder this service made: `--state` may name a folder already in use.
                warn!(dir = %dir.display(), "skipping a folder that is not a job's");
                continue;
            }
            if !state.exists() {
                // A submission or a removal that did not complete.
                warn!(dir = %dir.display(), "removing a job folder without a state");
                if let Err(e) = std::fs::remove_dir_all(&dir) {
                    warn!(dir = %dir.display(), error = %e, "cannot remove it");
                }
                continue;
            }
            let loaded = std::fs::read(&state)
                .map_err(|e| e.to_string())
                .and_then(|b| serde_json::from_slice::<JobRecord>(&b).map_err(|e| e.to_string()))
                .and_then(|r| {
                    std::fs::read_to_string(dir.join(JOB_FILE))
                        .map(|t| (r, t))
                        .map_err(|e| e.to_string())
                });
            match loaded {
                Ok((record, _))
                    if Some(record.id.as_str()) != dir.file_name().and_then(|n| n.to_str()) =>
                {
                    warn!(dir = %dir.display(), "skipping a job whose state names another id");
                }
                Ok(job) => out.push(job),
                Err(e) => warn!(dir = %dir.display(), error = %e, "skipping an unreadable job"),
            }
        }
        out.sort_by_key(|(r, _)| r.seq);
        out
    }
}

/// Why [`Store::remove`] did not remove a job whole.
#[derive(Debug, thiserror::Error)]
pub(crate) enum RemoveError {
    /// Its state file is still there: nothing was removed, the job is as it was.
    #[error("cannot remove its state file: {0}")]
    Kept(std::io::Error),
    /// Its state file is gone, hence the job, but not the whole of its folder: the next start
    /// removes what is left.
    #[error("its folder {} was not deleted whole ({source}); the service deletes what is left at its next start", dir.display())]
    Leftover {
        dir: PathBuf,
        source: std::io::Error,
    },
}

/// Whether `name` is a job id as the service makes them (`http::new_id`: 32 hexadecimal
/// digits, lower case): only such folders are the service's to remove.
pub(crate) fn is_job_id(name: &str) -> bool {
    name.len() == 32
        && name
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Temporary file in the same folder, fsync, rename: readers see the old or the new bytes.
fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut tmp = tempfile::Builder::new()
        .prefix(".state.")
        .suffix(".tmp")
        .tempfile_in(dir)?;
    tmp.write_all(bytes)?;
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(id: &str, seq: u64) -> JobRecord {
        JobRecord::queued(id.into(), seq, "output.smb".into())
    }

    const AA: &str = "aa000000000000000000000000000000";
    const BB: &str = "bb000000000000000000000000000000";

    #[test]
    fn jobs_survive_a_reopen_in_submission_order() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        store.create(&record(BB, 2), "b = 1").unwrap();
        store.create(&record(AA, 1), "a = 1").unwrap();
        let mut r = record(BB, 2);
        r.state = JobState::Running;
        store.save(&r).unwrap();
        std::fs::write(store.job_dir(BB).join(".output.smb.x.tmp"), b"half").unwrap();
        store.clear_outputs(BB, &[]).unwrap();
        let half_made = "cc000000000000000000000000000000";
        std::fs::create_dir(store.job_dir(half_made)).unwrap();
        // Not the service's: a `--state` folder that was in use before must keep its files.
        let theirs = store.job_dir("my-project").join("src");
        std::fs::create_dir_all(&theirs).unwrap();
        std::fs::write(theirs.join("thesis.tex"), b"precious").unwrap();

        let err = Store::open(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains("another isostream serve") && !err.contains("writable"),
            "{err}"
        );
        drop(store);
        let store = Store::open(dir.path()).unwrap();
        let loaded = store.load_all();
        let ids: Vec<_> = loaded.iter().map(|(r, _)| r.id.as_str()).collect();
        assert_eq!(ids, [AA, BB]);
        assert_eq!(loaded[1].0.state, JobState::Running);
        assert_eq!(loaded[0].1, "a = 1");
        assert!(!store.job_dir(half_made).exists());
        assert_eq!(
            std::fs::read(theirs.join("thesis.tex")).unwrap(),
            b"precious"
        );
        let left: Vec<_> = std::fs::read_dir(store.job_dir(BB)).unwrap().collect();
        assert_eq!(left.len(), 2, "only job.toml and state.json stay");
    }

    #[test]
    fn the_state_folder_is_made_canonical() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("made")).unwrap();
        let store = Store::open(&dir.path().join("made/../state")).unwrap();
        let root = dir.path().canonicalize().unwrap().join("state");
        assert_eq!(store.root(), root);
        assert_eq!(store.job_dir(AA), root.join("jobs").join(AA));
    }

    #[test]
    fn job_ids_are_what_the_service_makes() {
        assert!(is_job_id(AA));
        for not in [
            "aa",
            "my-project",
            "AA000000000000000000000000000000",
            "../aa0000000000000000000000000000",
        ] {
            assert!(!is_job_id(not), "{not}");
        }
    }
}
