//! The job table, the scheduler and the runs.
//!
//! One mutex guards the table; every change of a job's state is written to its `state.json`
//! (see `store`) before it is published to watchers, so what a client saw is what a restart finds.
//! Runs happen on tokio's blocking threads through `isostream_pipeline::run`, which spawns its own
//! stage threads and knows nothing of tokio; progress comes back through its observer and is
//! published on a `watch` channel per job (the latest value is all a watcher needs, so a slow
//! client can never hold the run back).

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use isostream_pipeline::{
    Done, JobConfig, Pass, Progress, RunError, RunSummary, Start, eta_seconds,
};
use serde::Serialize;
use tokio::sync::{Notify, watch};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;
use tracing::{Instrument, error, info, info_span, warn};

use crate::admission::{self, Admitted};
use crate::metrics::{Metrics, Snapshot};
use crate::store::{JobRecord, JobState, RemoveError, Store, now_ms};

/// Progress of a run as clients see it (the pipeline's `Progress` without its channel details).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub(crate) struct ProgressView {
    /// `first` during the first pass of `[output] faces` or pruning (its slabs; no faces yet),
    /// then `run`.
    pub pass: Pass,
    pub slabs_done: u64,
    pub slabs_total: u64,
    /// Slabs done before this attempt (a run resumed from a checkpoint starts past 0):
    /// the ETA paces by the slabs done since, over the time since `started_unix_ms`
    /// (counting the checkpoint's slabs too promised 10 s of 40).
    pub slabs_at_start: u64,
    /// After a first pass: when the run's first progress came (the report it sends as it
    /// begins; the service's clock, Unix ms) and the slabs done then. The ETA paces from there: from the job's start, the first
    /// pass's seconds counted as the run's (a 78 s job promised 15 minutes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub run_started_unix_ms: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub run_started_slab: Option<u64>,
    pub faces_in: u64,
    pub faces_out: u64,
    /// The run's faces as the ETA paces by them, when a first pass counted them
    /// ([`Progress::faces_done`]), from where its pace starts: the run's first report after a
    /// first pass, as the slabs (`run_started_slab`).
    #[serde(skip)]
    faces: Option<Done>,
    pub resident_faces: u64,
    /// Seconds left in a running job's run, by the command line's estimate ([`eta_seconds`]):
    /// the status page computed its own from the slabs, and promised a surface mid-volume's end
    /// long before it. Worked out when the job is viewed (`view_of`), as its time goes on (a
    /// `GET` afresh, an event as of its slab); `None` in the table, and before the run has a
    /// pace.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eta_s: Option<f64>,
}

impl ProgressView {
    /// A finished run's progress, read back from its summary (a restarted service showed the
    /// done jobs it loaded at zero).
    fn of_summary(summary: &serde_json::Value) -> Self {
        let count = |key: &str| summary[key].as_u64().unwrap_or(0);
        let slabs = summary["dims"][2]
            .as_u64()
            .map_or(0, |nz| nz.saturating_sub(1));
        Self {
            pass: Pass::Run,
            slabs_done: slabs,
            slabs_total: slabs,
            slabs_at_start: 0,
            run_started_unix_ms: None,
            run_started_slab: None,
            faces_in: count("faces_extracted"),
            faces_out: count("faces_written"),
            faces: None,
            resident_faces: 0,
            eta_s: None,
        }
    }

    /// Seconds left in the run of a job whose attempt started at `started_unix_ms`, `now_ms`
    /// (both the service's clock); `None` in a first pass, whose end is not the job's, and
    /// before the run has done anything to pace by.
    fn eta_s(&self, started_unix_ms: Option<u64>, now_ms: u64) -> Option<f64> {
        if self.pass != Pass::Run {
            return None;
        }
        let since = self.run_started_unix_ms.or(started_unix_ms)?;
        let slabs = Done {
            start: self.run_started_slab.unwrap_or(self.slabs_at_start),
            now: self.slabs_done,
            total: self.slabs_total,
        };
        eta_seconds(
            now_ms.saturating_sub(since) as f64 / 1000.0,
            slabs,
            self.faces,
        )
    }
}

/// Whether `p` reports a slab of the run done: an error before one is one of resuming (loading
/// and checking the checkpoint, reopening its files, and the first batch's check that the slice
/// it carried still holds the same values; the first pass comes before them), which a restart
/// may cure. The report a run sends as it begins has no slab done past its start: counted, an
/// input changed within the checkpoint's slice failed the job instead of starting it over.
fn did_a_slab(p: &Progress) -> bool {
    p.pass == Pass::Run && p.slabs_done > p.slabs_at_start
}

impl From<&Progress> for ProgressView {
    fn from(p: &Progress) -> Self {
        Self {
            pass: p.pass,
            slabs_done: p.slabs_done,
            slabs_total: p.slabs_total,
            slabs_at_start: p.slabs_at_start,
            run_started_unix_ms: None,
            run_started_slab: None,
            faces_in: p.faces_in,
            faces_out: p.faces_out,
            faces: p.faces_done(),
            resident_faces: p.resident_faces,
            eta_s: None,
        }
    }
}

/// A job as `GET /jobs/{id}` and the event stream show it.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct JobView {
    #[serde(flatten)]
    pub record: JobRecord,
    pub url: String,
    /// Present once the job is done.
    pub output_url: Option<String>,
    /// The run report with plots; present once the job is done.
    pub report_url: Option<String>,
    pub progress: ProgressView,
}

struct Job {
    record: JobRecord,
    /// What to run; dropped once the job is final, since it will never run again.
    config: Option<Arc<JobConfig>>,
    progress: ProgressView,
    cancel: Arc<AtomicBool>,
    events: watch::Sender<JobView>,
}

impl Job {
    fn new(record: JobRecord, config: Option<Arc<JobConfig>>) -> Self {
        let progress = ProgressView::default();
        Job {
            events: watch::channel(view_of(&record, progress)).0,
            record,
            config,
            progress,
            cancel: Arc::new(AtomicBool::new(false)),
        }
    }

    fn view(&self) -> JobView {
        view_of(&self.record, self.progress)
    }

