//! The job file: what to read, where the surface is, how to simplify, where to write.
//!
//! Parsed with serde (`deny_unknown_fields` everywhere, so a misspelt key is an error naming it)
//! and validated once, before any work starts: every error names the key or the file and says
//! what was expected. Every key is documented in `config/README.md`.

use std::path::{Path, PathBuf};

use isostream_volume::{Dtype, Endian, Shape};
use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// One job, as written in a TOML file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobConfig {
    pub input: InputConfig,
    pub extract: ExtractConfig,
    #[serde(default)]
    pub simplify: SimplifyConfig,
    pub output: OutputConfig,
    #[serde(default)]
    pub pipeline: PipelineConfig,
    #[serde(default)]
    pub log: LogConfig,
    /// Extra scalar fields sampled at the vertices (`[[attributes]]`, see `attributes.rs`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub attributes: Vec<crate::attributes::AttributeConfig>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputConfig {
    /// A volume file (relative paths are relative to the job file): raw, NRRD (.nrrd/.nhdr),
    /// NIfTI (.nii/.nii.gz), VTK (.vti/.vtk) or TIFF (a file or a folder of slices), chosen by
    /// extension or magic bytes. Exclusive with `shape`.
    pub path: Option<PathBuf>,
    /// A procedural volume instead of a file.
    pub shape: Option<Shape>,
    /// Grid size of a procedural volume.
    pub size: Option<[u64; 3]>,
    /// Voxel dimensions of a raw file (x y z); formats with a header define their own.
    pub dims: Option<[u64; 3]>,
    /// Voxel type of a raw file.
    pub dtype: Option<Dtype>,
    /// Byte order of a raw file (default little).
    pub endian: Option<Endian>,
    /// Bytes to skip at the start of a raw file (default 0).
    pub header_bytes: Option<u64>,
    /// Voxel size; overrides the file header (default: the header's, else 1 1 1).
    pub spacing: Option<[f64; 3]>,
    /// Position of voxel (0,0,0); overrides the file header (default: the header's, else 0).
    pub origin: Option<[f64; 3]>,
    /// The array to read from a multi-array file (VTK), or the child array / OME-Zarr level
    /// (its `path`) of a Zarr group, by name.
    pub array: Option<String>,
    /// See the volume at `k` times its resolution along each axis by trilinear interpolation
    /// (dims `(n - 1) k + 1`, spacing / k), never materialised: `[kx, ky, kz]`, each >= 1.
    pub upsample: Option<[u64; 3]>,
}

impl InputConfig {
    /// What a file reader needs besides the path.
    pub fn open_options(&self) -> isostream_volume::OpenOptions {
        isostream_volume::OpenOptions {
            dims: self.dims,
            dtype: self.dtype,
            endian: self.endian,
            header_bytes: self.header_bytes,
            spacing: self.spacing,
            origin: self.origin,
            array: self.array.clone(),
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExtractConfig {
    /// The iso value. Voxels strictly above it are inside.
    pub iso: f64,
    /// Empty-space skipping: blocks of cubes whose value bounds cannot cross `iso` are not
    /// looked at (an upsampled input does not even compute their voxels). The output is the
    /// same bytes either way; `false` is for comparisons.
    #[serde(default = "yes")]
    pub skip_empty: bool,
}

/// How the surface is simplified.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Hou and Chen's decimation rate.
    #[default]
    Rate,
    /// No simplification: the full-resolution surface, streamed.
    None,
    /// Attali, Cohen-Steiner and Edelsbrunner's Tandem algorithm: contract while the shape
    /// measure eps0 stays at most `error` (E0), with optional time-lag and isotropy.
    Error,
    /// The Tandem paper's baseline: extract the whole surface, keep it in memory, then simplify
    /// it with the same cost and rules as `error` (E0, isotropy; no time-lag). Stops with an
    /// error when the surface outgrows `pipeline.memory_budget_mib`.
    Classical,
}

/// The keys a mode or priority reads only where it applies are `Option`s, `None` when the job
/// leaves them out, so that a key given where it would be ignored can be refused
/// ([`SimplifyConfig::scoped_keys`]); their defaults are in the accessors.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimplifyConfig {
    #[serde(default)]
    pub mode: Mode,
    /// R: output faces / input faces, in (0, 1] (default 0.2; exclusive with `[output] faces`).
    pub rate: Option<f64>,
    /// B: faces extracted between two decimations (Hou and Chen's schedule). Unset (the
    /// default): the last simplifier decimates only when the memory budget is full, and at the
    /// end, so that every contraction is chosen among as much of the surface as memory holds
    /// (a cascade's first stage decimates every [`FIRST_STAGE_BATCH`] faces).
    pub batch: Option<u64>,
    /// R_i: decimation rate of the initial phase, used while R < R_i
    /// ([`DEFAULT_INITIAL_RATE`] when not given).
    pub initial_rate: Option<f64>,
    /// Modes "error" and "classical": slabs a vertex stays editable behind the front before it
    /// is retired and written, and the bound on a preimage's span, `2 retire_lag + 2` slabs
    /// ([`DEFAULT_RETIRE_LAG`] when not given).
    pub retire_lag: Option<u32>,
    /// E0 for mode = "error": the bound on the shape measure eps0, a length in the volume's
    /// physical units.
    pub error: Option<f64>,
    /// Mode "error": delay contractions whose patch reaches beyond the front (Tandem time-lag;
    /// on when not given).
    pub time_lag: Option<bool>,
    /// Modes "error" and "classical": isotropy parameter alpha in [0, 1]; 0 (when not given) is
    /// pure shape measure.
    pub isotropy: Option<f64>,
    /// Order of contractions: the mode's geometric cost (when not given), seed 001's
    /// data-dependent weight, or quadrics over position and attributes.
    pub priority: Option<PriorityKind>,
    /// `priority = "data-dependent"`: weight of curvature against the attribute gradient
    /// ([`DEFAULT_LAMBDA`] when not given).
    pub lambda: Option<f64>,
    /// `priority = "attribute-quadric"`: one weight per `[[attributes]]` entry (default 1 each).
    pub attribute_weights: Option<Vec<f64>>,
    /// Drop every connected component of fewer full-resolution faces than this, before
    /// simplifying (`isostream_prune`); 0 (the default) keeps every component. The one option
    /// that changes the topology.
    #[serde(default)]
    pub min_component_faces: u64,
    /// What may happen to the cut where the volume's box meets the surface: simplified within
    /// the box face (`planar`, the default except with the attribute quadric, which has no
    /// boundary cost) or kept exactly (`exact`: pieces simplified apart still meet).
    pub boundary: Option<BoundaryKind>,
}

/// `[simplify] boundary`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BoundaryKind {
    Planar,
    Exact,
}

/// `[simplify] priority`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum PriorityKind {
    #[default]
    Geometric,
    DataDependent,
    AttributeQuadric,
}

/// `simplify.lambda` when a data-dependent job does not give it.
pub(crate) const DEFAULT_LAMBDA: f64 = 0.5;

/// R when neither `rate` nor `[output] faces` is given.
const DEFAULT_RATE: f64 = 0.2;
/// B of a cascade's first stage when `batch` is unset: its output is intermediate, and it
/// must pass its faces on steadily for the second stage to work alongside.
pub(crate) const FIRST_STAGE_BATCH: u64 = 10_000;
/// R_i when `initial_rate` is not given.
const DEFAULT_INITIAL_RATE: f64 = 0.5;
/// `retire_lag` when not given: the time-lag's patches reach about 8 slabs at moderate E0.
const DEFAULT_RETIRE_LAG: u32 = 8;

/// How many slabs of a grid of `spacing` make one as thick as its voxels are wide: the smaller
/// in-plane spacing over the slabs', rounded (so 1 for slabs more than two thirds as thick),
/// from 1 to [`MAX_THIN_SLABS`]. The unit of the band depths given in slabs, which were chosen
/// on near-isotropic volumes.
pub(crate) fn thin_slabs(spacing: [f64; 3]) -> u32 {
    let ratio = (spacing[0].min(spacing[1]) / spacing[2]).round();
    if ratio.is_nan() {
        1
    } else {
        ratio.clamp(1.0, MAX_THIN_SLABS) as u32
    }
}

/// The most [`thin_slabs`] deepens a band: spacings 10^8 apart (the torture trials') must not
/// keep the whole volume resident.
const MAX_THIN_SLABS: f64 = 32.0;

impl SimplifyConfig {
    /// `rate`, or its default.
    pub fn rate(&self) -> f64 {
        self.rate.unwrap_or(DEFAULT_RATE)
    }

    /// `initial_rate`, or its default.
    pub fn initial_rate(&self) -> f64 {
        self.initial_rate.unwrap_or(DEFAULT_INITIAL_RATE)
    }

    /// `retire_lag`, or its default.
    pub fn retire_lag(&self) -> u32 {
        self.retire_lag.unwrap_or(DEFAULT_RETIRE_LAG)
    }

    /// `retire_lag` on a grid of `spacing`: as given, or its default in slabs as thick as the
    /// voxels are wide ([`thin_slabs`]). The time-lag's patches reach a distance, not a slab
    /// count: hydrogen upsampled [2, 2, 40] in mode error (E0 0.05) wrote 41,970 faces with 8
    /// slabs and 1,702 with 160.
    pub fn retire_lag_on(&self, spacing: [f64; 3]) -> u32 {
        self.retire_lag
            .unwrap_or(DEFAULT_RETIRE_LAG * thin_slabs(spacing))
    }

    /// `time_lag`, or its default (on).
    pub fn time_lag(&self) -> bool {
        self.time_lag.unwrap_or(true)
    }

    /// `isotropy`, or its default (0: the pure shape measure).
    pub fn isotropy(&self) -> f64 {
        self.isotropy.unwrap_or(0.0)
    }

    /// `priority`, or its default (geometric).
    pub fn priority(&self) -> PriorityKind {
        self.priority.unwrap_or_default()
    }

    /// These settings with the keys an earlier version always wrote out (before a key could be
    /// left out) filled with their values: what a checkpoint's job hash is taken of, so that a
    /// checkpoint of an earlier build resumes the same job (with `null` for them, it was
    /// refused as a changed job file).
    pub(crate) fn as_written_before(&self) -> Self {
        Self {
            initial_rate: Some(self.initial_rate()),
            retire_lag: Some(self.retire_lag()),
            time_lag: Some(self.time_lag()),
            isotropy: Some(self.isotropy()),
            priority: Some(self.priority()),
            ..self.clone()
        }
    }

