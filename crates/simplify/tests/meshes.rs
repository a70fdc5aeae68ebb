//! Deterministic scenarios: every policy on closed, open and tiny meshes fed as a sweep.

mod common;

use std::collections::HashMap;

use common::*;
use glam::DVec3;
use isostream_simplify::{Boundary, Cascade, Domain, Policy, SimplifyConfig, SimplifyStats};

/// Output faces within 10% of `rate * input`.
fn assert_rate_met(input: &Mesh, run: &Run, rate: f64) {
    let target = rate * input.tris.len() as f64;
    let got = run.mesh.tris.len() as f64;
    assert!(
        (got - target).abs() <= 0.1 * target,
        "{got} faces for target {target}: {:?}",
        run.stats
    );
}

#[test]
fn none_policy_reproduces_the_input_triangles() {
    let input =
        sphere(3, 5.0, DVec3::ZERO).union(torus(24, 12, 6.0, 2.0).translated(DVec3::X * 20.0));
    let run = run(
        &input,
        config(Policy::None, 1),
        &Sweep {
            batches_per_slab: 3,
            ..Sweep::default()
        },
    );
    assert_eq!(input.oriented_triangles(), run.mesh.oriented_triangles());
    assert_eq!(run.stats.contractions, 0);
    assert_eq!(run.stats.vertices_out as usize, input.pos.len());
}

/// The rate is met once the lag leaves the band room to absorb the decimation: 3 slabs for
/// rates down to 0.1, 5 below (with a lag of 1 or 2 the front region retires before it can be
/// squeezed enough to make up for it).
#[test]
fn rate_on_closed_surfaces_meets_the_target_and_keeps_topology() {
    let cases = [
        (sphere(5, 10.0, DVec3::ZERO), 0.3, 3),
        (sphere(5, 10.0, DVec3::ZERO), 0.1, 3),
        (torus(96, 32, 12.0, 4.0), 0.1, 3),
        (torus(96, 32, 12.0, 4.0), 0.05, 5),
        (sphere(6, 30.0, DVec3::ZERO), 0.02, 8),
    ];
    for (input, r, lag) in &cases {
        let run = run(input, config(rate(*r, 500), *lag), &Sweep::default());
        assert_same_topology(input, &run);
        assert!(run.check().is_closed_manifold());
        assert_rate_met(input, &run, *r);
    }
}

#[test]
fn rate_on_open_surfaces_keeps_the_boundary() {
    let bumpy = height_field(48, 48, 24.0, |u, v| 2.0 * (6.0 * u).sin() * (5.0 * v).cos());
    let flat = height_field(40, 40, 20.0, |_, _| 0.0);
    let tube = tube(32, 40, 5.0, 40.0);
    for input in [&bumpy, &flat, &tube] {
        let run = run(input, config(rate(0.2, 400), 2), &Sweep::default());
        assert_same_topology(input, &run);
        let (a, b) = (boundary(input), boundary(&run.mesh));
        assert!(b.len() <= a.len());
        // Boundary vertices never move; only those on straight pieces may disappear.
        let key = |p: &DVec3| p.to_array().map(f64::to_bits);
        let on_input: std::collections::HashSet<[u64; 3]> = a.iter().map(key).collect();
        assert!(b.iter().all(|p| on_input.contains(&key(p))));
        assert!(
            (boundary_length(input) - boundary_length(&run.mesh)).abs()
                < 1e-9 * boundary_length(input)
        );
    }
    // A flat square loses its interior and the straight sides' inner vertices freely.
    let run = run(&flat, config(rate(0.05, 400), 2), &Sweep::default());
    assert_rate_met(&flat, &run, 0.05);
}

