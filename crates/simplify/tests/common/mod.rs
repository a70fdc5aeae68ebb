//! Test meshes built in-test, a sweep feeder that plays the detector, and an output collector
//! that checks compact pre-order and finalization.
#![allow(dead_code)] // each test binary uses its own subset

use std::collections::HashMap;

use glam::DVec3;
use isostream_meshcheck::Report;
use isostream_simplify::{
    Front, OutBatch, OutElement, Policy, Simplifier, SimplifyConfig, SimplifyStats,
};

#[derive(Debug, Clone, Default)]
pub struct Mesh {
    pub pos: Vec<DVec3>,
    pub tris: Vec<[u32; 3]>,
}

impl Mesh {
    pub fn union(mut self, other: Mesh) -> Mesh {
        let n = self.pos.len() as u32;
        self.pos.extend(other.pos);
        self.tris
            .extend(other.tris.iter().map(|t| t.map(|i| i + n)));
        self
    }

    pub fn translated(mut self, d: DVec3) -> Mesh {
        for p in &mut self.pos {
            *p += d;
        }
        self.exact()
    }

    /// Positions rounded to `f32`, as the simplifier stores them (what every output format
    /// writes), so that comparisons of unmoved vertices are exact.
    pub fn exact(mut self) -> Mesh {
        for p in &mut self.pos {
            *p = p.as_vec3().as_dvec3();
        }
        self
    }

    /// The triangles as sorted position triples, each rotated to start at its smallest corner
    /// (orientation kept): equal for two meshes with the same oriented triangles, whatever the
    /// vertex numbering.
    pub fn oriented_triangles(&self) -> Vec<[[u64; 3]; 3]> {
        let key = |v: u32| self.pos[v as usize].to_array().map(f64::to_bits);
        let mut tris: Vec<[[u64; 3]; 3]> = self
            .tris
            .iter()
            .map(|t| {
                let k = t.map(key);
                let i = (0..3).min_by_key(|&i| k[i]).unwrap_or(0);
                [k[i], k[(i + 1) % 3], k[(i + 2) % 3]]
            })
            .collect();
        tris.sort_unstable();
        tris
    }

    pub fn check(&self) -> Report {
        let pos: Vec<[f64; 3]> = self.pos.iter().map(|p| p.to_array()).collect();
        isostream_meshcheck::check(&pos, &self.tris)
    }
}

/// A `nu x nv` quad grid over a parametrisation, optionally wrapping in u and/or v, two
/// consistently oriented triangles per quad.
pub fn param_grid(
    nu: u32,
    nv: u32,
    wrap_u: bool,
    wrap_v: bool,
    f: impl Fn(f64, f64) -> DVec3,
) -> Mesh {
    let cu = if wrap_u { nu } else { nu + 1 };
    let cv = if wrap_v { nv } else { nv + 1 };
    let mut m = Mesh::default();
    for j in 0..cv {
        for i in 0..cu {
            m.pos.push(f(
                f64::from(i) / f64::from(nu),
                f64::from(j) / f64::from(nv),
            ));
        }
    }
    let id = |i: u32, j: u32| (j % cv) * cu + (i % cu);
    for j in 0..nv {
        for i in 0..nu {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            m.tris.push([a, b, c]);
            m.tris.push([a, c, d]);
        }
    }
    m.exact()
}

pub fn torus(n_major: u32, n_minor: u32, big: f64, small: f64) -> Mesh {
    use std::f64::consts::TAU;
    param_grid(n_major, n_minor, true, true, |u, v| {
        let (su, cu) = (TAU * u).sin_cos();
        let (sv, cv) = (TAU * v).sin_cos();
        DVec3::new((big + small * cv) * cu, (big + small * cv) * su, small * sv)
    })
}

/// Open cylinder along z: two boundary circles.
pub fn tube(around: u32, along: u32, radius: f64, length: f64) -> Mesh {
    use std::f64::consts::TAU;
    param_grid(around, along, true, false, |u, v| {
        let (s, c) = (TAU * u).sin_cos();
        DVec3::new(radius * c, radius * s, length * v)
    })
}

