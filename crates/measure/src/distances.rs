//! Metro-style distances between the output mesh and the full-resolution iso-surface, Tandem paper
//! section 4 "Approximation error": directed `L_p(M|N) = (1/area(M) int_M d^p(x, N) dx)^(1/p)` for
//! p = 1 (mean), 2 (RMS) and infinity (Hausdorff), estimated from area-proportional samples as
//! Metro does, and the undirected distance as the larger of the two directions.
//!
//! The output mesh is in memory and indexed once by a BVH. The full-resolution surface arrives in
//! batches in z order (slab by slab), each with the `front`: the lowest z any later triangle can
//! have. Memory is bounded by a window of batches `2 r` high, `r = max_distance`:
//!
//! * full -> output: every batch triangle is sampled and each sample queries the output BVH.
//! * output -> full: the output mesh is sampled up front and the samples sorted by z. A sample at
//!   height `z` can only have full-resolution points within `r` in `[z - r, z + r]`, so once the
//!   front passes `z + r` every candidate is in the window: the sample is measured then, against
//!   the window's batches (each with its own small BVH), those spanning `z` first, so the bound
//!   found in its own slab prunes the others by their vertical gap. Batches entirely below the
//!   lowest pending sample's `z - r` leave the window, and a batch enters it with only the
//!   triangles within `r` across of a pending sample of its heights (`Reach`). Samples with
//!   nothing within `r` ("far") are set aside and measured exactly against the whole surface in
//!   a second pass (`far`): counted at `r`, they made the Hausdorff distance and the 99.9th
//!   percentile silent lower bounds.
//!
//! Measuring each sample against every batch as it passed would need no window at all, but then a
//! sample meets the slabs below it first, with nothing but `r` to prune the search: on a 256^3
//! gyroid the whole measurement was 2.7 times slower that way.

use std::collections::VecDeque;

use glam::DVec3;
use serde::Serialize;

use crate::MeasureError;
use crate::bvh::Bvh;
use crate::far::{FarSamples, Landmarks};
use crate::halves::{Halves, InTurn};
use crate::quantile::LogBins;
use crate::sampling::{SplitMix64, sample_triangle};
use crate::triangle::{Triangle, area};

/// Samples per unit of area when none is given: a sphere of radius 10 voxels (unit spacing) then
/// gets about 12 000 samples per direction.
pub const DEFAULT_SAMPLES_PER_AREA: f64 = 10.0;
/// Floor on the samples per direction: the density is raised to reach it, so meshes in small
/// units (millimetres given in metres) still get a meaningful estimate.
pub const MIN_SAMPLES: f64 = 10_000.0;
/// Cap on the samples per direction: the density is lowered to stay under it, which bounds the
/// running time (one exact nearest-point query per sample; about 10 s for both directions of a
/// 2-million-triangle surface on one core) and the memory of the output samples (24 bytes each).
pub const MAX_SAMPLES: f64 = 4_000_000.0;
/// Samples of the full-resolution surface past which its density falls: a quarter (each sample
/// then counting four times) once the surface seen so far would take this many at the output's
/// density, a sixteenth past twice that area, and so on, so that every later doubling of the
/// area takes half the samples of the one before. The full surface is sampled at the output's
/// density, about as many samples as the output gets when the two have about the same area; an
/// output far smaller (another volume's mesh, or one in other units, whose density
/// [`MIN_SAMPLES`] then raises) otherwise drew samples without bound: a unit tetrahedron against
/// bonsai's surface took 1.6 billion of them and two minutes. Never reached when the full
/// surface has less than four times the output's area.
pub(crate) const FULL_SAMPLES_CAP: f64 = 4.0 * MAX_SAMPLES;
/// Default search radius of the first pass of the output -> full direction, in voxel diagonals.
/// A simplified mesh within its error bound stays well inside a few voxels of the
/// full-resolution surface; the few samples farther than that are measured in a second pass.
pub const DEFAULT_SEARCH_VOXEL_DIAGONALS: f64 = 4.0;
/// Most bins of each direction's distance histogram.
pub const DISTANCE_BINS: usize = 20;
/// Samples are counted in this many bins over `[0, max_distance]` as they come (the largest
/// distance is not known before the end), then merged into at most [`DISTANCE_BINS`] covering
/// the distances seen: the bins follow the data even when it stays far inside the search radius.
/// The quantile is not read from them (they are `max_distance / 4096` wide, 4-7 % of it on a
/// small sphere) but from [`LogBins`].
const FINE_BINS: usize = 4096;
/// Full-resolution samples drawn before their distances are computed, in two halves: 2 MiB of
/// points and weights, so that a slab of any size adds little memory.
const SAMPLE_CHUNK: usize = 1 << 16;
/// Distances past the search radius kept for the quantile (16 MiB at most); past that the
/// quantile there is the largest distance.
const BEYOND_KEPT: usize = 1 << 20;
/// The share of the samples [`DirectedDistance::p999`] bounds.
const QUANTILE: f64 = 0.999;
/// Default seed: reports are reproducible unless a seed is asked for.
pub const DEFAULT_SEED: u64 = 0x1505_7EA3;

/// How the distances are sampled.
#[derive(Debug, Clone)]
pub struct MeasureOptions {
    /// Samples per unit^2 of surface (default [`DEFAULT_SAMPLES_PER_AREA`]). The density actually
    /// used is clamped so that the output mesh gets between [`MIN_SAMPLES`] and [`MAX_SAMPLES`]
    /// samples; the full-resolution surface, of about the same area, is sampled at the same density.
    pub samples_per_area: f64,
    /// Seed of the sample positions; equal seeds give identical reports.
    pub seed: u64,
    /// Search radius of the first pass of the output -> full direction in the volume's units
    /// (default [`DEFAULT_SEARCH_VOXEL_DIAGONALS`] voxel diagonals). It changes no distance, only
    /// the work: every sample is compared with all slabs within it, and the samples with nothing
    /// within it need a second pass over the surface.
    pub max_distance: Option<f64>,
}

impl Default for MeasureOptions {
    fn default() -> Self {
        MeasureOptions {
            samples_per_area: DEFAULT_SAMPLES_PER_AREA,
            seed: DEFAULT_SEED,
            max_distance: None,
        }
    }
}

