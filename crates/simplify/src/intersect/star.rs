//! A cheap proof that no two triangles of a vertex star cross: the star is embedded in a plane
//! projection.
//!
//! Nearly every pair the guard meets shares a vertex `w` (a fan triangle and a neighbour of the
//! fan, or two fan triangles), and nearly every such pair is far from crossing: the surface is
//! smooth around `w`. The exact test costs hundreds of instructions per pair; this proof costs a
//! few dozen per triangle and covers every pair of the star at once. When it fails (sharp
//! features, open stars on the boundary) the exact test decides, so the guard's answer never
//! depends on the proof, only its cost does.
//!
//! The proof: project the star of `w` along `d`, the sum of its triangle normals. If every
//! triangle projects with positive orientation (its normal within about 87 degrees of `d`, and
//! not a sliver: the projected angle at `w` is at least `1e-6`), and the triangles, chained
//! around `w` edge to edge, turn exactly once around `w`, their projections are disjoint sectors
//! at `w`. Two triangles that share only `w` then meet only at `w` (the projection is injective
//! on each of them), which the referee's predicate counts neither as a crossing nor as a contact
//! (a shared corner is not one); the margins keep its `f64` orientation signs far from rounding.

use glam::DVec3;

/// One triangle of a star seen from its apex: its other two corners in counter-clockwise order.
#[derive(Debug, Clone, Copy)]
pub(super) struct Spoke {
    pub(super) s: u64,
    pub(super) e: u64,
    pub(super) ps: DVec3,
    pub(super) pe: DVec3,
}

/// The normal of a star triangle may lean at most this far from the star's mean normal
/// (cosine; about 87 degrees).
const MIN_COS: f64 = 0.05;
/// The smallest projected angle of a triangle at the apex, and of the gap an open star leaves,
/// in pseudo-angle units (a quarter turn is 1).
const MIN_STEP: f64 = 1e-6;
/// Stars with more triangles are not proven.
const MAX: usize = 24;

/// Whether the star around apex `pw` made of `spokes` is embedded (see the module
/// documentation): closed (every corner starts one triangle and ends one) or open (one path,
/// as on the boundary or where triangles are still to come). `false` means "not proven", not
/// "crossing".
pub(super) fn embedded(pw: DVec3, spokes: &[Spoke]) -> bool {
    let k = spokes.len();
    if !(2..=MAX).contains(&k) {
        return false;
    }
    // `next[i]`: the spoke starting where spoke `i` ends (`NONE` for the end of a path).
    const NONE: u8 = u8::MAX;
    let mut next = [NONE; MAX];
    let mut starts_taken = 0u32; // bit j: spoke j follows some spoke
    for (i, a) in spokes.iter().enumerate() {
        for (j, b) in spokes.iter().enumerate() {
            if b.s == a.e {
                if next[i] != NONE || starts_taken & (1 << j) != 0 {
                    return false; // a corner twice: not one chain
                }
                next[i] = j as u8;
                starts_taken |= 1 << j;
            }
        }
    }
    let path_ends = next[..k].iter().filter(|&&n| n == NONE).count();
    if path_ends > 1 {
        return false;
    }
    let mut normals = [DVec3::ZERO; MAX];
    let mut d = DVec3::ZERO;
    for (n, sp) in normals.iter_mut().zip(spokes) {
        *n = (sp.ps - pw).cross(sp.pe - pw);
        d += *n;
    }
    let dd = d.length_squared();
    // NaN corners fail here and below: not proven.
    if dd.is_nan() || dd <= 0.0 {
        return false;
    }
    for n in &normals[..k] {
        let nd = n.dot(d);
        if !(nd > 0.0 && nd * nd >= MIN_COS * MIN_COS * n.length_squared() * dd) {
            return false;
        }
    }
    // Walk the corners by angle: every step turns forward (the orientations are positive) by at
    // least MIN_STEP, and all of them together make one turn (closed) or less than one, with a
    // gap of at least MIN_STEP (open). Each corner's angle is computed once.
    let axis = d / dd.sqrt();
    let e1 = axis.any_orthonormal_vector();
    let e2 = axis.cross(e1);
    let angle = |p: DVec3| {
        let r = p - pw;
        pseudo_angle(r.dot(e1), r.dot(e2))
    };
    let mut start = [0.0; MAX];
    for (a, sp) in start.iter_mut().zip(spokes) {
        *a = angle(sp.ps);
    }
    let mut total = 0.0;
    for i in 0..k {
        let end = match next[i] {
            NONE => angle(spokes[i].pe),
            j => start[usize::from(j)],
        };
        let mut step = end - start[i];
        if step < 0.0 {
            step += 4.0;
        }
        if step.is_nan() || step < MIN_STEP {
            return false;
        }
        total += step;
    }
    if path_ends == 0 {
        (total - 4.0).abs() < 1.0
    } else {
        total <= 4.0 - MIN_STEP
    }
}