/// Height field over the xz plane (spans many ranks along z), open with a rectangular boundary.
pub fn height_field(nx: u32, nz: u32, size: f64, h: impl Fn(f64, f64) -> f64) -> Mesh {
    param_grid(nx, nz, false, false, |u, v| {
        DVec3::new(size * u, h(u, v), size * v)
    })
}

/// Pseudo-random heights from a seed (SplitMix64), for random height-field grids.
pub fn random_heights(nx: u32, nz: u32, size: f64, amp: f64, seed: u64) -> Mesh {
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let hs: Vec<f64> = (0..(nx + 1) * (nz + 1)).map(|_| amp * next()).collect();
    height_field(nx, nz, size, |u, v| {
        let i = (u * f64::from(nx)).round() as u32;
        let j = (v * f64::from(nz)).round() as u32;
        hs[(j * (nx + 1) + i) as usize]
    })
}

pub fn tetrahedron(center: DVec3, size: f64) -> Mesh {
    let pos = [
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(1.0, -1.0, -1.0),
        DVec3::new(-1.0, 1.0, -1.0),
        DVec3::new(-1.0, -1.0, 1.0),
    ]
    .map(|p| (center + size * p).as_vec3().as_dvec3())
    .to_vec();
    Mesh {
        pos,
        tris: vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
    }
}

/// Octahedron subdivided `levels` times (each triangle into four), projected on a sphere:
/// `8 * 4^levels` triangles.
pub fn sphere(levels: u32, radius: f64, center: DVec3) -> Mesh {
    let mut pos = vec![
        DVec3::X,
        -DVec3::X,
        DVec3::Y,
        -DVec3::Y,
        DVec3::Z,
        -DVec3::Z,
    ];
    let mut tris: Vec<[u32; 3]> = Vec::new();
    for (x, y) in [(0, 2), (2, 1), (1, 3), (3, 0)] {
        tris.push([x, y, 4]);
        tris.push([y, x, 5]);
    }
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        for t in &tris {
            let mut m = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                m[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    pos.push((pos[a as usize] + pos[b as usize]).normalize());
                    pos.len() as u32 - 1
                });
            }
            next.extend([
                [t[0], m[0], m[2]],
                [m[0], t[1], m[1]],
                [m[2], m[1], t[2]],
                m,
            ]);
        }
        tris = next;
    }
    Mesh {
        pos: pos.into_iter().map(|p| center + radius * p).collect(),
        tris,
    }
    .exact()
}

/// How the mesh is fed: sweep axis and direction, slab thickness (rank = floor(coord / slab)),
/// and how many batches each slab is split into; with `rows` (a row's thickness along the next
/// axis), each slab's triangles come in the order of their farthest corner along that axis and
/// every batch closes with a front within the slab (`isostream_simplify::Front`).
#[derive(Debug, Clone)]
pub struct Sweep {
    pub axis: usize,
    pub reverse: bool,
    pub slab: f64,
    pub batches_per_slab: usize,
    pub rows: Option<f64>,
}

impl Default for Sweep {
    fn default() -> Self {
        Sweep {
            axis: 2,
            reverse: false,
            slab: 1.0,
            batches_per_slab: 1,
            rows: None,
        }
    }
}

pub fn config(policy: Policy, retire_lag: u32) -> SimplifyConfig {
    SimplifyConfig {
        retire_lag,
        ..SimplifyConfig::new(policy)
    }
}

pub fn rate(rate: f64, batch: u64) -> Policy {
    Policy::Rate {
        rate,
        batch,
        initial_rate: rate.max(0.5),
    }
}

/// The collected output of one run.
#[derive(Debug, Clone)]
pub struct Run {
    pub mesh: Mesh,
    pub attrs: Vec<f32>,
    pub stats: SimplifyStats,
    /// The raw output, for determinism checks.
    pub out: OutBatch,
    /// Statistics after each `end_batch`.
    pub trace: Vec<SimplifyStats>,
}

impl Run {
    pub fn check(&self) -> Report {
        self.mesh.check()
    }
}

/// Plays the detector: vertices sorted along the sweep get increasing ids, each triangle is added
/// in the slab of its highest vertex, a vertex becomes modifiable after the batch holding its
/// last triangle, and `end_batch(k)` follows every batch of slab `k`. Attribute 0 (if any) is the
/// vertex's z coordinate.
pub fn run(mesh: &Mesh, config: SimplifyConfig, sweep: &Sweep) -> Run {
    let attributes = config.attributes;
    feed(mesh, config, sweep, |p| {
        [p.z as f32].into_iter().take(attributes).collect()
    })
}

