//! The wiring of an isostream job: config, stage threads, bounded channels, run summary.
//!
//! This is the only crate that spawns threads. Each stage (read, extract, detect, simplify,
//! write) runs on its own thread, extraction on a pool of `[pipeline] threads`; the channels between them are bounded, so a slow stage makes
//! the earlier ones wait instead of queueing without limit: together with the simplifier's
//! retirement this keeps memory bounded by the sweep front. See ARCHITECTURE.md.
#![deny(unsafe_code)]

mod attributes;
mod checkpoint;
mod config;
mod error;
mod extract_pool;
mod flow;
mod index_limit;
mod mirror;
mod monitor;
mod output;
mod range;
mod rss;
mod sink;
mod source;
mod stages;

use std::num::NonZeroU64;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use isostream_detect::{Detector, MeshDelta};
use isostream_extract::{CubeBatch, ExtractStats};
use isostream_prune::{Census, Filter, SmallPieces};
use isostream_simplify::{
    Boundary, Cascade, Domain, Policy, Simplifier, SimplifyConfig as SimplifierConfig,
};
use isostream_smesh::{Header, printable_ascii};
use isostream_volume::VolumeSource;
use serde::{Deserialize, Serialize};
use tracing::{info, warn};

pub use attributes::{AttributeConfig, Derived, SliceReader, Slices};
pub use checkpoint::{checkpoint_note, path_for as checkpoint_path, resumable_files};
pub use config::{
    CheckpointConfig, CheckpointEvery, ExtractConfig, InputConfig, JobConfig, LogConfig, LogFormat,
    Mode, OutputConfig, PipelineConfig, PriorityKind, SimplifyConfig,
};
pub use error::{ConfigError, RunError};
pub use index_limit::Counted;
pub use mirror::Mirror;
pub use monitor::{Done, MAX_SERIES_POINTS, SeriesPoint, TimeSeries, eta_seconds};
pub use output::{OutputLock, lock_output, lock_path, one_file, output_in_use, stale_temp_files};
pub use rss::{current_rss_bytes, peak_rss_bytes};
pub use sink::SinkStats;
pub use source::{open_source, orientation_warning, preflight};
pub use stages::{Pass, Progress, StageSeconds};

/// What a finished run reports (logged, and written as `<output>.run.json`; read back from a
/// run's `checkpoint::Finished` record).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunSummary {
    pub input: String,
    pub dims: [u64; 3],
    pub voxels: u64,
    pub iso: f64,
    pub mode: Mode,
    pub output: PathBuf,
    pub faces_extracted: u64,
    /// The faces the simplifier received: `faces_extracted` less the faces pruned
    /// (`[simplify] min_component_faces`).
    pub faces_kept: u64,
    /// Mode `rate`: `[output] faces`, else `round(rate x faces_kept)`.
    pub target_faces: Option<u64>,
    /// Mode `rate`: the rate used (`[output] faces` over `faces_kept` when faces is set).
    pub rate: Option<f64>,
    pub faces_written: u64,
    pub vertices_written: u64,
    pub seconds: f64,
    pub stage_seconds: StageSeconds,
    /// The most of the kernel's high-water mark (`VmHWM`) and of the series' samples
    /// ([`TimeSeries::peak_rss_bytes`]): the kernel updates its mark lazily, and it came out
    /// below the series' highest value.
    pub peak_rss_bytes: Option<u64>,
    /// The simplifiers' most faces held ([`isostream_simplify::SimplifyStats::peak_resident_faces`]:
    /// for two stages, the sum of their peaks).
    pub peak_resident_faces: u64,
    /// Tandem section 4: Error(K) = max eps0 over the vertices made by contractions (0 when
    /// nothing was contracted). Bounded by E0 in mode = "error".
    pub shape_error: f64,
    pub extract: isostream_extract::ExtractStats,
    pub detect: isostream_detect::DetectStats,
    /// `[simplify] min_component_faces`: the components and faces dropped before simplifying
    /// (`None` when every component is kept).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prune: Option<isostream_prune::PruneStats>,
    pub simplify: isostream_simplify::SimplifyStats,
    /// `[pipeline] simplify_stages = 2`: the first and the second stage's counters (`simplify`
    /// adds them up), to see which stage decimated, delayed or retired what.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub simplify_stages: Option<[isostream_simplify::SimplifyStats; 2]>,
    pub sink: SinkStats,
    /// The slab this run continued from (`--resume`), `None` when it started at the beginning.
    /// Counters cover the whole job; times cover this run only.
    pub resumed_at_slab: Option<u64>,
    /// What the user should know about the result (also logged as warnings).
    pub warnings: Vec<String>,
    /// Per slab: voxels done, faces in / out / resident, RSS, seconds (at most
    /// [`MAX_SERIES_POINTS`] points; see `monitor`). Plotted by `isostream report`.
    pub series: TimeSeries,
}

impl RunSummary {
    /// The voxels this run read: all of them, or for a resumed run those from its checkpoint's
    /// slab on ([`voxels_from_slab`]). Its counters cover the whole job, its times this run only:
    /// a rate, or a metric counted per run, needs this.
    pub fn voxels_this_run(&self) -> u64 {
        voxels_from_slab(self.dims, self.resumed_at_slab)
    }
}

/// The voxels of a `dims` volume a run that started at slab `start` reads (`None`: at the
/// beginning, all of them): the slices from `start` on, as the progress monitor counts them.
pub fn voxels_from_slab(dims: [u64; 3], start: Option<u64>) -> u64 {
    let per_slice = dims[0] * dims[1];
    let all = per_slice * dims[2];
    all.saturating_sub(start.unwrap_or(0).saturating_mul(per_slice))
}

/// How a run treats the checkpoint an earlier run of the same output left (see `checkpoint`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Start {
    /// Refuse when there is a checkpoint ([`RunError::CheckpointFound`]): it may hold hours of
    /// work, which only an explicit `Restart` throws away.
    #[default]
    Fresh,
    /// Continue from the checkpoint when there is one (after checking that the job and the
    /// input are the same), else start from the beginning.
    Resume,
    /// Remove any checkpoint and its temporary files, then start from the beginning.
    Restart,
}

/// Runs a validated job from the beginning (refusing to when a checkpoint exists: see
/// [`run_from`]). `cancel` stops it (Ctrl-C): between slices, and within milliseconds in the
/// simplifier's passes and its final decimation; `observer` sees progress after every slab.
pub fn run(
    job: &JobConfig,
    job_path: &Path,
    cancel: &AtomicBool,
    observer: &(dyn Fn(&Progress) + Sync),
) -> Result<RunSummary, RunError> {
    run_from(job, job_path, Start::Fresh, cancel, observer)
}

/// Runs a validated job, continuing from a checkpoint as `start` says. A run that completes
/// removes its checkpoint; one that is cancelled after a checkpoint keeps it and its temporary
/// files and returns [`RunError::Interrupted`].
pub fn run_from(
    job: &JobConfig,
    job_path: &Path,
    start: Start,
    cancel: &AtomicBool,
    observer: &(dyn Fn(&Progress) + Sync),
) -> Result<RunSummary, RunError> {
    let ckpt_path = checkpoint::path_for(&job.output.path);
    let result = run_job(job, job_path, start, &ckpt_path, cancel, observer);
    match result {
        Err(RunError::Cancelled) if ckpt_path.exists() => Err(RunError::Interrupted {
            percent: checkpoint::read(&ckpt_path).map_or(0.0, |c| c.percent()),
            checkpoint: ckpt_path,
        }),
        other => other,
    }
}

/// A run stopped at its end by what a resume would meet again (an empty surface, a classical
/// run over its budget: the job and the data decide them) leaves nothing worth resuming: its
/// checkpoint and temporary files are removed, or the next run asked for `--resume` only to
/// fail the same way. Interrupts and I/O failures (a full disk) keep them: a resume finishes
/// those runs.
fn abandon(ckpt_path: &Path, e: RunError) -> RunError {
    if matches!(
        e,
        RunError::EmptySurface { .. } | RunError::ClassicalOverBudget { .. }
    ) && let Err(d) = checkpoint::discard(ckpt_path)
    {
        warn!("{d}");
    }
    e
}

