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
//! Safety (0 crossings): the two stages edit the same surface in two regions the sweep keeps
//! apart. The first stage announces its **rear**, a [`Front`]: every triangle it holds (and
//! every new fan it will make: contractions that would not be are refused) is clear of the
//! rear's complete region (`Sweep::clear_of`: at or above its plane, and at or above its next
//! slab's top or beyond its rows). The second stage uses the rear as its sweep front, so its
//! contractions wait until their new fan lies in one of that region's two boxes
//! ([`crate::Sweep`]). A triangle on either side of a box's wall cannot cross one on the other,
//! and each stage's guard sees every triangle that can meet its fans: the first stage's
//! emitted triangles stay in its guard index ("ghosts"), and the second stage only changes them
//! inside the region, where the first stage's fans never reach. Contacts are ruled out too: the
//! first stage's triangles lie on or beyond the region's walls, and the second stage keys its
//! new fans strictly inside it, off the walls (`Sweep::key_inside`, as `seam.rs` splits its two
//! workers by a half-open plane), so the two stages' new geometry never shares a point.
//!
//! The rear is what the first stage's lowest held triangles allow ([`rear_of`]): a triangle
//! stays until its three corners are retired. It would trail the first stage's front by its
//! retirement lag, the rank span of its preimages and how far below them it places a vertex;
//! the first stage keeps the last two short (`Decimator::span_ok`,
//! `decimate::outside_first_stage_room`; quadric optima far below their preimage once kept it
//! 15 to 20 slabs back on bonsai upsampled to 511^3, and the second stage's front held 1.8x
//! the faces), and once per slab of its front writes every triangle that reaches more than two
//! slabs behind it, after a pass (`Stage::catch_up_due`): a corner with a young preimage kept
//! such a triangle, and the rear, 5 to 6 slabs back. The rear, raised at every hand-off, then
//! moves by rows as the extraction's front does.
//!
//! The second stage holds what the first wrote above the rear (two or three slabs) and lets a
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
use crate::{Front, Sweep};

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
    /// Every triangle the first stage holds or will make stays clear of this front's complete
    /// region (`Sweep::clear_of`): the second stage's front.
    pub rear: Front,
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
        self.rear.slabs == u32::MAX
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

/// The highest rear a first stage holding triangles with corners `tris` can announce: the
/// lowest rank of their corners, rounded down (`slabs`), and with rows, the lowest row (rounded
/// down) of those reaching below rank `slabs + 1` (at most the last row): every triangle is
/// then clear of the rear's region ([`Sweep::clear_of`]). `None` when there are none.
pub(crate) fn rear_of(sweep: &Sweep, tris: impl Iterator<Item = [DVec3; 3]>) -> Option<Front> {
    let lows: Vec<(f64, f64)> = tris
        .map(|p| {
            let rank = p
                .iter()
                .map(|&x| sweep.rank_of(x))
                .fold(f64::INFINITY, f64::min);
            let row = p
                .iter()
                .map(|&x| sweep.row_of(x).unwrap_or(0.0))
                .fold(f64::INFINITY, f64::min);
            (rank, row)
        })
        .collect();
    let low = lows.iter().map(|l| l.0).min_by(f64::total_cmp)?;
    let slabs = low.floor().clamp(0.0, f64::from(u32::MAX)) as u32;
    let rows = sweep.rows.map_or(0, |r| {
        let row = lows
            .iter()
            .filter(|l| l.0 < f64::from(slabs) + 1.0)
            .map(|l| l.1)
            .fold(f64::INFINITY, f64::min);
        row.floor().clamp(0.0, f64::from(r.count - 1)) as u32
    });
    Some(Front { slabs, rows })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ratio_is_the_first_stage_rate_until_the_end_then_exact() {
        let h = Handoff {
            rear: Front::from(7),
            rate: 0.5,
            faces_in: 1000,
            faces_out: 300,
            faces_resident: 400,
        };
        assert_eq!(h.ratio(), 0.5);
        let end = Handoff {
            rear: Front::from(u32::MAX),
            faces_resident: 0,
            faces_out: 600,
            ..h
        };
        assert_eq!(end.ratio(), 0.6);
    }

    fn sweep(rows: Option<u32>) -> Sweep {
        crate::sweep::tests::along_z(1.0, 0.5, rows)
    }

    fn tri(p: [[f64; 3]; 3]) -> [DVec3; 3] {
        p.map(DVec3::from_array)
    }

    #[test]
    fn without_rows_the_rear_is_the_floor_of_the_lowest_rank() {
        let s = sweep(None);
        // Ranks (z - 1) / 0.5: 6.4, 2.6, and 0 or below (clamped).
        let high = tri([[0.0, 0.0, 4.2], [1.0, 0.0, 4.2], [0.0, 1.0, 4.2]]);
        let low = tri([[9.0, 0.0, 2.3], [9.0, 1.0, 4.2], [8.0, 0.0, 4.2]]);
        assert_eq!(rear_of(&s, [high, low].into_iter()), Some(Front::from(2)));
        assert_eq!(rear_of(&s, std::iter::empty()), None);
        let below = tri([[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        assert_eq!(rear_of(&s, [below].into_iter()), Some(Front::from(0)));
    }

    /// With rows, the rear also has the rows below every triangle that reaches into the slab
    /// above its plane, and every triangle it was made from is clear of it.
    #[test]
    fn with_rows_the_rear_holds_the_rows_below_the_triangles_in_its_next_slab() {
        let s = sweep(Some(10));
        // From rank 2.6 (slab 2) and row 4.5 on; from rank 2.8 and row 1.5; from rank 5.
        let near = tri([[0.0, 4.5, 2.3], [0.0, 9.0, 2.5], [1.0, 9.0, 2.5]]);
        let next = tri([[0.0, 1.5, 2.4], [0.0, 3.0, 3.0], [1.0, 3.0, 3.0]]);
        let far = tri([[0.0, 0.0, 3.5], [0.0, 0.0, 3.6], [1.0, 0.0, 3.5]]);
        let rear = rear_of(&s, [near, next, far].into_iter()).expect("triangles");
        assert_eq!(rear, Front { slabs: 2, rows: 1 });
        for t in [near, next, far] {
            assert!(s.clear_of(rear, &t), "{t:?}");
        }
        assert!(!s.clear_of(Front { slabs: 2, rows: 2 }, &next));
        assert!(s.clear_of(Front { slabs: 2, rows: 2 }, &far));
        assert!(!s.clear_of(Front { slabs: 3, rows: 0 }, &near));
        // Only the triangles reaching below the next slab's top count for rows.
        let rear = rear_of(&s, [near, far].into_iter()).expect("triangles");
        assert_eq!(rear, Front { slabs: 2, rows: 4 });
        let rear = rear_of(&s, [far].into_iter()).expect("triangles");
        assert_eq!(rear, Front { slabs: 5, rows: 0 });
        // Fronts order as their keys do.
        assert!(Front { slabs: 2, rows: 9 } < Front::from(3));
        assert!(s.front_key(Front { slabs: 2, rows: 9 }) < s.front_key(Front::from(3)));
    }
}
