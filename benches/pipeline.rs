//! Criterion benches of the three hot paths, on procedural volumes (no data files):
//!
//! * `extract/gyroid128`: `Extractor::extract_slab` over a 128^3 gyroid whose slices are computed
//!   before timing (throughput in extracted triangles);
//! * `simplify/gyroid64_rate0.2`: `Simplifier` fed with the extractor + detector output of a 64^3
//!   gyroid (117k triangles), recorded before timing, Hou and Chen's rate policy at R = 0.2
//!   (throughput in input triangles; 64^3 keeps 10 samples near 10 s at ~100k faces/s);
//! * `simplify/bonsai_rate0.2`: the same on the delta stream of bonsai (1.1 M faces, from
//!   `../shared/data`, iso 40), the reference surface; only when the file is present and
//!   only when benchmarking (`cargo test` runs each bench once, and this one takes seconds);
//! * `pipeline/sphere128_rate0.1`: a whole `isostream_pipeline::run` (five threads, SMB written to
//!   a temporary folder) on a 128^3 procedural sphere.
//!
//! Run: `cargo bench --bench pipeline` (about 40 s in all; add `-- extract` to pick one group).
//! Sample counts are small on purpose: the machine is shared, read medians and their spread.

use std::hint::black_box;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use isostream_detect::{Detector, MeshDelta};
use isostream_extract::{CubeBatch, Extractor};
use isostream_pipeline::JobConfig;
use isostream_simplify::{OutBatch, Policy, Simplifier, SimplifyConfig, Sweep};
use isostream_volume::{Grid, Procedural, Shape, VolumeSource};

const N: u64 = 128;
/// The simplifier is ~50x slower per face than extraction: a smaller gyroid keeps the bench short.
const N_SIMPLIFY: u64 = 64;
const BATCH_TRIANGLES: usize = 8192;

/// All slices of a procedural volume, computed once.
fn slices(shape: Shape, n: u64) -> (Grid, Vec<Vec<f32>>) {
    let mut source = Procedural::new(shape, [n; 3], [1.0; 3], [0.0; 3]).unwrap();
    let grid = source.grid();
    let slices = (0..n)
        .map(|z| {
            let mut s = vec![0.0f32; grid.slice_len()];
            source.read_slice(z, &mut s).unwrap();
            s
        })
        .collect();
    (grid, slices)
}

/// Runs the extractor over every slab, handing each batch to `sink`; returns the triangle count.
fn extract_all(grid: Grid, slices: &[Vec<f32>], iso: f32, mut sink: impl FnMut(CubeBatch)) -> u64 {
    let mut extractor = Extractor::new(grid, iso);
    let mut triangles = 0u64;
    for z in 0..slices.len() - 1 {
        extractor
            .extract_slab(
                z as u64,
                &slices[z],
                &slices[z + 1],
                BATCH_TRIANGLES,
                |batch| {
                    triangles += batch.triangle_count() as u64;
                    sink(batch);
                    Ok::<_, ()>(())
                },
            )
            .unwrap();
    }
    triangles
}

fn extraction(c: &mut Criterion) {
    let (grid, slices) = slices(Shape::Gyroid, N);
    let triangles = extract_all(grid, &slices, 0.0, |_| {});
    let mut group = c.benchmark_group("extract");
    group.throughput(Throughput::Elements(triangles));
    group.bench_function("gyroid128", |b| {
        b.iter(|| {
            black_box(extract_all(grid, &slices, 0.0, |batch| {
                drop(black_box(batch))
            }))
        })
    });
    group.finish();
}

/// The detector's output over a whole volume, recorded once, and its triangle count.
fn delta_stream(grid: Grid, slices: &[Vec<f32>], iso: f32) -> (Vec<MeshDelta>, u64) {
    let mut detector = Detector::new(grid.dims);
    let mut deltas = Vec::new();
    let triangles = extract_all(grid, slices, iso, |batch| {
        let mut delta = MeshDelta::default();
        detector.process(&batch, &mut delta);
        deltas.push(delta);
    });
    if let Some(last) = deltas.last_mut() {
        detector.finish(last);
    }
    (deltas, triangles)
}

