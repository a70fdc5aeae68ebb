//! Seeded random sampling of surfaces, area-proportional, as Metro does (Cignoni, Rocchini,
//! Scopigno 1998) and as the Tandem paper's section 4 "Approximation error" relies on.
//!
//! The generator is SplitMix64 (Steele, Lea, Flood 2014), written out here rather than taken from
//! `rand`: it is five lines, passes BigCrush, and its output is fixed forever, so a report made
//! with seed `s` today is reproduced bit for bit by any later build. `rand`'s `StdRng` makes no
//! such promise across versions.

use glam::DVec3;

use crate::MeasureError;
use crate::distances::FULL_SAMPLES_CAP;
use crate::triangle::{Triangle, area, uniform_point};

#[derive(Debug, Clone)]
pub(crate) struct SplitMix64(u64);

impl SplitMix64 {
    pub(crate) fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with the full 53 bits of mantissa.
    pub(crate) fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Most samples one triangle may take: twice what any density its callers settle on gives one
/// (`DistanceStream` keeps each triangle's expected count under `FULL_SAMPLES_CAP`). A larger
/// count comes of a density out of range (infinite, or a mesh's area out of scale with the
/// volume's), and was up to 2^64 draws.
pub(crate) const MAX_TRIANGLE_SAMPLES: f64 = 2.0 * FULL_SAMPLES_CAP;

/// Calls `visit` on about `density * area(t)` points spread uniformly over `t`, or refuses
/// (before any draw) when that count is not a number or exceeds [`MAX_TRIANGLE_SAMPLES`].
///
/// The count is `floor(density * area)` plus one more with probability equal to the fraction, so
/// every unit of area gets `density` samples in expectation however small the triangles are (the
/// full-resolution surface has triangles far below one sample each). Each sample then stands for
/// the same area, and plain averages over samples estimate the area integrals of the L_p distances.
pub(crate) fn sample_triangle(
    t: &Triangle,
    density: f64,
    rng: &mut SplitMix64,
    mut visit: impl FnMut(DVec3),
) -> Result<(), MeasureError> {
    let expected = density * area(t);
    if expected.is_nan() || expected > MAX_TRIANGLE_SAMPLES {
        return Err(MeasureError::Unsampleable(format!(
            "a triangle of area {:e} at {density:e} samples per unit area would take {expected:e} samples, over the {MAX_TRIANGLE_SAMPLES:e} one triangle may",
            area(t)
        )));
    }
    // Truncation is the floor of a non-negative count (and no library call, as `floor` is on
    // baseline x86-64).
    let mut count = expected as u64;
    if rng.next_f64() < expected - count as f64 {
        count += 1;
    }
    for _ in 0..count {
        let (r1, r2) = (rng.next_f64(), rng.next_f64());
        visit(uniform_point(t, r1, r2));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::triangle::tests::equilateral;

    #[test]
    fn splitmix_reference_values() {
        // First outputs for seed 1234567 from the reference C implementation.
        let mut rng = SplitMix64::new(1234567);
        assert_eq!(rng.next_u64(), 6457827717110365317);
        assert_eq!(rng.next_u64(), 3203168211198807973);
    }

    /// A density out of range (infinite, NaN, or finite but past any settled one) is refused
    /// before a single draw (an infinite one was `u64::MAX` draws).
    #[test]
    fn a_runaway_density_is_refused_before_drawing() {
        let mut rng = SplitMix64::new(3);
        for density in [1e18, f64::INFINITY, f64::NAN, 1e30] {
            let mut n = 0u64;
            let sampled = sample_triangle(&equilateral(1.0), density, &mut rng, |_| {
                n += 1;
                assert!(n < 100_000_000, "sampled without bound at {density}");
            });
            assert!(
                matches!(sampled, Err(MeasureError::Unsampleable(_))),
                "{density}: {sampled:?}"
            );
            assert_eq!(n, 0, "{density}");
        }
    }

    #[test]
    fn counts_follow_area_in_expectation() {
        let mut rng = SplitMix64::new(3);
        let tiny = equilateral(0.1); // area 0.00433: far below one sample per triangle
        let mut n = 0u64;
        for _ in 0..100_000 {
            sample_triangle(&tiny, 10.0, &mut rng, |_| n += 1).unwrap();
        }
        let expected = 100_000.0 * 10.0 * area(&tiny);
        assert!(
            (n as f64 - expected).abs() < 4.0 * expected.sqrt(),
            "{n} vs {expected}"
        );
    }
}