/// The checkpoint to continue from, as `start` says.
fn saved_checkpoint(
    start: Start,
    ckpt_path: &Path,
    output: &Path,
) -> Result<Option<checkpoint::Saved>, RunError> {
    let exists = ckpt_path.exists();
    match start {
        Start::Restart => {
            checkpoint::discard(ckpt_path)?;
            Ok(None)
        }
        Start::Fresh if exists => Err(match checkpoint::read(ckpt_path) {
            Ok(checkpoint::Saved::Partway(c)) => RunError::CheckpointFound {
                output: output.to_path_buf(),
                checkpoint: ckpt_path.to_path_buf(),
                percent: c.percent(),
            },
            Ok(checkpoint::Saved::Finished(_)) => RunError::FinishedFound {
                output: output.to_path_buf(),
                checkpoint: ckpt_path.to_path_buf(),
            },
            Err(e) => e,
        }),
        Start::Resume if exists => checkpoint::read(ckpt_path).map(Some),
        Start::Resume => {
            info!(checkpoint = %ckpt_path.display(), "no checkpoint: starting from the beginning");
            Ok(None)
        }
        Start::Fresh => Ok(None),
    }
}

fn run_job(
    job: &JobConfig,
    job_path: &Path,
    start: Start,
    ckpt_path: &Path,
    cancel: &AtomicBool,
    observer: &(dyn Fn(&Progress) + Sync),
) -> Result<RunSummary, RunError> {
    let started = Instant::now();
    let saved = saved_checkpoint(start, ckpt_path, &job.output.path)?;
    let mut source = open_source(&job.input)?;
    let grid = source.grid();
    let input = source.describe();
    info!(input = %input, dims = ?grid.dims, iso = job.extract.iso, mode = %job.simplify.mode, "job start");
    // Said at the start (the mesh of a long run is in the wrong place from its first slab), and
    // kept for the summary's warnings.
    let dropped_orientation = orientation_warning(source.as_ref())
        .into_iter()
        .chain(attributes_not_written(job))
        .collect::<Vec<_>>();
    // The input's axis flips, undone on the way out (`mirror.rs`).
    let mirror = Mirror::of(source.as_ref());
    for w in &dropped_orientation {
        warn!("{w}");
    }
    if source.loads_whole_volume() {
        warn!(input = %input, "the input's encoding forces decoding the whole volume at once (one chunk spans every slice): memory grows with the volume; re-chunk it along z");
    }

    // What `preflight` checks, checked before the first pass of `[output] faces` (a bad
    // attribute file failed only after it).
    source::check_against_input(job, source.as_ref())?;
    let attribute_sources =
        attributes::open(&job.attributes, &job.input, grid, source.orientation())?;
    // A resume of a changed job or input is refused before the first pass of `[output] faces`
    // (it ran to its end first).
    let every = job.pipeline.checkpoint.every(grid.voxel_count());
    let identity = match every.is_some() || saved.is_some() {
        true => Some(checkpoint::InputIdentity::read(job, source.as_mut())?),
        false => None,
    };
    if let (Some(saved), Some(identity)) = (&saved, &identity) {
        checkpoint::verify(ckpt_path, saved, job, identity)?;
    }
    let saved = match saved {
        Some(checkpoint::Saved::Finished(finished)) => {
            info!(checkpoint = %ckpt_path.display(), "the run that saved the checkpoint had written its output: finishing it");
            finished.place(ckpt_path, &job.output.path)?;
            return conclude(job, ckpt_path, finished.summary);
        }
        Some(checkpoint::Saved::Partway(c)) => Some(c),
        None => None,
    };
    let rate = job.simplify.rate();
    let prune = NonZeroU64::new(job.simplify.min_component_faces);
    // `[output] faces` needs the counts, pruning the census, and the stage count on large slices
    // the largest slab's. A resumed run finds the pruning state and the counts in its
    // checkpoint (the interrupted run's, which the same job and input give again).
    let counted =
        job.output.faces.is_some() || prune.is_some() || job.counts_slabs_for_stages(grid.dims);
    // From the job's start: the first pass's progress goes through it too.
    let monitor = monitor::Monitor::new(started, grid, job.log.progress_interval(), observer);
    let observe = |p: &Progress| monitor.observe(p);
    let mut filter = None;
    let counts = match &saved {
        Some(c) => {
            if let Some(counts) = &c.first_pass {
                info!(
                    kept = counts.kept,
                    largest_slab = counts.largest_slab,
                    "first pass's counts from the checkpoint: not run again"
                );
            }
            c.first_pass
        }
        None if counted => {
            monitor.pass_begins(Pass::First, stages::RunStart::default(), None);
            let pass = first_pass(job, prune, cancel, &observe)?;
            if !job.output.allow_empty {
                pass.check_something_kept(job, job_path)?;
            }
            let counts = pass.counts();
            filter = pass.small.map(Filter::new);
            Some(counts)
        }
        None => None,
    };
    let largest_slab = counts.map(|c| c.largest_slab);
    let rate = match (job.output.faces, counts) {
        // R applies to the faces kept: `faces` is what the simplifier is asked to write.
        (Some(faces), Some(counts)) => (faces as f64 / counts.kept.max(1) as f64).min(1.0),
        _ => rate,
    };
    let (config, second_config) = simplifier_configs(job, grid, rate, largest_slab);
    // The faces of the whole budget: a cascade's second stage has it all, less what the first holds.
    let budget_faces = second_config.as_ref().unwrap_or(&config).max_resident_faces;
    let new_simplifier = |config: &SimplifierConfig| {
        Simplifier::new(config.clone()).map_err(|e| {
            RunError::Config(ConfigError::Invalid {
                path: job_path.to_path_buf(),
                key: "simplify".into(),
                expected: "a valid simplification setting".into(),
                got: e.to_string(),
            })
        })
    };
    let mut simplifier = new_simplifier(&config)?;
    let mut second = second_config.as_ref().map(new_simplifier).transpose()?;
    let header = Header {
        comments: vec![
            format!("isostream {}", env!("CARGO_PKG_VERSION")),
            format!("input {} iso {}", printable_ascii(&input), job.extract.iso),
        ],
        attribute_names: job.attributes.iter().map(|a| a.name.clone()).collect(),
    };
    output::create_output_dir(&job.output.path).map_err(|e| {
        RunError::Config(ConfigError::Invalid {
            path: job_path.to_path_buf(),
            key: "output.path".into(),
            expected: "a folder that can be created".into(),
            got: format!("{}: {e}", job.output.path.display()),
        })
    })?;
    let (sink, resume) = match (saved, &identity) {
        (Some(saved), Some(_)) => {
            let restore = |config: &SimplifierConfig, saved: Simplifier| {
                Simplifier::restore(config, saved).map_err(|e| RunError::ResumeMismatch {
                    path: ckpt_path.to_path_buf(),
                    what: e.to_string(),
                })
            };
            simplifier = restore(
                &config,
                checkpoint::decode_section(ckpt_path, saved.simplify)?,
            )?;
            second = match &second_config {
                Some(c) => Some(restore(
                    c,
                    checkpoint::decode_section(ckpt_path, saved.simplify_second)?,
                )?),
                None => None,
            };
            let parts = saved.parts;
            if prune.is_some() {
                filter = Some(Filter::restore(checkpoint::decode(
                    ckpt_path,
                    &parts.prune,
                )?));
            }
            let detector =
                Detector::restore(grid.dims, checkpoint::decode(ckpt_path, &parts.detect)?)
                    .map_err(|e| RunError::ResumeMismatch {
                        path: ckpt_path.to_path_buf(),
                        what: e.to_string(),
                    })?;
            info!(
                slab = parts.reader.z,
                of = grid.dims[2] - 1,
                checkpoint = %ckpt_path.display(),
                "resuming from the checkpoint"
            );
            let sink =
                sink::Sink::resume(&job.output.path, &header, mirror, parts.sink, ckpt_path)?;
            let resume = stages::Resume {
                reader: parts.reader,
                extract: parts.extract,
                detector,
            };
            (sink, Some(resume))
        }
        _ => (sink::Sink::create(&job.output.path, &header, mirror)?, None),
    };
    let mut reader = SliceReader::new(source, attribute_sources).rows_on_demand();
    if job.extract.skip_empty {
        reader = reader.skip_empty(job.extract.iso as f32);
    }
    let resumed_at_slab = resume.as_ref().map(|r| r.reader.z);
    let checkpoints = every
        .zip(identity.clone())
        .map(|(every, input)| stages::Plan {
            every,
            path: ckpt_path.to_path_buf(),
            job: checkpoint::job_hash(job),
            input,
            first_pass: counts,
        });
    if let Some(r) = &resume {
        // The checkpoint's carried slice is read again (and checked against its hash).
        reader.seek(r.reader.z)?;
    }
    // The faces the simplifier receives are the first pass's kept ones.
    monitor.pass_begins(
        Pass::Run,
        stages::RunStart::of(resumed_at_slab.unwrap_or(0), &simplifier, second.as_ref()),
        counts.map(|c| c.kept),
    );
    let mut outputs = stages::Stages {
        reader,
        input: input.clone(),
        iso: job.extract.iso,
        filter,
        simplifier,
        second,
        sink,
        capacity: job.pipeline.channel_capacity,
        batch_triangles: job.pipeline.batch_triangles,
        threads: job.pipeline.threads(),
        skip_empty: job.extract.skip_empty,
        allow_empty: job.output.allow_empty,
        cancel,
        observer: &observe,
        checkpoints,
        resume,
    }
    .run()
    .map_err(|e| abandon(ckpt_path, e))?;
    let series = monitor.finish();
    let peak_rss = peak_rss_bytes().max(series.peak_rss_bytes());
    let peak_rss_mib = peak_rss.map(|b| b as f64 / (1024.0 * 1024.0));

    let sink_stats = outputs.sink;
    let faces_kept = outputs.extract.triangles - outputs.prune.map_or(0, |p| p.faces_pruned);
    let target_faces = (job.simplify.mode == Mode::Rate).then(|| {
        job.output
            .faces
            .unwrap_or_else(|| rate_target(rate, faces_kept))
    });
    let late: Vec<String> = target_faces
        .and_then(|target| {
            // A cascade's first stage retires for memory by design (it hands its surface on);
            // what the last stage retired early was written less simplified.
            let last = outputs
                .simplify_stages
                .as_ref()
                .map_or(&outputs.simplify, |[_, second]| second);
            rate_missed(
                target,
                sink_stats.triangles,
                &outputs.simplify,
                last.forced_retirements,
                job.simplify.min_component_faces,
            )
        })
        .into_iter()
        .chain(front_stretched(
            job,
            budget_faces,
            &outputs.simplify,
            peak_rss_mib,
            |faces| job.budget_holding(grid.dims, largest_slab, faces),
        ))
        .chain(over_budget(
            job,
            grid.dims,
            outputs.simplify_stages.is_some(),
            budget_faces,
            &outputs.simplify,
            peak_rss_mib,
        ))
        .chain(retired_early(job, &outputs.simplify, sink_stats.vertices))
        .chain(faces_past_the_surface(job, faces_kept))
        .chain(non_finite_voxels(&outputs.extract, grid.voxel_count()))
        .chain(non_finite_attributes(&outputs.extract))
        .chain(saturated_voxels(&outputs.extract, &input))
        .chain(saturated_attribute_voxels(&outputs.extract, job))
        .chain(outputs.range.coarse_iso(job.extract.iso, &input))
        .collect();
    if let Some(p) = &outputs.prune {
        info!(
            min_component_faces = p.min_component_faces,
            components = p.components_pruned,
            faces = p.faces_pruned,
            "small components pruned"
        );
    }
    for w in &late {
        warn!("{w}");
    }
    let warnings = dropped_orientation.into_iter().chain(late).collect();
    let summary = RunSummary {
        input,
        dims: grid.dims,
        voxels: grid.voxel_count(),
        iso: job.extract.iso,
        mode: job.simplify.mode,
        output: job.output.path.clone(),
        faces_extracted: outputs.extract.triangles,
        faces_kept,
        target_faces,
        rate: (job.simplify.mode == Mode::Rate).then_some(rate),
        faces_written: sink_stats.triangles,
        vertices_written: sink_stats.vertices,
        seconds: started.elapsed().as_secs_f64(),
        stage_seconds: outputs.seconds,
        peak_rss_bytes: peak_rss,
        peak_resident_faces: outputs.simplify.peak_resident_faces as u64,
        shape_error: outputs.simplify.max_shape_error,
        extract: outputs.extract,
        detect: outputs.detect,
        prune: outputs.prune,
        simplify: outputs.simplify,
        simplify_stages: outputs.simplify_stages,
        sink: sink_stats,
        resumed_at_slab,
        warnings,
        series,
    };
    // Nothing is left to compute: said over the checkpoint before the output is renamed, so
    // that a kill from here on leaves a run `--resume` finishes (`checkpoint::Finished`). A run
    // without a checkpoint has nothing to resume from: its output only needs its name.
    if let Some(input) = identity {
        outputs.output.keep()?;
        let finished = checkpoint::Finished {
            job: checkpoint::job_hash(job),
            input,
            temp: outputs.output.temp_path().to_path_buf(),
            scratch: outputs.output.scratch_paths(),
            bytes: summary.sink.bytes,
            summary: summary.clone(),
        };
        checkpoint::write_finished(ckpt_path, &finished)?;
    }
    outputs.output.persist()?;
    conclude(job, ckpt_path, summary)
}

