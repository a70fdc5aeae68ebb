//! Two workers on one surface, either side of a seam: how the final decimation uses both cores.
//!
//! At the end of the volume a run's last simplifier decimates everything it holds down to the
//! target while the rest of the pipeline has finished: at low rates that was 15-21 % of the
//! second stage's instructions with the other core idle (docs/performance.md, "Forty-fifth
//! session"). So the surface is cut by a plane across the sweep (`z = z0`, near the median
//! vertex height where it crosses the fewest triangles, [`Cut::plan`]):
//! a vertex is on the lower side when `z < z0`, else on the upper; a triangle with corners on
//! both sides is a **seam** triangle, and its corners are frozen (they read as retired, so no
//! candidate names them). Each worker contracts only edges between its own side's free
//! vertices, and places the survivor strictly on its side ([`HalfSpace`], tested in the
//! contraction loop). Then:
//!
//! * every triangle a worker makes has its corners on its side: the lower worker's lie in the
//!   open half-space `z < z0`, the upper's in the closed `z >= z0`, so no triangle of one can
//!   cross one of the other, and each worker's guard needs only its side, the seam and the
//!   ghosts ([`crate::intersect::TriIndex::split_off`]);
//! * a contraction allocates no slot (the survivor keeps one endpoint's), its removed triangles'
//!   third corners are on its side (or the triangle would be a seam triangle and its endpoints
//!   frozen), and it relinks only its own side's triangles: each vertex and triangle slot is
//!   changed by one worker only, so the two results merge slot by slot, exactly
//!   ([`crate::store::Store::absorb`]).
//!
//! The workers contract in rounds of rising cost ([`ROUND_FACTOR`]) and stop when the sides
//! hold a multiple of their share of the target ([`slack`]: more where the seam is large
//! against the target); the stage then finishes on the merged surface as before, over one
//! queue again: the seam's edges, and the global cost order between the sides. The result is a
//! deterministic function of the input, whatever runs the two workers ([`Join`]): the pipeline
//! runs them on two threads, the tests one after the other, with the same output.

use glam::DVec3;

use crate::band::Band;
use crate::store::{Store, TriId};

/// A worker's side of the cut: `z < z0` below, `z >= z0` above. Positions are `f32`-exact
/// and `z0` is one of them, so the test is exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct HalfSpace {
    z0: f64,
    upper: bool,
}

impl HalfSpace {
    pub(crate) fn holds(&self, p: DVec3) -> bool {
        (p.z >= self.z0) == self.upper
    }
}

/// Runs two pieces of work, at once when it can: how a simplifier uses a second core without
/// spawning a thread itself (the pipeline owns the threads, `isostream_pipeline`). Whether a
/// final decimation is worth cutting is the runner's to say, since only it knows what a second
/// worker costs; given a cut, the output is the same however the two pieces run.
pub trait Join: Sync {
    /// Whether to cut a final decimation of `faces` held faces in two.
    fn worth_cutting(&self, faces: usize) -> bool;
    fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send));
}

/// One thread and no cut: the final decimation as one queue ([`crate::Simplifier::finish`]).
pub struct Serial;

impl Join for Serial {
    fn worth_cutting(&self, _faces: usize) -> bool {
        false
    }

    fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
        a();
        b();
    }
}

/// Fewest faces on each side for a cut to be made at all (the runner decides above it,
/// [`Join::worth_cutting`]).
const MIN_SIDE_FACES: usize = 1000;