    fn publish(&self) {
        self.events.send_replace(self.view());
    }

    /// Makes `change` to a copy of the record, writes that to the job's `state.json`, and only
    /// then makes it the job's and publishes it: a write that fails (the state folder's disk
    /// full or unwritable) leaves the job as it was, in memory as on disk, so what a client saw
    /// is what a restart finds. A job that turns final drops its config: it never runs again.
    fn change(
        &mut self,
        store: &Store,
        change: impl FnOnce(&mut JobRecord),
    ) -> std::io::Result<()> {
        let mut record = self.record.clone();
        change(&mut record);
        store.save(&record)?;
        if record.state.is_final() {
            self.config = None;
        }
        self.record = record;
        self.publish();
        Ok(())
    }
}

fn view_of(record: &JobRecord, progress: ProgressView) -> JobView {
    let url = format!("/jobs/{}", record.id);
    JobView {
        output_url: (record.state == JobState::Done).then(|| format!("{url}/output")),
        report_url: (record.state == JobState::Done).then(|| format!("{url}/report")),
        url,
        record: record.clone(),
        progress: ProgressView {
            eta_s: (record.state == JobState::Running)
                .then(|| progress.eta_s(record.started_unix_ms, now_ms()))
                .flatten(),
            ..progress
        },
    }
}

#[derive(Default)]
struct Table {
    jobs: HashMap<String, Job>,
    /// Ids in submission order.
    order: Vec<String>,
    running: usize,
    next_seq: u64,
}

impl Table {
    /// The job whose run is `id`'s: only a finished job leaves the table (`Queue::delete`),
    /// and a running one is finished by its run alone, once its end is written.
    fn running_job(&mut self, id: &str) -> &mut Job {
        self.jobs
            .get_mut(id)
            .expect("a running job stays in the table until its end is written")
    }
}

/// What `DELETE /jobs/{id}` did.
pub(crate) enum DeleteOutcome {
    /// The job was queued and is now cancelled.
    Cancelled(JobView),
    /// The job is running; its run stops at the next slice (or within milliseconds in the
    /// simplifier's passes and final decimation) and it then becomes `cancelled`.
    Stopping(JobView),
    /// The job had finished (done, failed or cancelled): it and its folder, output included,
    /// are gone, but for the files `leftover` says could not be deleted (the next start does).
    Removed {
        leftover: Option<String>,
    },
    NotFound,
}

/// Runs of one job the service may die in before the job is failed rather than run again: a
/// job that aborts the process (memory exhausted, a bug) would otherwise bring the service down
/// at every start, and with it every job queued behind it. A host's reboot or one `kill -9`
/// during a long run is survived. Every job found running counts a death; from its first on, a
/// job runs alone (`Queue::start_ready`), so its later deaths are its own, and the jobs that
/// only ran beside it once finish.
const MAX_CRASHES: u32 = 3;

/// How long a change of state that could not be written (the state folder's disk full or
/// unwritable) waits before it is tried again: a long-running service outlives a full disk, so
/// the change is made once the disk takes it rather than given up, and a small write every few
/// seconds costs nothing meanwhile.
const STATE_RETRY: std::time::Duration = std::time::Duration::from_secs(5);

/// Whether [`Queue::start_ready`] started what it could, or stopped at a job whose state
/// could not be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Starts {
    Started,
    WaitForDisk,
}

/// How a run ended, as its job's record says once that is written ([`Queue::finish`]).
struct RunEnd {
    state: JobState,
    finished_unix_ms: Option<u64>,
    /// The one-line error of a failed run.
    error: Option<String>,
    /// The run summary of a done one.
    summary: Option<serde_json::Value>,
}

impl RunEnd {
    fn apply(&self, record: &mut JobRecord) {
        record.state = self.state;
        record.finished_unix_ms = self.finished_unix_ms;
        record.error.clone_from(&self.error);
        record.summary.clone_from(&self.summary);
    }
}

/// How many jobs may run, and wait, at once.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Limits {
    pub running: usize,
    pub queued: usize,
}

/// Why a submission was not stored.
#[derive(Debug)]
pub(crate) enum SubmitError {
    /// [`Limits::queued`] jobs are waiting already.
    Full(usize),
    Io(std::io::Error),
}

pub(crate) struct Queue {
    table: Mutex<Table>,
    store: Store,
    /// The `--allow-input` folders, checked again when a run starts (see [`Queue::run`]).
    roots: Arc<admission::Roots>,
    wake: Notify,
    limits: Limits,
    metrics: Arc<Metrics>,
    shutdown: CancellationToken,
    runs: TaskTracker,
    /// Cancelled once [`Queue::drain`] is over: every run has stopped and its job is as saved
    /// for the next start.
    drained: CancellationToken,
}

