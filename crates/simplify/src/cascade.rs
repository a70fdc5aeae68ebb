//! Two simplifiers in series, so that one job uses two cores: the first takes the extracted
//! surface down to an intermediate rate, the second takes the first's output down to the
//! job's rate. The pipeline runs each on its own thread; this module is what they exchange and
//! the rules that keep the pair exactly as safe as one simplifier.
//!
//! Why a cascade rather than two workers on two halves of the band: the stages share no memory
//! and no lock (the second reads the first's output stream, which is ordered and final), the
//! output is a deterministic function of the job (each stage is), and the same hand-off would
//! work between processes. The work splits by contraction count: the first stage contracts the
//! cheapest `1 - r1` of the faces, the second the rest, with the quadrics carried along
//! ([`VertexState`]) so the second stage's costs are those a single simplifier would see.
//!
//! Safety (0 crossings): the two stages edit the same surface in two regions separated by a
//! plane of the sweep. The first stage announces its **rear**: every vertex it holds (and
//! every vertex it will place: contractions below the rear are refused) lies at or above that
//! rank plane. The second stage uses the rear as its sweep front, so its contractions wait until
//! their new fan lies at or below the plane ([`crate::Sweep`]). Triangles on either side then
//! cannot cross (the referee's predicate is strict), and each stage's guard sees every triangle
//! that can meet its fans: the first stage's emitted triangles stay in its guard index
//! ("ghosts"), and the second stage only changes them below the rear, where the first stage's
//! fans never reach.
//!
//! The rear is the lowest vertex the first stage holds, retired ones included (a vertex stays
//! until its last triangle is written). It trails the first stage's front by its retirement lag,
//! the rank span of its preimages and how far below them it places a vertex; the first stage
//! keeps the last two short (`Decimator::span_ok`, `decimate::outside_first_stage_room`):
//! about ten slabs, where quadric optima far below their preimage once made it 15 to 20 on
//! bonsai upsampled to 511^3, and the second stage's front held 1.8x the faces.
//!
//! The second stage holds what the first wrote above the rear (about ten slabs) and lets a
//! vertex move only once the rear has passed its whole star (as every stage now does): gated
//! by its preimage's ranks alone, vertices whose triangles reach into that backlog counted as
//! modifiable but could not contract (half of its candidates waited for the front), so the rate
//! target over-decimated the rest (engine at R = 0.01: 1.27x the single simplifier's RMS
//! distance; gated by the star, 0.95x, and 11 candidates wait instead of 159 k).
//!
//! Rate: the first stage runs Hou and Chen's schedule at the intermediate rate and retires by a
//! lag behind its front or by its (small) share of the memory budget (its output is not final,
//! so the reasons the single simplifier keeps its simplified surface resident do not apply). The
//! second stage aims at `R` of the *extracted* faces: its input is `r1` of them, where `r1` is
//! the first stage's rate while it runs and its exact ratio once it has finished
//! ([`Handoff::ratio`]), so its schedule runs at `R / r1` of its own input.

use glam::DVec3;

use crate::quadric::Quadric;

/// A simplifier's place in a cascade.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Cascade {
    /// Alone: extracted faces in, the final surface out.
    #[default]
    Single,
    /// Extracted faces in, an intermediate surface out, with [`VertexState`]s and a
    /// [`Handoff`] in every [`crate::OutBatch`]; retires `retire_lag` slabs behind the front
    /// and never places a vertex below its announced rear.
    First,
    /// The first stage's batches in ([`crate::Simplifier::ingest`]), the final surface out.
    Second,
}

/// What the second stage needs of a vertex beyond its position: the error quadric and area of
/// its preimage, and the ranks that preimage spans.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VertexState {
    pub(crate) quadric: Quadric,
    pub(crate) area: f64,
    pub(crate) rank_min: u32,
    pub(crate) rank_max: u32,
}

/// The first stage's word with each batch.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Handoff {
    /// Every vertex the first stage holds or will place lies at or above this rank plane: the
    /// second stage's front.
    pub rear: u32,
    /// The first stage's rate (what it aims at).
    pub rate: f64,
    /// The first stage's counts so far: faces extracted, written to the second stage, resident
    /// (its resident faces count against the second stage's budget, which both share).
    pub faces_in: u64,
    pub faces_out: u64,
    pub faces_resident: u64,
}

impl Handoff {
    /// The last hand-off (the first stage has finished).
    pub(crate) fn is_last(&self) -> bool {
        self.rear == u32::MAX
    }

    /// Faces out of the first stage per extracted face, as the second stage should count them:
    /// the first stage's rate while it runs, and exactly what it wrote once it has finished.
    /// (Its running ratio, written and resident over extracted, starts near 1 while its first
    /// band waits for decimation; a second stage steering by it over-decimated its first batches
    /// to R of what it had: engine at R = 0.01 came out with 11x the single simplifier's RMS.)
    pub(crate) fn ratio(&self) -> f64 {
        if !self.is_last() || self.faces_in == 0 {
            self.rate
        } else {
            (self.faces_out as f64 / self.faces_in as f64).clamp(1e-12, 1.0)
        }
    }
}

/// The lowest rank plane (floored) at or below every position in `positions`; `None` when
/// there is none.
pub(crate) fn rear_of(sweep: &crate::Sweep, positions: impl Iterator<Item = DVec3>) -> Option<u32> {
    positions
        .map(|p| sweep.rank_of(p))
        .min_by(f64::total_cmp)
        .map(|r| r.floor().clamp(0.0, f64::from(u32::MAX)) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ratio_is_the_first_stage_rate_until_the_end_then_exact() {
        let h = Handoff {
            rear: 7,
            rate: 0.5,
            faces_in: 1000,
            faces_out: 300,
            faces_resident: 400,
        };
        assert_eq!(h.ratio(), 0.5);
        let end = Handoff {
            rear: u32::MAX,
            faces_resident: 0,
            faces_out: 600,
            ..h
        };
        assert_eq!(end.ratio(), 0.6);
    }

    #[test]
    fn the_rear_is_the_floor_of_the_lowest_rank() {
        let sweep = crate::Sweep {
            direction: DVec3::Z,
            origin: 1.0,
            spacing: 0.5,
            rows: None,
        };
        let pts = [DVec3::new(0.0, 0.0, 4.2), DVec3::new(9.0, 0.0, 2.3)];
        assert_eq!(rear_of(&sweep, pts.into_iter()), Some(2)); // (2.3 - 1) / 0.5 = 2.6
        assert_eq!(rear_of(&sweep, std::iter::empty()), None);
        assert_eq!(
            rear_of(&sweep, [DVec3::ZERO].into_iter()),
            Some(0),
            "clamped"
        );
    }
}