/// The workers stop once the sides hold [`slack`] times their share of the target, and the one
/// queue does the rest on the merged surface. The seam is still at the density it had when the
/// cut was made, and taking it down next to sides already near their final density costs
/// accuracy where the seam is large against the target, and nowhere else. In core, one run
/// each, RMS distance with a slack of 3 / 2 / 1.5 / 1.2: mni152 at R = 0.01 (2.0 k seam faces
/// for a 3.3 k target) 0.468 / 0.476 / 0.522 / 0.819 voxels, engine at R = 0.01 (3.4 k for
/// 5.9 k) 0.182 / 0.183 / 0.189 / 0.270; at R = 0.05 within 1.3 % of each other on both, at
/// R = 0.2 within 0.3 % on engine, bonsai and mni152. A slack of 3 everywhere left two thirds of
/// an R = 0.2 job to the one queue (bonsai in core 7.2 s, 6.3 s with this rule), so the slack is
/// [`SLACK_MIN`] plus [`SLACK_PER_SEAM_FACE`] per seam face per target face, at most
/// [`SLACK_MAX`] (docs/performance.md, "Forty-sixth session").
const SLACK_MIN: f64 = 1.2;
/// See [`SLACK_MIN`]: mni152 gets 3 at R = 0.01, 1.57 at R = 0.05 and 1.29 at R = 0.2.
const SLACK_PER_SEAM_FACE: f64 = 3.0;
/// See [`SLACK_MIN`].
const SLACK_MAX: f64 = 3.0;

/// How many times their share of the `target` the sides hold when the workers stop, with a
/// seam of `seam` faces (see [`SLACK_MIN`]).
fn slack(seam: usize, target: usize) -> f64 {
    (SLACK_MIN + SLACK_PER_SEAM_FACE * seam as f64 / target.max(1) as f64).min(SLACK_MAX)
}

/// Each round of the workers contracts up to this factor above the last round's cost (or the
/// cheapest candidate's, if that is higher): the sides then share the contractions by cost, as
/// one queue would, rather than by a split of the target fixed in advance. The price is a wait
/// at the end of each round for the slower side (in core that wait is small: mni152's workers
/// were busy 1.07 and 1.03 s in 1.10 s of rounds).
pub(crate) const ROUND_FACTOR: f64 = 1.5;

/// Where a cut may go, as quantiles of the vertex heights: the median first, so that it wins
/// ties. The sides then hold 40 to 60 % of the vertices each. The plane crossing the fewest
/// triangles leaves the smallest seam: at the median, mni152's seam (2.5 k faces at full
/// resolution, in core at R = 0.01) took its 99.9th-percentile distance from 1.19 % to 1.40 %;
/// at the least crossed of these planes it is 1.17 %.
const CANDIDATE_QUANTILES: [f64; 5] = [0.5, 0.45, 0.55, 0.4, 0.6];

/// Where the surface is cut, and what each side holds.
#[derive(Debug)]
pub(crate) struct Cut {
    z0: f64,
    /// Slots of the live vertices on the upper side (moved to the upper worker).
    upper_slots: Vec<usize>,
    /// Triangles with all corners on the upper side.
    upper_tris: Vec<TriId>,
    /// Triangles with corners on both sides, in both workers' guards.
    seam_tris: Vec<TriId>,
    /// Seam corners that were free: frozen while the workers run.
    frozen: Vec<u64>,
    lower_faces: usize,
}

