//! The run report: one self-contained HTML page (no script, no external resource: the machines
//! it is read on may have no internet) with SVG plots drawn in Rust, from a run summary
//! (`<output>.run.json`) and optionally the JSON of `isostream measure --json`.
//!
//! Used by `isostream report` and by the service's `GET /jobs/{id}/report`.
#![deny(unsafe_code)]

mod page;
pub mod plots;

mod input;

use std::path::{Path, PathBuf};

pub use input::{Bins, Directed, Distances, Measure, Quality, Run};
pub use page::html;

/// Why a report could not be made. One line each, naming the file and what to give instead.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: not an isostream run summary ({reason}); give the `<output>.run.json` that `isostream run` wrote", path.display())]
    NotRun { path: PathBuf, reason: String },
    #[error("{}: not a measure report ({reason}); make one with `isostream measure --volume JOB.toml MESH --json > M.json`", path.display())]
    NotMeasure { path: PathBuf, reason: String },
    #[error("{}: measures a mesh of {triangles} triangles, but the run of {} wrote {faces_written}; give the measure of that run's output (`isostream measure --volume JOB.toml OUTPUT --json`)", measure.display(), run.display())]
    OtherMesh {
        measure: PathBuf,
        triangles: u64,
        run: PathBuf,
        faces_written: u64,
    },
    #[error("drawing the {plot} plot: {reason}")]
    Plot { plot: &'static str, reason: String },
    #[error("{}: cannot write the report: {reason}", path.display())]
    Write { path: PathBuf, reason: String },
    #[error("{}: the report would replace a file it is made from; choose another -o", path.display())]
    OverInput { path: PathBuf },
}

/// Writes the page under a temporary name in the same folder and renames it: a failure leaves
/// no half-written report under the final name. Its folder is created when missing, as
/// `isostream run` creates its output's.
pub fn write(path: &Path, html: &str) -> Result<(), ReportError> {
    let fail = |e: std::io::Error| ReportError::Write {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(fail)?;
    }
    isostream_pipeline::write_atomically(path, html.as_bytes()).map_err(fail)
}