impl Queue {
    /// Loads the stored jobs: queued ones stay queued, one that was running is queued again (its
    /// partial output removed) unless its run had completed ([`completed_run`]), finished ones
    /// are kept for clients to read.
    pub fn recover(
        store: Store,
        roots: Arc<admission::Roots>,
        limits: Limits,
        metrics: Arc<Metrics>,
        shutdown: CancellationToken,
    ) -> Arc<Self> {
        let mut table = Table::default();
        for (mut record, text) in store.load_all() {
            if record.state == JobState::Running
                && let Some((summary, ended)) =
                    completed_run(&store.job_dir(&record.id), &record.output)
            {
                // Its run completed, but its end was not written: done, as it would have been
                // shown (even with a cancel requested: the run finished before it was heard).
                info!(id = %record.id, "a job whose end was not written had completed: done");
                record.state = JobState::Done;
                record.summary = Some(summary);
                record.finished_unix_ms = Some(ended);
                // A finished-run record the run did not get to remove (its last step) has
                // served: the output and its summary are what a done job keeps.
                let output = store.job_dir(&record.id).join(&record.output);
                let summary = isostream_pipeline::summary_path(&output);
                if let Err(e) = store.clear_outputs(&record.id, &[output, summary]) {
                    warn!(id = %record.id, error = %e, "cannot remove the finished run's checkpoint");
                }
            }
            if record.state == JobState::Running && record.cancel_requested {
                // Cancelled by a client (`Queue::delete` wrote that first), and the service
                // stopped before the end of the run was recorded: cancelled, as it was told.
                info!(id = %record.id, "a job cancelled while running stays cancelled");
                record.state = JobState::Cancelled;
                record.finished_unix_ms = Some(now_ms());
                if let Err(e) = store.clear_outputs(&record.id, &[]) {
                    warn!(id = %record.id, error = %e, "cannot remove the partial output");
                }
            }
            let mut config = None;
            if !record.state.is_final() {
                match admission::reload(&text, &store.job_dir(&record.id)) {
                    Ok(job) => config = Some(Arc::new(job)),
                    Err(e) => {
                        warn!(id = %record.id, error = %e, "stored job no longer valid");
                        record.state = JobState::Failed;
                        record.error = Some(e);
                        record.finished_unix_ms = Some(now_ms());
                    }
                }
            }
            if record.state == JobState::Running {
                // The service died during this run (its own stop requeues what it interrupts).
                record.crashes += 1;
                if record.crashes >= MAX_CRASHES {
                    warn!(id = %record.id, crashes = record.crashes, "not running again a job the service died in");
                    record.state = JobState::Failed;
                    record.error = Some(format!(
                        "the service stopped abnormally (crash, kill -9 or power cut) during {} runs of this job, so it is not run again: see the service's log around each start of it, and resubmit once the cause is fixed",
                        record.crashes
                    ));
                    record.finished_unix_ms = Some(now_ms());
                    config = None;
                } else {
                    info!(id = %record.id, "restarting a job interrupted while running (from its checkpoint if it saved one)");
                    record.state = JobState::Queued;
                }
                if let Err(e) = store.clear_outputs(&record.id, &resumable(config.as_deref())) {
                    warn!(id = %record.id, error = %e, "cannot remove the partial output");
                }
            }
            if let Err(e) = store.save(&record) {
                warn!(id = %record.id, error = %e, "cannot write the job state");
            }
            table.next_seq = table.next_seq.max(record.seq + 1);
            table.order.push(record.id.clone());
            let mut job = Job::new(record, config);
            if let (JobState::Done, Some(summary)) = (job.record.state, &job.record.summary) {
                job.progress = ProgressView::of_summary(summary);
                job.publish();
            }
            table.jobs.insert(job.record.id.clone(), job);
        }
        let queued = table
            .jobs
            .values()
            .filter(|j| j.record.state == JobState::Queued)
            .count();
        info!(jobs = table.order.len(), queued, "state loaded");
        Arc::new(Queue {
            table: Mutex::new(table),
            store,
            roots,
            wake: Notify::new(),
            limits,
            metrics,
            shutdown,
            runs: TaskTracker::new(),
            drained: CancellationToken::new(),
        })
    }

    fn lock(&self) -> MutexGuard<'_, Table> {
        // A panic while holding the lock leaves plain data behind; keep serving it.
        self.table.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn job_dir(&self, id: &str) -> std::path::PathBuf {
        self.store.job_dir(id)
    }

    /// Stores and queues an admitted job under a fresh id.
    /// Stores and queues an admitted job, unless [`Limits::queued`] jobs are waiting already
    /// (a queue without bound let any client that may submit fill the state folder's disk).
    pub fn submit(&self, id: String, admitted: Admitted) -> Result<JobView, SubmitError> {
        let output = admitted
            .job
            .output
            .path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut t = self.lock();
        let waiting = t
            .jobs
            .values()
            .filter(|j| j.record.state == JobState::Queued)
            .count();
        if waiting >= self.limits.queued {
            return Err(SubmitError::Full(waiting));
        }
        let record = JobRecord::queued(id.clone(), t.next_seq, output);
        self.store
            .create(&record, &admitted.toml)
            .map_err(SubmitError::Io)?;
        t.next_seq += 1;
        let job = Job::new(record, Some(Arc::new(admitted.job)));
        let view = job.view();
        t.order.push(id.clone());
        t.jobs.insert(id.clone(), job);
        drop(t);
        info!(%id, "job queued");
        self.wake.notify_one();
        Ok(view)
    }

    pub fn get(&self, id: &str) -> Option<JobView> {
        self.lock().jobs.get(id).map(Job::view)
    }

    pub fn list(&self) -> Vec<JobView> {
        let t = self.lock();
        t.order
            .iter()
            .filter_map(|id| t.jobs.get(id))
            .map(Job::view)
            .collect()
    }

    pub fn watch(&self, id: &str) -> Option<watch::Receiver<JobView>> {
        self.lock().jobs.get(id).map(|j| j.events.subscribe())
    }

    pub fn snapshot(&self) -> Snapshot {
        let t = self.lock();
        let count = |s: JobState| t.jobs.values().filter(|j| j.record.state == s).count();
        Snapshot {
            jobs: JobState::ALL.iter().map(|&s| (s, count(s))).collect(),
            resident_faces: t
                .jobs
                .values()
                .filter(|j| j.record.state == JobState::Running)
                .map(|j| j.progress.resident_faces)
                .sum(),
        }
    }

