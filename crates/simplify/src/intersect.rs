//! Self-intersection guard: a spatial hash of the resident triangles (and of the latest emitted
//! ones), and the test whether a contraction's new fan would cross any of them.
//!
//! The topology checks only see the fans of `a` and `b`: a contraction on a thin structure (two
//! sheets a voxel apart, touching surfaces) may pass the link condition and flip no triangle yet
//! push the fan through the other sheet. [`TriIndex::would_intersect`] rejects those.
//!
//! Decisions:
//! * **Cell size**: `CELL_EDGES` times the mean edge length of the first `SAMPLE` triangles
//!   (marching-cubes edges are about 0.6 grid spacings, so cells are about two voxels). It adapts
//!   to any spacing without the caller passing one; until it is fixed, triangles wait unfiled and
//!   the first query files them. Simplified triangles grow to a few cells; a triangle is filed in
//!   every cell its bounding box overlaps.
//! * **Records**: each filed triangle keeps its ids and corner positions, so a query reads no
//!   store; contractions rewrite the records of the surviving vertex's triangles.
//! * **Emitted triangles** stay as obstacles ("ghosts") after they leave the store, since a
//!   contraction just ahead of the retirement front could otherwise cross them. The oldest ghosts
//!   are dropped once they outnumber the resident triangles (emission follows the sweep, so the
//!   oldest are the farthest behind): memory stays proportional to the band.
//! * **Predicate**: as `isostream_meshcheck::self_intersections`, strict `f64` orientation signs:
//!   triangles with no common vertex cross when an edge of one crosses the other; with one common
//!   vertex when the edge opposite it in one crosses the other; with two, never (flips are
//!   `topology::geometry_ok`'s). The new fan is also tested against itself (its triangles share
//!   the new vertex).
//! * **Cost**: a bounding-box overlap test precedes every exact test; a new triangle spanning
//!   more than `MAX_QUERY_CELLS` cells is refused unchecked.

use std::collections::VecDeque;

use glam::DVec3;
use rustc_hash::FxHashMap;
use smallvec::SmallVec;

use crate::store::{Store, TriId};

/// Cell edge in mean triangle edge lengths.
const CELL_EDGES: f64 = 3.0;
/// Triangles averaged for the cell size.
const SAMPLE: usize = 1024;
const NONE: u32 = u32::MAX;
/// A new triangle whose bounding box spans more cells than this is refused as if it crossed
/// something: checking it would cost a hash lookup per cell (attribute-driven priorities made
/// fans of long slivers and a ten-minute engine run), and filing it would take as many entries.
/// 32³ cells is a triangle about a hundred voxels across diagonally; flat ones may be larger.
const MAX_QUERY_CELLS: i64 = 1 << 15;

type Cell = [i32; 3];

#[derive(Debug, Clone, Copy)]
struct Rec {
    v: [u64; 3],
    p: [DVec3; 3],
    /// Bounding box of `p`, kept with it (queries test it for every record they meet).
    blo: DVec3,
    bhi: DVec3,
    lo: Cell,
    hi: Cell,
    filed: bool,
}

#[derive(Debug, Default)]
pub(crate) struct TriIndex {
    /// Cell edge; 0 until fixed.
    cell: f64,
    cells: FxHashMap<Cell, SmallVec<[u32; 8]>>,
    recs: Vec<Rec>,
    free: Vec<u32>,
    /// Record of each store triangle slot (`NONE` when empty).
    of_tri: Vec<u32>,
    ghosts: VecDeque<u32>,
    live: usize,
    /// Per record: the query generation that last met it (see `would_intersect`).
    seen: Vec<u32>,
    generation: u32,
}

impl TriIndex {
    /// A new store triangle `t`.
    pub(crate) fn insert(&mut self, t: TriId, v: [u64; 3], p: [DVec3; 3]) {
        let r = self.new_rec(v, p);
        let t = t as usize;
        if self.of_tri.len() <= t {
            self.of_tri.resize(t + 1, NONE);
        }
        self.of_tri[t] = r;
        self.live += 1;
        if self.cell == 0.0 && self.recs.len() - self.free.len() >= SAMPLE {
            self.fix_cell();
        }
    }

    /// Store triangle `t` collapsed away.
    pub(crate) fn remove(&mut self, t: TriId) {
        if let Some(r) = self.take(t) {
            self.drop_rec(r);
        }
    }