/// One direction of the distance, `L_p(M|N)` with M the sampled surface.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DirectedDistance {
    /// L_1: mean distance.
    pub mean: f64,
    /// L_2: root mean square distance.
    pub rms: f64,
    /// L_infinity over the samples: Hausdorff distance.
    pub hausdorff: f64,
    /// The distance 99.9 % of the samples are within: within `max_distance`, from bins 1/1024
    /// of an octave wide, never below the exact quantile of the samples and at most 0.1 % above
    /// it (and never above `hausdorff`); past `max_distance`, where the bins end, the exact
    /// quantile of the distances there, or `hausdorff` when over a million were (never below the
    /// exact quantile either way). Why beside the Hausdorff
    /// distance: that is one sample's distance, and small changes of the order of contractions move it by a factor of two or three (engine
    /// at R = 0.2 in core: 0.063 to 0.197 % of the diagonal, docs/performance.md "Twenty-seventh
    /// session"), while the 99.9th percentile follows the surface as a whole.
    pub p999: f64,
    /// Samples drawn (full -> output: each counts `Distances::full_sample_weight` times or
    /// less, see there).
    pub samples: u64,
    /// `(bin start, samples counted by their weight)`: at most [`DISTANCE_BINS`] bins of equal
    /// width from 0 up to just past the largest distance (the width a multiple of `max_distance
    /// / 4096`); distances past `max_distance` count in the last bin.
    pub histogram: Vec<(f64, u64)>,
}

/// Both directions, the undirected distances (the larger of the two, section 4) and the same in
/// percent of the bounding-box diagonal of both surfaces.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Distances {
    pub full_to_output: DirectedDistance,
    pub output_to_full: DirectedDistance,
    pub mean: f64,
    pub rms: f64,
    pub hausdorff: f64,
    /// The larger of the two directions' [`DirectedDistance::p999`].
    pub p999: f64,
    /// Diagonal of the bounding box of both surfaces.
    pub diagonal: f64,
    pub mean_pct: f64,
    pub rms_pct: f64,
    pub hausdorff_pct: f64,
    pub p999_pct: f64,
    pub full_resolution_triangles: u64,
    /// How many times each of the last full-resolution samples counts: 1, or a power of four
    /// once the full surface outgrew the output's sample budget (see `FULL_SAMPLES_CAP`), when
    /// its later parts were sampled that much more sparsely.
    pub full_sample_weight: u64,
    /// Output samples with no full-resolution point within `max_distance`, measured exactly in a
    /// second pass over the full-resolution surface (no distance is a bound).
    pub far_samples: u64,
    /// The search radius of the first pass of output -> full.
    pub max_distance: f64,
    /// The sampling density used, after clamping.
    pub samples_per_area: f64,
}

#[derive(Debug)]
struct Accumulator {
    sum: f64,
    sum_squares: f64,
    max: f64,
    /// Samples, each counted by its weight.
    count: u64,
    /// Samples drawn.
    samples: u64,
    radius: f64,
    bin_width: f64,
    /// The histogram's bins.
    bins: Vec<u64>,
    /// The distances up to the radius, for the quantile.
    near: LogBins,
    /// The distances past the radius (which the last bin counts with the others) and their
    /// weights, for the quantile when it lies there; `None` once more than [`BEYOND_KEPT`].
    beyond: Option<Vec<(f64, u64)>>,
}

impl Accumulator {
    /// Histogram bins over `[0, radius]`.
    fn new(radius: f64) -> Self {
        Accumulator {
            sum: 0.0,
            sum_squares: 0.0,
            max: 0.0,
            count: 0,
            samples: 0,
            radius,
            bin_width: radius / FINE_BINS as f64,
            bins: vec![0; FINE_BINS],
            near: LogBins::new(radius),
            beyond: Some(Vec::new()),
        }
    }

    /// A distance standing for `weight` samples.
    fn add(&mut self, d: f64, weight: u64) {
        // `f64::max` passes over NaN: a NaN distance would vanish from the maximum and the
        // report's larger-of-both-directions while it spoiled the sums.
        debug_assert!(!d.is_nan(), "a NaN distance");
        let w = weight as f64;
        self.sum += w * d;
        self.sum_squares += w * d * d;
        self.max = self.max.max(d);
        self.count += weight;
        self.samples += 1;
        let bin = (d / self.bin_width) as usize;
        self.bins[bin.min(FINE_BINS - 1)] += weight;
        if d <= self.radius {
            self.near.add(d, weight);
        } else if let Some(beyond) = &mut self.beyond {
            if beyond.len() < BEYOND_KEPT {
                beyond.push((d, weight));
            } else {
                self.beyond = None;
            }
        }
    }

    fn finish(&self) -> DirectedDistance {
        let n = self.count as f64;
        DirectedDistance {
            mean: self.sum / n,
            rms: (self.sum_squares / n).sqrt(),
            hausdorff: self.max,
            p999: self.quantile(QUANTILE),
            samples: self.samples,
            histogram: self.histogram(),
        }
    }

    /// A share `q` of the samples is within it: within the radius, from [`LogBins`] (at most
    /// 0.1 % above the exact quantile), capped by the largest distance; past the radius, the
    /// kept distances there, exactly, or the largest distance when too many were past it to
    /// keep: the radius was reported before, below most of the samples of a mesh far from the
    /// surface (meshoptimizer's bonsai output: 1.62 % of the diagonal, where the largest
    /// distance is 6.22 %).
    fn quantile(&self, q: f64) -> f64 {
        let need = ((q * self.count as f64).ceil() as u64).max(1);
        if let Some(d) = self.near.at_least(need) {
            return d.min(self.max);
        }
        let Some(beyond) = &self.beyond else {
            return self.max;
        };
        let mut seen = self.count - beyond.iter().map(|&(_, w)| w).sum::<u64>();
        let mut sorted = beyond.clone();
        sorted.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        sorted
            .iter()
            .find(|&&(_, w)| {
                seen += w;
                seen >= need
            })
            .map_or(self.max, |&(d, _)| d)
    }

    /// The fine bins up to the last one used, merged into at most [`DISTANCE_BINS`].
    fn histogram(&self) -> Vec<(f64, u64)> {
        let used = self.bins.iter().rposition(|&k| k > 0).map_or(1, |i| i + 1);
        let per = used.div_ceil(DISTANCE_BINS);
        self.bins[..used]
            .chunks(per)
            .enumerate()
            .map(|(i, c)| ((i * per) as f64 * self.bin_width, c.iter().sum()))
            .collect()
    }
}

