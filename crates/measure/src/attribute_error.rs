//! Attribute error (issue 5): for area-proportional samples of the full-resolution surface, the
//! difference between the true attribute (interpolated on the full-resolution triangle, whose
//! vertices carry the attribute sampled exactly as the pipeline samples it) and the attribute
//! interpolated at the nearest point of the nearest output triangle. Mean, RMS and max per
//! attribute. The full-resolution surface streams slab by slab, as for [`crate::surface_distances`].

use std::collections::HashMap;

use glam::DVec3;
use isostream_extract::Extractor;
use isostream_extract::attributes::AttributeSlab;
use isostream_volume::Grid;
use serde::Serialize;

use crate::bvh::Bvh;
use crate::distances::{MAX_SAMPLES, MIN_SAMPLES};
use crate::sampling::SplitMix64;
use crate::triangle::{Triangle, area, closest_point, corners};
use crate::{MeasureError, MeasureOptions};

/// The error of one attribute over the full-resolution surface.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AttributeError {
    pub name: String,
    pub mean: f64,
    pub rms: f64,
    pub max: f64,
    pub samples: u64,
}

/// One slice of the iso volume and the same slice of every attribute, in z order.
pub type SliceSet = (Vec<f32>, Vec<Vec<f32>>);

/// Attribute errors of the output mesh (`attrs`: `names.len()` values per vertex) against the
/// full-resolution surface of `grid` at `iso`, whose slices `next` yields for z = 0, 1, ...
///
/// # Errors
/// A slice could not be read, the output has no area or a triangle names a missing vertex.
#[allow(clippy::too_many_arguments)]
pub fn attribute_errors(
    grid: Grid,
    iso: f32,
    names: &[String],
    mut next: impl FnMut() -> Result<Option<SliceSet>, MeasureError>,
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    attrs: &[f32],
    opts: &MeasureOptions,
) -> Result<Vec<AttributeError>, MeasureError> {
    let m = names.len();
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(&v) = tri.iter().find(|&&v| v as usize >= positions.len()) {
            return Err(MeasureError::VertexIndex {
                triangle: t,
                vertex: v,
                vertices: positions.len(),
            });
        }
    }
    let out_tris: Vec<Triangle> = triangles.iter().map(|t| corners(positions, t)).collect();
    let out_area: f64 = out_tris.iter().map(area).sum();
    if out_area.is_nan() || out_area <= 0.0 {
        return Err(MeasureError::EmptyOutput);
    }
    let density = opts
        .samples_per_area
        .clamp(MIN_SAMPLES / out_area, MAX_SAMPLES / out_area);
    let bvh = Bvh::new(out_tris);
    let index: HashMap<[u64; 3], usize> = positions
        .iter()
        .enumerate()
        .map(|(i, p)| (p.map(f64::to_bits), i))
        .collect();
    let out_attr = |p: DVec3| -> Option<&[f32]> {
        let i = *index.get(&p.to_array().map(f64::to_bits))?;
        attrs.get(i * m..(i + 1) * m)
    };
    let mut acc = vec![(0.0f64, 0.0f64, 0.0f64); m];
    let mut samples = 0u64;
    let mut rng = SplitMix64::new(opts.seed);
    let mut hint = 0usize;
    let mut extractor = Extractor::new(grid, iso);
    let Some(mut lower) = next()? else {
        return Ok(Vec::new());
    };
    for z in 0..grid.dims[2].saturating_sub(1) {
        let Some(upper) = next()? else {
            break;
        };
        let slabs: Vec<AttributeSlab<'_>> = lower
            .1
            .iter()
            .zip(&upper.1)
            .map(|(l, u)| AttributeSlab { lower: l, upper: u })
            .collect();
        extractor.extract_slab_with_attributes(
            z,
            &lower.0,
            &upper.0,
            &slabs,
            None,
            1 << 16,
            |b| {
                for cube in &b.cubes {
                    let first = cube.first_vertex as usize;
                    for t in b.cube_triangles(cube) {
                        let idx = t.map(|i| first + i as usize);
                        let tri: Triangle = idx.map(|i| b.vertices[i].pos);
                        let expected = density * area(&tri);
                        let mut count = expected.floor() as u64;
                        if rng.next_f64() < expected - count as f64 {
                            count += 1;
                        }
                        for _ in 0..count {
                            let s = rng.next_f64().sqrt();
                            let r = rng.next_f64();
                            let w = [1.0 - s, s * (1.0 - r), s * r];
                            let p = w[0] * tri[0] + w[1] * tri[1] + w[2] * tri[2];
                            bvh.nearest(p, &mut hint);
                            let Some(near) = bvh.triangle(hint) else {
                                continue;
                            };
                            let q = closest_point(p, near);
                            let wq = barycentric(near, q);
                            let corner_attrs = near.map(out_attr);
                            let [Some(a0), Some(a1), Some(a2)] = corner_attrs else {
                                continue;
                            };
                            samples += 1;
                            for (j, e) in acc.iter_mut().enumerate() {
                                let truth: f64 = (0..3)
                                    .map(|k| w[k] * f64::from(b.attrs[idx[k] * m + j]))
                                    .sum();
                                let got = wq[0] * f64::from(a0[j])
                                    + wq[1] * f64::from(a1[j])
                                    + wq[2] * f64::from(a2[j]);
                                let d = (truth - got).abs();
                                e.0 += d;
                                e.1 += d * d;
                                e.2 = e.2.max(d);
                            }
                        }
                    }
                }
                Ok::<_, MeasureError>(())
            },
        )?;
        lower = upper;
    }
    let n = samples.max(1) as f64;
    Ok(names
        .iter()
        .zip(acc)
        .map(|(name, (sum, sq, max))| AttributeError {
            name: name.clone(),
            mean: sum / n,
            rms: (sq / n).sqrt(),
            max,
            samples,
        })
        .collect())
}

