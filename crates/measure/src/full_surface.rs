//! The full-resolution iso-surface regenerated from the volume as a stream: two slices resident,
//! each slab's triangles handed to the distance computation and dropped.
//!
//! This is what keeps `isostream measure` within the service's memory promise (ARCHITECTURE.md,
//! "Memory is bounded by the sweep front"): the full-resolution surface of a large volume is far
//! bigger than the simplified output and is never held whole.

use glam::DVec3;
use isostream_extract::{CubeBatch, Extractor};
use isostream_volume::{Grid, VolumeError, VolumeSource};

use crate::distances::{DEFAULT_SEARCH_VOXEL_DIAGONALS, DistanceStream, FarPass, Streamed};
use crate::halves::Halves;
use crate::triangle::Triangle;
use crate::{Distances, MeasureError, MeasureOptions};

/// Triangles gathered before a batch is handed on, even mid-slab: bounds memory on slabs with an
/// enormous surface (about 20 MB of triangles) while keeping batches slab-sized in practice.
const MAX_BATCH_TRIANGLES: usize = 1 << 18;

/// Metro-style distances between the output mesh (in memory: it is the simplified one) and the
/// full-resolution iso-surface, which is regenerated from the volume as a stream (slab by slab,
/// via `Extractor`, on the calling thread) and never held in memory whole. Tandem paper, section
/// 4 "Approximation error". A caller with its own extraction (`isostream measure` uses the
/// pipeline's parallel one, which skips empty space) feeds [`FullSurfaceDistances`] instead.
///
/// `open` gives the volume to read from slice 0: once, or twice when output samples have no
/// full-resolution point within the search radius (see [`FirstPass`]); `positions`/`triangles`
/// are the output mesh in the volume's physical coordinates.
pub fn surface_distances<V: VolumeSource>(
    mut open: impl FnMut() -> Result<V, VolumeError>,
    iso: f32,
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    opts: &MeasureOptions,
) -> Result<Distances, MeasureError> {
    let mut volume = open()?;
    let mut full = FullSurfaceDistances::new(volume.grid(), positions, triangles, opts)?;
    let max_batch = full.gather.max_batch;
    feed(&mut volume, iso, max_batch, |batch| full.add(batch))?;
    Ok(match full.finish()? {
        FirstPass::Done(distances) => distances,
        FirstPass::Again(mut again) => {
            feed(&mut open()?, iso, max_batch, |batch| again.add(batch))?;
            again.finish()
        }
    })
}

/// The distances of [`surface_distances`], taking the full-resolution surface as the batches
/// of marching cubes over the volume's grid: every slab's batches after the previous slab's, as
/// [`Extractor::extract_slab`] emits them (empty cubes may be left out). Only the triangles
/// within the search radius of output samples still to measure are held. Output samples with no
/// full-resolution point within that radius need the surface once more ([`FirstPass::Again`]).
#[derive(Debug)]
pub struct FullSurfaceDistances {
    stream: DistanceStream,
    gather: Gather,
}

/// How the first pass over the full-resolution surface ends.
#[derive(Debug)]
pub enum FirstPass {
    /// Every output sample had a full-resolution point within the search radius.
    Done(Distances),
    /// Some had none (a part of the mesh farther from the surface than the radius): they are
    /// measured exactly against the whole surface, which must go by once more, the same
    /// batches in the same order, through [`SecondPass::add`]. Counting them at the radius
    /// made the Hausdorff distance and the 99.9th percentile silent lower bounds.
    Again(SecondPass),
}

/// The second pass over the full-resolution surface, for the output samples the first found
/// nothing within the search radius of: it holds them and one batch of the surface at a time.
#[derive(Debug)]
pub struct SecondPass {
    far: FarPass,
    gather: Gather,
}

impl SecondPass {
    /// How many output samples had no full-resolution point within the search radius.
    pub fn far_samples(&self) -> u64 {
        self.far.far_samples()
    }