/// Both directions of the distance while the full-resolution surface streams by in batches.
#[derive(Debug)]
pub(crate) struct DistanceStream {
    output: Bvh,
    density: f64,
    radius: f64,
    rng: SplitMix64,
    full_to_output: Accumulator,
    /// Output triangle nearest to the last full-resolution sample: the next is likely near it.
    output_hint: usize,
    /// Runs a chunk's two halves of full -> output queries ([`InTurn`] unless the caller lends
    /// two threads).
    halves: Box<dyn Halves>,
    /// Full-resolution samples drawn and not yet measured, with their weights.
    drawn: Vec<(DVec3, u64)>,
    /// Output samples sorted by z; those before `next` are measured.
    samples: Vec<DVec3>,
    next: usize,
    output_to_full: Accumulator,
    /// Output samples with nothing within the radius, sorted by z: for the second pass.
    far: Vec<DVec3>,
    /// Points of the full surface drawn so far: bounds for the far samples' second pass.
    landmarks: Landmarks,
    window: VecDeque<WindowBatch>,
    full_triangles: u64,
    /// Area of the full-resolution triangles seen so far.
    full_area: f64,
    /// What each full-resolution sample counts for; the density over it is theirs.
    full_weight: u64,
    /// [`FULL_SAMPLES_CAP`] (smaller in tests).
    full_cap: f64,
    /// Why the full surface could not be sampled, kept for `finish` to report (the callers'
    /// batch visitors cannot fail); later batches are ignored.
    refused: Option<MeasureError>,
    bounds: (DVec3, DVec3),
}

/// A batch of full-resolution triangles kept while output samples within `r` may need it.
#[derive(Debug)]
struct WindowBatch {
    z_min: f64,
    z_max: f64,
    bvh: Bvh,
}

impl WindowBatch {
    /// Vertical gap from `z` to the batch: a lower bound on the distance to its triangles.
    fn gap(&self, z: f64) -> f64 {
        (self.z_min - z).max(z - self.z_max).max(0.0)
    }
}

/// Where the output samples that may still need a batch lie, in columns `r` wide: a triangle
/// farther than `r` across from every such sample is never any sample's nearest within `r`, so
/// the window need not hold it. The window held every triangle of its slabs, and where a
/// nearly flat surface crosses the slabs (hundreds of thousands of triangles each) against a
/// few hundred output samples nearby that was most of `isostream measure`'s memory.
struct Reach {
    radius: f64,
    /// Column of the first cell and cells per row and column.
    origin: [i64; 2],
    size: [i64; 2],
    /// Whether a sample lies in each cell (row-major).
    cells: Vec<bool>,
}

impl Reach {
    /// The columns of `pending` samples (sorted by z) within `radius` of heights `z_min..=z_max`.
    fn of(pending: &[DVec3], z_min: f64, z_max: f64, radius: f64) -> Self {
        let from = pending.partition_point(|p| p.z < z_min - radius);
        let to = pending.partition_point(|p| p.z <= z_max + radius);
        let near = &pending[from..to.max(from)];
        let cell = |p: &DVec3| [floor(p.x / radius), floor(p.y / radius)];
        let (lo, hi) = near
            .iter()
            .map(cell)
            .fold(([i64::MAX; 2], [i64::MIN; 2]), |(lo, hi), c| {
                (
                    [lo[0].min(c[0]), lo[1].min(c[1])],
                    [hi[0].max(c[0]), hi[1].max(c[1])],
                )
            });
        let size = if near.is_empty() {
            [0, 0]
        } else {
            [hi[0] - lo[0] + 1, hi[1] - lo[1] + 1]
        };
        let mut cells = vec![false; (size[0] * size[1]) as usize];
        for c in near.iter().map(cell) {
            cells[((c[1] - lo[1]) * size[0] + c[0] - lo[0]) as usize] = true;
        }
        Self {
            radius,
            origin: lo,
            size,
            cells,
        }
    }

    /// Whether a sample's column cell lies within `radius` across (in x and y) of `t`'s box.
    fn touches(&self, t: &Triangle) -> bool {
        let r = self.radius;
        let (lo, hi) = t.iter().fold(
            ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]),
            |(lo, hi), p| {
                (
                    [lo[0].min(p.x), lo[1].min(p.y)],
                    [hi[0].max(p.x), hi[1].max(p.y)],
                )
            },
        );
        let span = |k: usize| {
            let a = floor((lo[k] - r) / r) - self.origin[k];
            let b = floor((hi[k] + r) / r) - self.origin[k];
            a.max(0)..=b.min(self.size[k] - 1)
        };
        span(1).any(|y| span(0).any(|x| self.cells[(y * self.size[0] + x) as usize]))
    }
}

