//! The bundle `isostream measure` prints: mesh quality, distances and the run's shape error.

use std::fmt::Write as _;

use serde::Serialize;

use crate::{DirectedDistance, Distances, MeshQuality};

/// Everything measured about one output mesh.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeasureReport {
    pub quality: MeshQuality,
    /// Absent when no volume was given to regenerate the full-resolution surface from.
    pub distances: Option<Distances>,
    /// Tandem paper section 4: `Error(K) = max_u eps0(u)`, known only to the run that simplified
    /// (read from its run summary); absent when there is none.
    pub shape_error: Option<f64>,
    /// Per vertex attribute: its error against the full-resolution surface's (empty without
    /// attributes or without a volume).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub attributes: Vec<crate::AttributeError>,
}

impl MeasureReport {
    /// Human-readable form, one fact per line.
    pub fn to_text(&self) -> String {
        let q = &self.quality;
        let mut s = String::new();
        // Writing into a String cannot fail.
        let _ = writeln!(
            s,
            "mesh: {}, {}, {}, Euler characteristic {}",
            count(q.triangles, "triangle", "triangles"),
            count(q.vertices, "vertex", "vertices"),
            count(q.components, "component", "components"),
            q.euler
        );
        let _ = writeln!(s, "topology: {}", topology(q));
        let [out, inward] = q.closed_by_sign;
        let _ = writeln!(
            s,
            "closed components: {out} enclosing positive volume (facing out), {inward} negative \
             (cavities; a simplification keeps both counts)"
        );
        let _ = writeln!(
            s,
            "anisotropy {:.4}, directional bias {:.4}",
            q.anisotropy, q.directional_bias
        );
        let bins: Vec<String> = q
            .min_angle_histogram
            .iter()
            .map(|(start, n)| format!("{start}-{}: {n}", start + 5.0))
            .collect();
        let _ = writeln!(s, "min angle (degrees): {}", bins.join(", "));
        match self.shape_error {
            Some(e) => {
                let _ = writeln!(s, "shape error (max eps0): {e:.6}");
            }
            None => s.push_str("shape error: unknown (no run summary of this mesh)\n"),
        }
        if let Some(d) = &self.distances {
            write_distances(&mut s, d);
        }
        for a in &self.attributes {
            let _ = writeln!(
                s,
                "attribute {}: error mean {:.6}, rms {:.6}, max {:.6} ({} samples of the full-resolution surface)",
                a.name, a.mean, a.rms, a.max, a.samples
            );
        }
        s
    }
}

/// `n` and the noun in the number it takes: "1 component", "800 components" (the text said
/// "1 components").
fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// The topology line's facts. A mesh without boundary edges that is not a closed manifold (a
/// bowtie, a flipped face) said "NOT closed, ..., 0 boundary edges", which read as a
/// contradiction: it says instead that it has no boundary and what else is wrong, with counts.
fn topology(q: &MeshQuality) -> String {
    let property = |ok: bool, what: &str, n: usize, units: (&str, &str)| {
        if ok {
            what.to_string()
        } else {
            format!("NOT {what} ({})", count(n, units.0, units.1))
        }
    };
    let mut parts = vec![
        property(
            q.edge_manifold,
            "edge-manifold",
            q.non_manifold_edges,
            ("non-manifold edge", "non-manifold edges"),
        ),
        property(
            q.vertex_manifold,
            "vertex-manifold",
            q.non_manifold_vertices,
            ("non-manifold vertex", "non-manifold vertices"),
        ),
        property(
            q.oriented,
            "oriented",
            q.misoriented_edges,
            ("misoriented edge", "misoriented edges"),
        ),
    ];
    let boundary = q.boundary_edges;
    let lead = match (q.closed, boundary) {
        (true, _) => "closed,",
        (false, 0) => "no boundary edges, but NOT a closed manifold:",
        (false, _) => "NOT closed,",
    };
    if boundary > 0 || q.closed {
        parts.push(count(boundary, "boundary edge", "boundary edges"));
    }
    if q.duplicate_triangles > 0 {
        parts.push(count(
            q.duplicate_triangles,
            "duplicate triangle",
            "duplicate triangles",
        ));
    }
    if q.repeated_index_triangles > 0 {
        parts.push(count(
            q.repeated_index_triangles,
            "triangle that uses a vertex twice",
            "triangles that use a vertex twice",
        ));
    }
    parts.push(count(
        q.zero_area_triangles,
        "zero-area triangle",
        "zero-area triangles",
    ));
    format!("{lead} {}", parts.join(", "))
}

