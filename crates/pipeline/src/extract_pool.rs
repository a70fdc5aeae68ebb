//! Parallel extraction: the reader hands every slab (its two slices, shared with the
//! neighbouring slabs) to a pool of worker threads, each with its own [`Extractor`], and the
//! detector takes the slabs' batches back strictly in slab order.
//!
//! Ordering and the memory bound come from one device: for each slab the reader makes a reply
//! channel of a few batches ([`RUN_REPLY_BATCHES`], [`COUNT_REPLY_BATCHES`]), gives its sender
//! to the workers with the job and passes
//! its receiver down the bounded `order` channel. The detector reads `order` in slab order and
//! drains each reply in turn, so it sees exactly the stream one extractor would give (slabs are
//! independent, see [`Extractor::extract_slab`]), and the reader blocks once `order` is full: at
//! most `order`'s capacity + 2 slabs are extracted or waiting, whatever the number of workers,
//! each holding at most that many batches (a worker ahead waits for the detector rather
//! than holding its whole slab's surface, which grows with the slice). The worker of the
//! earliest slab the detector waits for never waits on anyone else (jobs are taken in order),
//! so the pool cannot deadlock.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Instant;

use crossbeam_channel::{Receiver, Sender, bounded};
use isostream_extract::attributes::AttributeSlab;
use isostream_extract::{CubeBatch, ExtractStats, Extractor, RowQuad, SlabRows};
use isostream_volume::{Grid, SlabBounds, SliceRows};

use crate::attributes::{SliceReader, Slices};
use crate::checkpoint::Cut;
use crate::config::CheckpointEvery;
use crate::error::RunError;
use crate::flow::{Control, In, Inbox, Msg, Outbox, StageResult, Step, Stop, recv, send};
use crate::range::DataRange;

/// What a slab's reply channel carries: its batches in the order its extractor emitted them,
/// then what the slab added to the counters and the data range: they are summed in slab order
/// (`Ordered`), so that a checkpoint between two slabs knows them exactly, whichever worker ran
/// ahead.
pub(crate) enum SlabReply {
    Batch(CubeBatch),
    Done {
        stats: ExtractStats,
        range: DataRange,
    },
}

/// Batches a slab's reply channel holds in a whole run: a worker running ahead of the detector
/// waits once its slab has this many waiting. The simplifier is the run's slowest stage, so
/// every reply channel is full and room ahead only holds memory: with 4, the batches in flight
/// grew with the slab's surface (1 per slab at 256^3, 4 from 1021^3 on: about 0.7 MB each, 16 in
/// all), which kept the whole run's peak RSS from being flat across upsampled sizes
/// (docs/scale.md). One per slab is what a 256^3 slab needs anyway, and since the workers send
/// batches of [`CHUNK_TRIANGLES`] it is about 0.1 MB whatever the slice.
pub(crate) const RUN_REPLY_BATCHES: usize = 1;
/// The same for the first pass of `[output] faces`, which only counts: extraction is its slowest
/// stage, and a worker ahead needs room to keep busy while the one behind finishes its slab.
pub(crate) const COUNT_REPLY_BATCHES: usize = 4;

/// One slab to extract and where to answer.
pub(crate) struct SlabJob {
    z: u64,
    lower: Arc<Slices>,
    upper: Arc<Slices>,
    /// The slab's value bounds when the volume knows them (an upsampled input).
    bounds: Option<Arc<SlabBounds>>,
    reply: Sender<SlabReply>,
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
    /// Capacity of each slab's reply channel.
    reply_batches: usize,
}

impl<'c> ReadStep<'c> {
    /// `reader` is at the first slice to read; `carried` and `reply_batches`: see the fields.
    pub fn new(
        reader: SliceReader,
        jobs: Sender<Msg<SlabJob>>,
        workers: usize,
        ctl: &'c Control<'c>,
        schedule: Schedule,
        carried: Option<u64>,
        reply_batches: usize,
    ) -> Self {
        Self {
            reader,
            jobs,
            workers,
            ctl,
            prev: None,
            schedule,
            carried,
            reply_batches,
        }
    }
}

