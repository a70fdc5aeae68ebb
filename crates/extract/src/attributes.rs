//! Vertex attributes: extra scalar fields sampled at the surface vertices (issue 5).
//!
//! An attribute is a second field on the same grid (another volume, another array of the same
//! file, or one derived from the iso volume such as [`gradient_magnitude_slice`]). At a vertex on
//! the grid edge from voxel `a` to voxel `b` it takes the value `f_a + t (f_b - f_a)` with the same
//! `t` that placed the vertex ([`EdgePlacement::crossing`]), so an attribute equal to the iso
//! field itself is exactly the iso value everywhere, and a field linear along the edge is exact.

use isostream_volume::{Grid, SlabBounds};

use crate::interp::EdgePlacement;
use crate::slab::{CubeBatch, Extractor};

/// One attribute's values on the two slices of a slab (each `grid.slice_len()` values).
#[derive(Debug, Clone, Copy)]
pub struct AttributeSlab<'a> {
    pub lower: &'a [f32],
    pub upper: &'a [f32],
}

impl Extractor {
    /// [`Extractor::extract_slab_skipping`], and every batch's `attrs` filled with the
    /// attributes' values at its vertices (`attributes.len()` values per vertex, vertex-major).
    ///
    /// # Panics
    /// As `extract_slab`, and if an attribute slice does not hold `grid.slice_len()` values.
    #[allow(clippy::too_many_arguments)] // one slab: its slices, attributes, bounds and sink
    pub fn extract_slab_with_attributes<E>(
        &mut self,
        z: u64,
        lower: &[f32],
        upper: &[f32],
        attributes: &[AttributeSlab<'_>],
        bounds: Option<&SlabBounds>,
        max_triangles: usize,
        mut emit: impl FnMut(CubeBatch) -> Result<(), E>,
    ) -> Result<(), E> {
        let place = *self.placement();
        let n = place.grid().slice_len();
        assert!(
            attributes
                .iter()
                .all(|a| a.lower.len() == n && a.upper.len() == n),
            "attribute slices must hold {n} values"
        );
        let mut replaced = 0;
        let done =
            self.extract_slab_skipping(z, lower, upper, bounds, max_triangles, |mut batch| {
                if !attributes.is_empty() {
                    replaced += sample(&place, z, [lower, upper], attributes, &mut batch);
                }
                emit(batch)
            });
        self.add_non_finite_attribute_values(replaced);
        done
    }
}

/// Fills `batch.attrs` from the slab's iso and attribute slices; returns how many values came
/// out non-finite and were replaced, each vertex's counted by one of the cubes listing it
/// ([`owns`]). An attribute voxel that is NaN or infinite (masked data,
/// a division by zero upstream) made its vertices' values NaN: written into the output and, as
/// the attribute quadric's coordinates, poisoning the cost of every contraction near them (a
/// sphere with 4 % such voxels came out 21 % of its diagonal away from the surface). The value
/// of the edge's finite end stands in, or 0 when neither end is finite; the run summary counts
/// them and warns.
fn sample(
    place: &EdgePlacement,
    z: u64,
    iso_slices: [&[f32]; 2],
    attributes: &[AttributeSlab<'_>],
    batch: &mut CubeBatch,
) -> u64 {
    let mut replaced = 0;
    let dims = place.grid().dims;
    let nx = dims[0] as usize;
    batch.attrs.clear();
    batch.attrs.reserve(batch.vertices.len() * attributes.len());
    // Each cube lists its own vertices (ranges tiling `vertices` in order).
    let owners = batch
        .cubes
        .iter()
        .flat_map(|cube| std::iter::repeat_n(cube.coord, usize::from(cube.vertex_count)));
    for (v, cube) in batch.vertices.iter().zip(owners) {
        let ([x, y, vz], axis) = v.key.decode(dims);
        let counts = owns(cube, [x, y, vz], dims);
        let (x, y) = (x as usize, y as usize);
        // Ends of the edge: (slice, index) with slice 0 = lower, 1 = upper.
        let upper = usize::from(vz > z);
        let a = (upper, x + nx * y);
        let b = match axis {
            0 => (upper, a.1 + 1),
            1 => (upper, a.1 + nx),
            _ => (1, a.1),
        };
        let t = place.crossing(axis, iso_slices[a.0][a.1], iso_slices[b.0][b.1]);
        for attr in attributes {
            let s = [attr.lower, attr.upper];
            let (fa, fb) = (f64::from(s[a.0][a.1]), f64::from(s[b.0][b.1]));
            let value = (fa + t * (fb - fa)) as f32;
            batch.attrs.push(if value.is_finite() {
                value
            } else {
                replaced += u64::from(counts);
                [fa, fb].into_iter().find(|f| f.is_finite()).unwrap_or(0.0) as f32
            });
        }
    }
    replaced
}

/// Whether the cube at `cube` is the one that counts the vertex on the edge from voxel `edge`:
/// up to four cubes (in neighbouring rows and slabs) list a vertex, and the counters are per
/// surface vertex. The owner is the cube starting at the edge's own voxel, or the one below it
/// on an axis where that voxel is on the volume's last face (no cube starts there); along the
/// edge's axis the cube always starts at the edge's voxel.
fn owns(cube: [u64; 3], edge: [u64; 3], dims: [u64; 3]) -> bool {
    (0..3).all(|d| cube[d] == edge[d].min(dims[d].saturating_sub(2)))
}

/// `|grad f|` on slice `z` by central differences in physical units (`spacing`), one-sided at
/// the volume's faces: `prev` and `next` are slices `z - 1` and `z + 1` (`None` at the ends).
/// Non-finite neighbours give a non-finite value, as the data does.
///
/// # Panics
/// If a slice or `out` does not hold `grid.slice_len()` values.
pub fn gradient_magnitude_slice(
    grid: &Grid,
    prev: Option<&[f32]>,
    cur: &[f32],
    next: Option<&[f32]>,
    out: &mut [f32],
) {
    let [nx, ny, _] = grid.dims.map(|d| d as usize);
    let n = nx * ny;
    assert!(
        cur.len() == n && out.len() == n,
        "slices must hold {n} values"
    );
    let [sx, sy, sz] = grid.spacing;
    // (lower, upper, distance) of a difference along an axis with `len` samples at index `i`.
    let span = |i: usize, len: usize, h: f64| {
        let lo = i.saturating_sub(1);
        let hi = (i + 1).min(len - 1);
        (lo, hi, (hi - lo) as f64 * h)
    };
    let (zlo, zhi, dz) = match (prev, next) {
        (Some(p), Some(q)) => (p, q, 2.0 * sz),
        (None, Some(q)) => (cur, q, sz),
        (Some(p), None) => (p, cur, sz),
        (None, None) => (cur, cur, 0.0),
    };
    for y in 0..ny {
        let (y0, y1, dy) = span(y, ny, sy);
        for x in 0..nx {
            let (x0, x1, dx) = span(x, nx, sx);
            let i = x + nx * y;
            let d = |a: f32, b: f32, h: f64| {
                if h > 0.0 {
                    (f64::from(b) - f64::from(a)) / h
                } else {
                    0.0
                }
            };
            let gx = d(cur[x0 + nx * y], cur[x1 + nx * y], dx);
            let gy = d(cur[x + nx * y0], cur[x + nx * y1], dy);
            let gz = d(zlo[i], zhi[i], dz);
            out[i] = (gx * gx + gy * gy + gz * gz).sqrt() as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slices(grid: &Grid, f: impl Fn(f64, f64, f64) -> f64) -> Vec<Vec<f32>> {
        let [nx, ny, nz] = grid.dims;
        (0..nz)
            .map(|z| {
                (0..ny)
                    .flat_map(|y| (0..nx).map(move |x| (x, y)))
                    .map(|(x, y)| {
                        let p = grid.position(x as f64, y as f64, z as f64);
                        f(p.x, p.y, p.z) as f32
                    })
                    .collect()
            })
            .collect()
    }

    /// A linear attribute is exact at every vertex; the iso field itself samples to iso.
    #[test]
    fn attributes_use_the_vertex_placement() {
        let grid = Grid::new([6, 5, 4], [1.0, 0.5, 2.0], [1.0, 2.0, 3.0]).unwrap();
        let centre = grid.position(2.5, 2.0, 1.5);
        let iso_f = |x: f64, y: f64, z: f64| {
            4.0 - ((x - centre.x).powi(2) + (y - centre.y).powi(2) + (z - centre.z).powi(2)).sqrt()
        };
        let lin = |x: f64, y: f64, z: f64| 2.0 * x - 3.0 * y + 0.5 * z;
        let (iso_s, lin_s) = (slices(&grid, iso_f), slices(&grid, lin));
        let mut ex = Extractor::new(grid, 1.5);
        let mut vertices = 0;
        for z in 0..3 {
            let attrs = [
                AttributeSlab {
                    lower: &lin_s[z],
                    upper: &lin_s[z + 1],
                },
                AttributeSlab {
                    lower: &iso_s[z],
                    upper: &iso_s[z + 1],
                },
            ];
            ex.extract_slab_with_attributes(
                z as u64,
                &iso_s[z],
                &iso_s[z + 1],
                &attrs,
                None,
                7,
                |b| {
                    assert_eq!(b.attrs.len(), 2 * b.vertices.len());
                    for (v, a) in b.vertices.iter().zip(b.attrs.chunks(2)) {
                        let want = lin(v.pos.x, v.pos.y, v.pos.z);
                        assert!((f64::from(a[0]) - want).abs() < 1e-4, "{a:?} {want}");
                        assert!((a[1] - 1.5).abs() < 1e-5, "{a:?}");
                        vertices += 1;
                    }
                    Ok::<_, ()>(())
                },
            )
            .unwrap();
        }
        assert!(vertices > 20);
    }

    /// A vertex is shared by up to four cubes, in neighbouring rows and slabs: each of its
    /// non-finite values is counted once all the same. (Each cube counted its own: a trial's
    /// 1,488-vertex surface reported 5,572 such values.)
    #[test]
    fn non_finite_attribute_values_are_counted_once_per_vertex() {
        let grid = Grid::new([7, 6, 5], [1.0; 3], [0.0; 3]).unwrap();
        let centre = grid.position(3.0, 2.5, 2.0);
        let iso_s = slices(&grid, |x, y, z| {
            3.0 - ((x - centre.x).powi(2) + (y - centre.y).powi(2) + (z - centre.z).powi(2)).sqrt()
        });
        let nan = vec![f32::NAN; grid.slice_len()];
        let finite = vec![1.0; grid.slice_len()];
        let mut ex = Extractor::new(grid, 0.5);
        let mut keys = std::collections::HashSet::new();
        for z in 0..4 {
            let attrs = [
                AttributeSlab {
                    lower: &finite,
                    upper: &finite,
                },
                AttributeSlab {
                    lower: &nan,
                    upper: &nan,
                },
            ];
            ex.extract_slab_with_attributes(
                z,
                &iso_s[z as usize],
                &iso_s[z as usize + 1],
                &attrs,
                None,
                7,
                |b| {
                    keys.extend(b.vertices.iter().map(|v| v.key));
                    assert!(b.attrs.iter().all(|a| a.is_finite()));
                    Ok::<_, ()>(())
                },
            )
            .unwrap();
        }
        assert!(keys.len() > 50, "{}", keys.len());
        assert_eq!(ex.stats().non_finite_attribute_values, keys.len() as u64);
    }

    #[test]
    fn gradient_magnitude_of_a_linear_field_is_its_slope_in_physical_units() {
        let grid = Grid::new([5, 4, 3], [2.0, 0.5, 1.0], [0.0; 3]).unwrap();
        let s = slices(&grid, |x, y, z| 3.0 * x + 4.0 * y + 12.0 * z);
        let mut out = vec![0.0; grid.slice_len()];
        for z in 0..3usize {
            let prev = z.checked_sub(1).map(|p| s[p].as_slice());
            let next = s.get(z + 1).map(Vec::as_slice);
            gradient_magnitude_slice(&grid, prev, &s[z], next, &mut out);
            assert!(out.iter().all(|g| (g - 13.0).abs() < 1e-4), "{out:?}");
        }
    }
}