/// As [`run`], with the attributes `attr(position)` of each vertex (`config.attributes` of them).
/// The harness sets `config.sweep` to its slabs.
pub fn feed(
    mesh: &Mesh,
    config: SimplifyConfig,
    sweep: &Sweep,
    attr: impl Fn(DVec3) -> Vec<f32>,
) -> Run {
    feed_stages(mesh, config, None, sweep, attr)
}

/// As [`run`], through a cascade: `first` (a first stage) feeds `second` (a second stage)
/// batch by batch, as the pipeline's two simplify threads do. The statistics are the second
/// stage's, with the faces and vertices in of the first.
pub fn run_cascade(
    mesh: &Mesh,
    first: SimplifyConfig,
    second: SimplifyConfig,
    sweep: &Sweep,
) -> Run {
    let attributes = first.attributes;
    feed_stages(mesh, first, Some(second), sweep, |p| {
        [p.z as f32].into_iter().take(attributes).collect()
    })
}

fn feed_stages(
    mesh: &Mesh,
    mut config: SimplifyConfig,
    second: Option<SimplifyConfig>,
    sweep: &Sweep,
    attr: impl Fn(DVec3) -> Vec<f32>,
) -> Run {
    let attributes = config.attributes;
    let coord = |p: DVec3| {
        if sweep.reverse {
            -p[sweep.axis]
        } else {
            p[sweep.axis]
        }
    };
    let min = mesh
        .pos
        .iter()
        .map(|&p| coord(p))
        .fold(f64::INFINITY, f64::min);
    // Ranks from 1: slab 0 stays empty, so that a front one below the lowest rank still to
    // come is never negative.
    let rank: Vec<u32> = mesh
        .pos
        .iter()
        .map(|&p| ((coord(p) - min) / sweep.slab).floor() as u32 + 1)
        .collect();
    let mut order: Vec<usize> = (0..mesh.pos.len()).collect();
    order.sort_by(|&a, &b| {
        coord(mesh.pos[a])
            .total_cmp(&coord(mesh.pos[b]))
            .then(a.cmp(&b))
    });
    let mut id = vec![0u64; mesh.pos.len()];
    for (k, &v) in order.iter().enumerate() {
        id[v] = k as u64;
    }
    // Slab `k`'s triangles lie below the plane `coord = min + k * slab`, rank `k`'s plane. Unlike
    // marching cubes', harness triangles may reach back: a slab thinner than the mesh's cells,
    // or not aligned with them, delivers triangles whose lowest corner lies slabs behind. The
    // simplifier relies on what is still to come lying beyond its front (`Sweep`), so a
    // cascade's batches close with the front below the lowest corner of every triangle not yet
    // delivered (at most `k`): with `k` alone, a later triangle reaching back crossed a fan the
    // first stage had contracted around its still incomplete corner (found by the cascade
    // property test, which counts crossings). Single runs keep the front at `k`: their tests
    // count no crossings, and the memory-budget tests measure what the band holds at `k`.
    let mut direction = DVec3::ZERO;
    direction[sweep.axis] = if sweep.reverse { -1.0 } else { 1.0 };
    let row_axis = (sweep.axis + 1) % 3;
    let row_min = mesh
        .pos
        .iter()
        .map(|p| p[row_axis])
        .fold(f64::INFINITY, f64::min);
    let rows = sweep.rows.map(|thickness| {
        let far = mesh
            .pos
            .iter()
            .map(|p| p[row_axis])
            .fold(f64::NEG_INFINITY, f64::max);
        let mut direction = DVec3::ZERO;
        direction[row_axis] = 1.0;
        isostream_simplify::Rows {
            direction,
            origin: row_min,
            spacing: thickness,
            count: ((far - row_min) / thickness).floor() as u32 + 2,
        }
    });
    config.sweep = Some(isostream_simplify::Sweep {
        direction,
        origin: min,
        spacing: sweep.slab,
        rows,
    });
    // A second stage's front is the first's rear, with the same rows.
    let mut second = second.map(|c| {
        Simplifier::new(SimplifyConfig {
            sweep: config.sweep,
            ..c
        })
        .expect("valid second stage")
    });
    let mut s = Simplifier::new(config).expect("valid config");
    let max_rank = rank.iter().copied().max().unwrap_or(0);
    let mut tris_by_slab: Vec<Vec<[u32; 3]>> = vec![Vec::new(); max_rank as usize + 1];
    let mut remaining = vec![0usize; mesh.pos.len()];
    for t in &mesh.tris {
        let r = t.iter().map(|&v| rank[v as usize]).max().unwrap_or(0);
        tris_by_slab[r as usize].push(*t);
        for &v in t {
            remaining[v as usize] += 1;
        }
    }
    // With rows, a slab's triangles by their farthest corner across, as rows are extracted.
    let across = |t: &[u32; 3]| {
        t.iter()
            .map(|&v| mesh.pos[v as usize][row_axis])
            .fold(f64::NEG_INFINITY, f64::max)
    };
    if sweep.rows.is_some() {
        for tris in &mut tris_by_slab {
            tris.sort_by(|a, b| across(a).total_cmp(&across(b)));
        }
    }
    // Each slab in `batches_per_slab` batches (an empty slab still closes one).
    let mut batches: Vec<(usize, &[[u32; 3]])> = Vec::new();
    for (k, tris) in tris_by_slab.iter().enumerate() {
        let per_batch = tris.len().div_ceil(sweep.batches_per_slab).max(1);
        batches.extend(tris.chunks(per_batch).map(|c| (k, c)));
        if tris.is_empty() {
            batches.push((k, &[]));
        }
    }
    // The lowest rank among the corners of the triangles after each batch.
    let mut still_to_come = vec![u32::MAX; batches.len()];
    for i in (0..batches.len().saturating_sub(1)).rev() {
        let next = batches[i + 1].1.iter().flatten().map(|&v| rank[v as usize]);
        still_to_come[i] = next.fold(still_to_come[i + 1], u32::min);
    }
    // With rows, the front after each batch is the farthest the triangles still to come allow
    // (`row_fronts`).
    let row_fronts = rows.map(|r| {
        let rank = |p: DVec3| (coord(p) - min) / sweep.slab;
        let row = |p: DVec3| (p[row_axis] - row_min) / r.spacing;
        row_fronts(mesh, &batches, r.count, rank, row)
    });
    let mut out = OutBatch::default();
    let mut trace = Vec::new();
    let mut next_vertex = 0;
    for (i, &(k, chunk)) in batches.iter().enumerate() {
        while next_vertex < order.len() && rank[order[next_vertex]] as usize == k {
            let v = order[next_vertex];
            s.add_vertex(id[v], mesh.pos[v], rank[v], &attr(mesh.pos[v]));
            next_vertex += 1;
        }
        let mut done = Vec::new();
        for t in chunk {
            s.add_triangle(t.map(|v| id[v as usize]));
            for &v in t {
                remaining[v as usize] -= 1;
                if remaining[v as usize] == 0 {
                    done.push(id[v as usize]);
                }
            }
        }
        done.sort_unstable();
        for v in done {
            s.set_modifiable(v);
        }
        let mut batch = OutBatch::default();
        let front = match &row_fronts {
            Some(fronts) => {
                let f = fronts[i];
                Front {
                    slabs: f.slabs.min(k as u32),
                    rows: f.rows,
                }
            }
            None if second.is_some() => {
                Front::from((k as u32).min(still_to_come[i].saturating_sub(1)))
            }
            None => Front::from(k as u32),
        };
        s.end_batch(front, &mut batch);
        pass_on(batch, second.as_mut(), false, &mut out);
        trace.push(s.stats());
    }
    let mut batch = OutBatch::default();
    s.finish(&mut batch);
    pass_on(batch, second.as_mut(), true, &mut out);
    let stats = match &second {
        Some(t) => SimplifyStats {
            faces_in: s.stats().faces_in,
            vertices_in: s.stats().vertices_in,
            ..t.stats()
        },
        None => s.stats(),
    };
    assert_eq!(s.stats().faces_resident, 0, "everything emitted");
    assert_eq!(stats.faces_resident, 0, "everything emitted");
    let (mesh, attrs) = collect(&out, attributes);
    Run {
        mesh,
        attrs,
        stats,
        out,
        trace,
    }
}

