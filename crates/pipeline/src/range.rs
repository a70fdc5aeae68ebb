//! The values a run saw, for the error of an empty surface ("the data range is [0, 255]").

/// Smallest and largest finite value, how many voxels were NaN or infinite, and how many were
/// finite beyond f32's range and saturated to `±f32::MAX` when read.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct DataRange {
    min: f32,
    max: f32,
    non_finite: u64,
    saturated: u64,
}

impl Default for DataRange {
    fn default() -> Self {
        Self {
            min: f32::INFINITY,
            max: f32::NEG_INFINITY,
            non_finite: 0,
            saturated: 0,
        }
    }
}

/// Independent running minima, maxima and counts in [`DataRange::add`]: lanes the compiler
/// turns into vector instructions. One running `f32::min` through `&mut self` was a chain of
/// scalar steps with a store each: every voxel goes through here, and past a Gvoxel (where
/// empty space is skipped) that loop was most of the extraction's time (59 % of `isostream
/// measure` on a 65.6-Gvoxel job by `perf`).
const LANES: usize = 16;

impl DataRange {
    pub fn add(&mut self, values: &[f32]) {
        let mut lo = [f32::INFINITY; LANES];
        let mut hi = [f32::NEG_INFINITY; LANES];
        // At most `values.len() / LANES` each: no slice has 2^32 chunks.
        let mut bad = [0u32; LANES];
        let chunks = values.chunks_exact(LANES);
        let rest = chunks.remainder();
        for chunk in chunks {
            let chunk: &[f32; LANES] = chunk.try_into().expect("chunks of LANES values");
            for i in 0..LANES {
                let v = chunk[i];
                // False for NaN and both infinities, which then leave the lanes as they are.
                let finite = v.abs() < f32::INFINITY;
                let (l, h) = if finite {
                    (v, v)
                } else {
                    (f32::INFINITY, f32::NEG_INFINITY)
                };
                lo[i] = if l < lo[i] { l } else { lo[i] };
                hi[i] = if h > hi[i] { h } else { hi[i] };
                bad[i] += u32::from(!finite);
            }
        }
        for &v in rest {
            if v.is_finite() {
                self.min = self.min.min(v);
                self.max = self.max.max(v);
            } else {
                self.non_finite += 1;
            }
        }
        self.min = lo.into_iter().fold(self.min, f32::min);
        self.max = hi.into_iter().fold(self.max, f32::max);
        self.non_finite += bad.iter().map(|&b| u64::from(b)).sum::<u64>();
    }

    /// Finite values known to lie in the data without being seen (value bounds of blocks);
    /// `lo > hi` adds nothing.
    pub fn include(&mut self, (lo, hi): (f32, f32)) {
        if lo <= hi {
            self.min = self.min.min(lo);
            self.max = self.max.max(hi);
        }
    }

    /// Voxels the reader saturated (`VolumeSource::saturated_voxels`): their values, `±f32::MAX`,
    /// are in the range as any other, and the error says where they came from.
    pub fn add_saturated(&mut self, n: u64) {
        self.saturated += n;
    }

