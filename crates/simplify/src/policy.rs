//! Simplification policies: what the user asks for, and when decimation runs and stops.
//!
//! The cost and placement of a single contraction live in [`crate::cost`]; this module decides
//! how far to decimate after each batch.

use serde::{Deserialize, Serialize};

use crate::SimplifyError;
use crate::cost::Objective;

#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub enum Policy {
    /// Pass-through: no contraction (still retires and emits in streaming order).
    None,
    /// Hou & Chen: target F_t = (F_g - F_u) * rate + F_u after every `batch` extracted faces
    /// (and whenever the resident faces pass the memory budget: with `batch = u64::MAX` only
    /// then, and at the end, which chooses every contraction among as much of the surface as
    /// the budget holds); initial phase with `initial_rate` while rate < initial_rate.
    Rate {
        rate: f64,
        batch: u64,
        initial_rate: f64,
    },
    /// Tandem (seed 000, section 3): after every batch (layer), contract while the cheapest
    /// candidate's shape measure `eps0(c) = sqrt(c^T H_c c / W_c)` is at most `e0` (a length, in
    /// the units of the vertex positions). `time_lag` delays contractions whose patch reaches
    /// beyond the front; `isotropy` (alpha in [0, 1]) mixes in the anisotropy measure for
    /// placement and priority, while still only contracting when `eps0 <= e0`. With the
    /// time-lag, `retire_lag` should exceed the patch radii reached (about 8 slabs at moderate
    /// `e0`): edges still waiting when their vertices retire are never contracted.
    Error {
        e0: f64,
        time_lag: bool,
        isotropy: f64,
    },
}

impl Policy {
    pub(crate) fn validate(&self) -> Result<(), SimplifyError> {
        let unit = |x: f64| x > 0.0 && x <= 1.0;
        let invalid = |why: &str| Err(SimplifyError::InvalidPolicy(why.to_owned()));
        match *self {
            Policy::None => Ok(()),
            Policy::Rate { rate, .. } if !unit(rate) => invalid("rate must be in (0, 1]"),
            Policy::Rate { batch: 0, .. } => invalid("batch must be at least 1"),
            Policy::Rate { initial_rate, .. } if !unit(initial_rate) => {
                invalid("initial_rate must be in (0, 1]")
            }
            Policy::Rate { .. } => Ok(()),
            Policy::Error { e0, .. } if !(e0 > 0.0 && e0.is_finite()) => {
                invalid("e0 must be positive and finite")
            }
            Policy::Error { isotropy, .. } if !(0.0..=1.0).contains(&isotropy) => {
                invalid("isotropy must be in [0, 1]")
            }
            Policy::Error { .. } => Ok(()),
        }
    }

    /// Cost and placement of contractions, `None` for pass-through.
    pub(crate) fn objective(&self) -> Option<Objective> {
        match *self {
            Policy::None => None,
            Policy::Rate { .. } => Some(Objective::Quadric),
            Policy::Error { e0, isotropy, .. } => Some(Objective::Shape {
                e0,
                alpha: isotropy,
            }),
        }
    }

    pub(crate) fn schedule(&self) -> Schedule {
        match *self {
            Policy::None => Schedule::Off,
            Policy::Rate {
                rate,
                batch,
                initial_rate,
            } => Schedule::Rate(RateSchedule {
                rate,
                batch,
                initial_rate,
                initial_phase: rate < initial_rate,
                faces_at_last: 0,
                source_ratio: 1.0,
            }),
            Policy::Error { .. } => Schedule::Threshold,
        }
    }

    pub(crate) fn time_lag(&self) -> bool {
        matches!(self, Policy::Error { time_lag: true, .. })
    }
}

/// When decimation runs and where it stops.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) enum Schedule {
    Off,
    /// Down to a face count (Hou and Chen, section 4.2).
    Rate(RateSchedule),
    /// Until no candidate passes the objective's threshold (every candidate in the heap does, so:
    /// until the heap is empty).
    Threshold,
}

