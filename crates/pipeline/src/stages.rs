//! The stages of a run and their wiring: read -> extract (a pool of workers, see
//! `extract_pool.rs`) -> detect -> simplify (one simplifier, or a cascade's two stages, each on
//! its own thread) -> write, each on its own thread(s), joined by bounded channels of [`Msg`].
//! How a stage is driven, timed and stopped is in `flow.rs`; this file says
//! what each stage does with one input and at its end.

use std::convert::Infallible;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

use crossbeam_channel::{Receiver, Sender, bounded, unbounded};
use isostream_detect::{DetectStats, Detector, MeshDelta};
use isostream_extract::{CubeBatch, ExtractStats};
use isostream_prune::{Filter, PruneStats};
use isostream_simplify::{Front, Interrupted, Join, OutBatch, Serial, Simplifier, SimplifyStats};
use isostream_smesh::Completed;
use tracing::{debug, info};

use crate::attributes::SliceReader;
use crate::checkpoint::{self, Checkpoint, Cut, InputIdentity, Parts, ReaderState};
use crate::config::CheckpointEvery;
use crate::error::RunError;
use crate::extract_pool::{
    COUNT_REPLY_BATCHES, Ordered, RUN_REPLY_BATCHES, ReadStep, Schedule, SlabReply, WorkStep,
};
use crate::flow::{Control, Msg, Outbox, StageResult, Step, Stop, run};
use crate::range::DataRange;
use crate::sink::Sink;

/// Which pass over the volume a [`Progress`] is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pass {
    /// The first pass of `[output] faces`, `[simplify] min_component_faces` or a stage count
    /// decided by the largest slab: it counts the faces (or takes the census of components)
    /// before the run, and can take as long as the run's extraction (20 s and more at
    /// `upsample` 16), so it reports its slabs too.
    First,
    /// The run itself: extraction, simplification, output.
    #[default]
    Run,
}

impl Pass {
    /// The name in `progress` log lines and the service's events.
    pub fn name(self) -> &'static str {
        match self {
            Pass::First => "first",
            Pass::Run => "run",
        }
    }
}

/// Snapshot passed to the progress observer as each pass begins ([`Progress::begins`]) and after
/// every completed slab, of the first pass (when the job makes one) and then of the run.
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    pub pass: Pass,
    pub slabs_done: u64,
    /// Slabs done before this run started: past 0 when it resumed a checkpoint (a rate or an
    /// ETA counts the slabs done since, over the time since the start).
    pub slabs_at_start: u64,
    pub slabs_total: u64,
    /// The faces are the run's: the first pass reports 0 (its extractors only count, and the
    /// count is summed at its end).
    pub faces_in: u64,
    pub faces_out: u64,
    /// The part of `faces_in` and `faces_out` restored from the checkpoint this run resumed (0
    /// on a fresh run): a counter of the work done counts from here (the service counted a
    /// resumed run's restored faces again, as if new).
    pub faces_in_at_start: u64,
    pub faces_out_at_start: u64,
    /// The faces the run's simplifier receives in all (`faces_in` at its end), when a first pass
    /// counted them before the run: its ETA paces by them ([`crate::eta_seconds`]). `None`
    /// otherwise and in the first pass. The job's monitor fills it in: the stages leave `None`.
    pub faces_total: Option<u64>,
    pub resident_faces: u64,
    /// Slabs extracted or being extracted that the detector has not taken yet, and batches
    /// waiting in the detect->simplify and simplify->write channels (0 in the first pass).
    pub queued: [usize; 3],
}

impl Progress {
    /// The first pass's slab `slab` done (its faces are counted at its end).
    pub(crate) fn first_pass(slab: u64, slabs_total: u64) -> Self {
        Progress {
            slabs_done: slab + 1,
            ..Progress::fresh(Pass::First, slabs_total)
        }
    }

    /// `pass` of `slabs_total` slabs begins from the volume's start (not a resumed run):
    /// [`Progress::begins`] at slab 0, the report observers' own tests build on.
    pub fn fresh(pass: Pass, slabs_total: u64) -> Self {
        Progress::begins(pass, RunStart::default(), slabs_total)
    }

    /// `pass` begins at `start` (past 0 for a resumed run) of `slabs_total` slabs, nothing of
    /// it done yet (`slabs_done == slabs_at_start`): reported before its first slab so that an
    /// observer shows the pass's real total from its start, and no pace (the bar showed "slab
    /// 0/1" and a rate of thousands of slabs a second until the first slab).
    pub(crate) fn begins(pass: Pass, start: RunStart, slabs_total: u64) -> Self {
        Progress {
            pass,
            slabs_done: start.slabs,
            slabs_at_start: start.slabs,
            slabs_total,
            faces_in: start.faces_in,
            faces_out: start.faces_out,
            faces_in_at_start: start.faces_in,
            faces_out_at_start: start.faces_out,
            faces_total: None,
            resident_faces: 0,
            queued: [0; 3],
        }
    }

    /// The run's faces as an ETA paces by them, when their total is known.
    pub fn faces_done(&self) -> Option<crate::Done> {
        self.faces_total.map(|total| crate::Done {
            start: self.faces_in_at_start,
            now: self.faces_in,
            total,
        })
    }
}

/// Busy time of each stage (time blocked on channels excluded). `extract` adds up the workers.
#[derive(Debug, Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
pub struct StageSeconds {
    pub read: f64,
    pub extract: f64,
    pub detect: f64,
    /// `None` when the job does not prune.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prune: Option<f64>,
    pub simplify: f64,
    /// The second simplifier of a cascade (`[pipeline] simplify_stages = 2`), 0 without one.
    pub simplify_second: f64,
    pub write: f64,
}

pub(crate) struct StageOutputs {
    pub seconds: StageSeconds,
    pub extract: ExtractStats,
    pub detect: DetectStats,
    /// `None` when the job does not prune.
    pub prune: Option<PruneStats>,
    pub simplify: SimplifyStats,
    /// A cascade's two stages, each on its own (`simplify` adds them up); `None` without one.
    pub simplify_stages: Option<[SimplifyStats; 2]>,
    pub sink: crate::sink::SinkStats,
    /// The output, complete under its temporary name.
    pub output: Completed,
    /// The values the run saw (the whole volume's, as read in f32), for the precision warning.
    pub range: DataRange,
}

