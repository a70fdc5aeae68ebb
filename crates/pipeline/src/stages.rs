//! The five stages, each on its own thread, joined by bounded channels.
//!
//! Every stage ends in one of three ways: it saw the end-of-volume marker and passed it on
//! (success), its own work failed (it records the error in the shared [`Control`], which raises
//! the abort flag), or it saw the abort flag / a neighbour hang up (it stops quietly: someone
//! else has the error to report). Only the writer can make a file appear, and only after it has
//! received the end marker, so an error or Ctrl-C anywhere leaves no output.
//!
//! No stage ever blocks for good on a channel: sends and receives wait in short slices
//! ([`POLL`]) and look at the abort and cancel flags in between. A channel alone is not enough to
//! stop a neighbour: the progress observer keeps clones of the receivers (queue depths), so a
//! failed writer does not disconnect the simplifier's channel, and a full channel would otherwise
//! block its producer forever (the deadlock of a write error on a full disk).

use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, SendTimeoutError, Sender, bounded};
use isostream_detect::{DetectStats, Detector, MeshDelta};
use isostream_extract::attributes::AttributeSlab;
use isostream_extract::{CubeBatch, ExtractStats, Extractor};
use isostream_simplify::{OutBatch, Simplifier, SimplifyStats};
use isostream_volume::{Grid, VolumeSource};
use tracing::{debug, info, info_span};

use crate::attributes::{SliceReader, Slices};
use crate::checkpoint::{self, Checkpoint, InputIdentity, Parts, ReaderState};
use crate::config::CheckpointEvery;
use crate::error::RunError;
use crate::sink::Sink;

/// How a stage stopped when it did not finish.
pub(crate) enum Stop {
    /// A neighbour hung up; it reports the cause.
    Disconnected,
    Failed(RunError),
}

impl From<RunError> for Stop {
    fn from(e: RunError) -> Self {
        Stop::Failed(e)
    }
}

type StageResult<T> = Result<T, Stop>;

/// How long a blocked send or receive waits before it looks at the abort and cancel flags again.
const POLL: Duration = Duration::from_millis(20);

/// Shared by every stage: the user's cancel flag, and the first error of any stage (recording it
/// raises the abort flag that stops every other stage, whatever the state of the channels).
pub(crate) struct Control<'a> {
    cancel: &'a AtomicBool,
    abort: AtomicBool,
    first: Mutex<Option<RunError>>,
    /// Values the reader saw, for the empty-surface error.
    range: Mutex<DataRange>,
}

/// Smallest and largest finite value read, and how many voxels were NaN or infinite.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
pub(crate) struct DataRange {
    min: f32,
    max: f32,
    non_finite: u64,
}

impl DataRange {
    pub(crate) const EMPTY: DataRange = DataRange {
        min: f32::INFINITY,
        max: f32::NEG_INFINITY,
        non_finite: 0,
    };

    fn add(&mut self, values: &[f32]) {
        for &v in values {
            if v.is_finite() {
                self.min = self.min.min(v);
                self.max = self.max.max(v);
            } else {
                self.non_finite += 1;
            }
        }
    }

    /// "[0, 255] (12 NaN or infinite voxels)", or what to say when no voxel was finite.
    fn describe(&self) -> String {
        if self.min > self.max {
            return format!(
                "the volume has no finite voxel (all {} are NaN or infinite)",
                self.non_finite
            );
        }
        let mut s = format!("the data range is [{}, {}]", self.min, self.max);
        if self.non_finite > 0 {
            s.push_str(&format!(" ({} NaN or infinite voxels)", self.non_finite));
        }
        s
    }
}

impl<'a> Control<'a> {
    fn new(cancel: &'a AtomicBool) -> Self {
        Self {
            cancel,
            abort: AtomicBool::new(false),
            first: Mutex::new(None),
            range: Mutex::new(DataRange::EMPTY),
        }
    }

    /// Records a stage's failure (only the first one is kept) and stops every stage.
    fn fail(&self, e: RunError) {
        let mut first = self.first.lock().unwrap_or_else(|p| p.into_inner());
        if first.is_none() {
            *first = Some(e);
        }
        self.abort.store(true, Ordering::SeqCst);
    }