impl Cut {
    /// The cut (see [`CANDIDATE_QUANTILES`]), and how many faces the workers leave for a final
    /// `target` ([`slack`]): `None` when a side would be too small, or the target leaves little
    /// to contract.
    pub(crate) fn plan(store: &Store, target: usize) -> Option<(Cut, usize)> {
        let mut zs: Vec<f32> = store.positions().map(|(_, p)| p.z as f32).collect();
        if zs.is_empty() {
            return None;
        }
        zs.sort_unstable_by(f32::total_cmp);
        // Each triangle's lowest and highest corner, once: a plane at `z0` crosses it when
        // `lo < z0 <= hi`.
        let spans: Vec<(f64, f64)> = store
            .positions()
            .flat_map(|(v, _)| store.tris_of(v).iter().map(move |&t| (v, t)))
            .filter(|&(v, t)| store.tri(t).v[0] == v)
            .map(|(_, t)| {
                let z = store.tri(t).v.map(|x| store.pos(x).z);
                (z[0].min(z[1]).min(z[2]), z[0].max(z[1]).max(z[2]))
            })
            .collect();
        let crossed = |z0: f64| {
            spans
                .iter()
                .filter(|&&(lo, hi)| lo < z0 && z0 <= hi)
                .count()
        };
        // Of the planes through the 40th to 60th percentile of the heights, the one crossing
        // the fewest triangles (the median on a tie): the seam is what the workers leave whole.
        let z0 = CANDIDATE_QUANTILES
            .iter()
            .map(|&q| f64::from(zs[((zs.len() - 1) as f64 * q) as usize]))
            .min_by_key(|&z0| crossed(z0))
            .unwrap_or_default();
        let upper = |p: DVec3| p.z >= z0;
        let mut cut = Cut {
            z0,
            upper_slots: Vec::new(),
            upper_tris: Vec::new(),
            seam_tris: Vec::new(),
            frozen: Vec::new(),
            lower_faces: 0,
        };
        let mut frozen_slot = std::collections::HashSet::new();
        for (v, p) in store.positions() {
            if upper(p) {
                cut.upper_slots.push(Store::slot_index(v));
            }
            for &t in store.tris_of(v) {
                let tri = store.tri(t);
                // Each triangle once, from its first corner's list.
                if tri.v[0] != v {
                    continue;
                }
                let sides = tri.v.map(|x| upper(store.pos(x)));
                if sides.iter().all(|&s| s) {
                    cut.upper_tris.push(t);
                } else if sides.iter().all(|&s| !s) {
                    cut.lower_faces += 1;
                } else {
                    cut.seam_tris.push(t);
                    for x in tri.v {
                        if store.is_free(x) && frozen_slot.insert(x) {
                            cut.frozen.push(x);
                        }
                    }
                }
            }
        }
        let (lower, upper, seam) = (cut.lower_faces, cut.upper_tris.len(), cut.seam_tris.len());
        // The seam is still whole when the workers stop: its faces count besides the sides'
        // share of the target, or the sides are squeezed to make room for them (mni152 at
        // R = 0.01 in core, 2.5 k seam faces for a 3.3 k target: 14x the RMS distance).
        let total = lower + upper + seam;
        let sides = target as f64 * slack(seam, target) * (lower + upper) as f64 / total as f64;
        let goal = seam + sides.ceil() as usize;
        if lower.min(upper) < MIN_SIDE_FACES || goal >= total {
            return None;
        }
        Some((cut, goal))
    }

    pub(crate) fn lower(&self) -> HalfSpace {
        HalfSpace {
            z0: self.z0,
            upper: false,
        }
    }

    pub(crate) fn upper(&self) -> HalfSpace {
        HalfSpace {
            z0: self.z0,
            upper: true,
        }
    }

    /// Moves the upper side out of `band` into a band of its own, the seam frozen in both.
    pub(crate) fn split(&self, band: &mut Band) -> Band {
        for &v in &self.frozen {
            band.store.freeze(v);
        }
        let store = band.store.split_off(&self.upper_slots, &self.upper_tris);
        let guard = band.guard.split_off(&self.upper_tris, &self.seam_tris);
        Band {
            store,
            guard,
            ..Band::default()
        }
    }