pub(crate) struct Stages<'a> {
    /// The iso volume and the attributes, read slice by slice.
    pub reader: SliceReader,
    /// What the volume is, for the empty-surface error.
    pub input: String,
    /// The job's iso, as written: extraction compares in `iso as f32`, and the empty-surface
    /// error tells the two apart (`DataRange::empty_surface`).
    pub iso: f64,
    /// `[simplify] min_component_faces`: the stage between the detector and the simplifier
    /// (restored already when resuming); `None`: no such stage.
    pub filter: Option<Filter>,
    pub simplifier: Simplifier,
    /// The second stage of a cascade: `simplifier` is then its first.
    pub second: Option<Simplifier>,
    pub sink: Sink,
    pub capacity: usize,
    pub batch_triangles: usize,
    /// Extraction workers (`[pipeline] threads`, at least 1).
    pub threads: usize,
    /// Empty-space skipping (`[extract] skip_empty`).
    pub skip_empty: bool,
    /// Accept a surface without any triangle (`[output] allow_empty`); else it is an error.
    pub allow_empty: bool,
    pub cancel: &'a AtomicBool,
    pub observer: &'a (dyn Fn(&Progress) + Sync),
    /// Save checkpoints (`None`: never).
    pub checkpoints: Option<Plan>,
    /// Continue from a checkpoint (the simplifier and the sink above are restored already, the
    /// reader is at the checkpoint's carried slice).
    pub resume: Option<Resume>,
}

/// When and where the run saves checkpoints, and what identifies it.
pub(crate) struct Plan {
    pub every: CheckpointEvery,
    pub path: PathBuf,
    pub job: u64,
    pub input: InputIdentity,
    /// The first pass's counts, saved with every checkpoint (a resume does not count again).
    pub first_pass: Option<checkpoint::FirstPassCounts>,
}

/// What the stages before the simplifier saved at the checkpoint a run continues from.
pub(crate) struct Resume {
    pub reader: ReaderState,
    pub extract: ExtractStats,
    pub detector: Detector,
}

impl Stages<'_> {
    pub fn run(self) -> Result<StageOutputs, RunError> {
        let Stages {
            reader,
            input,
            iso,
            filter,
            simplifier,
            second,
            sink,
            capacity,
            batch_triangles,
            threads,
            skip_empty,
            allow_empty,
            cancel,
            observer,
            checkpoints,
            resume,
        } = self;
        let grid = reader.grid();
        let first = resume.as_ref().map_or(0, |r| r.reader.z);
        let schedule = Schedule::new(checkpoints.as_ref().map(|p| p.every), first, grid.dims[2]);
        let carried = resume.as_ref().map(|r| r.reader.carried);
        let (range, extract_before, detector) = match resume {
            Some(r) => (r.reader.range, r.extract, r.detector),
            None => (
                DataRange::default(),
                ExtractStats::default(),
                Detector::new(grid.dims),
            ),
        };
        let threads = threads.max(1);
        let deltas = capacity.min(DELTA_DEPTH);
        let (delta_tx, delta_rx) = bounded::<Msg<MeshDelta>>(deltas);
        // With pruning, the detector sends to the filter, which sends on to the simplifier.
        let (detect_tx, pruned) = insert_stage(filter, delta_tx, deltas);
        let (out_tx, out_rx) = bounded::<Msg<OutBatch>>(capacity);
        // With a cascade the first simplifier's batches go to the second, whose go to the writer.
        let (first_tx, second) = insert_stage(second, out_tx, capacity);
        let (order_tx, order_rx) = bounded::<Msg<Receiver<SlabReply>>>(threads);
        // `[pipeline] threads = 1` keeps the whole job on one core, its final decimation too.
        let last = &FinalWorkers {
            threads: threads > 1,
        };
        let depth = Depths {
            slabs: order_rx.clone(),
            deltas: delta_rx.clone(),
            out: out_rx.clone(),
            second: second.as_ref().map(|(s, _, _)| SecondCounts::of(s)),
        };
        let depth = &depth;
        let empty = (!allow_empty).then_some(EmptyCheck { input: &input, iso });
        let ctl = Control::new(cancel);
        let ctl = &ctl;
        ctl.add_range(&range);
        let start = RunStart::of(first, &simplifier, second.as_ref().map(|(s, _, _)| s));

        let extraction = Extraction {
            reader,
            iso: iso as f32,
            batch_triangles,
            threads,
            skip_empty,
            first,
            schedule,
            carried,
            stats: extract_before,
            counting: false,
        };
        std::thread::scope(|s| {
            let (read, workers) = extraction.spawn(s, order_tx, ctl, RUN_REPLY_BATCHES);
            let detect = s.spawn(move || {
                let step = DetectStep {
                    detector,
                    group: MeshDelta::default(),
                    pending: None,
                };
                run(
                    "detect",
                    ctl,
                    step,
                    Ordered::new(order_rx, extract_before, range),
                    Outbox::new(ctl, detect_tx),
                )
            });
            let prune = pruned.map(|(filter, rx, tx)| {
                s.spawn(move || run("prune", ctl, PruneStep(filter), rx, Outbox::new(ctl, tx)))
            });
            let plan = checkpoints.as_ref();
            let simplify = s.spawn(move || {
                let slabs_total = grid.dims[2] - 1;
                let step = SimplifyStep {
                    simplifier,
                    ctl,
                    checkpoint: plan.map(|p| p.path.as_path()),
                    front: None,
                    last_front: u32::try_from(first).unwrap_or(u32::MAX),
                    start,
                    slabs_total,
                    log_every: (slabs_total / 20).max(1),
                    depth,
                    observer,
                    last,
                };
                run("simplify", ctl, step, delta_rx, Outbox::new(ctl, first_tx))
            });
            let simplify_second = second.map(|(simplifier, rx, tx)| {
                s.spawn(move || {
                    let step = SecondStep {
                        simplifier,
                        ctl,
                        faces_in: 0,
                        slabs_total: grid.dims[2] - 1,
                        start,
                        depth,
                        observer,
                        last,
                    };
                    run("simplify2", ctl, step, rx, Outbox::new(ctl, tx))
                })
            });
            let write = s.spawn(move || {
                let step = WriteStep {
                    sink,
                    empty,
                    ctl,
                    plan,
                    slabs_total: grid.dims[2] - 1,
                };
                run("write", ctl, step, out_rx, Outbox::none(ctl))
            });

            // Join every stage. The first failure recorded (in time, whichever stage) is the
            // cause; a panic counts as a failure of its stage.
            let read = join(read, "read");
            let extract = join_workers(workers);
            let detect = join(detect, "detect");
            let prune = prune.map(|h| join(h, "prune")).transpose();
            let simplify = join(simplify, "simplify");
            let simplify_second = simplify_second.map(|h| join(h, "simplify2"));
            let simplify = match (simplify, simplify_second) {
                (Ok((s1, first)), Some(Ok((s2, second)))) => Ok((
                    (s1, s2),
                    SimplifyStats::of_cascade(&first, &second),
                    Some([first, second]),
                )),
                (_, Some(Err(e))) | (Err(e), _) => Err(e),
                (Ok((s1, first)), None) => Ok(((s1, 0.0), first, None)),
            };
            let write = join(write, "write");
            match (read, extract, detect, prune, simplify, write) {
                (
                    Ok((read, ())),
                    Ok((extract_s, extract)),
                    Ok((detect_s, detect)),
                    Ok(prune),
                    Ok((simplify_s, simplify, simplify_stages)),
                    Ok((write_s, (sink, output))),
                ) => Ok(StageOutputs {
                    seconds: StageSeconds {
                        read,
                        extract: extract_s,
                        detect: detect_s,
                        prune: prune.map(|(s, _)| s),
                        simplify: simplify_s.0,
                        simplify_second: simplify_s.1,
                        write: write_s,
                    },
                    extract,
                    detect,
                    prune: prune.map(|(_, stats)| stats),
                    simplify,
                    simplify_stages,
                    sink,
                    output,
                    range: ctl.range(),
                }),
                (read, extract, detect, prune, simplify, write) => {
                    Err(ctl.take_first().unwrap_or_else(|| {
                        first_failure([
                            read.err(),
                            extract.err(),
                            detect.err(),
                            prune.err(),
                            simplify.err(),
                            write.err(),
                        ])
                    }))
                }
            }
        })
    }
}

