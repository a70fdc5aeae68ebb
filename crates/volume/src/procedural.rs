//! Analytic test volumes: implicit functions sampled on a grid, computed slice by slice, so tests
//! and benchmarks of any size need no files and no memory beyond one slice.

use crate::grid::dims_text;
use crate::source::check_request;
use crate::{Grid, VolumeError, VolumeSource};
use std::f64::consts::PI;

/// The implicit shapes. Inside where the value is > 0; the surface is iso = 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    /// Sphere of radius 0.7 around the centre.
    Sphere,
    /// Torus in the xy-plane, major radius 0.55, tube radius 0.22 (genus 1).
    Torus,
    /// Two interlocked tori (Attali et al.'s "Link"): genus 2 in total, two components.
    Link,
    /// Rounded cube x^4 + y^4 + z^4 <= 0.6^4 (the "Pillow Box").
    Pillow,
    /// Gyroid with 1.5 periods across the box: open, genus-heavy, touches the boundary.
    Gyroid,
}

/// Link: each ring has major radius 0.5 and is centred on the other ring's circle, which keeps the
/// two centre circles exactly 0.5 apart everywhere; tubes of 0.15 leave a 0.2 gap.
const LINK_R: f64 = 0.5;
const LINK_TUBE: f64 = 0.15;
const GYROID_K: f64 = 2.0 * PI * 1.5;

impl Shape {
    /// Lower-case name, as written in job files and logs.
    pub fn name(self) -> &'static str {
        match self {
            Shape::Sphere => "sphere",
            Shape::Torus => "torus",
            Shape::Link => "link",
            Shape::Pillow => "pillow",
            Shape::Gyroid => "gyroid",
        }
    }

    /// The implicit function at `p` in [-1, 1]^3.
    pub fn value(self, [x, y, z]: [f64; 3]) -> f64 {
        match self {
            Shape::Sphere => 0.7 - (x * x + y * y + z * z).sqrt(),
            Shape::Torus => torus(x, y, z, 0.55, 0.22),
            // One ring in the xy-plane around (-0.25, 0, 0), one in the xz-plane around (0.25, 0, 0).
            Shape::Link => torus(x + 0.25, y, z, LINK_R, LINK_TUBE).max(torus(
                x - 0.25,
                z,
                y,
                LINK_R,
                LINK_TUBE,
            )),
            Shape::Pillow => 0.6f64.powi(4) - (x.powi(4) + y.powi(4) + z.powi(4)),
            Shape::Gyroid => {
                let (sx, cx) = (GYROID_K * x).sin_cos();
                let (sy, cy) = (GYROID_K * y).sin_cos();
                let (sz, cz) = (GYROID_K * z).sin_cos();
                sx * cy + sy * cz + sz * cx
            }
        }
    }
}

/// Signed distance-like field of a torus around the z-axis of the local frame, positive inside.
fn torus(x: f64, y: f64, z: f64, major: f64, tube: f64) -> f64 {
    let ring = (x * x + y * y).sqrt() - major;
    tube - (ring * ring + z * z).sqrt()
}

/// A procedural volume: voxel (i, j, k) holds `shape.value(p)` with p = -1 + 2 * i / (n - 1) per
/// axis, so the shape fills the same fraction of the box at every resolution.
#[derive(Debug, Clone)]
pub struct Procedural {
    shape: Shape,
    grid: Grid,
}

impl Procedural {
    pub fn new(
        shape: Shape,
        size: [u64; 3],
        spacing: [f64; 3],
        origin: [f64; 3],
    ) -> Result<Self, VolumeError> {
        let grid = Grid::new(size, spacing, origin)
            .map_err(|e| e.in_origin(&format!("procedural {}", shape.name())))?;
        Ok(Procedural { shape, grid })
    }
}

/// Maps voxel index `i` of `n` to [-1, 1].
fn unit(i: u64, n: u64) -> f64 {
    -1.0 + 2.0 * i as f64 / (n - 1) as f64
}

impl VolumeSource for Procedural {
    fn grid(&self) -> Grid {
        self.grid
    }