    /// Err when the run must stop: the user cancelled, or another stage failed.
    fn check(&self) -> StageResult<()> {
        if self.cancel.load(Ordering::Relaxed) {
            return Err(Stop::Failed(RunError::Cancelled));
        }
        if self.abort.load(Ordering::SeqCst) {
            return Err(Stop::Disconnected);
        }
        Ok(())
    }

    fn take_first(&self) -> Option<RunError> {
        self.first.lock().unwrap_or_else(|p| p.into_inner()).take()
    }

    /// Runs a stage body; a failure is recorded the moment it happens, so the others stop.
    fn stage<T>(&self, body: impl FnOnce() -> StageResult<T>) -> StageResult<T> {
        /// A panicking stage stops the others too (the join reports the panic).
        struct AbortOnPanic<'c>(&'c AtomicBool);
        impl Drop for AbortOnPanic<'_> {
            fn drop(&mut self) {
                if std::thread::panicking() {
                    self.0.store(true, Ordering::SeqCst);
                }
            }
        }
        let _guard = AbortOnPanic(&self.abort);
        let r = body();
        match r {
            Err(Stop::Failed(e)) => {
                self.fail(e);
                Err(Stop::Disconnected)
            }
            Err(Stop::Disconnected) => {
                // Whoever hung up has recorded (or will record) the cause; make sure nobody
                // keeps waiting on us.
                self.abort.store(true, Ordering::SeqCst);
                Err(Stop::Disconnected)
            }
            ok => ok,
        }
    }
}

/// Sends, waiting while the channel is full, but never past an abort or a cancel.
fn send<T>(ctl: &Control<'_>, tx: &Sender<T>, mut value: T) -> StageResult<()> {
    loop {
        match tx.send_timeout(value, POLL) {
            Ok(()) => return Ok(()),
            Err(SendTimeoutError::Disconnected(_)) => return Err(Stop::Disconnected),
            Err(SendTimeoutError::Timeout(v)) => {
                ctl.check()?;
                value = v;
            }
        }
    }
}

/// Receives the next message; `None` when the producer hung up. Never waits past an abort or a
/// cancel.
fn recv<T>(ctl: &Control<'_>, rx: &Receiver<T>) -> StageResult<Option<T>> {
    loop {
        match rx.recv_timeout(POLL) {
            Ok(v) => return Ok(Some(v)),
            Err(RecvTimeoutError::Disconnected) => return Ok(None),
            Err(RecvTimeoutError::Timeout) => ctl.check()?,
        }
    }
}

/// Snapshot passed to the progress observer after every completed slab.
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    pub slabs_done: u64,
    pub slabs_total: u64,
    pub faces_in: u64,
    pub faces_out: u64,
    pub resident_faces: u64,
    /// Batches waiting in the extract->detect, detect->simplify and simplify->write channels.
    pub queued: [usize; 3],
}

/// Busy time of each stage (time blocked on channels excluded).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct StageSeconds {
    pub read: f64,
    pub extract: f64,
    pub detect: f64,
    pub simplify: f64,
    pub write: f64,
}

pub(crate) struct StageOutputs {
    pub seconds: StageSeconds,
    pub extract: ExtractStats,
    pub detect: DetectStats,
    pub simplify: SimplifyStats,
    pub sink: crate::sink::SinkStats,
}

pub(crate) struct Stages<'a> {
    pub source: Box<dyn VolumeSource>,
    /// Attribute sources, read slice by slice with the iso volume.
    pub attributes: Vec<crate::attributes::Source>,
    pub iso: f32,
    pub simplifier: Simplifier,
    pub sink: Sink,
    pub capacity: usize,
    pub batch_triangles: usize,
    /// Accept a surface without any triangle (`[output] allow_empty`); else it is an error.
    pub allow_empty: bool,
    pub cancel: &'a AtomicBool,
    pub observer: &'a (dyn Fn(&Progress) + Sync),
    /// Save checkpoints (`None`: never).
    pub checkpoints: Option<Plan>,
    /// Continue from a checkpoint (the simplifier and the sink above are restored already).
    pub resume: Option<Resume>,
}

