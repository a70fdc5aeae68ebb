//! A quantile of the distances within the search radius to 0.1 %, in a fixed memory whatever
//! the number of samples.
//!
//! The 99.9th percentile was read from the 4096 equal bins of the histogram over the radius:
//! on a small sphere every seed and both directions gave the same 0.045669, one bin's edge,
//! 4-7 % above the quantile. Here each octave below the radius is cut into 1024 bins (the
//! float's exponent and its top 10 mantissa bits: no logarithm per sample), so a bin is at most
//! 1/1024 of its lower edge wide wherever the quantile falls.

/// Mantissa bits kept: 2^10 bins an octave, each at most 1/1024 (0.098 %) of its start wide.
const SUB_BITS: u32 = 10;
const SHIFT: u32 = 52 - SUB_BITS;
/// Octaves below the top binned apart (24 K bins, 192 KiB); distances below `top * 2^-24`
/// (a millionth of a voxel at the default radius) share the first bin.
const OCTAVES: i32 = 24;

/// Weighted counts of distances in `[0, top]`.
#[derive(Debug)]
pub(crate) struct LogBins {
    /// Key (bits shifted) of the first bin's upper part: everything up to `floor` is in bin 0.
    base: u64,
    floor: f64,
    counts: Vec<u64>,
}

impl LogBins {
    /// `top`: positive and finite (the search radius).
    pub(crate) fn new(top: f64) -> Self {
        let floor = top * 2f64.powi(-OCTAVES);
        let base = floor.to_bits() >> SHIFT;
        let last = top.to_bits() >> SHIFT;
        LogBins {
            base,
            floor,
            counts: vec![0; (last - base + 1) as usize],
        }
    }

    /// A distance in `[0, top]` standing for `weight` samples.
    pub(crate) fn add(&mut self, d: f64, weight: u64) {
        let i = if d <= self.floor {
            0
        } else {
            // Non-negative floats order as their bits do.
            ((d.to_bits() >> SHIFT) - self.base) as usize
        };
        let last = self.counts.len() - 1;
        self.counts[i.min(last)] += weight;
    }

    /// An upper bound on the distance within which `need` counted samples lie: the end of the
    /// bin that holds the `need`-th smallest, at most 1/1024 of it above it (or `top * 2^-24`
    /// for distances below that). `None` when fewer were counted.
    pub(crate) fn at_least(&self, need: u64) -> Option<f64> {
        let mut seen = 0;
        let i = self.counts.iter().position(|&k| {
            seen += k;
            seen >= need
        })?;
        Some(f64::from_bits((self.base + i as u64 + 1) << SHIFT))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::SplitMix64;

    /// Against a sort of the same samples: never below the exact quantile, at most 0.1 % above
    /// it, for spreads from a hair to the whole radius.
    #[test]
    fn the_bound_is_within_a_thousandth_of_the_sorted_quantile() {
        let mut rng = SplitMix64::new(3);
        for (lo, hi) in [(0.0, 1.0), (0.04, 0.046), (1e-5, 2e-5), (0.5, 0.5000001)] {
            let mut bins = LogBins::new(1.0);
            let mut all: Vec<f64> = (0..20_000)
                .map(|_| lo + (hi - lo) * rng.next_f64())
                .collect();
            all.iter().for_each(|&d| bins.add(d, 1));
            all.sort_unstable_by(f64::total_cmp);
            for q in [0.5, 0.9, 0.999, 1.0] {
                let need = (q * all.len() as f64).ceil() as u64;
                let exact = all[need as usize - 1];
                let got = bins.at_least(need).unwrap();
                assert!(
                    got >= exact && got <= exact * (1.0 + 1.0 / 1024.0),
                    "{lo}..{hi} q {q}: {got} against {exact}"
                );
            }
            assert_eq!(bins.at_least(all.len() as u64 + 1), None);
        }
    }

    #[test]
    fn zero_and_the_top_are_counted() {
        let mut bins = LogBins::new(2.0);
        bins.add(0.0, 1);
        bins.add(-0.0, 1);
        assert!(bins.at_least(2).unwrap() <= 2.0 * 2f64.powi(-OCTAVES) * 1.001);
        bins.add(2.0, 3);
        let top = bins.at_least(5).unwrap();
        assert!((2.0..=2.0 * (1.0 + 1.0 / 1024.0)).contains(&top), "{top}");
    }
}