/// With a planar boundary the cut of an open surface (here the sides of a bumpy height field,
/// on the faces x = 0, x = 24, z = 0, z = 24 of its box) is simplified within those faces: a
/// rate whose face count lies below the exact rule's floor (every vertex of the curved sides)
/// is met, every boundary vertex left is an input boundary vertex on a box face, the four
/// corners (where the cut turns between faces) stay, and the topology is unchanged.
#[test]
fn a_planar_boundary_is_simplified_within_the_box_faces() {
    let h = |u: f64, v: f64| 2.0 * (6.0 * u).sin() * (5.0 * v).cos();
    let bumpy = height_field(48, 48, 24.0, h);
    let domain = Some(Domain {
        lo: DVec3::new(0.0, -2.0, 0.0),
        hi: DVec3::new(24.0, 2.0, 24.0),
    });
    let rate_low = 0.02;
    let exact = run(&bumpy, config(rate(rate_low, 400), 2), &Sweep::default());
    assert!(
        exact.mesh.tris.len() as f64 > 1.5 * rate_low * bumpy.tris.len() as f64,
        "the exact rule's floor: {} faces",
        exact.mesh.tris.len()
    );
    let cfg = SimplifyConfig {
        boundary: Boundary::Planar,
        domain,
        ..config(rate(rate_low, 400), 2)
    };
    let got = run(&bumpy, cfg, &Sweep::default());
    assert_same_topology(&bumpy, &got);
    assert_rate_met(&bumpy, &got, rate_low);
    // As written: positions are rounded to `f32`.
    let key = |p: &DVec3| p.as_vec3().to_array().map(f32::to_bits);
    let on_input: std::collections::HashSet<[u32; 3]> = boundary(&bumpy).iter().map(key).collect();
    let out = boundary(&got.mesh);
    assert!(out.len() < boundary(&bumpy).len() / 4, "{} left", out.len());
    for p in &out {
        assert!(
            on_input.contains(&key(p)),
            "{p} is no input boundary vertex"
        );
        assert!(
            [p.x, p.z].iter().any(|&c| c == 0.0 || c == 24.0),
            "{p} is off the box faces"
        );
    }
    for corner in [[0.0, 0.0], [24.0, 0.0], [0.0, 24.0], [24.0, 24.0]] {
        let p = DVec3::new(corner[0], h(corner[0] / 24.0, corner[1] / 24.0), corner[1]);
        assert!(out.iter().any(|q| key(q) == key(&p)), "corner {p} moved");
    }
}

/// Positions of the vertices on boundary edges.
fn boundary(m: &Mesh) -> Vec<DVec3> {
    let mut v: Vec<u32> = boundary_edges(m)
        .into_iter()
        .flat_map(|(a, b)| [a, b])
        .collect();
    v.sort_unstable();
    v.dedup();
    v.into_iter().map(|i| m.pos[i as usize]).collect()
}

fn boundary_length(m: &Mesh) -> f64 {
    boundary_edges(m)
        .into_iter()
        .map(|(a, b)| (m.pos[a as usize] - m.pos[b as usize]).length())
        .sum()
}

fn boundary_edges(m: &Mesh) -> Vec<(u32, u32)> {
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &m.tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    count
        .into_iter()
        .filter(|&(_, n)| n == 1)
        .map(|(e, _)| e)
        .collect()
}

#[test]
fn tiny_components_never_collapse() {
    let input = tetrahedron(DVec3::ZERO, 1.0)
        .union(tetrahedron(DVec3::new(5.0, 0.0, 3.0), 0.5))
        .union(sphere(0, 1.0, DVec3::new(-4.0, 0.0, 2.0))) // octahedron
        .union(sphere(2, 2.0, DVec3::new(0.0, 6.0, 1.0)));
    for policy in [
        rate(0.01, 1),
        Policy::Error {
            e0: 100.0,
            time_lag: false,
            isotropy: 0.0,
        },
    ] {
        let run = run(
            &input,
            config(policy, 1),
            &Sweep {
                slab: 0.5,
                ..Sweep::default()
            },
        );
        assert_same_topology(&input, &run);
        let report = run.check();
        assert_eq!(report.components.len(), 4);
        // Every closed component keeps at least a tetrahedron's 4 triangles; the tetrahedra and
        // the octahedron end as exactly that (the sphere may stop earlier, on the flip check).
        assert!(
            report.components.iter().all(|c| c.triangles >= 4),
            "{report:?}"
        );
        assert_eq!(
            report
                .components
                .iter()
                .filter(|c| c.triangles == 4)
                .count(),
            3 + usize::from(report.triangles == 16),
            "{report:?}"
        );
    }
}

