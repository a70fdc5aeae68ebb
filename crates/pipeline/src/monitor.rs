//! What a run shows while it goes and leaves behind: the per-slab time series of the run summary
//! (memory, faces, time over the sweep: the view of Hou and Chen's Fig. 5) and a structured
//! progress log line every `[log] progress_seconds`.
//!
//! Both are fed by the stages' progress observer, called on the simplifier's thread after every
//! completed slab; the monitor wraps the caller's observer, so the stages know nothing of it. A
//! job's first pass (`[output] faces`, pruning) reports its slabs through it too: it logs
//! `progress` lines (with `pass = "first"`) but adds nothing to the series, which is the run's.
//!
//! Every clock counts from the job's start, as the summary's `seconds` does: the lines'
//! `elapsed_s` and the series' `seconds`. A rate and an ETA are those of the pass under way,
//! over the time since that pass began ([`Monitor::pass_begins`]). The run's ETA paces by the
//! faces when a first pass counted them ([`eta_seconds`]): its time goes where the surface is.
//!
//! The series is bounded: it holds at most [`MAX_SERIES_POINTS`] points whatever the volume. When
//! it is full, neighbouring points are merged pairwise and each later point covers twice as many
//! slabs (`stride` 1, 2, 4, ...). A merged point keeps the cumulative counts of its last slab, the
//! largest resident face count and RSS of its slabs (so the peaks survive) and the smallest
//! resident face count (so the saw-tooth stays visible as a band).

use std::sync::Mutex;
use std::time::{Duration, Instant};

use isostream_volume::Grid;
use serde::{Deserialize, Serialize};
use tracing::info;

use crate::rss::current_rss_bytes;
use crate::stages::{Pass, Progress, RunStart};

/// Most points a run summary's series holds (between half this and this once decimated).
pub const MAX_SERIES_POINTS: usize = 1024;

/// The state of the run at the end of one slab, or of several merged slabs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SeriesPoint {
    /// Slabs completed (the last slab this point covers).
    pub slab: u64,
    /// Slabs this point stands for: 1 until the series is decimated.
    pub slabs: u64,
    /// Voxels read so far.
    pub voxels_done: u64,
    /// Full-resolution faces the simplifier received so far.
    pub faces_in: u64,
    /// Faces it emitted so far.
    pub faces_out: u64,
    /// Most faces resident in the simplifier at the end of any of the point's slabs.
    pub resident_faces: u64,
    /// Fewest faces resident at the end of any of the point's slabs.
    pub resident_faces_min: u64,
    /// Largest resident set size of the process (from the OS) at the end of any of its slabs.
    pub rss_bytes: Option<u64>,
    /// Seconds since the job started (its first pass included), at its last slab.
    pub seconds: f64,
}

impl SeriesPoint {
    /// `self` followed by `later`, as one point.
    fn merge(self, later: SeriesPoint) -> SeriesPoint {
        SeriesPoint {
            slabs: self.slabs + later.slabs,
            resident_faces: self.resident_faces.max(later.resident_faces),
            resident_faces_min: self.resident_faces_min.min(later.resident_faces_min),
            rss_bytes: self.rss_bytes.max(later.rss_bytes),
            ..later
        }
    }
}

/// The per-slab time series of a run, at most [`MAX_SERIES_POINTS`] points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeSeries {
    /// Observed slabs merged into each point (1, 2, 4, ...; the last point may hold fewer).
    pub stride: u64,
    pub points: Vec<SeriesPoint>,
}

impl TimeSeries {
    /// The highest resident set size sampled (merged points keep their slabs' highest).
    pub fn peak_rss_bytes(&self) -> Option<u64> {
        self.points.iter().filter_map(|p| p.rss_bytes).max()
    }
}

/// Builds a [`TimeSeries`] one observation at a time, within `max` points.
#[derive(Debug)]
struct SeriesBuilder {
    max: usize,
    stride: u64,
    points: Vec<SeriesPoint>,
    /// Observations merged so far into the point not yet pushed, and that point.
    pending: Option<(u64, SeriesPoint)>,
    last_slab: u64,
}