    /// Leaves out every key the mode or priority ignores. A job stored by a service before such
    /// keys were refused has each of them written out (`retire_lag = 8` in mode rate), and its
    /// reload must not fail it for what did nothing.
    pub fn drop_ignored_keys(&mut self) {
        while let Some((key, ..)) = self.ignored_key() {
            match key {
                "rate" => self.rate = None,
                "batch" => self.batch = None,
                "initial_rate" => self.initial_rate = None,
                "error" => self.error = None,
                "retire_lag" => self.retire_lag = None,
                "time_lag" => self.time_lag = None,
                "isotropy" => self.isotropy = None,
                "priority" => self.priority = None,
                "boundary" => self.boundary = None,
                "lambda" => self.lambda = None,
                "attribute_weights" => self.attribute_weights = None,
                _ => return,
            }
        }
    }

    /// `boundary`, or its default: planar unless the priority has no boundary cost.
    pub fn boundary(&self) -> BoundaryKind {
        self.boundary.unwrap_or(match self.priority() {
            PriorityKind::AttributeQuadric => BoundaryKind::Exact,
            _ => BoundaryKind::Planar,
        })
    }

    /// Every key that only some modes or priorities read, with its value when the job gives it
    /// and where it is read (by `simplifier_config` in `lib.rs`: the policy of mode `rate`
    /// takes `rate`, `batch` and `initial_rate`; that of `error` takes `error`, `time_lag` and
    /// `isotropy`, and `classical` the same without the time-lag; both bound preimages by
    /// `retire_lag`, which mode `rate` replaces by its face budget; mode `none` contracts
    /// nothing, so no priority or boundary rule applies). The one list
    /// [`JobConfig::validate`] refuses keys from: a key given where it is not read would be
    /// silently ignored (`time_lag = false` in mode `rate` wrote the same bytes as without it).
    fn scoped_keys(&self) -> [(&'static str, Option<String>, Reads); 11] {
        use Mode::{Classical, Error, Rate};
        const CONTRACTING: Reads = Reads::Modes(&[Rate, Error, Classical]);
        const SHAPE: Reads = Reads::Modes(&[Error, Classical]);
        let shown = |v: Option<f64>| v.map(|v| v.to_string());
        [
            ("rate", shown(self.rate), Reads::Modes(&[Rate])),
            (
                "batch",
                self.batch.map(|b| b.to_string()),
                Reads::Modes(&[Rate]),
            ),
            (
                "initial_rate",
                shown(self.initial_rate),
                Reads::Modes(&[Rate]),
            ),
            ("error", shown(self.error), SHAPE),
            ("retire_lag", self.retire_lag.map(|l| l.to_string()), SHAPE),
            (
                "time_lag",
                self.time_lag.map(|t| t.to_string()),
                Reads::Modes(&[Error]),
            ),
            ("isotropy", shown(self.isotropy), SHAPE),
            (
                "priority",
                self.priority.map(|p| format!("{:?}", p.name())),
                CONTRACTING,
            ),
            (
                "boundary",
                self.boundary.map(|b| format!("{:?}", b.name())),
                CONTRACTING,
            ),
            (
                "lambda",
                shown(self.lambda),
                Reads::Priority(PriorityKind::DataDependent),
            ),
            (
                "attribute_weights",
                self.attribute_weights.as_ref().map(|w| format!("{w:?}")),
                Reads::Priority(PriorityKind::AttributeQuadric),
            ),
        ]
    }

    /// The first key of [`SimplifyConfig::scoped_keys`] given where it is not read: its name,
    /// its value and the error's "expected" part, which says what ignores it and the fix.
    fn ignored_key(&self) -> Option<(&'static str, String, String)> {
        self.scoped_keys().into_iter().find_map(|(key, value, reads)| {
            let value = value?;
            let (name, setting, here) = match reads {
                Reads::Modes(modes) if !modes.contains(&self.mode) => (
                    "mode",
                    modes.iter().map(|m| m.name()).collect::<Vec<_>>(),
                    self.mode.name(),
                ),
                // Mode none reads no priority: the mode is what to change, not the priority.
                Reads::Priority(_) if self.mode == Mode::None => (
                    "mode",
                    vec![Mode::Rate.name(), Mode::Error.name(), Mode::Classical.name()],
                    self.mode.name(),
                ),
                Reads::Priority(p) if p != self.priority() => {
                    ("priority", vec![p.name()], self.priority().name())
                }
                _ => return None,
            };
            let quoted: Vec<String> = setting.iter().map(|s| format!("{s:?}")).collect();
            let wanted = match quoted.split_last() {
                Some((last, [])) => last.clone(),
                Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
                None => String::new(),
            };
            let expected = format!(
                "absent unless {name} = {wanted} ({name} {here:?} ignores it: remove it, or use \
                 {name} = {wanted} where it applies)"
            );
            Some((key, value, expected))
        })
    }
}

/// Where a key of [`SimplifyConfig::scoped_keys`] is read.
#[derive(Debug, Clone, Copy)]
enum Reads {
    Modes(&'static [Mode]),
    Priority(PriorityKind),
}

impl Mode {
    /// The name a job file gives it.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Mode::Rate => "rate",
            Mode::None => "none",
            Mode::Error => "error",
            Mode::Classical => "classical",
        }
    }
}

/// The job file's spelling (`rate`, not the `Rate` of `Debug`), for what a user reads.
impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl PriorityKind {
    /// The name a job file gives it.
    pub(crate) fn name(self) -> &'static str {
        match self {
            PriorityKind::Geometric => "geometric",
            PriorityKind::DataDependent => "data-dependent",
            PriorityKind::AttributeQuadric => "attribute-quadric",
        }
    }
}

impl BoundaryKind {
    /// The name a job file gives it.
    pub(crate) fn name(self) -> &'static str {
        match self {
            BoundaryKind::Planar => "planar",
            BoundaryKind::Exact => "exact",
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// `.smb` or `.sma` (relative paths are relative to the job file).
    pub path: PathBuf,
    /// Also write a JSON run summary next to the output (`<path>.run.json`).
    #[serde(default = "yes")]
    pub summary: bool,
    /// Accept a surface without any triangle (iso outside the data range, all-NaN volume);
    /// by default that is an error naming the data range, and nothing is written.
    #[serde(default)]
    pub allow_empty: bool,
    /// Mode `rate`: aim at this many output faces instead of `[simplify] rate`; the rate is
    /// then this over the extracted face count, which a first extraction pass counts.
    pub faces: Option<u64>,
}

fn yes() -> bool {
    true
}

/// The most batches a link between two stages may hold: a bounded channel allocates its room
/// when it is made, and `channel_capacity = 1000000000` asked for 128 GB and aborted the process
/// (the service with it). Past a few dozen batches a deeper link only holds more memory.
const MAX_CHANNEL_CAPACITY: usize = 4096;

/// The most extraction threads a job may ask for: each holds a slab's slices and buffers, and
/// `threads = 100000` failed to spawn its threads and aborted the process.
const MAX_THREADS: usize = 256;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PipelineConfig {
    /// Batches a channel between two stages may hold before its producer blocks (the
    /// detector's link at most `stages::DELTA_DEPTH`).
    #[serde(default = "default_capacity")]
    pub channel_capacity: usize,
    /// Budget for the simplifier's resident surface; vertices are retired early to stay inside.
    #[serde(default = "default_budget")]
    pub memory_budget_mib: u64,
    /// Triangles per delta the simplifier takes at once: the detector joins the extraction
    /// workers' batches (whole rows of cubes) into groups of whole rows holding at least this
    /// many (the last of a slab may hold fewer). The simplifier decimates after each delta, so
    /// the output depends on it.
    #[serde(default = "default_batch_triangles")]
    pub batch_triangles: usize,
    /// When to save a resumable state (`isostream run --resume`).
    #[serde(default)]
    pub checkpoint: CheckpointConfig,
    /// Threads extracting slabs in parallel (default: one per core, at most 8), and above 1 the last
    /// simplifier's final decimation on two threads when it is cut in two (`stages.rs`,
    /// `FinalWorkers`). The output does not depend on it: slabs reach the detector in order,
    /// and whether a final decimation is cut depends on its faces only.
    pub threads: Option<usize>,
    /// Simplifiers in series, each on its own thread (a cascade, see
    /// `isostream_simplify::Cascade`): 2 uses two cores for one job (mode `rate` with the
    /// geometric priority only, where it is the default), 1 is a single simplifier (the default
    /// elsewhere). Part of the job: the output depends on it, never on the machine.
    pub simplify_stages: Option<u8>,
}

/// Extraction threads when `threads` is not given: the machine's cores, at most this many.
/// Every extraction thread holds a slab in flight, outside the memory budget's faces (a user
/// trial on this 2-core machine: bonsai at R = 0.2 peaked at 50.9 MiB with 2 threads and 85.8
/// MiB with 64, hydrogen upsampled 16x in mode none at 14.0 / 27.1 / 69.0 MiB with 1 / 16 /
/// 64), while the simplifier's one or two threads set the pace of every simplified job (bonsai:
/// extraction 0.13 s of 3.2 s on two threads). So a many-core node would take a default job
/// over its budget for no gain; a job that wants more asks for them.
const DEFAULT_MAX_THREADS: usize = 8;

impl PipelineConfig {
    /// Extraction threads: `threads`, else the machine's cores up to [`DEFAULT_MAX_THREADS`].
    pub fn threads(&self) -> usize {
        self.threads.unwrap_or_else(|| {
            default_threads(
                std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get),
            )
        })
    }
}

/// Extraction threads by default on a machine of `cores` cores.
fn default_threads(cores: usize) -> usize {
    cores.clamp(1, DEFAULT_MAX_THREADS)
}

/// `[pipeline] checkpoint = { every_seconds = 60 }` (or `every_slabs = N`, or `enabled = false`).
/// Without the key, jobs on volumes of at least [`CheckpointConfig::AUTO_MIN_VOXELS`] voxels
/// checkpoint every [`CheckpointConfig::DEFAULT_SECONDS`] seconds and smaller ones never.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct CheckpointConfig {
    /// `false`: never; `true`: every [`CheckpointConfig::DEFAULT_SECONDS`] unless an interval
    /// is given.
    pub enabled: Option<bool>,
    pub every_seconds: Option<f64>,
    pub every_slabs: Option<u64>,
}

/// How often a run saves a checkpoint, at the first slab boundary after the interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CheckpointEvery {
    Seconds(f64),
    Slabs(u64),
}

impl CheckpointConfig {
    /// Checkpoints are on by default from 512^3 voxels (2^27): such jobs run for minutes (bonsai's
    /// 2^24 voxels take seconds; see docs/performance.md), so losing one costs something, while
    /// a checkpoint every minute costs little (docs/performance.md).
    pub const AUTO_MIN_VOXELS: u64 = 1 << 27;
    pub const DEFAULT_SECONDS: f64 = 60.0;