impl DistanceStream {
    /// Indexes and samples the output mesh. `radius` is the resolved `max_distance`.
    pub(crate) fn new(
        positions: &[[f64; 3]],
        triangles: &[[u32; 3]],
        opts: &MeasureOptions,
        radius: f64,
    ) -> Result<Self, MeasureError> {
        if !(opts.samples_per_area.is_finite() && opts.samples_per_area > 0.0) {
            return Err(MeasureError::SamplesPerArea(opts.samples_per_area));
        }
        if !(radius.is_finite() && radius > 0.0) {
            return Err(MeasureError::MaxDistance(radius));
        }
        let tris = output_triangles(positions, triangles)?;
        let total_area: f64 = tris.iter().map(area).sum();
        if total_area <= 0.0 {
            return Err(MeasureError::EmptyOutput);
        }
        // A NaN area made the density's clamp panic; an infinite one left no samples.
        if !total_area.is_finite() {
            return Err(MeasureError::Unsampleable(format!(
                "its area is {total_area}: a coordinate is out of range"
            )));
        }
        let density = opts
            .samples_per_area
            .clamp(MIN_SAMPLES / total_area, MAX_SAMPLES / total_area);

        // Two generators from one seed: the output's samples do not depend on the volume, and the
        // full surface's do not depend on the output mesh's size.
        let mut rng = SplitMix64::new(opts.seed);
        let mut samples = Vec::with_capacity((density * total_area * 1.01) as usize + 16);
        for t in &tris {
            sample_triangle(t, density, &mut rng, |p| samples.push(p))?;
        }
        samples.sort_unstable_by(|a, b| a.z.total_cmp(&b.z));
        let bounds = tris
            .iter()
            .flatten()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            });
        Ok(DistanceStream {
            output: Bvh::new(tris),
            density,
            radius,
            rng: SplitMix64::new(opts.seed ^ 0x5EED_F011_0000_0001),
            full_to_output: Accumulator::new(radius),
            output_hint: 0,
            halves: Box::new(InTurn),
            drawn: Vec::new(),
            samples,
            next: 0,
            output_to_full: Accumulator::new(radius),
            far: Vec::new(),
            landmarks: Landmarks::new(radius),
            window: VecDeque::new(),
            full_triangles: 0,
            full_area: 0.0,
            full_weight: 1,
            full_cap: FULL_SAMPLES_CAP,
            refused: None,
            bounds,
        })
    }

    /// Takes the next batch of full-resolution triangles. `front` is a lower bound on the z of
    /// every triangle of later batches (the bottom slice of the slab still to come). A batch
    /// that cannot be sampled is refused at `finish`, and nothing after it is sampled.
    pub(crate) fn add_batch(&mut self, batch: Vec<Triangle>, front: f64) {
        if self.refused.is_some() {
            return;
        }
        if !batch.is_empty() {
            let (z_min, z_max) = match self.sample_full(&batch) {
                Ok(heights) => heights,
                Err(e) => {
                    self.refused = Some(e);
                    self.window.clear();
                    return;
                }
            };
            let reach = Reach::of(&self.samples[self.next..], z_min, z_max, self.radius);
            let mut kept: Vec<Triangle> = batch.into_iter().filter(|t| reach.touches(t)).collect();
            // The filter reuses the batch's allocation, which the window would otherwise hold.
            kept.shrink_to_fit();
            if !kept.is_empty() {
                let (z_min, z_max) = kept
                    .iter()
                    .flatten()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                        (lo.min(p.z), hi.max(p.z))
                    });
                self.window.push_back(WindowBatch {
                    z_min,
                    z_max,
                    bvh: Bvh::new(kept),
                });
            }
        }
        self.advance(front);
    }

    /// Draws the samples of a batch of full-resolution triangles and measures them, thinning
    /// the surface as its area grows; gives the batch's lowest and highest z.
    fn sample_full(&mut self, batch: &[Triangle]) -> Result<(f64, f64), MeasureError> {
        self.full_triangles += batch.len() as u64;
        let (mut z_min, mut z_max) = (f64::INFINITY, f64::NEG_INFINITY);
        for t in batch {
            for &p in t {
                self.bounds = (self.bounds.0.min(p), self.bounds.1.max(p));
                z_min = z_min.min(p.z);
                z_max = z_max.max(p.z);
            }
            self.full_area += area(t);
            let wanted = self.full_area * self.density;
            self.full_weight = thinned_weight(wanted, self.full_cap, self.full_weight).ok_or_else(|| {
                MeasureError::Unsampleable(format!(
                    "the full-resolution surface's area {:e} at {:e} samples per unit area would take {wanted:e} samples, which no sample weight below 2^64 thins to {:e}",
                    self.full_area, self.density, self.full_cap
                ))
            })?;
            let (weight, drawn) = (self.full_weight, &mut self.drawn);
            let density = self.density / weight as f64;
            sample_triangle(t, density, &mut self.rng, |p| drawn.push((p, weight)))?;
            if self.drawn.len() >= SAMPLE_CHUNK {
                self.measure_drawn();
            }
        }
        self.measure_drawn();
        Ok((z_min, z_max))
    }

    /// Runs on two threads from now on when `halves` has them.
    pub(crate) fn set_halves(&mut self, halves: Box<dyn Halves>) {
        self.halves = halves;
    }

    /// The full -> output distances of the samples drawn so far, in two halves that `halves`
    /// may run at once (each with its own hint: a hint only saves work, the distances are
    /// exact), added in the order they were drawn, so the sums do not depend on the threads.
    fn measure_drawn(&mut self) {
        if self.drawn.is_empty() {
            return;
        }
        let (first, second) = self.drawn.split_at(self.drawn.len() / 2);
        let output = &self.output;
        let (mut hint_a, mut hint_b) = (self.output_hint, self.output_hint);
        let nearest = |points: &[(DVec3, u64)], hint: &mut usize| -> Vec<f64> {
            points
                .iter()
                .map(|&(p, _)| output.nearest(p, hint))
                .collect()
        };
        let (mut da, mut db) = (Vec::new(), Vec::new());
        self.halves
            .both(&mut || da = nearest(first, &mut hint_a), &mut || {
                db = nearest(second, &mut hint_b)
            });
        for (&(p, weight), d) in self.drawn.iter().zip(da.into_iter().chain(db)) {
            self.full_to_output.add(d, weight);
            self.landmarks.add(p);
        }
        self.output_hint = hint_b;
        self.drawn.clear();
    }

    /// Measures the samples whose every candidate is now in the window, then drops the batches
    /// no pending sample can reach.
    fn advance(&mut self, front: f64) {
        while let Some(&p) = self.samples.get(self.next) {
            if p.z + self.radius > front {
                break;
            }
            // Batches spanning the sample's height first: the bound they give prunes the rest by
            // their vertical gap alone.
            let mut best = self.radius;
            for spanning in [true, false] {
                for b in &self.window {
                    let gap = b.gap(p.z);
                    if (gap == 0.0) != spanning || gap >= best {
                        continue;
                    }
                    if let Some((d, _)) = b.bvh.nearest_within(p, best) {
                        best = d;
                    }
                }
            }
            if best < self.radius {
                self.output_to_full.add(best, 1);
            } else {
                self.far.push(p);
            }
            self.next += 1;
        }
        let lowest = self.samples.get(self.next).map_or(f64::INFINITY, |p| p.z);
        self.window.retain(|b| b.z_max + self.radius >= lowest);
    }

    /// The output mesh's samples, sorted by z.
    #[cfg(test)]
    pub(crate) fn samples(&self) -> &[DVec3] {
        &self.samples
    }

    /// The end of the first pass: the distances, or the far samples' second pass.
    pub(crate) fn finish(mut self) -> Result<Streamed, MeasureError> {
        if let Some(e) = self.refused {
            return Err(e);
        }
        self.advance(f64::INFINITY);
        if self.full_to_output.count == 0 {
            return Err(MeasureError::EmptySurface);
        }
        let totals = Totals {
            diagonal: (self.bounds.1 - self.bounds.0).length(),
            full_triangles: self.full_triangles,
            full_weight: self.full_weight,
            far_samples: self.far.len() as u64,
            radius: self.radius,
            density: self.density,
        };
        let full_to_output = self.full_to_output.finish();
        if self.far.is_empty() {
            return Ok(Streamed::Done(
                totals.distances(full_to_output, self.output_to_full.finish()),
            ));
        }
        Ok(Streamed::Far(FarPass {
            far: FarSamples::new(self.far, self.landmarks),
            output_to_full: self.output_to_full,
            full_to_output,
            totals,
        }))
    }
}

/// What the first pass over the full-resolution surface ends with.
#[derive(Debug)]
pub(crate) enum Streamed {
    /// Every output sample had a full-resolution point within the radius.
    Done(Distances),
    /// Some had none: the surface must go by again for them.
    Far(FarPass),
}

/// The second pass: every distance of the first but the far output samples', which the
/// full-resolution surface going by again gives exactly.
#[derive(Debug)]
pub(crate) struct FarPass {
    far: FarSamples,
    output_to_full: Accumulator,
    full_to_output: DirectedDistance,
    totals: Totals,
}

