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

use crossbeam_channel::{Receiver, Sender, bounded};
use isostream_extract::attributes::AttributeSlab;
use isostream_extract::{CubeBatch, ExtractStats, Extractor};
use isostream_volume::{Grid, SlabBounds};

use crate::attributes::{SliceReader, Slices};
use crate::error::RunError;
use crate::flow::{Control, Inbox, Msg, Outbox, StageResult, Step, Stop, recv, send};
use crate::range::DataRange;

/// One slab's batches, in the order its extractor emitted them.
pub(crate) type SlabBatches = Vec<CubeBatch>;

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
}

impl<'c> ReadStep<'c> {
    pub fn new(
        reader: SliceReader,
        jobs: Sender<Msg<SlabJob>>,
        workers: usize,
        ctl: &'c Control<'c>,
    ) -> Self {
        Self {
            reader,
            jobs,
            workers,
            ctl,
            prev: None,
        }
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
        Ok(())
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
pub(crate) struct WorkStep<'c> {
    extractor: Extractor,
    batch_triangles: usize,
    /// Empty-space skipping (`[extract] skip_empty`).
    skip_empty: bool,
    ctl: &'c Control<'c>,
}

impl<'c> WorkStep<'c> {
    pub fn new(
        grid: Grid,
        iso: f32,
        batch_triangles: usize,
        skip_empty: bool,
        ctl: &'c Control<'c>,
    ) -> Self {
        Self {
            extractor: Extractor::new(grid, iso),
            batch_triangles,
            skip_empty,
            ctl,
        }
    }
}

impl Step for WorkStep<'_> {
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
        self.ctl.add_range(&range);
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
        let mut batches = SlabBatches::new();
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
        // A one-slot channel that only this job fills: never blocks. A hang-up means the
        // detector stopped.
        job.reply.send(batches).map_err(|_| Stop::Disconnected)
    }

    fn end(self, _: &mut Outbox<'_, Infallible>) -> StageResult<ExtractStats> {
        Ok(self.extractor.stats())
    }
}

/// The detector's input: the slabs' batches in slab order, each slab waited for in turn.
pub(crate) struct Ordered {
    order: Receiver<Msg<Receiver<SlabBatches>>>,
    current: std::vec::IntoIter<CubeBatch>,
}

impl Ordered {
    pub fn new(order: Receiver<Msg<Receiver<SlabBatches>>>) -> Self {
        Self {
            order,
            current: Vec::new().into_iter(),
        }
    }
}

impl Inbox for Ordered {
    type Item = CubeBatch;

    fn next(&mut self, ctl: &Control<'_>) -> StageResult<Option<CubeBatch>> {
        loop {
            if let Some(b) = self.current.next() {
                return Ok(Some(b));
            }
            let Some(answer) = self.order.next(ctl)? else {
                return Ok(None);
            };
            self.current = recv(ctl, &answer)?.into_iter();
        }
    }
}