/// The last steps of a run once its output is under its final name: the run summary, then the
/// checkpoint's removal (a `Finished` record by then, if any), in that order, so that a kill
/// between them leaves the record for `--resume` to do them again. A summary that cannot be
/// written leaves no record behind: the mesh is in place, and the error says so.
fn conclude(
    job: &JobConfig,
    ckpt_path: &Path,
    summary: RunSummary,
) -> Result<RunSummary, RunError> {
    let written = replace_summary(job, &summary);
    let removed = checkpoint::remove(ckpt_path);
    written.and(removed).map(|()| summary)
}

/// Writes the run summary of a run whose output is in place (when `[output] summary` asks).
fn replace_summary(job: &JobConfig, summary: &RunSummary) -> Result<(), RunError> {
    // A summary left by an earlier run describes the mesh this run replaced: gone whether or
    // not this run writes one (`measure` trusts it to name the job that made the mesh).
    let summary_file = summary_path(&job.output.path);
    match std::fs::remove_file(&summary_file) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(RunError::Summary {
                path: summary_file,
                reason: format!("cannot remove the earlier run's: {e}"),
            });
        }
        _ => {}
    }
    if job.output.summary {
        write_summary(summary, &summary_file)?;
    }
    Ok(())
}

/// What the first pass found: the extracted faces, the most one slab had, and, when the job
/// prunes, the small pieces.
struct FirstPass {
    extracted: u64,
    largest_slab: u64,
    small: Option<SmallPieces>,
}

impl FirstPass {
    /// The faces the simplifier will receive.
    fn kept(&self) -> u64 {
        self.extracted - self.small.as_ref().map_or(0, |s| s.stats.faces_pruned)
    }

    /// What the run depends on, saved with its checkpoints.
    fn counts(&self) -> checkpoint::FirstPassCounts {
        checkpoint::FirstPassCounts {
            kept: self.kept(),
            largest_slab: self.largest_slab,
        }
    }

    /// A surface whose every component `min_component_faces` drops is that key's error, not an
    /// empty surface's (whose message points at the iso value, which is right).
    fn check_something_kept(&self, job: &JobConfig, job_path: &Path) -> Result<(), RunError> {
        let Some(small) = self.small.as_ref().filter(|_| self.kept() == 0) else {
            return Ok(());
        };
        if self.extracted == 0 {
            return Ok(());
        }
        let s = &small.stats;
        Err(RunError::Config(ConfigError::Invalid {
            path: job_path.to_path_buf(),
            key: "simplify.min_component_faces".into(),
            expected: format!(
                "at most the largest component's faces, or nothing is kept (the surface's {} \
                 component(s) hold {} faces in all); lower it, or set [output] allow_empty = true",
                s.components_pruned, s.faces_pruned
            ),
            got: job.simplify.min_component_faces.to_string(),
        }))
    }
}

