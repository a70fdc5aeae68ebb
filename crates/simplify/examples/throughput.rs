//! Throughput on a synthetic surface: `cargo run --release -p isostream-simplify --example
//! throughput [faces_millions] [policy] [retire_lag]` where policy is `rate`, `error`, `tandem`
//! or `none`.
//! Feeds a bumpy torus slab by slab (the same feeder as the tests) and prints faces/s.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Instant;

use common::{Sweep, config, param_grid, run};
use glam::DVec3;
use isostream_simplify::Policy;

fn main() {
    let mut args = std::env::args().skip(1);
    let millions: f64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(1.0);
    let policy = match args.next().as_deref() {
        Some("none") => Policy::None,
        Some("error") => Policy::Error {
            e0: 0.05,
            time_lag: false,
            isotropy: 0.0,
        },
        Some("tandem") => Policy::Error {
            e0: 0.05,
            time_lag: true,
            isotropy: 0.2,
        },
        _ => Policy::Rate {
            rate: 0.1,
            batch: 20_000,
            initial_rate: 0.5,
        },
    };
    let lag: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(4);
    // A torus standing along z (the sweep axis), with ripples so that quadrics are not flat;
    // about one grid unit per edge, like a marching-cubes surface.
    let minor = 128u32;
    let major = ((millions * 1e6) / (2.0 * f64::from(minor))).ceil() as u32;
    let big = f64::from(major) / std::f64::consts::TAU;
    let small = f64::from(minor) / std::f64::consts::TAU;
    let mesh = param_grid(major, minor, true, true, |u, v| {
        let (su, cu) = (std::f64::consts::TAU * u).sin_cos();
        let (sv, cv) = (std::f64::consts::TAU * v).sin_cos();
        let r = small + 0.8 * (40.0 * u).sin() * (9.0 * v).cos();
        DVec3::new((big + r * cv) * cu, r * sv, (big + r * cv) * su)
    });
    let faces = mesh.tris.len();
    let start = Instant::now();
    let result = run(&mesh, config(policy.clone(), lag), &Sweep::default());
    let secs = start.elapsed().as_secs_f64();
    let s = &result.stats;
    println!(
        "{policy:?}, lag {lag}: {faces} faces in, {} out, {:.2} s (including the test feeder and output \
         checks), {:.0} faces/s; peak resident {} faces, {} contractions, rejected link {} flip {}",
        s.faces_out,
        secs,
        faces as f64 / secs,
        s.peak_resident_faces,
        s.contractions,
        s.rejected_link,
        s.rejected_flip,
    );
}