    /// The interval for a volume of `voxels`, `None` when the run saves no checkpoint.
    pub fn every(&self, voxels: u64) -> Option<CheckpointEvery> {
        if self.enabled == Some(false) {
            return None;
        }
        match (self.every_seconds, self.every_slabs) {
            (_, Some(n)) => Some(CheckpointEvery::Slabs(n)),
            (Some(s), None) => Some(CheckpointEvery::Seconds(s)),
            (None, None) => (self.enabled == Some(true) || voxels >= Self::AUTO_MIN_VOXELS)
                .then_some(CheckpointEvery::Seconds(Self::DEFAULT_SECONDS)),
        }
    }
}

fn default_capacity() -> usize {
    8
}
/// 64 MiB: the whole process of a default job stays near it (see `max_resident_faces`).
fn default_budget() -> u64 {
    64
}
fn default_batch_triangles() -> usize {
    8192
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            channel_capacity: default_capacity(),
            memory_budget_mib: default_budget(),
            batch_triangles: default_batch_triangles(),
            checkpoint: CheckpointConfig::default(),
            threads: None,
            simplify_stages: None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    #[default]
    Text,
    Json,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogConfig {
    #[serde(default)]
    pub format: LogFormat,
    /// A tracing filter such as "info" or "isostream_pipeline=debug"; RUST_LOG wins when set.
    pub level: Option<String>,
    /// Seconds between two `progress` log lines (rate, ETA, faces, RSS); 0 for none.
    #[serde(default = "default_progress_seconds")]
    pub progress_seconds: f64,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            format: LogFormat::default(),
            level: None,
            progress_seconds: default_progress_seconds(),
        }
    }
}

fn default_progress_seconds() -> f64 {
    10.0
}

impl LogConfig {
    /// How often a run logs its progress; `None` when `progress_seconds = 0`.
    pub fn progress_interval(&self) -> Option<std::time::Duration> {
        (self.progress_seconds > 0.0)
            .then(|| std::time::Duration::from_secs_f64(self.progress_seconds))
    }
}

/// A `[log] level` must parse as a tracing filter, and a bare word must be a level: `debugg`
/// would otherwise be taken for a target name and silently log nothing of ours.
fn check_log_filter(level: &str) -> Result<(), String> {
    tracing_subscriber::EnvFilter::try_new(level).map_err(|e| e.to_string())?;
    const LEVELS: [&str; 6] = ["trace", "debug", "info", "warn", "error", "off"];
    for d in level.split(',').map(str::trim).filter(|d| !d.is_empty()) {
        if !d.contains('=')
            && !d.contains('[')
            && !LEVELS.contains(&d.to_ascii_lowercase().as_str())
        {
            return Err(format!(
                "`{d}` is not a level ({}); use target=level for a target",
                LEVELS.join(", ")
            ));
        }
    }
    Ok(())
}

/// serde's "unknown field `faces`, expected one of ..." with, when the key is one of another
/// section, where it goes: "; `faces` belongs in [output]". serde lists only the keys of the
/// section the key was found in, which did not tell a key put under the wrong header from a
/// misspelt one.
fn with_section_hint(message: &str) -> String {
    let key = message
        .strip_prefix("unknown field `")
        .and_then(|rest| rest.split_once('`'))
        .map(|(key, _)| key);
    let homes: Vec<String> = key.map_or_else(Vec::new, |key| {
        sections()
            .into_iter()
            .filter(|(_, keys)| keys.contains(&key))
            .map(|(section, _)| section.to_string())
            .collect()
    });
    match (key, homes.split_last()) {
        (Some(key), Some((last, []))) => format!("{message}; `{key}` belongs in {last}"),
        (Some(key), Some((last, rest))) => {
            format!(
                "{message}; `{key}` belongs in {} or {last}",
                rest.join(", ")
            )
        }
        _ => message.to_string(),
    }
}

/// Each section of a job file with its keys, the keys as the config structs' derived
/// `Deserialize` lists them ([`keys_of`]), so this table cannot drift from what is accepted.
fn sections() -> [(&'static str, &'static [&'static str]); 9] {
    [
        ("the top level", keys_of::<JobConfig>()),
        ("[input]", keys_of::<InputConfig>()),
        ("[extract]", keys_of::<ExtractConfig>()),
        ("[simplify]", keys_of::<SimplifyConfig>()),
        ("[output]", keys_of::<OutputConfig>()),
        ("[pipeline]", keys_of::<PipelineConfig>()),
        ("[pipeline.checkpoint]", keys_of::<CheckpointConfig>()),
        ("[log]", keys_of::<LogConfig>()),
        (
            "[[attributes]]",
            keys_of::<crate::attributes::AttributeConfig>(),
        ),
    ]
}

/// The field names a derived `Deserialize` struct accepts: the list it hands to
/// `deserialize_struct` (the one serde's "expected one of" names), caught by a deserializer
/// that asks for nothing else and stops there.
fn keys_of<'de, T: Deserialize<'de>>() -> &'static [&'static str] {
    use serde::de::{Error, Visitor, value::Error as Stop};

    struct Keys<'a>(&'a mut &'static [&'static str]);

    impl<'de> serde::Deserializer<'de> for Keys<'_> {
        type Error = Stop;

        fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Stop> {
            Err(Stop::custom("not a struct"))
        }

        fn deserialize_struct<V: Visitor<'de>>(
            self,
            _: &'static str,
            fields: &'static [&'static str],
            _: V,
        ) -> Result<V::Value, Stop> {
            *self.0 = fields;
            Err(Stop::custom("keys listed"))
        }

        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map enum
            identifier ignored_any
        }
    }

    let mut keys: &'static [&'static str] = &[];
    // Always an error: the deserializer stops as soon as it has the list.
    let _ = T::deserialize(Keys(&mut keys));
    keys
}

/// The text of a TOML error's span, run on to the end of the token it starts: a number too
/// large for its type is reported with a span of its first digit (`(at `9`)` for
/// 99999999999999999999999).
fn quoted_token(text: &str, span: std::ops::Range<usize>) -> Option<String> {
    let rest = text.get(span.end..)?;
    let more = rest
        .find(|c: char| !(c.is_ascii_alphanumeric() || "_.+-".contains(c)))
        .unwrap_or(rest.len());
    let token = match text.get(span.clone())? {
        s if s.ends_with(|c: char| c.is_ascii_alphanumeric()) => &text[span.start..span.end + more],
        s => s,
    };
    Some(token.trim().to_string())
}

