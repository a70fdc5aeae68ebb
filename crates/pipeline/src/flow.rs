//! How stages talk and stop: one message protocol on every channel ([`Msg`]), the shared
//! [`Control`] (cancel, abort, first error), and one runner ([`run`]) that drives any [`Step`]
//! with its span, its busy time and the hang-up and abort rules. The stages themselves
//! (`stages.rs`, `extract_pool.rs`) only say what to do with one input and at the end.
//!
//! Every stage ends in one of three ways: its input ended with [`Msg::End`] and it sent its own
//! `End` (success), its own work failed (it records the error in the shared [`Control`], which
//! raises the abort flag), or it saw the abort flag / a neighbour hang up (it stops quietly:
//! someone else has the error to report). Only the writer can make a file appear, and only after
//! it has received `End`, so an error or Ctrl-C anywhere leaves no output.
//!
//! No stage ever blocks for good on a channel: sends and receives wait in short slices
//! ([`POLL`]) and look at the abort and cancel flags in between. A channel alone is not enough
//! to stop a neighbour: the progress observer keeps clones of the receivers (queue depths), so a
//! failed writer does not disconnect the simplifier's channel, and a full channel would otherwise
//! block its producer forever (the deadlock of a write error on a full disk). Nor does a stage
//! work on for long past the flags: the simplifier's passes and its final decimation ask them as
//! they go (`stages::interruptible`).

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, SendTimeoutError, Sender};
use tracing::{debug, info_span};

use crate::checkpoint::Cut;
use crate::error::RunError;
use crate::range::DataRange;

/// What every channel carries: batches, the checkpoint marker between two of them (see
/// `checkpoint`), then `End` once the producer is done. A channel that disconnects before its
/// `End` means its producer stopped early (failed or aborted).
pub(crate) enum Msg<T> {
    Batch(T),
    Cut(Box<Cut>),
    End,
}

/// What an inbox yields: the next input, or the checkpoint marker.
pub(crate) enum In<T> {
    Item(T),
    Cut(Box<Cut>),
}

/// How a stage stopped when it did not finish.
pub(crate) enum Stop {
    /// A neighbour hung up or the run was aborted; whoever failed reports the cause.
    Disconnected,
    Failed(RunError),
}

impl From<RunError> for Stop {
    fn from(e: RunError) -> Self {
        Stop::Failed(e)
    }
}

pub(crate) type StageResult<T> = Result<T, Stop>;

/// Checkpoints on their way at once: one the writer saves while the simplifiers encode the next
/// into its file. With one, the next marker waited for the last to go the whole way from the
/// reader to the writer, more than 10 slabs with two simplifier stages: with `every_slabs = 10`
/// a run stopped at slab 70 resumed from slab 54-56, not 60 (`tests/checkpoint.rs`).
const PENDING_CHECKPOINTS: usize = 2;

/// How long a blocked send or receive waits before it looks at the abort and cancel flags again.
const POLL: Duration = Duration::from_millis(20);

/// Shared by every stage: the user's cancel flag, and the first error of any stage (recording it
/// raises the abort flag that stops every other stage, whatever the state of the channels).
pub(crate) struct Control<'a> {
    cancel: &'a AtomicBool,
    abort: AtomicBool,
    first: Mutex<Option<RunError>>,
    /// Values the extractors saw, for the empty-surface error.
    range: Mutex<DataRange>,
    /// Checkpoint markers the reader sent and the writer has not saved yet: at most
    /// [`PENDING_CHECKPOINTS`], so at most that many checkpoint files are being written at a
    /// time. (The simplifier begins the file as the marker passes it; with a checkpoint after
    /// every slab the markers held back behind the slowest stage each had one, 13 files of 2 MB
    /// at once.)
    checkpoints_pending: AtomicUsize,
    /// The caller's span (the service's `job{id}`), parent of every stage's span: each log line
    /// of a stage thread carries the caller's fields.
    parent: tracing::Span,
}

