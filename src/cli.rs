//! Command-line interface (clap derive).

use std::path::PathBuf;

use clap::{Parser, Subcommand};

/// Streaming iso-surface extraction and simplification for huge volumes.
#[derive(Debug, Parser)]
#[command(name = "isostream", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the job described by a TOML file and write its mesh.
    Run {
        /// The job file (see config/README.md).
        job: PathBuf,
        /// No progress bar even on a terminal.
        #[arg(long)]
        quiet: bool,
        /// Remove temporary files an interrupted run or conversion of the same output left next
        /// to it (`.NAME.XXXXXX.tmp`); without it they are only reported.
        #[arg(long)]
        clean_stale: bool,
        /// Continue from the checkpoint an interrupted run of this job left (after checking that
        /// the job and the input did not change); without a checkpoint, start from the beginning.
        #[arg(long, conflicts_with = "restart")]
        resume: bool,
        /// Throw away the checkpoint an interrupted run left and start from the beginning.
        #[arg(long)]
        restart: bool,
    },
    /// Check a job file (keys, values, input file, output folder) without running it.
    Validate { job: PathBuf },
    /// Convert a mesh between SMB, SMA, PLY, OBJ, STL and GLB (streaming for SMB/SMA inputs).
    Convert {
        input: PathBuf,
        output: PathBuf,
        /// Print the counts as JSON instead of a sentence.
        #[arg(long)]
        json: bool,
        /// Remove temporary files an interrupted run or conversion of the same output left next
        /// to it (`.NAME.XXXXXX.tmp`); without it they are only reported.
        #[arg(long)]
        clean_stale: bool,
        /// A PLY output in ASCII instead of binary little-endian.
        #[arg(long)]
        ascii: bool,
        /// A GLB output with area-weighted per-vertex normals (smooth shading; without them
        /// viewers shade each triangle flat).
        #[arg(long)]
        normals: bool,
    },
    /// Check a streaming mesh file: indices, finalization, header counts, finite coordinates,
    /// stream width.
    Check {
        mesh: PathBuf,
        /// Print the report as JSON instead of a sentence (`"valid": false` and the error for an
        /// invalid file, which still exits with status 2).
        #[arg(long)]
        json: bool,
    },
    /// Measure a mesh: topology, triangle quality, anisotropy, directional bias, and with
    /// `--volume` the mean/RMS/Hausdorff distances to the full-resolution surface (and the
    /// distance 99.9 % of the samples are within).
    Measure {
        /// The job file whose volume and iso value define the full-resolution surface.
        #[arg(long)]
        volume: Option<PathBuf>,
        /// The mesh to measure (.smb, .sma, .ply, .obj, .stl, .glb).
        mesh: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Surface samples per unit area (physical units squared) for the distances: a positive
        /// finite number, raised or lowered (with a warning) so that each direction gets between
        /// 10,000 and 4,000,000 samples.
        #[arg(long, requires = "volume", value_parser = positive_finite)]
        samples_per_area: Option<f64>,
        /// Random seed for the distances' sample positions (a fixed default keeps reports
        /// repeatable).
        #[arg(long, requires = "volume")]
        seed: Option<u64>,
    },
    /// Make one self-contained HTML page with plots of a run: memory over the sweep, faces per
    /// slab, stage busy time, and with `--measure` the min-angle and distance histograms.
    Report {
        /// The run summary a run wrote next to its output (`<output>.run.json`).
        run: PathBuf,
        /// Where to write the page.
        #[arg(short, long, value_name = "HTML")]
        output: PathBuf,
        /// The JSON of `isostream measure --json` for the same output.
        #[arg(long, value_name = "JSON")]
        measure: Option<PathBuf>,
    },
    /// Run a durable queue of jobs, submitted and watched over HTTP (see docs/service.md).
    Serve(crate::serve_cmd::ServeArgs),
}

/// `--samples-per-area`: refused by clap as a usage error (exit 2, naming the flag) rather than
/// by the measure, whose message named its internal field and exited 1.
fn positive_finite(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(
            "expected a positive finite number of samples per unit^2 (greater than 0, e.g. 10)"
                .into(),
        ),
    }
}

impl Command {
    pub fn execute(self) -> anyhow::Result<()> {
        match self {
            Command::Run {
                job,
                quiet,
                clean_stale,
                resume,
                restart,
            } => {
                let start = match (resume, restart) {
                    (true, _) => isostream_pipeline::Start::Resume,
                    (_, true) => isostream_pipeline::Start::Restart,
                    _ => isostream_pipeline::Start::Fresh,
                };
                crate::run_cmd::run(&job, quiet, clean_stale, start)
            }
            Command::Validate { job } => crate::run_cmd::validate(&job),
            Command::Convert {
                input,
                output,
                json,
                clean_stale,
                ascii,
                normals,
            } => {
                let options = crate::run_cmd::convert_options(&output, ascii, normals)?;
                crate::run_cmd::convert(&input, &output, &options, json, clean_stale)
            }
            Command::Check { mesh, json } => crate::run_cmd::check(&mesh, json),
            Command::Measure {
                volume,
                mesh,
                json,
                samples_per_area,
                seed,
            } => {
                crate::measure_cmd::measure(volume.as_deref(), &mesh, json, samples_per_area, seed)
            }
            Command::Report {
                run,
                output,
                measure,
            } => crate::run_cmd::report_page(&run, &output, measure.as_deref()),
            Command::Serve(args) => crate::serve_cmd::serve(args),
        }
    }
}

/// A command line asking for what cannot be done (a flag the output has no use for): exit 2,
/// like clap's own usage errors.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);