/// When and where the run saves checkpoints, and what identifies it.
pub(crate) struct Plan {
    pub every: CheckpointEvery,
    pub path: PathBuf,
    pub job: u64,
    pub input: InputIdentity,
}

/// The states of the first stages at the checkpoint a run continues from.
pub(crate) struct Resume {
    pub reader: ReaderState,
    pub extract: ExtractStats,
    pub detector: Detector,
}

/// What travels between the first stages: data, or the checkpoint marker carrying the states of
/// the stages it has passed (see `checkpoint`).
enum Msg<T> {
    Data(T),
    Cut(Box<Cut>),
}

/// The marker: each stage fills in its state as it passes.
struct Cut {
    reader: ReaderState,
    extract: ExtractStats,
    detect: Vec<u8>,
    simplify: Vec<u8>,
}

/// Messages to the writer: batches, the checkpoint marker, then `End` when the volume is
/// complete.
enum ToWriter {
    Batch(OutBatch),
    Cut(Box<Cut>),
    End,
}

impl Stages<'_> {
    pub fn run(self) -> Result<StageOutputs, RunError> {
        let grid = self.source.grid();
        let (slice_tx, slice_rx) = bounded::<Msg<Slices>>(2);
        let (cube_tx, cube_rx) = bounded::<Msg<CubeBatch>>(self.capacity);
        let (delta_tx, delta_rx) = bounded::<Msg<MeshDelta>>(self.capacity);
        let (out_tx, out_rx) = bounded::<ToWriter>(self.capacity);
        let depth = Depths {
            cubes: cube_rx.clone(),
            deltas: delta_rx.clone(),
            out: out_rx.clone(),
        };
        let Stages {
            source,
            attributes,
            iso,
            simplifier,
            sink,
            batch_triangles,
            allow_empty,
            cancel,
            observer,
            checkpoints,
            resume,
            ..
        } = self;
        let (reader_resume, extract_resume, detector) = match resume {
            Some(r) => (Some(r.reader), Some(r.extract), r.detector),
            None => (None, None, Detector::new(grid.dims)),
        };
        let every = checkpoints.as_ref().map(|p| p.every);
        let input = source.describe();
        let empty = (!allow_empty).then_some(EmptyCheck { input: &input, iso });
        let ctl = Control::new(cancel);
        let ctl = &ctl;

        std::thread::scope(|s| {
            let reader = s.spawn(move || {
                ctl.stage(|| {
                    let reader = SliceReader::new(source, attributes);
                    read_stage(reader, grid, reader_resume, every, slice_tx, ctl)
                })
            });
            let extractor = s.spawn(move || {
                ctl.stage(|| {
                    let extractor = match extract_resume {
                        Some(stats) => Extractor::resume(grid, iso, stats),
                        None => Extractor::new(grid, iso),
                    };
                    extract_stage(extractor, grid, batch_triangles, slice_rx, cube_tx, ctl)
                })
            });
            let detector =
                s.spawn(move || ctl.stage(|| detect_stage(detector, cube_rx, delta_tx, ctl)));
            let simplifier = s.spawn(move || {
                ctl.stage(|| {
                    simplify_stage(simplifier, grid, delta_rx, out_tx, &depth, observer, ctl)
                })
            });
            let writer = s.spawn(move || {
                ctl.stage(|| write_stage(sink, out_rx, empty, checkpoints.as_ref(), grid, ctl))
            });

            // Join every stage. The first failure recorded (in time, whichever stage) is the
            // cause; a panic counts as a failure of its stage.
            let read = join(reader, "read");
            let extract = join(extractor, "extract");
            let detect = join(detector, "detect");
            let simplify = join(simplifier, "simplify");
            let write = join(writer, "write");
            match (read, extract, detect, simplify, write) {
                (
                    Ok(read),
                    Ok((extract_s, extract)),
                    Ok((detect_s, detect)),
                    Ok((simplify_s, simplify)),
                    Ok((write_s, sink)),
                ) => Ok(StageOutputs {
                    seconds: StageSeconds {
                        read,
                        extract: extract_s,
                        detect: detect_s,
                        simplify: simplify_s,
                        write: write_s,
                    },
                    extract,
                    detect,
                    simplify,
                    sink,
                }),
                (read, extract, detect, simplify, write) => {
                    Err(ctl.take_first().unwrap_or_else(|| {
                        first_failure([
                            read.err(),
                            extract.err(),
                            detect.err(),
                            simplify.err(),
                            write.err(),
                        ])
                    }))
                }
            }
        })
    }
}