/// The front after each of `batches`: every triangle still to come lies outside both of its
/// boxes (`rank <= slabs`, and `rank <= slabs + 1` with `row <= rows`), as the extraction's
/// cubes do: `slabs` the lowest rank of their corners (rounded down), `rows` the lowest row of
/// the corners of those that reach below `slabs + 1` (rounded down, at most `count - 1`).
fn row_fronts(
    mesh: &Mesh,
    batches: &[(usize, &[[u32; 3]])],
    count: u32,
    rank: impl Fn(DVec3) -> f64,
    row: impl Fn(DVec3) -> f64,
) -> Vec<Front> {
    let low = |t: &[u32; 3], f: &dyn Fn(DVec3) -> f64| {
        t.iter()
            .map(|&v| f(mesh.pos[v as usize]))
            .fold(f64::INFINITY, f64::min)
    };
    (0..batches.len())
        .map(|i| {
            let later = || batches[i + 1..].iter().flat_map(|b| b.1.iter());
            let z = later().map(|t| low(t, &rank)).fold(f64::INFINITY, f64::min);
            let slabs = z.floor().clamp(0.0, f64::from(u32::MAX)) as u32;
            let y = later()
                .filter(|t| low(t, &rank) < f64::from(slabs) + 1.0)
                .map(|t| low(t, &row))
                .fold(f64::INFINITY, f64::min);
            let rows = y.floor().clamp(0.0, f64::from(count - 1)) as u32;
            Front { slabs, rows }
        })
        .collect()
}