    /// The next batch of the full-resolution surface, as for [`FullSurfaceDistances::add`].
    pub fn add(&mut self, batch: &CubeBatch) {
        let far = &mut self.far;
        self.gather
            .add(batch, |triangles, _| far.add_batch(triangles));
    }

    /// The distances, once the whole surface went by again.
    pub fn finish(mut self) -> Distances {
        if let Some(rest) = self.gather.rest() {
            self.far.add_batch(rest);
        }
        self.far.finish()
    }
}

/// The batches' triangles gathered into slabs, or groups of `max_batch` triangles.
#[derive(Debug)]
struct Gather {
    grid: Grid,
    /// Triangles gathered since the last hand-over.
    pending: Vec<Triangle>,
    max_batch: usize,
}

impl Gather {
    /// Hands the triangles on at the end of the batch's slab with the height of its top slice
    /// (later triangles lie above it), or once `max_batch` wait with that of its bottom slice.
    fn add(&mut self, batch: &CubeBatch, mut hand: impl FnMut(Vec<Triangle>, f64)) {
        append_triangles(batch, &mut self.pending);
        let slice_height = |k: u64| self.grid.position(0.0, 0.0, k as f64).z;
        if batch.end_of_slab {
            let top = slice_height(batch.slab + 1);
            hand(std::mem::take(&mut self.pending), top);
        } else if self.pending.len() >= self.max_batch {
            let bottom = slice_height(batch.slab);
            hand(std::mem::take(&mut self.pending), bottom);
        }
    }

    /// The triangles not handed on yet.
    fn rest(&mut self) -> Option<Vec<Triangle>> {
        Some(std::mem::take(&mut self.pending)).filter(|rest| !rest.is_empty())
    }
}

/// Refuses a mesh whose box reaches farther than `radius` outside `grid`'s box (no full-surface
/// point is within reach of it, and the samples' grid grew with the gap) or is under a millionth
/// of a voxel across (the full surface's sampling density grew with its inverse area).
fn on_volume(grid: &Grid, positions: &[[f64; 3]], radius: f64) -> Result<(), MeasureError> {
    let (lo, hi) = positions
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), &p| {
            (lo.min(p.into()), hi.max(p.into()))
        });
    let origin = DVec3::from(grid.origin);
    let far = origin
        + DVec3::from(grid.spacing) * DVec3::from(grid.dims.map(|d| d.saturating_sub(1) as f64));
    let (vlo, vhi) = (origin.min(far) - radius, origin.max(far) + radius);
    if lo.cmplt(vlo).any() || hi.cmpgt(vhi).any() {
        return Err(MeasureError::OffVolume(format!(
            "its box {:?}..{:?} leaves the volume's {:?}..{:?} by more than the search radius {radius}",
            lo.to_array(),
            hi.to_array(),
            vlo.to_array(),
            vhi.to_array()
        )));
    }
    let voxel = DVec3::from(grid.spacing).abs().length();
    let across = (hi - lo).length();
    if !positions.is_empty() && (across.is_nan() || across < 1e-6 * voxel) {
        return Err(MeasureError::OffVolume(format!(
            "it is {across:e} across, under a millionth of a voxel ({voxel:e})"
        )));
    }
    Ok(())
}

impl FullSurfaceDistances {
    /// Indexes and samples the output mesh (`positions`/`triangles`, in `grid`'s physical
    /// coordinates).
    pub fn new(
        grid: Grid,
        positions: &[[f64; 3]],
        triangles: &[[u32; 3]],
        opts: &MeasureOptions,
    ) -> Result<Self, MeasureError> {
        Self::with_max_batch(grid, positions, triangles, opts, MAX_BATCH_TRIANGLES)
    }

