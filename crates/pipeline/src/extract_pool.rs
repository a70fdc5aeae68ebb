//! Parallel extraction: the reader hands every slab (its two slices, shared with the
//! neighbouring slabs) to a pool of worker threads, each with its own [`Extractor`], and the
//! detector takes the slabs' batches back strictly in slab order.
//!
//! Ordering and the memory bound come from one device: for each slab the reader makes a
//! one-slot reply channel, gives its sender to the workers with the job and passes its receiver
//! down the bounded `order` channel. The detector reads `order` in slab order and waits on each
//! reply in turn, so it sees exactly the stream one extractor would give (slabs are independent,
//! see [`Extractor::extract_slab`]), and the reader blocks once `order` is full: at most
//! `order`'s capacity + 2 slabs are extracted or waiting, whatever the number of workers.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Instant;

use crossbeam_channel::{Receiver, Sender, bounded};
use isostream_extract::attributes::AttributeSlab;
use isostream_extract::{CubeBatch, ExtractStats, Extractor};
use isostream_volume::{Grid, SlabBounds};

use crate::attributes::{SliceReader, Slices};
use crate::checkpoint::{self, Cut};
use crate::config::CheckpointEvery;
use crate::error::RunError;
use crate::flow::{Control, In, Inbox, Msg, Outbox, StageResult, Step, Stop, recv, send};
use crate::range::DataRange;

/// One slab's batches, in the order its extractor emitted them, with what the slab added to
/// the counters and the data range: they are summed in slab order (`Ordered`), so that a
/// checkpoint between two slabs knows them exactly, whichever worker ran ahead.
pub(crate) struct SlabBatches {
    batches: Vec<CubeBatch>,
    stats: ExtractStats,
    range: DataRange,
}

/// One slab to extract and where to answer.
pub(crate) struct SlabJob {
    z: u64,
    lower: Arc<Slices>,
    upper: Arc<Slices>,
    /// The slab's value bounds when the volume knows them (an upsampled input).
    bounds: Option<Arc<SlabBounds>>,
    reply: Sender<SlabBatches>,
}

/// The reader: slices in z order, each slab handed to the workers (`jobs`) and its reply's
/// receiver passed on in order (its output, to the detector).
pub(crate) struct ReadStep<'c> {
    reader: SliceReader,
    jobs: Sender<Msg<SlabJob>>,
    workers: usize,
    ctl: &'c Control<'c>,
    prev: Option<Arc<Slices>>,
    /// When to send the checkpoint marker.
    schedule: Schedule,
    /// Resuming: the hash the first slice read (the checkpoint's carried slice) must have.
    carried: Option<u64>,
}

impl<'c> ReadStep<'c> {
    /// `reader` is at the first slice to read; `carried`: see the field.
    pub fn new(
        reader: SliceReader,
        jobs: Sender<Msg<SlabJob>>,
        workers: usize,
        ctl: &'c Control<'c>,
        schedule: Schedule,
        carried: Option<u64>,
    ) -> Self {
        Self {
            reader,
            jobs,
            workers,
            ctl,
            prev: None,
            schedule,
            carried,
        }
    }
}

/// When the reader sends the checkpoint marker: after slice `z` (the cut after slab `z - 1`),
/// once the interval has passed. Never after the run's first slice nor after the volume's last:
/// a checkpoint there would save nothing new.
pub(crate) struct Schedule {
    every: Option<CheckpointEvery>,
    first: u64,
    last: u64,
    since: Instant,
}

impl Schedule {
    /// `first`: the run's first slice; `slices`: the volume's.
    pub fn new(every: Option<CheckpointEvery>, first: u64, slices: u64) -> Self {
        Self {
            every,
            first,
            last: slices.saturating_sub(1),
            since: Instant::now(),
        }
    }

    /// No checkpoint (the counting pass of `[output] faces`).
    pub fn never() -> Self {
        Self::new(None, 0, 0)
    }

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

impl Step for ReadStep<'_> {
    type In = u64;
    type Out = Receiver<SlabBatches>;
    type Done = ();

    fn batch(&mut self, z: u64, out: &mut Outbox<'_, Self::Out>) -> StageResult<()> {
        let upper = Arc::new(self.reader.next_slices()?.ok_or(RunError::Internal {
            stage: "read",
            reason: format!("slice {z} missing"),
        })?);
        if let Some(expected) = self.carried.take()
            && checkpoint::hash_slice(&upper.iso) != expected
        {
            return Err(Stop::Failed(RunError::InputChanged {
                what: format!("slice {z} holds other values than when the checkpoint was saved"),
            }));
        }
        let cut = self
            .schedule
            .due(z)
            .then(|| Cut::new(z, checkpoint::hash_slice(&upper.iso)));
        if let Some(lower) = self.prev.replace(upper.clone()) {
            let (reply, answer) = bounded(1);
            let job = SlabJob {
                z: z - 1,
                lower,
                upper,
                bounds: self.reader.slab_bounds(z - 1)?,
                reply,
            };
            // `jobs` is unbounded: `order` (bounded) holds the reader back.
            send(self.ctl, &self.jobs, Msg::Batch(job))?;
            out.send(answer)?;
        }
        // Behind slab z - 1's answer: the detector gets the cut once it has taken slab z - 1.
        match cut {
            Some(cut) => out.cut(cut),
            None => Ok(()),
        }
    }