/// Feeds a recorded delta stream through a fresh simplifier at rate 0.2.
fn simplify_stream(grid: Grid, deltas: &[MeshDelta]) -> isostream_simplify::SimplifyStats {
    let config = SimplifyConfig {
        sweep: Some(Sweep {
            direction: glam::DVec3::Z,
            origin: grid.origin[2],
            spacing: grid.spacing[2],
            rows: None,
        }),
        ..SimplifyConfig::new(Policy::Rate {
            rate: 0.2,
            batch: 10_000,
            initial_rate: 0.5,
        })
    };
    let mut simplifier = Simplifier::new(config).unwrap();
    let mut out = OutBatch::default();
    for (i, delta) in deltas.iter().enumerate() {
        for v in &delta.vertices {
            simplifier.add_vertex(v.id, v.pos, v.rank, &[]);
        }
        for &t in &delta.triangles {
            simplifier.add_triangle(t);
        }
        for &id in &delta.modifiable {
            simplifier.set_modifiable(id);
        }
        if i + 1 == deltas.len() {
            simplifier.finish(&mut out);
        } else {
            simplifier.end_batch(delta.front, &mut out);
        }
        out.elements.clear();
        out.attrs.clear();
    }
    simplifier.stats()
}

fn simplification(c: &mut Criterion) {
    let (grid, slices) = slices(Shape::Gyroid, N_SIMPLIFY);
    let (deltas, triangles) = delta_stream(grid, &slices, 0.0);
    drop(slices);
    let mut group = c.benchmark_group("simplify");
    group.throughput(Throughput::Elements(triangles));
    group.bench_function("gyroid64_rate0.2", |b| {
        b.iter(|| black_box(simplify_stream(grid, &deltas)))
    });
    let bonsai = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/bonsai/bonsai.vti");
    let benchmarking = std::env::args().any(|a| a == "--bench");
    if benchmarking && bonsai.is_file() {
        let mut source =
            isostream_volume::open_path(&bonsai, &isostream_volume::OpenOptions::default())
                .unwrap();
        let grid = source.grid();
        let slices: Vec<Vec<f32>> = (0..grid.dims[2])
            .map(|z| {
                let mut s = vec![0.0f32; grid.slice_len()];
                source.read_slice(z, &mut s).unwrap();
                s
            })
            .collect();
        let (deltas, triangles) = delta_stream(grid, &slices, 40.0);
        drop(slices);
        group.throughput(Throughput::Elements(triangles));
        group.sample_size(10);
        group.bench_function("bonsai_rate0.2", |b| {
            b.iter(|| black_box(simplify_stream(grid, &deltas)))
        });
    }
    group.finish();
}

fn whole_run(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let job_path = dir.path().join("sphere.toml");
    std::fs::write(
        &job_path,
        format!(
            "[input]\nshape = \"sphere\"\nsize = [{N}, {N}, {N}]\n\n[extract]\niso = 0.0\n\n\
             [simplify]\nmode = \"rate\"\nrate = 0.1\n\n[output]\npath = \"sphere.smb\"\n\
             summary = false\n"
        ),
    )
    .unwrap();
    let job = JobConfig::load(&job_path).unwrap();
    let cancel = AtomicBool::new(false);
    let first = run(&job, &job_path, &cancel);
    let mut group = c.benchmark_group("pipeline");
    group.throughput(Throughput::Elements(first));
    group.bench_function("sphere128_rate0.1", |b| {
        b.iter(|| black_box(run(&job, &job_path, &cancel)))
    });
    group.finish();
}

/// One whole run; returns the extracted face count.
fn run(job: &JobConfig, job_path: &Path, cancel: &AtomicBool) -> u64 {
    isostream_pipeline::run(job, job_path, cancel, &|_| {})
        .unwrap()
        .faces_extracted
}

fn config() -> Criterion {
    Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5))
}

criterion_group! {
    name = benches;
    config = config();
    targets = extraction, simplification, whole_run
}
criterion_main!(benches);