    fn with_max_batch(
        grid: Grid,
        positions: &[[f64; 3]],
        triangles: &[[u32; 3]],
        opts: &MeasureOptions,
        max_batch: usize,
    ) -> Result<Self, MeasureError> {
        let voxel_diagonal = DVec3::from(grid.spacing).length();
        let radius = opts
            .max_distance
            .unwrap_or(DEFAULT_SEARCH_VOXEL_DIAGONALS * voxel_diagonal);
        on_volume(&grid, positions, radius)?;
        Ok(Self {
            stream: DistanceStream::new(positions, triangles, opts, radius)?,
            gather: Gather {
                grid,
                pending: Vec::new(),
                max_batch,
            },
        })
    }

    /// Computes each batch's full -> output distances in two halves that `halves` runs (on two
    /// threads, the caller's); the distances are the same as on one.
    pub fn with_halves(mut self, halves: Box<dyn Halves>) -> Self {
        self.stream.set_halves(halves);
        self
    }

    /// The next batch of the full-resolution surface.
    pub fn add(&mut self, batch: &CubeBatch) {
        let stream = &mut self.stream;
        self.gather
            .add(batch, |triangles, front| stream.add_batch(triangles, front));
    }

    /// The distances once the whole surface went by, or the second pass they still need.
    pub fn finish(mut self) -> Result<FirstPass, MeasureError> {
        if let Some(rest) = self.gather.rest() {
            self.stream.add_batch(rest, f64::INFINITY);
        }
        Ok(match self.stream.finish()? {
            Streamed::Done(distances) => FirstPass::Done(distances),
            Streamed::Far(far) => FirstPass::Again(SecondPass {
                far,
                gather: self.gather,
            }),
        })
    }
}

/// Extracts the volume slab by slab into `add`, in groups of rows of at least `max_batch`
/// triangles.
fn feed(
    volume: &mut dyn VolumeSource,
    iso: f32,
    max_batch: usize,
    mut add: impl FnMut(&CubeBatch),
) -> Result<(), MeasureError> {
    let grid = volume.grid();
    let mut extractor = Extractor::new(grid, iso);
    let n = grid.slice_len();
    let (mut lower, mut upper) = (vec![0.0f32; n], vec![0.0f32; n]);
    volume.read_slice(0, &mut lower)?;
    for z in 0..grid.dims[2].saturating_sub(1) {
        volume.read_slice(z + 1, &mut upper)?;
        extractor.extract_slab(z, &lower, &upper, max_batch, |batch: CubeBatch| {
            add(&batch);
            Ok::<(), MeasureError>(())
        })?;
        std::mem::swap(&mut lower, &mut upper);
    }
    Ok(())
}

fn append_triangles(batch: &CubeBatch, out: &mut Vec<Triangle>) {
    for cube in &batch.cubes {
        let vertices = batch.cube_vertices(cube);
        out.extend(
            batch
                .cube_triangles(cube)
                .iter()
                .map(|t| t.map(|i| vertices[i as usize].pos)),
        );
    }
}

#[cfg(test)]
mod tests {
    use isostream_extract::extract_indexed;
    use isostream_volume::{Grid, MemoryVolume, Procedural, Shape};

    use super::*;
    use crate::bias::tests::geodesic_sphere;
    use crate::triangle::{closest_point, corners};

    /// A mesh moved 4e6 away from the volume (its samples' grid was 93 GB) or shrunk to
    /// denormal coordinates (the sampling density of the full surface never settled) is refused
    /// in one line; the same mesh on the volume is measured.
    #[test]
    fn a_mesh_off_the_volume_is_refused() {
        let grid = Grid::new([12; 3], [1.0; 3], [0.0; 3]).unwrap();
        let tris = [[0, 1, 2]];
        let moved = |scale: f64, shift: f64| {
            [[2.0, 2.0, 2.0], [6.0, 2.0, 3.0], [2.0, 6.0, 4.0]]
                .map(|p: [f64; 3]| p.map(|c| c * scale).map(|c| c + shift))
        };
        let new = |positions: [[f64; 3]; 3]| {
            FullSurfaceDistances::new(grid, &positions, &tris, &MeasureOptions::default())
        };
        assert!(new(moved(1.0, 0.0)).is_ok());
        for positions in [moved(1.0, 4e6), moved(1e-44, 0.0)] {
            let e = new(positions).err().unwrap();
            assert!(matches!(e, MeasureError::OffVolume(_)), "{e:?}");
            let msg = e.to_string();
            assert!(
                msg.starts_with("the mesh does not lie on that volume") && !msg.contains('\n'),
                "{msg}"
            );
        }
    }