    fn end(self, _: &mut Outbox<'_, Self::Out>) -> StageResult<()> {
        for _ in 0..self.workers {
            send(self.ctl, &self.jobs, Msg::End)?;
        }
        Ok(())
    }
}

/// Cubes per block along x and y when a stored volume's slab bounds come from its slices:
/// small enough to fit around thin surfaces, large enough that a block's bookkeeping is small
/// next to its 256 cubes.
const STORED_BLOCK: [u64; 2] = [16, 16];

/// One worker: extracts whole slabs and answers each on its job's reply channel.
pub(crate) struct WorkStep {
    extractor: Extractor,
    batch_triangles: usize,
    /// Empty-space skipping (`[extract] skip_empty`).
    skip_empty: bool,
}

impl WorkStep {
    /// `stats`: the counters to start from (a resumed run's first worker carries those of the
    /// slabs done before the checkpoint, so that the workers' counters add up to the job's).
    pub fn new(
        grid: Grid,
        iso: f32,
        batch_triangles: usize,
        skip_empty: bool,
        stats: ExtractStats,
    ) -> Self {
        Self {
            extractor: Extractor::resume(grid, iso, stats),
            batch_triangles,
            skip_empty,
        }
    }
}

impl Step for WorkStep {
    type In = SlabJob;
    type Out = Infallible;
    type Done = ExtractStats;

    fn batch(&mut self, job: SlabJob, _: &mut Outbox<'_, Infallible>) -> StageResult<()> {
        let (lo, up) = (&job.lower, &job.upper);
        // Slice 0 counts with slab 0, every other slice as the upper slice of its slab.
        let mut range = DataRange::default();
        if job.z == 0 {
            range.add(&lo.iso);
        }
        range.add(&up.iso);
        let before = self.extractor.stats();
        let attrs: Vec<AttributeSlab<'_>> = lo
            .attrs
            .iter()
            .zip(&up.attrs)
            .map(|(l, u)| AttributeSlab { lower: l, upper: u })
            .collect();
        let grid = self.extractor.grid();
        let bounds = self.skip_empty.then(|| {
            job.bounds.clone().unwrap_or_else(|| {
                Arc::new(SlabBounds::from_slices(
                    &grid,
                    STORED_BLOCK,
                    &lo.iso,
                    &up.iso,
                ))
            })
        });
        let mut batches = Vec::new();
        let Ok(()) = self.extractor.extract_slab_with_attributes(
            job.z,
            &lo.iso,
            &up.iso,
            &attrs,
            bounds.as_deref(),
            self.batch_triangles,
            |b| {
                batches.push(b);
                Ok::<_, Infallible>(())
            },
        );
        let slab = SlabBatches {
            batches,
            stats: self.extractor.stats() - before,
            range,
        };
        // A one-slot channel that only this job fills: never blocks. A hang-up means the
        // detector stopped.
        job.reply.send(slab).map_err(|_| Stop::Disconnected)
    }

    fn end(self, _: &mut Outbox<'_, Infallible>) -> StageResult<ExtractStats> {
        Ok(self.extractor.stats())
    }
}

/// The detector's input: the slabs' batches in slab order, each slab waited for in turn. Sums
/// the slabs' counters and data ranges in that order, for the run and for checkpoints.
pub(crate) struct Ordered {
    order: Receiver<Msg<Receiver<SlabBatches>>>,
    current: std::vec::IntoIter<CubeBatch>,
    stats: ExtractStats,
    range: DataRange,
}

impl Ordered {
    /// `stats` and `range`: those of the slabs before the first (a resumed run's).
    pub fn new(
        order: Receiver<Msg<Receiver<SlabBatches>>>,
        stats: ExtractStats,
        range: DataRange,
    ) -> Self {
        Self {
            order,
            current: Vec::new().into_iter(),
            stats,
            range,
        }
    }
}

impl Inbox for Ordered {
    type Item = CubeBatch;

    fn next(&mut self, ctl: &Control<'_>) -> StageResult<Option<In<CubeBatch>>> {
        loop {
            if let Some(b) = self.current.next() {
                return Ok(Some(In::Item(b)));
            }
            match self.order.next(ctl)? {
                None => return Ok(None),
                Some(In::Item(answer)) => {
                    let slab = recv(ctl, &answer)?;
                    self.stats += slab.stats;
                    self.range.merge(&slab.range);
                    ctl.add_range(&slab.range);
                    self.current = slab.batches.into_iter();
                }
                // Every slab before the cut has been handed out: their sums are the cut's.
                Some(In::Cut(mut cut)) => {
                    cut.extract = self.stats;
                    cut.reader.range = self.range;
                    return Ok(Some(In::Cut(cut)));
                }
            }
        }
    }
}