#[test]
fn coincident_vertices_are_contracted_first() {
    // Marching cubes at value == iso puts several vertices on one grid corner: snap some sphere
    // vertices onto a neighbour, making zero-length edges and zero-area triangles.
    let mut input = sphere(4, 10.0, DVec3::ZERO);
    let mut snapped = 0;
    for t in input.tris.clone().iter().step_by(37) {
        input.pos[t[1] as usize] = input.pos[t[0] as usize];
        snapped += 1;
    }
    let before = input.check();
    assert!(before.zero_area_triangles >= snapped, "{before:?}");
    let run = run(&input, config(rate(0.5, 200), 2), &Sweep::default());
    let after = run.check();
    assert!(after.is_closed_manifold());
    assert_eq!(after.euler(), 2);
    assert_eq!(after.zero_area_triangles, 0, "{after:?}");
}

#[test]
fn output_is_deterministic() {
    let input = torus(48, 16, 8.0, 3.0).union(sphere(3, 4.0, DVec3::new(0.0, 0.0, 10.0)));
    let sweep = Sweep {
        batches_per_slab: 2,
        ..Sweep::default()
    };
    for policy in [
        rate(0.2, 300),
        Policy::Error {
            e0: 0.05,
            time_lag: true,
            isotropy: 0.3,
        },
    ] {
        let a = run(&input, config(policy.clone(), 2), &sweep);
        let b = run(&input, config(policy, 2), &sweep);
        assert_eq!(a.out, b.out);
    }
}

#[test]
fn memory_is_bounded_by_the_budget_not_the_length() {
    // Highest faces, vertices and heap entries held after any batch.
    let budget = 400;
    let peaks = |len: u32| {
        let input = tube(24, len, 4.0, f64::from(len));
        let cfg = SimplifyConfig {
            max_resident_faces: budget,
            ..config(rate(0.25, 200), 3)
        };
        let run = run(&input, cfg, &Sweep::default());
        assert_same_topology(&input, &run);
        assert_rate_met(&input, &run, 0.25);
        let max = |f: fn(&SimplifyStats) -> usize| run.trace.iter().map(f).max().unwrap_or(0);
        (
            run.stats.peak_resident_faces,
            max(|s| s.vertices_resident),
            max(|s| s.candidates),
        )
    };
    let (short, long) = (peaks(100), peaks(1600));
    // Rate mode keeps the simplified surface until the budget is reached, then retires the
    // oldest: the peak is the budget plus what one batch and a slab or two add before the next
    // pass, whatever the length.
    assert!(long.0 <= budget + 200 + 96, "faces: {long:?}");
    assert!(
        long.0 <= short.0 + 96,
        "faces: short {short:?}, long {long:?}"
    );
    assert!(
        long.1 <= short.1 + 48,
        "vertices: short {short:?}, long {long:?}"
    );
    // The heap is compacted at 2 entries per resident face plus 1024.
    assert!(long.2 <= 2 * long.0 + 1024, "candidates: {long:?}");
}