/// The first pass, for `[output] faces` (the extracted face count sets the rate) and for
/// `[simplify] min_component_faces` (the census of components, see `isostream_prune`): the
/// volume is extracted (parallel, empty space skipped) and, to prune, detected; nothing is kept
/// but the counts and the list of small pieces. Without a census the triangles are only
/// counted, not made.
fn first_pass(
    job: &JobConfig,
    prune: Option<NonZeroU64>,
    cancel: &AtomicBool,
    observer: &(dyn Fn(&Progress) + Sync),
) -> Result<FirstPass, RunError> {
    let started = Instant::now();
    let source = open_source(&job.input)?;
    let dims = source.grid().dims;
    let mut census = prune.map(|n| (Detector::new(dims), Census::new(n)));
    // Only the census needs the triangles themselves; a face count is the extractors'.
    let extraction = stages::Extraction {
        counting: census.is_none(),
        ..whole_extraction(job, source)
    };
    let counted = extraction.visit("count", cancel, |batch| {
        if let Some((detector, census)) = &mut census {
            // Batch by batch, not by group: the census follows the triangles' order, and a
            // notice never precedes a triangle of its vertex however the stream is cut.
            let mut delta = MeshDelta::default();
            detector.process(batch, &mut delta);
            census.add(&delta);
        }
        // Every slab ends with a batch saying so, an empty one if need be.
        if batch.end_of_slab {
            observer(&Progress::first_pass(batch.slab, dims[2] - 1));
        }
    })?;
    let small = census.map(|(mut detector, mut census)| {
        let mut last = MeshDelta::default();
        detector.finish(&mut last);
        census.add(&last);
        census.finish()
    });
    let pass = FirstPass {
        extracted: counted.triangles,
        largest_slab: counted.max_slab_triangles,
        small,
    };
    info!(
        extracted = pass.extracted,
        largest_slab = pass.largest_slab,
        kept = pass.kept(),
        small_components = pass.small.as_ref().map(|s| s.stats.components_pruned),
        seconds = started.elapsed().as_secs_f64(),
        "first pass (output.faces, simplify.min_component_faces, the stage count)"
    );
    Ok(pass)
}

/// The job's full-resolution iso-surface, extracted as the first pass extracts it (the pool of
/// `[pipeline] threads` workers, empty space skipped unless `[extract] skip_empty = false`) and
/// handed to `visit` batch by batch in slab order, on the calling thread; nothing of it is kept.
/// `source` is `open_source(&job.input)`'s, so that the caller can read its grid first.
/// `isostream measure` streams the surface its distances need through this.
pub fn visit_surface(
    job: &JobConfig,
    source: Box<dyn VolumeSource>,
    cancel: &AtomicBool,
    visit: impl FnMut(&CubeBatch),
) -> Result<ExtractStats, RunError> {
    whole_extraction(job, source).visit("surface", cancel, visit)
}

/// Two threads for `isostream measure`'s distance queries (its crate spawns none): each
/// batch's samples are queried in two halves, which is most of a measure's time (bonsai's
/// output: 85 % of it in the full -> output queries, on one thread before). With one thread
/// (`[pipeline] threads = 1`) the halves run in turn; the measures are the same either way.
#[derive(Debug, Clone, Copy)]
pub struct MeasureHalves {
    pub threads: bool,
}

impl isostream_measure::Halves for MeasureHalves {
    fn both(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        if !self.threads {
            return isostream_measure::InTurn.both(a, b);
        }
        stages::on_two_threads(a, b);
    }
}

/// The reader and the extraction pool over the whole of `source` (the job's input), without
/// checkpoints.
fn whole_extraction(job: &JobConfig, source: Box<dyn VolumeSource>) -> stages::Extraction {
    let iso = job.extract.iso as f32;
    let mut reader = SliceReader::new(source, Vec::new()).rows_on_demand();
    if job.extract.skip_empty {
        reader = reader.skip_empty(iso);
    }
    stages::Extraction {
        reader,
        iso,
        batch_triangles: job.pipeline.batch_triangles,
        threads: job.pipeline.threads(),
        skip_empty: job.extract.skip_empty,
        first: 0,
        schedule: extract_pool::Schedule::never(),
        carried: None,
        stats: Default::default(),
        counting: false,
    }
}

/// Slabs the first stage of a cascade keeps a vertex editable behind its front: its output is
/// not final, so a short band is enough, and the band is what it adds to the memory. In slabs
/// as thick as the voxels are wide ([`config::thin_slabs`]): in slabs of a thick-slice CT
/// upsampled along z, the band was a fraction of a voxel deep, and the first stage took it to
/// its rate by contractions across it (hydrogen upsampled [2, 2, 40] at `faces = 2000`: 2.9x
/// one stage's RMS distance, 282 triangles under 5 degrees; deepened, 1.00x and none).
const FIRST_STAGE_LAG: u32 = 3;

/// The rate a cascade's first stage decimates to, for a job at `rate`. The second stage's
/// contractions cost more (larger triangles, more candidates refused) and it also takes in its
/// input again, so the first takes more than half of the contractions: at R = 0.2 the stages
/// then execute 3.1 and 3.0 G instructions on the engine crop (callgrind per thread; halfway,
/// 0.6, gave 3.0 and 3.7 G; one simplifier, 5.2 G; docs/performance.md).
fn intermediate_rate(rate: f64) -> f64 {
    rate.max(0.47 + 0.53 * rate)
}

/// The first stage's share of a cascade's face budget, for its retirement by memory: it holds
/// the extraction's unfinished band and a few slabs behind it, and retires the rest. The second
/// stage has the whole budget less what the first holds (`isostream_simplify::Simplifier`'s
/// shared budget), so a dense band beyond this share (engine: 35 k faces) is taken from the
/// second. With a quarter of a fixed split the second stage forced out 23 k faces on bonsai at
/// R = 0.05; with a twelfth of the shared budget engine at R = 0.2 came out with a 0.20 %
/// Hausdorff distance against 0.15 % with a sixth (docs/performance.md).
const FIRST_STAGE_SHARE: usize = 6;

/// The simplifiers of the job: one, or a cascade's two (`[pipeline] simplify_stages`, see
/// `isostream_simplify::Cascade`): the first to [`intermediate_rate`], retiring
/// [`FIRST_STAGE_LAG`] slabs behind its front within `1 / FIRST_STAGE_SHARE` of the face
/// budget and decimating every [`config::FIRST_STAGE_BATCH`] faces unless `batch` is set, the
/// second to the job's rate within the budget less what the first holds.
fn simplifier_configs(
    job: &JobConfig,
    grid: isostream_volume::Grid,
    rate: f64,
    largest_slab: Option<u64>,
) -> (SimplifierConfig, Option<SimplifierConfig>) {
    let single = simplifier_config(job, grid, rate, largest_slab);
    let Policy::Rate { initial_rate, .. } = single.policy else {
        return (single, None);
    };
    if !job.cascade(grid.dims, largest_slab) {
        if let Some(hint) = job.one_stage_hint(grid.dims, largest_slab) {
            info!("{hint}");
        }
        return (single, None);
    }
    let budget = single.max_resident_faces;
    let first = SimplifierConfig {
        policy: Policy::Rate {
            rate: intermediate_rate(rate),
            batch: job.simplify.batch.unwrap_or(config::FIRST_STAGE_BATCH),
            initial_rate,
        },
        retire_lag: FIRST_STAGE_LAG * config::thin_slabs(grid.spacing),
        max_resident_faces: (budget / FIRST_STAGE_SHARE).max(1),
        cascade: Cascade::First,
        ..single.clone()
    };
    // The second stage is given the whole budget: what the first holds counts against it. Its
    // front is the first stage's rear, which moves by rows as the extraction's front does.
    let second = SimplifierConfig {
        cascade: Cascade::Second,
        ..single
    };
    (first, Some(second))
}

/// The simplifier's whole configuration: policy, priority, budget, attributes, and the sweep
/// along z (marching cubes' slabs), in-core for `classical`.
fn simplifier_config(
    job: &JobConfig,
    grid: isostream_volume::Grid,
    rate: f64,
    largest_slab: Option<u64>,
) -> SimplifierConfig {
    let s = &job.simplify;
    SimplifierConfig {
        priority: attributes::priority(job),
        sweep: Some(isostream_simplify::Sweep {
            direction: glam::DVec3::Z,
            origin: grid.origin[2],
            spacing: grid.spacing[2],
            // The extraction reports the rows of each slab it has done (`MeshDelta::rows`).
            rows: Some(isostream_simplify::Rows {
                direction: glam::DVec3::Y,
                origin: grid.origin[1],
                spacing: grid.spacing[1],
                count: u32::try_from(grid.dims[1].saturating_sub(1).max(1)).unwrap_or(u32::MAX),
            }),
        }),
        in_core: s.mode == Mode::Classical,
        policy: match s.mode {
            Mode::None => Policy::None,
            Mode::Rate => Policy::Rate {
                rate,
                batch: s.batch.unwrap_or(u64::MAX),
                initial_rate: s.initial_rate(),
            },
            Mode::Error => Policy::Error {
                e0: s.error.unwrap_or(f64::INFINITY),
                time_lag: s.time_lag(),
                isotropy: s.isotropy(),
            },
            // Everything is modifiable when classical decimation starts: no front, no time-lag.
            Mode::Classical => Policy::Error {
                e0: s.error.unwrap_or(f64::INFINITY),
                time_lag: false,
                isotropy: s.isotropy(),
            },
        },
        retire_lag: s.retire_lag_on(grid.spacing),
        max_resident_faces: job.max_resident_faces(grid.dims, largest_slab),
        attributes: job.attributes.len(),
        cascade: Cascade::Single,
        boundary: match s.boundary() {
            config::BoundaryKind::Exact => Boundary::Exact,
            config::BoundaryKind::Planar => Boundary::Planar,
        },
        domain: Some(domain(&grid)),
    }
}