/// Barycentric coordinates of `q` (a point of the triangle's plane) in `t`; the edge midpoint
/// weights for a degenerate triangle.
fn barycentric(t: &Triangle, q: DVec3) -> [f64; 3] {
    let (e1, e2, d) = (t[1] - t[0], t[2] - t[0], q - t[0]);
    let (a11, a12, a22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = a11 * a22 - a12 * a12;
    if det.is_nan() || det <= 1e-300 {
        return [1.0 / 3.0; 3];
    }
    let (b1, b2) = (d.dot(e1), d.dot(e2));
    let u = ((a22 * b1 - a12 * b2) / det).clamp(0.0, 1.0);
    let v = ((a11 * b2 - a12 * b1) / det).clamp(0.0, 1.0 - u);
    [1.0 - u - v, u, v]
}

#[cfg(test)]
mod tests {
    use isostream_extract::extract_indexed;
    use isostream_volume::{MemoryVolume, VolumeSource};

    use super::*;

    /// The full-resolution surface itself, with its own attributes, has no attribute error; a
    /// constant offset shows up as that offset.
    #[test]
    fn full_resolution_output_has_zero_error_and_offsets_are_measured() {
        let grid = Grid::new([12, 12, 12], [1.0, 1.0, 0.5], [0.0; 3]).unwrap();
        let c = grid.position(5.5, 5.5, 5.5);
        let mut iso = Vec::new();
        let mut attr = Vec::new();
        for z in 0..12 {
            for y in 0..12 {
                for x in 0..12 {
                    let p = grid.position(x as f64, y as f64, z as f64);
                    iso.push((4.0 - (p - c).length()) as f32);
                    attr.push((p.x * p.y + 3.0 * p.z) as f32);
                }
            }
        }
        let mut vol = MemoryVolume::new(grid, iso.clone()).unwrap();
        let full = extract_indexed(&mut vol, 0.0).unwrap();
        let positions = full.position_arrays();
        // The attribute at each full-resolution vertex, sampled the pipeline's way: extract the
        // attribute volume's "surface" values by streaming, matched by position.
        let n = grid.slice_len();
        let mut truth: HashMap<[u64; 3], f32> = HashMap::new();
        let mut ex = Extractor::new(grid, 0.0);
        for z in 0..11 {
            let a = [AttributeSlab {
                lower: &attr[z * n..(z + 1) * n],
                upper: &attr[(z + 1) * n..(z + 2) * n],
            }];
            ex.extract_slab_with_attributes(
                z as u64,
                &iso[z * n..(z + 1) * n],
                &iso[(z + 1) * n..(z + 2) * n],
                &a,
                None,
                1 << 16,
                |b| {
                    for (v, x) in b.vertices.iter().zip(&b.attrs) {
                        truth.insert(v.pos.to_array().map(f64::to_bits), *x);
                    }
                    Ok::<_, ()>(())
                },
            )
            .unwrap();
        }
        let attrs: Vec<f32> = positions
            .iter()
            .map(|p| truth[&p.map(f64::to_bits)])
            .collect();
        let run = |attrs: &[f32]| {
            let mut z = 0;
            attribute_errors(
                grid,
                0.0,
                &["a".to_string()],
                || {
                    if z == 12 {
                        return Ok(None);
                    }
                    let s = (
                        iso[z * n..(z + 1) * n].to_vec(),
                        vec![attr[z * n..(z + 1) * n].to_vec()],
                    );
                    z += 1;
                    Ok(Some(s))
                },
                &positions,
                &full.triangles,
                attrs,
                &MeasureOptions::default(),
            )
            .unwrap()
        };
        let e = &run(&attrs)[0];
        assert!(e.samples > 5000, "{e:?}");
        assert!(e.max < 1e-3, "{e:?}");
        let shifted: Vec<f32> = attrs.iter().map(|a| a + 0.25).collect();
        let e = &run(&shifted)[0];
        assert!(
            (e.mean - 0.25).abs() < 1e-3 && (e.rms - 0.25).abs() < 1e-3,
            "{e:?}"
        );
        let _ = vol.grid();
    }
}
