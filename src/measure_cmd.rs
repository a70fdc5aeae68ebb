//! `measure`: quality of an output mesh, and with `--volume` its distances to the
//! full-resolution surface of that job's volume (regenerated as a stream).

use std::path::Path;
use std::sync::atomic::AtomicBool;

use anyhow::Context;
use isostream_measure::{
    Distances, FirstPass, FullSurfaceDistances, MAX_SAMPLES, MIN_SAMPLES, MeasureOptions,
    MeasureReport, MeshQuality, mesh_quality,
};
use isostream_pipeline::{
    JobConfig, LogConfig, MeasureHalves, open_source, summary_path, visit_surface,
};

pub fn measure(
    job_path: Option<&Path>,
    mesh_path: &Path,
    json: bool,
    samples_per_area: Option<f64>,
    seed: Option<u64>,
) -> anyhow::Result<()> {
    // Warnings only unless RUST_LOG asks for more: the report is the answer, and the
    // extraction `--volume` borrows logs its own progress at info.
    crate::logging::init(
        &LogConfig {
            level: Some("warn".into()),
            ..LogConfig::default()
        },
        None,
    );
    let mut mesh = isostream_smesh::read_indexed(mesh_path)?;
    let quality = mesh_quality(&mesh.positions, &mesh.triangles);
    let run = run_summary(mesh_path).filter(|run| describes(run, mesh_path, &quality));
    let defaults = MeasureOptions::default();
    let opts = MeasureOptions {
        samples_per_area: samples_per_area.unwrap_or(defaults.samples_per_area),
        seed: seed.unwrap_or(defaults.seed),
        ..defaults
    };
    let distances = match job_path {
        None => None,
        Some(job_path) => {
            let job = JobConfig::load(job_path)?;
            let source = open_source(&job.input)?;
            if let Some(run) = &run {
                let read = Made {
                    input: source.describe(),
                    dims: source.grid().dims,
                    iso: job.extract.iso,
                };
                check_made_by(run, &read).map_err(|made| OtherJob {
                    mesh: mesh_path.display().to_string(),
                    made,
                    job: job_path.display().to_string(),
                    read,
                })?;
            }
            // The volume is extracted in the coordinates its axis flips are undone from
            // (`isostream_pipeline::Mirror`): the mesh is taken there too, for the distances and
            // the attributes (a reflection changes neither).
            let mirror = isostream_pipeline::Mirror::of(source.as_ref());
            for p in &mut mesh.positions {
                *p = mirror.position(*p);
            }
            let context = || format!("measuring {}", mesh_path.display());
            let halves = MeasureHalves {
                threads: job.pipeline.threads() > 1,
            };
            let mut full =
                FullSurfaceDistances::new(source.grid(), &mesh.positions, &mesh.triangles, &opts)
                    .with_context(context)?
                    .with_halves(Box::new(halves));
            // The run's own extraction (parallel, empty space skipped): the full-resolution
            // surface of a large job has far more faces than fit in memory, and streaming it
            // on one thread through every voxel was most of the time.
            let never = AtomicBool::new(false);
            visit_surface(&job, source, &never, |batch| full.add(batch)).with_context(context)?;
            let distances = match full.finish().with_context(context)? {
                FirstPass::Done(distances) => distances,
                // Output samples with nothing within the first pass's search radius: the
                // surface once more, for them alone.
                FirstPass::Again(mut again) => {
                    tracing::info!(
                        "{} output samples have no full-resolution point within the search radius: measuring them in a second pass",
                        again.far_samples()
                    );
                    let source = open_source(&job.input)?;
                    visit_surface(&job, source, &never, |batch| again.add(batch))
                        .with_context(context)?;
                    again.finish()
                }
            };
            if let Some(asked) = samples_per_area {
                density_note(asked, &distances);
            }
            Some(distances)
        }
    };
    let attributes = match job_path {
        Some(job_path) if !mesh.attribute_names.is_empty() => {
            attribute_report(job_path, &mesh, &opts)?
        }
        _ => Vec::new(),
    };
    let report = MeasureReport {
        quality,
        distances,
        // The shape error `max eps0` is only known to the run that simplified; it is in the
        // run summary when that run bounded it (mode = "error").
        shape_error: run.as_ref().and_then(|r| r.get("shape_error")?.as_f64()),
        attributes,
    };
    if json {
        crate::stdout::line(serde_json::to_string_pretty(&report)?)?;
    } else {
        crate::stdout::text_as_is(report.to_text())?;
    }
    Ok(())
}

/// The run summary `isostream run` wrote next to `mesh`, when there is one.
fn run_summary(mesh: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(summary_path(mesh)).ok()?;
    serde_json::from_str(&text).ok()
}