    /// Store triangle `t` was emitted: it stays as an obstacle for a while.
    pub(crate) fn emit(&mut self, t: TriId) {
        if let Some(r) = self.take(t) {
            self.ghosts.push_back(r);
        }
        while self.ghosts.len() > self.live.max(SAMPLE) {
            if let Some(r) = self.ghosts.pop_front() {
                self.drop_rec(r);
            }
        }
    }

    /// Store triangle `t` now has ids `v` at `p`.
    pub(crate) fn update(&mut self, t: TriId, v: [u64; 3], p: [DVec3; 3]) {
        let Some(&r) = self.of_tri.get(t as usize) else {
            return;
        };
        if r == NONE {
            return;
        }
        self.unfile(r);
        let rec = &mut self.recs[r as usize];
        rec.v = v;
        rec.p = p;
        (rec.blo, rec.bhi) = bbox(&p);
        // Before the cell size is fixed nothing is filed (coincident merges, which skip the
        // query, can come first); `fix_cell` files every record then.
        if self.cell > 0.0 {
            self.file(r);
        }
    }

    /// Whether contracting `a`, `b` to `pos` (the survivor keeps `keep`'s id) makes a triangle of
    /// the new fan cross another triangle (see the module documentation).
    pub(crate) fn would_intersect(
        &mut self,
        store: &Store,
        a: u64,
        b: u64,
        keep: u64,
        pos: DVec3,
    ) -> bool {
        if self.cell == 0.0 {
            self.fix_cell();
        }
        let mut old: SmallVec<[TriId; 32]> = [a, b]
            .iter()
            .filter_map(|&x| store.vertex(x))
            .flat_map(|x| x.tris.iter().copied())
            .collect();
        old.sort_unstable();
        old.dedup();
        let excluded: SmallVec<[u32; 32]> = old
            .iter()
            .filter_map(|&t| self.of_tri.get(t as usize).copied())
            .collect();
        let mut fan: SmallVec<[([u64; 3], [DVec3; 3]); 24]> = SmallVec::new();
        for &t in &old {
            let tri = store.tri(t);
            if tri.contains(a) && tri.contains(b) {
                continue;
            }
            let v = tri.v.map(|x| if x == a || x == b { keep } else { x });
            let p = v.map(|x| {
                if x == keep {
                    pos
                } else {
                    store.vertex(x).map_or(DVec3::ZERO, |y| y.pos)
                }
            });
            fan.push((v, p));
        }
        for (i, (v, p)) in fan.iter().enumerate() {
            if fan[..i].iter().any(|(w, q)| cross(*v, *p, *w, *q)) {
                return true;
            }
        }
        let span = |lo: DVec3, hi: DVec3| {
            let (clo, chi) = (self.key(lo), self.key(hi));
            (0..3)
                .map(|k| i64::from(chi[k]) - i64::from(clo[k]) + 1)
                .product::<i64>()
        };
        let boxes: SmallVec<[(DVec3, DVec3); 24]> = fan.iter().map(|(_, p)| bbox(p)).collect();
        if boxes.iter().any(|&(lo, hi)| span(lo, hi) > MAX_QUERY_CELLS) {
            return true;
        }
        // One pass over the records near the whole fan (each met once), each tested against
        // every fan triangle whose box it overlaps.
        let (lo, hi) = boxes.iter().fold(
            (DVec3::INFINITY, DVec3::NEG_INFINITY),
            |(lo, hi), &(l, h)| (lo.min(l), hi.max(h)),
        );
        let hits = |r: u32, rec: &Rec| {
            let (rlo, rhi) = (rec.blo, rec.bhi);
            if rlo.cmpgt(hi).any() || rhi.cmplt(lo).any() || excluded.contains(&r) {
                return false;
            }
            fan.iter().zip(&boxes).any(|((v, p), &(flo, fhi))| {
                !(rlo.cmpgt(fhi).any() || rhi.cmplt(flo).any()) && cross(*v, *p, rec.v, rec.p)
            })
        };
        // A large fan spans more cells than there are records: test every record then.
        let cells = span(lo, hi);
        if cells as usize > self.live + self.ghosts.len() {
            let mut filed = self.recs.iter().zip(0u32..).filter(|(rec, _)| rec.filed);
            return filed.any(|(rec, r)| hits(r, rec));
        }
        // Each record once: a generation mark instead of a list of seen records, whose scans
        // grew quadratic where large triangles share many cells.
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.seen.fill(0);
            self.generation = 1;
        }
        self.seen.resize(self.recs.len(), 0);
        let (clo, chi) = (self.key(lo), self.key(hi));
        for x in clo[0]..=chi[0] {
            for y in clo[1]..=chi[1] {
                for z in clo[2]..=chi[2] {
                    let Some(list) = self.cells.get(&[x, y, z]) else {
                        continue;
                    };
                    for &r in list {
                        let mark = &mut self.seen[r as usize];
                        if *mark == self.generation {
                            continue;
                        }
                        *mark = self.generation;
                        if hits(r, &self.recs[r as usize]) {
                            return true;
                        }
                    }
                }
            }
        }
        false
    }

    fn take(&mut self, t: TriId) -> Option<u32> {
        let slot = self.of_tri.get_mut(t as usize)?;
        let r = std::mem::replace(slot, NONE);
        if r == NONE {
            return None;
        }
        self.live -= 1;
        Some(r)
    }

    fn new_rec(&mut self, v: [u64; 3], p: [DVec3; 3]) -> u32 {
        let (blo, bhi) = bbox(&p);
        let rec = Rec {
            v,
            p,
            blo,
            bhi,
            lo: [0; 3],
            hi: [0; 3],
            filed: false,
        };
        let r = match self.free.pop() {
            Some(r) => {
                self.recs[r as usize] = rec;
                r
            }
            None => {
                self.recs.push(rec);
                u32::try_from(self.recs.len() - 1).expect("fewer than 2^32 indexed triangles")
            }
        };
        if self.cell > 0.0 {
            self.file(r);
        }
        r
    }

    fn drop_rec(&mut self, r: u32) {
        self.unfile(r);
        self.free.push(r);
    }

    fn fix_cell(&mut self) {
        let mut free = vec![false; self.recs.len()];
        for &r in &self.free {
            free[r as usize] = true;
        }
        let (mut sum, mut n, mut longest) = (0.0, 0usize, 0.0f64);
        for (rec, _) in self.recs.iter().zip(&free).filter(|(_, f)| !**f) {
            for k in 0..3 {
                let d = rec.p[k].distance(rec.p[(k + 1) % 3]);
                sum += d;
                longest = longest.max(d);
                n += 1;
            }
        }
        // Many coincident vertices (isos on grid values) make the mean edge tiny; a cell far
        // smaller than the triangles would file each one in millions of cells.
        let cell = CELL_EDGES * (sum / n.max(1) as f64).max(0.25 * longest);
        self.cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            1.0
        };
        for (r, _) in free.iter().enumerate().filter(|(_, f)| !**f) {
            self.file(r as u32);
        }
    }

    fn key(&self, p: DVec3) -> Cell {
        let k = (p / self.cell).floor();
        // Clamped: far-out coordinates share the outermost cells instead of overflowing.
        let c = |x: f64| x.clamp(-1e9, 1e9) as i32;
        [c(k.x), c(k.y), c(k.z)]
    }

    fn file(&mut self, r: u32) {
        let rec = &self.recs[r as usize];
        let (lo, hi) = (self.key(rec.blo), self.key(rec.bhi));
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    self.cells.entry([x, y, z]).or_default().push(r);
                }
            }
        }
        let rec = &mut self.recs[r as usize];
        (rec.lo, rec.hi, rec.filed) = (lo, hi, true);
    }

    fn unfile(&mut self, r: u32) {
        let rec = self.recs[r as usize];
        if !rec.filed {
            return;
        }
        for x in rec.lo[0]..=rec.hi[0] {
            for y in rec.lo[1]..=rec.hi[1] {
                for z in rec.lo[2]..=rec.hi[2] {
                    if let Some(list) = self.cells.get_mut(&[x, y, z]) {
                        if let Some(i) = list.iter().position(|&s| s == r) {
                            list.swap_remove(i);
                        }
                        if list.is_empty() {
                            self.cells.remove(&[x, y, z]);
                        }
                    }
                }
            }
        }
        self.recs[r as usize].filed = false;
    }
}