impl SeriesBuilder {
    fn new(max: usize) -> Self {
        assert!(
            max >= 2 && max.is_multiple_of(2),
            "an even number of points"
        );
        SeriesBuilder {
            max,
            stride: 1,
            points: Vec::new(),
            pending: None,
            last_slab: 0,
        }
    }

    /// `point.slabs` is filled in here from the previous observation.
    fn push(&mut self, mut point: SeriesPoint) {
        point.slabs = point.slab.saturating_sub(self.last_slab);
        self.last_slab = point.slab;
        let (count, merged) = match self.pending.take() {
            Some((n, p)) => (n + 1, p.merge(point)),
            None => (1, point),
        };
        if count < self.stride {
            self.pending = Some((count, merged));
            return;
        }
        self.points.push(merged);
        if self.points.len() == self.max {
            self.points = self
                .points
                .chunks(2)
                .map(|pair| pair[0].merge(pair[1]))
                .collect();
            self.stride *= 2;
        }
    }

    fn finish(mut self) -> TimeSeries {
        self.points.extend(self.pending.map(|(_, p)| p));
        TimeSeries {
            stride: self.stride,
            points: self.points,
        }
    }
}

/// Watches a job through its progress observer: records the run's series, logs progress every
/// `log_every`, and passes every `Progress` on to the caller's observer.
pub(crate) struct Monitor<'a> {
    /// The job's start.
    started: Instant,
    voxels_per_slab: u64,
    voxels: u64,
    slabs_total: u64,
    log_every: Option<Duration>,
    observer: &'a (dyn Fn(&Progress) + Sync),
    state: Mutex<State>,
}

struct State {
    series: SeriesBuilder,
    last_log: Instant,
    /// When the pass under way began: its rate and ETA count from here.
    pass_started: Instant,
    /// The faces the pass's simplifier receives in all, when counted before it (see
    /// [`Progress::faces_total`]).
    faces_total: Option<u64>,
}

impl<'a> Monitor<'a> {
    /// `started`: the job's start. `log_every`: `None` logs no progress lines.
    pub fn new(
        started: Instant,
        grid: Grid,
        log_every: Option<Duration>,
        observer: &'a (dyn Fn(&Progress) + Sync),
    ) -> Self {
        Monitor {
            started,
            voxels_per_slab: grid.dims[0] * grid.dims[1],
            voxels: grid.voxel_count(),
            slabs_total: grid.dims[2].saturating_sub(1),
            log_every,
            observer,
            state: Mutex::new(State {
                series: SeriesBuilder::new(MAX_SERIES_POINTS),
                last_log: started,
                pass_started: started,
                faces_total: None,
            }),
        }
    }

    /// A pass over the volume begins now (the first pass, then the run): a rate over the time
    /// before it (the first pass's 20 s and more at `upsample` 16) promised a 78 s run's end in
    /// 15 minutes. `faces_total`: the faces its simplifier will receive, when a first pass
    /// counted them (the run's ETA paces by them; `None` for the first pass itself).
    /// `start`: where it begins (a resumed run's checkpoint slab and faces, else 0).
    ///
    /// The caller's observer hears of it at once ([`Progress::begins`]): until the first slab
    /// it knew neither the pass nor its total.
    pub fn pass_begins(&self, pass: Pass, start: RunStart, faces_total: Option<u64>) {
        {
            let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
            state.pass_started = Instant::now();
            state.faces_total = faces_total;
        }
        (self.observer)(&Progress {
            faces_total,
            ..Progress::begins(pass, start, self.slabs_total)
        });
    }