/// Face counts the rate target is computed from.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FaceCounts {
    /// `F_g`: faces extracted so far.
    pub(crate) generated: u64,
    /// `F_u`: resident faces with at least one non-modifiable vertex.
    pub(crate) unmodifiable: usize,
    /// Faces already handed to the writer.
    pub(crate) emitted: u64,
    /// Faces in memory.
    pub(crate) resident: usize,
    /// At most this many faces kept beyond the rate target in what leaves before the end (see
    /// [`HEDGE`]); 0 where this stage's output is not the job's (a cascade's first stage).
    pub(crate) hedge: u64,
}

/// What leaves before the end is decimated to this much more than the rate target of its
/// prefix, at most [`FaceCounts::hedge`] faces: the final decimation of the last band, which
/// knows everything written, takes the difference back (the final target is unchanged). The
/// stream keeps R of every prefix while in core keeps more where the rest of the volume turns
/// out cheaper to simplify (bonsai: a quarter more in its first 30 % along z, where three
/// quarters of the streamed gap to in core lay; `tools/zprofile.py`). Streamed over in-core RMS
/// at R = 0.2 with 1 / 1.03 / 1.05 / 1.07 / 1.1: bonsai 1.087 / 1.079 / 1.071 / 1.077 / 1.100,
/// engine 1.062 / 1.043 / 1.044 / 1.040 / 1.045 (docs/performance.md, "Forty-seventh session").
pub(crate) const HEDGE: f64 = 0.05;
/// [`FaceCounts::hedge`] as a share of the stage's face budget: what the last band, which holds
/// about its budget, gives back at the end stays a tenth of it however large the output (at
/// R = 0.2 bonsai upsampled 2x writes about 860 k faces through a band of about 70 k, where 5 %
/// of what left would be more than the whole band).
pub(crate) const HEDGE_BUDGET_SHARE: f64 = 0.1;

/// Share of the face budget a budget-driven pass leaves resident (see [`RateSchedule::kept`]):
/// the rest is room for the faces that arrive before the next pass.
const BUDGET_KEPT: f64 = 0.75;

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct RateSchedule {
    rate: f64,
    batch: u64,
    initial_rate: f64,
    initial_phase: bool,
    faces_at_last: u64,
    /// Input faces per extracted face: 1, except in the second stage of a cascade, whose input
    /// is the first stage's output (`cascade`).
    source_ratio: f64,
}

impl RateSchedule {
    /// The second stage of a cascade: its input is `ratio` of the extracted faces.
    pub(crate) fn set_source_ratio(&mut self, ratio: f64) {
        self.source_ratio = ratio;
    }

    /// The rate applied to this simplifier's own input faces.
    fn input_rate(&self) -> f64 {
        (self.rate / self.source_ratio).min(1.0)
    }

    /// Whether at least `batch` faces arrived since the last decimation (then remembers this one).
    pub(crate) fn due(&mut self, generated: u64) -> bool {
        let due = generated - self.faces_at_last >= self.batch;
        if due {
            self.faces_at_last = generated;
        }
        due
    }

    /// Faces a pass decimating for the memory budget (`batch` unset) leaves resident whatever
    /// the rate target says, as long as that brings the band within the budget (the stage goes
    /// on to the target only when faces must leave: `Stage::end_batch`): [`BUDGET_KEPT`] of the
    /// `budget`. The rate target ([`RateSchedule::resident_target`]) counts the faces next to the
    /// sweep front as contractible, yet most of their contractions must wait for the front (their
    /// fans reach past it), and before any face is written it is the initial phase's target,
    /// which halves the modifiable faces at every pass; where the output is small against the
    /// front (low rates, large slices) every pass chasing it contracted far past what the whole
    /// surface needs: bonsai upsampled to 511 x 511 x 256 at R = 0.01 came out with 3.8x the
    /// in-core RMS distance; 1.9x with this rule for passes made as the front moves on only (the
    /// twentieth session), 1.01x with it for every pass and the budget measured again (the
    /// twenty-first). Kept resident, those faces are decimated later among more of the surface,
    /// as in core; where the output is larger than the budget the rate target is the larger and
    /// rules as before. With `batch` set (Hou and Chen's schedule) the target is theirs alone.
    pub(crate) fn kept(&self, budget: usize) -> usize {
        if self.hou_chen_batches() {
            0
        } else {
            (budget as f64 * BUDGET_KEPT) as usize
        }
    }

    /// Whether `batch` is set: Hou and Chen's schedule, whose targets are theirs alone.
    fn hou_chen_batches(&self) -> bool {
        self.batch != u64::MAX
    }

