//! Errors of a job. Each message is one line that names the file or key and says what to do.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{}: cannot read job file: {reason}", path.display())]
    Read { path: PathBuf, reason: String },
    #[error("{}:{line}: {reason}{}", path.display(), if key.is_empty() { String::new() } else { format!(" (at `{key}`)") })]
    Parse {
        path: PathBuf,
        line: usize,
        reason: String,
        key: String,
    },
    #[error("{}: `{key}` must be {expected}, got {got}", path.display())]
    Invalid {
        path: PathBuf,
        key: String,
        expected: String,
        got: String,
    },
}

/// Why a run stopped. The first failing stage's error is the one reported.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Volume(#[from] isostream_volume::VolumeError),
    #[error(transparent)]
    Output(#[from] isostream_smesh::SmeshError),
    /// The mesh is complete under its final name when this happens (the summary comes after).
    #[error(
        "{}: cannot write run summary: {reason} (the mesh itself was written complete; free space or fix permissions, or set [output] summary = false)",
        path.display()
    )]
    Summary { path: PathBuf, reason: String },
    #[error(
        "simplify.mode = \"classical\" keeps the whole surface in memory and it outgrew pipeline.memory_budget_mib ({faces} faces resident, no output written): raise pipeline.memory_budget_mib or use mode = \"error\""
    )]
    ClassicalOverBudget { faces: usize },
    #[error(
        "{}: another isostream job is writing this output (it holds {}); wait for it to finish or choose another output.path",
        output.display(), lock.display()
    )]
    Locked { output: PathBuf, lock: PathBuf },
    /// The output's folder cannot be created or written: the output path is unusable as it is.
    #[error(
        "{}: cannot {what} {}: {source}; {fix}, or choose another output folder",
        output.display(), folder.display()
    )]
    OutputFolder {
        output: PathBuf,
        folder: PathBuf,
        what: &'static str,
        fix: &'static str,
        source: std::io::Error,
    },
    #[error("{}: cannot take the output's lock {}: {reason}", output.display(), lock.display())]
    Lock {
        output: PathBuf,
        lock: PathBuf,
        reason: String,
    },
    #[error(
        "{input}: the surface at extract.iso = {iso} is empty: {why}; or set [output] allow_empty = true to accept an empty mesh (no output written)"
    )]
    EmptySurface {
        input: String,
        /// As written in the job (extraction compares in f32).
        iso: f64,
        /// Why, from the data range or before any work from the stored type's, and what iso to
        /// set (`DataRange::empty_surface`, `range::ruled_out_by_type`).
        why: String,
    },
    #[error(
        "output.path {}: this job could write up to {bound} {counted}, past the {limit} that {what} (nothing was run): write {instead}, or {lower}",
        output.display()
    )]
    IndexLimit {
        output: PathBuf,
        bound: u64,
        counted: crate::index_limit::Counted,
        limit: u64,
        /// The format's field, with its verb ("binary STL's 32-bit triangle count holds").
        what: &'static str,
        /// The formats without the limit.
        instead: &'static str,
        /// How this job's mode lowers its output (`[output] faces` is mode rate's only).
        lower: &'static str,
    },
    #[error(
        "{input}: slices of {nx} x {ny} voxels are read whole as f32, and {slices} of them take {need_gib:.1} GiB, more than this machine's {physical_gib:.1} GiB of memory (nothing was run): {fix}"
    )]
    SliceMemory {
        input: String,
        nx: u64,
        ny: u64,
        slices: u64,
        need_gib: f64,
        physical_gib: f64,
        fix: &'static str,
    },
    #[error("interrupted: no output was written (the partial file was removed)")]
    Cancelled,
    #[error(
        "interrupted: no output was written yet; the checkpoint at {percent:.0} % ({}) is kept: add --resume to continue",
        checkpoint.display()
    )]
    Interrupted { checkpoint: PathBuf, percent: f64 },
    #[error(
        "{}: found a checkpoint at {percent:.0} % ({}); add --resume to continue, or --restart to start over",
        output.display(), checkpoint.display()
    )]
    CheckpointFound {
        output: PathBuf,
        checkpoint: PathBuf,
        percent: f64,
    },
    /// A run of this output was killed after its output was complete (`checkpoint::Finished`).
    #[error(
        "{}: a run of this job wrote it but was stopped before its last steps (its checkpoint {} records that); add --resume to finish it without computing anything again, or --restart to start over",
        output.display(), checkpoint.display()
    )]
    FinishedFound {
        output: PathBuf,
        checkpoint: PathBuf,
    },
    #[error("{}: {reason}; run with --restart to start over", path.display())]
    Checkpoint { path: PathBuf, reason: String },
    /// The checkpoint file could not be read or removed (permissions, a failing disk): not a
    /// checkpoint to throw away with `--restart`, which removes it too, but the file to fix.
    #[error(
        "{}: cannot {what} the checkpoint: {source}; check that file's folder and disk, then run again",
        path.display()
    )]
    CheckpointIo {
        path: PathBuf,
        what: &'static str,
        source: std::io::Error,
    },
    /// Saving a checkpoint failed (a full disk): the run stops, and the checkpoint saved before
    /// it, if any, is left as it was, so the fix is to resume, not to start over.
    #[error(
        "{}: cannot write the checkpoint: {source}; {}, then run with --resume ({})",
        path.display(),
        write_fix(source),
        kept.map_or_else(
            || "no checkpoint was saved before: it starts from the beginning".to_string(),
            |(done, total)| format!("the checkpoint of slab {done} of {total} is kept")
        )
    )]
    CheckpointWrite {
        path: PathBuf,
        #[source]
        source: std::io::Error,
        /// The slabs done and in all of the checkpoint saved before, if there is one.
        kept: Option<(u64, u64)>,
    },
    #[error("{}: {what}; run with --restart instead of --resume to start over", path.display())]
    ResumeMismatch { path: PathBuf, what: String },
    #[error(
        "{input}: the input changed since the checkpoint ({what}); run with --restart instead of --resume to start over"
    )]
    InputChanged { input: String, what: String },
    #[error("internal error in the {stage} stage: {reason}; please report it with the job file")]
    Internal { stage: &'static str, reason: String },
}

/// What to do about a checkpoint that could not be written.
fn write_fix(e: &std::io::Error) -> &'static str {
    use std::io::ErrorKind;
    match e.kind() {
        ErrorKind::StorageFull | ErrorKind::QuotaExceeded | ErrorKind::FileTooLarge => {
            "free space on that disk"
        }
        _ => "fix that",
    }
}