impl<'a> Control<'a> {
    pub fn new(cancel: &'a AtomicBool) -> Self {
        Self {
            cancel,
            abort: AtomicBool::new(false),
            first: Mutex::new(None),
            range: Mutex::new(DataRange::default()),
            checkpoints_pending: AtomicUsize::new(0),
            parent: tracing::Span::current(),
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
    pub fn check(&self) -> StageResult<()> {
        if self.cancel.load(Ordering::Relaxed) {
            return Err(Stop::Failed(RunError::Cancelled));
        }
        if self.abort.load(Ordering::SeqCst) {
            return Err(Stop::Disconnected);
        }
        Ok(())
    }

    /// Why the run stops, once [`Control::check`] has said it must: a long call that gave up
    /// on it (the simplifier's passes) ends its stage with this, as `check` between two inputs
    /// would have. The flags never go down, so it always has the cause; were it asked too
    /// early, a hang-up is the quiet answer (whoever failed reports).
    pub fn stop(&self) -> Stop {
        self.check().err().unwrap_or(Stop::Disconnected)
    }

    /// Whether the reader must wait before it sends another checkpoint marker: the most that
    /// may be on their way to being saved are.
    pub fn checkpoints_held(&self) -> bool {
        self.checkpoints_pending.load(Ordering::Acquire) >= PENDING_CHECKPOINTS
    }

    /// The reader sent a checkpoint marker.
    pub fn checkpoint_sent(&self) {
        self.checkpoints_pending.fetch_add(1, Ordering::AcqRel);
    }

    /// The writer saved a checkpoint.
    pub fn checkpoint_saved(&self) {
        self.checkpoints_pending.fetch_sub(1, Ordering::AcqRel);
    }

    pub fn take_first(&self) -> Option<RunError> {
        self.first.lock().unwrap_or_else(|p| p.into_inner()).take()
    }

    /// Adds what one slab's extractor saw to the run's data range.
    pub fn add_range(&self, part: &DataRange) {
        self.range
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .merge(part);
    }

    pub fn range(&self) -> DataRange {
        *self.range.lock().unwrap_or_else(|p| p.into_inner())
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
        match body() {
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
pub(crate) fn send<T>(ctl: &Control<'_>, tx: &Sender<T>, mut value: T) -> StageResult<()> {
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

/// Receives the next value; a hang-up is [`Stop::Disconnected`]. Never waits past an abort or a
/// cancel.
pub(crate) fn recv<T>(ctl: &Control<'_>, rx: &Receiver<T>) -> StageResult<T> {
    loop {
        match rx.recv_timeout(POLL) {
            Ok(v) => return Ok(v),
            Err(RecvTimeoutError::Disconnected) => return Err(Stop::Disconnected),
            Err(RecvTimeoutError::Timeout) => ctl.check()?,
        }
    }
}

/// Where a stage's inputs come from; `None` once they have ended.
pub(crate) trait Inbox {
    type Item;
    fn next(&mut self, ctl: &Control<'_>) -> StageResult<Option<In<Self::Item>>>;
}

/// A channel of [`Msg`]: its `End` ends the input.
impl<T> Inbox for Receiver<Msg<T>> {
    type Item = T;
    fn next(&mut self, ctl: &Control<'_>) -> StageResult<Option<In<T>>> {
        Ok(match recv(ctl, self)? {
            Msg::Batch(v) => Some(In::Item(v)),
            Msg::Cut(cut) => Some(In::Cut(cut)),
            Msg::End => None,
        })
    }
}

/// The first stage's input: the slice numbers.
impl Inbox for std::ops::Range<u64> {
    type Item = u64;
    fn next(&mut self, _: &Control<'_>) -> StageResult<Option<In<u64>>> {
        Ok(Iterator::next(self).map(In::Item))
    }
}

/// Where a stage's outputs go. Time spent blocked on a full channel is not busy time.
pub(crate) struct Outbox<'c, T> {
    ctl: &'c Control<'c>,
    /// `None` for the last stages (workers answer on their jobs' own channels, the writer
    /// writes a file).
    tx: Option<Sender<Msg<T>>>,
    blocked: Duration,
}

impl<'c, T> Outbox<'c, T> {
    pub fn new(ctl: &'c Control<'c>, tx: Sender<Msg<T>>) -> Self {
        Self {
            ctl,
            tx: Some(tx),
            blocked: Duration::ZERO,
        }
    }

    /// For a stage without an output channel.
    pub fn none(ctl: &'c Control<'c>) -> Self {
        Self {
            ctl,
            tx: None,
            blocked: Duration::ZERO,
        }
    }

    pub fn send(&mut self, value: T) -> StageResult<()> {
        self.put(Msg::Batch(value))
    }

    /// Passes the checkpoint marker on, behind everything sent so far.
    pub fn cut(&mut self, cut: Box<Cut>) -> StageResult<()> {
        self.put(Msg::Cut(cut))
    }

    /// Sends on a channel of the stage's own (an extraction worker answers on each job's reply
    /// channel), timed like the output: time blocked there is not busy time either.
    pub fn send_on<U>(&mut self, tx: &Sender<U>, value: U) -> StageResult<()> {
        timed_send(self.ctl, &mut self.blocked, tx, value)
    }

    fn put(&mut self, msg: Msg<T>) -> StageResult<()> {
        match &self.tx {
            Some(tx) => timed_send(self.ctl, &mut self.blocked, tx, msg),
            None => Ok(()),
        }
    }
}

/// [`send`], adding the time it took to `blocked`.
fn timed_send<U>(
    ctl: &Control<'_>,
    blocked: &mut Duration,
    tx: &Sender<U>,
    value: U,
) -> StageResult<()> {
    let t = Instant::now();
    let sent = send(ctl, tx, value);
    *blocked += t.elapsed();
    sent
}

/// One stage's work: what to do with each input, and once after the last.
pub(crate) trait Step {
    type In;
    type Out;
    /// What the stage reports when it finished (its counters).
    type Done;
    fn batch(&mut self, input: Self::In, out: &mut Outbox<'_, Self::Out>) -> StageResult<()>;
    /// The checkpoint marker: add this stage's state to it and pass it on. Stages without state
    /// of their own pass it on as it is.
    fn cut(&mut self, cut: Box<Cut>, out: &mut Outbox<'_, Self::Out>) -> StageResult<()> {
        out.cut(cut)
    }
    fn end(self, out: &mut Outbox<'_, Self::Out>) -> StageResult<Self::Done>;
}

/// Runs a stage to its end: takes inputs until they end, hands each to the step, then calls its
/// `end` and sends `End`. Returns the seconds the step was busy (blocked sends excluded) and what
/// it reported. Failures are recorded in `ctl` as they happen, so every other stage stops.
pub(crate) fn run<S: Step>(
    name: &'static str,
    ctl: &Control<'_>,
    mut step: S,
    mut inbox: impl Inbox<Item = S::In>,
    mut out: Outbox<'_, S::Out>,
) -> StageResult<(f64, S::Done)> {
    ctl.stage(|| {
        // The field is `stage`, not `name`: JSON lines put the span's own name under `name`,
        // and `"span":{"name":"simplify","name":"stage"}` lost one of them in JSON parsers.
        let _span = info_span!(parent: &ctl.parent, "stage", stage = name).entered();
        let started = Instant::now();
        let mut busy = Duration::ZERO;
        loop {
            ctl.check()?;
            let Some(input) = inbox.next(ctl)? else {
                break;
            };
            let t = Instant::now();
            match input {
                In::Item(input) => step.batch(input, &mut out)?,
                In::Cut(cut) => step.cut(cut, &mut out)?,
            }
            busy += t.elapsed();
        }
        let t = Instant::now();
        let done = step.end(&mut out)?;
        busy += t.elapsed();
        let seconds = busy.saturating_sub(out.blocked).as_secs_f64();
        out.put(Msg::End)?;
        // Where a stage that is not the slowest spends the rest: waiting for its input, or
        // for the next stage to take its output.
        let waiting_in = started.elapsed().saturating_sub(busy).as_secs_f64();
        let waiting_out = out.blocked.as_secs_f64();
        debug!(seconds, waiting_in, waiting_out, "{name} done");
        Ok((seconds, done))
    })
}