    /// Resident face count to decimate down to after a batch.
    ///
    /// Hou and Chen (section 4.2): `F_t = (F_g - F_u) R + F_u` for the whole surface, of which
    /// `emitted` faces already left, so resident target `F_t - emitted`. While `R < R_i` an
    /// initial phase decimates the intermediate surface only by `R_i`:
    /// `(resident - F_u) R_i + F_u`, as long as that is the larger target; once the standard target
    /// catches up the phase ends for good. This avoids over-decimating the first batches, which
    /// would otherwise be squeezed to `R` of the whole (still small) surface. The phase also ends
    /// once faces have been emitted: Hou and Chen keep the whole surface resident, so their phase
    /// always ends; with retirement the emitted part is fixed, and only the standard target (which
    /// subtracts it) can still steer the overall rate to `R`.
    pub(crate) fn resident_target(&mut self, c: FaceCounts) -> usize {
        let standard = self.standard_target(c);
        if self.initial_phase {
            let fu = c.unmodifiable as f64;
            let initial = (c.resident as f64 - fu) * self.initial_rate + fu;
            if c.emitted == 0 && initial > standard as f64 {
                return initial.ceil() as usize;
            }
            self.initial_phase = false;
        }
        standard
    }

    /// Hou and Chen's `F_t - emitted` without the initial phase, plus the [`HEDGE`]: what faces
    /// that must leave for the memory budget are decimated to first (`Stage::end_batch`), so
    /// that they leave at about the density the whole output will have. The initial phase
    /// spares faces that stay resident; applied to faces about to be written it fixed their
    /// density for good: hydrogen upsampled
    /// to 2017^3 (`[output] faces = 10000`) met a 108 k-face slab before anything was written,
    /// halved the band behind it and wrote 21.9 k faces of its first 2.9 M at once, and the rest
    /// of the surface (6.7 M faces) was then squeezed into 176.
    pub(crate) fn standard_target(&self, c: FaceCounts) -> usize {
        let fu = c.unmodifiable as f64;
        let kept = (c.generated as f64 - fu) * self.input_rate();
        let hedge = if self.hou_chen_batches() {
            0.0
        } else {
            (kept * HEDGE).min(c.hedge as f64)
        };
        (kept + hedge + fu - c.emitted as f64).max(0.0).ceil() as usize
    }

