//! Mesh quality of the (simplified) output mesh: topology from the `meshcheck` referee, the
//! minimum-angle histogram, and the Tandem paper's section 4 anisotropy and directional bias.

use serde::Serialize;

use crate::anisotropy::anisotropy;
use crate::bias::directional_bias;
use crate::triangle::{Triangle, corners, min_angle_degrees};

/// Width of a minimum-angle bin in degrees. A triangle's smallest angle is at most 60 degrees,
/// so twelve bins cover every triangle.
const ANGLE_BIN_DEGREES: f64 = 5.0;
const ANGLE_BINS: usize = 12;

/// Topology and shape of one mesh. Counts come from `isostream_meshcheck::check`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshQuality {
    pub triangles: usize,
    /// Vertices referenced by at least one triangle.
    pub vertices: usize,
    /// No edge has three or more triangles.
    pub edge_manifold: bool,
    /// Every vertex's link is one cycle or one path.
    pub vertex_manifold: bool,
    /// Neighbouring triangles traverse their shared edge in opposite directions.
    pub oriented: bool,
    /// A closed manifold: no boundary edges, and edge-manifold, vertex-manifold, oriented,
    /// without duplicate triangles or triangles that use a vertex twice. A mesh without boundary
    /// edges can still fail it (a bowtie, a flipped face): the counts below say which way. An
    /// empty mesh (an `allow_empty` output) is closed: it has no boundary.
    pub closed: bool,
    pub boundary_edges: usize,
    /// Edges of three or more triangles (`edge_manifold` is false when there is one).
    pub non_manifold_edges: usize,
    /// Vertices whose link is not one cycle or one path (`vertex_manifold` is false when there
    /// is one).
    pub non_manifold_vertices: usize,
    /// Edges whose two triangles traverse it the same way (`oriented` is false when there is
    /// one).
    pub misoriented_edges: usize,
    /// Copies of a triangle beyond its first (same three vertices).
    pub duplicate_triangles: usize,
    /// Triangles that use a vertex twice (also counted in `zero_area_triangles`).
    pub repeated_index_triangles: usize,
    pub zero_area_triangles: usize,
    /// V - E + F over the whole mesh.
    pub euler: i64,
    pub components: usize,
    /// Closed components enclosing positive volume (facing out, as isostream writes a surface
    /// around high values) and negative volume (a cavity, or a component turned inside out):
    /// a simplification keeps both counts of its full-resolution surface.
    pub closed_by_sign: [usize; 2],
    /// `(bin start in degrees, triangles)` for bins 0-5, 5-10, ..., 55-60 of the smallest angle of
    /// each triangle; an equilateral triangle counts in the last bin.
    pub min_angle_histogram: Vec<(f64, u64)>,
    /// Tandem paper section 4 "Mesh quality": `1 - mean rho(t)`, 0 iff all triangles are
    /// equilateral.
    pub anisotropy: f64,
    /// Tandem paper section 4 "Directional bias": `1 - 27 det M / (trace M)^3`.
    pub directional_bias: f64,
}

/// Measures an indexed mesh held in memory (the output mesh; the full-resolution surface is
/// never materialised).
///
/// # Panics
/// If a triangle indexes past `positions` (readers validate indices before this point).
pub fn mesh_quality(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> MeshQuality {
    let report = isostream_meshcheck::check(positions, triangles);
    let tris: Vec<Triangle> = triangles.iter().map(|t| corners(positions, t)).collect();
    MeshQuality {
        triangles: report.triangles,
        vertices: report.vertices,
        edge_manifold: report.non_manifold_edges == 0,
        vertex_manifold: report.non_manifold_vertices == 0,
        oriented: report.misoriented_edges == 0,
        closed: report.is_closed_manifold(),
        boundary_edges: report.boundary_edges,
        non_manifold_edges: report.non_manifold_edges,
        non_manifold_vertices: report.non_manifold_vertices,
        misoriented_edges: report.misoriented_edges,
        duplicate_triangles: report.duplicate_triangles,
        repeated_index_triangles: report.repeated_index_triangles,
        // A triangle using a vertex twice has no area either (the check counts it apart).
        zero_area_triangles: report.zero_area_triangles + report.repeated_index_triangles,
        euler: report.euler(),
        components: report.components.len(),
        closed_by_sign: report.closed_by_sign(),
        min_angle_histogram: min_angle_histogram(&tris),
        anisotropy: anisotropy(tris.iter()),
        directional_bias: directional_bias(tris.iter()),
    }
}

fn min_angle_histogram(tris: &[Triangle]) -> Vec<(f64, u64)> {
    let mut counts = [0u64; ANGLE_BINS];
    for t in tris {
        let bin = (min_angle_degrees(t) / ANGLE_BIN_DEGREES) as usize;
        counts[bin.min(ANGLE_BINS - 1)] += 1;
    }
    counts
        .iter()
        .enumerate()
        .map(|(i, &n)| (i as f64 * ANGLE_BIN_DEGREES, n))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bias::tests::{geodesic_sphere, icosahedron};

    fn arrays(v: &[glam::DVec3]) -> Vec<[f64; 3]> {
        v.iter().map(|p| p.to_array()).collect()
    }

    #[test]
    fn icosahedron_is_perfect() {
        let (v, f) = icosahedron();
        let q = mesh_quality(&arrays(&v), &f);
        assert_eq!(
            (q.triangles, q.vertices, q.euler, q.components),
            (20, 12, 2, 1)
        );
        assert!(q.closed && q.edge_manifold && q.vertex_manifold && q.oriented);
        assert!(q.anisotropy.abs() < 1e-9, "{}", q.anisotropy);
        assert!(q.directional_bias < 1e-9);
        assert_eq!(q.min_angle_histogram.len(), 12);
        assert_eq!(q.min_angle_histogram[11], (55.0, 20));
    }

    #[test]
    fn open_strip_reports_boundary_and_skinny_angles() {
        // Two triangles of a 100 x 1 rectangle.
        let p = [
            [0.0, 0.0, 0.0],
            [100.0, 0.0, 0.0],
            [100.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let q = mesh_quality(&p, &[[0, 1, 2], [0, 2, 3]]);
        assert!(!q.closed && q.edge_manifold);
        assert_eq!(q.boundary_edges, 4);
        assert_eq!(q.euler, 1);
        assert_eq!(q.min_angle_histogram[0], (0.0, 2));
        assert!(q.anisotropy > 0.9);
    }

    #[test]
    fn sphere_quality_serialises() {
        let (v, f) = geodesic_sphere(2);
        let q = mesh_quality(&arrays(&v), &f);
        assert!(q.closed);
        let json = serde_json::to_value(&q).unwrap();
        assert_eq!(json["triangles"], 320);
        assert_eq!(json["min_angle_histogram"][11][0], 55.0);
    }

    #[test]
    fn empty_mesh_is_harmless() {
        let q = mesh_quality(&[], &[]);
        assert_eq!(
            (q.triangles, q.anisotropy, q.directional_bias),
            (0, 0.0, 0.0)
        );
    }
}