/// Where the whole output fits the memory budget, a pass run for the budget (`batch` unset)
/// stops once the band has room again (three quarters of the budget), within a slab too, and
/// nothing is written before the end: the surface is decimated among all of it, as in core.
/// (Passes within a slab used to chase the rate target, whose initial phase halves the
/// modifiable faces at every pass: bonsai upsampled to 511 x 511 x 256 at R = 0.01 came out with
/// 1.3x the in-core RMS distance for it.)
#[test]
fn budget_passes_keep_the_band_where_the_output_fits() {
    let input = tube(24, 400, 4.0, 400.0);
    let budget = 2000;
    let cfg = SimplifyConfig {
        max_resident_faces: budget,
        ..config(rate(0.02, u64::MAX), 3)
    };
    let sweep = Sweep {
        batches_per_slab: 4,
        ..Sweep::default()
    };
    let run = run(&input, cfg, &sweep);
    assert_same_topology(&input, &run);
    assert_rate_met(&input, &run, 0.02);
    assert_eq!(
        run.stats.forced_retirements, 0,
        "the output fits the budget"
    );
    let kept = budget * 3 / 4;
    let resident: Vec<usize> = run.trace.iter().map(|s| s.faces_resident).collect();
    let first_full = resident
        .iter()
        .position(|&f| f >= kept)
        .expect("the band fills up");
    let low = resident[first_full..].iter().min().copied().unwrap_or(0);
    // A contraction removes two faces, so a pass may stop one face below its target.
    assert!(
        low + 2 >= kept,
        "a pass went below the kept share: {low} < {kept}"
    );
    assert!(resident.iter().all(|&f| f <= budget + 48), "{resident:?}");
}

#[test]
fn memory_budget_forces_early_retirement() {
    let input = sphere(5, 10.0, DVec3::ZERO);
    let budget = 600;
    let cfg = SimplifyConfig {
        max_resident_faces: budget,
        ..config(rate(0.2, 100), 50)
    };
    let run = run(
        &input,
        cfg,
        &Sweep {
            batches_per_slab: 4,
            ..Sweep::default()
        },
    );
    assert_same_topology(&input, &run);
    assert!(run.stats.forced_retirements > 0);
    // After each batch the simplifier is back under budget (slabs are small against it, so there
    // are always modifiable vertices to retire).
    assert!(run.trace.iter().all(|s| s.faces_resident <= budget));
}

#[test]
fn attributes_follow_contractions() {
    let input = sphere(4, 10.0, DVec3::ZERO);
    let cfg = SimplifyConfig {
        attributes: 1,
        ..config(rate(0.2, 200), 2)
    };
    let run = run(&input, cfg, &Sweep::default());
    assert_eq!(run.attrs.len(), run.mesh.pos.len());
    // Attribute 0 started as z and is interpolated along contracted edges.
    for (p, a) in run.mesh.pos.iter().zip(&run.attrs) {
        assert!((p.z - f64::from(*a)).abs() < 1.0, "{p} {a}");
    }
}

#[test]
fn error_policy_bounds_the_shape_measure() {
    let input = torus(96, 32, 12.0, 4.0);
    for (e0, time_lag, isotropy) in [
        (0.02, false, 0.0),
        (0.05, true, 0.0),
        (0.05, true, 0.3),
        (0.2, false, 1.0),
    ] {
        let run = run(
            &input,
            config(
                Policy::Error {
                    e0,
                    time_lag,
                    isotropy,
                },
                4,
            ),
            &Sweep::default(),
        );
        assert_same_topology(&input, &run);
        assert!(run.stats.contractions > 1000, "{:?}", run.stats);
        assert!(run.stats.max_shape_error <= e0, "{:?}", run.stats);
        assert_eq!(run.stats.lag_violations, 0);
    }
}

#[test]
fn time_lag_holds_contractions_until_the_front_passes() {
    let input = sphere(5, 10.0, DVec3::ZERO);
    let policy = Policy::Error {
        e0: 0.05,
        time_lag: true,
        isotropy: 0.0,
    };
    let run = run(
        &input,
        config(policy, 3),
        &Sweep {
            batches_per_slab: 2,
            ..Sweep::default()
        },
    );
    assert_same_topology(&input, &run);
    assert!(run.stats.contractions > 1000);
    assert_eq!(run.stats.lag_violations, 0);
}

