//! The five stages, each on its own thread, joined by bounded channels.
//!
//! Every stage ends in one of three ways: it saw the end-of-volume marker and passed it on
//! (success), its own work failed (it reports the error), or its neighbour hung up (it stops
//! quietly: the neighbour has the error to report). Only the writer can make a file appear, and
//! only after it has received the end marker, so an error or Ctrl-C anywhere leaves no output.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, bounded};
use isostream_detect::{DetectStats, Detector, MeshDelta};
use isostream_extract::attributes::AttributeSlab;
use isostream_extract::{CubeBatch, ExtractStats, Extractor};
use isostream_simplify::{OutBatch, Simplifier, SimplifyStats};
use isostream_volume::{Grid, VolumeSource};
use tracing::{debug, info, info_span};

use crate::attributes::{SliceReader, Slices};
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

fn send<T>(tx: &Sender<T>, value: T) -> StageResult<()> {
    tx.send(value).map_err(|_| Stop::Disconnected)
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
    pub cancel: &'a AtomicBool,
    pub observer: &'a (dyn Fn(&Progress) + Sync),
}

/// Messages to the writer: batches, then `End` when the volume is complete.
enum ToWriter {
    Batch(OutBatch),
    End,
}

impl Stages<'_> {
    pub fn run(self) -> Result<StageOutputs, RunError> {
        let grid = self.source.grid();
        let (slice_tx, slice_rx) = bounded::<Slices>(2);
        let (cube_tx, cube_rx) = bounded::<CubeBatch>(self.capacity);
        let (delta_tx, delta_rx) = bounded::<MeshDelta>(self.capacity);
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
            cancel,
            observer,
            ..
        } = self;

        std::thread::scope(|s| {
            let reader = s.spawn(move || {
                let reader = SliceReader::new(source, attributes);
                read_stage(reader, grid, slice_tx, cancel)
            });
            let extractor =
                s.spawn(move || extract_stage(grid, iso, batch_triangles, slice_rx, cube_tx));
            let detector = s.spawn(move || detect_stage(grid, cube_rx, delta_tx));
            let simplifier = s.spawn(move || {
                simplify_stage(simplifier, grid, delta_rx, out_tx, &depth, observer)
            });
            let writer = s.spawn(move || write_stage(sink, out_rx));

            // Join every stage; the one that failed (not merely saw a neighbour hang up) is the
            // cause. Cancellation surfaces as the reader's failure.
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
                (read, extract, detect, simplify, write) => Err(first_failure([
                    read.err(),
                    extract.err(),
                    detect.err(),
                    simplify.err(),
                    write.err(),
                ])),
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
    cubes: Receiver<CubeBatch>,
    deltas: Receiver<MeshDelta>,
    out: Receiver<ToWriter>,
}

fn read_stage(
    mut reader: SliceReader,
    grid: Grid,
    tx: Sender<Slices>,
    cancel: &AtomicBool,
) -> StageResult<f64> {
    let _span = info_span!("read").entered();
    let mut busy = Duration::ZERO;
    for _ in 0..grid.dims[2] {
        if cancel.load(Ordering::Relaxed) {
            return Err(Stop::Failed(RunError::Cancelled));
        }
        let t = Instant::now();
        let Some(slices) = reader.next_slices()? else {
            break;
        };
        busy += t.elapsed();
        send(&tx, slices)?;
    }
    debug!(seconds = busy.as_secs_f64(), "read done");
    Ok(busy.as_secs_f64())
}

fn extract_stage(
    grid: Grid,
    iso: f32,
    batch_triangles: usize,
    rx: Receiver<Slices>,
    tx: Sender<CubeBatch>,
) -> StageResult<(f64, ExtractStats)> {
    let _span = info_span!("extract").entered();
    let mut extractor = Extractor::new(grid, iso);
    let mut busy = Duration::ZERO;
    let mut lower: Option<Slices> = None;
    for upper in rx.iter() {
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
                    let sent = send(&tx, batch);
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
    grid: Grid,
    rx: Receiver<CubeBatch>,
    tx: Sender<MeshDelta>,
) -> StageResult<(f64, DetectStats)> {
    let _span = info_span!("detect").entered();
    let mut detector = Detector::new(grid.dims);
    let mut busy = Duration::ZERO;
    for batch in rx.iter() {
        let t = Instant::now();
        let mut delta = MeshDelta::default();
        detector.process(&batch, &mut delta);
        busy += t.elapsed();
        let end = delta.end_of_volume;
        send(&tx, delta)?;
        if end {
            return Ok((busy.as_secs_f64(), detector.stats()));
        }
    }
    Err(Stop::Disconnected)
}

fn simplify_stage(
    mut simplifier: Simplifier,
    grid: Grid,
    rx: Receiver<MeshDelta>,
    tx: Sender<ToWriter>,
    depth: &Depths,
    observer: &(dyn Fn(&Progress) + Sync),
) -> StageResult<(f64, SimplifyStats)> {
    let _span = info_span!("simplify").entered();
    let slabs_total = grid.dims[2] - 1;
    let log_every = (slabs_total / 20).max(1);
    let mut busy = Duration::ZERO;
    let mut last_front = 0u32;
    for delta in rx.iter() {
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
            send(&tx, ToWriter::Batch(out))?;
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
            send(&tx, ToWriter::End)?;
            return Ok((busy.as_secs_f64(), simplifier.stats()));
        }
    }
    Err(Stop::Disconnected)
}

fn write_stage(
    mut sink: Sink,
    rx: Receiver<ToWriter>,
) -> StageResult<(f64, crate::sink::SinkStats)> {
    let _span = info_span!("write").entered();
    let mut busy = Duration::ZERO;
    for msg in rx.iter() {
        let t = Instant::now();
        match msg {
            ToWriter::Batch(batch) => sink.write(&batch)?,
            ToWriter::End => {
                let stats = sink.finish()?;
                busy += t.elapsed();
                return Ok((busy.as_secs_f64(), stats));
            }
        }
        busy += t.elapsed();
    }
    // Upstream hung up before the end: dropping the sink removes the partial file.
    Err(Stop::Disconnected)
}