impl FarPass {
    /// How many output samples had nothing within the radius.
    pub(crate) fn far_samples(&self) -> u64 {
        self.far.len() as u64
    }

    /// The next batch of the full-resolution surface (in any order).
    pub(crate) fn add_batch(&mut self, batch: Vec<Triangle>) {
        self.far.add_batch(batch);
    }

    /// The distances, once the whole surface went by again.
    pub(crate) fn finish(mut self) -> Distances {
        for d in self.far.into_distances() {
            self.output_to_full.add(d, 1);
        }
        self.totals
            .distances(self.full_to_output, self.output_to_full.finish())
    }
}

/// What the report says besides the two directions.
#[derive(Debug)]
struct Totals {
    diagonal: f64,
    full_triangles: u64,
    full_weight: u64,
    far_samples: u64,
    radius: f64,
    density: f64,
}

impl Totals {
    fn distances(self, f2o: DirectedDistance, o2f: DirectedDistance) -> Distances {
        let (mean, rms, hausdorff, p999) = (
            f2o.mean.max(o2f.mean),
            f2o.rms.max(o2f.rms),
            f2o.hausdorff.max(o2f.hausdorff),
            f2o.p999.max(o2f.p999),
        );
        let pct = |d: f64| 100.0 * d / self.diagonal;
        Distances {
            mean_pct: pct(mean),
            rms_pct: pct(rms),
            hausdorff_pct: pct(hausdorff),
            p999_pct: pct(p999),
            full_to_output: f2o,
            output_to_full: o2f,
            mean,
            rms,
            hausdorff,
            p999,
            diagonal: self.diagonal,
            full_resolution_triangles: self.full_triangles,
            full_sample_weight: self.full_weight,
            far_samples: self.far_samples,
            max_distance: self.radius,
            samples_per_area: self.density,
        }
    }
}

/// What each full-resolution sample counts for once the surface seen so far would take
/// `wanted` samples at the output's density: the smallest power of four from `weight` on with
/// `wanted <= cap * sqrt(weight)`, four times sparser each time the area doubles, so that the
/// samples of each doubling halve and all of them stay within one and a half times the cap.
/// `None` past 4^31, the last power of four a `u64` holds (an infinite or runaway `wanted`):
/// the multiplications stop at the first overflow, so the loop runs at most 32 times (it
/// multiplied past `u64::MAX`, and in release wrapped to a zero weight and never ended).
fn thinned_weight(wanted: f64, cap: f64, mut weight: u64) -> Option<u64> {
    while wanted > cap * (weight as f64).sqrt() {
        weight = weight.checked_mul(4)?;
    }
    Some(weight)
}

/// `x.floor() as i64` without the library call `f64::floor` is on baseline x86-64 (no SSE4.1):
/// 8 % of a measure's time, for the column cells of every full-resolution triangle.
fn floor(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t - 1 } else { t }
}