/// The front half of a run, shared with the counting pass of `[output] faces`: the reader and the
/// extraction pool, answering slabs in order on `order`.
pub(crate) struct Extraction {
    /// At slice `first`.
    pub reader: SliceReader,
    pub iso: f32,
    pub batch_triangles: usize,
    /// Workers, at least 1.
    pub threads: usize,
    pub skip_empty: bool,
    /// The first slice to read: 0, or a resumed run's carried slice.
    pub first: u64,
    /// When to send the checkpoint marker.
    pub schedule: Schedule,
    /// Resuming: the hash slice `first` must have.
    pub carried: Option<u64>,
    /// The counters of the slabs before `first`.
    pub stats: ExtractStats,
    /// Count the triangles without making them (`Extractor::counting`): the batches are empty.
    pub counting: bool,
}

type Handle<'s, T> = std::thread::ScopedJoinHandle<'s, StageResult<T>>;
/// The reader's handle and the workers' (busy seconds and counters each).
type ExtractionHandles<'s> = (Handle<'s, (f64, ())>, Vec<Handle<'s, (f64, ExtractStats)>>);

impl Extraction {
    /// Spawns the reader and the workers; the slabs' batches come back in order on `order`, at
    /// most `reply_batches` waiting per slab.
    fn spawn<'s, 'e: 's>(
        self,
        s: &'s std::thread::Scope<'s, 'e>,
        order: Sender<Msg<Receiver<SlabReply>>>,
        ctl: &'e Control<'e>,
        reply_batches: usize,
    ) -> ExtractionHandles<'s> {
        let Extraction {
            reader,
            iso,
            batch_triangles,
            threads,
            skip_empty,
            first,
            schedule,
            carried,
            mut stats,
            counting,
        } = self;
        let grid = reader.grid();
        let threads = threads.max(1);
        let (job_tx, job_rx) = unbounded();
        let read = s.spawn(move || {
            let step = ReadStep::new(
                reader,
                job_tx,
                threads,
                ctl,
                schedule,
                carried,
                reply_batches,
            );
            let slices = first..grid.dims[2];
            run("read", ctl, step, slices, Outbox::new(ctl, order))
        });
        let workers = (0..threads)
            .map(|_| {
                let jobs = job_rx.clone();
                // The counters before `first` go to the first worker.
                let stats = std::mem::take(&mut stats);
                s.spawn(move || {
                    let step = WorkStep::new(grid, iso, batch_triangles, skip_empty, stats);
                    let step = if counting { step.counting() } else { step };
                    run("extract", ctl, step, jobs, Outbox::none(ctl))
                })
            })
            .collect();
        (read, workers)
    }

    /// Extracts the whole volume and hands every batch, in slab order, to `visit` on the calling
    /// thread (the stage `name` in the logs); nothing is kept. Returns the extractors'
    /// counters. The first pass of `[output] faces` counts (and takes the census of components)
    /// with it; `isostream measure` streams the full-resolution surface through it.
    pub fn visit(
        self,
        name: &'static str,
        cancel: &AtomicBool,
        visit: impl FnMut(&CubeBatch),
    ) -> Result<ExtractStats, RunError> {
        let ctl = Control::new(cancel);
        let ctl = &ctl;
        let (order_tx, order_rx) = bounded(self.threads.max(1));
        std::thread::scope(|s| {
            let (read, workers) = self.spawn(s, order_tx, ctl, COUNT_REPLY_BATCHES);
            let drain = run(
                name,
                ctl,
                Visit(visit),
                Ordered::new(order_rx, ExtractStats::default(), DataRange::default()),
                Outbox::none(ctl),
            );
            let read = join(read, "read");
            match (read, join_workers(workers), drain) {
                (Ok(_), Ok((_, stats)), Ok(_)) => Ok(stats),
                (read, extract, drain) => Err(ctl.take_first().unwrap_or_else(|| {
                    first_failure([read.err(), extract.err(), drain.err(), None, None, None])
                })),
            }
        })
    }
}

