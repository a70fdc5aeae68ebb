//! `measure`: quality of an output mesh, and with `--volume` its distances to the
//! full-resolution surface of that job's volume (regenerated as a stream).

use std::path::Path;
use std::sync::atomic::AtomicBool;

use anyhow::Context;
use isostream_measure::{FullSurfaceDistances, MeasureOptions, MeasureReport, mesh_quality};
use isostream_pipeline::{JobConfig, MeasureHalves, open_source, summary_path, visit_surface};

pub fn measure(
    job_path: Option<&Path>,
    mesh_path: &Path,
    json: bool,
    samples_per_area: Option<f64>,
    seed: Option<u64>,
) -> anyhow::Result<()> {
    let mesh = isostream_smesh::read_indexed(mesh_path)?;
    let quality = mesh_quality(&mesh.positions, &mesh.triangles);
    let distances = match job_path {
        None => None,
        Some(job_path) => {
            let job = JobConfig::load(job_path)?;
            let source = open_source(&job.input)?;
            let defaults = MeasureOptions::default();
            let opts = MeasureOptions {
                samples_per_area: samples_per_area.unwrap_or(defaults.samples_per_area),
                seed: seed.unwrap_or(defaults.seed),
                ..defaults
            };
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
            Some(full.finish().with_context(context)?)
        }
    };
    let attributes = match job_path {
        Some(job_path) if !mesh.attribute_names.is_empty() => {
            attribute_report(job_path, &mesh, samples_per_area, seed)?
        }
        _ => Vec::new(),
    };
    let report = MeasureReport {
        quality,
        distances,
        shape_error: shape_error_from_run(mesh_path),
        attributes,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.to_text());
    }
    Ok(())
}

/// The shape error `max eps0` is only known to the run that simplified; it is in the run
/// summary next to the mesh when that run bounded it (mode = "error").
fn shape_error_from_run(mesh: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(summary_path(mesh)).ok()?;
    let summary: serde_json::Value = serde_json::from_str(&text).ok()?;
    summary.get("shape_error")?.as_f64()
}

/// Attribute errors against the job's full-resolution surface, for the attributes the mesh and
/// the job's `[[attributes]]` share by name (matched in the job's order).
fn attribute_report(
    job_path: &Path,
    mesh: &isostream_smesh::IndexedMesh,
    samples_per_area: Option<f64>,
    seed: Option<u64>,
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
    let defaults = MeasureOptions::default();
    let opts = MeasureOptions {
        samples_per_area: samples_per_area.unwrap_or(defaults.samples_per_area),
        seed: seed.unwrap_or(defaults.seed),
        ..defaults
    };
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
        &opts,
    )?)
}