fn first_failure(stops: [Option<Stop>; 5]) -> RunError {
    stops
        .into_iter()
        .flatten()
        .find_map(|stop| match stop {
            Stop::Failed(e) => Some(e),
            Stop::Disconnected => None,
        })
        .unwrap_or(RunError::Internal {
            stage: "pipeline",
            reason: "a stage hung up without reporting why".into(),
        })
}

fn join<T>(
    h: std::thread::ScopedJoinHandle<'_, StageResult<T>>,
    stage: &'static str,
) -> StageResult<T> {
    h.join().unwrap_or_else(|panic| {
        let reason = panic
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "panic".into());
        Err(Stop::Failed(RunError::Internal { stage, reason }))
    })
}

struct Depths {
    cubes: Receiver<Msg<CubeBatch>>,
    deltas: Receiver<Msg<MeshDelta>>,
    out: Receiver<ToWriter>,
}

/// Whether the reader sends the checkpoint marker after slice `z` (the cut after slab `z - 1`).
/// Never after the first slice of the run nor after the last slice of the volume: a checkpoint
/// there would save nothing new.
struct Schedule {
    every: Option<CheckpointEvery>,
    first: u64,
    last: u64,
    since: Instant,
}

impl Schedule {
    fn due(&mut self, z: u64) -> bool {
        if z == self.first || z >= self.last {
            return false;
        }
        let due = match self.every {
            None => false,
            Some(CheckpointEvery::Slabs(n)) => (z - self.first).is_multiple_of(n),
            Some(CheckpointEvery::Seconds(s)) => self.since.elapsed().as_secs_f64() >= s,
        };
        if due {
            self.since = Instant::now();
        }
        due
    }
}

fn read_stage(
    mut reader: SliceReader,
    grid: Grid,
    resume: Option<ReaderState>,
    every: Option<CheckpointEvery>,
    tx: Sender<Msg<Slices>>,
    ctl: &Control<'_>,
) -> StageResult<f64> {
    let _span = info_span!("read").entered();
    let mut busy = Duration::ZERO;
    let first = resume.map_or(0, |r| r.z);
    if let Some(r) = resume {
        reader.seek(first)?;
        *ctl.range.lock().unwrap_or_else(|p| p.into_inner()) = r.range;
    }
    let mut schedule = Schedule {
        every,
        first,
        last: grid.dims[2].saturating_sub(1),
        since: Instant::now(),
    };
    for z in first..grid.dims[2] {
        ctl.check()?;
        let t = Instant::now();
        let Some(slices) = reader.next_slices()? else {
            break;
        };
        if let Some(r) = resume
            && z == first
            && checkpoint::hash_slice(&slices.iso) != r.carried
        {
            return Err(Stop::Failed(RunError::InputChanged {
                what: format!("slice {z} holds other values than when the checkpoint was taken"),
            }));
        }
        let cut = schedule.due(z).then(|| checkpoint::hash_slice(&slices.iso));
        let range = {
            let mut range = ctl.range.lock().unwrap_or_else(|p| p.into_inner());
            // The carried slice was counted before the checkpoint.
            if resume.is_none() || z != first {
                range.add(&slices.iso);
            }
            *range
        };
        busy += t.elapsed();
        send(ctl, &tx, Msg::Data(slices))?;
        if let Some(carried) = cut {
            let reader = ReaderState { z, carried, range };
            send(ctl, &tx, Msg::Cut(Box::new(Cut::new(reader))))?;
        }
    }
    debug!(seconds = busy.as_secs_f64(), "read done");
    Ok(busy.as_secs_f64())
}

impl Cut {
    fn new(reader: ReaderState) -> Self {
        Cut {
            reader,
            extract: ExtractStats::default(),
            detect: Vec::new(),
            simplify: Vec::new(),
        }
    }
}