    /// At the end every face is modifiable: `F_g R` overall, minus what was emitted already.
    pub(crate) fn final_target(&self, c: FaceCounts) -> usize {
        (c.generated as f64 * self.input_rate() - c.emitted as f64)
            .max(0.0)
            .ceil() as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rate(rate: f64, batch: u64, initial_rate: f64) -> RateSchedule {
        match (Policy::Rate {
            rate,
            batch,
            initial_rate,
        })
        .schedule()
        {
            Schedule::Rate(r) => r,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn validation() {
        let ok = |p: Policy| p.validate().is_ok();
        assert!(ok(Policy::None));
        assert!(ok(Policy::Rate {
            rate: 1.0,
            batch: 1,
            initial_rate: 0.5
        }));
        assert!(!ok(Policy::Rate {
            rate: 0.0,
            batch: 1,
            initial_rate: 0.5
        }));
        assert!(!ok(Policy::Rate {
            rate: f64::NAN,
            batch: 1,
            initial_rate: 0.5
        }));
        assert!(!ok(Policy::Rate {
            rate: 0.5,
            batch: 0,
            initial_rate: 0.5
        }));
        assert!(!ok(Policy::Rate {
            rate: 0.5,
            batch: 1,
            initial_rate: 1.5
        }));
        assert!(ok(Policy::Error {
            e0: 0.1,
            time_lag: true,
            isotropy: 0.0
        }));
        assert!(!ok(Policy::Error {
            e0: 0.0,
            time_lag: true,
            isotropy: 0.0
        }));
        assert!(!ok(Policy::Error {
            e0: 0.1,
            time_lag: false,
            isotropy: 1.5
        }));
    }

    #[test]
    fn batches_are_counted_in_faces() {
        let mut r = rate(0.5, 100, 0.5);
        assert!(!r.due(99));
        assert!(r.due(100));
        assert!(!r.due(150));
        assert!(r.due(200));
    }

    #[test]
    fn hou_chen_target() {
        let mut r = rate(0.1, 10, 0.1);
        let c = FaceCounts {
            hedge: 0,
            generated: 1000,
            unmodifiable: 100,
            emitted: 20,
            resident: 900,
        };
        // (1000 - 100) * 0.1 + 100 - 20
        assert_eq!(r.resident_target(c), 170);
        let c = FaceCounts { emitted: 500, ..c };
        assert_eq!(r.resident_target(c), 0);
        assert_eq!(r.final_target(FaceCounts { emitted: 50, ..c }), 50);
    }

    fn counts(generated: u64, unmodifiable: usize, emitted: u64, resident: usize) -> FaceCounts {
        FaceCounts {
            generated,
            unmodifiable,
            emitted,
            resident,
            hedge: 0,
        }
    }

    /// What leaves early keeps [`HEDGE`] more than the rate target, at most `hedge` faces; the
    /// final target does not change; Hou and Chen's schedule (`batch` set) has no hedge.
    #[test]
    fn the_hedge_is_a_share_of_the_target_capped_and_only_before_the_end() {
        let r = rate(0.1, u64::MAX, 0.1);
        let c = FaceCounts {
            hedge: 1000,
            ..counts(100_000, 0, 0, 0)
        };
        assert_eq!(r.standard_target(c), 10_000 + 500);
        assert_eq!(r.standard_target(FaceCounts { hedge: 100, ..c }), 10_100);
        assert_eq!(r.standard_target(FaceCounts { hedge: 0, ..c }), 10_000);
        assert_eq!(r.final_target(c), 10_000);
        assert_eq!(rate(0.1, 100, 0.1).standard_target(c), 10_000);
    }

    #[test]
    fn the_standard_target_has_no_initial_phase() {
        let mut r = rate(0.1, 10, 0.5);
        let early = counts(1000, 100, 0, 1000);
        assert_eq!(r.standard_target(early), 190);
        assert_eq!(
            r.resident_target(early),
            550,
            "asking did not end the phase"
        );
    }

    #[test]
    fn initial_phase_ends_once_the_standard_target_catches_up() {
        let mut r = rate(0.1, 10, 0.5);
        let early = counts(1000, 100, 0, 1000);
        // initial: 900 * 0.5 + 100 = 550 > standard 190
        assert_eq!(r.resident_target(early), 550);
        let later = counts(10_000, 100, 0, 1000);
        // initial 550 < standard 1090: the phase ends ...
        assert_eq!(r.resident_target(later), 1090);
        // ... and does not come back.
        assert_eq!(r.resident_target(early), 190);
    }

    #[test]
    fn a_second_stage_aims_at_the_rate_of_the_extracted_faces() {
        let mut r = rate(0.1, 10, 0.5);
        r.set_source_ratio(0.5);
        let c = counts(1000, 100, 0, 1000);
        // initial phase: (1000 - 100) * 0.5 + 100 = 550 > standard (1000 - 100) * (0.1 / 0.5) + 100
        assert_eq!(r.resident_target(c), 550);
        let c = FaceCounts { emitted: 1, ..c };
        assert_eq!(r.resident_target(c), 279);
        let c = FaceCounts { emitted: 0, ..c };
        assert_eq!(r.final_target(c), 200);
        r.set_source_ratio(0.05);
        assert_eq!(r.final_target(c), 1000, "never above the input");
    }

    #[test]
    fn a_budget_driven_pass_keeps_three_quarters_of_the_budget() {
        assert_eq!(rate(0.01, u64::MAX, 0.5).kept(1000), 750);
        assert_eq!(
            rate(0.01, 10_000, 0.5).kept(1000),
            0,
            "batch set: Hou and Chen's target"
        );
    }

    #[test]
    fn initial_phase_ends_when_output_starts() {
        let mut r = rate(0.1, 10, 0.5);
        let c = FaceCounts {
            hedge: 0,
            generated: 1000,
            unmodifiable: 100,
            emitted: 1,
            resident: 1000,
        };
        assert_eq!(r.resident_target(c), 189);
        assert_eq!(r.resident_target(FaceCounts { emitted: 0, ..c }), 190);
    }
}