/// [`Extraction::visit`]'s last stage: each batch to the visitor.
struct Visit<F>(F);

impl<F: FnMut(&CubeBatch)> Step for Visit<F> {
    type In = CubeBatch;
    type Out = Infallible;
    type Done = ();
    fn batch(&mut self, batch: CubeBatch, _: &mut Outbox<'_, Infallible>) -> StageResult<()> {
        (self.0)(&batch);
        Ok(())
    }
    fn end(self, _: &mut Outbox<'_, Infallible>) -> StageResult<()> {
        Ok(())
    }
}

/// Joins the workers: their busy seconds and counters added up.
fn join_workers(workers: Vec<Handle<'_, (f64, ExtractStats)>>) -> StageResult<(f64, ExtractStats)> {
    let mut total = Ok((0.0, ExtractStats::default()));
    for w in workers {
        total = match (total, join(w, "extract")) {
            (Ok((s, mut st)), Ok((ws, wst))) => {
                st += wst;
                Ok((s + ws, st))
            }
            (Err(e), _) | (_, Err(e)) => Err(e),
        };
    }
    total
}

fn first_failure(stops: [Option<Stop>; 6]) -> RunError {
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

/// How the last simplifier runs its final decimation (`isostream_simplify::Join`): cut in two
/// when it is large, whatever the machine, so that the output never depends on the thread
/// count; the two workers then run on two threads (`[pipeline] threads` above 1: by then every
/// other stage has finished and the second core is free) or one after the other.
struct FinalWorkers {
    threads: bool,
}

/// Fewest held faces for which the final decimation is cut in two. A cut costs a pass over
/// the surface and the second worker's copies, and its rounds wait for the slower side: at the
/// 60-70 k faces the default budget holds at the end (engine and bonsai at R = 0.01) the final
/// decimation took as long cut as not (0.38-0.46 s against 0.41 s on engine), while in core it
/// took engine's job at R = 0.01 from 6.05 to 3.02 s and mni152's from 2.71 to 1.73 s
/// (docs/performance.md, "Forty-fifth session").
const MIN_CUT_FACES: usize = 150_000;

impl Join for FinalWorkers {
    fn worth_cutting(&self, faces: usize) -> bool {
        faces >= MIN_CUT_FACES
    }

    fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        if !self.threads {
            return Serial.join(a, b);
        }
        on_two_threads(a, b);
    }
}

/// `a` on a helper thread while `b` runs on this one (a panic in either is this thread's):
/// the final workers' join and `isostream measure`'s halves ([`crate::MeasureHalves`]).
pub(crate) fn on_two_threads(a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
    std::thread::scope(|s| {
        let helper = s.spawn(a);
        b();
        if let Err(panic) = helper.join() {
            std::panic::resume_unwind(panic);
        }
    });
}

/// Deltas a channel from the detector may hold (at most `channel_capacity`). The detector
/// is never the slow side (bonsai: 0.18 s of a 5 s run; 17 s of 3,090 s at 2041^3), so deeper
/// queues only hold full-resolution faces the simplifier is not ready for: up to 8 batches of
/// 8,192 faces on slices large enough to fill them: bonsai at 2041^3 peaked at 65.4 MiB with
/// this depth against 69.0 with 8, same bytes, same speed at 256^3 (docs/scale.md, "The 2041^3
/// peak is the widest section's high-water mark"). The simplifier stages' own links keep
/// `channel_capacity`: a cascade's two stages work in bursts, and a depth of 2 between them too
/// made bonsai about 15 % slower (under load).
const DELTA_DEPTH: usize = 2;

/// An optional stage put in front of `downstream`: the sender its producer then writes to, and
/// the stage with its own input and `downstream` as its output.
type Inserted<S, T> = (
    Sender<Msg<T>>,
    Option<(S, Receiver<Msg<T>>, Sender<Msg<T>>)>,
);

fn insert_stage<S, T>(
    stage: Option<S>,
    downstream: Sender<Msg<T>>,
    capacity: usize,
) -> Inserted<S, T> {
    match stage {
        Some(stage) => {
            let (tx, rx) = bounded(capacity);
            (tx, Some((stage, rx, downstream)))
        }
        None => (downstream, None),
    }
}

/// Queue depths for the progress observer.
struct Depths {
    slabs: Receiver<Msg<Receiver<SlabReply>>>,
    deltas: Receiver<Msg<MeshDelta>>,
    out: Receiver<Msg<OutBatch>>,
    /// A cascade's second stage: what it wrote and holds, so that progress reports the run's
    /// output, not the intermediate surface.
    second: Option<SecondCounts>,
}

impl Depths {
    fn queued(&self) -> [usize; 3] {
        [self.slabs.len(), self.deltas.len(), self.out.len()]
    }
}

struct SecondCounts {
    faces_out: AtomicU64,
    resident: AtomicU64,
}

impl SecondCounts {
    /// Starts at what the second stage holds already: a resumed run's is restored from the
    /// checkpoint, and the first stage reports progress before the second has taken a batch
    /// (from zero, a run resumed at slab 1600 reported 0 faces written for its first slabs).
    fn of(second: &Simplifier) -> Self {
        let st = second.stats();
        SecondCounts {
            faces_out: AtomicU64::new(st.faces_out),
            resident: AtomicU64::new(st.faces_resident as u64),
        }
    }
}

/// Cube batches -> indexed deltas, one per group of batches (`CubeBatch::ends_group`: the
/// extraction workers send smaller batches than the simplifier's unit of work, which the
/// groups keep). The delta of the last group is held back until the end is known, so the
/// detector's final release joins it and the simplifier sees one final delta.
struct DetectStep {
    detector: Detector,
    /// The group's batches so far, converted.
    group: MeshDelta,
    pending: Option<MeshDelta>,
}

impl Step for DetectStep {
    type In = CubeBatch;
    type Out = MeshDelta;
    type Done = DetectStats;