/// When the reader sends the checkpoint marker: after slice `z` (the cut after slab `z - 1`),
/// once the interval has passed and there is room for it (`Control::checkpoints_held`). Never
/// after the run's first slice nor after the volume's last: a checkpoint there would save
/// nothing new.
///
/// A marker due while two are still on their way waits for room and is sent as soon as there is
/// some, and the interval counts again from there, for `every_slabs` as for `every_seconds`.
/// Keeping `every_slabs` markers on their multiples of the interval sent the held one and the
/// next back to back (slabs 9 and 10 with `every_slabs = 5`): the second saved a single slab
/// more, cost a whole checkpoint (the simplifier's state encoded, a file written and fsynced)
/// and, two being on their way again, was itself likely held. Skipping the held one instead
/// would leave up to twice the interval unsaved; sent late with the interval restarted, no two
/// markers are closer than the interval and none is later than it need be.
pub(crate) struct Schedule {
    every: Option<CheckpointEvery>,
    first: u64,
    last: u64,
    /// `every_slabs`: the slice after which the next marker is due (the interval after the
    /// last one sent, or after the run's first slice).
    next: u64,
    since: Instant,
}

impl Schedule {
    /// `first`: the run's first slice; `slices`: the volume's.
    pub fn new(every: Option<CheckpointEvery>, first: u64, slices: u64) -> Self {
        Self {
            every,
            first,
            last: slices.saturating_sub(1),
            next: match every {
                Some(CheckpointEvery::Slabs(n)) => first.saturating_add(n),
                _ => first,
            },
            since: Instant::now(),
        }
    }

    /// No checkpoint (the counting pass of `[output] faces`).
    pub fn never() -> Self {
        Self::new(None, 0, 0)
    }