    fn sphere_volume(n: u64) -> Procedural {
        Procedural::new(Shape::Sphere, [n; 3], [1.0; 3], [0.0; 3]).unwrap()
    }

    fn brute_nearest(p: DVec3, positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> f64 {
        triangles
            .iter()
            .map(|t| {
                let t = corners(positions, t);
                closest_point(p, &t).distance(p)
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn full_resolution_surface_is_at_distance_zero_from_itself() {
        let mut v = sphere_volume(24);
        let full = extract_indexed(&mut v, 0.0).unwrap();
        let p = full.position_arrays();
        let opts = MeasureOptions::default();
        let d =
            surface_distances(|| Ok(sphere_volume(24)), 0.0, &p, &full.triangles, &opts).unwrap();
        assert!(d.hausdorff < 1e-9, "{d:?}");
        assert_eq!(d.full_resolution_triangles, full.triangles.len() as u64);
        assert_eq!(d.far_samples, 0);
        assert!(d.full_to_output.samples >= 9_000 && d.output_to_full.samples >= 9_000);
    }

    /// A geodesic sphere against the marching-cubes sphere of the same radius: the streamed
    /// output -> full distances equal a brute-force search over the whole extracted surface.
    #[test]
    fn streamed_distances_match_brute_force_on_a_sphere() {
        let n = 20;
        let centre = (n - 1) as f64 / 2.0;
        let radius = 0.7 * centre; // Shape::Sphere: 0.7 of the half-box
        let (v, f) = geodesic_sphere(2);
        let positions: Vec<[f64; 3]> = v
            .iter()
            .map(|p| (*p * radius + centre).to_array())
            .collect();
        let full = extract_indexed(&mut sphere_volume(n), 0.0).unwrap();
        let full_positions = full.position_arrays();
        let opts = MeasureOptions {
            max_distance: Some(1.0),
            ..MeasureOptions::default()
        };
        let d = surface_distances(|| Ok(sphere_volume(n)), 0.0, &positions, &f, &opts).unwrap();

        // Re-draw the same output samples and measure them against the whole surface.
        let s = DistanceStream::new(&positions, &f, &opts, 1.0).unwrap();
        let (mut sum, mut max) = (0.0, 0.0f64);
        for p in s.samples() {
            let dist = brute_nearest(*p, &full_positions, &full.triangles);
            sum += dist;
            max = max.max(dist);
        }
        let mean = sum / s.samples().len() as f64;
        assert!(
            (d.output_to_full.mean - mean).abs() < 1e-9 * mean,
            "{d:?} vs {mean}"
        );
        assert_eq!(d.output_to_full.hausdorff, max);
        assert!(d.hausdorff > 0.05 && d.hausdorff < 1.0, "{d:?}");
        assert!(d.mean_pct > 0.0 && d.mean_pct < 5.0);
    }

    #[test]
    fn marching_cubes_sphere_has_little_bias() {
        let full = extract_indexed(&mut sphere_volume(41), 0.0).unwrap();
        let q = crate::mesh_quality(&full.position_arrays(), &full.triangles);
        assert!(q.closed);
        assert!(q.directional_bias < 0.02, "{}", q.directional_bias);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]

        /// On random small volumes, with batches cut mid-slab or not, the windowed output -> full
        /// direction and the far samples' second pass equal a brute-force search over the whole
        /// extracted surface, sample by sample (mean, RMS, Hausdorff, the 99.9th percentile),
        /// whatever the radius: it was the distance of every sample farther than it.
        #[test]
        fn windowed_stream_equals_brute_force(
            dims in proptest::array::uniform3(3u64..7),
            spacing in proptest::array::uniform3(0.5f64..2.0),
            seed in 0u64..1000,
            radius in 0.2f64..2.0,
            max_batch in proptest::sample::select(vec![1usize, 7, 1 << 20]),
        ) {
            let grid = Grid::new(dims, spacing, [-1.0, 2.0, 0.5]).unwrap();
            let mut rng = crate::sampling::SplitMix64::new(seed);
            let values: Vec<f32> =
                (0..grid.voxel_count()).map(|_| rng.next_f64() as f32).collect();
            let volume = MemoryVolume::new(grid, values).unwrap();
            let full = extract_indexed(&mut volume.clone(), 0.5).unwrap();
            proptest::prop_assume!(!full.triangles.is_empty());
            let full_positions = full.position_arrays();
            // The "simplified" mesh: the same surface with every vertex moved up to 0.4 voxel.
            let jitter = 0.4 * spacing.iter().cloned().fold(f64::INFINITY, f64::min);
            let output: Vec<[f64; 3]> = full_positions
                .iter()
                .map(|p| p.map(|c| c + jitter * (2.0 * rng.next_f64() - 1.0)))
                .collect();
            let opts = MeasureOptions {
                seed,
                max_distance: Some(radius),
                ..MeasureOptions::default()
            };
            let Ok(mut stream) = FullSurfaceDistances::with_max_batch(
                grid, &output, &full.triangles, &opts, max_batch,
            ) else {
                return Ok(()); // every jittered triangle degenerate: nothing to sample
            };
            feed(&mut volume.clone(), 0.5, max_batch, |b| stream.add(b)).unwrap();
            let mut expected: Vec<f64> = stream
                .stream
                .samples()
                .iter()
                .map(|p| brute_nearest(*p, &full_positions, &full.triangles))
                .collect();
            let d = match stream.finish().unwrap() {
                FirstPass::Done(d) => d,
                FirstPass::Again(mut again) => {
                    feed(&mut volume.clone(), 0.5, max_batch, |b| again.add(b)).unwrap();
                    again.finish()
                }
            };
            let n = expected.len() as f64;
            let mean = expected.iter().sum::<f64>() / n;
            let rms = (expected.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
            let max = expected.iter().cloned().fold(0.0, f64::max);
            let far = expected.iter().filter(|&&x| x >= radius).count() as u64;
            expected.sort_unstable_by(f64::total_cmp);
            let p999 = expected[(0.999 * n).ceil() as usize - 1];
            let o2f = &d.output_to_full;
            proptest::prop_assert!((o2f.mean - mean).abs() <= 1e-9 * mean.max(1e-9));
            proptest::prop_assert!((o2f.rms - rms).abs() <= 1e-9 * rms.max(1e-9));
            proptest::prop_assert_eq!(o2f.hausdorff, max);
            proptest::prop_assert!(p999 <= o2f.p999 && o2f.p999 <= p999 * (1.0 + 1.0 / 1024.0));
            proptest::prop_assert_eq!(d.far_samples, far);
            proptest::prop_assert_eq!(d.full_resolution_triangles, full.triangles.len() as u64);
        }
    }

    #[test]
    fn empty_iso_surface_is_an_error() {
        let grid = Grid::new([3, 3, 3], [1.0; 3], [0.0; 3]).unwrap();
        let v = MemoryVolume::new(grid, vec![0.0; 27]).unwrap();
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let opts = MeasureOptions::default();
        let err = surface_distances(|| Ok(v.clone()), 5.0, &p, &[[0, 1, 2]], &opts);
        assert!(matches!(err, Err(MeasureError::EmptySurface)), "{err:?}");
    }
}