    fn batch(&mut self, batch: CubeBatch, out: &mut Outbox<'_, MeshDelta>) -> StageResult<()> {
        // `process` appends: the group's delta is its batches' deltas end to end.
        self.detector.process(&batch, &mut self.group);
        if !batch.ends_group {
            return Ok(());
        }
        let delta = std::mem::take(&mut self.group);
        match self.pending.replace(delta) {
            Some(ready) => out.send(ready),
            None => Ok(()),
        }
    }

    /// The delta held back goes out first: the cut is never after the last slab, so a later
    /// batch still carries the final release, and the simplifier sees the same deltas. (Cuts
    /// come between slabs, where no group is open.)
    fn cut(&mut self, mut cut: Box<Cut>, out: &mut Outbox<'_, MeshDelta>) -> StageResult<()> {
        debug_assert!(self.group.triangles.is_empty() && self.group.vertices.is_empty());
        if let Some(ready) = self.pending.take() {
            out.send(ready)?;
        }
        cut.detect = checkpoint::encode(&self.detector.snapshot());
        out.cut(cut)
    }

    fn end(mut self, out: &mut Outbox<'_, MeshDelta>) -> StageResult<DetectStats> {
        let mut last = self.pending.take().unwrap_or_default();
        self.detector.finish(&mut last);
        out.send(last)?;
        Ok(self.detector.stats())
    }
}

/// Deltas -> the same deltas without the components below `[simplify] min_component_faces`
/// (see `isostream_prune`), one out per delta in, with the same front.
struct PruneStep(Filter);

impl Step for PruneStep {
    type In = MeshDelta;
    type Out = MeshDelta;
    type Done = PruneStats;

    fn batch(&mut self, delta: MeshDelta, out: &mut Outbox<'_, MeshDelta>) -> StageResult<()> {
        out.send(self.0.process(delta))
    }

    fn cut(&mut self, mut cut: Box<Cut>, out: &mut Outbox<'_, MeshDelta>) -> StageResult<()> {
        cut.prune = checkpoint::encode(&self.0.snapshot());
        out.cut(cut)
    }

    /// The census's counts, which the faces dropped must match: both passes saw one stream.
    fn end(self, _: &mut Outbox<'_, MeshDelta>) -> StageResult<PruneStats> {
        let stats = self.0.stats();
        if self.0.dropped_faces() != stats.faces_pruned {
            return Err(Stop::Failed(RunError::Internal {
                stage: "prune",
                reason: format!(
                    "the census counted {} faces in small components but {} were dropped",
                    stats.faces_pruned,
                    self.0.dropped_faces()
                ),
            }));
        }
        Ok(stats)
    }
}

/// Runs one of the simplifier's long calls (a pass, the final decimation) with the run's stop
/// flags as its interrupt: a cancel or another stage's failure seen in the middle ends the stage
/// as it would between two batches (Ctrl-C: exit 130, no output, the last checkpoint kept). The
/// flags were looked at only between batches, and a classical run's Ctrl-C after the sweep
/// waited seconds (minutes on large volumes) for a final decimation whose result was dropped.
fn interruptible(
    ctl: &Control<'_>,
    call: impl FnOnce(&(dyn Fn() -> bool + Sync)) -> Result<(), Interrupted>,
) -> StageResult<()> {
    call(&|| ctl.check().is_err()).map_err(|Interrupted| ctl.stop())
}

/// Where a run started: the front and face totals of the checkpoint it resumed, 0 on a fresh
/// run ([`Progress::slabs_at_start`], [`Progress::faces_in_at_start`]).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct RunStart {
    pub(crate) slabs: u64,
    pub(crate) faces_in: u64,
    pub(crate) faces_out: u64,
}

impl RunStart {
    /// A run beginning at slab `slabs` with these simplifiers: the faces a resumed run restored
    /// are the first simplifier's in, and the written ones of the last (a cascade's second).
    pub(crate) fn of(slabs: u64, simplifier: &Simplifier, second: Option<&Simplifier>) -> Self {
        let first = simplifier.stats();
        RunStart {
            slabs,
            faces_in: first.faces_in,
            faces_out: second.map_or(first.faces_out, |s| s.stats().faces_out),
        }
    }
}

/// Deltas -> simplified batches. A delta is added as soon as it arrives, but its batch is closed
/// (`end_batch`) only when the next one arrives: the last one is closed by `finish` instead.
struct SimplifyStep<'a> {
    simplifier: Simplifier,
    /// Looked at during the simplifier's long calls ([`interruptible`]).
    ctl: &'a Control<'a>,
    /// Where checkpoints go (`None`: no checkpoints): a cut begins the file with the
    /// simplifier's state (`checkpoint::Partial`).
    checkpoint: Option<&'a std::path::Path>,
    /// The front of the delta added last, whose batch is still open.
    front: Option<Front>,
    last_front: u32,
    /// Where this run started (the resumed checkpoint's front and faces, or 0).
    start: RunStart,
    slabs_total: u64,
    log_every: u64,
    depth: &'a Depths,
    observer: &'a (dyn Fn(&Progress) + Sync),
    /// How the last simplifier runs its final decimation (`isostream_simplify::Join`).
    last: &'a dyn Join,
}