    /// `held`: the markers sent before are not saved yet, and no other may be sent.
    fn due(&mut self, z: u64, held: bool) -> bool {
        if held || z == self.first || z >= self.last {
            return false;
        }
        let due = match self.every {
            None => false,
            Some(CheckpointEvery::Slabs(n)) => {
                let due = z >= self.next;
                if due {
                    self.next = z.saturating_add(n);
                }
                due
            }
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
    type Out = Receiver<SlabReply>;
    type Done = ();

    fn batch(&mut self, z: u64, out: &mut Outbox<'_, Self::Out>) -> StageResult<()> {
        let upper = Arc::new(self.reader.next_slices()?.ok_or(RunError::Internal {
            stage: "read",
            reason: format!("slice {z} missing"),
        })?);
        if let Some(expected) = self.carried.take()
            && self.reader.hash(&upper)? != expected
        {
            return Err(Stop::Failed(RunError::InputChanged {
                input: self.reader.describe(),
                what: format!("slice {z} holds other values than when the checkpoint was saved"),
            }));
        }
        let cut = match self.schedule.due(z, self.ctl.checkpoints_held()) {
            true => {
                let cut = Cut::new(z, self.reader.hash(&upper)?);
                self.ctl.checkpoint_sent();
                Some(cut)
            }
            false => None,
        };
        if let Some(lower) = self.prev.replace(upper.clone()) {
            let (reply, answer) = bounded(self.reply_batches);
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

/// Voxels per strip row buffer when slices come as rows (`Slices::rows`): a strip is
/// `STRIP_VOXELS / nx` rows of cubes (at least [`MIN_STRIP_ROWS`]), so a worker holds two
/// strips of about 256 KiB each whatever the slice area (32 rows of a 2041^2 slice). With
/// 1 MiB strips the two workers' four buffers were 3.8 MiB of the peak of bonsai's slices
/// 100-131 upsampled 8x (mode `none`: 26.7 -> 22.9 MiB; docs/scale.md).
const STRIP_VOXELS: usize = 1 << 16;
/// Triangles per batch a worker sends (`Extractor::chunked`): the detector joins them into the
/// job's `batch_triangles` groups. Batches wait in the slab replies and in the workers, several
/// at once, and a group of 8,192 triangles on wide slices is about 0.8 MB.
const CHUNK_TRIANGLES: usize = 1024;
/// Rows of cubes per strip at least: each strip computes its first row again (the last row of
/// the strip before), an overhead of one row per strip.
const MIN_STRIP_ROWS: usize = 16;

/// One worker: extracts whole slabs (from whole slices, or strip by strip from slices given as
/// rows) and answers each on its job's reply channel.
pub(crate) struct WorkStep {
    extractor: Extractor,
    batch_triangles: usize,
    /// Empty-space skipping (`[extract] skip_empty`).
    skip_empty: bool,
    /// Rows of cubes per strip (slices given as rows).
    strip_rows: usize,
    /// The strips' buffers, reused from slab to slab.
    strips: [Vec<f32>; 2],
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
        let nx = grid.dims[0] as usize;
        Self {
            extractor: Extractor::resume(grid, iso, stats).chunked(CHUNK_TRIANGLES),
            batch_triangles,
            skip_empty,
            strip_rows: (STRIP_VOXELS / nx).max(MIN_STRIP_ROWS),
            strips: Default::default(),
        }
    }

    /// This step, counting the triangles without making them (`Extractor::counting`).
    pub fn counting(self) -> Self {
        Self {
            extractor: self.extractor.counting(),
            ..self
        }
    }

    /// Extracts a slab from its two whole slices (and its attributes'); adds its blocks' bounds
    /// to `range`, or its voxels when it has no bounds or a block has none
    /// ([`range_from_bounds`]).
    fn extract_slices(
        &mut self,
        job: &SlabJob,
        range: &mut DataRange,
        out: &mut Outbox<'_, Infallible>,
    ) -> StageResult<()> {
        let (lo, up) = (&job.lower, &job.upper);
        let attrs: Vec<AttributeSlab<'_>> = lo
            .attrs
            .iter()
            .zip(&up.attrs)
            .map(|(l, u)| AttributeSlab { lower: l, upper: u })
            .collect();
        let grid = self.extractor.grid();
        let bounds = self.skip_empty.then(|| {
            job.bounds.clone().unwrap_or_else(|| {
                Arc::new(
                    lo.bounds(&grid, STORED_BLOCK)
                        .merged(up.bounds(&grid, STORED_BLOCK)),
                )
            })
        });
        // Slice 0 counts with slab 0, every other slice as the upper slice of its slab.
        if !range_from_bounds(bounds.as_deref(), range) {
            if job.z == 0 {
                range.add(&lo.iso);
            }
            range.add(&up.iso);
        }
        self.extractor.extract_slab_with_attributes(
            job.z,
            &lo.iso,
            &up.iso,
            &attrs,
            bounds.as_deref(),
            self.batch_triangles,
            |b| out.send_on(&job.reply, SlabReply::Batch(b)),
        )
    }

    /// Extracts a slab whose two slices come as rows, strip by strip: the same batches as from
    /// the whole slices ([`Extractor::extract_slab_rows`]); adds its blocks' bounds to `range`,
    /// and the voxels it computed when a block has none ([`range_from_bounds`]).
    fn extract_strips(
        &mut self,
        job: &SlabJob,
        lower: &dyn SliceRows,
        upper: &dyn SliceRows,
        range: &mut DataRange,
        out: &mut Outbox<'_, Infallible>,
    ) -> StageResult<()> {
        let bounds = match (&job.bounds, self.skip_empty) {
            (Some(b), true) => Some(b.as_ref()),
            (None, true) => {
                return Err(Stop::Failed(RunError::Internal {
                    stage: "extract",
                    reason: "a volume that gives rows on demand gave no slab bounds".into(),
                }));
            }
            (_, false) => None,
        };
        let range = (!range_from_bounds(bounds, range)).then_some(range);
        let grid = self.extractor.grid();
        let mut strips = Strips {
            slices: [lower, upper],
            buffers: std::mem::take(&mut self.strips),
            nx: grid.dims[0] as usize,
            ny: grid.dims[1] as usize,
            height: self.strip_rows,
            at: 0..0,
            counted: 0,
            // Slice 0 counts with slab 0, every other slice as the upper slice of its slab.
            count_lower: job.z == 0,
            range,
        };
        let done = self.extractor.extract_slab_rows(
            job.z,
            &mut strips,
            bounds,
            self.batch_triangles,
            |b| out.send_on(&job.reply, SlabReply::Batch(b)),
        );
        self.strips = strips.buffers;
        done
    }
}

/// Adds the finite range of a slab's blocks' `bounds` (rows of cubes that cannot cross are never
/// computed: their values are in the range by their bounds), and says whether that is the
/// slab's whole range: then no pass over the voxels is needed (that pass was a fifth of the
/// extraction of an upsampled volume by `perf`). Bounds are values the voxels take (for an
/// upsampled source, its own voxels'), and every voxel lies within its block's; but a block
/// holding a non-finite voxel has no finite bounds, and its voxels must then be seen.
fn range_from_bounds(bounds: Option<&SlabBounds>, range: &mut DataRange) -> bool {
    bounds.is_some_and(|b| {
        range.include(b.finite_range());
        !b.has_unbounded()
    })
}

/// A slab's two slices, given as rows, held a strip of rows at a time.
struct Strips<'a> {
    /// Lower and upper slice.
    slices: [&'a dyn SliceRows; 2],
    /// Rows `at` of each.
    buffers: [Vec<f32>; 2],
    nx: usize,
    /// Rows per slice.
    ny: usize,
    /// Rows of cubes per strip.
    height: usize,
    at: std::ops::Range<usize>,
    /// Rows before this one are in `range` already.
    counted: usize,
    count_lower: bool,
    /// Where the rows' values go, when no bounds give the range.
    range: Option<&'a mut DataRange>,
}

impl SlabRows for Strips<'_> {
    fn quad(&mut self, y: u64) -> RowQuad<'_> {
        let y = y as usize;
        if !(self.at.contains(&y) && self.at.contains(&(y + 1))) {
            // The next strip starts at the row of cubes asked for (its lower row again).
            self.at = y..(y + self.height + 1).min(self.ny);
            let nx = self.nx;
            for (slice, buf) in self.slices.iter().zip(&mut self.buffers) {
                buf.resize(self.at.len() * nx, 0.0);
                slice.fill_rows(y as u64, buf);
            }
            if let Some(range) = &mut self.range {
                let new = self.counted.max(self.at.start) - self.at.start;
                range.add(&self.buffers[1][new * nx..]);
                if self.count_lower {
                    range.add(&self.buffers[0][new * nx..]);
                }
                self.counted = self.at.end;
            }
        }
        let nx = self.nx;
        let i = (y - self.at.start) * nx;
        let [lo, up] = &self.buffers;
        [
            &lo[i..i + nx],
            &lo[i + nx..i + 2 * nx],
            &up[i..i + nx],
            &up[i + nx..i + 2 * nx],
        ]
    }
}

impl Step for WorkStep {
    type In = SlabJob;
    type Out = Infallible;
    type Done = ExtractStats;

    fn batch(&mut self, job: SlabJob, out: &mut Outbox<'_, Infallible>) -> StageResult<()> {
        let mut range = DataRange::default();
        let before = self.extractor.stats();
        match (&job.lower.rows, &job.upper.rows) {
            (Some(l), Some(u)) => {
                self.extract_strips(&job, l.as_ref(), u.as_ref(), &mut range, out)?;
            }
            _ => self.extract_slices(&job, &mut range, out)?,
        }
        // The voxels the reader saturated, counted like the non-finite ones: slice 0 with slab
        // 0, every other slice as the upper slice of its slab.
        let slices = if job.z == 0 {
            &[&job.lower, &job.upper][..]
        } else {
            &[&job.upper][..]
        };
        for s in slices {
            self.extractor
                .add_saturated_voxels(s.saturated, s.saturated_attributes);
            range.add_saturated(s.saturated);
        }
        let done = SlabReply::Done {
            stats: self.extractor.stats() - before,
            range,
        };
        // A hang-up means the detector stopped.
        out.send_on(&job.reply, done)
    }

    fn end(self, _: &mut Outbox<'_, Infallible>) -> StageResult<ExtractStats> {
        Ok(self.extractor.stats())
    }
}

/// The detector's input: the slabs' batches in slab order, each slab waited for in turn. Sums
/// the slabs' counters and data ranges in that order, for the run and for checkpoints.
pub(crate) struct Ordered {
    order: Receiver<Msg<Receiver<SlabReply>>>,
    /// The reply of the slab being taken.
    current: Option<Receiver<SlabReply>>,
    stats: ExtractStats,
    range: DataRange,
}

impl Ordered {
    /// `stats` and `range`: those of the slabs before the first (a resumed run's).
    pub fn new(
        order: Receiver<Msg<Receiver<SlabReply>>>,
        stats: ExtractStats,
        range: DataRange,
    ) -> Self {
        Self {
            order,
            current: None,
            stats,
            range,
        }
    }
}

impl Inbox for Ordered {
    type Item = CubeBatch;

    fn next(&mut self, ctl: &Control<'_>) -> StageResult<Option<In<CubeBatch>>> {
        loop {
            if let Some(answer) = &self.current {
                match recv(ctl, answer)? {
                    SlabReply::Batch(b) => return Ok(Some(In::Item(b))),
                    SlabReply::Done { stats, range } => {
                        self.stats += stats;
                        self.range.merge(&range);
                        ctl.add_range(&range);
                        self.current = None;
                    }
                }
                continue;
            }
            match self.order.next(ctl)? {
                None => return Ok(None),
                Some(In::Item(answer)) => self.current = Some(answer),
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

#[cfg(test)]
mod tests {
    use std::sync::atomic::AtomicBool;

    use isostream_volume::{MemoryVolume, Upsampled, VolumeSource};

    use super::*;

    /// A marker due while no other may be sent waits for room, and the next of `every_slabs`
    /// is the interval after it: never two back to back (they were at 9 and 10 here, the next
    /// kept on its multiple of the interval from the run's first slice).
    #[test]
    fn a_checkpoint_due_while_others_are_pending_waits_for_them() {
        let mut schedule = Schedule::new(Some(CheckpointEvery::Slabs(4)), 2, 30);
        let held = |z: u64| (6..9).contains(&z);
        let cuts: Vec<u64> = (2..30).filter(|&z| schedule.due(z, held(z))).collect();
        assert_eq!(cuts, vec![9, 13, 17, 21, 25]);
    }

    /// The example of a held marker with `every_slabs = 5` from slice 0, held twice: each is
    /// sent when room comes, and no two are closer than the interval.
    #[test]
    fn held_checkpoints_are_never_back_to_back() {
        let mut schedule = Schedule::new(Some(CheckpointEvery::Slabs(5)), 0, 40);
        let held = |z: u64| (5..9).contains(&z) || (14..20).contains(&z);
        let cuts: Vec<u64> = (0..40).filter(|&z| schedule.due(z, held(z))).collect();
        assert_eq!(cuts, vec![9, 20, 25, 30, 35]);
        assert!(cuts.windows(2).all(|w| w[1] - w[0] >= 5), "{cuts:?}");
    }

    /// One slab's reply, gathered.
    struct Slab {
        batches: Vec<CubeBatch>,
        stats: ExtractStats,
        range: DataRange,
    }

    /// Every slab's reply (batches, counters, data range) of a worker fed by `reader` as the
    /// reader stage feeds it.
    fn replies(mut reader: SliceReader, step: &mut WorkStep, ctl: &Control<'_>) -> Vec<Slab> {
        let mut out = Outbox::none(ctl);
        let mut prev: Option<Arc<Slices>> = None;
        let mut replies = Vec::new();
        while let Some(upper) = reader.next_slices().unwrap() {
            let upper = Arc::new(upper);
            let z = upper.z;
            if let Some(lower) = prev.replace(upper.clone()) {
                // Unbounded: the worker runs on this thread, ahead of the reading below.
                let (reply, answer) = crossbeam_channel::unbounded();
                let bounds = reader.slab_bounds(z - 1).unwrap();
                let job = SlabJob {
                    z: z - 1,
                    lower,
                    upper,
                    bounds,
                    reply,
                };
                let Ok(()) = step.batch(job, &mut out) else {
                    panic!("slab {z} failed");
                };
                let mut batches = Vec::new();
                loop {
                    match answer.try_recv().unwrap() {
                        SlabReply::Batch(b) => batches.push(b),
                        SlabReply::Done { stats, range } => {
                            replies.push(Slab {
                                batches,
                                stats,
                                range,
                            });
                            break;
                        }
                    }
                }
            }
        }
        replies
    }

    /// Strips of any height give the batches, counters and data range of whole slices (with
    /// batches split inside slabs, across strip borders), with and without skipping.
    #[test]
    fn strips_extract_what_whole_slices_do() {
        let grid = Grid::new([9, 11, 6], [1.0, 1.5, 2.0], [0.0; 3]).unwrap();
        let iso = 20.0;
        let cancel = AtomicBool::new(false);
        let ctl = Control::new(&cancel);
        // Without and with a NaN voxel: its blocks have no finite bounds, so their values are
        // seen one by one, and the range is the same as without skipping.
        for nan in [None, Some(300)] {
            let data = (0..grid.voxel_count())
                .map(|i| {
                    let [x, y, z] = [i % 9, (i / 9) % 11, i / 99].map(|c| c as f32);
                    let v = (x * 0.9).sin() * 40.0 + (y * 0.7).cos() * 30.0 + z * 8.0;
                    if Some(i) == nan { f32::NAN } else { v }
                })
                .collect();
            let volume = MemoryVolume::new(grid, data).unwrap();
            let source = || -> Box<dyn VolumeSource> {
                Box::new(Upsampled::new(Box::new(volume.clone()), [3, 2, 2]).unwrap())
            };
            let fine = source().grid();
            let mut whole_range = Vec::new();
            for skip in [false, true] {
                let reader = |rows: bool| {
                    let mut r = SliceReader::new(source(), Vec::new());
                    if rows {
                        r = r.rows_on_demand();
                    }
                    if skip { r.skip_empty(iso) } else { r }
                };
                let step = || WorkStep::new(fine, iso, 40, skip, ExtractStats::default());
                let want = replies(reader(false), &mut step(), &ctl);
                assert!(want.iter().map(|r| r.batches.len()).sum::<usize>() > 2 * want.len());
                let mut range = DataRange::default();
                want.iter().for_each(|w| range.merge(&w.range));
                whole_range.push(range);
                for height in [1, 2, 3, 7, 100] {
                    let mut tiled = step();
                    tiled.strip_rows = height;
                    let got = replies(reader(true), &mut tiled, &ctl);
                    assert_eq!(got.len(), want.len());
                    for (g, w) in got.iter().zip(&want) {
                        assert!(
                            g.batches == w.batches,
                            "strips of {height} rows, skip {skip}"
                        );
                        assert_eq!(g.stats, w.stats);
                        assert_eq!(g.range, w.range);
                    }
                }
            }
            assert_eq!(whole_range[0], whole_range[1], "NaN at {nan:?}");
            let said = whole_range[0].empty_surface(f64::from(iso));
            assert_eq!(said.contains("NaN or infinite"), nan.is_some(), "{said}");
        }
    }
}