/// A batch of the (first) simplifier: appended to the output, or taken by the second stage,
/// whose own output is appended.
fn pass_on(batch: OutBatch, second: Option<&mut Simplifier>, end: bool, out: &mut OutBatch) {
    match second {
        Some(t) => {
            let rear = t.ingest(&batch);
            if end {
                t.finish(out);
            } else {
                t.end_batch(rear, out);
            }
        }
        None => {
            out.elements.extend(batch.elements);
            out.attrs.extend(batch.attrs);
        }
    }
}

/// Reads the output, checking compact pre-order: every vertex is emitted right before the first
/// triangle using it, and finalized (`last_use`) exactly once, after which it is never used.
pub fn collect(out: &OutBatch, attributes: usize) -> (Mesh, Vec<f32>) {
    let mut mesh = Mesh::default();
    let mut used = Vec::new();
    let mut finalized = Vec::new();
    let mut pending: Vec<u64> = Vec::new();
    for e in &out.elements {
        match e {
            OutElement::Vertex { pos } => {
                pending.push(mesh.pos.len() as u64);
                mesh.pos.push(*pos);
                used.push(false);
                finalized.push(false);
            }
            OutElement::Triangle { v, last_use } => {
                for &x in v {
                    let i = x as usize;
                    assert!(i < mesh.pos.len(), "vertex {x} used before it was emitted");
                    assert!(!finalized[i], "vertex {x} used after its last use");
                    assert!(
                        used[i] || pending.contains(&x),
                        "vertex {x} not emitted right before its first triangle"
                    );
                    used[i] = true;
                }
                assert!(
                    pending.iter().all(|p| v.contains(p)),
                    "vertices {pending:?} emitted but not used by the next triangle"
                );
                pending.clear();
                for (&x, &last) in v.iter().zip(last_use) {
                    if last {
                        finalized[x as usize] = true;
                    }
                }
                mesh.tris.push(v.map(|x| x as u32));
            }
        }
    }
    assert!(pending.is_empty(), "vertices emitted without a triangle");
    assert!(finalized.iter().all(|&f| f), "every vertex is finalized");
    assert_eq!(out.attrs.len(), mesh.pos.len() * attributes);
    (mesh, out.attrs.clone())
}

/// Topology is preserved: valid (oriented, no duplicates), closed stays closed, the same
/// Euler characteristic per component, and no zero-area triangle unless the input had some.
pub fn assert_same_topology(input: &Mesh, run: &Run) {
    let (a, b) = (input.check(), run.check());
    assert!(b.is_valid_manifold(), "{b:?}");
    assert_eq!(
        a.boundary_edges == 0,
        b.boundary_edges == 0,
        "closed stays closed: {b:?}"
    );
    assert_eq!(a.sorted_eulers(), b.sorted_eulers(), "{b:?}");
    assert_eq!(a.closed_by_sign(), b.closed_by_sign(), "turned inside out");
    assert!(
        a.zero_area_triangles > 0 || b.zero_area_triangles == 0,
        "{b:?}"
    );
}

