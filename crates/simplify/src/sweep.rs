//! Where the extraction stands: the sweep's rank planes, and a front that may also move row by
//! row within a slab.
//!
//! Every contraction must keep its new fan where the extraction is complete, since the triangles
//! still to come are checked by no one (a marching-cubes triangle stays in its cube, so what is
//! still to come lies in cubes not yet extracted). With slabs alone the complete region is the
//! half-space below the front's plane, and a slab's surface waits, unmodifiable, until the whole
//! slab is extracted: a slab crowded by a flat face across the sweep (engine's, 128 k faces
//! upsampled to 511^2 slices) was held whole at full resolution, past the memory budget.
//!
//! With rows ([`Rows`]), a front `(slabs, rows)` also has the first `rows` rows of cubes of the
//! next slab: the complete region is the union of two boxes, `B1 = {rank <= slabs}` and
//! `B2 = {rank <= slabs + 1, row <= rows}`. A union of boxes is not convex, and a triangle with
//! its corners in both could leave it, so a point set is taken as behind the front only when it
//! lies in one of the two: then so does its convex hull, which holds every fan over those
//! points. For a set whose highest rank is `z` and farthest row `y`, with `k = ceil(z)`: it lies
//! in `B1` once `slabs >= k`, and in `B2` once `slabs = k - 1` and `rows >= ceil(y)`. Ordered as
//! the front moves, those are one number: the front's key is `slabs + rows / count`, the set's
//! `k - 1 + ceil(y) / count` (at most `k`), and the set is behind the front exactly when its key
//! is at most the front's ([`Sweep::key_of`]). Without rows both are plain ranks, as before.

use glam::DVec3;

/// The sweep's rank planes: rank `r` is the plane `p . direction = origin + r * spacing` (for
/// marching cubes along z: `direction = Z`, the grid's z origin and spacing).
///
/// `spacing` converts lengths into ranks for the time-lag radius (which adds edge lengths to
/// heights). The planes also keep contractions behind the front: triangles still to come lie
/// beyond it (a marching-cubes triangle stays in its cube), so a contraction whose new fan
/// reaches past the front waits (like a time-lag DELAY) until the front has passed the fan;
/// otherwise a later triangle could cross it, and no check would see that.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sweep {
    pub direction: DVec3,
    pub origin: f64,
    pub spacing: f64,
    /// The rows of cubes within a slab, when the extraction reports fronts within slabs
    /// ([`Front::rows`]); `None`: the front moves slab by slab.
    pub rows: Option<Rows>,
}

/// Rows of cubes across the sweep: row `j` lies between the planes
/// `p . direction = origin + j * spacing` and `origin + (j + 1) * spacing`, `count` of them in
/// a slab (marching cubes along z: `direction = Y`, the grid's y origin and spacing, `dims[1] -
/// 1` rows).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rows {
    pub direction: DVec3,
    pub origin: f64,
    pub spacing: f64,
    pub count: u32,
}

/// How far the extraction has come: `slabs` whole slabs, and the first `rows` rows of cubes of
/// the next one (0 between slabs). Without [`Sweep::rows`] only `slabs` counts. Fronts order as
/// the extraction moves (slabs first), which is also the order of their keys
/// (`Sweep::front_key`) while `rows` stays below the slab's row count.
///
/// A cascade's first stage announces its rear as a front too ([`crate::Handoff::rear`]): the
/// region the second stage may edit, which the first stage's triangles stay clear of
/// (`Sweep::clear_of`).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Default,
    serde::Serialize,
    serde::Deserialize,
)]
pub struct Front {
    pub slabs: u32,
    pub rows: u32,
}

impl From<u32> for Front {
    /// A front between slabs.
    fn from(slabs: u32) -> Self {
        Front { slabs, rows: 0 }
    }
}

impl Sweep {
    /// The (fractional) rank of the plane through `p`.
    pub(crate) fn rank_of(&self, p: DVec3) -> f64 {
        self.rank_at(self.height(p))
    }

    /// How far along the sweep `p` lies (the rank is monotonic in it).
    pub(crate) fn height(&self, p: DVec3) -> f64 {
        p.dot(self.direction)
    }

    /// The rank at height `h`.
    pub(crate) fn rank_at(&self, h: f64) -> f64 {
        (h - self.origin) / self.spacing
    }

    /// Whether the configuration is usable: finite, with positive spacings and rows.
    pub(crate) fn is_valid(&self) -> bool {
        let plane =
            |d: DVec3, o: f64, s: f64| s > 0.0 && s.is_finite() && o.is_finite() && d.is_finite();
        plane(self.direction, self.origin, self.spacing)
            && self
                .rows
                .is_none_or(|r| r.count > 0 && plane(r.direction, r.origin, r.spacing))
    }

    /// The front as one number ordered as the extraction moves (see the module documentation):
    /// `slabs + rows / count`, or `slabs` without rows. Its floor is always `slabs`.
    pub(crate) fn front_key(&self, front: Front) -> f64 {
        let slabs = f64::from(front.slabs);
        match self.rows {
            Some(r) if front.rows > 0 => {
                slabs + f64::from(front.rows.min(r.count - 1)) / f64::from(r.count)
            }
            _ => slabs,
        }
    }