fn write_distances(s: &mut String, d: &Distances) {
    let line = |label: &str, x: &DirectedDistance| {
        format!(
            "  {label}: mean {:.6}, rms {:.6}, hausdorff {:.6}, 99.9 % within {:.6} ({} samples)\n",
            x.mean, x.rms, x.hausdorff, x.p999, x.samples
        )
    };
    let _ = writeln!(
        s,
        "distances to the full-resolution surface ({} triangles, {:.4} samples per unit^2):",
        d.full_resolution_triangles, d.samples_per_area
    );
    s.push_str(&line("full -> output", &d.full_to_output));
    if d.full_sample_weight > 1 {
        let _ = writeln!(
            s,
            "  the full-resolution surface has over four times the output's area (is the mesh from this volume, in its units?): its later parts were sampled more sparsely, the last samples counting {} times each",
            d.full_sample_weight
        );
    }
    s.push_str(&line("output -> full", &d.output_to_full));
    if d.far_samples > 0 {
        let _ = writeln!(
            s,
            "  {} output samples had no full-resolution point within {:.6}: measured exactly in a second pass over the full-resolution surface",
            d.far_samples, d.max_distance
        );
    }
    let _ = writeln!(
        s,
        "  undirected: mean {:.6} ({:.4}%), rms {:.6} ({:.4}%), hausdorff {:.6} ({:.4}%), 99.9 % within {:.6} ({:.4}%) of diagonal {:.6}",
        d.mean,
        d.mean_pct,
        d.rms,
        d.rms_pct,
        d.hausdorff,
        d.hausdorff_pct,
        d.p999,
        d.p999_pct,
        d.diagonal
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh_quality;

    fn directed(x: f64) -> DirectedDistance {
        DirectedDistance {
            mean: x,
            rms: x,
            hausdorff: x,
            p999: x / 2.0,
            samples: 10,
            histogram: vec![(0.0, 10)],
        }
    }

    fn report(far: u64) -> MeasureReport {
        report_weighted(far, 1)
    }

    fn report_weighted(far: u64, full_sample_weight: u64) -> MeasureReport {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        MeasureReport {
            quality: mesh_quality(&p, &[[0, 1, 2]]),
            distances: Some(Distances {
                full_to_output: directed(0.1),
                output_to_full: directed(0.2),
                mean: 0.2,
                rms: 0.2,
                hausdorff: 0.2,
                p999: 0.1,
                diagonal: 2.0,
                mean_pct: 10.0,
                rms_pct: 10.0,
                hausdorff_pct: 10.0,
                p999_pct: 5.0,
                full_resolution_triangles: 7,
                full_sample_weight,
                far_samples: far,
                max_distance: 0.2,
                samples_per_area: 100.0,
            }),
            shape_error: Some(0.05),
            attributes: Vec::new(),
        }
    }

    #[test]
    fn text_names_every_measure() {
        let text = report(0).to_text();
        for needle in [
            "mesh: 1 triangle, 3 vertices, 1 component, Euler characteristic 1",
            "NOT closed, edge-manifold, vertex-manifold, oriented, 3 boundary edges, 0 zero-area",
            "anisotropy",
            "directional bias",
            "55-60: 0",
            "shape error (max eps0): 0.050000",
            "full -> output: mean 0.100000",
            "output -> full: mean 0.200000",
            "hausdorff 0.200000 (10.0000%)",
            "99.9 % within 0.100000 (5.0000%)",
        ] {
            assert!(text.contains(needle), "{needle:?} missing from\n{text}");
        }
        assert!(!text.contains("second pass") && !text.contains("sparsely"));
        let far = report(3).to_text();
        assert!(
            far.contains("3 output samples had no full-resolution point within 0.200000: measured exactly in a second pass"),
            "{far}"
        );
        assert!(!far.contains("lower bound"), "{far}");
        assert!(
            report_weighted(0, 16)
                .to_text()
                .contains("sampled more sparsely, the last samples counting 16 times each")
        );
    }

    /// Two tetrahedra sharing one vertex (a bowtie), and an icosahedron with one face flipped:
    /// no boundary edge, yet not closed manifolds. The text said "NOT closed" beside "0 boundary
    /// edges"; it now says what is wrong, and the JSON has the counts.
    /// The text report of a mesh's quality alone.
    fn quality_text(quality: MeshQuality) -> String {
        MeasureReport {
            quality,
            distances: None,
            shape_error: None,
            attributes: Vec::new(),
        }
        .to_text()
    }

    #[test]
    fn a_mesh_without_boundary_that_is_not_a_closed_manifold_says_why() {
        let tetra = |o: [f64; 3], s: f64| {
            [
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ]
            .map(|p| [o[0] + s * p[0], o[1] + s * p[1], o[2] + s * p[2]])
        };
        let mut p: Vec<[f64; 3]> = tetra([0.0; 3], 1.0).to_vec();
        p.extend(&tetra([0.0; 3], -1.0)[1..]);
        let faces = |v: [u32; 4]| {
            [
                [v[0], v[2], v[1]],
                [v[0], v[1], v[3]],
                [v[0], v[3], v[2]],
                [v[1], v[2], v[3]],
            ]
        };
        let mut t = faces([0, 1, 2, 3]).to_vec();
        // Mirrored by the negative scale: the other winding points out.
        t.extend(faces([0, 4, 5, 6]).map(|[a, b, c]| [a, c, b]));
        let q = mesh_quality(&p, &t);
        assert_eq!((q.boundary_edges, q.non_manifold_vertices), (0, 1), "{q:?}");
        assert!(!q.closed && q.edge_manifold && q.oriented && !q.vertex_manifold);
        let text = quality_text(q);
        assert!(
            text.contains("topology: no boundary edges, but NOT a closed manifold: edge-manifold, NOT vertex-manifold (1 non-manifold vertex), oriented, 0 zero-area triangles"),
            "{text}"
        );

        let (v, mut f) = crate::bias::tests::icosahedron();
        f[0].swap(1, 2);
        let p: Vec<[f64; 3]> = v.iter().map(|x| x.to_array()).collect();
        let q = mesh_quality(&p, &f);
        let json = serde_json::to_value(&q).unwrap();
        assert_eq!(json["misoriented_edges"], 3);
        assert_eq!(
            (json["closed"].clone(), json["boundary_edges"].clone()),
            (false.into(), 0.into())
        );
        let text = quality_text(q);
        assert!(
            text.contains("no boundary edges, but NOT a closed manifold: edge-manifold, vertex-manifold, NOT oriented (3 misoriented edges)"),
            "{text}"
        );
        assert!(!text.contains("NOT closed"), "{text}");
    }

    #[test]
    fn json_has_the_same_facts() {
        let json = serde_json::to_value(report(0)).unwrap();
        assert_eq!(json["distances"]["output_to_full"]["samples"], 10);
        assert_eq!(json["shape_error"], 0.05);
        assert_eq!(json["quality"]["boundary_edges"], 3);
    }
}
