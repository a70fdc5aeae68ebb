//! Vertex attributes through contractions and the data-aware priorities (issue 5): every mode,
//! every priority, topology kept, linear attributes reproduced exactly.

mod common;

use common::*;
use glam::DVec3;
use isostream_simplify::{Policy, Priority, SimplifyConfig};

/// Feeds `mesh` as a sweep along z (rank = floor(z)) with `m` attributes `attr(pos)`, returns
/// the output mesh and its attributes.
fn run_with(
    mesh: &Mesh,
    policy: Policy,
    priority: Priority,
    m: usize,
    attr: impl Fn(DVec3) -> Vec<f32>,
) -> (Mesh, Vec<f32>) {
    let config = SimplifyConfig {
        attributes: m,
        priority,
        ..config(policy, 3)
    };
    let run = feed(mesh, config, &Sweep::default(), attr);
    (run.mesh, run.attrs)
}

fn modes() -> Vec<(&'static str, Policy)> {
    vec![
        ("rate", rate(0.1, 200)),
        (
            "error",
            Policy::Error {
                e0: 0.05,
                time_lag: false,
                isotropy: 0.0,
            },
        ),
        (
            "tandem",
            Policy::Error {
                e0: 0.05,
                time_lag: true,
                isotropy: 0.3,
            },
        ),
    ]
}

fn priorities(m: usize) -> Vec<Priority> {
    vec![
        Priority::Geometric,
        Priority::DataDependent { lambda: 0.0 },
        Priority::DataDependent { lambda: 0.5 },
        Priority::DataDependent { lambda: 1.0 },
        Priority::AttributeQuadric {
            weights: vec![1.0; m],
        },
    ]
}

fn linear(p: DVec3) -> Vec<f32> {
    vec![
        (0.7 * p.x - 0.2 * p.y + 0.4 * p.z + 1.0) as f32,
        (p.x - p.z) as f32,
    ]
}

fn max_linear_error(out: &Mesh, attrs: &[f32]) -> f64 {
    out.pos
        .iter()
        .zip(attrs.chunks(2))
        .map(|(p, a)| {
            let f = linear(*p);
            (0..2)
                .map(|j| (f64::from(a[j]) - f64::from(f[j])).abs())
                .fold(0.0, f64::max)
        })
        .fold(0.0, f64::max)
}

/// On a flat surface every merge (interpolated or solved) reproduces a linear attribute, in
/// every mode and with every priority, and the topology guarantees hold.
#[test]
fn a_linear_attribute_is_reproduced_exactly_on_a_plane() {
    let plane = height_field(24, 24, 12.0, |_, _| 0.0);
    for (name, policy) in modes() {
        for priority in priorities(2) {
            let (out, attrs) = run_with(&plane, policy.clone(), priority.clone(), 2, linear);
            assert!(
                out.tris.len() < plane.tris.len() / 2,
                "{name} {priority:?}: {}",
                out.tris.len()
            );
            assert_eq!(attrs.len(), 2 * out.pos.len());
            let report = out.check();
            assert!(
                report.is_valid_manifold(),
                "{name} {priority:?}: {report:?}"
            );
            assert_eq!(report.sorted_eulers(), plane.check().sorted_eulers());
            let err = max_linear_error(&out, &attrs);
            assert!(err < 1e-5, "{name} {priority:?}: {err}");
        }
    }
}

/// On a curved closed surface the attribute quadric's joint solve still reproduces a linear
/// attribute (its minimum lies on the graph of the linear function), up to the clamp to the
/// replaced patch's values: a placement bulging out past the patch's corners (a sphere's) has
/// a linear value past theirs. That costs 0.019 here on values spanning about 10 (the solve
/// alone was within 1e-3; clamping to the two ends' values instead cost 0.092).
#[test]
fn attribute_quadric_reproduces_a_linear_attribute_on_a_sphere() {
    let ball = sphere(4, 6.0, DVec3::new(0.0, 0.0, 8.0));
    let (out, attrs) = run_with(
        &ball,
        rate(0.2, 200),
        Priority::AttributeQuadric {
            weights: vec![1.0, 1.0],
        },
        2,
        linear,
    );
    assert!(out.tris.len() <= ball.tris.len() / 3);
    let report = out.check();
    assert!(report.is_valid_manifold(), "{report:?}");
    assert_eq!(report.sorted_eulers(), ball.check().sorted_eulers());
    let err = max_linear_error(&out, &attrs);
    assert!(err < 0.025, "{err}");
}