    /// The (fractional) row of `p` across the sweep, `None` without rows.
    pub(crate) fn row_of(&self, p: DVec3) -> Option<f64> {
        self.rows
            .map(|r| (p.dot(r.direction) - r.origin) / r.spacing)
    }

    /// Whether the convex hull of `points` stays clear of the complete region of `front` (see
    /// the module documentation): all of them at rank `slabs` or beyond, and, with rows, all at
    /// rank `slabs + 1` or beyond or all at row `rows` or beyond. The hull then meets the
    /// region's two boxes at most on their walls, and a triangle there cannot cross a triangle
    /// inside them: this is what keeps a cascade's stages apart ([`crate::Handoff::rear`]), the
    /// second keeping its new fans off the walls ([`Sweep::key_inside`]).
    ///
    /// The lowest rank is that of the lowest point (`rank_at` is monotonic, in floating point
    /// too), so one division serves all points, and the same for rows.
    pub(crate) fn clear_of(&self, front: Front, points: &[DVec3]) -> bool {
        let low = self.rank_at(self.lowest(points, self.direction));
        if low < f64::from(front.slabs) {
            return false;
        }
        match self.rows {
            None => true,
            Some(r) => {
                low >= f64::from(front.slabs) + 1.0
                    || (self.lowest(points, r.direction) - r.origin) / r.spacing
                        >= f64::from(front.rows)
            }
        }
    }

    /// The least `p . direction` over `points` (`+inf` for none).
    fn lowest(&self, points: &[DVec3], direction: DVec3) -> f64 {
        points
            .iter()
            .map(|p| p.dot(direction))
            .fold(f64::INFINITY, f64::min)
    }

    /// The front whose key is `key` (at least 0; rows rounded to the nearest): the inverse of
    /// [`Sweep::front_key`].
    pub(crate) fn front_at(&self, key: f64) -> Front {
        let slabs = key.max(0.0).floor();
        let rows = self.rows.map_or(0, |r| {
            let rows = ((key - slabs) * f64::from(r.count)).round();
            rows.min(f64::from(r.count - 1)) as u32
        });
        Front {
            slabs: slabs.min(f64::from(u32::MAX)) as u32,
            rows,
        }
    }

    /// The front key at which the front's plane reaches rank `rank`: the rank itself without
    /// rows (fronts are whole then), its ceiling with them (the Tandem time-lag's reach is a
    /// rank, and no row of a slab brings its plane nearer).
    pub(crate) fn key_of_rank(&self, rank: f64) -> f64 {
        match self.rows {
            Some(_) => rank.ceil(),
            None => rank,
        }
    }

    /// The least front key at which every point of `points` lies where the extraction is
    /// complete (so that any fan over them does too): without rows, the highest rank, as a
    /// fraction (a front is a whole number of slabs then, so that is the same test as its
    /// ceiling); with rows, `k - 1 + ceil(y) / count` for the highest rank `z`, `k = ceil(z)`,
    /// and the farthest row coordinate `y`, at least 0. `None` for no points.
    pub(crate) fn key_of(&self, points: impl IntoIterator<Item = DVec3>) -> Option<f64> {
        self.key_with(points, false)
    }

    /// [`Sweep::key_of`] for the open region: the least front key at which every point lies
    /// strictly inside the complete region, off its walls (`k = floor(z) + 1`, `floor(y) + 1`
    /// rows). A cascade's second stage keys its fans so (`decimate::beyond_front`): the first
    /// stage's triangles lie on or beyond the rear's walls (`Sweep::clear_of`), so the two
    /// stages' new geometry never shares a point, a contact included.
    pub(crate) fn key_inside(&self, points: impl IntoIterator<Item = DVec3>) -> Option<f64> {
        self.key_with(points, true)
    }

    /// The keys of [`Sweep::key_of`] and of [`Sweep::key_inside`] (`inside`).
    fn key_with(&self, points: impl IntoIterator<Item = DVec3>, inside: bool) -> Option<f64> {
        // A rank or a row rounded up to the whole slab or row that holds it (off its far wall
        // for `inside`).
        let up = |x: f64| if inside { x.floor() + 1.0 } else { x.ceil() };
        let mut points = points.into_iter();
        let first = points.next()?;
        match self.rows {
            None => {
                let top = points.fold(self.height(first), |top, p| top.max(self.height(p)));
                // A fraction compares with whole fronts as its ceiling does.
                let rank = self.rank_at(top);
                Some(if inside { up(rank) } else { rank })
            }
            Some(r) => {
                let across = |p: DVec3| p.dot(r.direction);
                let (top, far) = points.fold((self.height(first), across(first)), |(t, f), p| {
                    (t.max(self.height(p)), f.max(across(p)))
                });
                let k = up(self.rank_at(top));
                let row = up((far - r.origin) / r.spacing);
                let count = f64::from(r.count);
                let key = if row >= count {
                    k
                } else {
                    k - 1.0 + row.max(0.0) / count
                };
                Some(key.max(0.0))
            }
        }
    }
}