/// The volume's box where the extractor puts vertices on its faces (`Grid::position`), rounded
/// like every position the simplifier holds.
fn domain(grid: &isostream_volume::Grid) -> Domain {
    let far = grid.dims.map(|n| n.saturating_sub(1) as f64);
    let [p, q] = [
        grid.position(0.0, 0.0, 0.0),
        grid.position(far[0], far[1], far[2]),
    ]
    .map(|x| x.as_vec3().as_dvec3());
    Domain {
        lo: p.min(q),
        hi: p.max(q),
    }
}

/// The face count `rate` aims at on `faces` extracted (and kept) faces: at least 1 face when
/// there are any, since no surface has fewer and a rate small enough to round to 0 (1e-300)
/// missed its target of 0 with "+0 %".
fn rate_target(rate: f64, faces: u64) -> u64 {
    ((rate * faces as f64).round() as u64).max(faces.min(1))
}

/// `[[attributes]]` asked for an output format with no place for them: they still weigh in the
/// simplification (a priority may read them), but nothing of them is written. The OBJ or STL
/// file said so in a comment only, which a user reading the screen never saw.
fn attributes_not_written(job: &JobConfig) -> Option<String> {
    let format = isostream_smesh::Format::from_path(&job.output.path).ok()?;
    (!job.attributes.is_empty() && !format.keeps_attributes()).then(|| {
        let names: Vec<&str> = job.attributes.iter().map(|a| a.name.as_str()).collect();
        format!(
            "{}: this format keeps no vertex attributes, so [[attributes]] {} {} not written; \
             write .smb, .sma, .ply or .glb to keep them",
            job.output.path.display(),
            names.join(", "),
            if names.len() == 1 { "is" } else { "are" }
        )
    })
}

/// The rate target missed by more than 2 %: say by how much and why. Every contraction keeps the
/// topology (the link condition keeps each closed component at least a tetrahedron, and boundary
/// vertices stay on the box's faces: all of them with `boundary = "exact"`), so a surface of many
/// small components or a long boundary (a volume cut by its box) cannot go below a floor; the
/// final pass stops there, having tried every edge it still holds again. What the last
/// simplifier retired for the memory budget (`forced`: vertices) left before it could be taken
/// that far: then the budget, not only the topology, kept the count up (bonsai upsampled to
/// 1021^3, `faces = 10000`, two stages: 87,307 faces at 128 MiB with 37 k vertices retired
/// early, 49,813 at 256 MiB with none), and the warning says so.
///
/// One face off a small target is the step of a contraction, not a floor: it removes two faces
/// (one on a boundary edge), so a closed surface always has an even count. A sphere asked for
/// 11 faces got 10 with no word and for 13 got 14 with a warning blaming the topology checks,
/// which had refused nothing (a torture trial: 8 jobs with targets of 8 to 22 one face under,
/// silent); each now says why in one line.
///
/// The hint on `[simplify] min_component_faces` (`min_faces`, 0 when unset) is phrased for the
/// job's value: a job that set it was told to set it.
fn rate_missed(
    target: u64,
    written: u64,
    stats: &isostream_simplify::SimplifyStats,
    forced: u64,
    min_faces: u64,
) -> Option<String> {
    let off = written as f64 / target.max(1) as f64 - 1.0;
    if written.abs_diff(target) == 1 && off.abs() > 0.02 {
        return Some(format!(
            "face target missed by one face: {written} faces written for a target of {target} \
             ({:+.0} %); a contraction removes two faces (one where the volume's box cuts the \
             surface), so a closed surface has an even number of them: ask for [output] faces \
             = {written} to meet the target exactly",
            100.0 * off
        ));
    }
    (written as f64 > 1.02 * target as f64).then(|| {
        let hint = match min_faces {
            0 => "; [simplify] min_component_faces drops small components (it changes the \
                  topology)"
                .to_string(),
            n => format!(
                "; [simplify] min_component_faces = {n} dropped the components of fewer faces: \
                 a larger value drops more"
            ),
        };
        let cause = if forced == 0 {
            "the topology and geometry checks allow no fewer here".to_string()
        } else {
            format!(
                "the memory budget retired {forced} vertices before the target was reached, so \
                 part of the surface was written less simplified: a larger [pipeline] \
                 memory_budget_mib may get closer, unless the topology floor is what is left \
                 (every closed component stays at least a tetrahedron); the topology refused \
                 the rest"
            )
        };
        format!(
            "rate target missed: {written} faces written for a target of {target} (+{:.0} %); \
             {cause}: the remaining edges were refused by the link condition ({} times: closed \
             components stay at least tetrahedra, the box's cut stays on its faces), by flips \
             ({}) and by the self-intersection guard ({}, and {} next to written triangles it \
             no longer holds){hint}",
            100.0 * off,
            stats.rejected_link,
            stats.rejected_flip,
            stats.rejected_intersection,
            stats.rejected_unguarded,
        )
    })
}

/// Voxels of the iso volume that were NaN or infinite. They are treated as outside, so a surface
/// is made around them and the run succeeds; but a volume mostly non-finite (masked data, a
/// header scale that overflows) gave a mesh of something else with no word said, which the
/// user must hear about (an all-non-finite volume is refused as empty before this).
fn non_finite_voxels(extract: &ExtractStats, voxels: u64) -> Option<String> {
    let n = extract.non_finite_voxels;
    (n > 0).then(|| {
        format!(
            "{n} of the {voxels} voxels ({:.1} %) of the volume were NaN or infinite and were treated as outside, the surface going around them (extract.non_finite_voxels); fill those voxels in the input, or fix its header's scaling, if they belong inside",
            100.0 * n as f64 / voxels.max(1) as f64
        )
    })
}

/// Attribute values that were NaN or infinite at surface vertices, and were replaced.
fn non_finite_attributes(extract: &ExtractStats) -> Option<String> {
    let n = extract.non_finite_attribute_values;
    (n > 0).then(|| {
        format!(
            "{n} attribute values at surface vertices were NaN or infinite (the attribute volumes' own voxels) and were replaced by the edge's finite end, or 0 (extract.non_finite_attribute_values); fill those voxels in the attribute volume for values that mean something"
        )
    })
}

/// Voxels of the iso volume whose finite values were beyond f32's range (an f64 volume's 1e40),
/// read as `±f32::MAX`. `as f32` made them infinite, meshed as outside (holes, and a spurious
/// inner surface around a core of large values) and warned about as "NaN or infinite" though
/// the file held none; saturated, they are inside or outside by their value, but the user
/// must hear that the data went past what isostream computes in.
fn saturated_voxels(extract: &ExtractStats, input: &str) -> Option<String> {
    let n = extract.saturated_voxels;
    (n > 0).then(|| {
        format!(
            "{input}: {n} voxels hold finite values beyond f32's range (magnitude above {:e}) and were read as ±{:e}, inside or outside by that value (extract.saturated_voxels); isostream computes in f32: scale the data down if the size of those values matters",
            f32::MAX,
            f32::MAX
        )
    })
}