/// With lambda = 1 the attributes play no part: the same surface as without attributes.
#[test]
fn lambda_one_without_attributes_is_purely_curvature_driven() {
    let ball = sphere(4, 6.0, DVec3::new(0.0, 0.0, 8.0));
    let curvature = Priority::DataDependent { lambda: 1.0 };
    for (name, policy) in modes() {
        let (plain, _) = run_with(&ball, policy.clone(), curvature.clone(), 0, |_| Vec::new());
        let (with, _) = run_with(&ball, policy.clone(), curvature.clone(), 2, linear);
        assert_eq!(
            plain.oriented_triangles(),
            with.oriented_triangles(),
            "{name}"
        );
        let report = plain.check();
        assert!(report.is_valid_manifold(), "{name} {report:?}");
        assert_eq!(
            report.sorted_eulers(),
            ball.check().sorted_eulers(),
            "{name}"
        );
    }
}

/// A step in the attribute across a flat plane: the data-dependent priority keeps vertices near
/// the step, the geometric one does not care; the attribute quadric keeps the step sharp: the
/// area of triangles whose corners straddle it (where interpolation smears it) is far smaller.
/// (It used to count the attribute quadric's vertices near the step too, but a straight step is
/// kept with few: moving along it costs nothing, and with the cost's tie-break by edge length
/// it keeps 0.13 of its vertices there, against 0.10 for the uniform geometric result; the
/// smeared area is 10 against 42.5.)
#[test]
fn data_dependent_priority_keeps_detail_at_an_attribute_step() {
    let plane = height_field(40, 40, 20.0, |_, _| 0.0);
    let step = |p: DVec3| vec![if p.x > 10.3 { 1.0 } else { 0.0 }];
    let near = |out: &Mesh| {
        out.pos.iter().filter(|p| (p.x - 10.3).abs() < 1.0).count() as f64 / out.pos.len() as f64
    };
    let smeared = |out: &Mesh, attrs: &[f32]| -> f64 {
        out.tris
            .iter()
            .filter(|t| {
                let a = t.map(|i| attrs[i as usize]);
                a.iter().any(|&x| x < 0.5) && a.iter().any(|&x| x > 0.5)
            })
            .map(|t| {
                let [p, q, r] = t.map(|i| out.pos[i as usize]);
                0.5 * (q - p).cross(r - p).length()
            })
            .sum()
    };
    let policy = rate(0.1, 400);
    let (geo, geo_attrs) = run_with(&plane, policy.clone(), Priority::Geometric, 1, step);
    let (dd, _) = run_with(
        &plane,
        policy.clone(),
        Priority::DataDependent { lambda: 0.2 },
        1,
        step,
    );
    let (aq, aq_attrs) = run_with(
        &plane,
        policy,
        Priority::AttributeQuadric { weights: vec![1.0] },
        1,
        step,
    );
    let (g, d) = (near(&geo), near(&dd));
    assert!(d > 1.5 * g, "data-dependent {d} vs geometric {g}");
    let (sg, sa) = (smeared(&geo, &geo_attrs), smeared(&aq, &aq_attrs));
    assert!(
        sa < sg / 1.5,
        "smeared area: attribute quadric {sa} vs geometric {sg}"
    );
}

/// The attribute quadric's solve extrapolates: on a bumpy surface with a bounded, non-linear
/// attribute its values went past the input's range (a trial's 0..5 came out -0.90..6.71, a
/// label 0..3 came out -0.011..3.0099). Each placed value is clamped to the values of the
/// replaced patch, so every output value lies within the input's range, in every mode.
#[test]
fn attribute_quadric_keeps_values_within_the_input_range() {
    let bumps = random_heights(30, 30, 15.0, 2.0, 7);
    // 0..5 with sharp steps: a label-like field the quadric cannot fit linearly.
    let label = |p: DVec3| vec![((p.x * 0.9).floor() + (p.z * 0.7).floor()).rem_euclid(6.0) as f32];
    let input: Vec<f32> = bumps.pos.iter().flat_map(|p| label(*p)).collect();
    let (lo, hi) = input
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, h), &a| (l.min(a), h.max(a)));
    for (name, policy) in modes() {
        let (out, attrs) = run_with(
            &bumps,
            policy,
            Priority::AttributeQuadric { weights: vec![1.0] },
            1,
            label,
        );
        assert!(out.tris.len() < bumps.tris.len(), "{name}");
        let outside = attrs.iter().filter(|a| !(lo..=hi).contains(*a)).count();
        let (min, max) = attrs
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &a| (l.min(a), h.max(a)));
        assert_eq!(outside, 0, "{name}: {min}..{max} from {lo}..{hi}");
    }
}
