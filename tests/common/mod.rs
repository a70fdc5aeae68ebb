//! Shared helpers for the integration tests: generated volumes written as raw files, job files,
//! and the reference in-memory marching cubes.
#![allow(dead_code)] // each test binary uses a different subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::AtomicBool;

use isostream_meshcheck::Report;
use isostream_pipeline::{JobConfig, RunSummary};
use isostream_volume::{Grid, MemoryVolume};

/// A volume generated in a test, with the iso value to extract.
#[derive(Debug, Clone)]
pub struct TestVolume {
    pub dims: [u64; 3],
    pub data: Vec<f32>,
    pub iso: f32,
}

impl TestVolume {
    /// Writes the volume as a raw little-endian f32 file and a job file next to it.
    pub fn job(&self, dir: &Path, simplify: &str, output: &str) -> PathBuf {
        let raw = dir.join("volume.raw");
        let bytes: Vec<u8> = self.data.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&raw, bytes).unwrap();
        let job = dir.join("job.toml");
        let text = format!(
            "[input]\npath = \"volume.raw\"\ndims = [{}, {}, {}]\ndtype = \"f32\"\n\n[extract]\niso = {}\n\n[simplify]\n{simplify}\n\n[output]\npath = \"{output}\"\nallow_empty = true\n\n[pipeline]\nchannel_capacity = 2\nbatch_triangles = 64\n",
            self.dims[0], self.dims[1], self.dims[2], self.iso
        );
        std::fs::write(&job, text).unwrap();
        job
    }

    /// The reference: plain in-memory marching cubes of the same volume.
    pub fn reference(&self) -> Mesh {
        let grid = Grid::new(self.dims, [1.0; 3], [0.0; 3]).unwrap();
        let mut vol = MemoryVolume::new(grid, self.data.clone()).unwrap();
        let s = isostream_extract::extract_indexed(&mut vol, self.iso).unwrap();
        Mesh {
            positions: s.positions.iter().map(|p| p.to_array()).collect(),
            triangles: s.triangles,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Mesh {
    pub positions: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    pub fn read(path: &Path) -> Mesh {
        let m = isostream_smesh::read_indexed(path).unwrap();
        Mesh {
            positions: m.positions,
            triangles: m.triangles,
        }
    }

    pub fn check(&self) -> Report {
        isostream_meshcheck::check(&self.positions, &self.triangles)
    }

    /// The signed volume the triangles enclose: positive when they face out.
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [p, q, r] = t.map(|i| self.positions[i as usize]);
                p[0] * (q[1] * r[2] - q[2] * r[1]) - p[1] * (q[0] * r[2] - q[2] * r[0])
                    + p[2] * (q[0] * r[1] - q[1] * r[0])
            })
            .sum::<f64>()
            / 6.0
    }

    /// Vertices on boundary edges (edges of one triangle) that lie on no face of the box of
    /// a volume of `dims` voxels (origin 0, spacing 1): an iso-surface's boundary is its cut by
    /// the box, and simplification may shorten the cut but never move it off the box.
    pub fn boundary_off_the_box(&self, dims: [u64; 3]) -> usize {
        let mut uses = std::collections::HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *uses.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        let mut ends: Vec<u32> = uses
            .into_iter()
            .filter(|&(_, n)| n == 1)
            .flat_map(|((a, b), _)| [a, b])
            .collect();
        ends.sort_unstable();
        ends.dedup();
        let on_face = |p: [f64; 3]| (0..3).any(|i| p[i] == 0.0 || p[i] == (dims[i] - 1) as f64);
        ends.iter()
            .filter(|&&v| !on_face(self.positions[v as usize]))
            .count()
    }

    /// Triangles crossing another triangle of the mesh (the referee's count).
    pub fn self_intersections(&self) -> usize {
        isostream_meshcheck::self_intersections(&self.positions, &self.triangles)
    }

    /// Triangles as position triples (f32 bits), rotated so the smallest comes first
    /// (orientation kept), sorted: comparable across meshes whose vertex numbering differs.
    pub fn canonical_triangles(&self) -> Vec<[[u32; 3]; 3]> {
        let mut out: Vec<[[u32; 3]; 3]> = self
            .triangles
            .iter()
            .map(|t| {
                let p = t.map(|i| self.positions[i as usize].map(|c| (c as f32).to_bits()));
                let k = (0..3).min_by_key(|&i| p[i]).unwrap();
                [p[k], p[(k + 1) % 3], p[(k + 2) % 3]]
            })
            .collect();
        out.sort_unstable();
        out
    }
}