/// The same for the attribute volumes, named (their count is one sum, as for the non-finite
/// attribute values).
fn saturated_attribute_voxels(extract: &ExtractStats, job: &JobConfig) -> Option<String> {
    let n = extract.saturated_attribute_voxels;
    let volumes: Vec<String> = job
        .attributes
        .iter()
        .filter(|a| a.derive.is_none())
        .map(|a| match (&a.path, &a.array, &job.input.path) {
            (Some(p), _, _) => format!("`{}` ({})", a.name, p.display()),
            (None, Some(array), Some(p)) => {
                format!("`{}` ({} array {array})", a.name, p.display())
            }
            _ => format!("`{}`", a.name),
        })
        .collect();
    (n > 0).then(|| {
        format!(
            "{n} voxels of the attribute volumes ({}) hold finite values beyond f32's range (magnitude above {:e}) and were read as ±{:e} (extract.saturated_attribute_voxels); scale those volumes down for values that mean something",
            volumes.join(", "),
            f32::MAX,
            f32::MAX
        )
    })
}

/// `[output] faces` asked for more faces than the surface has: it is written whole, which the
/// user may not expect of a job that names a face count.
fn faces_past_the_surface(job: &JobConfig, faces_kept: u64) -> Option<String> {
    let asked = job.output.faces.filter(|&f| f > faces_kept)?;
    Some(format!(
        "output.faces = {asked} is more than the {faces_kept} faces of the full-resolution \
         surface: it was written whole, unsimplified"
    ))
}

/// The simplifier held more faces than the memory budget's (`isostream_simplify::Simplifier`'s
/// budget): the sweep front's faces (not modifiable yet) and those of the last two slabs behind
/// it, whose contractions wait for the front to pass, are never written out for memory. When the
/// process went over `memory_budget_mib` for it, a warning says so with the budget whose faces
/// (`budget_holding`) hold them, and twice the front; within it (cthead at R = 0.2: 58 of 64 MiB), an info line.
/// What stretches it is mostly a slab crowded with surface behind the front, not the front:
/// engine upsampled to 511 x 511 x 128 puts 138 k faces of its flat top into slab 108, and
/// mode `error` held 153 k faces while the front held 8.3 k (the warning said "the sweep front
/// held up to 8274 faces, more than half of the 78684" and suggested scaling the whole budget,
/// fixed part included, by the faces: 125 MiB).
fn front_stretched(
    job: &JobConfig,
    faces: usize,
    stats: &isostream_simplify::SimplifyStats,
    peak_mib: Option<f64>,
    budget_holding: impl FnOnce(usize) -> u64,
) -> Option<String> {
    let stretch = stats.front_stretch_faces;
    if stretch == 0 {
        return None;
    }
    let mib = job.pipeline.memory_budget_mib;
    if peak_mib.is_some_and(|p| p <= mib as f64) {
        info!(
            front_faces = stats.peak_front_faces,
            stretch_faces = stretch,
            "the simplifier held more faces than the face budget (the sweep front and the two slabs behind it), within memory_budget_mib"
        );
        return None;
    }
    let rss = peak_mib.map_or(String::new(), |p| format!(", peak RSS {p:.1} MiB"));
    let held = faces + stretch;
    // A budget holds them without stretching when its faces hold them all and twice the front
    // (`Stage::budget` stretches past half of it): bonsai with four attributes at the attribute
    // quadric held 7.6 k faces at 32 MiB, and at the 35 MiB whose faces hold those, 9.1 k.
    let holds = held.max(2 * stats.peak_front_faces);
    Some(format!(
        "the simplifier held up to {held} faces, {stretch} more than the {faces} that \
         [pipeline] memory_budget_mib = {mib} holds for this volume{rss}: the faces of the sweep \
         front (up to {} not modifiable yet) and of the last two slabs behind it are never \
         written out for memory, since their contractions wait for the front to pass, and these \
         slabs hold much surface (a slab crowded with surface, such as a flat face across the \
         sweep, or large slices); memory_budget_mib = {} or more holds them",
        stats.peak_front_faces,
        budget_holding(holds),
    ))
}

/// Peak RSS may pass `memory_budget_mib` by this share before [`over_budget`] warns (the
/// allocator's and the kernel's rounding: engine, bonsai and cthead at 24 to 64 MiB peaked
/// within 2.5 % of the budget or well under it, except cthead at 28: 31.2 MiB).
const OVER_BUDGET_TOLERANCE: f64 = 0.02;

/// Peak RSS went over `memory_budget_mib` while the simplifier kept within its faces (a
/// stretched budget has its own warning, [`front_stretched`]): the rest of the process took
/// more than the budget sets aside for it. Small budgets did so silently: every run at 16 MiB
/// peaked at 20-23.6 MiB, engine at 20 MiB at 20.9 (engine, bonsai and cthead, whatever they
/// held: the code, the slices and slabs in flight, the channels, a cascade's first stage's band
/// come to about 20 MiB on 256^2 slices). Every extraction thread holds a slab in flight:
/// `[pipeline] threads = 64` took bonsai from 51 to 86 MiB. The warning names only what the run
/// had (its stage count, or no simplifier at all with mode `none`, its slices, its threads): it
/// spoke of a cascade and 256^2 slices to every run. No budget is suggested: the faces the run
/// held did not take it over, so a larger budget would give it more faces as well as more room.
fn over_budget(
    job: &JobConfig,
    dims: [u64; 3],
    two_stages: bool,
    faces: usize,
    stats: &isostream_simplify::SimplifyStats,
    peak_mib: Option<f64>,
) -> Option<String> {
    let mib = job.pipeline.memory_budget_mib;
    let peak = peak_mib.filter(|&p| {
        stats.front_stretch_faces == 0 && p > mib as f64 * (1.0 + OVER_BUDGET_TOLERANCE)
    })?;
    let head = format!("peak RSS {peak:.1} MiB went over [pipeline] memory_budget_mib = {mib}");
    let slabs = match job.pipeline.threads() {
        1 => "the slab in flight".to_string(),
        n => format!(
            "a slab in flight on each of the {n} extraction threads: a lower [pipeline] threads \
             holds fewer"
        ),
    };
    let process = format!(
        "code, channels, slices of {} x {} voxels, {slabs}",
        dims[0], dims[1]
    );
    if job.simplify.mode == Mode::None {
        return Some(format!(
            "{head}: the budget bounds a simplifier's faces, and [simplify] mode = \"none\" \
             simplifies nothing: the process ({process}) is what took it, which no budget bounds"
        ));
    }
    let (simplifiers, stages) = match two_stages {
        true => (
            "the cascade's two simplifiers",
            " (its first stage keeps its band of unfinished slabs beyond its share, and the \
             second at least a third of the budget)",
        ),
        false => ("the simplifier", ""),
    };
    Some(format!(
        "{head}: {simplifiers} held up to {} faces against the {faces} of the budget{stages}, \
         and the rest of the process ({process}) took the rest; a budget this small does not \
         bound this job",
        stats.peak_resident_faces,
    ))
}

/// Share of the written vertices past which a mode `error` run's early retirements are warned
/// about: a few are the budget doing its work at the odd crowded slab.
const RETIRED_EARLY_SHARE: f64 = 0.01;

/// Mode `error` has no face target, so the rate warning never says when the budget, not the
/// shape measure, decided what was written: a trial's tilted sheets at 128^3 wrote 519,785
/// faces with `error = 2.0`, 262,224 vertices retired early for the memory budget and no
/// word, where `error = 0.5` without time lag wrote 27,782. Those parts are written less
/// simplified than `error` allows.
fn retired_early(
    job: &JobConfig,
    stats: &isostream_simplify::SimplifyStats,
    vertices_written: u64,
) -> Option<String> {
    let forced = stats.forced_retirements;
    (job.simplify.mode == Mode::Error
        && forced as f64 > RETIRED_EARLY_SHARE * vertices_written as f64)
        .then(|| {
            format!(
                "{forced} of the {vertices_written} vertices written were retired early for \
                 [pipeline] memory_budget_mib = {}, before the shape measure allowed (the band \
                 held up to {} faces): those parts are less simplified than error = {} asks; a \
                 larger budget keeps them longer",
                job.pipeline.memory_budget_mib,
                stats.peak_resident_faces,
                job.simplify.error.unwrap_or_default(),
            )
        })
}

/// `out/x.smb` -> `out/x.smb.run.json`.
pub fn summary_path(output: &Path) -> PathBuf {
    let mut name = output.file_name().unwrap_or_default().to_os_string();
    name.push(".run.json");
    output.with_file_name(name)
}