/// Bytes of simplifier state per resident face of a cascade: the face, half a vertex with its
/// quadric, heap entries and the intersection index's record and cells, counted over both stages
/// (which share the budget). Measured after the allocator fix (`src/main.rs`): peak RSS 55-61
/// MiB at the default 64 MiB on engine and bonsai at R = 0.2, 0.05 and 0.01, whose first stages
/// hold up to 35 k faces of unfinished band beyond their share. 1150 (before the fix, when
/// glibc's heap crept by 10 MiB over a run) held 43 k faces: bonsai at R = 0.05 (55 k faces out)
/// then had to write part of its surface before the end, 1.17x the in-core RMS distance; 600
/// held 84 k faces and reached 65 MiB (docs/performance.md, "Sixth session").
const BYTES_PER_FACE_CASCADE: u64 = 700;
/// The same for one simplifier alone, which runs by default on larger slices only, besides
/// [`SLICE_BYTES_PER_CUBE`]. 1150 bytes (before the allocator fix) left a third of the budget
/// unused and cost accuracy: bonsai upsampled to 511 x 511 x 256 at R = 0.01 peaked at 52.1 MiB
/// with 43.7 k faces held and came out with 1.89x the in-core RMS distance (the passes squeezed
/// the surface behind the front, two slabs of 15 k faces, into what the budget left). With 850
/// and the slice's share (55.5 k faces): 57.9 MiB and 1.31x; R = 0.05 and 0.2 peaked at 62.3
/// and 61.1 MiB, bonsai upsampled to 1021 x 1021 x 256 (`[output] faces = 10000`) at 62.0 MiB
/// (docs/performance.md, "Twenty-first session"). The memory work since then left 850 using
/// 40-52 MiB of the 64, and on large slices that shallow band was slow: the coarse fans just
/// behind the front lie next to its full-resolution triangles, and the guard's queries met
/// 192 records each at 1021^3 (`faces = 10000`, 350 s, 48.8 MiB). With 600: 79 records,
/// 247 s, 56.6 MiB, 21,786 faces written instead of 22,909; bonsai upsampled to 511 x 511 x
/// 256 at R = 0.2, 0.05 and 0.01 peaks at 60.1, 61.5 and 59.3 MiB, and one stage on bonsai or
/// engine at 51-52 MiB. Where the front stretches the budget (`Stage::budget`) the larger share
/// stretches it further: 2041^3 peaks at 65.7 MiB instead of 58.0 (docs/performance.md,
/// "Thirtieth session").
const BYTES_PER_FACE_ALONE: u64 = 600;
/// What the pipeline holds per cube of one slice outside the simplifier's faces (slabs being
/// extracted on every core, the detector's front, batches in flight), set aside from the budget
/// of one simplifier alone, whose slices are the large ones: without it, 850 bytes per face took
/// bonsai upsampled to 1021 x 1021 x 256 to 65.5 MiB; 12 bytes (12 MiB on 1021^2 slices) hold
/// it at 62.0. (The cascade's [`BYTES_PER_FACE_CASCADE`] was measured on the slices it runs on,
/// at most about 294^2 voxels, where this would be under 1 MiB.)
const SLICE_BYTES_PER_CUBE: u64 = 12;
/// The same for a cascade that the default put on slices larger than about 294^2 voxels
/// ([`JobConfig::cascade_faces`]). Beside the slices it has the first stage's ghosts, which
/// grow with the slab (17.5 k at 511^2 against 8.6 k at 256^2), and on an upsampled input the
/// source's cell bounds (about 2 MB); with 12 bytes, bonsai upsampled to 511^3 peaked 19 % above
/// its own 256^3 (56.1 against 47.2 MiB at `faces = 10000`), the only point of the scale curve
/// that runs two stages. With 36: 50.9-51.6 MiB; at R = 0.2 57.8 -> 53.1 MiB with the same RMS
/// distance (0.0263 voxels) and the 99.9 % distance +0.6 %; at R = 0.02 60.1 -> 54.0 MiB, RMS and
/// 99.9 % distance +2 % and +3 % (docs/scale.md, "The guard's cells in a pool").
const CASCADE_SLICE_BYTES_PER_CUBE: u64 = 36;
/// Largest slab, in cubes per face of the memory budget, that gets two simplifier stages by
/// default (about 294^2 voxels at the default budget). The first stage keeps a band of a few
/// slabs within its share of the budget; past about this size its band no longer fits and it
/// writes its faces uncontracted, and the second stage then holds the backlog: bonsai
/// upsampled 2x (261 k cubes per slab, 43 k budget faces) came out with 88.7 k faces for a
/// target of 10 k (one stage: 38 k) in 75 MiB, while bonsai, engine and cthead (65 k cubes per
/// slab) are valid and within 64 MiB at every rate measured (docs/performance.md, "Fifth
/// session"; the bound was 2 cubes per face of 1150 bytes, the same slab size).
const CASCADE_CUBES_PER_FACE: f64 = 1.2;
/// Largest slab, as a share of the cascade's face budget, that gets two simplifier stages by
/// default where the slices are larger than [`CASCADE_CUBES_PER_FACE`] allows (a counting pass
/// measures it first): what spoils a cascade is a slab crowded with surface, not the slice's
/// size. Volumes upsampled to 511^2-voxel slices at the default budget (72 k faces; two stages
/// against one, `isostream measure --volume`): bonsai (largest slab 16.1 k faces), mni152 (12.1
/// k) and aneurism (6.0 k) ran 1.3-1.8x faster at 0.98-1.05x one stage's RMS distance and
/// 0.96-1.03x its 99.9 % distance, in at most 61.7 MiB (docs/performance.md, "Thirty-eighth
/// session"). The crowded ones, mean_head (22.3 k), cthead (28.5 k), stent upsampled 4x (37.1 k)
/// and engine (128 k: a flat face across the sweep), came out 1.06-1.35x one stage's RMS while
/// the front moved by whole slabs; since it moves by rows within a slab they are as accurate
/// with two (0.98-0.99x its RMS at R = 0.2) and 1.2-1.7x faster, but the second stage holds the
/// first's output of the crowded slab beyond its front (the first stage's rear): 59-72 MiB
/// against 52-60, cthead and engine over the 64 (docs/performance.md, "Thirty-ninth
/// session"). Since the rear moves by rows and follows the first stage's front within two
/// slabs: 56-75 MiB, engine still at 75 (the rear stays two slabs behind the crowded slab while
/// its 90 k faces pass; "Fortieth session"). So the share stays, for the memory.
const CASCADE_SLAB_SHARE: u64 = 4;
/// Bytes per resident face that `[[attributes]]` add whatever the priority, besides
/// [`ATTRIBUTE_BYTES_PER_FACE_EACH`] per attribute: half a vertex's boxed `f32` values (the
/// pointer and the allocation with its header, the same for 1 to 4 values). Measured as the
/// growth of peak RSS with the resident faces between `memory_budget_mib = 32` and 64 (engine
/// and bonsai at R = 0.2 and 0.05, geometric priority, two stages: 33-35 k against 84-90 k
/// faces held): 0.9-1.0 MiB more for 51-55 k more faces with one attribute, 18-20 bytes a face,
/// and no more with four (`isostream run` of each job of the grid in docs/performance.md,
/// "Fifty-fifth session", its summary's `peak_rss_bytes` and `peak_resident_faces`).
const ATTRIBUTE_BYTES_PER_FACE: u64 = 24;
/// Bytes per resident face per attribute (see [`ATTRIBUTE_BYTES_PER_FACE`]).
const ATTRIBUTE_BYTES_PER_FACE_EACH: u64 = 2;
/// Bytes per resident face of the attribute quadric (`priority = "attribute-quadric"`), per
/// `f64` of its `(3 + m)^2 + (3 + m)` (m attributes): half a vertex's quadric.
const ATTRIBUTE_QUADRIC_BYTES_PER_ENTRY: u64 = 4;
/// Bytes per resident face of the attribute quadric besides its entries: half a vertex's two
/// vectors and their allocations. With [`ATTRIBUTE_QUADRIC_BYTES_PER_ENTRY`] that is 144, 184
/// and 288 bytes a face for 1, 2 and 4 attributes; measured as above (one stage, 33-35 k
/// against 89-90 k faces held), peak RSS grew by 140-150, 173-187 and 293-298 bytes a face
/// (the quadric: 8 bytes an entry per vertex, about two faces a vertex).
const ATTRIBUTE_QUADRIC_BYTES_PER_FACE: u64 = 64;
/// Bytes per cube of a slice that each attribute adds outside the faces, set aside from the
/// budget: its slices in flight with the slabs being extracted, and the values the batches
/// carry to the simplifier. Once more half of it for the first attribute's company (a derived
/// gradient reads an iso slice ahead and keeps one behind; an upsampled input then gives its
/// iso slices whole instead of rows). Measured on engine and bonsai (256^2 slices, 65 k cubes)
/// at the same faces held, against no attributes: 1, 2 and 4 attributes (the first one a
/// derived gradient, the others a volume file) took 3.4-4.0, 5.8-5.9 and 9.4-10.5 MiB more at
/// `memory_budget_mib = 32`, whatever the priority once its faces are counted: 36 bytes a cube
/// per attribute and half of it once; 40 and 20 hold them all.
const ATTRIBUTE_SLICE_BYTES_PER_CUBE: u64 = 40;
/// What the process needs besides the resident surface: code, two slices, channels, the
/// detector's front map (measured: 15 MiB on the volumes in `../shared/data`).
const FIXED_MIB: u64 = 16;

/// Cubes in one slab of a volume of `dims` voxels (the sweep runs along z).
fn slice_cubes(dims: [u64; 3]) -> u64 {
    dims[0].saturating_sub(1) * dims[1].saturating_sub(1)
}