/// Anisotropy of seed 000 section 4: one minus the mean aspect ratio `sqrt(lambda2 / lambda1)` of
/// `M = (aa^T + bb^T + cc^T) / 3` (vertices relative to the centroid).
fn anisotropy(m: &Mesh) -> f64 {
    let sum: f64 = m
        .tris
        .iter()
        .map(|t| {
            let p = t.map(|v| m.pos[v as usize]);
            let c = (p[0] + p[1] + p[2]) / 3.0;
            let mat = p.iter().fold(glam::DMat3::ZERO, |acc, x| {
                let d = *x - c;
                acc + glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z) / 3.0
            });
            // Rank 2: lambda1 + lambda2 = trace, lambda1 * lambda2 = sum of principal 2x2 minors.
            let (a, b, cc) = (mat.x_axis, mat.y_axis, mat.z_axis);
            let trace = a.x + b.y + cc.z;
            let minors = a.x * b.y - a.y * b.x + a.x * cc.z - a.z * cc.x + b.y * cc.z - b.z * cc.y;
            let disc = (trace * trace - 4.0 * minors).max(0.0).sqrt();
            let (l1, l2) = ((trace + disc) / 2.0, (trace - disc) / 2.0);
            (l2.max(0.0) / l1).sqrt()
        })
        .sum();
    1.0 - sum / m.tris.len() as f64
}

#[test]
fn isotropy_improves_triangle_shape_within_the_error_bound() {
    let input = torus(96, 32, 12.0, 4.0);
    let go = |isotropy| {
        let policy = Policy::Error {
            e0: 0.05,
            time_lag: true,
            isotropy,
        };
        let run = run(&input, config(policy, 4), &Sweep::default());
        assert_same_topology(&input, &run);
        assert!(run.stats.max_shape_error <= 0.05);
        (anisotropy(&run.mesh), run.mesh.tris.len())
    };
    let (plain, iso) = (go(0.0), go(0.5));
    assert!(
        iso.0 < plain.0,
        "anisotropy with alpha 0.5 {iso:?}, alpha 0 {plain:?}"
    );
}

/// Closest to what the extractor sends: grid-edge vertices, z slabs, and many grid values exactly
/// at the iso value (integer fields), which put several vertices on one point.
#[test]
fn marching_tetrahedra_surfaces_with_exact_iso_values() {
    let c = DVec3::new(20.0, 20.0, 20.0);
    let sphere_field = |p: DVec3| (p - c).length_squared();
    let torus_field = |p: DVec3| {
        let d = p - c;
        let ring = (d.x * d.x + d.y * d.y).sqrt() - 12.0;
        (ring * ring + d.z * d.z).round()
    };
    let cases = [
        marching_tetrahedra([40, 40, 40], 225.0, sphere_field),
        marching_tetrahedra([40, 40, 40], 25.0, torus_field),
    ];
    for input in &cases {
        let before = input.check();
        assert!(
            before.is_closed_manifold() && before.zero_area_triangles > 0,
            "{before:?}"
        );
        let policies = [
            rate(0.1, 2000),
            Policy::Error {
                e0: 0.1,
                time_lag: true,
                isotropy: 0.2,
            },
        ];
        for policy in policies {
            let run = run(input, config(policy.clone(), 8), &Sweep::default());
            assert_same_topology(input, &run);
            assert_eq!(run.check().zero_area_triangles, 0, "{:?}", run.stats);
            if let Policy::Rate { rate, .. } = policy {
                assert_rate_met(input, &run, rate);
            }
            assert_eq!(run.stats.lag_violations, 0);
        }
    }
}

/// Two sheets 1.2 voxels apart (a thin spherical shell) simplified hard: without the intersection
/// guard contractions on one sheet push fans through the other (the normal-flip test sees only
/// the fan); with it the output never crosses itself.
#[test]
fn thin_shells_do_not_self_intersect() {
    let c = DVec3::splat(10.0);
    for (rate, lag) in [(0.1, 3), (0.03, 5)] {
        let input = marching_tetrahedra([20, 20, 20], 0.36, |p| ((p - c).length() - 7.3).powi(2));
        let input_pos: Vec<[f64; 3]> = input.pos.iter().map(|p| p.to_array()).collect();
        assert_eq!(
            isostream_meshcheck::self_intersections(&input_pos, &input.tris),
            0
        );
        let run = run(
            &input,
            config(common::rate(rate, 500), lag),
            &Sweep::default(),
        );
        let report = run.check();
        assert!(report.is_closed_manifold(), "{report:?}");
        let pos: Vec<[f64; 3]> = run.mesh.pos.iter().map(|p| p.to_array()).collect();
        let crossing = isostream_meshcheck::self_intersections(&pos, &run.mesh.tris);
        assert_eq!(crossing, 0, "rate {rate}: {:?}", run.stats);
        assert!(run.stats.rejected_intersection > 0, "{:?}", run.stats);
    }
}