fn output_triangles(
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
) -> Result<Vec<Triangle>, MeasureError> {
    triangles
        .iter()
        .enumerate()
        .map(
            |(i, t)| match t.iter().find(|&&v| v as usize >= positions.len()) {
                Some(&vertex) => Err(MeasureError::VertexIndex {
                    triangle: i,
                    vertex,
                    vertices: positions.len(),
                }),
                None => Ok(crate::triangle::corners(positions, t)),
            },
        )
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::bias::tests::geodesic_sphere;
    use crate::triangle::closest_point;

    /// The window keeps a triangle exactly when a pending sample of its heights lies within
    /// `r` of its box across: the nearest triangle within `r` of any sample is never dropped.
    #[test]
    fn the_window_keeps_what_samples_can_reach() {
        let r = 1.0;
        let samples = [DVec3::new(0.5, 0.5, 0.0), DVec3::new(10.5, 0.5, 5.0)];
        let reach = Reach::of(&samples, -0.5, 0.5, r);
        let tri = |x: f64, y: f64| {
            [
                DVec3::new(x, y, 0.0),
                DVec3::new(x + 0.1, y, 0.0),
                DVec3::new(x, y + 0.1, 0.0),
            ]
        };
        assert!(reach.touches(&tri(0.5, 0.5)));
        // 0.9 away across: in reach, whatever the cells' borders.
        assert!(reach.touches(&tri(1.4, 1.4)));
        assert!(reach.touches(&tri(-0.5, 0.5)));
        // Far across, and under the second sample but out of its heights' reach.
        assert!(!reach.touches(&tri(4.0, 0.5)));
        assert!(!reach.touches(&tri(10.5, 0.5)));
        assert!(!Reach::of(&[], 0.0, 1.0, r).touches(&tri(0.0, 0.0)));

        // Sampled: every triangle within `r` of a sample of its heights is kept.
        let mut rng = SplitMix64::new(7);
        let mut unit = || rng.next_f64();
        let samples: Vec<DVec3> = {
            let mut s: Vec<DVec3> = (0..40)
                .map(|_| DVec3::new(20.0 * unit(), 20.0 * unit(), 4.0 * unit()))
                .collect();
            s.sort_unstable_by(|a, b| a.z.total_cmp(&b.z));
            s
        };
        let reach = Reach::of(&samples, 1.0, 3.0, r);
        for _ in 0..2000 {
            let (x, y, z) = (20.0 * unit(), 20.0 * unit(), 1.0 + 2.0 * unit());
            let t = [
                DVec3::new(x, y, z),
                DVec3::new(x + 0.3, y, z),
                DVec3::new(x, y + 0.3, z),
            ];
            let near = samples
                .iter()
                .any(|p| closest_point(*p, &t).distance(*p) < r);
            assert!(!near || reach.touches(&t), "{t:?}");
        }
    }

    #[test]
    fn histogram_bins_follow_the_data() {
        let mut acc = Accumulator::new(100.0);
        for i in 0..1000 {
            acc.add(i as f64 / 1000.0, 1);
        }
        let h = acc.histogram();
        assert!(h.len() >= DISTANCE_BINS / 2 && h.len() <= DISTANCE_BINS);
        assert_eq!(h.iter().map(|b| b.1).sum::<u64>(), 1000);
        // The bins span the data (below 1), not the search radius (100).
        let end = h.last().unwrap().0 + h[1].0;
        assert!((0.999..1.2).contains(&end), "{h:?}");
        // A distance past the radius counts in the last bin.
        acc.add(250.0, 1);
        let h = acc.histogram();
        assert_eq!(h.len(), DISTANCE_BINS);
        assert_eq!(h.last().unwrap().1, 1);
    }

    /// Past the radius the quantile is exact from the distances kept there (weights counted),
    /// and the largest distance once too many were past it to keep.
    #[test]
    fn the_quantile_past_the_radius_is_the_exact_one() {
        let mut acc = Accumulator::new(1.0);
        (0..10).for_each(|_| acc.add(0.5, 1));
        for k in 1..=4995 {
            acc.add(1.0 + f64::from(k) / 1000.0, 2);
        }
        // 10,000 samples with the weights: 0.999 of them are reached by the 10 within the radius
        // and 4,990 distances of weight 2 past it, the last of which is 1 + 4,990 / 1,000.
        assert_eq!(acc.quantile(0.999), 1.0 + 4990.0 / 1000.0);
        assert_eq!(acc.finish().samples, 10 + 4995);
        let mut acc = Accumulator::new(1.0);
        (0..=BEYOND_KEPT).for_each(|k| acc.add(2.0 + k as f64 * 1e-6, 1));
        assert!(acc.beyond.is_none());
        assert_eq!(acc.quantile(0.999), acc.max);
    }

    #[test]
    fn the_quantile_is_within_a_thousandth_above_the_exact_one_and_never_above_the_maximum() {
        // 10,000 distances 0, 1e-4, ..., 0.9999 and one outlier: the outlier sets the Hausdorff
        // distance, not the 99.9th percentile (the 9,991st smallest, 0.9990).
        let mut acc = Accumulator::new(4.096);
        for i in 0..10_000 {
            acc.add(i as f64 * 1e-4, 1);
        }
        acc.add(3.5, 1);
        let d = acc.finish();
        assert_eq!(d.hausdorff, 3.5);
        assert!(
            (0.999..=0.999 * (1.0 + 1.0 / 1024.0)).contains(&d.p999),
            "{}",
            d.p999
        );
        // All samples alike: capped by the largest.
        let mut flat = Accumulator::new(4.096);
        (0..100).for_each(|_| flat.add(0.25, 1));
        assert_eq!(flat.finish().p999, 0.25);
    }

    /// A square `[0, size]^2` at height `z`, split into `n x n` cells of two triangles.
    pub(crate) fn plane(size: f64, n: u32, z: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let step = size / n as f64;
        let positions = (0..=n)
            .flat_map(|j| (0..=n).map(move |i| [i as f64 * step, j as f64 * step, z]))
            .collect();
        let idx = |i: u32, j: u32| j * (n + 1) + i;
        let triangles = (0..n)
            .flat_map(|j| {
                (0..n).flat_map(move |i| {
                    [
                        [idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)],
                        [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)],
                    ]
                })
            })
            .collect();
        (positions, triangles)
    }

    fn soup(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> Vec<Triangle> {
        output_triangles(positions, triangles).unwrap()
    }

    /// Streams `full` in slabs of height `slab` along z, as the volume stream would.
    fn stream(
        output: (&[[f64; 3]], &[[u32; 3]]),
        full: &[Triangle],
        slab: f64,
        opts: &MeasureOptions,
        radius: f64,
    ) -> Distances {
        let mut s = DistanceStream::new(output.0, output.1, opts, radius).unwrap();
        let mut batches: std::collections::BTreeMap<i64, Vec<Triangle>> = Default::default();
        for t in full {
            let z = t.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
            batches
                .entry((z / slab).floor() as i64)
                .or_default()
                .push(*t);
        }
        // Bucket k holds triangles whose lowest corner is in [k slab, (k + 1) slab).
        for (k, b) in batches {
            s.add_batch(b, (k + 1) as f64 * slab);
        }
        both_passes(s, full)
    }

    /// The end of the first pass and, when there are far samples, the second over `full`.
    pub(crate) fn both_passes(s: DistanceStream, full: &[Triangle]) -> Distances {
        match s.finish().unwrap() {
            Streamed::Done(d) => d,
            Streamed::Far(mut far) => {
                far.add_batch(full.to_vec());
                far.finish()
            }
        }
    }

    fn sphere(radius: f64, levels: u32) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let (v, f) = geodesic_sphere(levels);
        (v.iter().map(|p| (*p * radius).to_array()).collect(), f)
    }

    /// `output` measured against a full-resolution plane `[0, 10]^2` at height 0.3 (20 x 20
    /// cells), streamed in slabs of 1, search radius 1.
    fn under_the_plane(output: (&[[f64; 3]], &[[u32; 3]])) -> Distances {
        let (fp, ft) = plane(10.0, 20, 0.3);
        stream(
            output,
            &soup(&fp, &ft),
            1.0,
            &MeasureOptions::default(),
            1.0,
        )
    }

    #[test]
    fn parallel_planes_are_offset_apart() {
        let (op, ot) = plane(10.0, 4, 0.0);
        let d = under_the_plane((&op, &ot));
        for dir in [&d.full_to_output, &d.output_to_full] {
            assert!((dir.mean - 0.3).abs() < 1e-12, "{dir:?}");
            assert!((dir.rms - 0.3).abs() < 1e-12);
            assert!((dir.hausdorff - 0.3).abs() < 1e-12);
            assert!(
                dir.samples >= MIN_SAMPLES as u64 * 9 / 10,
                "{}",
                dir.samples
            );
        }
        assert!((d.mean - 0.3).abs() < 1e-12 && (d.hausdorff - 0.3).abs() < 1e-12);
        assert_eq!(d.far_samples, 0);
        assert_eq!(d.full_resolution_triangles, 800);
        assert!((d.diagonal - (200.0f64 + 0.09).sqrt()).abs() < 1e-12);
    }

    /// Zero-area triangles with two coincident corners, as other tools leave them: needles
    /// 0.1 below the full surface, over an output plane 0.3 below it. Their closest points were
    /// 0 / 0 from one side; once such a needle was the nearest triangle, the next sample's bound
    /// from it was NaN, and every later full -> output query read the whole hierarchy and
    /// returned NaN, which the larger-of-both-directions then passed over.
    #[test]
    fn coincident_corners_in_the_output_are_measured() {
        let (mut op, mut ot) = plane(10.0, 4, 0.0);
        for k in 0..100u32 {
            let (x, y) = (f64::from(k % 10) + 0.25, f64::from(k / 10) + 0.25);
            let i = op.len() as u32;
            op.extend([[x, y, 0.2], [x + 0.5, y, 0.2]]);
            ot.extend([[i, i, i + 1], [i + 1, i, i], [i, i + 1, i + 1]]);
        }
        let d = under_the_plane((&op, &ot));
        let f2o = &d.full_to_output;
        assert!(f2o.mean > 0.1 && f2o.mean < 0.3, "{f2o:?}");
        assert!(f2o.rms > 0.1 && f2o.rms < 0.3, "{f2o:?}");
        assert!((f2o.hausdorff - 0.3).abs() < 1e-12, "{f2o:?}");
        assert!(d.rms >= f2o.rms, "{d:?}");
    }

    /// The halves of each chunk's queries in the other order, as two threads may finish them.
    #[derive(Debug)]
    struct Reversed;

    impl Halves for Reversed {
        fn both(&self, a: &mut (dyn FnMut() + Send), b: &mut (dyn FnMut() + Send)) {
            b();
            a();
        }
    }

    /// However the halves run, the same report: each distance is exact and the sums are made in
    /// the order the samples were drawn.
    #[test]
    fn the_halves_run_in_any_order_give_the_same_distances() {
        let (op, ot) = sphere(10.0, 2);
        let (fp, ft) = sphere(10.3, 4);
        let run = |halves: Box<dyn Halves>| {
            let mut s = DistanceStream::new(&op, &ot, &MeasureOptions::default(), 2.0).unwrap();
            s.set_halves(halves);
            s.add_batch(soup(&fp, &ft), f64::INFINITY);
            both_passes(s, &soup(&fp, &ft))
        };
        let (a, b) = (run(Box::new(InTurn)), run(Box::new(Reversed)));
        assert_eq!(a, b);
        assert!(a.full_to_output.samples > 10_000, "{a:?}");
    }

    #[test]
    fn a_mesh_is_at_distance_zero_from_itself() {
        let (p, t) = sphere(10.0, 3);
        let d = stream(
            (&p, &t),
            &soup(&p, &t),
            1.0,
            &MeasureOptions::default(),
            1.0,
        );
        assert!(d.hausdorff < 1e-9, "{d:?}");
        assert_eq!(d.far_samples, 0);
    }

    /// Trial bug: samples with nothing within the radius were counted at it, and the Hausdorff
    /// distance and the 99.9th percentile were silently the radius (19.07 on headsq at R = 0.01,
    /// where the exact distance is 24.85). A plane 5 above the output plane, radius 2: every
    /// output sample is far and measured at its exact distance in the second pass.
    #[test]
    fn far_samples_are_measured_exactly() {
        let (op, ot) = plane(10.0, 2, 0.0);
        let (fp, ft) = plane(10.0, 2, 5.0);
        let d = stream(
            (&op, &ot),
            &soup(&fp, &ft),
            1.0,
            &MeasureOptions::default(),
            2.0,
        );
        assert_eq!(d.far_samples, d.output_to_full.samples);
        let o2f = &d.output_to_full;
        for x in [o2f.mean, o2f.rms, o2f.hausdorff, o2f.p999] {
            assert!((x - 5.0).abs() < 1e-12, "{o2f:?}");
        }
        assert!((d.hausdorff - 5.0).abs() < 1e-12 && (d.p999 - 5.0).abs() < 1e-12);
        assert!((d.full_to_output.mean - 5.0).abs() < 1e-12);
        // Past the radius: in the last bin.
        assert_eq!(o2f.histogram.last().unwrap().1, o2f.samples);
    }

    /// The streamed, windowed output -> full direction equals a brute-force nearest search over
    /// the whole full surface for every sample within the radius.
    #[test]
    fn streamed_output_to_full_matches_brute_force() {
        let (op, ot) = sphere(10.0, 2); // coarse: its faces cut inside the fine sphere
        let (fp, ft) = sphere(10.2, 4);
        let full = soup(&fp, &ft);
        let opts = MeasureOptions {
            samples_per_area: 1.0,
            ..MeasureOptions::default()
        };
        let radius = 1.5;
        let streamed = stream((&op, &ot), &full, 0.7, &opts, radius);

        let s = DistanceStream::new(&op, &ot, &opts, radius).unwrap();
        let mut acc = Accumulator::new(radius);
        let mut sorted = Vec::new();
        for p in &s.samples {
            let d = full
                .iter()
                .map(|t| closest_point(*p, t).distance(*p))
                .fold(f64::INFINITY, f64::min);
            acc.add(d, 1);
            sorted.push(d);
        }
        let brute = acc.finish();
        // The 99.9th percentile against a sort of the same samples: 0.1 % at most above it (it
        // was read from bins `radius / 4096` wide, 4-7 % of it).
        sorted.sort_unstable_by(f64::total_cmp);
        let exact = sorted[(0.999 * sorted.len() as f64).ceil() as usize - 1];
        let p999 = streamed.output_to_full.p999;
        assert!(
            exact <= p999 && p999 <= exact * (1.0 + 1.0 / 1024.0),
            "{p999} against {exact}"
        );
        let o2f = &streamed.output_to_full;
        assert_eq!(o2f.samples, brute.samples);
        for h in [&o2f.histogram, &streamed.full_to_output.histogram] {
            assert!(
                h.len() <= DISTANCE_BINS && h.len() >= DISTANCE_BINS / 2,
                "{h:?}"
            );
            // Bins of equal width that cover the largest distance.
            let width = h[1].0 - h[0].0;
            assert!(
                h.windows(2)
                    .all(|w| (w[1].0 - w[0].0 - width).abs() < 1e-12)
            );
        }
        let (last, width) = (o2f.histogram.last().unwrap().0, radius / FINE_BINS as f64);
        assert!(last <= o2f.hausdorff && o2f.hausdorff < last + (o2f.histogram[1].0 + width));
        assert_eq!(o2f.histogram.iter().map(|b| b.1).sum::<u64>(), o2f.samples);
        assert!(
            (o2f.mean - brute.mean).abs() < 1e-9 * brute.mean,
            "{o2f:?} {brute:?}"
        );
        assert!((o2f.rms - brute.rms).abs() < 1e-9 * brute.rms);
        assert_eq!(o2f.hausdorff, brute.hausdorff);
        assert!(o2f.hausdorff > 0.2 && o2f.hausdorff < radius);
    }

    #[test]
    fn same_seed_same_report_other_seed_other_samples() {
        let (op, ot) = sphere(10.0, 2);
        let (fp, ft) = sphere(10.2, 3);
        let full = soup(&fp, &ft);
        let opts = MeasureOptions::default();
        let a = stream((&op, &ot), &full, 1.0, &opts, 2.0);
        let b = stream((&op, &ot), &full, 1.0, &opts, 2.0);
        assert_eq!(a, b);
        let other = MeasureOptions { seed: 99, ..opts };
        let c = stream((&op, &ot), &full, 1.0, &other, 2.0);
        assert_ne!(a.output_to_full.mean, c.output_to_full.mean);
        assert!(
            (a.output_to_full.mean - c.output_to_full.mean).abs() < 0.02 * a.output_to_full.mean
        );
    }

    /// Past the cap, the full surface is sampled ever more sparsely with weights: a small
    /// output square at a corner of a large full plane keeps the samples within one and a half
    /// times the cap, and the mean distance is the plane's (integrated on a fine grid here).
    #[test]
    fn a_full_surface_far_larger_than_the_output_is_thinned_without_bias() {
        let (op, ot) = plane(0.1, 1, 0.0); // area 0.01: density raised to 10^6 per unit^2
        let (fp, ft) = plane(10.0, 20, 0.0); // area 100: 10^8 samples at that density
        let mut s = DistanceStream::new(&op, &ot, &MeasureOptions::default(), 1.0).unwrap();
        s.full_cap = 20_000.0;
        s.add_batch(soup(&fp, &ft), f64::INFINITY);
        let d = both_passes(s, &soup(&fp, &ft));
        let f2o = &d.full_to_output;
        assert!(f2o.samples <= 30_000, "{}", f2o.samples);
        assert!(d.full_sample_weight >= 1 << 12, "{}", d.full_sample_weight);
        let n = 2000;
        let exact = (0..n * n)
            .map(|k| {
                let (x, y) = ((k % n) as f64 + 0.5, (k / n) as f64 + 0.5);
                let (x, y) = (x * 10.0 / n as f64, y * 10.0 / n as f64);
                (x - x.clamp(0.0, 0.1)).hypot(y - y.clamp(0.0, 0.1))
            })
            .sum::<f64>()
            / (n * n) as f64;
        assert!(
            (f2o.mean - exact).abs() < 0.03 * exact,
            "{} against {exact}",
            f2o.mean
        );
        // The farthest samples are past the radius: 99.9 % are within the largest distance, not
        // within the radius.
        assert!(f2o.p999 > 10.0 && f2o.p999 <= f2o.hausdorff, "{f2o:?}");
    }

    /// An output with a coordinate out of range has no finite area to spread the samples over:
    /// refused in one line (was a panic in `clamp` on a NaN area).
    #[test]
    fn an_output_of_no_finite_area_is_refused() {
        let opts = MeasureOptions::default();
        for c in [f64::NAN, f64::INFINITY, 1e300] {
            let positions = [[0.0, 0.0, 0.0], [c, 0.0, 0.0], [0.0, c, 0.0]];
            let e = DistanceStream::new(&positions, &[[0, 1, 2]], &opts, 1.0)
                .err()
                .unwrap();
            assert!(matches!(e, MeasureError::Unsampleable(_)), "{c}: {e:?}");
            let msg = e.to_string();
            assert!(
                msg.starts_with("the mesh cannot be sampled") && !msg.contains('\n'),
                "{msg}"
            );
        }
    }

    /// A full-resolution triangle whose area overflows to infinity, or a density so high that
    /// no power-of-four weight below 2^64 thins it: the stream refuses it at `finish` (was a
    /// weight multiplied past `u64::MAX`: a panic, or in release a zero weight and a loop that
    /// never ended).
    #[test]
    fn a_full_surface_no_weight_thins_is_refused() {
        let (op, ot) = plane(1.0, 1, 0.0);
        let opts = MeasureOptions::default();
        let huge = [DVec3::ZERO, DVec3::X * 1e200, DVec3::Y * 1e200];
        let unit = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let mut dense = DistanceStream::new(&op, &ot, &opts, 1.0).unwrap();
        dense.density = 1e300;
        for (mut s, t) in [
            (DistanceStream::new(&op, &ot, &opts, 1.0).unwrap(), huge),
            (dense, unit),
        ] {
            s.add_batch(vec![t], 0.5);
            // Later batches are not sampled: the refusal stands.
            s.add_batch(vec![unit], f64::INFINITY);
            let e = s.finish().err().unwrap();
            assert!(matches!(e, MeasureError::Unsampleable(_)), "{e:?}");
        }
    }

    /// The weight settles on the smallest power of four that thins `wanted` to the cap, and
    /// past 4^31 there is none: the loop stops at the first overflow.
    #[test]
    fn the_weight_is_bounded_by_construction() {
        let cap = FULL_SAMPLES_CAP;
        assert_eq!(thinned_weight(cap, cap, 1), Some(1));
        assert_eq!(thinned_weight(cap * 3.0, cap, 1), Some(16));
        assert_eq!(thinned_weight(cap * 2f64.powi(31), cap, 1), Some(1 << 62));
        assert_eq!(thinned_weight(cap * 2f64.powi(32), cap, 1), None);
        assert_eq!(thinned_weight(cap * 2.0, cap, 1 << 62), Some(1 << 62));
        assert_eq!(thinned_weight(f64::INFINITY, cap, 1), None);
        assert_eq!(thinned_weight(f64::MAX, cap, 1), None);
        // A NaN area leaves the weight; the triangle sampler refuses the NaN count.
        assert_eq!(thinned_weight(f64::NAN, cap, 4), Some(4));
    }

    #[test]
    fn density_is_clamped_to_the_sample_budget() {
        let (p, t) = plane(1000.0, 1, 0.0); // area 10^6
        let opts = MeasureOptions {
            samples_per_area: 100.0,
            ..MeasureOptions::default()
        };
        let s = DistanceStream::new(&p, &t, &opts, 1.0).unwrap();
        assert!((s.density - MAX_SAMPLES / 1e6).abs() < 1e-12);
        let (p, t) = plane(1.0, 1, 0.0); // area 1
        let s = DistanceStream::new(&p, &t, &MeasureOptions::default(), 1.0).unwrap();
        assert!((s.density - MIN_SAMPLES).abs() < 1e-9);
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let (p, t) = plane(1.0, 1, 0.0);
        let opts = MeasureOptions {
            samples_per_area: f64::NAN,
            ..MeasureOptions::default()
        };
        assert!(matches!(
            DistanceStream::new(&p, &t, &opts, 1.0),
            Err(MeasureError::SamplesPerArea(_))
        ));
        let opts = MeasureOptions::default();
        assert!(matches!(
            DistanceStream::new(&p, &t, &opts, 0.0),
            Err(MeasureError::MaxDistance(_))
        ));
        assert!(matches!(
            DistanceStream::new(&p, &[[0, 1, 7]], &opts, 1.0),
            Err(MeasureError::VertexIndex {
                triangle: 0,
                vertex: 7,
                vertices: 4
            })
        ));
        assert!(matches!(
            DistanceStream::new(&p, &[], &opts, 1.0),
            Err(MeasureError::EmptyOutput)
        ));
        let s = DistanceStream::new(&p, &t, &opts, 1.0).unwrap();
        assert!(matches!(s.finish(), Err(MeasureError::EmptySurface)));
    }
}