    /// Both parts together (slabs seen by different extractors).
    pub fn merge(&mut self, o: &DataRange) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.non_finite += o.non_finite;
        self.saturated += o.saturated;
    }

    /// "the data range is [0, 255], 12 NaN or infinite voxels": the finite range and what the
    /// reader met besides.
    fn range_text(&self) -> String {
        let mut s = format!(
            "the data range is [{}, {}]",
            value(self.min),
            value(self.max)
        );
        if self.non_finite > 0 {
            s.push_str(&format!(", {} NaN or infinite voxels", self.non_finite));
        }
        if self.saturated > 0 {
            s.push_str(&format!(
                ", {} voxels finite beyond f32's range read as ±{:e}",
                self.saturated,
                f32::MAX
            ));
        }
        s
    }

    /// Why the surface at `iso` is empty, and what to set instead (the run found no triangle).
    /// A voxel is inside when it is above iso and finite ([`isostream_extract::interp::is_inside`]):
    /// a surface needs a finite voxel above iso and one at or below it, so only an iso in
    /// [min, max) gives one. "Set extract.iso inside the data range" was wrong advice at the
    /// maximum (iso 7 on data [0, 7]: 7 is inside the range, and nothing is above it).
    ///
    /// `iso` is the job's, as written: extraction compares in f32, so where the iso and every
    /// finite voxel lie within one [`f32_step`] of each other the rounding itself may have
    /// emptied the surface (u32 voxels 4000000001 and 4000000003 and iso 4000000002 all read
    /// as 4000000000), and that is what is said, with the fix: no iso helps there.
    pub fn empty_surface(&self, iso: f64) -> String {
        let (lo, hi) = (self.min, self.max);
        if lo > hi {
            return format!(
                "the volume has no finite voxel (all {} are NaN or infinite, which count as \
                 outside), so no extract.iso gives a surface; fill those voxels in the input",
                self.non_finite
            );
        }
        let range = self.range_text();
        let step = f32_step(iso);
        let spread = f64::from(hi).max(iso) - f64::from(lo).min(iso);
        let exact = lo == hi && f64::from(lo) == iso;
        if spread <= step && !exact {
            return format!(
                "extract.iso and every finite voxel differ by less than f32's resolution at \
                 magnitude {} ({}, the step between neighbouring f32 values there), and voxels \
                 and iso are compared in f32, where they read as {} ({range}); subtract an \
                 offset near {} from the data (and from extract.iso), or rescale it, so that its \
                 variations are large against its magnitude",
                value(iso.abs()),
                value(step),
                value(iso as f32),
                value(iso as f32),
            );
        }
        let iso = iso as f32;
        let (iso_s, lo_s, hi_s) = (value(iso), value(lo), value(hi));
        if lo == hi {
            format!(
                "every finite voxel is {hi_s} ({range}), so no extract.iso gives a surface: \
                 voxels above iso are inside and those equal to it outside"
            )
        } else if iso == hi {
            format!(
                "iso {iso_s} is the data's maximum: voxels equal to iso count as outside, so \
                 nothing is inside; set extract.iso below {hi_s} ({range})"
            )
        } else if iso > hi {
            format!(
                "no voxel is above iso {iso_s}, so nothing is inside; set extract.iso below \
                 {hi_s} ({range})"
            )
        } else if iso < lo {
            format!(
                "every finite voxel is above iso {iso_s}, so nothing is outside; set \
                 extract.iso to at least {lo_s}, the data's minimum (voxels equal to iso count \
                 as outside), and below {hi_s} ({range})"
            )
        } else {
            format!("{range}; set extract.iso at least {lo_s} and below {hi_s}")
        }
    }
}

/// Why a stored type whose voxels all lie in `[lo, hi]` (`VolumeSource::stored_range`,
/// `dtype` its name) leaves no surface at `iso`, known before any voxel is read; `None` when
/// the type allows one. [`DataRange::empty_surface`]'s rule (only an iso in [min, max) gives a
/// surface) on the type's range, compared in f32 as extraction compares.
pub(crate) fn ruled_out_by_type(iso: f64, dtype: &str, (lo, hi): (f32, f32)) -> Option<String> {
    let iso32 = iso as f32;
    let (iso_s, lo_s, hi_s) = (value(iso), value(lo), value(hi));
    if iso32 >= hi {
        Some(format!(
            "the input's voxels are {dtype}, at most {hi_s}, so none is above iso {iso_s} and \
             nothing is inside; set extract.iso below {hi_s}"
        ))
    } else if iso32 < lo {
        Some(format!(
            "the input's voxels are {dtype}, at least {lo_s}, so every one is above iso {iso_s} \
             and nothing is outside; set extract.iso to at least {lo_s}"
        ))
    } else {
        None
    }
}

/// [`DataRange::coarse_iso`] warns when the f32 step at the iso passes this fraction of the
/// data's range: there the rounding to f32 is a visible part of every voxel difference.
const COARSE_STEP: f64 = 1e-3;