fn write_summary(summary: &RunSummary, path: &Path) -> Result<(), RunError> {
    let fail = |reason: String| RunError::Summary {
        path: path.to_path_buf(),
        reason,
    };
    let bytes = serde_json::to_vec_pretty(summary).map_err(|e| fail(e.to_string()))?;
    write_atomically(path, &bytes).map_err(|e| fail(e.to_string()))
}

/// Writes a small file (a summary, a report) under a temporary name next to it, then renames
/// it: a failure leaves nothing under the final name. The temporary name is
/// `.NAME.XXXXXX.tmp`, named after the file, so a stale one is recognised. A link, device, FIFO
/// or socket at `path` is refused, as for a mesh (`smesh::check_replaceable`).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write as _;
    isostream_smesh::check_replaceable(path)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()))?;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let prefix = format!(
        ".{}.",
        path.file_name().unwrap_or_default().to_string_lossy()
    );
    let mut tmp = isostream_smesh::output_builder(&prefix).tempfile_in(dir)?;
    tmp.write_all(bytes)?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A resumed run reads the slices from its checkpoint's slab on, not the whole volume
    /// (the service's voxel metric and the report's rate counted all of them).
    #[test]
    fn a_resumed_run_reads_the_voxels_from_its_slab_on() {
        assert_eq!(voxels_from_slab([4, 5, 10], None), 200);
        assert_eq!(voxels_from_slab([4, 5, 10], Some(0)), 200);
        assert_eq!(voxels_from_slab([4, 5, 10], Some(6)), 80);
        assert_eq!(voxels_from_slab([4, 5, 10], Some(11)), 0);
    }

    #[test]
    fn a_rate_aims_at_one_face_at_least() {
        assert_eq!(rate_target(1e-300, 115_809), 1);
        assert_eq!(rate_target(0.2, 115_809), 23_162);
        assert_eq!(
            rate_target(1e-300, 0),
            0,
            "an empty surface aims at nothing"
        );
        assert_eq!(
            rate_missed(rate_target(1e-300, 115_809), 1, &Default::default(), 0, 0),
            None
        );
    }

    #[test]
    fn a_missed_rate_names_the_budget_when_it_retired_vertices_early() {
        let stats = isostream_simplify::SimplifyStats::default();
        assert_eq!(rate_missed(1000, 1020, &stats, 0, 0), None, "within 2 %");
        let floor = rate_missed(1000, 1500, &stats, 0, 0).unwrap();
        assert!(
            floor.contains("+50 %")
                && floor.contains("the topology and geometry checks allow no fewer")
        );
        assert!(!floor.contains("memory_budget_mib"), "{floor}");
        assert!(
            floor.contains("min_component_faces drops small components"),
            "{floor}"
        );
        let budget = rate_missed(1000, 1500, &stats, 37, 50).unwrap();
        assert!(
            budget.contains("retired 37 vertices")
                && budget.contains("a larger [pipeline] memory_budget_mib")
                && budget.contains("min_component_faces = 50 dropped")
                && !budget.contains("drops small components"),
            "{budget}"
        );
        assert!(!budget.contains("allows no fewer"), "{budget}");
    }

    #[test]
    fn one_face_off_a_small_target_is_put_down_to_the_step_of_a_contraction() {
        let stats = isostream_simplify::SimplifyStats::default();
        for (target, written) in [(11, 10), (13, 14), (20, 19)] {
            let said = rate_missed(target, written, &stats, 0, 0).unwrap();
            assert!(
                said.contains("missed by one face")
                    && said.contains("an even number")
                    && said.contains(&format!("faces = {written}"))
                    && !said.contains("topology"),
                "{said}"
            );
        }
        assert_eq!(rate_missed(51, 50, &stats, 0, 0), None, "within 2 %");
        assert!(
            rate_missed(12, 14, &stats, 0, 0)
                .unwrap()
                .contains("the topology and geometry checks"),
            "two faces off is not one step"
        );
    }

    /// An 8^3 sphere job with `extra` appended (the budget warnings read only its config).
    fn small_sphere(extra: &str) -> JobConfig {
        let text = format!(
            "[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\n[extract]\niso = 0\n\
             [output]\npath = \"o.smb\"\n{extra}"
        );
        JobConfig::parse(&text, Path::new("job.toml")).unwrap()
    }

    /// What stretched the budget is told as it was: the faces held past it (the front and the
    /// two slabs behind it), the front's own count, and the budget that holds them all.
    #[test]
    fn a_stretched_budget_names_the_faces_held_and_a_budget_that_holds_them() {
        let job = small_sphere("");
        let stats = isostream_simplify::SimplifyStats {
            front_stretch_faces: 74_081,
            peak_front_faces: 8_274,
            ..Default::default()
        };
        let within = front_stretched(&job, 78_684, &stats, Some(60.0), |_| unreachable!());
        assert_eq!(within, None, "within the budget: an info line");
        let mut asked = None;
        let w = front_stretched(&job, 78_684, &stats, Some(74.5), |f| {
            asked = Some(f);
            111
        })
        .unwrap();
        assert_eq!(asked, Some(78_684 + 74_081));
        assert!(
            w.contains("held up to 152765 faces, 74081 more than the 78684")
                && w.contains("up to 8274 not modifiable yet")
                && w.contains("the last two slabs behind it")
                && w.contains("memory_budget_mib = 111 or more holds them")
                && !w.contains("more than half"),
            "{w}"
        );
        let front = isostream_simplify::SimplifyStats {
            front_stretch_faces: 1_000,
            peak_front_faces: 5_000,
            ..Default::default()
        };
        front_stretched(&job, 4_665, &front, Some(70.0), |f| {
            assert_eq!(f, 10_000, "twice the front, or the budget stretches again");
            40
        })
        .unwrap();
    }

    /// A run over its budget without a stretch says so; within the tolerance, or stretched (its
    /// own warning), it does not.
    #[test]
    fn a_run_over_its_budget_warns_without_a_stretch() {
        let job = small_sphere("[pipeline]\nmemory_budget_mib = 20\n");
        let dims = [8, 8, 8];
        let mut stats = isostream_simplify::SimplifyStats {
            peak_resident_faces: 7_000,
            ..Default::default()
        };
        assert_eq!(
            over_budget(&job, dims, false, 7_490, &stats, Some(20.3)),
            None
        );
        let w = over_budget(&job, dims, false, 7_490, &stats, Some(20.9)).unwrap();
        assert!(
            w.contains("peak RSS 20.9 MiB went over [pipeline] memory_budget_mib = 20")
                && w.contains("held up to 7000 faces against the 7490"),
            "{w}"
        );
        stats.front_stretch_faces = 1;
        assert_eq!(
            over_budget(&job, dims, false, 7_490, &stats, Some(22.0)),
            None
        );
    }

    /// The over-budget warning names what the run had: its stage count (or no simplifier with
    /// mode `none`), its slices and its extraction threads; it spoke of a cascade's stages and
    /// 256^2 slices to every run.
    #[test]
    fn the_over_budget_warning_says_what_the_run_had() {
        let stats = isostream_simplify::SimplifyStats {
            peak_resident_faces: 7_000,
            ..Default::default()
        };
        let dims = [511, 300, 256];
        let threaded = small_sphere("[pipeline]\nmemory_budget_mib = 20\nthreads = 64\n");
        let one = over_budget(&threaded, dims, false, 7_490, &stats, Some(86.0)).unwrap();
        assert!(
            one.contains("the simplifier held up to 7000 faces")
                && one.contains("slices of 511 x 300 voxels")
                && one.contains("each of the 64 extraction threads")
                && one.contains("[pipeline] threads")
                && !one.contains("cascade")
                && !one.contains("256^2"),
            "{one}"
        );
        let two = over_budget(&threaded, dims, true, 7_490, &stats, Some(86.0)).unwrap();
        assert!(
            two.contains("two simplifiers") && two.contains("band of unfinished slabs"),
            "{two}"
        );
        let single = small_sphere("[pipeline]\nmemory_budget_mib = 20\nthreads = 1\n");
        let one = over_budget(&single, dims, false, 7_490, &stats, Some(30.0)).unwrap();
        assert!(
            one.contains("the slab in flight") && !one.contains("[pipeline] threads"),
            "{one}"
        );
        let none = small_sphere(
            "[simplify]\nmode = \"none\"\n[pipeline]\nmemory_budget_mib = 20\nthreads = 1\n",
        );
        let w = over_budget(&none, dims, false, 7_490, &stats, Some(30.0)).unwrap();
        assert!(
            w.contains("mode = \"none\"") && !w.contains("held up to") && !w.contains("cascade"),
            "{w}"
        );
    }

    /// A mode `error` run whose budget retired more than a hundredth of its vertices early
    /// says so; fewer, or another mode, do not.
    #[test]
    fn early_retirements_in_mode_error_are_warned() {
        let job = small_sphere("[simplify]\nmode = \"error\"\nerror = 2.0\n");
        let stats = isostream_simplify::SimplifyStats {
            forced_retirements: 262_224,
            peak_resident_faces: 80_000,
            ..Default::default()
        };
        let w = retired_early(&job, &stats, 260_000).unwrap();
        assert!(
            w.starts_with("262224 of the 260000 vertices written were retired early")
                && w.contains("error = 2"),
            "{w}"
        );
        assert_eq!(retired_early(&job, &stats, 30_000_000), None);
        assert_eq!(retired_early(&small_sphere(""), &stats, 260_000), None);
    }

    /// A run killed once its output was complete (its `checkpoint::Finished` record written) is
    /// finished by a resume from the record alone, computing nothing (the cancel flag is up, and
    /// no slab may be seen), whether the kill came before the output's rename or after it; a
    /// record whose output is gone as well, or damaged, is refused with `--restart` as the fix.
    #[test]
    fn a_finished_record_is_finished_by_resume_without_computing() {
        let dir = tempfile::tempdir().unwrap();
        let job_path = dir.path().join("job.toml");
        let output = dir.path().join("o.ply");
        let text = format!(
            "[input]\nshape = \"sphere\"\nsize = [16, 16, 16]\n[extract]\niso = 0\n\
             [output]\npath = \"{}\"\n",
            output.display()
        );
        std::fs::write(&job_path, text).unwrap();
        let job = JobConfig::load(&job_path).unwrap();
        let summary = run(&job, &job_path, &AtomicBool::new(false), &|_| {}).unwrap();
        let bytes = std::fs::read(&output).unwrap();
        let ckpt = checkpoint_path(&output);
        let temp = dir.path().join(".o.ply.abc123.tmp");
        let scratch = dir.path().join(".o.ply.def456.tmp");
        let mut source = open_source(&job.input).unwrap();
        let record = checkpoint::Finished {
            job: checkpoint::job_hash(&job),
            input: checkpoint::InputIdentity::read(&job, source.as_mut()).unwrap(),
            temp: temp.clone(),
            scratch: vec![scratch.clone()],
            bytes: bytes.len() as u64,
            summary: summary.clone(),
        };
        let resume = |start| {
            run_from(&job, &job_path, start, &AtomicBool::new(true), &|_| {
                panic!("a slab was computed")
            })
        };
        for renamed in [false, true] {
            std::fs::remove_file(summary_path(&output)).unwrap();
            if !renamed {
                std::fs::rename(&output, &temp).unwrap();
            }
            std::fs::write(&scratch, b"scratch").unwrap();
            checkpoint::write_finished(&ckpt, &record).unwrap();
            let found = resume(Start::Fresh).unwrap_err();
            assert!(matches!(found, RunError::FinishedFound { .. }), "{found:?}");
            let done = resume(Start::Resume).unwrap();
            assert_eq!(done.faces_written, summary.faces_written);
            assert_eq!(std::fs::read(&output).unwrap(), bytes);
            assert!(summary_path(&output).exists());
            assert!(!ckpt.exists() && !temp.exists() && !scratch.exists());
        }
        std::fs::remove_file(&output).unwrap();
        checkpoint::write_finished(&ckpt, &record).unwrap();
        let gone = resume(Start::Resume).unwrap_err();
        assert!(matches!(gone, RunError::Checkpoint { .. }), "{gone:?}");
        let msg = gone.to_string();
        assert!(
            msg.contains("neither its temporary file")
                && msg.ends_with("run with --restart to start over"),
            "{msg}"
        );
        let mut damaged = std::fs::read(&ckpt).unwrap();
        let mid = damaged.len() / 2;
        damaged[mid] ^= 1;
        std::fs::write(&ckpt, damaged).unwrap();
        let e = resume(Start::Resume).unwrap_err().to_string();
        assert!(e.contains("corrupt checkpoint (checksum mismatch)"), "{e}");
    }

    /// A TIFF stack with ImageJ metadata (0.5 x 0.5 x 2.5 micron voxels) is meshed in microns,
    /// told in the job's input; `[input] spacing` overrides the file's as any header's.
    #[test]
    fn a_tiff_stack_is_meshed_in_its_metadata_units_unless_overridden() {
        use tiff::encoder::{Rational, TiffEncoder, colortype};
        use tiff::tags::{ResolutionUnit, Tag};
        let dir = tempfile::tempdir().unwrap();
        let stack = dir.path().join("ball.tif");
        let mut e = TiffEncoder::new(std::fs::File::create(&stack).unwrap()).unwrap();
        let n = [12u32, 12, 10];
        for z in 0..n[2] {
            // A ball of radius 3.5 voxels: > 0 inside.
            let page: Vec<f32> = (0..n[0] * n[1])
                .map(|i| {
                    let p = [i % n[0], i / n[0], z].map(|c| c as f32 - 5.5);
                    3.5 - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
                })
                .collect();
            let mut image = e.new_image::<colortype::Gray32Float>(n[0], n[1]).unwrap();
            if z == 0 {
                let desc = "ImageJ=1.54f\nimages=10\nslices=10\nunit=micron\nspacing=2.5\n";
                image
                    .encoder()
                    .write_tag(Tag::ImageDescription, desc)
                    .unwrap();
            }
            image.resolution(ResolutionUnit::None, Rational { n: 2, d: 1 });
            image.write_data(&page).unwrap();
        }
        drop(e);
        let mesh = |name: &str, spacing: &str| {
            let job_path = dir.path().join(format!("{name}.toml"));
            let output = dir.path().join(format!("{name}.ply"));
            let text = format!(
                "[input]\npath = \"{}\"\n{spacing}[extract]\niso = 0\n[simplify]\nmode = \"none\"\n\
                 [output]\npath = \"{}\"\n",
                stack.display(),
                output.display()
            );
            std::fs::write(&job_path, text).unwrap();
            let job = JobConfig::load(&job_path).unwrap();
            let summary = run(&job, &job_path, &AtomicBool::new(false), &|_| {}).unwrap();
            let m = isostream_smesh::read_indexed(&output).unwrap();
            let mut bounds = [[f64::INFINITY; 3], [f64::NEG_INFINITY; 3]];
            for p in &m.positions {
                for k in 0..3 {
                    bounds[0][k] = bounds[0][k].min(p[k]);
                    bounds[1][k] = bounds[1][k].max(p[k]);
                }
            }
            (summary.input, bounds)
        };
        let (input, physical) = mesh("file", "");
        assert!(
            input.ends_with(
                "(12x12x10 TIFF stack, voxel 0.5 x 0.5 x 2.5 um from its ImageJ metadata)"
            ),
            "{input}"
        );
        let (input, voxels) = mesh("given", "spacing = [1.0, 1.0, 1.0]\n");
        assert!(input.ends_with("(12x12x10 TIFF stack)"), "{input}");
        // The same surface, scaled by the file's voxel size (about 2 to 9 in voxels).
        for (side, (p, v)) in physical.iter().zip(&voxels).enumerate() {
            for (k, s) in [0.5, 0.5, 2.5].into_iter().enumerate() {
                assert!((p[k] - s * v[k]).abs() < 1e-4, "{side} {k}: {p:?} {v:?}");
            }
        }
        assert!(voxels[1][2] - voxels[0][2] > 6.0, "{voxels:?}");
    }

    /// With threads the halves run on two (one of them this one), without them both on this
    /// one; either way both run once.
    #[test]
    fn measure_halves_run_both_on_two_threads_or_one() {
        use isostream_measure::Halves;
        for threads in [true, false] {
            let here = std::thread::current().id();
            let (mut ta, mut tb) = (None, None);
            MeasureHalves { threads }
                .both(&mut || ta = Some(std::thread::current().id()), &mut || {
                    tb = Some(std::thread::current().id())
                });
            let (ta, tb) = (ta.unwrap(), tb.unwrap());
            assert_eq!(tb, here);
            assert_eq!(ta != here, threads, "threads = {threads}");
        }
    }
}
