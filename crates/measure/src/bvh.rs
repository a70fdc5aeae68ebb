//! Bounding volume hierarchy over triangles for exact nearest-point queries.
//!
//! Metro-style distances need, for each sample point, the distance to the closest point of a whole
//! surface. A BVH answers that with exact point-triangle distances while visiting O(log n) nodes:
//! children are visited nearest box first and pruned once their box is farther than the best
//! distance found so far. The same structure serves the in-memory output mesh and each slab of the
//! full-resolution stream, so there is one spatial index to trust.

use glam::DVec3;

use crate::triangle::{Triangle, closest_point};

/// Triangles per leaf: small enough that leaves cost little, large enough to keep the tree shallow.
const LEAF_SIZE: usize = 4;

/// An axis-aligned box: the hierarchy's nodes, and the second pass's batches and blocks of far
/// samples (`far`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Aabb {
    min: DVec3,
    max: DVec3,
}

impl Aabb {
    pub(crate) const EMPTY: Aabb = Aabb {
        min: DVec3::INFINITY,
        max: DVec3::NEG_INFINITY,
    };

    pub(crate) fn grow(self, p: DVec3) -> Aabb {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    pub(crate) fn distance_squared(&self, p: DVec3) -> f64 {
        let d = (self.min - p).max(p - self.max).max(DVec3::ZERO);
        d.length_squared()
    }

    /// Squared distance between the two boxes: no point of one is nearer a point of the other.
    pub(crate) fn gap_squared(&self, o: &Aabb) -> f64 {
        let d = (self.min - o.max).max(o.min - self.max).max(DVec3::ZERO);
        d.length_squared()
    }
}

/// A node spans `count` triangles from `first` when it is a leaf (`count > 0`); an inner node's
/// left child follows it directly and its right child is at `first`.
#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    first: u32,
    count: u32,
}

#[derive(Debug, Clone)]
pub(crate) struct Bvh {
    nodes: Vec<Node>,
    triangles: Vec<Triangle>,
}

impl Bvh {
    /// Builds by median split of triangle centroids along the longest axis of their bounds:
    /// O(n log n), balanced whatever the triangle sizes.
    pub(crate) fn new(mut triangles: Vec<Triangle>) -> Bvh {
        let mut nodes = Vec::with_capacity(2 * triangles.len() / LEAF_SIZE + 1);
        if !triangles.is_empty() {
            build(&mut nodes, &mut triangles, 0);
        }
        Bvh { nodes, triangles }
    }

    /// Triangle `i` (indices as returned by the queries; the build reorders the input).
    pub(crate) fn triangle(&self, i: usize) -> Option<&Triangle> {
        self.triangles.get(i)
    }

    /// Distance from `p` to the closest triangle and that triangle's index, if one is strictly
    /// closer than `limit`.
    pub(crate) fn nearest_within(&self, p: DVec3, limit: f64) -> Option<(f64, usize)> {
        let mut best = limit * limit;
        let mut found = None;
        let mut stack = Vec::with_capacity(64);
        if let Some(root) = self.nodes.first() {
            stack.push((0usize, root.bounds.distance_squared(p)));
        }
        while let Some((index, lower_bound)) = stack.pop() {
            if lower_bound >= best {
                continue;
            }
            let node = self.nodes[index];
            if node.count > 0 {
                let first = node.first as usize;
                for (i, t) in self.triangles[first..first + node.count as usize]
                    .iter()
                    .enumerate()
                {
                    let d = closest_point(p, t).distance_squared(p);
                    if d < best {
                        best = d;
                        found = Some(first + i);
                    }
                }
                continue;
            }
            let (left, right) = (index + 1, node.first as usize);
            let dl = self.nodes[left].bounds.distance_squared(p);
            let dr = self.nodes[right].bounds.distance_squared(p);
            // Pushed last, popped first: the nearer child tightens `best` before the other is seen.
            if dl < dr {
                stack.push((right, dr));
                stack.push((left, dl));
            } else {
                stack.push((left, dl));
                stack.push((right, dr));
            }
        }
        found.map(|i| (best.sqrt(), i))
    }

    /// Distance from `p` to the closest triangle (infinite for an empty hierarchy). `hint` is the
    /// index of a triangle likely to be near, and is updated to the closest one: consecutive
    /// queries of nearby points then start from a tight bound and visit few nodes.
    pub(crate) fn nearest(&self, p: DVec3, hint: &mut usize) -> f64 {
        let Some(t) = self.triangles.get(*hint) else {
            return self
                .nearest_within(p, f64::INFINITY)
                .map_or(f64::INFINITY, |(d, i)| {
                    *hint = i;
                    d
                });
        };
        let bound = closest_point(p, t).distance(p);
        match self.nearest_within(p, bound) {
            Some((d, i)) => {
                *hint = i;
                d
            }
            None => bound,
        }
    }
}

/// Appends the subtree over `tris` (which it reorders) to `nodes`; `offset` is the index of
/// `tris[0]` in the whole triangle array.
fn build(nodes: &mut Vec<Node>, tris: &mut [Triangle], offset: usize) {
    let bounds = tris.iter().flatten().fold(Aabb::EMPTY, |b, &p| b.grow(p));
    let index = nodes.len();
    nodes.push(Node {
        bounds,
        first: offset as u32,
        count: tris.len() as u32,
    });
    if tris.len() <= LEAF_SIZE {
        return;
    }
    let centroid = |t: &Triangle| (t[0] + t[1] + t[2]) / 3.0;
    let spread = tris
        .iter()
        .map(|t| {
            let c = centroid(t);
            Aabb { min: c, max: c }
        })
        .fold(Aabb::EMPTY, Aabb::union);
    let extent = spread.max - spread.min;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = tris.len() / 2;
    tris.select_nth_unstable_by(mid, |a, b| centroid(a)[axis].total_cmp(&centroid(b)[axis]));
    let (left, right) = tris.split_at_mut(mid);
    build(nodes, left, offset);
    let right_index = nodes.len() as u32;
    build(nodes, right, offset + mid);
    nodes[index].first = right_index;
    nodes[index].count = 0;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::SplitMix64;

    fn random_triangles(rng: &mut SplitMix64, n: usize) -> Vec<Triangle> {
        (0..n)
            .map(|_| {
                let base = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 10.0;
                [0, 1, 2].map(|_| {
                    base + DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) - 0.5
                })
            })
            .collect()
    }

    #[test]
    fn nearest_matches_brute_force() {
        let mut rng = SplitMix64::new(7);
        let tris = random_triangles(&mut rng, 500);
        let bvh = Bvh::new(tris.clone());
        let mut hint = 0;
        for _ in 0..300 {
            let p = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 14.0 - 2.0;
            let brute = tris
                .iter()
                .map(|t| closest_point(p, t).distance(p))
                .fold(f64::INFINITY, f64::min);
            assert!((bvh.nearest(p, &mut hint) - brute).abs() < 1e-12, "{p}");
            let mut no_hint = usize::MAX;
            assert!((bvh.nearest(p, &mut no_hint) - brute).abs() < 1e-12);
            assert_eq!(bvh.nearest_within(p, brute * 0.999), None);
        }
    }

    #[test]
    fn empty_hierarchy_finds_nothing() {
        let bvh = Bvh::new(Vec::new());
        assert_eq!(bvh.nearest_within(DVec3::ZERO, 1.0), None);
        assert_eq!(bvh.nearest(DVec3::ZERO, &mut 0), f64::INFINITY);
    }
}