impl DataRange {
    /// A warning when extraction's f32 cannot resolve the data near `iso` (the job's, as
    /// written): the step between neighbouring f32 values at the iso's magnitude is more than
    /// [`COARSE_STEP`] of the data's range as read (the magnitude more than about 8,400 times
    /// the range). f64 data around 101325 varying by 0.01 came out with radius errors 10 times
    /// those of the same data less 101325, with no word said. The range is the one the run
    /// already keeps for the empty-surface error, so the check costs nothing.
    pub fn coarse_iso(&self, iso: f64, input: &str) -> Option<String> {
        let (lo, hi) = (f64::from(self.min), f64::from(self.max));
        let step = f32_step(iso);
        (lo <= hi && step > COARSE_STEP * (hi - lo)).then(|| {
            format!(
                "{input}: extract.iso = {} and the voxels are compared in f32, whose step at that \
                 magnitude ({}) is {:.2} % of the data's range as read [{}, {}]: the values are \
                 rounded to that step before the surface is placed, which moves it by up to the \
                 step over the values' change across a voxel, in voxels; subtract an offset near \
                 {} from the data (and from extract.iso), or rescale it",
                value(iso),
                value(step),
                100.0 * step / (hi - lo),
                value(self.min),
                value(self.max),
                value(iso as f32),
            )
        })
    }
}

/// The spacing of `f32` values at `x`'s magnitude (the gap above `|x|` rounded to f32): how
/// finely extraction, which computes in f32, tells values near `x` apart.
pub(crate) fn f32_step(x: f64) -> f64 {
    let a = (x.abs() as f32).min(f32::MAX);
    f64::from(f32::from_bits(a.to_bits() + 1)) - f64::from(a)
}