/// A real volume from `../shared/data` (`rel` inside it), or `None` with a note when that folder
/// is not beside the checkout: tests on real data are skipped there.
pub fn shared_volume(rel: &str) -> Option<PathBuf> {
    let volume = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")).join(rel);
    if volume.exists() {
        Some(volume)
    } else {
        eprintln!("skipped: {} is not here", volume.display());
        None
    }
}

/// Runs a job file through the library (the same path as `isostream run`).
pub fn run_job(job: &Path) -> RunSummary {
    let config = JobConfig::load(job).unwrap();
    let cancel = AtomicBool::new(false);
    isostream_pipeline::run(&config, job, &cancel, &|_| {}).unwrap()
}

/// Deterministic pseudo-random numbers for building fields (splitmix64).
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Random integer field: iso values that fall exactly on grid values are common.
pub fn random_levels(dims: [u64; 3], levels: u32, iso: f32, seed: u64) -> TestVolume {
    let mut rng = Rng(seed);
    let n = (dims[0] * dims[1] * dims[2]) as usize;
    let data = (0..n)
        .map(|_| (rng.next_u64() % u64::from(levels)) as f32)
        .collect();
    TestVolume { dims, data, iso }
}

/// Uniform noise smoothed by three box filters of width 3 along each axis (close to a Gaussian
/// of sigma 1.4), scaled to unit deviation, with its surface at `iso` deviations: many small
/// closed components, blobs and cavities of a few dozen faces each.
pub fn smoothed_noise(n: u64, iso: f32, seed: u64) -> TestVolume {
    let mut rng = Rng(seed);
    let len = (n * n * n) as usize;
    let mut data: Vec<f64> = (0..len).map(|_| rng.unit() - 0.5).collect();
    let stride = [1, n as usize, (n * n) as usize];
    for _ in 0..3 {
        for s in stride {
            let prev = data.clone();
            for (i, v) in data.iter_mut().enumerate() {
                let at = (i / s) % n as usize;
                let lo = if at > 0 { prev[i - s] } else { prev[i] };
                let hi = if at + 1 < n as usize {
                    prev[i + s]
                } else {
                    prev[i]
                };
                *v = (lo + prev[i] + hi) / 3.0;
            }
        }
    }
    let deviation = (data.iter().map(|v| v * v).sum::<f64>() / len as f64).sqrt();
    TestVolume {
        dims: [n; 3],
        data: data.iter().map(|v| (v / deviation) as f32).collect(),
        iso,
    }
}

/// A smooth field: sum of random Gaussian blobs, so surfaces are closed or touch the box.
pub fn random_blobs(dims: [u64; 3], blobs: usize, seed: u64) -> TestVolume {
    let mut rng = Rng(seed);
    let centres: Vec<([f64; 3], f64)> = (0..blobs)
        .map(|_| {
            let c = [0, 1, 2].map(|i| (0.2 + 0.6 * rng.unit()) * (dims[i] - 1) as f64);
            let r = (0.12 + 0.15 * rng.unit()) * dims.iter().copied().min().unwrap() as f64;
            (c, r)
        })
        .collect();
    let mut data = Vec::with_capacity((dims[0] * dims[1] * dims[2]) as usize);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = [x as f64, y as f64, z as f64];
                let v: f64 = centres
                    .iter()
                    .map(|(c, r)| {
                        let d2: f64 = (0..3).map(|i| (p[i] - c[i]).powi(2)).sum();
                        (-d2 / (r * r)).exp()
                    })
                    .sum();
                data.push(v as f32);
            }
        }
    }
    TestVolume {
        dims,
        data,
        iso: 0.5,
    }
}

/// Runs the `isostream` binary with quiet logs and returns what it printed.
pub fn isostream(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_isostream"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap()
}

/// What a child process printed on stderr.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The error is one line starting with `error:`, the exit code is `code`, and the line holds
/// every needle (any of its `|`-separated alternatives).
pub fn assert_one_line_error(o: &Output, code: i32, needles: &[&str]) {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(code), "stderr: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "stderr: {err}");
    for n in needles {
        assert!(
            n.split('|').any(|alt| lines[0].contains(alt)),
            "{n:?} missing from: {}",
            lines[0]
        );
    }
}