impl SimplifyStep<'_> {
    /// Sends what the simplifier emitted and reports progress when the front moved.
    fn emit(
        &mut self,
        out: OutBatch,
        front: u32,
        tx: &mut Outbox<'_, OutBatch>,
    ) -> StageResult<()> {
        if let Some(faces) = self.simplifier.in_core_overflow() {
            return Err(Stop::Failed(RunError::ClassicalOverBudget { faces }));
        }
        // A cascade's first stage sends every batch: its handoff moves the second stage's front.
        if !out.elements.is_empty() || out.handoff.is_some() {
            tx.send(out)?;
        }
        let last = u64::from(front) == self.slabs_total;
        // A cascade's second stage reports the end, with the run's totals.
        if last && self.depth.second.is_some() {
            return Ok(());
        }
        if front > self.last_front || last {
            self.last_front = front;
            let st = self.simplifier.stats();
            let (faces_out, resident) = match &self.depth.second {
                Some(c) => (
                    c.faces_out.load(Ordering::Relaxed),
                    c.resident.load(Ordering::Relaxed) + st.faces_resident as u64,
                ),
                None => (st.faces_out, st.faces_resident as u64),
            };
            let progress = Progress {
                pass: Pass::Run,
                slabs_done: u64::from(front),
                slabs_at_start: self.start.slabs,
                slabs_total: self.slabs_total,
                faces_in: st.faces_in,
                faces_out,
                faces_in_at_start: self.start.faces_in,
                faces_out_at_start: self.start.faces_out,
                faces_total: None,
                resident_faces: resident,
                queued: self.depth.queued(),
            };
            (self.observer)(&progress);
            // Every 5 %, with the queue depths, for debugging; users get the monitor's timed
            // `progress` lines (rate, ETA, RSS).
            if u64::from(front) % self.log_every == 0 || last {
                debug!(
                    slab = progress.slabs_done,
                    of = self.slabs_total,
                    faces_in = progress.faces_in,
                    faces_out = progress.faces_out,
                    resident = progress.resident_faces,
                    queued = ?progress.queued,
                    "progress"
                );
            }
        }
        Ok(())
    }
}

impl Step for SimplifyStep<'_> {
    type In = MeshDelta;
    type Out = OutBatch;
    type Done = SimplifyStats;

    fn batch(&mut self, delta: MeshDelta, tx: &mut Outbox<'_, OutBatch>) -> StageResult<()> {
        if let Some(front) = self.front.take() {
            let mut out = OutBatch::default();
            interruptible(self.ctl, |stop| {
                self.simplifier.end_batch_with(front, &mut out, stop)
            })?;
            self.emit(out, front.slabs, tx)?;
        }
        let stride = delta
            .attrs
            .len()
            .checked_div(delta.vertices.len())
            .unwrap_or(0);
        for (i, v) in delta.vertices.iter().enumerate() {
            let attrs = delta.attrs.get(i * stride..(i + 1) * stride).unwrap_or(&[]);
            self.simplifier.add_vertex(v.id, v.pos, v.rank, attrs);
        }
        for &tri in &delta.triangles {
            self.simplifier.add_triangle(tri);
        }
        for &id in &delta.modifiable {
            self.simplifier.set_modifiable(id);
        }
        self.front = Some(Front {
            slabs: delta.front,
            rows: delta.rows,
        });
        Ok(())
    }

    /// The open batch is closed first (as the next delta would close it: more slabs follow a
    /// cut), so the saved simplifier is between two batches and its output precedes the cut.
    fn cut(&mut self, mut cut: Box<Cut>, tx: &mut Outbox<'_, OutBatch>) -> StageResult<()> {
        if let Some(front) = self.front.take() {
            let mut out = OutBatch::default();
            interruptible(self.ctl, |stop| {
                self.simplifier.end_batch_with(front, &mut out, stop)
            })?;
            self.emit(out, front.slabs, tx)?;
        }
        if let Some(path) = self.checkpoint {
            let t = Instant::now();
            let partial = checkpoint::Partial::begin(path, &self.simplifier)?;
            debug!(
                bytes = partial.simplify_len(),
                seconds = t.elapsed().as_secs_f64(),
                "simplifier state written for a checkpoint"
            );
            cut.simplify = Some(partial);
        }
        tx.cut(cut)
    }

    fn end(mut self, tx: &mut Outbox<'_, OutBatch>) -> StageResult<SimplifyStats> {
        let mut out = OutBatch::default();
        // A cascade's first stage ends while the second still works: no core is free.
        let join: &dyn Join = match self.depth.second {
            Some(_) => &Serial,
            None => self.last,
        };
        interruptible(self.ctl, |stop| {
            self.simplifier.finish_with(&mut out, join, stop)
        })?;
        let front = u32::try_from(self.slabs_total).unwrap_or(u32::MAX);
        self.emit(out, front, tx)?;
        Ok(self.simplifier.stats())
    }
}

/// A cascade's second stage: the first stage's batches -> simplified batches.
struct SecondStep<'a> {
    simplifier: Simplifier,
    /// Looked at during the simplifier's long calls ([`interruptible`]).
    ctl: &'a Control<'a>,
    /// Faces extracted so far, from the first stage's hand-offs.
    faces_in: u64,
    slabs_total: u64,
    /// Where this run started (see `SimplifyStep::start`).
    start: RunStart,
    depth: &'a Depths,
    observer: &'a (dyn Fn(&Progress) + Sync),
    last: &'a dyn Join,
}

impl Step for SecondStep<'_> {
    type In = OutBatch;
    type Out = OutBatch;
    type Done = SimplifyStats;

    fn batch(&mut self, batch: OutBatch, tx: &mut Outbox<'_, OutBatch>) -> StageResult<()> {
        let rear = self.simplifier.ingest(&batch);
        self.faces_in = batch.handoff.map_or(self.faces_in, |h| h.faces_in);
        let mut out = OutBatch::default();
        interruptible(self.ctl, |stop| {
            self.simplifier.end_batch_with(rear, &mut out, stop)
        })?;
        if let Some(c) = &self.depth.second {
            let st = self.simplifier.stats();
            c.faces_out.store(st.faces_out, Ordering::Relaxed);
            c.resident
                .store(st.faces_resident as u64, Ordering::Relaxed);
        }
        if !out.elements.is_empty() {
            tx.send(out)?;
        }
        Ok(())
    }

    /// Each batch is closed as it comes, so the state is between two batches here, after
    /// everything the first stage sent before the cut. It goes into the file the first stage
    /// began, after the first's state.
    fn cut(&mut self, mut cut: Box<Cut>, tx: &mut Outbox<'_, OutBatch>) -> StageResult<()> {
        if let Some(partial) = &mut cut.simplify {
            let t = Instant::now();
            let bytes = partial.append_second(&self.simplifier)?;
            debug!(
                bytes,
                seconds = t.elapsed().as_secs_f64(),
                "second simplifier's state written for a checkpoint"
            );
        }
        tx.cut(cut)
    }

    /// The run's last progress event comes from here (the first stage leaves it): only now are
    /// the written faces the run's totals.
    fn end(mut self, tx: &mut Outbox<'_, OutBatch>) -> StageResult<SimplifyStats> {
        let mut out = OutBatch::default();
        interruptible(self.ctl, |stop| {
            self.simplifier.finish_with(&mut out, self.last, stop)
        })?;
        if !out.elements.is_empty() {
            tx.send(out)?;
        }
        let st = self.simplifier.stats();
        (self.observer)(&Progress {
            pass: Pass::Run,
            slabs_done: self.slabs_total,
            slabs_at_start: self.start.slabs,
            slabs_total: self.slabs_total,
            faces_in: self.faces_in,
            faces_out: st.faces_out,
            faces_in_at_start: self.start.faces_in,
            faces_out_at_start: self.start.faces_out,
            faces_total: None,
            resident_faces: st.faces_resident as u64,
            queued: self.depth.queued(),
        });
        Ok(st)
    }
}