    /// Takes the upper side back from the band [`Cut::split`] made, and thaws the seam. The
    /// vertices the upper worker filed again, and those the rank buckets dropped while they
    /// read as retired, are filed again here (an entry filed twice is skipped once retired).
    pub(crate) fn merge(&self, band: &mut Band, upper: Band) {
        band.store
            .absorb(upper.store, &self.upper_slots, &self.upper_tris);
        band.guard
            .absorb(upper.guard, &band.store, &self.upper_tris);
        for &v in &self.frozen {
            band.store.thaw(v);
        }
        let refile: Vec<(u32, u64)> = self
            .upper_slots
            .iter()
            .filter_map(|&slot| band.store.handle_at(slot))
            .chain(self.frozen.iter().copied())
            .filter(|&v| !band.store.is_retired(v))
            .filter_map(|v| band.store.vertex(v).map(|x| (x.bucket, v)))
            .collect();
        for (rank, v) in refile {
            band.file(rank, v);
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::Join;
    use crate::{OutBatch, OutElement, Policy, Simplifier, SimplifyConfig, SimplifyStats, Sweep};

    /// Cuts every final decimation and runs the two workers one after the other (this crate
    /// spawns no thread: `tests/final_cut.rs` runs them on two, with the same bytes).
    struct Cutting;

    impl Join for Cutting {
        fn worth_cutting(&self, _faces: usize) -> bool {
            true
        }

        fn join(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
            super::Serial.join(a, b);
        }
    }

    #[test]
    fn the_slack_grows_with_the_seam_against_the_target() {
        use super::{SLACK_MAX, SLACK_MIN, slack};
        assert_eq!(slack(0, 1000), SLACK_MIN);
        // mni152 in core: 2.0 k seam faces against the targets of R = 0.01, 0.05 and 0.2.
        assert_eq!(slack(2033, 3335), SLACK_MAX);
        let (r005, r02) = (slack(2033, 16_675), slack(2033, 66_697));
        assert!(
            SLACK_MIN < r02 && r02 < r005 && r005 < SLACK_MAX,
            "{r02} {r005}"
        );
        assert_eq!(slack(10, 0), SLACK_MAX);
    }

    /// A bumpy torus lying across z = 0 (so that the cut meets it in two loops), `nu` by `nv`
    /// quads, `f32`-exact positions, outward oriented: Euler characteristic 0.
    fn torus(nu: u32, nv: u32) -> (Vec<DVec3>, Vec<[u64; 3]>) {
        let mut pos = Vec::new();
        for i in 0..nu {
            for j in 0..nv {
                let u = f64::from(i) / f64::from(nu) * std::f64::consts::TAU;
                let v = f64::from(j) / f64::from(nv) * std::f64::consts::TAU;
                let r = 6.0 + 0.8 * (3.0 * u).sin() * (5.0 * v).cos();
                let p = DVec3::new(
                    (20.0 + r * v.cos()) * u.cos(),
                    r * v.sin(),
                    (20.0 + r * v.cos()) * u.sin(),
                );
                pos.push(p.as_vec3().as_dvec3());
            }
        }
        let id = |i: u32, j: u32| u64::from((i % nu) * nv + (j % nv));
        let mut tris = Vec::new();
        for i in 0..nu {
            for j in 0..nv {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                tris.push([a, c, b]);
                tris.push([a, d, c]);
            }
        }
        (pos, tris)
    }

    /// The whole torus held, decimated at the end to 5 % (nothing contracts before: `batch`
    /// larger than the surface), finished with `join`.
    fn run(join: &dyn Join) -> (OutBatch, SimplifyStats) {
        let mut s = held(1 << 20);
        let mut out = OutBatch::default();
        s.end_batch(100, &mut out);
        s.finish_with(&mut out, join, &|| false).unwrap();
        (out, s.stats())
    }

    /// A simplifier at rate 5 % holding the whole torus, every vertex modifiable, no batch
    /// closed yet, with a budget of `faces`.
    fn held(faces: usize) -> Simplifier {
        let (pos, tris) = torus(160, 48);
        let mut s = Simplifier::new(SimplifyConfig {
            max_resident_faces: faces,
            sweep: Some(Sweep {
                direction: DVec3::Z,
                origin: -40.0,
                spacing: 1.0,
                rows: None,
            }),
            ..SimplifyConfig::new(Policy::Rate {
                rate: 0.05,
                batch: u64::MAX,
                initial_rate: 0.05,
            })
        })
        .expect("config");
        for (id, p) in pos.iter().enumerate() {
            s.add_vertex(id as u64, *p, (p.z + 40.0) as u32, &[]);
        }
        for t in &tris {
            s.add_triangle(*t);
        }
        for id in 0..pos.len() as u64 {
            s.set_modifiable(id);
        }
        s
    }

    /// An interrupt that says stop from its `n`th question on, and counts them.
    struct StopAt {
        n: usize,
        asked: std::sync::atomic::AtomicUsize,
    }

    impl StopAt {
        fn new(n: usize) -> Self {
            Self {
                n,
                asked: Default::default(),
            }
        }

        fn ask(&self) -> bool {
            let asked = self
                .asked
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                + 1;
            asked >= self.n
        }
    }

    fn triangles(out: &OutBatch) -> usize {
        out.elements
            .iter()
            .filter(|e| matches!(e, OutElement::Triangle { .. }))
            .count()
    }

    /// A final decimation stops when its interrupt says so, cut in two or not, at the start or
    /// after some contractions, and writes nothing; asked every few thousand candidates (and
    /// between the cut's passes over the surface), so a whole one asks many times (the torus's
    /// 14.6 k contractions).
    #[test]
    fn an_interrupted_final_decimation_stops_and_writes_nothing() {
        let joins: [&dyn Join; 2] = [&super::Serial, &Cutting];
        for join in joins {
            let whole = StopAt::new(usize::MAX);
            let mut s = held(1 << 20);
            s.end_batch(100, &mut OutBatch::default());
            s.finish_with(&mut OutBatch::default(), join, &|| whole.ask())
                .unwrap();
            let asked = whole.asked.into_inner();
            assert!(asked > 4, "{asked}");
            for n in [1, asked / 2, asked - 1] {
                let stop = StopAt::new(n);
                let mut s = held(1 << 20);
                let mut out = OutBatch::default();
                s.end_batch(100, &mut out);
                assert_eq!(
                    s.finish_with(&mut out, join, &|| stop.ask()),
                    Err(crate::Interrupted)
                );
                assert_eq!(stop.asked.into_inner(), n, "it stops at the first yes");
                assert_eq!(triangles(&out), 0, "nothing written");
                let contracted = s.stats().contractions;
                assert_eq!(contracted > 0, n > 1, "stopped at {n} of {asked}");
            }
        }
    }

    /// A pass over the memory budget during the sweep stops when its interrupt says so, before
    /// anything is retired for the budget; the same pass uninterrupted contracts and writes.
    #[test]
    fn an_interrupted_pass_over_the_budget_retires_nothing() {
        let mut s = held(500);
        let mut out = OutBatch::default();
        assert_eq!(
            s.end_batch_with(100, &mut out, &|| true),
            Err(crate::Interrupted)
        );
        assert!(out.elements.is_empty());
        assert_eq!(s.stats().contractions, 0);
        let mut s = held(500);
        s.end_batch_with(100, &mut out, &|| false).unwrap();
        let st = s.stats();
        assert!(st.contractions > 0 && st.forced_retirements > 0 && triangles(&out) > 0);
    }

    /// The output as an indexed mesh.
    fn indexed(out: &OutBatch) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let (mut pos, mut tris) = (Vec::new(), Vec::new());
        for e in &out.elements {
            match e {
                OutElement::Vertex { pos: p } => pos.push(p.to_array()),
                OutElement::Triangle { v, .. } => tris.push(v.map(|x| x as u32)),
            }
        }
        (pos, tris)
    }

    /// Two workers either side of the cut leave a surface as valid as one queue's: closed,
    /// edge-manifold, oriented, the torus's Euler characteristic, no two triangles crossing by
    /// the referee, the rate met; and the same one each time.
    #[test]
    fn a_cut_final_decimation_is_valid() {
        let (cut, stats) = run(&Cutting);
        let (again, again_stats) = run(&Cutting);
        assert!(stats.cut_faces > 0, "the decimation was cut: {stats:?}");
        assert!(stats.contractions > 0);
        assert_eq!(cut.elements, again.elements);
        assert_eq!(stats, again_stats);
        let (pos, tris) = indexed(&cut);
        let faces = 160 * 48 * 2;
        assert_eq!(tris.len(), faces / 20, "the rate is met");
        let report = isostream_meshcheck::check(&pos, &tris);
        assert!(report.is_closed_manifold(), "{report:?}");
        assert_eq!(report.euler(), 0);
        assert_eq!(isostream_meshcheck::self_intersections(&pos, &tris), 0);
        // One queue finishes the same surface to the same count.
        let (uncut, uncut_stats) = run(&super::Serial);
        assert_eq!(uncut_stats.cut_faces, 0);
        assert_eq!(indexed(&uncut).1.len(), tris.len());
    }
}
