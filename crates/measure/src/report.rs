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
        let yes_no = |b: bool, what: &str| {
            if b {
                what.to_string()
            } else {
                format!("NOT {what}")
            }
        };
        // Writing into a String cannot fail.
        let _ = writeln!(
            s,
            "mesh: {} triangles, {} vertices, {} components, Euler characteristic {}",
            q.triangles, q.vertices, q.components, q.euler
        );
        let _ = writeln!(
            s,
            "topology: {}, {}, {}, {}, {} boundary edges, {} zero-area triangles",
            yes_no(q.closed, "closed"),
            yes_no(q.edge_manifold, "edge-manifold"),
            yes_no(q.vertex_manifold, "vertex-manifold"),
            yes_no(q.oriented, "oriented"),
            q.boundary_edges,
            q.zero_area_triangles
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
            None => s.push_str("shape error: unknown (no run summary)\n"),
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
    if d.clipped_samples > 0 {
        let _ = writeln!(
            s,
            "  {} output samples had no full-resolution point within {:.6} and count at it: output -> full is a lower bound",
            d.clipped_samples, d.max_distance
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

    fn report(clipped: u64) -> MeasureReport {
        report_weighted(clipped, 1)
    }

    fn report_weighted(clipped: u64, full_sample_weight: u64) -> MeasureReport {
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
                clipped_samples: clipped,
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
            "1 triangles",
            "NOT closed",
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
        assert!(!text.contains("lower bound") && !text.contains("sparsely"));
        assert!(
            report(3)
                .to_text()
                .contains("3 output samples had no full-resolution point")
        );
        assert!(
            report_weighted(0, 16)
                .to_text()
                .contains("sampled more sparsely, the last samples counting 16 times each")
        );
    }

    #[test]
    fn json_has_the_same_facts() {
        let json = serde_json::to_value(report(0)).unwrap();
        assert_eq!(json["distances"]["output_to_full"]["samples"], 10);
        assert_eq!(json["shape_error"], 0.05);
        assert_eq!(json["quality"]["boundary_edges"], 3);
    }
}
