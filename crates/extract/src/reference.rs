//! Plain in-memory marching cubes of a whole volume: the reference the streaming pipeline is
//! tested against, and a convenience for small volumes.
//!
//! It shares only the case table and the interpolation with [`crate::Extractor`]; the traversal
//! is the naive one (eight corner look-ups per cube, no incremental case index, no batches), so
//! comparing the two checks the streaming code rather than repeating it.

use std::collections::HashMap;

use glam::DVec3;
use isostream_volume::{VolumeError, VolumeSource};

use crate::cube::{corner_offset, edge_axis, edge_corners};
use crate::interp::{EdgePlacement, is_inside};
use crate::key::EdgeKey;
use crate::table;

/// An indexed triangle mesh whose vertices are deduplicated by grid edge.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IndexedSurface {
    /// The grid edge of every vertex, in order of first use.
    pub keys: Vec<EdgeKey>,
    pub positions: Vec<DVec3>,
    /// Counter-clockwise seen from outside (normals point towards values at or below iso).
    pub triangles: Vec<[u32; 3]>,
}

impl IndexedSurface {
    /// Positions as plain arrays, the form `isostream-meshcheck` and writers take.
    pub fn position_arrays(&self) -> Vec<[f64; 3]> {
        self.positions.iter().map(|p| p.to_array()).collect()
    }
}

/// Extracts the whole surface of `volume` at `iso`, reading it slice by slice (two slices
/// resident); the surface itself is held in memory.
pub fn extract_indexed(
    volume: &mut dyn VolumeSource,
    iso: f32,
) -> Result<IndexedSurface, VolumeError> {
    let grid = volume.grid();
    let place = EdgePlacement::new(grid, iso);
    let [nx, ny, nz] = grid.dims;
    let mut surface = IndexedSurface::default();
    if nx < 2 || ny < 2 || nz < 2 {
        return Ok(surface);
    }
    let n = grid.slice_len();
    let mut slices = [vec![0.0f32; n], vec![0.0f32; n]];
    volume.read_slice(0, &mut slices[0])?;
    let mut index_of: HashMap<EdgeKey, u32> = HashMap::new();
    for z in 0..nz - 1 {
        volume.read_slice(z + 1, &mut slices[1])?;
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let voxel_of = |c: u8| {
                    let o = corner_offset(c).map(u64::from);
                    [x + o[0], y + o[1], z + o[2]]
                };
                let value = |c: u8| {
                    let v = voxel_of(c);
                    slices[(v[2] - z) as usize][(v[0] + nx * v[1]) as usize]
                };
                let index = (0..8u8)
                    .filter(|&c| is_inside(value(c), iso))
                    .fold(0u8, |i, c| i | (1 << c));
                for tri in table::case(index).edge_triangles() {
                    let vertices = tri.map(|e| {
                        let (a, b) = edge_corners(e);
                        let (voxel, axis) = (voxel_of(a), edge_axis(e));
                        let key = EdgeKey::new(voxel[0], voxel[1], voxel[2], axis, grid.dims);
                        *index_of.entry(key).or_insert_with(|| {
                            surface.keys.push(key);
                            let pos = place.position(voxel, axis, value(a), value(b));
                            surface.positions.push(pos);
                            u32::try_from(surface.keys.len() - 1)
                                .expect("the reference holds fewer than 2^32 vertices")
                        })
                    });
                    surface.triangles.push(vertices);
                }
            }
        }
        slices.swap(0, 1);
    }
    Ok(surface)
}

#[cfg(test)]
mod tests {
    use super::*;
    use isostream_volume::{Grid, MemoryVolume};

    #[test]
    fn single_inside_voxel_is_a_closed_octahedron() {
        let grid = Grid::new([3, 3, 3], [1.0; 3], [0.0; 3]).unwrap();
        let mut data = vec![0.0f32; 27];
        data[13] = 1.0;
        let mut volume = MemoryVolume::new(grid, data).unwrap();
        let s = extract_indexed(&mut volume, 0.5).unwrap();
        assert_eq!((s.keys.len(), s.triangles.len()), (6, 8));
        for p in &s.positions {
            assert_eq!((*p - DVec3::ONE).length(), 0.5);
        }
        let report = isostream_meshcheck::check(&s.position_arrays(), &s.triangles);
        assert!(report.is_closed_manifold(), "{report:?}");
        assert_eq!(report.euler(), 2);
    }

    /// A source whose slices after the first cannot be read.
    struct Truncated(Grid);

    impl VolumeSource for Truncated {
        fn grid(&self) -> Grid {
            self.0
        }
        fn describe(&self) -> String {
            "truncated".to_string()
        }
        fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
            if z > 0 {
                return Err(VolumeError::Contract {
                    origin: self.describe(),
                    problem: format!("slice {z} is missing"),
                });
            }
            out.fill(1.0);
            Ok(())
        }
    }

    #[test]
    fn read_errors_are_returned() {
        let grid = Grid::new([2, 2, 3], [1.0; 3], [0.0; 3]).unwrap();
        let e = extract_indexed(&mut Truncated(grid), 0.5).unwrap_err();
        assert!(e.to_string().contains("slice 1 is missing"), "{e}");
    }

    #[test]
    fn nothing_inside_gives_nothing() {
        let grid = Grid::new([2, 2, 2], [1.0; 3], [0.0; 3]).unwrap();
        let mut volume = MemoryVolume::new(grid, vec![1.0; 8]).unwrap();
        assert_eq!(
            extract_indexed(&mut volume, 1.0).unwrap(),
            IndexedSurface::default()
        );
    }
}