/// What the writer needs to refuse an empty surface.
#[derive(Clone, Copy)]
struct EmptyCheck<'a> {
    input: &'a str,
    iso: f64,
}

/// Simplified batches -> the output file, complete under its temporary name at the end (the run
/// gives it its final name).
struct WriteStep<'a, 'c> {
    sink: Sink,
    empty: Option<EmptyCheck<'a>>,
    ctl: &'c Control<'c>,
    plan: Option<&'a Plan>,
    slabs_total: u64,
}

impl Step for WriteStep<'_, '_> {
    type In = OutBatch;
    type Out = Infallible;
    type Done = (crate::sink::SinkStats, Completed);

    fn batch(&mut self, batch: OutBatch, _: &mut Outbox<'_, Infallible>) -> StageResult<()> {
        Ok(self.sink.write(&batch)?)
    }

    /// The end of the cut: the output's files are flushed and fsynced to the lengths saved,
    /// then the checkpoint is written atomically.
    fn cut(&mut self, cut: Box<Cut>, _: &mut Outbox<'_, Infallible>) -> StageResult<()> {
        let Some(plan) = self.plan else {
            return Ok(());
        };
        let t = Instant::now();
        let Cut {
            reader,
            extract,
            detect,
            prune,
            simplify,
        } = *cut;
        let partial = simplify.ok_or_else(|| RunError::Internal {
            stage: "write",
            reason: "a checkpoint marker passed the simplifier without its state".into(),
        })?;
        let ckpt = Checkpoint {
            job: plan.job,
            input: plan.input.clone(),
            slabs_total: self.slabs_total,
            parts: Parts {
                reader,
                extract,
                detect,
                prune,
                sink: self.sink.checkpoint()?,
            },
            first_pass: plan.first_pass,
            simplify: Default::default(),
            simplify_second: Default::default(),
        };
        let bytes = partial.finish(&ckpt)?;
        self.ctl.checkpoint_saved();
        info!(
            slab = ckpt.slabs_done(),
            of = ckpt.slabs_total,
            bytes,
            seconds = t.elapsed().as_secs_f64(),
            "checkpoint saved"
        );
        Ok(())
    }

    fn end(self, _: &mut Outbox<'_, Infallible>) -> StageResult<Self::Done> {
        if let Some(check) = self.empty
            && self.sink.triangles() == 0
        {
            // Every slab has been extracted: the range covers the whole volume.
            return Err(Stop::Failed(RunError::EmptySurface {
                input: check.input.to_string(),
                iso: check.iso,
                why: self.ctl.range().empty_surface(check.iso),
            }));
        }
        // Dropping the sink on any earlier error removes the partial file.
        Ok(self.sink.complete()?)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;
    use std::path::Path;

    use super::*;
    use crate::config::JobConfig;
    use crate::flow::{In, Inbox};

    /// Hands out `items`, then raises `cancel` as it says that the input ended. The runner
    /// looks at the flags before each input, not between the end of its input and the step's
    /// `end`: the cancel is first seen in the middle of the final decimation, as a Ctrl-C just
    /// after the sweep is.
    struct CancelAtEnd<'a, T> {
        items: VecDeque<T>,
        cancel: Option<&'a AtomicBool>,
    }

