//! Measures the streaming extractor's speed on procedural fields (no I/O, no detector):
//! `cargo run --release -p isostream-extract --example extract_throughput [n] [sphere|gyroid]`.
//!
//! Two fields bracket the real cases: a sphere (few active cubes, the empty-cube skip
//! dominates) and a gyroid (dense surface, vertex placement dominates).

use std::time::Instant;

use isostream_extract::Extractor;
use isostream_volume::Grid;

fn main() {
    let n: u64 = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("n is a voxel count per axis"))
        .unwrap_or(256);
    let only = std::env::args().nth(2);
    let grid = Grid::new([n; 3], [1.0; 3], [0.0; 3]).expect("valid grid");
    let fields: [(&str, Field); 2] = [("sphere", sphere), ("gyroid", gyroid)];
    for (name, f) in fields {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let slice = |z: u64| -> Vec<f32> {
            (0..n * n)
                .map(|i| f([(i % n) as f64, (i / n) as f64, z as f64], n as f64) as f32)
                .collect()
        };
        let slices: Vec<Vec<f32>> = (0..n).map(slice).collect();
        let mut extractor = Extractor::new(grid, 0.0);
        let start = Instant::now();
        let mut batches = 0u64;
        for z in 0..n - 1 {
            let (lower, upper) = (&slices[z as usize], &slices[z as usize + 1]);
            extractor
                .extract_slab(z, lower, upper, 65_536, |_| {
                    batches += 1;
                    Ok::<_, ()>(())
                })
                .expect("the sink never fails");
        }
        let secs = start.elapsed().as_secs_f64();
        let stats = extractor.stats();
        println!(
            "{name:>6} {n}^3: {:.1} Mvoxel/s, {:.1} M triangles/s ({} triangles, {} active cubes, {batches} batches, {secs:.3} s)",
            stats.cubes as f64 / secs / 1e6,
            stats.triangles as f64 / secs / 1e6,
            stats.triangles,
            stats.active_cubes,
        );
    }
}

/// A scalar field sampled at voxel coordinates of an n^3 grid.
type Field = fn([f64; 3], f64) -> f64;

/// A ball of radius 0.4 n centred in the grid, values decreasing outwards.
fn sphere(p: [f64; 3], n: f64) -> f64 {
    let c = n / 2.0;
    0.8 * c - ((p[0] - c).powi(2) + (p[1] - c).powi(2) + (p[2] - c).powi(2)).sqrt()
}

/// A gyroid with a period of about 21 voxels: a dense surface full of saddles.
fn gyroid(p: [f64; 3], _n: f64) -> f64 {
    let [x, y, z] = p.map(|v| v * 0.3);
    x.sin() * y.cos() + y.sin() * z.cos() + z.sin() * x.cos()
}