    /// `DELETE /jobs/{id}`: cancels a queued or running job, removes a finished one. Without
    /// removal a long-running service kept every output it ever made, and only deleting job
    /// folders by hand behind its back (which a running service does not notice) freed the disk.
    ///
    /// Each change is written to the job's folder before it is made in memory, and an error
    /// (the state folder's disk full) leaves the job as it was, in memory as on disk: a queued
    /// job stays queued, a running one keeps running. A cancel answered but not written came
    /// back at the next start (a running job's even counted as a crash).
    pub fn delete(&self, id: &str) -> std::io::Result<DeleteOutcome> {
        let mut t = self.lock();
        let Some(job) = t.jobs.get_mut(id) else {
            return Ok(DeleteOutcome::NotFound);
        };
        match job.record.state {
            JobState::Queued => {
                job.change(&self.store, |r| {
                    r.state = JobState::Cancelled;
                    r.finished_unix_ms = Some(now_ms());
                })?;
                info!(%id, "queued job cancelled");
                Ok(DeleteOutcome::Cancelled(job.view()))
            }
            JobState::Running => {
                if !job.record.cancel_requested {
                    job.change(&self.store, |r| r.cancel_requested = true)?;
                }
                job.cancel.store(true, Ordering::Relaxed);
                info!(%id, "cancelling a running job");
                Ok(DeleteOutcome::Stopping(job.view()))
            }
            JobState::Done | JobState::Failed | JobState::Cancelled => {
                // Its run has ended (the state turns final under this lock, once the run has
                // returned), so nothing writes in the folder any more. Forgotten once its state
                // file is gone, as the next start would (the event streams following it end as
                // its sender goes), even when the rest of its folder is not: answered
                // "unchanged", it was still listed while a restart found it gone.
                let leftover = match self.store.remove(id) {
                    Ok(()) => None,
                    Err(RemoveError::Kept(e)) => return Err(e),
                    Err(e @ RemoveError::Leftover { .. }) => Some(e.to_string()),
                };
                t.jobs.remove(id);
                t.order.retain(|x| x != id);
                match &leftover {
                    None => info!(%id, "finished job removed"),
                    Some(e) => warn!(%id, error = %e, "finished job removed, not all of its files"),
                }
                Ok(DeleteOutcome::Removed { leftover })
            }
        }
    }

    /// Starts queued jobs, oldest first, while fewer than `max_parallel` run; wakes up on every
    /// submission and every finished run, until shutdown, and every [`STATE_RETRY`] while a
    /// start waits for its state to be written.
    pub async fn schedule(self: Arc<Self>) {
        loop {
            let waiting = self.start_ready() == Starts::WaitForDisk;
            tokio::select! {
                _ = self.wake.notified() => {}
                () = tokio::time::sleep(STATE_RETRY), if waiting => {}
                _ = self.shutdown.cancelled() => return,
            }
        }
    }

    /// A job starts only once its `running` state is written. When it cannot be (the state
    /// folder's disk full or unwritable), the job stays queued, as its `state.json` says, and
    /// nothing starts until it can: failing it instead told clients it had failed while the
    /// disk still said queued, so the next start ran it anyway. Its turn is kept (the next jobs
    /// share its disk, and would jump the queue), and the write is tried again.
    fn start_ready(self: &Arc<Self>) -> Starts {
        let mut t = self.lock();
        while t.running < self.limits.running && !self.shutdown.is_cancelled() {
            let next = t
                .order
                .iter()
                .find(|id| t.jobs[*id].record.state == JobState::Queued)
                .cloned();
            let Some(id) = next else { break };
            // A job the service died in runs alone, and nothing starts beside it: should it
            // bring the service down again, the death is its own, not its neighbours' (the
            // count fails a job after `MAX_CRASHES`).
            let suspect = |j: &Job| j.record.crashes > 0;
            let running_suspect = t
                .jobs
                .values()
                .any(|j| j.record.state == JobState::Running && suspect(j));
            if running_suspect || (t.running > 0 && suspect(&t.jobs[&id])) {
                break;
            }
            let job = t.jobs.get_mut(&id).expect("ids in order are in the table");
            // Every queued job has its config (it is dropped only in final states); should that
            // ever break, fail the job rather than stall the queue behind it.
            let Some(config) = job.config.clone() else {
                let failed = job.change(&self.store, |r| {
                    r.state = JobState::Failed;
                    r.error = Some("internal error: the job's config was lost".into());
                    r.finished_unix_ms = Some(now_ms());
                });
                match failed {
                    Ok(()) => continue,
                    Err(e) => return self.wait_for_disk(&id, &e),
                }
            };
            if let Err(e) = self.store.clear_outputs(&id, &resumable(Some(&config))) {
                warn!(%id, error = %e, "cannot clear the job folder before its run");
            }
            job.progress = ProgressView::default();
            let started = job.change(&self.store, |r| {
                r.state = JobState::Running;
                r.started_unix_ms = Some(now_ms());
                r.attempts += 1;
            });
            if let Err(e) = started {
                return self.wait_for_disk(&id, &e);
            }
            let cancel = Arc::clone(&job.cancel);
            t.running += 1;
            let span = info_span!("job", id = %id);
            let queue = Arc::clone(self);
            self.runs
                .spawn(queue.run(id, config, cancel, span.clone()).instrument(span));
        }
        Starts::Started
    }

    /// Logs and counts a queued job's change that could not be written; the scheduler tries
    /// again in [`STATE_RETRY`].
    fn wait_for_disk(&self, id: &str, e: &std::io::Error) -> Starts {
        self.metrics.error("state_io");
        error!(
            %id,
            error = %e,
            retry_seconds = STATE_RETRY.as_secs(),
            "cannot write the job's state: it stays queued, and no job starts until it can be written; free space on the disk of the service's state folder, or make it writable"
        );
        Starts::WaitForDisk
    }

    async fn run(
        self: Arc<Self>,
        id: String,
        config: Arc<JobConfig>,
        cancel: Arc<AtomicBool>,
        span: tracing::Span,
    ) {
        info!("run started");
        let queue = Arc::clone(&self);
        let job_id = id.clone();
        let outcome = tokio::task::spawn_blocking(move || {
            let _entered = span.enter();
            // The inputs were confined at submission, but a file under an allowed folder may
            // have been replaced by a link to one outside since (or the folders changed with a
            // restart): checked again now, just before the run opens them.
            queue.roots.confirm(&config)?;
            // Whether a slab of the run was done: an error before is one of resuming, after
            // it one of the run (`did_a_slab`).
            let progressed = AtomicBool::new(false);
            let observer = |p: &Progress| {
                if did_a_slab(p) {
                    progressed.store(true, Ordering::Relaxed);
                }
                queue.progress(&job_id, p);
            };
            // A job folder holds one job: a checkpoint in it is this job's, from a run the
            // service's stop or crash interrupted.
            let run = |start| {
                isostream_pipeline::run_from(
                    &config,
                    Path::new(admission::ORIGIN),
                    start,
                    &cancel,
                    &observer,
                )
            };
            match run(Start::Resume) {
                // No one can pass `--restart` to a service: a checkpoint that cannot be resumed
                // (the input was touched or replaced, another build wrote it, its temporary
                // output is gone) is thrown away and the job starts over, as it would without
                // one. Not a checkpoint that failed to be written mid-run (a full disk).
                Err(
                    e @ (RunError::InputChanged { .. }
                    | RunError::ResumeMismatch { .. }
                    | RunError::Checkpoint { .. }
                    | RunError::CheckpointIo { .. }
                    | RunError::Output(_)),
                ) if !progressed.load(Ordering::Relaxed) => {
                    warn!(error = %e, "the checkpoint cannot be resumed; starting the job over");
                    run(Start::Restart)
                }
                outcome => outcome,
            }
        })
        .await
        .unwrap_or_else(|e| {
            Err(RunError::Internal {
                stage: "service",
                reason: format!("the run panicked: {e}"),
            })
        });
        self.finish(&id, outcome).await;
        self.wake.notify_one();
    }