/// A value as the messages show it (an `f32` voxel or an `f64` iso or step, each printed as its
/// own type prints it): plainly, but in scientific notation where plain would be a row of zeros
/// (f32::MAX is "340282350000000000000000000000000000000").
pub(crate) fn value<T>(v: T) -> String
where
    T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
{
    match v.into().abs() {
        a if a == 0.0 || (1e-4..1e16).contains(&a) => v.to_string(),
        _ => format!("{v:e}"),
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// The lanes give what one scalar pass gives, NaN and infinities included.
    fn scalar(values: &[f32]) -> DataRange {
        let finite: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
        DataRange {
            min: finite.iter().copied().fold(f32::INFINITY, f32::min),
            max: finite.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            non_finite: (values.len() - finite.len()) as u64,
            saturated: 0,
        }
    }

    fn value() -> impl Strategy<Value = f32> {
        prop_oneof![
            8 => -1e6f32..1e6,
            1 => Just(f32::NAN),
            1 => Just(f32::INFINITY),
            1 => Just(f32::NEG_INFINITY),
            1 => Just(f32::MAX),
            1 => Just(-f32::MAX),
        ]
    }

    proptest! {
        #[test]
        fn lanes_equal_one_scalar_pass(
            parts in prop::collection::vec(prop::collection::vec(value(), 0..70), 1..4),
        ) {
            let mut range = DataRange::default();
            for p in &parts {
                range.add(p);
            }
            let all: Vec<f32> = parts.concat();
            prop_assert_eq!(range, scalar(&all));
        }
    }

    #[test]
    fn no_finite_voxel_is_said() {
        let mut range = DataRange::default();
        range.add(&[f32::NAN; 20]);
        let said = range.empty_surface(0.5);
        assert!(
            said.starts_with("the volume has no finite voxel (all 20 are NaN"),
            "{said}"
        );
    }

    /// Saturated voxels are said, in scientific notation, where they make the range.
    #[test]
    fn saturated_voxels_are_said() {
        let mut range = DataRange::default();
        range.add(&[f32::MAX; 8]);
        range.add_saturated(8);
        assert_eq!(
            range.empty_surface(0.5),
            "every finite voxel is 3.4028235e38 (the data range is [3.4028235e38, 3.4028235e38], 8 voxels finite beyond f32's range read as ±3.4028235e38), so no extract.iso gives a surface: voxels above iso are inside and those equal to it outside"
        );
    }

    /// u32 voxels 4000000001 and 4000000003 read as 4000000000 in f32, and iso 4000000002 too:
    /// "every finite voxel is 4000000000 ... no extract.iso gives a surface" misstated both
    /// and gave no fix. What is said is the rounding, its size, and the offset to take off.
    #[test]
    fn an_iso_within_f32_resolution_of_the_data_says_so() {
        let mut range = DataRange::default();
        range.add(&[4_000_000_001.0f64 as f32, 4_000_000_003.0f64 as f32]);
        assert_eq!(
            range.empty_surface(4_000_000_002.0),
            "extract.iso and every finite voxel differ by less than f32's resolution at magnitude 4000000002 (256, the step between neighbouring f32 values there), and voxels and iso are compared in f32, where they read as 4000000000 (the data range is [4000000000, 4000000000]); subtract an offset near 4000000000 from the data (and from extract.iso), or rescale it, so that its variations are large against its magnitude"
        );
        // Data constant at the iso as written: nothing was rounded, the range's own words.
        let mut seven = DataRange::default();
        seven.add(&[7.0; 4]);
        assert!(
            seven
                .empty_surface(7.0)
                .starts_with("every finite voxel is 7")
        );
        assert!(f32_step(1.0) == f64::from(f32::EPSILON) && f32_step(-3e9) == 256.0);
    }

    /// f64 data around 101325 varying by 0.01: the f32 step there (1/128) is most of the range,
    /// and is warned about; u8 data at iso 128 is not.
    #[test]
    fn an_iso_coarse_against_the_data_range_is_warned_about() {
        let mut pressure = DataRange::default();
        pressure.add(&[101_324.99f64 as f32, 101_325.01f64 as f32]);
        let said = pressure.coarse_iso(101_325.0, "p.raw").unwrap();
        assert!(
            said.starts_with("p.raw: extract.iso = 101325 and the voxels are compared in f32, whose step at that magnitude (0.0078125) is 50.00 % of the data's range as read [101324.99, 101325.01]"),
            "{said}"
        );
        assert!(
            said.ends_with(
                "subtract an offset near 101325 from the data (and from extract.iso), or rescale it"
            ),
            "{said}"
        );
        let mut bytes = DataRange::default();
        bytes.add(&[0.0, 255.0]);
        assert_eq!(bytes.coarse_iso(128.0, "b.raw"), None);
        assert_eq!(DataRange::default().coarse_iso(1e9, "none"), None);
    }

    /// Each side of the range says what is wrong and what to set. At the maximum, iso is inside
    /// the data range and nothing is above it: "set extract.iso inside the data range" was no
    /// help.
    #[test]
    fn each_side_of_the_range_says_what_to_set() {
        let mut range = DataRange::default();
        range.add(&[0.0, 7.0, 7.0, 0.0]);
        assert_eq!(
            range.empty_surface(7.0),
            "iso 7 is the data's maximum: voxels equal to iso count as outside, so nothing is inside; set extract.iso below 7 (the data range is [0, 7])"
        );
        assert_eq!(
            range.empty_surface(9.5),
            "no voxel is above iso 9.5, so nothing is inside; set extract.iso below 7 (the data range is [0, 7])"
        );
        assert_eq!(
            range.empty_surface(-1.0),
            "every finite voxel is above iso -1, so nothing is outside; set extract.iso to at least 0, the data's minimum (voxels equal to iso count as outside), and below 7 (the data range is [0, 7])"
        );
        range.add(&[f32::NAN]);
        assert_eq!(
            range.empty_surface(3.0),
            "the data range is [0, 7], 1 NaN or infinite voxels; set extract.iso at least 0 and below 7"
        );
    }

    /// An iso the stored type rules out is told before any voxel is read, on the same rule as
    /// the data range's: its maximum and beyond have nothing inside, below its minimum nothing
    /// outside; the minimum itself and anything short of the maximum may give a surface.
    #[test]
    fn an_iso_the_stored_type_rules_out_says_what_to_set() {
        let u8_range = (0.0, 255.0);
        assert_eq!(
            ruled_out_by_type(300.0, "u8", u8_range).as_deref(),
            Some(
                "the input's voxels are u8, at most 255, so none is above iso 300 and nothing is inside; set extract.iso below 255"
            )
        );
        assert!(ruled_out_by_type(255.0, "u8", u8_range).is_some());
        assert_eq!(
            ruled_out_by_type(-5.0, "u8", u8_range).as_deref(),
            Some(
                "the input's voxels are u8, at least 0, so every one is above iso -5 and nothing is outside; set extract.iso to at least 0"
            )
        );
        for iso in [0.0, 128.0, 254.5] {
            assert_eq!(ruled_out_by_type(iso, "u8", u8_range), None, "iso {iso}");
        }
        // Compared in f32: an iso that rounds onto u32's largest value is as high as any voxel.
        let u32_range = (0.0, u32::MAX as f32);
        assert!(ruled_out_by_type(f64::from(u32::MAX), "u32", u32_range).is_some());
        assert_eq!(ruled_out_by_type(4e9, "u32", u32_range), None);
    }
}