/// A key (front or star) in a heap: non-negative, and ordered as its value (the bits of a
/// non-negative `f64` are).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub(crate) struct Key(u64);

impl Key {
    pub(crate) fn of(value: f64) -> Self {
        Key(value.max(0.0).to_bits())
    }

    pub(crate) fn value(self) -> f64 {
        f64::from_bits(self.0)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A sweep along z with rank planes `origin + r * spacing`, and `count` rows of unit
    /// thickness along y from 0 when given (for the tests of this crate).
    pub(crate) fn along_z(origin: f64, spacing: f64, count: Option<u32>) -> Sweep {
        Sweep {
            direction: DVec3::Z,
            origin,
            spacing,
            rows: count.map(|count| Rows {
                direction: DVec3::Y,
                origin: 0.0,
                spacing: 1.0,
                count,
            }),
        }
    }

    fn swept(count: Option<u32>) -> Sweep {
        along_z(0.0, 1.0, count)
    }

    /// Inside the complete region means off its walls: a point on the front's plane, on its
    /// row wall or on the top of its next slab is not inside until the front has passed it,
    /// with rows and without; points off the walls are inside exactly when they are behind.
    #[test]
    fn inside_the_front_is_off_its_walls() {
        for rows in [Some(10), None] {
            let s = swept(rows);
            let inside = |p: [f64; 3], f: Front| {
                s.key_inside([DVec3::from_array(p)]).expect("a point") <= s.front_key(f)
            };
            let behind = |p: [f64; 3], f: Front| {
                s.key_of([DVec3::from_array(p)]).expect("a point") <= s.front_key(f)
            };
            let whole = Front::from(3);
            assert!(behind([0.0, 9.5, 3.0], whole) && !inside([0.0, 9.5, 3.0], whole));
            assert!(inside([0.0, 9.5, 2.999], whole) && inside([0.0, 9.5, 3.0], Front::from(4)));
            if rows.is_some() {
                let part = Front { slabs: 3, rows: 5 };
                assert!(behind([0.0, 5.0, 3.5], part) && !inside([0.0, 5.0, 3.5], part));
                assert!(behind([0.0, 4.5, 4.0], part) && !inside([0.0, 4.5, 4.0], part));
                assert!(inside([0.0, 4.5, 3.5], part));
            }
            for p in [[0.0, 1.3, 2.2], [0.0, 7.7, 1.1], [0.0, 4.4, 3.6]] {
                for f in [Front::from(3), Front { slabs: 3, rows: 5 }] {
                    assert_eq!(inside(p, f), behind(p, f), "{p:?} {f:?}");
                }
            }
        }
    }

    /// A set is behind the front exactly when it lies in one of the front's two boxes.
    #[test]
    fn a_set_is_behind_the_front_when_one_box_holds_it() {
        let s = swept(Some(10));
        let key = |pts: &[[f64; 3]]| {
            s.key_of(pts.iter().map(|&p| DVec3::from_array(p)))
                .expect("points")
        };
        let front = |slabs, rows| s.front_key(Front { slabs, rows });
        let behind = |pts: &[[f64; 3]], f: Front| key(pts) <= s.front_key(f);
        // Within slab 3 (ranks 3..4), rows up to 4.5: in B2 of (3, 5), not of (3, 4).
        let set = [[0.0, 1.0, 3.2], [5.0, 4.5, 3.9]];
        assert!(behind(&set, Front { slabs: 3, rows: 5 }));
        assert!(!behind(&set, Front { slabs: 3, rows: 4 }));
        assert!(behind(&set, Front { slabs: 4, rows: 0 }));
        assert!(!behind(&set, Front { slabs: 2, rows: 9 }));
        // Reaching below the front's plane far across and into its slab near: in neither box
        // until the slab is done, whatever rows of it are.
        let both = [[0.0, 9.5, 2.5], [0.0, 0.5, 3.5]];
        assert!(!behind(&both, Front { slabs: 3, rows: 9 }));
        assert!(behind(&both, Front { slabs: 4, rows: 0 }));
        // At or below the plane of a whole slab: behind it at any row.
        assert!(behind(&[[0.0, 9.5, 3.0]], Front { slabs: 3, rows: 0 }));
        // Keys order as fronts do.
        assert!(front(3, 9) < front(4, 0));
        assert!(front(3, 0) < front(3, 1));
        assert_eq!(front(3, 0), 3.0);
        assert!(Key::of(front(3, 9)) < Key::of(front(4, 0)));
        assert_eq!(Key::of(2.5).value(), 2.5);
    }

    /// Without rows, keys are the highest rank, as they always were.
    #[test]
    fn without_rows_the_key_is_the_highest_rank() {
        let s = swept(None);
        let k = s
            .key_of([DVec3::new(0.0, 7.0, 2.25), DVec3::new(0.0, 0.0, 1.0)])
            .expect("points");
        assert_eq!(k, 2.25);
        assert_eq!(s.front_key(Front { slabs: 2, rows: 5 }), 2.0);
        assert!(s.key_of(std::iter::empty()).is_none());
    }
}