    fn describe(&self) -> String {
        format!(
            "procedural {} {}",
            self.shape.name(),
            dims_text(self.grid.dims)
        )
    }

    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        check_request(self, z, out)?;
        let [nx, ny, nz] = self.grid.dims;
        let pz = unit(z, nz);
        for (j, row) in out.chunks_exact_mut(nx as usize).enumerate() {
            let py = unit(j as u64, ny);
            for (i, v) in row.iter_mut().enumerate() {
                *v = self.shape.value([unit(i as u64, nx), py, pz]) as f32;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [Shape; 5] = [
        Shape::Sphere,
        Shape::Torus,
        Shape::Link,
        Shape::Pillow,
        Shape::Gyroid,
    ];

    fn inside(s: Shape, p: [f64; 3]) -> bool {
        s.value(p) > 0.0
    }

    #[test]
    fn sign_patterns() {
        let c = [0.0; 3];
        assert!(inside(Shape::Sphere, c) && !inside(Shape::Sphere, [0.71, 0.0, 0.0]));
        assert!(inside(Shape::Sphere, [0.69, 0.0, 0.0]));
        assert!(inside(Shape::Pillow, c) && inside(Shape::Pillow, [0.59, 0.0, 0.0]));
        assert!(!inside(Shape::Pillow, [0.61, 0.0, 0.0]));
        // A pillow is fuller than the inscribed sphere at the corners direction.
        assert!(inside(Shape::Pillow, [0.45, 0.45, 0.45]));
        // Torus: hole at the centre, tube at radius 0.55 in the xy-plane, not along z.
        assert!(!inside(Shape::Torus, c));
        assert!(inside(Shape::Torus, [0.55, 0.0, 0.0]) && inside(Shape::Torus, [0.0, -0.55, 0.2]));
        assert!(!inside(Shape::Torus, [0.55, 0.0, 0.23]));
        // Link: each ring's tube passes through the other's hole centre.
        assert!(inside(Shape::Link, [0.25, 0.0, 0.0]) && inside(Shape::Link, [-0.25, 0.0, 0.0]));
        assert!(inside(Shape::Link, [-0.75, 0.0, 0.0]) && inside(Shape::Link, [0.75, 0.0, 0.0]));
        assert!(inside(Shape::Link, [-0.25, 0.5, 0.0]) && inside(Shape::Link, [0.25, 0.0, 0.5]));
        assert!(!inside(Shape::Link, [-0.25, 0.0, 0.5]) && !inside(Shape::Link, [0.25, 0.5, 0.0]));
        // Gyroid: zero at the origin, both signs present.
        assert_eq!(Shape::Gyroid.value(c), 0.0);
    }

    #[test]
    fn link_rings_do_not_touch() {
        const { assert!(LINK_R > 2.0 * LINK_TUBE) };
        // On ring A's centre circle, ring B's centre circle is exactly LINK_R away, so the tubes
        // (radius LINK_TUBE each) are separated by LINK_R - 2 * LINK_TUBE > 0.
        for t in 0..360 {
            let a = (t as f64).to_radians();
            let p = [-0.25 + LINK_R * a.cos(), LINK_R * a.sin(), 0.0];
            let b = torus(p[0] - 0.25, p[2], p[1], LINK_R, LINK_TUBE);
            assert!((b - (LINK_TUBE - LINK_R)).abs() < 1e-9, "{a} {b}");
        }
    }

    #[test]
    fn closed_shapes_are_outside_on_the_boundary_and_gyroid_is_not() {
        for shape in ALL {
            let mut v = Procedural::new(shape, [17, 17, 17], [1.0; 3], [0.0; 3]).unwrap();
            let mut out = vec![0.0f32; 17 * 17];
            let mut boundary_inside = false;
            let (mut pos, mut neg) = (false, false);
            for z in 0..17 {
                v.read_slice(z, &mut out).unwrap();
                for (n, &val) in out.iter().enumerate() {
                    let (i, j) = (n % 17, n / 17);
                    let on_boundary = [i, j, z as usize].iter().any(|&c| c == 0 || c == 16);
                    boundary_inside |= on_boundary && val > 0.0;
                    pos |= val > 0.0;
                    neg |= val < 0.0;
                }
            }
            assert!(pos && neg, "{shape:?} needs both signs");
            assert_eq!(boundary_inside, shape == Shape::Gyroid, "{shape:?}");
        }
    }

    #[test]
    fn voxel_mapping_and_describe() {
        let mut v = Procedural::new(Shape::Sphere, [3, 5, 3], [1.0; 3], [0.0; 3]).unwrap();
        assert_eq!(v.describe(), "procedural sphere 3x5x3");
        let mut out = vec![0.0f32; 15];
        v.read_slice(1, &mut out).unwrap();
        // Centre voxel (1, 2, 1) is p = (0, 0, 0); voxel (0, 0, 1) is p = (-1, -1, 0).
        assert_eq!(out[2 * 3 + 1], 0.7);
        assert_eq!(out[0], (0.7 - 2f64.sqrt()) as f32);
        let e = Procedural::new(Shape::Torus, [1, 5, 3], [1.0; 3], [0.0; 3]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "procedural torus: dims 1x5x3 need at least 2 voxels per axis; check the dims"
        );
    }

    #[test]
    fn shapes_are_named_in_lowercase_in_job_files() {
        for shape in ALL {
            let json = serde_json::to_string(&shape).unwrap();
            assert_eq!(json, format!("\"{}\"", shape.name()));
            assert_eq!(serde_json::from_str::<Shape>(&json).unwrap(), shape);
        }
    }
}