    /// The observer the stages call after every slab. It passes `p` on with
    /// [`Progress::faces_total`] filled in, which the stages do not know.
    pub fn observe(&self, p: &Progress) {
        let faces_total = self
            .state
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .faces_total;
        let p = &Progress { faces_total, ..*p };
        let seconds = self.started.elapsed().as_secs_f64();
        // Slab k done means slices 0..=k were read.
        let voxels_done = ((p.slabs_done + 1) * self.voxels_per_slab).min(self.voxels);
        let rss_bytes = current_rss_bytes();
        {
            let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
            // Read before this run: a run resumed at slab 320 of 765 counted those slabs against
            // the seconds since the restart, and its progress lines promised the end in 3 s of 40.
            let before = p.slabs_at_start * self.voxels_per_slab;
            if p.pass == Pass::Run {
                state.series.push(SeriesPoint {
                    slab: p.slabs_done,
                    slabs: 1,
                    voxels_done,
                    faces_in: p.faces_in,
                    faces_out: p.faces_out,
                    resident_faces: p.resident_faces,
                    resident_faces_min: p.resident_faces,
                    rss_bytes,
                    seconds,
                });
            }
            if let Some(every) = self.log_every
                && state.last_log.elapsed() >= every
            {
                state.last_log = Instant::now();
                let pass_seconds = state.pass_started.elapsed().as_secs_f64();
                let rate = voxels_done.saturating_sub(before) as f64 / pass_seconds.max(1e-9);
                let voxels = Done {
                    start: before,
                    now: voxels_done,
                    total: self.voxels,
                };
                let eta_s = eta_seconds(pass_seconds, voxels, p.faces_done());
                log_progress(
                    p,
                    voxels_done,
                    self.voxels,
                    seconds,
                    (rate, eta_s),
                    rss_bytes,
                );
            }
        }
        (self.observer)(p);
    }

    pub fn finish(self) -> TimeSeries {
        self.state
            .into_inner()
            .unwrap_or_else(|e| e.into_inner())
            .series
            .finish()
    }
}

/// How far a pass has gone in one measure of its work (voxels, slabs or faces): what was done
/// when its pace began (past 0 for a resumed run), what is done now, and the pass's total.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Done {
    pub start: u64,
    pub now: u64,
    pub total: u64,
}

impl Done {
    /// Done since the pace began.
    fn since_start(self) -> u64 {
        self.now.saturating_sub(self.start)
    }

    /// Done per second over the `seconds` since the start, `None` before anything is done.
    pub fn per_second(self, seconds: f64) -> Option<f64> {
        let done = self.since_start();
        (done > 0).then(|| done as f64 / seconds.max(1e-9))
    }

    /// Seconds left at the pace of the `seconds` since the start, `None` before anything is done.
    fn left(self, seconds: f64) -> Option<f64> {
        let done = self.since_start();
        (done > 0).then(|| seconds * self.total.saturating_sub(self.now) as f64 / done as f64)
    }
}

/// The share of the faces over which the sweep's estimate gives way to the faces'.
const FACES_TRUSTED: f64 = 0.05;

/// Seconds left in a pass that began `seconds` ago, or `None` before it has done anything to
/// pace by. With `faces` (the run's, when a first pass counted them) the estimate follows the
/// faces: the simplifier's work does, and the surface is rarely spread evenly over the sweep (a
/// gigavoxel run whose surface sat mid-volume was promised its end in 51 s of 157 at 3.6 % of
/// the voxels, by the voxels). A few faces done pace the rest badly (and none not at all), so
/// over the first [`FACES_TRUSTED`] of them the estimate moves from the sweep's to the faces':
/// the true time left lies between the two, nearer the sweep's the more of the time so far the
/// sweep took. Without `faces` it is the sweep's alone.
pub fn eta_seconds(seconds: f64, sweep: Done, faces: Option<Done>) -> Option<f64> {
    let by_sweep = sweep.left(seconds)?;
    let Some((faces, by_faces)) = faces.and_then(|f| Some((f, f.left(seconds)?))) else {
        return Some(by_sweep);
    };
    let share = faces.since_start() as f64 / faces.total.saturating_sub(faces.start).max(1) as f64;
    let weight = (share / FACES_TRUSTED).min(1.0);
    Some(weight * by_faces + (1.0 - weight) * by_sweep)
}