    impl<T> Inbox for CancelAtEnd<'_, T> {
        type Item = T;
        fn next(&mut self, _: &Control<'_>) -> StageResult<Option<In<T>>> {
            let next = self.items.pop_front();
            if let (None, Some(cancel)) = (&next, self.cancel) {
                cancel.store(true, Ordering::Relaxed);
            }
            Ok(next.map(In::Item))
        }
    }

    /// A job on a procedural sphere of 40^3 voxels: `simplify` its `[simplify]` table,
    /// `pipeline` its `[pipeline]` table.
    fn sphere(simplify: &str, pipeline: &str) -> JobConfig {
        let text = format!(
            "[input]\nshape = \"sphere\"\nsize = [40, 40, 40]\n[extract]\niso = 0\n\
             [simplify]\n{simplify}\n[output]\npath = \"o.smb\"\n[pipeline]\n{pipeline}\n"
        );
        JobConfig::parse(&text, Path::new("job.toml")).unwrap()
    }

    /// `job`'s simplifiers (a cascade's two, or one), the deltas its detector stage hands the
    /// first, and the slabs of its volume.
    fn prepare(job: &JobConfig) -> (Simplifier, Option<Simplifier>, Vec<MeshDelta>, u64) {
        let source = crate::open_source(&job.input).unwrap();
        let grid = source.grid();
        let (first, second) = crate::simplifier_configs(job, grid, job.simplify.rate(), None);
        let never = AtomicBool::new(false);
        let ctl = Control::new(&never);
        let (tx, rx) = unbounded();
        let mut step = DetectStep {
            detector: Detector::new(grid.dims),
            group: MeshDelta::default(),
            pending: None,
        };
        let mut out = Outbox::new(&ctl, tx);
        crate::whole_extraction(job, source)
            .visit("surface", &never, |batch| {
                let Ok(()) = step.batch(batch.clone(), &mut out) else {
                    panic!("the detector's stage failed");
                };
            })
            .unwrap();
        let Ok(_) = step.end(&mut out) else {
            panic!("the detector's stage failed at its end");
        };
        let simplifier = |c| Simplifier::new(c).unwrap();
        (
            simplifier(first),
            second.map(simplifier),
            received(&rx).sent,
            grid.dims[2] - 1,
        )
    }

    /// How a simplifier's stage ended, and what it sent.
    struct Outcome<T> {
        /// The stage reported success.
        finished: bool,
        /// The run's error was the user's cancel.
        cancelled: bool,
        sent: Vec<T>,
        /// Its `End` was sent.
        ended: bool,
    }

    fn received<T>(rx: &Receiver<Msg<T>>) -> Outcome<T> {
        let mut outcome = Outcome {
            finished: false,
            cancelled: false,
            sent: Vec::new(),
            ended: false,
        };
        for msg in rx.try_iter() {
            match msg {
                Msg::Batch(b) => outcome.sent.push(b),
                Msg::Cut(_) => panic!("no checkpoint in these runs"),
                Msg::End => outcome.ended = true,
            }
        }
        outcome
    }

    /// Runs `step` as the pipeline does over `items`; with `cancel_at_end`, the cancel flag
    /// rises once they have all been taken.
    fn run_stage<'a, S>(
        make: impl FnOnce(&'a Control<'a>) -> S,
        ctl: &'a Control<'a>,
        cancel: &'a AtomicBool,
        items: Vec<S::In>,
        cancel_at_end: bool,
    ) -> Outcome<S::Out>
    where
        S: Step,
    {
        let (tx, rx) = unbounded();
        let inbox = CancelAtEnd {
            items: items.into(),
            cancel: cancel_at_end.then_some(cancel),
        };
        let done = run("simplify", ctl, make(ctl), inbox, Outbox::new(ctl, tx));
        Outcome {
            finished: done.is_ok(),
            cancelled: matches!(ctl.take_first(), Some(RunError::Cancelled)),
            ..received(&rx)
        }
    }

    /// Queue depths for a step that reports none of them.
    fn depths(cascade: bool) -> Depths {
        Depths {
            slabs: bounded(0).1,
            deltas: bounded(0).1,
            out: bounded(0).1,
            second: cascade.then(|| SecondCounts {
                faces_out: AtomicU64::new(0),
                resident: AtomicU64::new(0),
            }),
        }
    }

    /// The first (or only) simplifier's stage over `deltas`.
    fn first_stage(
        simplifier: Simplifier,
        deltas: Vec<MeshDelta>,
        slabs_total: u64,
        cascade: bool,
        cancel_at_end: bool,
    ) -> Outcome<OutBatch> {
        let cancel = AtomicBool::new(false);
        let ctl = Control::new(&cancel);
        let depth = depths(cascade);
        let last = FinalWorkers { threads: true };
        let make = |ctl| SimplifyStep {
            simplifier,
            ctl,
            checkpoint: None,
            front: None,
            last_front: 0,
            start: RunStart::default(),
            slabs_total,
            log_every: 1,
            depth: &depth,
            observer: &|_| {},
            last: &last,
        };
        run_stage(make, &ctl, &cancel, deltas, cancel_at_end)
    }

    /// A cascade's second simplifier's stage over the first's `batches`.
    fn second_stage(
        simplifier: Simplifier,
        batches: Vec<OutBatch>,
        slabs_total: u64,
        cancel_at_end: bool,
    ) -> Outcome<OutBatch> {
        let cancel = AtomicBool::new(false);
        let ctl = Control::new(&cancel);
        let depth = depths(true);
        let last = FinalWorkers { threads: true };
        let make = |ctl| SecondStep {
            simplifier,
            ctl,
            faces_in: 0,
            slabs_total,
            start: RunStart::default(),
            depth: &depth,
            observer: &|_| {},
            last: &last,
        };
        run_stage(make, &ctl, &cancel, batches, cancel_at_end)
    }

    /// A cancel raised once the sweep is over stops a classical run's final decimation (the
    /// whole surface's): the stage ends cancelled, as between two batches, and sends nothing,
    /// not even its `End`, so the writer makes no file. (It used to finish the decimation,
    /// seconds to minutes, then send its output for the writer to drop.)
    #[test]
    fn a_cancel_after_the_sweep_stops_the_classical_final_decimation() {
        let job = sphere("mode = \"classical\"\nerror = 0.5", "");
        let (simplifier, second, deltas, slabs) = prepare(&job);
        assert!(second.is_none());
        let cancelled = first_stage(simplifier, deltas.clone(), slabs, false, true);
        assert!(!cancelled.finished && cancelled.cancelled);
        assert!(cancelled.sent.is_empty() && !cancelled.ended);
        let (simplifier, ..) = prepare(&job);
        let whole = first_stage(simplifier, deltas, slabs, false, false);
        assert!(whole.finished && !whole.cancelled && whole.ended);
        assert_eq!(whole.sent.len(), 1, "a classical run writes all at the end");
    }

    /// The same in a cascade, at either stage's end: each sends what it sent during the sweep
    /// and nothing of its final decimation.
    #[test]
    fn a_cancel_after_the_sweep_stops_both_stages_of_a_cascade() {
        let job = sphere("mode = \"rate\"\nrate = 0.1", "simplify_stages = 2");
        let (first, second, deltas, slabs) = prepare(&job);
        let second = second.expect("a cascade");
        let whole = first_stage(first, deltas.clone(), slabs, true, false);
        assert!(whole.finished && whole.ended);
        let (first, ..) = prepare(&job);
        let cancelled = first_stage(first, deltas, slabs, true, true);
        assert!(!cancelled.finished && cancelled.cancelled && !cancelled.ended);
        assert!(cancelled.sent == whole.sent[..whole.sent.len() - 1]);

        let batches = whole.sent;
        let (_, second_again, ..) = prepare(&job);
        let whole = second_stage(second, batches.clone(), slabs, false);
        assert!(whole.finished && whole.ended);
        let cancelled = second_stage(second_again.unwrap(), batches, slabs, true);
        assert!(!cancelled.finished && cancelled.cancelled && !cancelled.ended);
        assert!(cancelled.sent == whole.sent[..whole.sent.len() - 1]);
    }
}