fn extract_stage(
    mut extractor: Extractor,
    grid: Grid,
    batch_triangles: usize,
    rx: Receiver<Msg<Slices>>,
    tx: Sender<Msg<CubeBatch>>,
    ctl: &Control<'_>,
) -> StageResult<(f64, ExtractStats)> {
    let _span = info_span!("extract").entered();
    let mut busy = Duration::ZERO;
    let mut lower: Option<Slices> = None;
    while let Some(msg) = recv(ctl, &rx)? {
        let upper = match msg {
            Msg::Data(slices) => slices,
            Msg::Cut(mut cut) => {
                cut.extract = extractor.stats();
                send(ctl, &tx, Msg::Cut(cut))?;
                continue;
            }
        };
        let z = upper.z;
        if let Some(lo) = &lower {
            let started = Instant::now();
            let mut blocked = Duration::ZERO;
            let attrs: Vec<AttributeSlab<'_>> = lo
                .attrs
                .iter()
                .zip(&upper.attrs)
                .map(|(l, u)| AttributeSlab { lower: l, upper: u })
                .collect();
            extractor.extract_slab_with_attributes(
                z - 1,
                &lo.iso,
                &upper.iso,
                &attrs,
                batch_triangles,
                |batch| {
                    let t = Instant::now();
                    let sent = send(ctl, &tx, Msg::Data(batch));
                    blocked += t.elapsed();
                    sent
                },
            )?;
            busy += started.elapsed().saturating_sub(blocked);
        }
        lower = Some(upper);
        if z + 1 == grid.dims[2] {
            return Ok((busy.as_secs_f64(), extractor.stats()));
        }
    }
    Err(Stop::Disconnected)
}

fn detect_stage(
    mut detector: Detector,
    rx: Receiver<Msg<CubeBatch>>,
    tx: Sender<Msg<MeshDelta>>,
    ctl: &Control<'_>,
) -> StageResult<(f64, DetectStats)> {
    let _span = info_span!("detect").entered();
    let mut busy = Duration::ZERO;
    while let Some(msg) = recv(ctl, &rx)? {
        let batch = match msg {
            Msg::Data(batch) => batch,
            Msg::Cut(mut cut) => {
                cut.detect = checkpoint::encode(&detector.snapshot());
                send(ctl, &tx, Msg::Cut(cut))?;
                continue;
            }
        };
        let t = Instant::now();
        let mut delta = MeshDelta::default();
        detector.process(&batch, &mut delta);
        busy += t.elapsed();
        let end = delta.end_of_volume;
        send(ctl, &tx, Msg::Data(delta))?;
        if end {
            return Ok((busy.as_secs_f64(), detector.stats()));
        }
    }
    Err(Stop::Disconnected)
}