/// A monotone stand-in for the angle of `(x, y)` in `[0, 4)`, without trigonometry.
fn pseudo_angle(x: f64, y: f64) -> f64 {
    if y >= 0.0 {
        if x >= 0.0 {
            y / (x + y)
        } else {
            1.0 + -x / (-x + y)
        }
    } else if x < 0.0 {
        2.0 + -y / (-x - y)
    } else {
        3.0 + x / (x - y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regular star of `k` spokes around the origin in the plane z = 0, lifted by `lift(i)`.
    fn star(k: usize, turns: usize, lift: impl Fn(usize) -> f64) -> Vec<Spoke> {
        let at = |i: usize| {
            let t = std::f64::consts::TAU * (turns * i) as f64 / k as f64;
            DVec3::new(t.cos(), t.sin(), lift(i % k))
        };
        (0..k)
            .map(|i| Spoke {
                s: i as u64,
                e: ((i + 1) % k) as u64,
                ps: at(i),
                pe: at(i + 1),
            })
            .collect()
    }

    #[test]
    fn a_smooth_star_is_embedded() {
        assert!(embedded(DVec3::ZERO, &star(6, 1, |i| 0.1 * i as f64)));
        assert!(embedded(DVec3::Z * 0.3, &star(9, 1, |_| 0.0)));
    }

    #[test]
    fn a_star_winding_twice_is_not() {
        // Seven spokes, each stepping 2/7 of a turn: positive triangles that overlap.
        let s = star(7, 2, |_| 0.0);
        assert!(!embedded(DVec3::ZERO, &s));
    }

    #[test]
    fn a_folded_star_is_not_proven() {
        let mut s = star(6, 1, |_| 0.0);
        // Fold one corner back over the first triangle: its two triangles turn backwards.
        let folded = DVec3::new(0.5, 0.1, 0.0);
        s[2].pe = folded;
        s[3].ps = folded;
        assert!(!embedded(DVec3::ZERO, &s));
    }

    #[test]
    fn open_stars_need_a_gap() {
        let open = star(6, 1, |_| 0.0)[..5].to_vec();
        assert!(embedded(DVec3::ZERO, &open));
        // Seven spokes of 1/6 turn each: the path overlaps itself.
        let mut over = star(6, 1, |_| 0.0);
        let mut extra = over[0];
        extra.s = 100;
        extra.e = 101;
        over[5].e = 100;
        extra.pe = DVec3::new(0.9, 0.5, 0.0);
        over.push(extra);
        assert!(!embedded(DVec3::ZERO, &over));
        // Two separate paths are no star.
        let mut two = star(6, 1, |_| 0.0)[..2].to_vec();
        two.extend_from_slice(&star(6, 1, |_| 0.0)[3..5]);
        assert!(!embedded(DVec3::ZERO, &two));
    }

    #[test]
    fn pseudo_angles_follow_the_angle() {
        let mut last = -1.0;
        for i in 0..64 {
            let t = std::f64::consts::TAU * f64::from(i) / 64.0;
            let a = pseudo_angle(t.cos(), t.sin());
            assert!(a > last, "{i}: {a} after {last}");
            last = a;
        }
    }
}