/// Marching tetrahedra over the grid `0..n` (six tetrahedra per cube around the main diagonal):
/// a watertight, consistently oriented surface whose vertices are keyed by grid edge, like the
/// extractor's. Where a grid value equals `iso` several vertices land on one point (zero-length
/// edges, zero-area triangles), as with marching cubes.
pub fn marching_tetrahedra(n: [u32; 3], iso: f64, f: impl Fn(DVec3) -> f64) -> Mesh {
    let corner = |i: u32| DVec3::new(f64::from(i & 1), f64::from((i >> 1) & 1), f64::from(i >> 2));
    // Cube corners 0 and 7 are opposite; each tetrahedron is 0-7 plus two adjacent corners.
    const TETS: [[u32; 4]; 6] = [
        [0, 1, 3, 7],
        [0, 3, 2, 7],
        [0, 2, 6, 7],
        [0, 6, 4, 7],
        [0, 4, 5, 7],
        [0, 5, 1, 7],
    ];
    let mut mesh = Mesh::default();
    let mut ids: HashMap<([i64; 3], [i64; 3]), u32> = HashMap::new();
    let key = |p: DVec3| p.to_array().map(|c| c as i64);
    for z in 0..n[2] {
        for y in 0..n[1] {
            for x in 0..n[0] {
                let base = DVec3::new(f64::from(x), f64::from(y), f64::from(z));
                for tet in TETS {
                    let p = tet.map(|c| base + corner(c));
                    let inside: Vec<usize> = (0..4).filter(|&i| f(p[i]) < iso).collect();
                    if inside.is_empty() || inside.len() == 4 {
                        continue;
                    }
                    let outside: Vec<usize> = (0..4).filter(|i| !inside.contains(i)).collect();
                    let mut vertex = |a: usize, b: usize| {
                        let (ka, kb) = (key(p[a]), key(p[b]));
                        let k = if ka < kb { (ka, kb) } else { (kb, ka) };
                        let pos = &mut mesh.pos;
                        let (va, vb) = (f(p[a]), f(p[b]));
                        *ids.entry(k).or_insert_with(|| {
                            let t = (iso - va) / (vb - va);
                            pos.push(p[a] + t * (p[b] - p[a]));
                            pos.len() as u32 - 1
                        })
                    };
                    // Crossing edges, in cyclic order around the section.
                    let (cross, mid_in, mid_out): (Vec<(usize, usize)>, DVec3, DVec3) = {
                        let c =
                            |s: &[usize]| s.iter().map(|&i| p[i]).sum::<DVec3>() / s.len() as f64;
                        let e = match (inside.len(), outside.len()) {
                            (1, 3) => outside.iter().map(|&o| (inside[0], o)).collect(),
                            (3, 1) => inside.iter().map(|&i| (i, outside[0])).collect(),
                            _ => vec![
                                (inside[0], outside[0]),
                                (inside[0], outside[1]),
                                (inside[1], outside[1]),
                                (inside[1], outside[0]),
                            ],
                        };
                        (e, c(&inside), c(&outside))
                    };
                    let verts: Vec<u32> = cross.iter().map(|&(a, b)| vertex(a, b)).collect();
                    // Orientation from edge midpoints (never degenerate): normals point outside.
                    let mids: Vec<DVec3> =
                        cross.iter().map(|&(a, b)| 0.5 * (p[a] + p[b])).collect();
                    let flip = (mids[1] - mids[0])
                        .cross(mids[2] - mids[0])
                        .dot(mid_out - mid_in)
                        < 0.0;
                    let mut emit = |i: usize, j: usize, k: usize| {
                        mesh.tris.push(if flip {
                            [verts[i], verts[k], verts[j]]
                        } else {
                            [verts[i], verts[j], verts[k]]
                        });
                    };
                    emit(0, 1, 2);
                    if verts.len() == 4 {
                        emit(0, 2, 3);
                    }
                }
            }
        }
    }
    mesh.exact()
}