/// The two stages of a cascade (first to `(1 + R) / 2`, second to `R`) on the thin shell: each
/// stage edits its side of the first stage's rear, so the pair never crosses itself either, the
/// topology is kept and the rate is met.
#[test]
fn a_cascade_keeps_thin_shells_apart_and_meets_the_rate() {
    let c = DVec3::splat(10.0);
    let input = marching_tetrahedra([20, 20, 20], 0.36, |p| ((p - c).length() - 7.3).powi(2));
    for (rate, lag) in [(0.1, 2), (0.03, 3)] {
        let first = SimplifyConfig {
            cascade: Cascade::First,
            ..config(common::rate((1.0 + rate) / 2.0, 500), lag)
        };
        let second = SimplifyConfig {
            cascade: Cascade::Second,
            ..config(common::rate(rate, 500), lag)
        };
        let run = run_cascade(&input, first, second, &Sweep::default());
        assert_same_topology(&input, &run);
        let pos: Vec<[f64; 3]> = run.mesh.pos.iter().map(|p| p.to_array()).collect();
        let crossing = isostream_meshcheck::self_intersections(&pos, &run.mesh.tris);
        assert_eq!(crossing, 0, "rate {rate}: {:?}", run.stats);
        assert_rate_met(&input, &run, rate);
    }
}

/// A thin flat box across the sweep (two sheets 1.2 apart, both in one slab: a crowded slab, as
/// a flat face of engine is): with fronts within the slab (rows) its sheets are simplified as
/// the rows pass, holding a fraction of the slab unmodifiable, and the guard still keeps the
/// sheets apart.
#[test]
fn a_crowded_slab_is_simplified_row_by_row() {
    let c = DVec3::new(10.0, 10.0, 10.0);
    let input = marching_tetrahedra([20, 20, 20], 0.0, |p| {
        let d = (p - c).abs() - DVec3::new(7.3, 7.3, 0.6);
        d.max_element()
    });
    let input_pos: Vec<[f64; 3]> = input.pos.iter().map(|p| p.to_array()).collect();
    assert_eq!(
        isostream_meshcheck::self_intersections(&input_pos, &input.tris),
        0
    );
    let sweep = |rows| Sweep {
        slab: 4.0,
        batches_per_slab: 8,
        rows,
        ..Sweep::default()
    };
    // One row thicker than the box: fronts between slabs only, computed as exactly as the rows'.
    let by_slabs = run(
        &input,
        config(common::rate(0.05, 200), 2),
        &sweep(Some(1e3)),
    );
    let by_rows = run(
        &input,
        config(common::rate(0.05, 200), 2),
        &sweep(Some(1.0)),
    );
    assert_same_topology(&input, &by_rows);
    let pos: Vec<[f64; 3]> = by_rows.mesh.pos.iter().map(|p| p.to_array()).collect();
    let crossing = isostream_meshcheck::self_intersections(&pos, &by_rows.mesh.tris);
    assert_eq!(crossing, 0, "{:?}", by_rows.stats);
    assert!(
        2 * by_rows.stats.peak_front_faces < by_slabs.stats.peak_front_faces,
        "{} front faces by rows, {} by slabs",
        by_rows.stats.peak_front_faces,
        by_slabs.stats.peak_front_faces
    );
    assert_rate_met(&input, &by_rows, 0.05);
}