    /// The observer: called on the pipeline's thread for every finished slab.
    fn progress(&self, id: &str, p: &Progress) {
        let mut t = self.lock();
        if let Some(job) = t.jobs.get_mut(id) {
            let mut now = ProgressView::from(p);
            // The faces pace from where the time and the slabs do.
            let faces_start;
            (now.run_started_unix_ms, now.run_started_slab, faces_start) =
                match (job.progress.pass, job.progress.run_started_unix_ms, p.pass) {
                    (_, Some(t), _) => (
                        Some(t),
                        job.progress.run_started_slab,
                        job.progress.faces.map(|f| f.start),
                    ),
                    (Pass::First, None, Pass::Run) => {
                        (Some(now_ms()), Some(p.slabs_done), Some(p.faces_in))
                    }
                    _ => (None, None, None),
                };
            if let (Some(faces), Some(start)) = (&mut now.faces, faces_start) {
                faces.start = start;
            }
            // Counted from where the run started: a resumed run's totals include the faces its
            // checkpoint restored, the work of the service that saved it.
            self.metrics.faces(
                now.faces_in
                    .saturating_sub(job.progress.faces_in.max(p.faces_in_at_start)),
                now.faces_out
                    .saturating_sub(job.progress.faces_out.max(p.faces_out_at_start)),
            );
            job.progress = now;
            job.publish();
        }
    }

    /// Records the end of a run. Until it is written the job stays `running`, as its
    /// `state.json` says, and keeps its slot: a write that fails (the state folder's disk full)
    /// is tried again every [`STATE_RETRY`], and once more when the service stops. Shown
    /// unwritten, the end told clients a job had failed (or was done) while the disk still said
    /// running, and the next start ran it again. A service that stops before the write succeeds
    /// leaves the job `running` on disk: its next start finds a completed run done
    /// ([`completed_run`]) and runs any other again.
    async fn finish(&self, id: &str, outcome: Result<RunSummary, RunError>) {
        let end = self.end_of_run(id, outcome);
        while !self.record_end(id, &end) {
            if self.shutdown.is_cancelled() {
                error!(
                    "the service stops before the end of this run could be written: its state.json still says running; the next start finds it done if its output and run summary are complete, else runs it again"
                );
                return;
            }
            tokio::select! {
                () = tokio::time::sleep(STATE_RETRY) => {}
                () = self.shutdown.cancelled() => {}
            }
        }
    }

    /// What the run's outcome makes of its job, counted and logged, its partial files removed
    /// (all but a checkpoint it may resume from): the end [`Queue::record_end`] writes.
    fn end_of_run(&self, id: &str, outcome: Result<RunSummary, RunError>) -> RunEnd {
        let mut t = self.lock();
        let shutting_down = self.shutdown.is_cancelled();
        let job = t.running_job(id);
        // The run's memory is gone, whether or not its end can be written yet.
        job.progress.resident_faces = 0;
        let mut end = RunEnd {
            state: JobState::Failed,
            finished_unix_ms: Some(now_ms()),
            error: None,
            summary: None,
        };
        match outcome {
            Ok(summary) => {
                self.metrics.stage_seconds(&summary.stage_seconds);
                // This run's voxels only, as the face counters count only this run's faces: a
                // resumed run's summary counts the whole volume.
                self.metrics.voxels(summary.voxels_this_run());
                end.state = JobState::Done;
                end.summary = serde_json::to_value(&summary).ok().map(without_series);
                info!(
                    faces_in = summary.faces_extracted,
                    faces_out = summary.faces_written,
                    seconds = summary.seconds,
                    "run done"
                );
            }
            Err(RunError::Cancelled | RunError::Interrupted { .. })
                if shutting_down && !job.record.cancel_requested =>
            {
                // Interrupted by the service stopping, not by a client: run it again next start
                // (from its checkpoint, which `clear_outputs` below keeps).
                end.state = JobState::Queued;
                end.finished_unix_ms = None;
                info!("run interrupted by shutdown; it stays queued");
            }
            Err(RunError::Cancelled | RunError::Interrupted { .. }) => {
                end.state = JobState::Cancelled;
                info!("run cancelled");
            }
            Err(e) => {
                self.metrics.error(run_error_kind(&e));
                end.error = Some(for_a_client(&e));
                warn!(error = %e, "run failed");
            }
        }
        let keep = match end.state {
            JobState::Queued => resumable(job.config.as_deref()),
            _ => Vec::new(),
        };
        if end.state != JobState::Done
            && let Err(e) = self.store.clear_outputs(id, &keep)
        {
            warn!(error = %e, "cannot remove the partial output");
        }
        end
    }

    /// Writes the end of the job's run and only then makes it the job's, freeing its slot;
    /// false (logged and counted) while it cannot be written.
    fn record_end(&self, id: &str, end: &RunEnd) -> bool {
        let mut t = self.lock();
        let job = t.running_job(id);
        if let Err(e) = job.change(&self.store, |r| end.apply(r)) {
            self.metrics.error("state_io");
            error!(
                error = %e,
                state = end.state.name(),
                retry_seconds = STATE_RETRY.as_secs(),
                "cannot write the end of the run: the job shows running until it is written; free space on the disk of the service's state folder, or make it writable"
            );
            return false;
        }
        t.running -= 1;
        true
    }