/// Whether the run summary next to `mesh` is that of the mesh read, by its face and vertex
/// counts; if not, says so in one warning. A conversion onto a run's output (`isostream convert
/// other.glb s.smb`) leaves the run's summary beside another mesh: its shape error was reported
/// for that mesh, and `--volume` took the summary as proof of which job made it.
fn describes(run: &serde_json::Value, mesh: &Path, quality: &MeshQuality) -> bool {
    let count = |key: &str| run.get(key).and_then(serde_json::Value::as_u64);
    let faces_differ = count("faces_written").is_some_and(|f| f != quality.triangles as u64);
    let vertices_differ = count("vertices_written").is_some_and(|v| v != quality.vertices as u64);
    if faces_differ || vertices_differ {
        tracing::warn!(
            "{} describes another mesh ({} faces, {} vertices written) than {} ({} triangles, {} vertices): ignored (no shape error, and it does not say which job made the mesh)",
            summary_path(mesh).display(),
            count("faces_written").map_or("?".into(), |f| f.to_string()),
            count("vertices_written").map_or("?".into(), |v| v.to_string()),
            mesh.display(),
            quality.triangles,
            quality.vertices
        );
        return false;
    }
    true
}

/// Says when `--samples-per-area` was not the density used: it is raised or lowered so that the
/// mesh's area gets about [`MIN_SAMPLES`] to [`MAX_SAMPLES`] samples, which was silent. Each
/// triangle's share is drawn at random around its expected count, and the full-resolution
/// surface is sampled at the same density over its own area: the message says so, with the count
/// drawn ("at least 10000 samples" was said of 9,960).
fn density_note(asked: f64, distances: &Distances) {
    let used = distances.samples_per_area;
    if (used - asked).abs() <= 1e-9 * asked {
        return;
    }
    let (how, count) = if used > asked {
        ("raised", MIN_SAMPLES)
    } else {
        ("lowered", MAX_SAMPLES)
    };
    tracing::warn!(
        "--samples-per-area {asked} {how} to {used:.4} so that this mesh's area gets about {count} samples ({} drawn; the full-resolution surface is sampled at the same density)",
        distances.output_to_full.samples
    );
}

/// What a surface is made from: the input as the run names it, its dims (after upsampling)
/// and the iso value.
#[derive(Debug)]
pub struct Made {
    input: String,
    dims: [u64; 3],
    iso: f64,
}

impl std::fmt::Display for Made {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.dims;
        write!(f, "{} ({x}x{y}x{z}) at iso {}", self.input, self.iso)
    }
}

/// `--volume` names a job whose surface is not the one the mesh was made from (by the mesh's
/// run summary): every distance would be measured to another surface. Bonsai's output
/// measured against engine's job reported a Hausdorff distance of 18.9 % of the diagonal and
/// no error.
#[derive(Debug)]
pub struct OtherJob {
    mesh: String,
    made: Made,
    job: String,
    read: Made,
}

impl std::fmt::Display for OtherJob {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} was made from {} (its run summary), but {} reads {}; measure it against the job that made it",
            self.mesh, self.made, self.job, self.read
        )
    }
}

impl std::error::Error for OtherJob {}

/// The run summary's input, dims and iso against the job's (`read`): the inputs compared by
/// file name, since a job file and the service's copy of it name one file by different paths.
fn check_made_by(run: &serde_json::Value, read: &Made) -> Result<(), Made> {
    let (Some(input), Some(iso)) = (run["input"].as_str(), run["iso"].as_f64()) else {
        return Ok(());
    };
    let dims: Option<Vec<u64>> = run["dims"]
        .as_array()
        .map(|d| d.iter().filter_map(serde_json::Value::as_u64).collect());
    let Some(Ok(dims)) = dims.map(<[u64; 3]>::try_from) else {
        return Ok(());
    };
    let made = Made {
        input: input.to_owned(),
        dims,
        iso,
    };
    let name = |s: &str| Path::new(s).file_name().map(|n| n.to_owned());
    if name(&made.input) == name(&read.input) && made.dims == read.dims && made.iso == read.iso {
        Ok(())
    } else {
        Err(made)
    }
}

/// Attribute errors against the job's full-resolution surface, for the attributes the mesh and
/// the job's `[[attributes]]` share by name (matched in the job's order).
fn attribute_report(
    job_path: &Path,
    mesh: &isostream_smesh::IndexedMesh,
    opts: &MeasureOptions,
) -> anyhow::Result<Vec<isostream_measure::AttributeError>> {
    let job = JobConfig::load(job_path)?;
    let names: Vec<String> = job.attributes.iter().map(|a| a.name.clone()).collect();
    let k = mesh.attribute_names.len();
    let column: Vec<usize> = names
        .iter()
        .map(|n| {
            mesh.attribute_names
                .iter()
                .position(|m| m == n)
                .with_context(|| format!("the mesh has no attribute `{n}` named in the job"))
        })
        .collect::<anyhow::Result<_>>()?;
    let attrs: Vec<f32> = mesh
        .attrs
        .chunks(k.max(1))
        .flat_map(|a| column.iter().map(move |&c| a[c]))
        .collect();
    let mut reader = isostream_pipeline::SliceReader::open(&job)?;
    Ok(isostream_measure::attribute_errors(
        reader.grid(),
        job.extract.iso as f32,
        &names,
        || {
            reader
                .next_slices()
                .map(|s| s.map(|s| (s.iso, s.attrs)))
                .map_err(|e| isostream_measure::MeasureError::Slices(e.to_string()))
        },
        &mesh.positions,
        &mesh.triangles,
        &attrs,
        opts,
    )?)
}