fn simplify_stage(
    mut simplifier: Simplifier,
    grid: Grid,
    rx: Receiver<Msg<MeshDelta>>,
    tx: Sender<ToWriter>,
    depth: &Depths,
    observer: &(dyn Fn(&Progress) + Sync),
    ctl: &Control<'_>,
) -> StageResult<(f64, SimplifyStats)> {
    let _span = info_span!("simplify").entered();
    let slabs_total = grid.dims[2] - 1;
    let log_every = (slabs_total / 20).max(1);
    let mut busy = Duration::ZERO;
    let mut last_front = 0u32;
    while let Some(msg) = recv(ctl, &rx)? {
        let delta = match msg {
            Msg::Data(delta) => delta,
            Msg::Cut(mut cut) => {
                let t = Instant::now();
                cut.simplify = checkpoint::encode(&simplifier);
                busy += t.elapsed();
                send(ctl, &tx, ToWriter::Cut(cut))?;
                continue;
            }
        };
        let t = Instant::now();
        let stride = delta
            .attrs
            .len()
            .checked_div(delta.vertices.len())
            .unwrap_or(0);
        for (i, v) in delta.vertices.iter().enumerate() {
            let attrs = delta.attrs.get(i * stride..(i + 1) * stride).unwrap_or(&[]);
            simplifier.add_vertex(v.id, v.pos, v.rank, attrs);
        }
        for &tri in &delta.triangles {
            simplifier.add_triangle(tri);
        }
        for &id in &delta.modifiable {
            simplifier.set_modifiable(id);
        }
        let mut out = OutBatch::default();
        if delta.end_of_volume {
            simplifier.finish(&mut out);
        } else {
            simplifier.end_batch(delta.front, &mut out);
        }
        busy += t.elapsed();
        if let Some(faces) = simplifier.in_core_overflow() {
            return Err(Stop::Failed(RunError::ClassicalOverBudget { faces }));
        }
        if !out.elements.is_empty() {
            send(ctl, &tx, ToWriter::Batch(out))?;
        }
        if delta.front > last_front || delta.end_of_volume {
            last_front = delta.front;
            let st = simplifier.stats();
            let progress = Progress {
                slabs_done: u64::from(delta.front),
                slabs_total,
                faces_in: st.faces_in,
                faces_out: st.faces_out,
                resident_faces: st.faces_resident as u64,
                queued: [depth.cubes.len(), depth.deltas.len(), depth.out.len()],
            };
            observer(&progress);
            if u64::from(delta.front) % log_every == 0 || delta.end_of_volume {
                info!(
                    slab = progress.slabs_done,
                    of = slabs_total,
                    faces_in = progress.faces_in,
                    faces_out = progress.faces_out,
                    resident = progress.resident_faces,
                    queued = ?progress.queued,
                    "progress"
                );
            }
        }
        if delta.end_of_volume {
            send(ctl, &tx, ToWriter::End)?;
            return Ok((busy.as_secs_f64(), simplifier.stats()));
        }
    }
    Err(Stop::Disconnected)
}

/// What the writer needs to refuse an empty surface.
#[derive(Clone, Copy)]
struct EmptyCheck<'a> {
    input: &'a str,
    iso: f32,
}

fn write_stage(
    mut sink: Sink,
    rx: Receiver<ToWriter>,
    empty: Option<EmptyCheck<'_>>,
    plan: Option<&Plan>,
    grid: Grid,
    ctl: &Control<'_>,
) -> StageResult<(f64, crate::sink::SinkStats)> {
    let _span = info_span!("write").entered();
    let mut busy = Duration::ZERO;
    while let Some(msg) = recv(ctl, &rx)? {
        let t = Instant::now();
        match msg {
            ToWriter::Batch(batch) => sink.write(&batch)?,
            ToWriter::Cut(cut) => {
                if let Some(plan) = plan {
                    save_checkpoint(&mut sink, *cut, plan, grid)?;
                }
            }
            ToWriter::End => {
                if let Some(check) = empty
                    && sink.triangles() == 0
                {
                    // The reader has finished: the range covers the whole volume.
                    let range = *ctl.range.lock().unwrap_or_else(|p| p.into_inner());
                    return Err(Stop::Failed(RunError::EmptySurface {
                        input: check.input.to_string(),
                        iso: check.iso,
                        range: range.describe(),
                    }));
                }
                let stats = sink.finish()?;
                busy += t.elapsed();
                return Ok((busy.as_secs_f64(), stats));
            }
        }
        busy += t.elapsed();
    }
    // Upstream hung up before the end: dropping the sink removes the partial file (unless a
    // checkpoint refers to it).
    Err(Stop::Disconnected)
}

/// The writer's end of the cut: the output's files are flushed and fsynced to the saved lengths
/// first, then the checkpoint is written atomically.
fn save_checkpoint(sink: &mut Sink, cut: Cut, plan: &Plan, grid: Grid) -> Result<(), RunError> {
    let t = Instant::now();
    let ckpt = Checkpoint {
        job: plan.job,
        input: plan.input.clone(),
        slabs_total: grid.dims[2] - 1,
        parts: Parts {
            reader: cut.reader,
            extract: cut.extract,
            detect: cut.detect,
            simplify: cut.simplify,
            sink: sink.checkpoint()?,
        },
    };
    checkpoint::write(&plan.path, &ckpt)?;
    info!(
        slab = ckpt.slabs_done(),
        of = ckpt.slabs_total,
        bytes = ckpt.parts.simplify.len() + ckpt.parts.detect.len(),
        seconds = t.elapsed().as_secs_f64(),
        "checkpoint saved"
    );
    Ok(())
}