    /// After shutdown: interrupt running jobs and wait until their runs have cleaned up and
    /// their ends are written, or given up (see [`Queue::finish`]).
    pub async fn drain(&self) {
        {
            let t = self.lock();
            for job in t.jobs.values() {
                if job.record.state == JobState::Running {
                    job.cancel.store(true, Ordering::Relaxed);
                }
            }
        }
        self.runs.close();
        self.runs.wait().await;
        self.drained.cancel();
    }

    /// Returns once [`Queue::drain`] is over: the jobs are as the next start finds them.
    pub async fn drained(&self) {
        self.drained.cancelled().await;
    }
}

/// The fix a client can follow when the service's disk is full or unwritable: it chose no
/// output folder (the service's is its state) and cannot pass `--resume`.
const STATE_DISK_FIX: &str = "free space on the disk of the service's state folder";

/// A run's error as a client of the service reads it: one line, and without advice only the
/// command line can follow. A failed job keeps none of its files (`end_of_run`), so the command
/// line's "run with --resume (the checkpoint ... is kept)" after a failed checkpoint write and
/// "the mesh itself was written complete" after a failed summary write are false here: those two
/// are said again for the service.
fn for_a_client(error: &RunError) -> String {
    let line = match error {
        RunError::CheckpointWrite { path, source, .. } => format!(
            "{}: cannot write the checkpoint: {source}; {STATE_DISK_FIX}, then submit the job again",
            path.display()
        ),
        RunError::Summary { path, reason } => format!(
            "{}: cannot write run summary: {reason}; {STATE_DISK_FIX}, then submit the job again",
            path.display()
        ),
        RunError::OutputFolder {
            output,
            folder,
            what,
            source,
            ..
        } => format!(
            "{}: cannot {what} {}: {source}; {STATE_DISK_FIX} or make it writable, then submit the job again",
            output.display(),
            folder.display()
        ),
        e => e.to_string(),
    };
    one_line(&line)
}

/// `text` on one line, the command line's advice about the output folder said for the service.
fn one_line(text: &str) -> String {
    text.replace('\n', " ").replace(
        "free space on that disk or choose another output folder",
        STATE_DISK_FIX,
    )
}

/// The files of a job's checkpoint (kept while the job may resume from it).
fn resumable(config: Option<&JobConfig>) -> Vec<std::path::PathBuf> {
    config.map_or_else(Vec::new, |c| {
        isostream_pipeline::resumable_files(&c.output.path)
    })
}

/// The run summary as `state.json`, the job views and every event carry it: without its time
/// series (up to a thousand points), which only the report reads, from `<output>.run.json`.
fn without_series(mut summary: serde_json::Value) -> serde_json::Value {
    if let Some(map) = summary.as_object_mut() {
        map.remove("series");
    }
    summary
}

/// The summary (without its series) and end time of the completed run of a job found
/// `running`: its end was never written (the state folder's disk full until the service
/// stopped, or a crash just after the run), and running it again would redo finished work
/// under a client who may have its output already.
///
/// Sound because of the order of the files: the pipeline fsyncs the output and renames it to
/// its final name, then writes the summary, its `sink.bytes` the output's size (and last
/// removes a checkpoint's finished-run record, which this removes too); and the service
/// removes both before every run. A summary there whose `sink.bytes` is
/// the output's size is this job's last run's, and that run completed. Anything less (no
/// summary, a torn one, an output of another size) is a run to do again.
fn completed_run(dir: &Path, output: &str) -> Option<(serde_json::Value, u64)> {
    let output = dir.join(output);
    let summary_file = isostream_pipeline::summary_path(&output);
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&summary_file).ok()?).ok()?;
    let written = std::fs::metadata(&output).ok()?.len();
    if summary["sink"]["bytes"].as_u64() != Some(written) {
        return None;
    }
    let ended = std::fs::metadata(&summary_file).and_then(|m| m.modified());
    let ended_ms = ended
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
    Some((
        without_series(summary),
        ended_ms.map_or_else(now_ms, |d| d.as_millis() as u64),
    ))
}