impl JobConfig {
    /// Reads and validates a job file; relative paths inside are resolved against its folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        let mut job = Self::parse(&text, path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        job.resolve_paths(base);
        job.validate(path)?;
        Ok(job)
    }

    /// Parses TOML text; `origin` only names the source in errors.
    pub fn parse(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: origin.to_path_buf(),
            reason: with_section_hint(e.message()),
            key: e
                .span()
                .and_then(|s| quoted_token(text, s))
                .unwrap_or_default(),
            line: e
                .span()
                .map(|s| text[..s.start.min(text.len())].lines().count().max(1))
                .unwrap_or(0),
        })
    }

    fn resolve_paths(&mut self, base: &Path) {
        if let Some(p) = &self.input.path
            && p.is_relative()
        {
            self.input.path = Some(base.join(p));
        }
        if self.output.path.is_relative() {
            self.output.path = base.join(&self.output.path);
        }
        for a in &mut self.attributes {
            a.resolve_path(base);
        }
    }

    /// Checks every value a run depends on; the error names the key and what was expected.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, got: String| ConfigError::Invalid {
            path: origin.to_path_buf(),
            key: key.to_string(),
            expected: expected.to_string(),
            got,
        };
        let i = &self.input;
        match (&i.path, &i.shape) {
            (Some(_), Some(_)) => {
                return Err(bad(
                    "input.path",
                    "either `path` or `shape`, not both",
                    "both".into(),
                ));
            }
            (None, None) => {
                return Err(bad(
                    "input.path",
                    "a volume file `path` or a procedural `shape`",
                    "neither".into(),
                ));
            }
            (None, Some(_)) => {
                let size = i.size.ok_or_else(|| {
                    bad(
                        "input.size",
                        "[nx, ny, nz] for a procedural shape",
                        "nothing".into(),
                    )
                })?;
                if size.iter().any(|&n| n < 2) {
                    return Err(bad(
                        "input.size",
                        "at least 2 voxels per axis",
                        format!("{size:?}"),
                    ));
                }
                // A file's layout keys would be ignored by a shape: refused rather than
                // silently dropped, as every other impossible value is.
                let file_keys = [
                    ("dims", i.dims.is_some()),
                    ("dtype", i.dtype.is_some()),
                    ("endian", i.endian.is_some()),
                    ("header_bytes", i.header_bytes.is_some()),
                    ("array", i.array.is_some()),
                ];
                if let Some((key, _)) = file_keys.iter().find(|(_, set)| *set) {
                    return Err(bad(
                        &format!("input.{key}"),
                        "absent with a procedural `shape` (its grid is `size`; `dims`, `dtype`, \
                         `endian`, `header_bytes` and `array` describe a file)",
                        "a value".into(),
                    ));
                }
            }
            (Some(_), None) => {
                if let Some(size) = i.size {
                    return Err(bad(
                        "input.size",
                        "absent with a file `path` (its grid is its header's, or `dims` for a \
                         raw file; `size` is a procedural shape's)",
                        format!("{size:?}"),
                    ));
                }
            }
        }
        if let Some(sp) = i
            .spacing
            .filter(|sp| sp.iter().any(|s| !(s.is_finite() && *s > 0.0)))
        {
            return Err(bad(
                "input.spacing",
                "three finite values > 0",
                format!("{sp:?}"),
            ));
        }
        if let Some(k) = i.upsample.filter(|k| k.contains(&0)) {
            return Err(bad(
                "input.upsample",
                "three integers >= 1 ([kx, ky, kz]; 1 keeps an axis)",
                format!("{k:?}"),
            ));
        }
        if let Some(o) = i.origin.filter(|o| o.iter().any(|s| !s.is_finite())) {
            return Err(bad("input.origin", "three finite values", format!("{o:?}")));
        }
        if !self.extract.iso.is_finite() {
            return Err(bad(
                "extract.iso",
                "a finite number",
                self.extract.iso.to_string(),
            ));
        }
        let s = &self.simplify;
        if let Some(rate) = s.rate.filter(|r| !(*r > 0.0 && *r <= 1.0)) {
            return Err(bad("simplify.rate", "a value in (0, 1]", rate.to_string()));
        }
        match (self.output.faces, s.rate, s.mode) {
            (Some(0), _, _) => {
                return Err(bad("output.faces", "at least 1 face", "0".into()));
            }
            (Some(_), Some(rate), _) => {
                return Err(bad(
                    "output.faces",
                    "absent when [simplify] rate is given (one target: remove one of them)",
                    format!("faces and rate = {rate}"),
                ));
            }
            (Some(n), None, mode) if mode != Mode::Rate => {
                return Err(bad(
                    "output.faces",
                    "used only with [simplify] mode = \"rate\" (remove it or change the mode)",
                    format!("{n} with mode = \"{mode}\""),
                ));
            }
            _ => {}
        }
        if let Some(r) = s.initial_rate.filter(|r| !(*r > 0.0 && *r <= 1.0)) {
            return Err(bad(
                "simplify.initial_rate",
                "a value in (0, 1]",
                r.to_string(),
            ));
        }
        if matches!(s.mode, Mode::Error | Mode::Classical) {
            match s.error {
                Some(e) if e > 0.0 && e.is_finite() => {}
                Some(e) => return Err(bad("simplify.error", "a length > 0", e.to_string())),
                None => {
                    return Err(bad(
                        "simplify.error",
                        "E0, a length in the volume's units, for mode = \"error\" or \"classical\"",
                        "nothing".into(),
                    ));
                }
            }
        }
        if let Some((key, value, expected)) = s.ignored_key() {
            return Err(bad(&format!("simplify.{key}"), &expected, value));
        }
        // 0 passed every check and quietly undid the job: vertices left the band as soon as
        // their triangles were complete and preimages could span 2 slabs, so almost nothing was
        // contracted (a trial's 115,809 faces became 113,880 where the default gave 33,062).
        if s.retire_lag == Some(0) {
            return Err(bad(
                "simplify.retire_lag",
                "at least 1 slab (0 writes vertices before they can be contracted and turns \
                 simplification nearly off; leave it out for the default 8)",
                "0".into(),
            ));
        }
        if let Some(a) = s.isotropy.filter(|a| !(0.0..=1.0).contains(a)) {
            return Err(bad("simplify.isotropy", "a value in [0, 1]", a.to_string()));
        }
        if s.batch == Some(0) {
            return Err(bad("simplify.batch", "at least 1 face", "0".into()));
        }
        if s.boundary == Some(BoundaryKind::Planar)
            && s.priority() == PriorityKind::AttributeQuadric
        {
            return Err(bad(
                "simplify.boundary",
                "\"exact\" with priority = \"attribute-quadric\" (its quadric has no boundary cost; remove the key)",
                "\"planar\"".into(),
            ));
        }
        let p = &self.pipeline;
        if !(1..=MAX_CHANNEL_CAPACITY).contains(&p.channel_capacity) {
            return Err(bad(
                "pipeline.channel_capacity",
                &format!(
                    "1 to {MAX_CHANNEL_CAPACITY} batches (each link allocates its room up front)"
                ),
                p.channel_capacity.to_string(),
            ));
        }
        if p.memory_budget_mib < 16 {
            return Err(bad(
                "pipeline.memory_budget_mib",
                "at least 16 MiB",
                p.memory_budget_mib.to_string(),
            ));
        }
        if p.batch_triangles == 0 {
            return Err(bad("pipeline.batch_triangles", "at least 1", "0".into()));
        }
        let c = &p.checkpoint;
        if c.every_seconds.is_some() && c.every_slabs.is_some() {
            return Err(bad(
                "pipeline.checkpoint",
                "either `every_seconds` or `every_slabs`, not both",
                "both".into(),
            ));
        }
        if c.enabled == Some(false) && (c.every_seconds.is_some() || c.every_slabs.is_some()) {
            return Err(bad(
                "pipeline.checkpoint",
                "no interval when `enabled = false`",
                "an interval".into(),
            ));
        }
        if let Some(s) = c.every_seconds
            && !(s > 0.0 && s.is_finite())
        {
            return Err(bad(
                "pipeline.checkpoint.every_seconds",
                "a number of seconds > 0",
                s.to_string(),
            ));
        }
        if c.every_slabs == Some(0) {
            return Err(bad(
                "pipeline.checkpoint.every_slabs",
                "at least 1",
                "0".into(),
            ));
        }
        if let Some(n) = p.threads.filter(|n| !(1..=MAX_THREADS).contains(n)) {
            return Err(bad(
                "pipeline.threads",
                &format!(
                    "1 to {MAX_THREADS} (or leave it out for one per core, at most \
                     {DEFAULT_MAX_THREADS})"
                ),
                n.to_string(),
            ));
        }
        match p.simplify_stages {
            None | Some(1) => {}
            Some(2) if self.cascade_possible() => {}
            Some(2) => {
                return Err(bad(
                    "pipeline.simplify_stages",
                    "1 unless mode = \"rate\" with the geometric priority (the only setting two stages support)",
                    "2".into(),
                ));
            }
            Some(n) => return Err(bad("pipeline.simplify_stages", "1 or 2", n.to_string())),
        }
        let every = self.log.progress_seconds;
        if !(0.0..=1e9).contains(&every) {
            return Err(bad(
                "log.progress_seconds",
                "seconds between progress lines, from 0 (none) to 1e9",
                every.to_string(),
            ));
        }
        if let Some(level) = &self.log.level {
            check_log_filter(level).map_err(|why| {
                bad(
                    "log.level",
                    "a tracing filter such as \"info\" or \"warn,isostream_pipeline=debug\"",
                    format!("{level:?} ({why})"),
                )
            })?;
        }
        crate::attributes::validate(self, origin)?;
        crate::output::check_output_path(&self.output.path).map_err(|reason| {
            bad(
                "output.path",
                "a writable .smb, .sma, .ply, .obj, .stl or .glb path",
                reason,
            )
        })?;
        // The run would replace a volume it reads (a raw file may carry any extension).
        let inputs = self.input.path.iter().map(|p| ("[input] path", p)).chain(
            self.attributes
                .iter()
                .filter_map(|a| a.path.as_ref().map(|p| ("an [[attributes]] path", p))),
        );
        for (what, input) in inputs {
            if crate::output::one_file(input, &self.output.path) {
                return Err(bad(
                    "output.path",
                    "a file other than the volumes the job reads",
                    format!("{} is also {what}", self.output.path.display()),
                ));
            }
        }
        Ok(())
    }

    /// Whether the simplification of a volume of `dims` voxels runs as a cascade of two stages:
    /// `[pipeline] simplify_stages`, by default wherever a cascade is possible and either a slab
    /// has at most [`CASCADE_CUBES_PER_FACE`] cubes per face of the budget or the largest slab's
    /// surface (`largest_slab` faces, from a counting pass: see
    /// [`JobConfig::counts_slabs_for_stages`]) is at most [`CASCADE_SLAB_SHARE`] of it. There it
    /// is faster (two cores: 0.56-0.75x the wall time of one stage), at least as accurate
    /// (0.89-0.98x one stage's RMS distance), as valid, and within the default budget since the
    /// guard's cells shrank (docs/performance.md, "Fifth session" and "Thirty-eighth session").
    pub fn cascade(&self, dims: [u64; 3], largest_slab: Option<u64>) -> bool {
        match self.pipeline.simplify_stages {
            Some(n) => n == 2,
            None => {
                self.cascade_possible()
                    && (self.small_slices(dims)
                        || largest_slab.is_some_and(|faces| {
                            faces * CASCADE_SLAB_SHARE <= self.cascade_faces(dims) as u64
                        }))
            }
        }
    }

    /// Whether the stage count waits for the largest slab's face count (a counting pass before
    /// the run): by default, where two stages are possible but the slices are too large for
    /// [`JobConfig::cascade`] to decide by their size. The pass costs an extraction without
    /// triangles (bonsai upsampled to 511 x 511 x 256: 0.53 s, which the second core pays back
    /// many times: 8.7 s with two stages against 14.0 s with one at R = 0.2).
    pub fn counts_slabs_for_stages(&self, dims: [u64; 3]) -> bool {
        self.pipeline.simplify_stages.is_none()
            && self.cascade_possible()
            && !self.small_slices(dims)
    }

    /// A cascade's faces: where the default chose two stages on slices larger than
    /// [`JobConfig::small_slices`], the slices' share is set aside first, as for one stage alone
    /// ([`CASCADE_SLICE_BYTES_PER_CUBE`]; 9 MiB on 511^2 slices: bonsai upsampled so peaked at
    /// 60.9-63.6 MiB without a share, 56-58 with 3 MiB). A job that asks for two stages keeps
    /// the budget it was measured with (the bundled 64x job: 168 k faces at 128 MiB, not 120 k).
    fn cascade_faces(&self, dims: [u64; 3]) -> usize {
        let set_aside = match self.counts_slabs_for_stages(dims) {
            true => slice_cubes(dims).saturating_mul(CASCADE_SLICE_BYTES_PER_CUBE),
            false => 0,
        };
        self.faces_held(dims, BYTES_PER_FACE_CASCADE, set_aside)
    }

    /// Slices small enough for two stages whatever their surface.
    fn small_slices(&self, dims: [u64; 3]) -> bool {
        slice_cubes(dims) as f64
            <= CASCADE_CUBES_PER_FACE * self.faces_held(dims, BYTES_PER_FACE_CASCADE, 0) as f64
    }

    fn cascade_possible(&self) -> bool {
        self.simplify.mode == Mode::Rate && self.simplify.priority() == PriorityKind::Geometric
    }

    /// When the default left a job that could run two simplifier stages on one because its
    /// slabs are large for the budget: a line saying how to use both cores, and at what cost.
    /// Two stages at such sizes cost memory (the second holds the first's output above its
    /// rear) and save time (mean_head upsampled to 351 x 511 x 256, whose largest slab of 22 k
    /// faces keeps it on one stage, at R = 0.2: 9.6 s against 11.9 s, 59.1 MiB against 52.4,
    /// 0.99x one stage's RMS distance; hydrogen upsampled to 2017^3 at 128 MiB: 59.8 s against
    /// 89.0 s, as accurate; at 4033^3 and 128 MiB: 298 s against 463 s, as accurate, at 252
    /// MiB against 183, before the front moved by rows). Where the stages' fronts leave the second
    /// no room behind its own, it writes faces before it has seen the rest of the surface and
    /// the rest is squeezed: hydrogen at 4033^3 and 96 MiB came out 20 % over its face target
    /// at 500 times the RMS distance (docs/scale.md, "Two stages at 64x once more").
    pub fn one_stage_hint(&self, dims: [u64; 3], largest_slab: Option<u64>) -> Option<String> {
        (self.counts_slabs_for_stages(dims) && !self.cascade(dims, largest_slab)).then(|| {
            let slab =
                largest_slab.map_or(String::new(), |f| format!(" (its largest slab: {f} faces)"));
            format!(
                "one simplifier stage: slices of {} x {} voxels{slab} are large for two within \
                 [pipeline] memory_budget_mib = {}; simplify_stages = 2 uses both cores for \
                 more memory (mean_head at 351 x 511: 9.6 s against 11.9 s, 59 MiB against 52, \
                 as accurate), and is less accurate where its fronts leave the budget no room \
                 (the run then warns that faces were written before the target was reached)",
                dims[0], dims[1], self.pipeline.memory_budget_mib
            )
        })
    }

    /// The simplifiers' resident-face budget on a volume of `dims` voxels, derived from
    /// `pipeline.memory_budget_mib` (shared by the two stages of a cascade).
    pub fn max_resident_faces(&self, dims: [u64; 3], largest_slab: Option<u64>) -> usize {
        if self.cascade(dims, largest_slab) {
            self.cascade_faces(dims)
        } else {
            self.faces_held(
                dims,
                BYTES_PER_FACE_ALONE,
                slice_cubes(dims).saturating_mul(SLICE_BYTES_PER_CUBE),
            )
        }
    }

    /// The smallest `memory_budget_mib` (at least this job's) whose face budget on a volume of
    /// `dims` voxels ([`JobConfig::max_resident_faces`]) holds `faces`: what a warning suggests
    /// when the simplifier held more, so that the run at it holds them. Scaling the budget by
    /// the faces' ratio instead counted the fixed part and the slices' share as faces too.
    pub fn budget_holding(&self, dims: [u64; 3], largest_slab: Option<u64>, faces: usize) -> u64 {
        let mut job = self.clone();
        (self.pipeline.memory_budget_mib..)
            .find(|&mib| {
                job.pipeline.memory_budget_mib = mib;
                job.max_resident_faces(dims, largest_slab) >= faces
            })
            .unwrap_or(u64::MAX)
    }

    /// Faces the budget holds at `bytes` per face: the budget less the fixed part and
    /// `set_aside` bytes, of which at most a quarter of the budget (past that the slices alone
    /// fill the budget, the front stretches it, and the faces behind the front still need room:
    /// bonsai upsampled to 2041^3 would otherwise hold 20 k faces behind a 33 k-face front), and
    /// at least a quarter of the budget is left to the faces.
    ///
    /// `[[attributes]]` cost more per face and per slice ([`JobConfig::attribute_bytes`]); their
    /// share is taken from the faces' (down to an eighth of the budget): with it counted as
    /// faces, engine with four attributes at the attribute quadric peaked at 45.7 MiB in a
    /// budget of 32 and 79.8 MiB in 64.
    fn faces_held(&self, dims: [u64; 3], bytes: u64, set_aside: u64) -> usize {
        let budget = self.pipeline.memory_budget_mib * 1024 * 1024;
        let (per_face, per_cube) = self.attribute_bytes();
        let held = budget
            .saturating_sub(FIXED_MIB * 1024 * 1024 + set_aside.min(budget / 4))
            .max(budget / 4);
        let held = match per_cube {
            0 => held,
            _ => held
                .saturating_sub(slice_cubes(dims).saturating_mul(per_cube))
                .max(budget / 8),
        };
        (held / (bytes + per_face)) as usize
    }

    /// What `[[attributes]]` add: bytes per resident face (their values, and with the attribute
    /// quadric its `(3 + m)^2 + (3 + m)` entries) and bytes per cube of a slice (their slices
    /// in flight), both 0 without attributes.
    fn attribute_bytes(&self) -> (u64, u64) {
        let m = self.attributes.len() as u64;
        if m == 0 {
            return (0, 0);
        }
        let quadric = match self.simplify.priority() {
            PriorityKind::AttributeQuadric => {
                let n = 3 + m;
                (n * n + n) * ATTRIBUTE_QUADRIC_BYTES_PER_ENTRY + ATTRIBUTE_QUADRIC_BYTES_PER_FACE
            }
            PriorityKind::Geometric | PriorityKind::DataDependent => 0,
        };
        (
            ATTRIBUTE_BYTES_PER_FACE + m * ATTRIBUTE_BYTES_PER_FACE_EACH + quadric,
            ATTRIBUTE_SLICE_BYTES_PER_CUBE * m + ATTRIBUTE_SLICE_BYTES_PER_CUBE / 2,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<JobConfig, ConfigError> {
        let job = JobConfig::parse(text, Path::new("job.toml"))?;
        job.validate(Path::new("job.toml"))?;
        Ok(job)
    }

    const MINIMAL: &str = r#"
        [input]
        shape = "sphere"
        size = [16, 16, 16]
        [extract]
        iso = 0.0
        [output]
        path = "/tmp/isostream-config-test.smb"
    "#;

    #[test]
    fn minimal_job_gets_defaults() {
        let job = parse(MINIMAL).unwrap();
        assert_eq!(job.simplify.mode, Mode::Rate);
        assert_eq!(job.pipeline.channel_capacity, 8);
        assert_eq!(job.input.spacing, None);
    }

    #[test]
    fn a_priority_key_in_mode_none_names_the_mode() {
        let e = parse("[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\n[extract]\niso = 0.0\n[simplify]\nmode = \"none\"\nlambda = 0.3\n[output]\npath = \"o.smb\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`simplify.lambda` must be absent unless mode = \"rate\", \"error\" or \"classical\""), "{e}");
    }

    #[test]
    fn a_number_too_large_is_quoted_whole() {
        let text = "[input]\nshape = \"sphere\"\nsize = [16, 16, 99999999999999999999999]\n[extract]\niso = 0.0\n[output]\npath = \"o.smb\"\n";
        let e = JobConfig::parse(text, Path::new("job.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("(at `99999999999999999999999`)"), "{e}");
        // A key's span is the key, as before.
        let e = JobConfig::parse("[input]\nbogus = 1\n", Path::new("job.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("(at `bogus`)"), "{e}");
    }

    /// A key of another section says where it belongs, in one line; a misspelt key gets no
    /// such hint.
    #[test]
    fn a_key_in_the_wrong_section_says_where_it_belongs() {
        let text = format!("{MINIMAL}\n[simplify]\nfaces = 10\n");
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.starts_with("job.toml:10: unknown field `faces`"),
            "{err}"
        );
        assert!(err.contains("; `faces` belongs in [output]"), "{err}");
        assert!(!err.contains('\n'), "{err}");
        let text = MINIMAL.replace("iso = 0.0", "iso = 0.0\npath = \"a.raw\"");
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("; `path` belongs in [input], [output] or [[attributes]]"),
            "{err}"
        );
        let text = MINIMAL.replace("iso = 0.0", "iso = 0.0\nisovalue = 3");
        let err = parse(&text).unwrap_err().to_string();
        assert!(!err.contains("belongs"), "{err}");
    }

    /// The table of sections names every table of a job, with the keys serde accepts there.
    #[test]
    fn sections_are_the_jobs_tables() {
        let mut names: Vec<&str> = sections()[1..]
            .iter()
            .map(|(s, _)| s.trim_matches(['[', ']']))
            .filter(|s| !s.contains('.'))
            .collect();
        names.sort_unstable();
        let mut top = keys_of::<JobConfig>().to_vec();
        top.sort_unstable();
        assert_eq!(top, names);
        assert!(keys_of::<OutputConfig>().contains(&"faces"));
    }

    #[test]
    fn unknown_key_is_named() {
        let text = MINIMAL.replace("iso = 0.0", "iso = 0.0\nisovalue = 3");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("isovalue"), "{err}");
        assert!(err.contains("job.toml"), "{err}");
    }

    #[test]
    fn rate_out_of_range_is_named() {
        let text = format!("{MINIMAL}\n[simplify]\nrate = 1.5\n");
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("simplify.rate") && err.contains("(0, 1]"),
            "{err}"
        );
    }

    #[test]
    fn classical_needs_an_error_bound() {
        let text = format!("{MINIMAL}\n[simplify]\nmode = \"classical\"\n");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("simplify.error"), "{err}");
        let text = format!("{MINIMAL}\n[simplify]\nmode = \"classical\"\nerror = 0.1\n");
        assert_eq!(parse(&text).unwrap().simplify.mode, Mode::Classical);
    }

    #[test]
    fn wrong_type_is_an_error() {
        let text = MINIMAL.replace("iso = 0.0", "iso = \"high\"");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("job.toml"), "{err}");
    }

    #[test]
    fn path_and_shape_together_are_refused() {
        let text = MINIMAL.replace("shape = \"sphere\"", "shape = \"sphere\"\npath = \"a.raw\"");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("input.path"), "{err}");
    }

    #[test]
    fn unwritable_output_is_refused() {
        let text = MINIMAL.replace("/tmp/isostream-config-test.smb", "/proc/x.smb");
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("output.path") && err.contains("/proc"),
            "{err}"
        );
    }

    /// Planar by default, exact where the priority has no boundary cost, which refuses planar.
    #[test]
    fn the_boundary_rule_defaults_by_priority() {
        assert_eq!(
            parse(MINIMAL).unwrap().simplify.boundary(),
            BoundaryKind::Planar
        );
        let exact = format!("{MINIMAL}\n[simplify]\nboundary = \"exact\"\n");
        assert_eq!(
            parse(&exact).unwrap().simplify.boundary(),
            BoundaryKind::Exact
        );
        let attributes = "\n[[attributes]]\nname = \"g\"\nderive = \"gradient_magnitude\"\n";
        let aq =
            format!("{MINIMAL}\n[simplify]\npriority = \"attribute-quadric\"\n{{}}{attributes}");
        let job = parse(&aq.replace("{}", "")).unwrap();
        assert_eq!(job.simplify.boundary(), BoundaryKind::Exact);
        let err = parse(&aq.replace("{}", "boundary = \"planar\"\n"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("simplify.boundary"), "{err}");
        let bad = format!("{MINIMAL}\n[simplify]\nboundary = \"round\"\n");
        let err = parse(&bad).unwrap_err().to_string();
        assert!(err.contains("job.toml") && err.contains("planar"), "{err}");
    }

    #[test]
    fn error_bound_in_rate_mode_is_refused() {
        let text = format!("{MINIMAL}\n[simplify]\nrate = 0.5\nerror = 0.1\n");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("simplify.error"), "{err}");
    }

    /// A key the mode or priority does not read is refused, naming the key, what ignores it and
    /// where it applies; where it is read it is accepted (the trial's ignored keys first, then
    /// the rest of the audit).
    #[test]
    fn keys_the_mode_or_priority_ignores_are_refused() {
        let job = |simplify: &str| parse(&format!("{MINIMAL}\n[simplify]\n{simplify}\n"));
        let refused = [
            (
                "mode = \"error\"\nerror = 0.1\nbatch = 1000",
                "batch",
                "mode \"error\"",
                "mode = \"rate\"",
            ),
            (
                "mode = \"error\"\nerror = 0.1\ninitial_rate = 0.5",
                "initial_rate",
                "mode \"error\"",
                "mode = \"rate\"",
            ),
            (
                "time_lag = false",
                "time_lag",
                "mode \"rate\"",
                "mode = \"error\"",
            ),
            (
                "isotropy = 0.5",
                "isotropy",
                "mode \"rate\"",
                "mode = \"error\" or \"classical\"",
            ),
            (
                "retire_lag = 2",
                "retire_lag",
                "mode \"rate\"",
                "mode = \"error\" or \"classical\"",
            ),
            (
                "mode = \"classical\"\nerror = 0.1\ntime_lag = true",
                "time_lag",
                "mode \"classical\"",
                "mode = \"error\"",
            ),
            (
                "mode = \"none\"\nretire_lag = 8",
                "retire_lag",
                "mode \"none\"",
                "mode = \"error\" or \"classical\"",
            ),
            (
                "mode = \"none\"\npriority = \"geometric\"",
                "priority",
                "mode \"none\"",
                "mode = \"rate\", \"error\" or \"classical\"",
            ),
            (
                "mode = \"none\"\nboundary = \"exact\"",
                "boundary",
                "mode \"none\"",
                "mode = \"rate\", \"error\" or \"classical\"",
            ),
            (
                "mode = \"none\"\nbatch = 10",
                "batch",
                "mode \"none\"",
                "mode = \"rate\"",
            ),
            (
                "mode = \"none\"\nrate = 0.2",
                "rate",
                "mode \"none\"",
                "mode = \"rate\"",
            ),
            (
                "error = 0.1",
                "error",
                "mode \"rate\"",
                "mode = \"error\" or \"classical\"",
            ),
            (
                "lambda = 0.3",
                "lambda",
                "priority \"geometric\"",
                "priority = \"data-dependent\"",
            ),
        ];
        for (simplify, key, ignored_by, fix) in refused {
            let err = job(simplify).unwrap_err().to_string();
            assert!(
                err.starts_with(&format!(
                    "job.toml: `simplify.{key}` must be absent unless {fix} ("
                )) && err.contains(&format!(
                    "{ignored_by} ignores it: remove it, or use {fix} where it applies"
                )) && !err.contains('\n'),
                "{simplify}: {err}"
            );
        }
        for read in [
            "batch = 1000\ninitial_rate = 0.4\nboundary = \"exact\"\npriority = \"geometric\"",
            "mode = \"error\"\nerror = 0.1\ntime_lag = false\nisotropy = 0.5\nretire_lag = 2",
            "mode = \"classical\"\nerror = 0.1\nisotropy = 0.5\nretire_lag = 2\nboundary = \"exact\"",
            "mode = \"none\"\nmin_component_faces = 10",
            "priority = \"data-dependent\"\nlambda = 0.3",
        ] {
            job(read).unwrap_or_else(|e| panic!("{read}: {e}"));
        }
    }

    /// One extraction thread per core by default, at most eight (each holds a slab in flight).
    #[test]
    fn default_threads_are_the_cores_up_to_eight() {
        assert_eq!(default_threads(1), 1);
        assert_eq!(default_threads(2), 2);
        assert_eq!(default_threads(64), 8);
        assert!((1..=8).contains(&PipelineConfig::default().threads()));
    }

    /// A slab count is in slabs as thick as the voxels are wide; a `retire_lag` given is kept.
    #[test]
    fn band_depths_count_slabs_as_thick_as_the_voxels_are_wide() {
        assert_eq!(thin_slabs([1.0, 1.0, 1.0]), 1);
        assert_eq!(
            thin_slabs([1.0, 1.0, 2.0]),
            1,
            "thick slabs are not thinned"
        );
        assert_eq!(thin_slabs([1.0, 1.0, 0.7]), 1);
        assert_eq!(thin_slabs([0.5, 0.5, 0.025]), 20, "upsampled [2, 2, 40]");
        assert_eq!(
            thin_slabs([0.1, 1.0, 0.025]),
            4,
            "the smaller in-plane spacing"
        );
        assert_eq!(thin_slabs([1e8, 1e8, 1.0]), 32, "bounded");
        assert_eq!(
            thin_slabs([1e300, 1e300, 1e-10]),
            32,
            "a ratio past f64's range"
        );
        assert_eq!(thin_slabs([1.0, 1.0, 0.5]), 2);
        let job = |lag: &str| {
            parse(&format!(
                "{MINIMAL}\n[simplify]\nmode = \"error\"\nerror = 0.1\n{lag}"
            ))
            .unwrap()
            .simplify
        };
        assert_eq!(job("").retire_lag_on([0.5, 0.5, 0.025]), 160);
        assert_eq!(
            job("retire_lag = 3").retire_lag_on([0.5, 0.5, 0.025]),
            3,
            "as given"
        );
    }

    /// `retire_lag = 0` is refused in both modes that read it, in one line naming the key and
    /// the fix; 1 is accepted.
    #[test]
    fn a_retire_lag_of_zero_is_refused() {
        for mode in ["error", "classical"] {
            let job = |lag: u32| {
                parse(&format!(
                    "{MINIMAL}\n[simplify]\nmode = \"{mode}\"\nerror = 0.1\nretire_lag = {lag}\n"
                ))
            };
            let err = job(0).unwrap_err().to_string();
            assert!(
                err.starts_with("job.toml: `simplify.retire_lag` must be at least 1 slab (")
                    && err.contains("leave it out for the default 8")
                    && err.ends_with("got 0")
                    && !err.contains('\n'),
                "{mode}: {err}"
            );
            job(1).unwrap_or_else(|e| panic!("{mode}: {e}"));
        }
    }

    /// The data-dependent weight without attributes is lambda x curvature: lambda = 0 weighs
    /// every edge 0 and is refused, naming the fixes; any other lambda, or attributes, are fine.
    #[test]
    fn data_dependent_without_attributes_needs_a_curvature_weight() {
        let job = |lambda: &str, attributes: &str| {
            parse(&format!(
                "{MINIMAL}\n[simplify]\nrate = 0.1\npriority = \"data-dependent\"\n{lambda}\n{attributes}"
            ))
        };
        let err = job("lambda = 0.0", "").unwrap_err().to_string();
        assert!(
            err.starts_with("job.toml: `simplify.lambda` must be above 0 with priority = \"data-dependent\" and no [[attributes]] entry")
                && err.contains("raise lambda")
                && err.contains("add an [[attributes]] entry"),
            "{err}"
        );
        let gradient = "[[attributes]]\nname = \"g\"\nderive = \"gradient_magnitude\"";
        for (lambda, attributes) in [("lambda = 0.0", gradient), ("lambda = 0.3", ""), ("", "")] {
            job(lambda, attributes).unwrap_or_else(|e| panic!("{lambda} {attributes}: {e}"));
        }
    }

    /// The service stores a job as `toml::to_string` of its config and validates it again when it
    /// restarts: keys left out must stay out, or every default would come back as a key its mode
    /// ignores.
    #[test]
    fn a_stored_job_keeps_its_keys_left_out() {
        let text = format!("{MINIMAL}\n[simplify]\nmode = \"error\"\nerror = 0.1\n");
        let stored = toml::to_string(&parse(&text).unwrap()).unwrap();
        let again = parse(&stored).unwrap_or_else(|e| panic!("{stored}: {e}"));
        assert_eq!(again.simplify.initial_rate, None, "{stored}");
        assert!(again.simplify.time_lag());
    }

    #[test]
    fn bad_log_filter_is_refused() {
        for level in ["debugg", "info,=[", "x=notalevel"] {
            let text = format!("{MINIMAL}\n[log]\nlevel = {level:?}\n");
            let err = parse(&text).unwrap_err().to_string();
            assert!(err.contains("log.level"), "{level}: {err}");
        }
        let text = format!("{MINIMAL}\n[log]\nlevel = \"warn,isostream_pipeline=debug\"\n");
        parse(&text).unwrap();
    }

    #[test]
    fn checkpoint_intervals() {
        let job = |c: &str| {
            let job = parse(&format!("{MINIMAL}\n[pipeline]\ncheckpoint = {c}\n"))?;
            job.validate(Path::new("job.toml")).map(|()| job)
        };
        let every = |c: &str, voxels| job(c).unwrap().pipeline.checkpoint.every(voxels);
        let big = CheckpointConfig::AUTO_MIN_VOXELS;
        assert_eq!(every("{}", big - 1), None);
        assert_eq!(every("{}", big), Some(CheckpointEvery::Seconds(60.0)));
        assert_eq!(every("{ enabled = false }", big), None);
        assert_eq!(
            every("{ enabled = true }", 8),
            Some(CheckpointEvery::Seconds(60.0))
        );
        assert_eq!(
            every("{ every_slabs = 3 }", 8),
            Some(CheckpointEvery::Slabs(3))
        );
        assert_eq!(
            every("{ every_seconds = 0.5 }", 8),
            Some(CheckpointEvery::Seconds(0.5))
        );
        for bad in [
            "{ every_slabs = 0 }",
            "{ every_seconds = -1 }",
            "{ every_seconds = 1, every_slabs = 1 }",
            "{ enabled = false, every_slabs = 2 }",
            "{ every = 2 }",
        ] {
            let e = job(bad).unwrap_err().to_string();
            assert!(
                e.contains("checkpoint") || e.contains("every"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn upsample_factors_are_checked() {
        let text = MINIMAL.replace(
            "size = [16, 16, 16]",
            "size = [16, 16, 16]\nupsample = [2, 0, 1]",
        );
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("input.upsample") && err.contains(">= 1"),
            "{err}"
        );
        let text = MINIMAL.replace(
            "size = [16, 16, 16]",
            "size = [16, 16, 16]\nupsample = [2, -1, 1]",
        );
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("job.toml:5") && err.contains("u64"), "{err}");
        let text = MINIMAL.replace(
            "size = [16, 16, 16]",
            "size = [16, 16, 16]\nupsample = [2, 3, 1]",
        );
        assert_eq!(parse(&text).unwrap().input.upsample, Some([2, 3, 1]));
    }

    #[test]
    fn faces_and_rate_are_exclusive() {
        let with = |extra: &str, simplify: &str| {
            let text = MINIMAL.replace("[output]", &format!("{simplify}\n[output]\n{extra}"));
            parse(&text)
        };
        let err = with("faces = 100", "[simplify]\nrate = 0.1")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("output.faces") && err.contains("rate"),
            "{err}"
        );
        let err = with("faces = 0", "").unwrap_err().to_string();
        assert!(err.contains("output.faces"), "{err}");
        // The mode as the job file spells it, not its `Debug` name.
        for (mode, simplify) in [
            ("none", "mode = \"none\""),
            ("classical", "mode = \"classical\"\nerror = 0.1"),
        ] {
            let err = with("faces = 100", &format!("[simplify]\n{simplify}"))
                .unwrap_err()
                .to_string();
            assert!(
                err.ends_with(&format!("got 100 with mode = \"{mode}\"")),
                "{err}"
            );
        }
        assert_eq!(with("faces = 10", "").unwrap().output.faces, Some(10));
    }

    #[test]
    fn simplify_stages_are_one_or_two_and_two_only_where_supported() {
        let small = [256, 256, 256];
        let job = parse(MINIMAL).unwrap();
        assert!(
            job.cascade(small, None),
            "two stages by default in mode rate"
        );
        assert!(
            !job.cascade([1024, 1024, 64], None),
            "one stage by default on slabs too large for the first stage's band"
        );
        let one = format!("{MINIMAL}\n[pipeline]\nsimplify_stages = 1\n");
        assert!(!parse(&one).unwrap().cascade(small, None));
        let two = format!("{MINIMAL}\n[pipeline]\nsimplify_stages = 2\n");
        assert!(
            parse(&two)
                .unwrap()
                .cascade([1024, 1024, 64], Some(1 << 40)),
            "asked for"
        );
        let three = format!("{MINIMAL}\n[pipeline]\nsimplify_stages = 3\n");
        let err = parse(&three).unwrap_err().to_string();
        assert!(
            err.contains("pipeline.simplify_stages") && err.contains("1 or 2"),
            "{err}"
        );
        let none = format!("{MINIMAL}\n[simplify]\nmode = \"none\"\n");
        assert!(
            !parse(&none).unwrap().cascade(small, None),
            "one stage where two are not possible"
        );
        let two = format!("{none}\n[pipeline]\nsimplify_stages = 2\n");
        let err = parse(&two).unwrap_err().to_string();
        assert!(err.contains("mode = \"rate\""), "{err}");
    }

    /// On slices too large to decide by their size, the largest slab's surface decides: two
    /// stages where it is at most a quarter of the cascade's faces (the slices' share set aside),
    /// one where a flat face across the sweep fills the first stage's band. Only the default
    /// asks for that count.
    #[test]
    fn the_largest_slab_decides_the_stages_on_large_slices() {
        let job = parse(MINIMAL).unwrap();
        let (large, small) = ([1024, 1024, 64], [256, 256, 64]);
        assert!(job.counts_slabs_for_stages(large));
        assert!(!job.counts_slabs_for_stages(small), "decided by the slices");
        let mib = 1024 * 1024;
        let set_aside = (1023 * 1023 * CASCADE_SLICE_BYTES_PER_CUBE).min(16 * mib);
        let faces = (48 * mib - set_aside) / BYTES_PER_FACE_CASCADE;
        assert!(job.cascade(large, Some(faces / CASCADE_SLAB_SHARE)));
        assert!(!job.cascade(large, Some(faces / CASCADE_SLAB_SHARE + 1)));
        assert!(!job.cascade(large, None), "not counted: one stage");
        assert_eq!(
            job.max_resident_faces(large, Some(1000)),
            faces as usize,
            "the slices' share set aside"
        );
        let hint = job.one_stage_hint(large, Some(1 << 20)).unwrap();
        assert!(hint.contains("largest slab: 1048576 faces"), "{hint}");
        let asked = parse(&format!("{MINIMAL}\n[pipeline]\nsimplify_stages = 2\n")).unwrap();
        assert_eq!(
            asked.max_resident_faces(large, None),
            (48 * mib / BYTES_PER_FACE_CASCADE) as usize,
            "two stages asked for keep the budget they were measured with"
        );
        for fixed in [
            "[pipeline]\nsimplify_stages = 1",
            "[simplify]\nmode = \"none\"",
        ] {
            let job = parse(&format!("{MINIMAL}\n{fixed}\n")).unwrap();
            assert!(!job.counts_slabs_for_stages(large), "{fixed}");
        }
    }

    /// One stage alone sets its slices' share aside (their slabs in flight grow with them), up to
    /// a quarter of the budget, and leaves a quarter of it to the faces whatever the budget.
    #[test]
    fn one_stage_sets_the_slices_share_aside_from_its_faces() {
        let one = parse(&format!("{MINIMAL}\n[pipeline]\nsimplify_stages = 1\n")).unwrap();
        let faces = |side: u64| one.max_resident_faces([side, side, 64], None);
        let mib = 1024 * 1024;
        let held = |set_aside: u64| ((48 * mib - set_aside) / BYTES_PER_FACE_ALONE) as usize;
        assert_eq!(faces(2), held(SLICE_BYTES_PER_CUBE));
        assert_eq!(faces(511), held(510 * 510 * SLICE_BYTES_PER_CUBE));
        assert!(faces(511) < faces(256) && faces(1021) < faces(511));
        let capped = (32 * mib / BYTES_PER_FACE_ALONE) as usize;
        assert_eq!(
            faces(2041),
            capped,
            "a quarter of the budget set aside at most"
        );
        let tight = parse(&format!(
            "{MINIMAL}\n[pipeline]\nsimplify_stages = 1\nmemory_budget_mib = 20\n"
        ))
        .unwrap();
        assert_eq!(
            tight.max_resident_faces([511, 511, 64], None),
            (5 * mib / BYTES_PER_FACE_ALONE) as usize,
            "a quarter of the budget left to the faces at least"
        );
        let two = parse(MINIMAL).unwrap();
        assert_eq!(
            two.max_resident_faces([256, 256, 64], None),
            (48 * mib / BYTES_PER_FACE_CASCADE) as usize,
            "a cascade's bytes per face were measured with its slices"
        );
    }

    /// `[[attributes]]` are charged per face (more with the attribute quadric, whose size grows
    /// with their square) and per slice; a job without them keeps its faces.
    #[test]
    fn attributes_cost_faces_by_their_count_and_the_priority() {
        let with = |n: usize, priority: &str| {
            let attrs = "[[attributes]]\nname = \"g\"\nderive = \"gradient_magnitude\"\n";
            let text = format!(
                "{MINIMAL}\n[simplify]\npriority = \"{priority}\"\n\
                 [pipeline]\nsimplify_stages = 1\n{}",
                attrs.repeat(n)
            );
            let job = JobConfig::parse(&text, Path::new("job.toml")).unwrap();
            job.max_resident_faces([256, 256, 128], None)
        };
        let mib = 1024 * 1024;
        let plain = ((48 * mib - 255 * 255 * SLICE_BYTES_PER_CUBE) / BYTES_PER_FACE_ALONE) as usize;
        assert_eq!(with(0, "geometric"), plain);
        let slices = |m: u64| 255 * 255 * (ATTRIBUTE_SLICE_BYTES_PER_CUBE * m + 20);
        let one =
            (48 * mib - 255 * 255 * SLICE_BYTES_PER_CUBE - slices(1)) / (BYTES_PER_FACE_ALONE + 26);
        assert_eq!(with(1, "geometric"), one as usize);
        assert!(
            with(4, "geometric") < with(2, "geometric")
                && with(2, "geometric") < with(1, "geometric")
        );
        let quadric = |m: u64| ((3 + m) * (3 + m) + 3 + m) * 4 + 64;
        let four = (48 * mib - 255 * 255 * SLICE_BYTES_PER_CUBE - slices(4))
            / (BYTES_PER_FACE_ALONE + 32 + quadric(4));
        assert_eq!(with(4, "attribute-quadric"), four as usize);
        assert_eq!(quadric(4), 288, "the measured 293-298 bytes a face");
    }

    /// The budget a warning suggests holds the faces asked for, and is the smallest that does.
    #[test]
    fn the_budget_holding_some_faces_is_the_least_that_holds_them() {
        let job = parse(MINIMAL).unwrap();
        let dims = [511, 511, 128];
        let held = job.max_resident_faces(dims, None);
        assert_eq!(job.budget_holding(dims, None, held), 64);
        let want = 2 * held;
        let mib = job.budget_holding(dims, None, want);
        let at = |mib: u64| {
            let mut j = job.clone();
            j.pipeline.memory_budget_mib = mib;
            j.max_resident_faces(dims, None)
        };
        assert!(at(mib) >= want && at(mib - 1) < want, "{mib} MiB");
        assert!(
            mib < 128,
            "the fixed part is not scaled with the faces: {mib} MiB"
        );
    }

    #[test]
    fn a_job_left_on_one_stage_by_its_slabs_is_told_how_to_use_both_cores() {
        let job = parse(MINIMAL).unwrap();
        assert_eq!(
            job.one_stage_hint([256, 256, 256], None),
            None,
            "two stages already"
        );
        let hint = job.one_stage_hint([1024, 1024, 64], None).unwrap();
        assert!(
            hint.contains("1024 x 1024")
                && hint.contains("memory_budget_mib = 64")
                && hint.contains("simplify_stages = 2")
                && hint.contains("less accurate"),
            "{hint}"
        );
        let one = parse(&format!("{MINIMAL}\n[pipeline]\nsimplify_stages = 1\n")).unwrap();
        assert_eq!(
            one.one_stage_hint([1024, 1024, 64], None),
            None,
            "the user's choice"
        );
        let none = parse(&format!("{MINIMAL}\n[simplify]\nmode = \"none\"\n")).unwrap();
        assert_eq!(
            none.one_stage_hint([1024, 1024, 64], None),
            None,
            "two are not possible"
        );
    }

    #[test]
    fn thread_and_channel_limits_are_checked() {
        let text = format!("{MINIMAL}\n[pipeline]\nthreads = 0\n");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("pipeline.threads"), "{err}");
        for (key, value) in [
            ("threads", 100_000),
            ("channel_capacity", 1_000_000_000),
            ("channel_capacity", 0),
        ] {
            let text = format!("{MINIMAL}\n[pipeline]\n{key} = {value}\n");
            let err = parse(&text).unwrap_err().to_string();
            assert!(
                err.contains(&format!("pipeline.{key}")) && err.contains(&value.to_string()),
                "{err}"
            );
        }
        let text = format!("{MINIMAL}\n[pipeline]\nthreads = 3\n");
        assert_eq!(parse(&text).unwrap().pipeline.threads(), 3);
        assert!(parse(MINIMAL).unwrap().pipeline.threads() >= 1);
    }

    #[test]
    fn progress_interval_is_checked() {
        for bad in ["-1.0", "nan", "inf"] {
            let text = format!("{MINIMAL}\n[log]\nprogress_seconds = {bad}\n");
            let err = parse(&text).unwrap_err().to_string();
            assert!(err.contains("log.progress_seconds"), "{bad}: {err}");
        }
        let text = format!("{MINIMAL}\n[log]\nprogress_seconds = 0\n");
        assert_eq!(parse(&text).unwrap().log.progress_interval(), None);
        assert_eq!(
            parse(MINIMAL).unwrap().log.progress_interval(),
            Some(std::time::Duration::from_secs(10))
        );
    }

    #[test]
    fn output_extension_is_checked() {
        let text = MINIMAL.replace(".smb", ".xyz");
        let err = parse(&text).unwrap_err().to_string();
        assert!(err.contains("output.path"), "{err}");
    }
}