/// One structured line: which pass, where its sweep is, how fast it goes and when it should end
/// (`pace`: the pass's; no `eta_s` before there is a pace), the seconds since the job's start. The first pass has no faces to
/// tell yet (it counts them at its end), so its lines leave the faces out.
fn log_progress(
    p: &Progress,
    voxels_done: u64,
    voxels: u64,
    seconds: f64,
    (rate, eta_s): (f64, Option<f64>),
    rss: Option<u64>,
) {
    let round1 = |x: f64| (x * 10.0).round() / 10.0;
    // `None` fields are left out of the line.
    let faces = |n: u64| (p.pass == Pass::Run).then_some(n);
    info!(
        pass = p.pass.name(),
        slab = p.slabs_done,
        of = p.slabs_total,
        percent = round1(100.0 * voxels_done as f64 / voxels.max(1) as f64),
        voxels_per_s = rate.round(),
        elapsed_s = round1(seconds),
        eta_s = eta_s.map(round1),
        faces_in = faces(p.faces_in),
        faces_out = faces(p.faces_out),
        resident_faces = faces(p.resident_faces),
        rss_mib = round1(rss.unwrap_or(0) as f64 / (1024.0 * 1024.0)),
        "progress"
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A pass is reported as it begins, with its real total and nothing done: until its first
    /// slab the bar showed "slab 0/1" and a pace of nothing.
    #[test]
    fn a_pass_is_reported_as_it_begins() {
        let seen = Mutex::new(Vec::new());
        let observer = |p: &Progress| seen.lock().unwrap().push(*p);
        let grid = Grid::new([4, 4, 256], [1.0; 3], [0.0; 3]).unwrap();
        let monitor = Monitor::new(Instant::now(), grid, None, &observer);
        monitor.pass_begins(Pass::First, RunStart::default(), None);
        let resumed = RunStart {
            slabs: 40,
            faces_in: 5_000,
            faces_out: 300,
        };
        monitor.pass_begins(Pass::Run, resumed, Some(1_000));
        let seen = seen.into_inner().unwrap();
        let [first, run] = seen.as_slice() else {
            panic!("{seen:?}")
        };
        assert_eq!(
            (first.pass, first.slabs_done, first.slabs_total),
            (Pass::First, 0, 255)
        );
        assert_eq!(
            (
                run.pass,
                run.slabs_done,
                run.slabs_at_start,
                run.faces_total
            ),
            (Pass::Run, 40, 40, Some(1_000))
        );
        // A resumed run's restored faces, as its slabs will report them.
        assert_eq!(
            (run.faces_in, run.faces_out, run.faces_in_at_start),
            (5_000, 300, 5_000)
        );
        assert_eq!(
            Done {
                start: run.slabs_at_start,
                now: run.slabs_done,
                total: run.slabs_total
            }
            .per_second(1e-6),
            None
        );
    }

    #[test]
    fn a_resumed_run_paces_by_the_slabs_it_read() {
        // 1,000-voxel slices, 100 slabs; resumed at slab 40, slab 50 done 10 s later.
        let voxels = Done {
            start: 40_000,
            now: 51_000,
            total: 100_000,
        };
        let eta = eta_seconds(10.0, voxels, None).unwrap();
        assert!((eta - 49_000.0 / 1_100.0).abs() < 1e-9, "{eta}");
    }

    /// The trial's run: a quarter of the sweep done in 20 s, but the surface is mid-volume and
    /// only a tenth of the faces are in. The voxels promise 60 s; the faces say 180 s.
    #[test]
    fn the_run_paces_by_its_faces_when_their_total_is_known() {
        let voxels = Done {
            start: 0,
            now: 250,
            total: 1000,
        };
        let faces = Done {
            start: 0,
            now: 10_000,
            total: 100_000,
        };
        assert_eq!(eta_seconds(20.0, voxels, None), Some(60.0));
        assert_eq!(eta_seconds(20.0, voxels, Some(faces)), Some(180.0));
        // Resumed with half the faces in: the 10 s since paced 10,000 more of the 50,000 left.
        let resumed = Done {
            start: 50_000,
            now: 60_000,
            total: 100_000,
        };
        assert_eq!(eta_seconds(10.0, voxels, Some(resumed)), Some(40.0));
    }

    #[test]
    fn few_faces_lean_on_the_sweep_and_none_pace_nothing() {
        let voxels = Done {
            start: 0,
            now: 100,
            total: 1000,
        };
        let faces = |now| {
            Some(Done {
                start: 0,
                now,
                total: 100_000,
            })
        };
        // No face yet: all the time so far was the sweep's.
        assert_eq!(eta_seconds(10.0, voxels, faces(0)), Some(90.0));
        // 1 % of the faces: a fifth of the way to the faces' 990 s.
        let eta = eta_seconds(10.0, voxels, faces(1_000)).unwrap();
        assert!((eta - (0.2 * 990.0 + 0.8 * 90.0)).abs() < 1e-9, "{eta}");
        // Nothing done since the pass began: no pace, no ETA (not 0 s).
        let idle = Done { now: 0, ..voxels };
        assert_eq!(eta_seconds(10.0, idle, faces(0)), None);
    }

    fn point(slab: u64, resident: u64) -> SeriesPoint {
        SeriesPoint {
            slab,
            slabs: 1,
            voxels_done: slab * 100,
            faces_in: slab * 10,
            faces_out: slab * 2,
            resident_faces: resident,
            resident_faces_min: resident,
            rss_bytes: Some(1000 + resident),
            seconds: slab as f64 * 0.5,
        }
    }

    #[test]
    fn short_runs_keep_every_slab() {
        let mut b = SeriesBuilder::new(8);
        for s in 1..=5 {
            b.push(point(s, s * 3));
        }
        let series = b.finish();
        assert_eq!(series.stride, 1);
        assert_eq!(series.points.len(), 5);
        assert_eq!(series.points[2], point(3, 9));
    }

    #[test]
    fn a_full_series_is_halved_keeping_peaks_and_troughs() {
        let mut b = SeriesBuilder::new(4);
        // A saw-tooth: 10, 50, 20, 60.
        for (s, r) in [(1, 10), (2, 50), (3, 20), (4, 60)] {
            b.push(point(s, r));
        }
        let series = b.finish();
        assert_eq!(series.stride, 2);
        assert_eq!(series.points.len(), 2);
        let [a, c] = [series.points[0], series.points[1]];
        assert_eq!(
            (a.slab, a.slabs, a.resident_faces, a.resident_faces_min),
            (2, 2, 50, 10)
        );
        assert_eq!((c.slab, c.faces_in, c.rss_bytes), (4, 40, Some(1060)));
        assert_eq!(series.peak_rss_bytes(), Some(1060));
    }

    proptest! {
        /// Whatever the length: bounded, cumulative counts of the last slab kept, every slab
        /// accounted for, extremes kept.
        #[test]
        fn bounded_and_faithful(
            residents in prop::collection::vec(0u64..1000, 1..600),
            gaps in prop::collection::vec(1u64..3, 600),
        ) {
            let mut b = SeriesBuilder::new(16);
            let mut slab = 0;
            for (i, &r) in residents.iter().enumerate() {
                slab += gaps[i];
                b.push(point(slab, r));
            }
            let s = b.finish();
            prop_assert!(s.points.len() <= 16);
            let last = *s.points.last().unwrap();
            prop_assert_eq!(last.slab, slab);
            prop_assert_eq!(last.faces_in, slab * 10);
            prop_assert_eq!(s.points.iter().map(|p| p.slabs).sum::<u64>(), slab);
            prop_assert!(s.points.windows(2).all(|w| w[0].slab < w[1].slab));
            let max = s.points.iter().map(|p| p.resident_faces).max();
            let min = s.points.iter().map(|p| p.resident_faces_min).min();
            prop_assert_eq!(max, residents.iter().copied().max());
            prop_assert_eq!(min, residents.iter().copied().min());
            // The summary's peak RSS takes the most of this and the kernel's lagging mark.
            let rss = residents.iter().map(|r| 1000 + r).max();
            prop_assert_eq!(s.peak_rss_bytes(), rss);
        }
    }
}