fn run_error_kind(e: &RunError) -> &'static str {
    match e {
        RunError::Config(_) => "run_config",
        RunError::Volume(_) => "run_input",
        RunError::Output(_)
        | RunError::Summary { .. }
        | RunError::Locked { .. }
        | RunError::Lock { .. }
        | RunError::OutputFolder { .. } => "run_output",
        RunError::EmptySurface { .. } => "run_empty_surface",
        RunError::ClassicalOverBudget { .. } => "run_over_budget",
        RunError::IndexLimit { .. } => "run_index_limit",
        RunError::SliceMemory { .. } => "run_input",
        RunError::Cancelled | RunError::Interrupted { .. } => "run_cancelled",
        RunError::CheckpointFound { .. }
        | RunError::FinishedFound { .. }
        | RunError::Checkpoint { .. }
        | RunError::CheckpointIo { .. }
        | RunError::CheckpointWrite { .. }
        | RunError::ResumeMismatch { .. }
        | RunError::InputChanged { .. } => "run_checkpoint",
        RunError::Internal { .. } => "run_internal",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPHERE: &str = "[input]\nshape = \"sphere\"\nsize = [16, 16, 16]\n[extract]\niso = 0.0\n[output]\npath = \"output.smb\"\n";
    const QUEUED: &str = "aa000000000000000000000000000000";
    const RUNNING: &str = "bb000000000000000000000000000000";

    fn queue(state: &Path) -> Arc<Queue> {
        Queue::recover(
            Store::open(state).unwrap(),
            Arc::default(),
            Limits {
                running: 1,
                queued: 10,
            },
            Arc::new(Metrics::new()),
            CancellationToken::new(),
        )
    }

    fn stored_state(state: &Path, id: &str) -> serde_json::Value {
        let text = std::fs::read(state.join("jobs").join(id).join("state.json")).unwrap();
        serde_json::from_slice(&text).unwrap()
    }

    /// A `DELETE` whose change cannot be written (here `state.json` is a folder, as a full
    /// disk would fail it) changes nothing, in memory as on disk; one that can be is kept by
    /// a restart, a running job's too, even when the end of its run was never recorded.
    #[test]
    fn a_cancel_that_cannot_be_written_changes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let state = dir.path();
        {
            let store = Store::open(state).unwrap();
            for (seq, id) in [QUEUED, RUNNING].into_iter().enumerate() {
                store
                    .create(
                        &JobRecord::queued(id.into(), seq as u64, "output.smb".into()),
                        SPHERE,
                    )
                    .unwrap();
            }
        }
        let q = queue(state);
        {
            // As `start_ready` leaves it, without running anything.
            let mut t = q.lock();
            t.jobs.get_mut(RUNNING).unwrap().record.state = JobState::Running;
            t.running += 1;
            q.store.save(&t.jobs[RUNNING].record).unwrap();
        }
        let unwritable = |id: &str| {
            let file = state.join("jobs").join(id).join("state.json");
            std::fs::remove_file(&file).unwrap();
            std::fs::create_dir(&file).unwrap();
            file
        };
        let (queued_state, running_state) = (unwritable(QUEUED), unwritable(RUNNING));
        assert!(q.delete(QUEUED).is_err());
        assert!(q.delete(RUNNING).is_err());
        assert_eq!(q.get(QUEUED).unwrap().record.state, JobState::Queued);
        let running = q.get(RUNNING).unwrap().record;
        assert_eq!(running.state, JobState::Running);
        assert!(!running.cancel_requested);
        assert!(
            !q.lock().jobs[RUNNING].cancel.load(Ordering::Relaxed),
            "not stopped"
        );

        std::fs::remove_dir(queued_state).unwrap();
        std::fs::remove_dir(running_state).unwrap();
        assert!(matches!(q.delete(QUEUED), Ok(DeleteOutcome::Cancelled(_))));
        assert_eq!(stored_state(state, QUEUED)["state"], "cancelled");
        assert!(matches!(q.delete(RUNNING), Ok(DeleteOutcome::Stopping(_))));
        assert!(q.lock().jobs[RUNNING].cancel.load(Ordering::Relaxed));
        let stored = stored_state(state, RUNNING);
        assert_eq!(
            (&stored["state"], &stored["cancel_requested"]),
            (&"running".into(), &true.into())
        );

        // The service dies before the run's end is recorded.
        drop(q);
        let q = queue(state);
        let cancelled = q.get(RUNNING).unwrap().record;
        assert_eq!(
            (cancelled.state, cancelled.crashes),
            (JobState::Cancelled, 0),
            "cancelled as the client was told, not a crash to run again"
        );
        assert_eq!(q.get(QUEUED).unwrap().record.state, JobState::Cancelled);
    }

    /// A queue over `state` holding one job, `RUNNING`, as recorded when it was submitted.
    fn running_queue(state: &Path) -> Arc<Queue> {
        Store::open(state)
            .unwrap()
            .create(
                &JobRecord::queued(RUNNING.into(), 0, "output.smb".into()),
                SPHERE,
            )
            .unwrap();
        queue(state)
    }

    /// A run resumed from a checkpoint reports the faces it restored in its totals, from its
    /// first report on: the metrics count only the faces it adds (they counted the restored
    /// ones again, as if new).
    #[test]
    fn a_resumed_run_counts_only_the_faces_it_adds() {
        let dir = tempfile::tempdir().unwrap();
        let q = running_queue(dir.path());
        let report = |pass, slabs_done, faces_in, faces_out| Progress {
            pass,
            slabs_done,
            slabs_at_start: 40,
            slabs_total: 100,
            faces_in,
            faces_out,
            faces_in_at_start: 4000,
            faces_out_at_start: 700,
            faces_total: None,
            resident_faces: 0,
            queued: [0; 3],
        };
        // A first pass (`[output] faces`) reports no faces, then the run its totals.
        q.progress(RUNNING, &report(Pass::First, 100, 0, 0));
        q.progress(RUNNING, &report(Pass::Run, 41, 4100, 720));
        q.progress(RUNNING, &report(Pass::Run, 42, 4250, 760));
        let text = q.metrics.render(&Snapshot {
            jobs: Vec::new(),
            resident_faces: 0,
        });
        for needle in [
            "isostream_faces_in_total 250\n",
            "isostream_faces_out_total 60\n",
        ] {
            assert!(text.contains(needle), "{needle} missing from\n{text}");
        }
    }

    /// A job's ETA is the command line's ([`eta_seconds`]), paced by the faces when a first pass
    /// counted them: the status page paced its own by the slabs, and promised the end of a run
    /// whose surface lay in the volume's first half at the slabs' pace.
    #[test]
    fn the_eta_paces_by_the_faces_when_a_first_pass_counted_them() {
        let faces = Done {
            start: 100,
            now: 9_100,
            total: 10_100,
        };
        let view = ProgressView {
            slabs_done: 60,
            slabs_total: 100,
            run_started_unix_ms: Some(10_000),
            run_started_slab: Some(10),
            faces: Some(faces),
            ..ProgressView::default()
        };
        // 20 s since the run's first slab, over 50 slabs of 90 and 9000 faces of 10000.
        let slabs = Done {
            start: 10,
            now: 60,
            total: 100,
        };
        let eta = view.eta_s(Some(1_000), 30_000).unwrap();
        assert_eq!(Some(eta), eta_seconds(20.0, slabs, Some(faces)));
        assert!((eta - 20.0 * 1_000.0 / 9_000.0).abs() < 1e-9, "{eta}");
        let by_slabs = ProgressView {
            faces: None,
            ..view
        };
        assert_eq!(by_slabs.eta_s(Some(1_000), 30_000), Some(16.0));
        let first = ProgressView {
            pass: Pass::First,
            ..view
        };
        assert_eq!(first.eta_s(Some(1_000), 30_000), None, "not the job's end");
    }

    /// Only a slab done past the run's start counts as progress: the first pass's reports and
    /// the one a run sends as it begins come before the checks a restart may cure.
    #[test]
    fn only_a_slab_done_past_the_start_is_progress() {
        let report = |pass, slabs_done, slabs_at_start| Progress {
            slabs_done,
            slabs_at_start,
            ..Progress::fresh(pass, 100)
        };
        assert!(!did_a_slab(&report(Pass::First, 50, 0)));
        assert!(!did_a_slab(&report(Pass::Run, 0, 0)), "a fresh run begins");
        assert!(
            !did_a_slab(&report(Pass::Run, 40, 40)),
            "a resumed run begins"
        );
        assert!(did_a_slab(&report(Pass::Run, 41, 40)));
        assert!(did_a_slab(&report(Pass::Run, 1, 0)));
    }

    /// After a first pass, the faces pace from the run's first report, as the slabs and
    /// the time do; the job's view carries the estimate while it runs.
    #[test]
    fn after_a_first_pass_the_faces_pace_from_the_runs_first_slab() {
        let dir = tempfile::tempdir().unwrap();
        let q = running_queue(dir.path());
        {
            let mut t = q.lock();
            let record = &mut t.jobs.get_mut(RUNNING).unwrap().record;
            record.state = JobState::Running;
            record.started_unix_ms = Some(now_ms());
        }
        let report = |pass, slabs_done, faces_in| Progress {
            slabs_done,
            faces_in,
            faces_total: (pass == Pass::Run).then_some(10_000),
            ..Progress::fresh(pass, 100)
        };
        q.progress(RUNNING, &report(Pass::First, 100, 0));
        assert_eq!(q.get(RUNNING).unwrap().progress.eta_s, None);
        q.progress(RUNNING, &report(Pass::Run, 3, 300));
        q.progress(RUNNING, &report(Pass::Run, 5, 800));
        let view = q.get(RUNNING).unwrap().progress;
        assert_eq!(
            q.lock().jobs[RUNNING].progress.faces,
            Some(Done {
                start: 300,
                now: 800,
                total: 10_000
            })
        );
        assert!(view.eta_s.is_some(), "{view:?}");
    }

    /// A resumed run's end adds the voxels it read, from its checkpoint's slab on, as its
    /// faces count from the checkpoint: it added the whole volume's.
    #[test]
    fn a_resumed_run_counts_only_the_voxels_it_reads() {
        let dir = tempfile::tempdir().unwrap();
        let q = running_queue(dir.path());
        let summary = RunSummary {
            input: "sphere".into(),
            dims: [10, 10, 100],
            voxels: 10_000,
            iso: 0.0,
            mode: isostream_pipeline::Mode::Rate,
            output: "output.smb".into(),
            faces_extracted: 0,
            faces_kept: 0,
            target_faces: None,
            rate: None,
            faces_written: 0,
            vertices_written: 0,
            seconds: 1.0,
            stage_seconds: Default::default(),
            peak_rss_bytes: None,
            peak_resident_faces: 0,
            shape_error: 0.0,
            extract: Default::default(),
            detect: Default::default(),
            prune: None,
            simplify: Default::default(),
            simplify_stages: None,
            sink: Default::default(),
            resumed_at_slab: Some(90),
            warnings: Vec::new(),
            series: isostream_pipeline::TimeSeries {
                stride: 1,
                points: Vec::new(),
            },
        };
        q.end_of_run(RUNNING, Ok(summary));
        let text = q.metrics.render(&Snapshot {
            jobs: Vec::new(),
            resident_faces: 0,
        });
        assert!(
            text.contains("isostream_voxels_total 1000\n"),
            "the last 10 of 100 slices of 10 x 10 voxels:\n{text}"
        );
    }

    /// A job found `running` is done only when its run summary is whole and names the
    /// output's size: the pipeline writes it last, once the output is complete.
    #[test]
    fn only_a_whole_summary_of_the_output_as_it_is_makes_a_completed_run() {
        let dir = tempfile::tempdir().unwrap();
        let summary = dir.path().join("output.smb.run.json");
        let completed = || completed_run(dir.path(), "output.smb");
        std::fs::write(dir.path().join("output.smb"), b"12345").unwrap();
        assert!(completed().is_none(), "no summary: killed before the end");
        std::fs::write(&summary, br#"{"sink": {"bytes": 5}, "#).unwrap();
        assert!(completed().is_none(), "a torn summary");
        std::fs::write(
            &summary,
            br#"{"sink": {"bytes": 5}, "faces_written": 2, "series": [1, 2]}"#,
        )
        .unwrap();
        let (kept, ended) = completed().unwrap();
        assert_eq!(
            kept,
            serde_json::json!({"sink": {"bytes": 5}, "faces_written": 2})
        );
        assert!(ended > 0 && ended <= now_ms());
        std::fs::write(dir.path().join("output.smb"), b"1234").unwrap();
        assert!(completed().is_none(), "an output of another size");
        std::fs::remove_file(dir.path().join("output.smb")).unwrap();
        assert!(completed().is_none(), "no output");
    }

    #[test]
    fn errors_reach_clients_on_one_line_with_advice_they_can_follow() {
        let full = "out/output.smb: cannot write: No space left on device; free space on that disk or choose another output folder\nmore";
        assert_eq!(
            one_line(full),
            "out/output.smb: cannot write: No space left on device; free space on the disk of the service's state folder more"
        );
        // A failed job keeps no checkpoint and no mesh: no `--resume`, no "written complete".
        let checkpoint = RunError::CheckpointWrite {
            path: "jobs/1/.output.smb.ckpt".into(),
            source: std::io::Error::new(std::io::ErrorKind::StorageFull, "No space left on device"),
            kept: Some((60, 255)),
        };
        let summary = RunError::Summary {
            path: "jobs/1/output.smb.run.json".into(),
            reason: "No space left on device".into(),
        };
        let folder = RunError::OutputFolder {
            output: "jobs/1/output.smb".into(),
            folder: "jobs/1".into(),
            what: "write in",
            fix: "make it writable",
            source: std::io::Error::other("Read-only file system"),
        };
        let line = for_a_client(&folder);
        assert!(!line.contains("another output folder"), "{line}");
        for e in [checkpoint, summary] {
            let line = for_a_client(&e);
            assert!(
                line.contains(STATE_DISK_FIX) && line.ends_with("submit the job again"),
                "{line}"
            );
            for cli_only in ["--resume", "is kept", "written complete", "summary = false"] {
                assert!(!line.contains(cli_only), "{line}");
            }
        }
    }
}