fn bbox(p: &[DVec3; 3]) -> (DVec3, DVec3) {
    (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]))
}

/// `(b - a) . ((c - a) x (d - a))`.
fn orient(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    (b - a).dot((c - a).cross(d - a))
}

/// Segment `pq` strictly crosses triangle `t`.
fn segment_crosses(p: DVec3, q: DVec3, t: &[DVec3; 3]) -> bool {
    let [a, b, c] = *t;
    let (o1, o2) = (orient(a, b, c, p), orient(a, b, c, q));
    if !((o1 > 0.0 && o2 < 0.0) || (o1 < 0.0 && o2 > 0.0)) {
        return false;
    }
    let s = [orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)];
    s.iter().all(|&x| x > 0.0) || s.iter().all(|&x| x < 0.0)
}

/// Whether two triangles cross (see the module documentation for common vertices).
fn cross(va: [u64; 3], a: [DVec3; 3], vb: [u64; 3], b: [DVec3; 3]) -> bool {
    let mut shared = None;
    let mut count = 0;
    for (i, x) in va.iter().enumerate() {
        for (j, y) in vb.iter().enumerate() {
            if x == y {
                shared = Some((i, j));
                count += 1;
            }
        }
    }
    match (count, shared) {
        (0, _) => {
            // An edge crosses a triangle only from one side of its plane to the other: the same
            // orientations `segment_crosses` starts with, computed once per corner, dismiss most
            // pairs (the guard spends half the simplifier's time here).
            let straddles = |t: &[DVec3; 3], q: &[DVec3; 3]| {
                let s = q.map(|p| orient(t[0], t[1], t[2], p));
                !(s.iter().all(|&x| x > 0.0) || s.iter().all(|&x| x < 0.0))
            };
            (straddles(&b, &a) && (0..3).any(|i| segment_crosses(a[i], a[(i + 1) % 3], &b)))
                || (straddles(&a, &b) && (0..3).any(|i| segment_crosses(b[i], b[(i + 1) % 3], &a)))
        }
        (1, Some((i, j))) => {
            segment_crosses(a[(i + 1) % 3], a[(i + 2) % 3], &b)
                || segment_crosses(b[(j + 1) % 3], b[(j + 2) % 3], &a)
        }
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Legs of 2 along x and y at the origin.
    fn right_triangle() -> [DVec3; 3] {
        [
            DVec3::ZERO,
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        ]
    }

    #[test]
    fn crossing_and_touching_triangles() {
        let t = [
            DVec3::ZERO,
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        ];
        let s = [
            DVec3::new(0.5, 0.5, -1.0),
            DVec3::new(0.5, 0.5, 1.0),
            DVec3::new(3.0, 3.0, 0.5),
        ];
        assert!(cross([0, 1, 2], t, [3, 4, 5], s));
        assert!(!cross(
            [0, 1, 2],
            t,
            [3, 4, 5],
            s.map(|p| p + DVec3::X * 10.0)
        ));
        // Sharing a vertex and folding through: the opposite edge crosses.
        let f = [
            DVec3::ZERO,
            DVec3::new(1.0, 0.0, -1.0),
            DVec3::new(1.0, 0.0, 1.0),
        ];
        let g = [
            DVec3::ZERO,
            DVec3::new(2.0, -1.0, 0.0),
            DVec3::new(2.0, 1.0, 0.0),
        ];
        assert!(cross([0, 1, 2], g, [0, 3, 4], f));
        assert!(!cross(
            [0, 1, 2],
            g,
            [0, 3, 4],
            f.map(|p| p + DVec3::Z * 2.0)
        ));
    }

    #[test]
    fn the_index_follows_inserts_updates_and_removals() {
        let mut ix = TriIndex::default();
        let t = right_triangle();
        ix.insert(0, [0, 1, 2], t);
        ix.fix_cell();
        assert!(ix.cell > 0.0);
        let filed = |ix: &TriIndex| ix.cells.values().map(|l| l.len()).sum::<usize>();
        assert!(filed(&ix) > 0);
        ix.update(0, [0, 1, 2], t.map(|p| p * 3.0));
        let n = filed(&ix);
        ix.insert(1, [3, 4, 5], t.map(|p| p + DVec3::Z));
        assert!(filed(&ix) > n);
        ix.remove(1);
        assert_eq!(filed(&ix), n);
        ix.emit(0);
        assert_eq!(ix.ghosts.len(), 1);
        assert_eq!(filed(&ix), n, "ghosts stay filed");
    }

    #[test]
    fn updates_before_the_cell_is_fixed_file_nothing() {
        // A coincident merge may update records before any query fixed the cell: filing then
        // divided by a zero cell and put one triangle in billions of cells.
        let mut ix = TriIndex::default();
        let t = right_triangle();
        ix.insert(0, [0, 1, 2], t);
        ix.update(0, [0, 1, 3], t.map(|p| p + DVec3::X));
        assert!(ix.cells.is_empty());
        ix.fix_cell();
        assert!(!ix.cells.is_empty() && ix.cells.len() < 64);
    }
}
