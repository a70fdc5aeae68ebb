//! Self-intersection guard: a multi-level spatial hash of the resident triangles (and of the
//! latest emitted ones), and the test whether a contraction's new fan would cross any of them.
//!
//! The topology checks only see the fans of `a` and `b`: a contraction on a thin structure (two
//! sheets a voxel apart, touching surfaces) may pass the link condition and flip no triangle yet
//! push the fan through the other sheet. [`TriIndex::would_intersect`] rejects those.
//!
//! Decisions:
//! * **Levels**: level `L` has cells of `cell * 2^L`; a triangle is filed at the lowest level
//!   whose cell is at least `LEVEL_ROOM` times its bounding box's largest extent, so it lies in
//!   at most 2 x 2 x 2 cells whatever its size; a needle (`NEEDLE_ASPECT`) at the level of its
//!   width, in up to 2 x 2 x 5 cells. Simplification at low rates makes triangles tens
//!   of voxels wide; with one cell size they were filed in thousands of cells each and filing,
//!   unfiling and querying grew with their size (86 % of a 2 M-face run at R = 0.01).
//! * **Cell size**: `CELL_EDGES` times the median edge length of the first `SAMPLE` triangles
//!   (marching-cubes edges are about 0.6 grid spacings, so level-0 cells are about four voxels).
//!   Until it is fixed, triangles wait unfiled and the first query files them.
//! * **Records** hold `f32` corners (positions are `f32`-exact from the simplifier on, see
//!   `cost::output_precision`) and ids in one cache line: a query meets records in the order of
//!   the cells, which is random in memory, and with the box, a query mark and the corners in
//!   three arrays each record it met cost three cache misses (the largest part of the guard's
//!   time by `perf`, though not by instruction counts). The box is recomputed from the corners
//!   when needed. The old patch's records are told by their corners' ids (every triangle holding
//!   `a` or `b`): finding their numbers instead, from the store's triangle slots, took a random
//!   read of the slot map per patch triangle, and dropping those reads made the engine crop
//!   about 10 % faster (same output) though the patch's records are then read.
//!   A query gathers the records its cells name before it reads any, so that their cache misses
//!   overlap (8 % of a one-stage run on bonsai at R = 0.2, same output).
//! * **Large queries**: a query box spanning more cells of a level than that level has records
//!   takes every record of the level instead, by the entry in its first cell, in a pass over
//!   that level's cells: each level has its own map for that. (With one map for all levels the
//!   pass read every cell of every level, 430 a large query on bonsai upsampled to 511^3 and
//!   3,400 with cells of 8 edges. A list of each level's records, kept for that, cost a random
//!   write a record at every unfiling.)
//! * **Emitted triangles** stay as obstacles ("ghosts") after they leave the store, since a
//!   contraction just ahead of the retirement front could otherwise cross them. Ghosts lying
//!   wholly below every resident triangle are dropped once they outnumber a quarter of the
//!   resident triangles, the others only past twice their number (oldest first): memory stays
//!   proportional to the band. What was dropped is no longer seen, so the box around every
//!   dropped ghost (the `unguarded` region) is refused to new fans: a fan whose box meets it
//!   might cross a triangle the index forgot. Dropping the oldest quarter without that wrote
//!   crossing triangles when retirement for a tight memory budget emitted right next to
//!   contractible vertices (bonsai at R = 0.01 with 16 MiB: 4 with one stage, 25 with two; 86
//!   and 116 with no ghosts at all); with the default budget on the real volumes no fan reached
//!   a dropped ghost (every ghost dropped at once wrote the same bytes).
//! * **Predicate**: as `isostream_meshcheck::self_intersections`, closed, in exact orientation
//!   signs: triangles with no common vertex meet when an edge of one meets the other; with one
//!   common vertex when the edge opposite it in one meets the other; with two, never (flips are
//!   `topology::geometry_ok`'s). Touching is refused as crossing is: with strict signs alone
//!   (crossing only), contractions on blocky volumes put a vertex of one component exactly on a
//!   vertex or an edge of another, a surface that is not embedded (an STL welds such corners
//!   into non-manifold vertices). Edges in the other triangle's plane take the referee's
//!   two-dimensional test (`in_plane_edge_meets`). The new fan is also checked against itself
//!   (its triangles share the new vertex): first by a proof that its star is embedded (`star`),
//!   which covers every pair at once and almost always holds, then, when it does not, pair by
//!   pair.

use std::collections::VecDeque;

use glam::{DVec3, Vec3, Vec3A};
use rustc_hash::FxHashMap;
use smallvec::SmallVec;

use crate::store::{Store, TriId};
use crate::topology::Patch;

mod cells;
mod star;

use cells::{CellList, Pool};
use star::Spoke;

/// A triangle's level has cells at least this many times its extent. With 1 a decimated
/// triangle (extent between half a cell and a cell) met about five cells on average, and its
/// entries made the index the part of memory that grew at low rates: with 2, peak RSS at R = 0.05
/// fell from 66 to 51 MiB on engine and from 74 to 60 MiB on bonsai (R = 0.01 on engine: 54 to
/// 41 MiB) for 0.5 % more instructions and the same output; 4 saved 4-7 MiB more for 4 % more
/// instructions.
const LEVEL_ROOM: f64 = 2.0;
/// A needle (a triangle whose box is more than [`NEEDLE_ASPECT`] times longer along one axis
/// than along the next) is filed at the level of its middle extent, in up to this many cells
/// plus one along its length, rather than at the level of its length. Filed by its length, the
/// needles of a sheet decimated at a low rate (tilted parallel sheets 3 voxels apart at R =
/// 0.01, straight along the sweep: half the triangles 34 to 127 voxels long and 1 to 4 wide)
/// all sat in the one cell of a level wider than the volume, and every query scanned about
/// 15,500 entries there (807 of them meeting its box): 32.0 s for the 128^3 case, 14.3 s filed
/// this way (130 records a query), the same bytes.
const NEEDLE_SPAN: f64 = 4.0;
/// How much longer than wide a box must be to be filed as a needle. Every triangle filed by
/// its middle extent (no threshold) cost bonsai upsampled to 511^3 about 1.5 MiB of peak RSS
/// (more of the common, slightly elongated triangles in 12 cells rather than 8); with 8, the
/// same within the runs' spread, and +0.4 % instructions on bonsai at R = 0.2
/// (`tools/instructions.py`), the same bytes on every real volume.
const NEEDLE_ASPECT: f64 = 8.0;
/// Cell edge in median triangle edge lengths (the mean until the thirty-third session). 12
/// rather than 6: at low rates on large slices the fans behind the front grow tens of voxels
/// wide while the front is at full resolution, and a fan's box spanned hundreds of level-0
/// cells, most of them empty (bonsai upsampled 4x, one stage: 184 lookups a query, 17.6
/// found); with 12 that run went about 20 % faster side by side with 6 (slab 421 at 276 s
/// against slab 423 at 363 s), bonsai at R = 0.2 as fast within the noise, the same output
/// bytes (the index only narrows what the exact test sees).
/// 8 since the forty-fourth session, once a large query read only its own level's cells: a
/// query scanned about 485 entries of level-0 cells of 12 edges for 42 records met (bonsai at
/// R = 0.2, one stage), 280 with 8. By callgrind, same output bytes everywhere: bonsai one
/// stage 28.92 G against 29.45 G; two stages, the busier stage -0.8 % at R = 0.2 and -3.7 % at
/// R = 0.01 (its second stage, 19.91 -> 19.17 G); engine at R = 0.01 +0.8 %, bonsai upsampled
/// to 511^3 at 10 k faces +0.4 %. 10 gained less on bonsai (-0.3 %, -2.5 %); 6 scanned fewer
/// entries but made more lookups and refilings (bonsai one stage 28.92 G, as 8).
const CELL_EDGES: f64 = 8.0;
/// A record is filed with its box grown by this share of its level's cell on every side, so
/// that the updates a contraction makes to its neighbours' corners (about an edge; level-0
/// cells are [`CELL_EDGES`] edges) leave most records where they are filed.
const SLACK: f64 = 0.0625;
/// Triangles whose median edge sets the cell size.
const SAMPLE: usize = 1024;
/// Cell sizes `cell * 2^L` for `L < LEVELS`: 2^23 level-0 cells covers any volume.
const LEVELS: usize = 24;
const NONE: u32 = u32::MAX;
/// Emitted triangles kept as obstacles: once they outnumber one per `GHOST_SHARE` resident ones
/// (and `SAMPLE`), those lying wholly below every resident triangle are dropped (see
/// [`TriIndex::emit`]); with the simplified surface resident (rate mode) more would cost memory
/// per resident face for triangles far behind.
const GHOST_SHARE: usize = 4;
/// Ghosts that still reach the resident triangles are dropped too, oldest first, when they
/// outnumber the resident triangles this many times (and `SAMPLE`): the region they leave is
/// refused to new fans, which is safe but stops contractions there, so it is the last resort
/// that keeps memory bounded when a resident triangle lags far behind the others.
const GHOST_LIMIT: usize = 2;
/// `Filed::level` of a record in no cell.
const UNFILED: u8 = u8::MAX;

type Cell = [i32; 3];

/// A record: 64 bytes, one cache line (see the module documentation).
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
#[repr(C, align(64))]
struct Rec {
    p: [Vec3; 3],
    v: [u64; 3],
}

impl Rec {
    fn new(v: [u64; 3], p: [DVec3; 3]) -> Self {
        Self {
            p: p.map(|x| x.as_vec3()),
            v,
        }
    }

    fn aabb(&self) -> Aabb {
        Aabb::of(&self.p)
    }
}

/// An axis-aligned box in `f32` (exact for `f32` corners).
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
struct Aabb {
    lo: Vec3,
    hi: Vec3,
}

impl Aabb {
    const EMPTY: Self = Self {
        lo: Vec3::INFINITY,
        hi: Vec3::NEG_INFINITY,
    };

    fn of(p: &[Vec3; 3]) -> Self {
        Self {
            lo: p[0].min(p[1]).min(p[2]),
            hi: p[0].max(p[1]).max(p[2]),
        }
    }

    fn overlaps(&self, o: &Self) -> bool {
        !(self.lo.cmpgt(o.hi).any() || self.hi.cmplt(o.lo).any())
    }

    fn union(&self, o: &Self) -> Self {
        Self {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }

    /// The box's middle and largest extents.
    fn extents(&self) -> (f64, f64) {
        let e = self.hi - self.lo;
        let (lo, hi) = (e.x.min(e.y), e.x.max(e.y));
        (f64::from(lo.max(e.z).min(hi)), f64::from(hi.max(e.z)))
    }

    /// Whether `o` lies within this box.
    fn contains(&self, o: &Self) -> bool {
        self.lo.cmple(o.lo).all() && o.hi.cmple(self.hi).all()
    }

    /// This box grown by `m` on every side (rounded outward: `f32` subtraction and addition
    /// are monotonic, and `x - m <= x` for `m >= 0`).
    fn grown(&self, m: f32) -> Self {
        Self {
            lo: self.lo - Vec3::splat(m),
            hi: self.hi + Vec3::splat(m),
        }
    }
}

/// An [`Aabb`] in SIMD lanes, for comparing a record's box with every box of a fan: two vector
/// comparisons and no branch per pair (a branch per pair was about a quarter of the guard's
/// mispredicted branches by callgrind's simulation).
#[derive(Debug, Clone, Copy)]
struct Wide {
    lo: Vec3A,
    hi: Vec3A,
}

impl Wide {
    fn of(b: &Aabb) -> Self {
        Self {
            lo: b.lo.into(),
            hi: b.hi.into(),
        }
    }

    /// [`Aabb::overlaps`] (the same answer for boxes of finite corners, which every triangle's
    /// are).
    fn meets(&self, o: &Self) -> bool {
        (self.lo.cmple(o.hi) & self.hi.cmpge(o.lo)).all()
    }
}

/// Lanes of an entry's key and of a query's probe, compared all at once by [`meets`]: the key
/// holds `hi[k]`, `255 - lo[k]` (9-bit lanes) and the first-cell bit `k` (2-bit lanes); the
/// probe holds the query's `lo[k]`, `255 - hi[k]` and the bits the one-cell rule needs. Every
/// key lane at least its probe lane is exactly "the quantized boxes meet and the record's
/// first cell is this one along the needed axes". The cell scan is the guard's largest loop
/// (about 230 entries per query on bonsai at R = 0.2): branch-free, it is four instructions
/// an entry.
const BOX_LANE: u32 = 9;
const BIT_LANE: u32 = 2;
const BITS_AT: u32 = 6 * BOX_LANE;
/// The top bit of every lane.
const GUARD: u64 = {
    let mut g = 0u64;
    let mut k = 0;
    while k < 6 {
        g |= 1 << (k * BOX_LANE + BOX_LANE - 1);
        k += 1;
    }
    while k < 9 {
        g |= 1 << (BITS_AT + (k - 6) * BIT_LANE + BIT_LANE - 1);
        k += 1;
    }
    g
};

/// The first-cell bits of a key, all set: the entry in the record's first cell, which every
/// filed record has exactly one of.
const FIRST_CELL: u64 = {
    let mut m = 0u64;
    let mut k = 0;
    while k < 3 {
        m |= 1 << (BITS_AT + k * BIT_LANE);
        k += 1;
    }
    m
};

/// Lanes `hi, 255 - lo, bits` or `lo, 255 - hi, bits` (see [`GUARD`]).
fn lanes(x: [u8; 3], y: [u8; 3], bits: u8) -> u64 {
    let mut w = 0u64;
    for k in 0..3 {
        w |= u64::from(x[k]) << (k as u32 * BOX_LANE);
        w |= u64::from(255 - y[k]) << ((k as u32 + 3) * BOX_LANE);
        w |= u64::from((bits >> k) & 1) << (BITS_AT + k as u32 * BIT_LANE);
    }
    w
}

/// An entry's key: its quantized box `q` and its first-cell bits.
fn pack(q: &Quantized, first: u8) -> u64 {
    lanes([q[3], q[4], q[5]], [q[0], q[1], q[2]], first)
}

/// A query's probe in one cell: its quantized box `q` and the first-cell bits it needs.
fn probe(q: &Quantized, need: u8) -> u64 {
    lanes([q[0], q[1], q[2]], [q[3], q[4], q[5]], need)
}

/// Whether every lane of `key` is at least that of `probe`: with the guard bit set, a lane's
/// difference stays positive (no borrow reaches the next lane) and keeps that bit exactly when
/// the key's lane is not smaller.
fn meets(key: u64, probe: u64) -> bool {
    ((key | GUARD) - probe) & GUARD == GUARD
}

/// A box clipped to one cell in 1/256 of the cell: `[lo; 3]`, `[hi; 3]`. Every step from the
/// coordinate to the byte ([`TriIndex::scaled`], [`clip`]) is monotonic, so two boxes that meet
/// keep quantized boxes that meet: the test is conservative, and the exact box decides after.
type Quantized = [u8; 6];

/// A box in 1/256 of the cells of one level (see [`TriIndex::scaled`]).
type Scaled = [i64; 6];

/// `s` within cell `c`, clamped to the cell.
fn clip(s: &Scaled, c: Cell) -> Quantized {
    let q = |i: usize| (s[i] - 256 * i64::from(c[i % 3])).clamp(0, 255) as u8;
    [q(0), q(1), q(2), q(3), q(4), q(5)]
}

/// Where a record is filed: its level and the box its entries were made for (its room: its own
/// box grown by [`SLACK`] within its cells, which are those of the room's corners), so that an
/// update moving a corner a little needs no change of the index.
#[derive(Debug, Clone, Copy, serde::Serialize, serde::Deserialize)]
struct Filed {
    level: u8,
    room: Aabb,
}

const NOT_FILED: Filed = Filed {
    level: UNFILED,
    room: Aabb::EMPTY,
};

/// One level of the index: its cells, and how many records are filed there (a query box
/// spanning more of its cells than that reads the level's records instead, by a pass over its
/// cells alone).
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
struct Level {
    cells: FxHashMap<Cell, CellList>,
    records: usize,
}

#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct TriIndex {
    /// Level-0 cell edge; 0 until fixed.
    cell: f64,
    /// Each level's cells and record count, from level 0 up to the highest used so far.
    levels: Vec<Level>,
    /// The entries of every level's cells.
    pool: Pool,
    recs: Vec<Rec>,
    filed: Vec<Filed>,
    free: Vec<u32>,
    /// Record of each store triangle slot (`NONE` when empty).
    of_tri: Vec<u32>,
    /// Ghost records with their highest corner along z, oldest first: the scan for ghosts to
    /// drop reads no record (each a cache miss, half of that scan's time).
    ghosts: VecDeque<(u32, f32)>,
    /// Ghosts at which [`TriIndex::emit`] looks for ones to drop again.
    ghost_check: usize,
    /// The box around every ghost dropped so far (`None` before the first): no new fan may
    /// meet it.
    unguarded: Option<Aabb>,
    live: usize,
    work: GuardWork,
    /// The records a query's cells name, kept between queries so that gathering them is a
    /// plain push into room already there (scratch, empty between queries: a checkpoint need
    /// not hold it). As a `SmallVec` made afresh, each push checked where its items lived.
    #[serde(skip)]
    met: Vec<u32>,
}

/// What the guard's queries met, for the run summary: where its time goes is the records a
/// query reads (each a likely cache miss) and the fan/record pairs it tests, and both grow with
/// the fans' size against the triangles around them (bonsai at R = 0.2: about 26 records and 55
/// pairs a query; upsampled 4x with one stage, 162 and 223 once the fans are large: the
/// eighteenth session in docs/performance.md).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct GuardWork {
    /// Fans the guard was asked about: every contraction that passed the topology checks,
    /// merges of coincident vertices aside.
    pub queries: u64,
    /// Records of other triangles whose cell entry met a fan's box: each is read, unless a
    /// crossing found first ends the query.
    pub records: u64,
    /// Fan triangle and record pairs whose boxes met, tested exactly.
    pub pairs: u64,
}

impl std::ops::Add for GuardWork {
    type Output = Self;

    fn add(self, o: Self) -> Self {
        Self {
            queries: self.queries + o.queries,
            records: self.records + o.records,
            pairs: self.pairs + o.pairs,
        }
    }
}

/// What [`TriIndex::would_intersect`] found for a new fan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// No triangle it knows is crossed, and the fan stays clear of what it forgot.
    Clear,
    /// A triangle of the fan crosses another triangle.
    Crosses,
    /// The fan's box meets the region of dropped ghosts, which might be crossed.
    Unguarded,
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

    /// An index for a second worker on the other side of a cut (`seam`): the records of
    /// triangles `moved` (taken out of this one, whose worker's fans cannot reach them), copies
    /// of those of `shared` (the seam, which both workers' fans can meet) and of the ghosts,
    /// the same cell size and the same region refused to new fans.
    pub(crate) fn split_off(&mut self, moved: &[TriId], shared: &[TriId]) -> TriIndex {
        let mut other = TriIndex {
            cell: self.cell,
            unguarded: self.unguarded,
            ..TriIndex::default()
        };
        for &t in moved.iter().chain(shared) {
            if let Some(&r) = self.of_tri.get(t as usize).filter(|&&r| r != NONE) {
                let rec = self.recs[r as usize];
                other.insert(t, rec.v, rec.p.map(Vec3::as_dvec3));
            }
        }
        for &t in moved {
            self.remove(t);
        }
        for &(r, top) in &self.ghosts {
            let rec = self.recs[r as usize];
            let g = other.new_rec(rec.v, rec.p.map(Vec3::as_dvec3));
            other.ghosts.push_back((g, top));
        }
        other
    }

    /// Takes back the triangles [`TriIndex::split_off`] moved, those the other worker kept,
    /// as `store` now has them, and counts the other's work as this index's.
    pub(crate) fn absorb(&mut self, other: TriIndex, store: &Store, moved: &[TriId]) {
        for &t in moved {
            if other.of_tri.get(t as usize).is_some_and(|&r| r != NONE) {
                let tri = store.tri(t);
                self.insert(t, tri.v, store.corners(tri));
            }
        }
        self.work = self.work + other.work;
    }

    /// Store triangle `t` collapsed away.
    pub(crate) fn remove(&mut self, t: TriId) {
        if let Some(r) = self.take(t) {
            self.drop_rec(r);
        }
    }

    /// Store triangle `t` was emitted: it stays as an obstacle while a new fan could reach it.
    ///
    /// Fans are made of resident triangles' corners and a new vertex, so a ghost lying wholly
    /// below every resident triangle (along z, the sweep of a volume) is out of their reach
    /// unless a placement moves below it, which the `unguarded` region then refuses. Those are
    /// dropped whenever the ghosts outnumber a [`GHOST_SHARE`] of the resident triangles (a scan
    /// of both, paid once per that many emissions); the others only beyond [`GHOST_LIMIT`].
    pub(crate) fn emit(&mut self, t: TriId) {
        if let Some(r) = self.take(t) {
            let top = self.recs[r as usize].aabb().hi.z;
            self.ghosts.push_back((r, top));
        }
        let share = (self.live / GHOST_SHARE).max(SAMPLE);
        if self.ghosts.len() <= share.max(self.ghost_check) {
            return;
        }
        let floor = self.resident_floor();
        // Rotated through in place, the kept ones back in order: a deque taken out and filled
        // again grew from nothing at every scan (-0.24 % of the first stage's instructions on
        // bonsai at R = 0.2, `tools/instructions.py`, the same output).
        for _ in 0..self.ghosts.len() {
            let Some((r, top)) = self.ghosts.pop_front() else {
                break;
            };
            if top < floor {
                self.forget(r);
            } else {
                self.ghosts.push_back((r, top));
            }
        }
        let limit = (self.live * GHOST_LIMIT).max(SAMPLE);
        while self.ghosts.len() > limit {
            if let Some((r, _)) = self.ghosts.pop_front() {
                self.forget(r);
            }
        }
        self.ghost_check = self.ghosts.len() + share;
    }

    /// The lowest corner along z of the resident triangles' records. Read in the records' order
    /// (the records neither ghosts nor free), not through the triangles' slots: one read of
    /// the records in turn rather than a cache miss for each (reached through the slots, this
    /// was 6 % of a run that made no contraction).
    fn resident_floor(&self) -> f32 {
        let mut resident = vec![true; self.recs.len()];
        for &r in self.ghosts.iter().map(|(r, _)| r).chain(&self.free) {
            resident[r as usize] = false;
        }
        self.recs
            .iter()
            .zip(&resident)
            .filter(|(_, resident)| **resident)
            .map(|(rec, _)| rec.p[0].z.min(rec.p[1].z).min(rec.p[2].z))
            .fold(f32::INFINITY, f32::min)
    }

    /// Drops ghost record `r`, adding its box to the region refused to new fans.
    fn forget(&mut self, r: u32) {
        let bx = self.recs[r as usize].aabb();
        self.unguarded = Some(self.unguarded.map_or(bx, |u| u.union(&bx)));
        self.drop_rec(r);
    }

    /// Reads the index's data on triangles `tris` ahead of their [`TriIndex::update`]s: each
    /// is a cache miss, and reads issued together overlap where each update waited for its own.
    pub(crate) fn warm(&self, tris: &[TriId]) {
        let rec_of = |t: TriId| self.of_tri.get(t as usize).copied().unwrap_or(NONE);
        let records = tris.iter().fold(0, |acc, &t| acc ^ rec_of(t));
        std::hint::black_box(records);
        let levels = tris
            .iter()
            .filter_map(|&t| self.filed.get(rec_of(t) as usize))
            .fold(0, |acc, f| acc ^ f.level);
        std::hint::black_box(levels);
    }

    /// Store triangle `t` now has ids `v` at `p`.
    pub(crate) fn update(&mut self, t: TriId, v: [u64; 3], p: [DVec3; 3]) {
        let Some(&r) = self.of_tri.get(t as usize) else {
            return;
        };
        if r == NONE {
            return;
        }
        let rec = Rec::new(v, p);
        let bx = rec.aabb();
        self.recs[r as usize] = rec;
        // Entries are conservative filters (the record's own box decides after), so a box
        // that stays within the room it was filed with needs no change of the index: most
        // updates after a contraction move one corner by about an edge.
        let f = &self.filed[r as usize];
        if f.level != UNFILED && f.room.contains(&bx) {
            return;
        }
        if self.refile_in_place(r, bx) {
            return;
        }
        self.unfile(r);
        // Before the cell size is fixed nothing is filed (coincident merges, which skip the
        // query, can come first); `fix_cell` files every record then.
        if self.cell > 0.0 {
            self.file(r);
        }
    }

    /// Whether contracting `a`, `b` to `pos` (the survivor keeps `keep`'s id) makes a triangle of
    /// the new fan cross another triangle, or brings the fan where dropped ghosts might be
    /// crossed (see the module documentation).
    pub(crate) fn would_intersect(
        &mut self,
        old: &Patch,
        a: u64,
        b: u64,
        keep: u64,
        pos: DVec3,
    ) -> Verdict {
        if self.cell == 0.0 {
            self.fix_cell();
        }
        self.work.queries += 1;
        let mut fan: SmallVec<[Tri64; 24]> = SmallVec::new();
        // The fan's boxes side by side: a record is compared with all of them branch-free, and
        // only the fan triangles whose box meets its own are tested exactly.
        let mut fan_boxes: SmallVec<[Wide; 24]> = SmallVec::new();
        let mut union = Aabb::EMPTY;
        for pt in &old.tris {
            if pt.v.contains(&a) && pt.v.contains(&b) {
                continue; // removed by the contraction
            }
            // Rotated so that the new vertex comes first (a rotation keeps the orientation and
            // every edge's direction, so the predicates see the same segments).
            let i = pt.v.iter().position(|&x| x == a || x == b).unwrap_or(0);
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            let v = [keep, pt.v[j], pt.v[k]];
            let p = [pos, pt.p[j], pt.p[k]];
            let bx = Aabb::of(&p.map(|x| x.as_vec3()));
            union = union.union(&bx);
            fan.push(Tri64::new(v, p));
            fan_boxes.push(Wide::of(&bx));
        }
        if fan.is_empty() {
            return Verdict::Clear;
        }
        if self.unguarded.is_some_and(|u| u.overlaps(&union)) {
            return Verdict::Unguarded;
        }
        // Two triangles of an embedded star cannot cross (`star`): for the new fan that proof
        // replaces its pairwise self-test. (Ring vertices' stars would cover the fan's
        // neighbours too, but proving them costs more than the pair tests they save.)
        let fan_spokes: SmallVec<[Spoke; 24]> = fan
            .iter()
            .map(|t| Spoke {
                s: t.v[1],
                e: t.v[2],
                ps: t.p[1],
                pe: t.p[2],
            })
            .collect();
        if !star::embedded(pos, &fan_spokes) {
            for (i, t) in fan.iter().enumerate() {
                if fan[..i].iter().any(|u| cross(t, u)) {
                    return Verdict::Crosses;
                }
            }
        }
        let (mut pairs, mut others) = (0, 0);
        // Plain slices for the closure: a `SmallVec` checks where its items live at every
        // access, and the closure runs once per record met.
        let (fan, fan_boxes) = (&fan[..], &fan_boxes[..]);
        let mut hits = |r: u32| {
            let rec = &self.recs[r as usize];
            // The old patch's records (every triangle holding `a` or `b`): replaced, so no
            // obstacles.
            if rec.v.iter().any(|&x| x == a || x == b) {
                return false;
            }
            others += 1;
            let rb = rec.aabb();
            if !rb.overlaps(&union) {
                return false;
            }
            let mut other = None;
            let wide = Wide::of(&rb);
            for (chunk, boxes) in fan_boxes.chunks(64).enumerate() {
                let mut mask = boxes
                    .iter()
                    .enumerate()
                    .fold(0u64, |m, (i, fb)| m | (u64::from(fb.meets(&wide)) << i));
                while mask != 0 {
                    let i = 64 * chunk + mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    pairs += 1;
                    // Every fan triangle starts at the new vertex: its side of the record's
                    // plane once per record.
                    let (o, apex) = other.get_or_insert_with(|| {
                        let o = Tri64::new(rec.v, rec.p.map(|x| x.as_dvec3()));
                        let apex = o.side(pos);
                        (o, apex)
                    });
                    if crosses_fan(&fan[i], *apex, o) {
                        return true;
                    }
                }
            }
            false
        };
        // The records to test are gathered first and read after: each is a cache miss, and
        // reads issued together overlap where a test per record waited for each in turn.
        let mut met = std::mem::take(&mut self.met);
        let mut meet = |r: u32| met.push(r);
        let mut lists: SmallVec<[(CellList, u64); 32]> = SmallVec::new();
        for level in 0..LEVELS {
            let count = self.levels.get(level).map_or(0, |l| l.records);
            if count == 0 {
                continue;
            }
            let (clo, chi) = (
                self.key(level, union.lo.as_dvec3()),
                self.key(level, union.hi.as_dvec3()),
            );
            let cells: i64 = (0..3)
                .map(|k| i64::from(chi[k]) - i64::from(clo[k]) + 1)
                .product();
            if cells as usize > count {
                for list in self.levels[level].cells.values() {
                    self.pool.scan(list, |keys, recs| {
                        for (&key, &r) in keys.iter().zip(recs) {
                            if key & FIRST_CELL == FIRST_CELL {
                                meet(r);
                            }
                        }
                    });
                }
                continue;
            }
            let scaled = self.scaled(level, &union);
            for x in clo[0]..=chi[0] {
                for y in clo[1]..=chi[1] {
                    for z in clo[2]..=chi[2] {
                        let c = [x, y, z];
                        let Some(list) = self.levels[level].cells.get(&c) else {
                            continue;
                        };
                        // A record filed in several cells is tested in one: the cell holding
                        // the low corner of its overlap with the query box, which is the
                        // record's first cell along every axis where this cell is not the
                        // query's first. (`key` is monotonic, so the cell of the larger corner
                        // is the larger of the two corners' cells.)
                        let need = !first_bits(clo, c) & 0b111;
                        lists.push((*list, probe(&clip(&scaled, c), need)));
                    }
                }
            }
        }
        // The cells' lists are found first and scanned after, for the same reason as the
        // records below: each list's first entries are a cache miss.
        let first_keys = lists
            .iter()
            .fold(0, |acc, (list, _)| acc ^ self.pool.first_key(list));
        std::hint::black_box(first_keys);
        for (list, probe) in &lists {
            self.pool.scan(list, |keys, recs| {
                for (&key, &r) in keys.iter().zip(recs) {
                    if meets(key, *probe) {
                        meet(r);
                    }
                }
            });
        }
        let first_words = met
            .iter()
            .fold(0, |acc, &r| acc ^ self.recs[r as usize].v[0]);
        std::hint::black_box(first_words);
        let crosses = met.iter().any(|&r| hits(r));
        met.clear();
        self.met = met;
        self.work.records += others;
        self.work.pairs += pairs;
        if crosses {
            Verdict::Crosses
        } else {
            Verdict::Clear
        }
    }

    /// What the queries met so far.
    pub(crate) fn work(&self) -> GuardWork {
        self.work
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
        let rec = Rec::new(v, p);
        let r = match self.free.pop() {
            Some(r) => {
                self.recs[r as usize] = rec;
                self.filed[r as usize] = NOT_FILED;
                r
            }
            None => {
                self.recs.push(rec);
                self.filed.push(NOT_FILED);
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
        let mut edges: Vec<f64> = (self.recs.iter().zip(&free))
            .filter(|(_, f)| !**f)
            .flat_map(|(rec, _)| {
                // In f64: an f32 length squares past f32's range from 1.8e19 (a volume with a
                // spacing of 1e20 had every edge infinite, its cells fell back to 1.0 and each
                // triangle was filed in billions of them: 7 GB for 500 faces).
                (0..3).map(|k| rec.p[k].as_dvec3().distance(rec.p[(k + 1) % 3].as_dvec3()))
            })
            .filter(|&d| d > 0.0)
            .collect();
        // The median edge: coincident vertices (isos on grid values) make many edges zero, and
        // a cascade's second stage starts with the first stage's first output, where a few
        // large triangles of decimated caps stand among dense ones. With the mean, raised to a
        // quarter of the longest edge against the zeros, its cells came out five times too
        // large on hydrogen at 16x, and each query read 153 records against the first stage's
        // 37 (685 against 82 at 64x).
        let mid = edges.len() / 2;
        let median = if edges.is_empty() {
            0.0
        } else {
            *edges.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        let cell = CELL_EDGES * median;
        self.cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            1.0
        };
        for (r, _) in free.iter().enumerate().filter(|(_, f)| !**f) {
            self.file(r as u32);
        }
    }

    fn key(&self, level: usize, p: DVec3) -> Cell {
        let size = self.cell * (1u64 << level) as f64;
        let k = p / size;
        // Clamped: far-out coordinates share the outermost cells instead of overflowing. The
        // floor by hand: `f64::floor` is a library call on baseline x86-64 (no SSE4.1), and
        // 2 % of a run went into it.
        let c = |x: f64| {
            let x = x.clamp(-1e9, 1e9);
            let t = x as i32;
            if f64::from(t) > x { t - 1 } else { t }
        };
        [c(k.x), c(k.y), c(k.z)]
    }

    /// `bx` in 1/256 of the cells of `level`, truncated (monotonic; see [`Quantized`]).
    fn scaled(&self, level: usize, bx: &Aabb) -> Scaled {
        let scale = 256.0 / (self.cell * (1u64 << level) as f64);
        let q = |x: f32| (f64::from(x) * scale) as i64;
        [
            q(bx.lo.x),
            q(bx.lo.y),
            q(bx.lo.z),
            q(bx.hi.x),
            q(bx.hi.y),
            q(bx.hi.z),
        ]
    }

    /// The lowest level whose cell is at least [`LEVEL_ROOM`] times the box's largest extent
    /// (so the box meets at most two cells per axis there, and usually one); for a needle, at
    /// least [`LEVEL_ROOM`] times its middle extent and its largest over [`NEEDLE_SPAN`] (two
    /// cells along two axes at most, `NEEDLE_SPAN + 1` along the third).
    fn level_of(&self, bx: &Aabb) -> usize {
        let mut level = 0;
        let mut size = self.cell;
        let (middle, largest) = bx.extents();
        let needle = largest > NEEDLE_ASPECT * middle;
        while level + 1 < LEVELS
            && if needle {
                LEVEL_ROOM * middle > size || largest > NEEDLE_SPAN * size
            } else {
                LEVEL_ROOM * largest > size
            }
        {
            size *= 2.0;
            level += 1;
        }
        level
    }

    fn file(&mut self, r: u32) {
        let bx = self.recs[r as usize].aabb();
        let level = self.level_of(&bx);
        let (lo, hi) = self.cells_of(level, &bx);
        let room = self.room(level, &bx, lo, hi);
        let l = level as u8;
        let scaled = self.scaled(level, &room);
        if self.levels.len() <= level {
            self.levels.resize_with(level + 1, Level::default);
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let c = [x, y, z];
                    let key = pack(&clip(&scaled, c), first_bits(lo, c));
                    let list = self.levels[level].cells.entry(c).or_default();
                    self.pool.push(list, key, r);
                }
            }
        }
        self.levels[level].records += 1;
        self.filed[r as usize] = Filed { level: l, room };
    }

    /// The box whose entries a record of box `bx`, filed in cells `lo..=hi` of `level`, gets:
    /// `bx` grown by [`SLACK`] of the level's cell, within those cells (shrunk from their
    /// walls by a thousandth of a cell, and `bx` itself where rounding would still take a
    /// corner into another cell), so that its corners key to `lo` and `hi` and so does any box
    /// inside it (`key` is monotonic). Growing past the cells would file the record in more of
    /// them (more entries to scan and keep: measured slower).
    fn room(&self, level: usize, bx: &Aabb, lo: Cell, hi: Cell) -> Aabb {
        let size = self.cell * (1u64 << level) as f64;
        let wall = |c: i32, up: bool| {
            let edge = f64::from(c + i32::from(up)) * size;
            let inset = if up { -1e-3 } else { 1e-3 } * size;
            (edge + inset) as f32
        };
        let cells = Aabb {
            lo: Vec3::new(wall(lo[0], false), wall(lo[1], false), wall(lo[2], false)),
            hi: Vec3::new(wall(hi[0], true), wall(hi[1], true), wall(hi[2], true)),
        };
        let grown = bx.grown((SLACK * size) as f32);
        let room = Aabb {
            lo: grown.lo.max(cells.lo).min(bx.lo),
            hi: grown.hi.min(cells.hi).max(bx.hi),
        };
        if self.cells_of(level, &room) == (lo, hi) {
            room
        } else {
            *bx
        }
    }

    /// The cells of `level` a box meets, from its low corner's to its high corner's.
    fn cells_of(&self, level: usize, bx: &Aabb) -> (Cell, Cell) {
        (
            self.key(level, bx.lo.as_dvec3()),
            self.key(level, bx.hi.as_dvec3()),
        )
    }

    /// When record `r`'s new box `bx` stays on its level and in its cells, rewrites its room
    /// in those cells.
    fn refile_in_place(&mut self, r: u32, bx: Aabb) -> bool {
        let f = self.filed[r as usize];
        if f.level == UNFILED || self.level_of(&bx) != usize::from(f.level) {
            return false;
        }
        let level = usize::from(f.level);
        let (lo, hi) = self.cells_of(level, &bx);
        if (lo, hi) != self.cells_of(level, &f.room) {
            return false;
        }
        let room = self.room(level, &bx, lo, hi);
        let scaled = self.scaled(level, &room);
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let c = [x, y, z];
                    if let Some(list) = self.levels[level].cells.get(&c)
                        && let Some(place) = self.pool.find(list, r)
                    {
                        self.pool
                            .set_key(place, pack(&clip(&scaled, c), first_bits(lo, c)));
                    }
                }
            }
        }
        self.filed[r as usize].room = room;
        true
    }

    fn unfile(&mut self, r: u32) {
        let f = self.filed[r as usize];
        if f.level == UNFILED {
            return;
        }
        let level = usize::from(f.level);
        let (lo, hi) = self.cells_of(level, &f.room);
        let cells = &mut self.levels[level].cells;
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let key = [x, y, z];
                    if let Some(list) = cells.get_mut(&key) {
                        if let Some(place) = self.pool.find(list, r) {
                            self.pool.swap_remove(list, place);
                        }
                        if list.len() == 0 {
                            cells.remove(&key);
                        }
                    }
                }
            }
        }
        self.levels[level].records -= 1;
        self.filed[r as usize] = NOT_FILED;
    }
}

/// Bit `k` set where cell `c` is `first` along axis `k`.
fn first_bits(first: Cell, c: Cell) -> u8 {
    (0..3).fold(0, |bits, k| bits | (u8::from(first[k] == c[k]) << k))
}

/// A triangle as the exact test reads it: ids (for shared corners), corners, the normal
/// `(p1 - p0) x (p2 - p0)` and the rounding bound of its plane tests, computed once per
/// triangle rather than once per pair.
#[derive(Debug, Clone, Copy)]
struct Tri64 {
    v: [u64; 3],
    p: [DVec3; 3],
    n: DVec3,
    /// `ORIENT_ERROR |p1 - p0|_1 |p2 - p0|_1`: times `|x - p0|_1`, it bounds the rounding error
    /// of `n . (x - p0)` (see [`isostream_meshcheck::orient`]).
    err: f64,
}

impl Tri64 {
    fn new(v: [u64; 3], p: [DVec3; 3]) -> Self {
        let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
        Self {
            v,
            p,
            n: e1.cross(e2),
            err: isostream_meshcheck::ORIENT_ERROR * norm1(e1) * norm1(e2),
        }
    }

    /// Which side of this triangle's plane `x` lies on, exactly: `1` above, `-1` below, `0` on
    /// it: the sign of `orient(p0, p1, p2, x)`, the referee's `o1`/`o2`. The stored normal
    /// decides unless the point is within rounding of the plane; then the exact predicate does.
    #[inline(always)]
    fn side(&self, x: DVec3) -> i8 {
        let d = x - self.p[0];
        let s = d.dot(self.n);
        let bound = self.err * norm1(d);
        if s > bound {
            1
        } else if -s > bound {
            -1
        } else {
            self.side_exact(x)
        }
    }

    /// [`Tri64::side`] within rounding of the plane: touching configurations, and points
    /// exactly on the plane, which [`Tri64::on_plane_by_coordinates`] tells first.
    #[cold]
    #[inline(never)]
    fn side_exact(&self, x: DVec3) -> i8 {
        if self.on_plane_by_coordinates(x) {
            return 0;
        }
        sign(orient(self.p[0], self.p[1], self.p[2], x))
    }

    /// Whether equal coordinates alone put `x` exactly on this triangle's plane: when two
    /// corners differ along one axis only, the plane holds that axis, and so every point
    /// that differs from a corner along that axis only (two equal corners make the triangle
    /// degenerate, and `orient` 0 for every point); when all three corners share a
    /// coordinate, so does every point of their plane. Upsampled surfaces are full of such
    /// points: on hydrogen at 16x, 98.5 % of the 16.75 M points the filter left to the exact
    /// predicate (all of them exactly on the plane) were one of these, and each cost an
    /// exact determinant where this costs a few comparisons.
    fn on_plane_by_coordinates(&self, x: DVec3) -> bool {
        let p = &self.p;
        (0..3).any(|a| {
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            let beside = |u: DVec3, w: DVec3| u[b] == w[b] && u[c] == w[c];
            let along = (0..3).any(|i| beside(p[i], p[(i + 1) % 3]));
            (along && p.iter().any(|&q| beside(q, x))) || p.iter().all(|q| q[a] == x[a])
        })
    }
}

fn norm1(x: DVec3) -> f64 {
    x.abs().element_sum()
}

fn sign(x: f64) -> i8 {
    i8::from(x > 0.0) - i8::from(x < 0.0)
}

/// The sign of `(b - a) . ((c - a) x (d - a))`, exactly: the referee's predicate
/// ([`isostream_meshcheck::orient`]), so that the guard and the referee agree on every
/// configuration, touching ones included (coincident vertices with distinct ids: the `f64`
/// determinant's rounding once let the referee count such a pair as crossing).
fn orient(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> f64 {
    isostream_meshcheck::orient(a.to_array(), b.to_array(), c.to_array(), d.to_array())
}

/// The rest of the referee's closed predicate once `p` and `q` are known not to lie strictly on
/// one side of `t`'s plane, nor both on it: the segment meets the plane at one point, which lies
/// in the closed triangle iff `orient(p, q, a, b)`, `orient(p, q, b, c)` and `orient(p, q, c, a)`
/// are never of opposite signs (a zero puts it on an edge's line). With `d = q - p` and `w_x =
/// x - p`, `orient(p, q, x, y) = (d x w_x) . w_y`: three cross products serve the three signs,
/// and the second sign often settles it.
fn meets_planar(p: DVec3, q: DVec3, t: &Tri64) -> bool {
    let d = q - p;
    let w = t.p.map(|x| x - p);
    let nd = norm1(d);
    let nw = w.map(norm1);
    let sign_of = |i: usize, j: usize| {
        let det = d.cross(w[i]).dot(w[j]);
        let norms = nd * nw[i] * nw[j];
        sign(isostream_meshcheck::certify(
            det,
            norms,
            [p, q, t.p[i], t.p[j]].map(|x| x.to_array()),
        ))
    };
    let s0 = sign_of(0, 1);
    let s1 = sign_of(1, 2);
    if s0 * s1 < 0 {
        return false;
    }
    let s2 = sign_of(2, 0);
    s0 * s2 >= 0 && s1 * s2 >= 0
}

/// Whether the closed segment from `p` to `q`, its ends on sides `sp` and `sq` of `t`'s plane,
/// meets the closed triangle `t` (the referee's [`isostream_meshcheck::segment_meets_triangle`]).
fn edge_meets(p: DVec3, q: DVec3, [sp, sq]: [i8; 2], t: &Tri64) -> bool {
    if sp * sq > 0 {
        false
    } else if sp == 0 && sq == 0 {
        in_plane_edge_meets(p, q, t)
    } else {
        meets_planar(p, q, t)
    }
}

/// [`edge_meets`] for a segment in the triangle's plane: the referee's test in two dimensions.
/// Rare but for flat parts of a surface, where neighbouring triangles share a plane.
#[cold]
#[inline(never)]
fn in_plane_edge_meets(p: DVec3, q: DVec3, t: &Tri64) -> bool {
    isostream_meshcheck::coplanar_segment_meets_triangle(
        p.to_array(),
        q.to_array(),
        t.p.map(|x| x.to_array()),
    )
}

/// [`cross`] for a fan triangle `t` (the new vertex first) and another triangle `u`, with the
/// new vertex's side of `u`'s plane (`apex`) computed once for all fan triangles. The pairs that
/// matter are the fan against its neighbours, which share one ring vertex with it: one of the
/// far corners of `t` is then the new vertex, whose side is already known. Same answers as
/// `cross` (same segments, same directions).
fn crosses_fan(t: &Tri64, apex: i8, u: &Tri64) -> bool {
    if u.v.contains(&t.v[0]) {
        return cross(t, u);
    }
    let shared = |x: u64| u.v.iter().position(|&y| y == x);
    match (shared(t.v[1]), shared(t.v[2])) {
        // A neighbour across the fan's far edge: folded onto it when in one plane with it.
        (Some(j1), Some(j2)) if j1 != j2 => apex == 0 && folded_onto(t, 0, u.p[3 - j1 - j2]),
        (Some(_), Some(_)) => false,
        (Some(j), None) => cross_at_corner(t, 1, [u.side(t.p[2]), apex], u, j),
        (None, Some(j)) => cross_at_corner(t, 2, [apex, u.side(t.p[1])], u, j),
        (None, None) => cross_apart(t, [apex, u.side(t.p[1]), u.side(t.p[2])], u),
    }
}

/// Two triangles with no common corner, `sides` holding `tb`'s side of each corner of `ta`:
/// they meet iff an edge of one meets the other (closed: touching counts). A triangle strictly
/// on one side of the other's plane cannot meet it, so the six plane tests come first and most
/// pairs stop there; the edge tests then reuse them.
fn cross_apart(ta: &Tri64, sides: [i8; 3], tb: &Tri64) -> bool {
    let one_side = |s: [i8; 3]| s[0] != 0 && s[0] == s[1] && s[0] == s[2];
    if one_side(sides) {
        return false;
    }
    let back = tb.p.map(|x| ta.side(x));
    if one_side(back) {
        return false;
    }
    // Edge `i` of `p` (from corner `i` to the next), its corners' sides `s` of `other`.
    let edge = |s: [i8; 3], p: &[DVec3; 3], other: &Tri64, i: usize| {
        let j = (i + 1) % 3;
        edge_meets(p[i], p[j], [s[i], s[j]], other)
    };
    (0..3).any(|i| edge(sides, &ta.p, tb, i)) || (0..3).any(|i| edge(back, &tb.p, ta, i))
}

/// Two triangles sharing one corner, `ta`'s `i` and `tb`'s `j`, meet elsewhere iff the edge
/// opposite it in one meets the other (the referee's rule). `sides` holds `tb`'s side of `ta`'s
/// far corners `i + 1` and `i + 2`. When either triangle's far corners lie strictly on one side
/// of the other's plane, the two meet at the shared corner only: both such certificates (four
/// plane tests) come before any edge test, which most neighbour pairs then never reach.
fn cross_at_corner(ta: &Tri64, i: usize, sides: [i8; 2], tb: &Tri64, j: usize) -> bool {
    let one_side = |s: [i8; 2]| s[0] != 0 && s[0] == s[1];
    if one_side(sides) {
        return false;
    }
    let (q1, q2) = (tb.p[(j + 1) % 3], tb.p[(j + 2) % 3]);
    let back = [ta.side(q1), ta.side(q2)];
    if one_side(back) {
        return false;
    }
    edge_meets(ta.p[(i + 1) % 3], ta.p[(i + 2) % 3], sides, tb) || edge_meets(q1, q2, back, ta)
}

/// Whether two triangles cross (see the module documentation for common vertices).
fn cross(ta: &Tri64, tb: &Tri64) -> bool {
    let mut shared = None;
    let mut count = 0;
    for (i, x) in ta.v.iter().enumerate() {
        for (j, y) in tb.v.iter().enumerate() {
            if x == y {
                shared = Some((i, j));
                count += 1;
            }
        }
    }
    let a = &ta.p;
    match (count, shared) {
        (0, _) => cross_apart(ta, a.map(|x| tb.side(x)), tb),
        (1, Some((i, j))) => {
            let sides = [tb.side(a[(i + 1) % 3]), tb.side(a[(i + 2) % 3])];
            cross_at_corner(ta, i, sides, tb, j)
        }
        (2, _) => {
            // The corner of each off the shared edge.
            let off = |t: &Tri64, o: &Tri64| (0..3).find(|&k| !o.v.contains(&t.v[k]));
            match (off(ta, tb), off(tb, ta)) {
                (Some(i), Some(j)) => tb.side(a[i]) == 0 && folded_onto(ta, i, tb.p[j]),
                _ => false,
            }
        }
        _ => false,
    }
}

/// Whether `t`, whose corner `i` is off the edge it shares with a neighbour whose other corner
/// is `w` (on `t`'s plane: the caller knows), is folded onto that neighbour (the referee's
/// [`isostream_meshcheck::folded`]). Rare: neighbours in one plane, on flat parts.
#[cold]
#[inline(never)]
fn folded_onto(t: &Tri64, i: usize, w: DVec3) -> bool {
    let (u, v) = (t.p[(i + 1) % 3], t.p[(i + 2) % 3]);
    isostream_meshcheck::folded(u.to_array(), v.to_array(), t.p[i].to_array(), w.to_array())
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// An update within a record's room leaves the index as it was, one past it refiles the
    /// record, and either way the record is found by a query over its new box alone.
    #[test]
    fn updates_within_the_room_keep_the_entries() {
        let mut ix = TriIndex::default();
        let t = right_triangle();
        ix.insert(0, [0, 1, 2], t);
        ix.fix_cell();
        let entries = |ix: &TriIndex| {
            let mut e: Vec<_> = (ix.levels.iter().enumerate())
                .flat_map(|(i, level)| {
                    level
                        .cells
                        .iter()
                        .map(move |(c, l)| (i, *c, ix.pool.first_key(l)))
                })
                .collect();
            e.sort_unstable();
            e
        };
        let before = entries(&ix);
        let room = ix.filed[0].room;
        assert!(room.contains(&ix.recs[0].aabb()));
        // A corner moved by a hundredth of a cell stays within the room (slack is a sixteenth).
        let nudge = DVec3::splat(ix.cell * 0.01);
        let moved = [t[0] + nudge, t[1], t[2]];
        ix.update(0, [0, 1, 2], moved);
        assert_eq!(entries(&ix), before, "no change of the index");
        assert!(room.contains(&ix.recs[0].aabb()));
        let far = [t[0], t[1], t[2] + DVec3::splat(3.0 * ix.cell)];
        ix.update(0, [0, 1, 2], far);
        assert!(ix.filed[0].room.contains(&ix.recs[0].aabb()));
        assert_ne!(entries(&ix), before, "refiled");
        for corners in [moved, far] {
            ix.update(0, [0, 1, 2], corners);
            // A fan from a far vertex whose triangle pierces the record's new place.
            let mid = (corners[0] + corners[1] + corners[2]) / 3.0;
            let n = (corners[1] - corners[0])
                .cross(corners[2] - corners[0])
                .normalize();
            let patch = Patch::of(smallvec::smallvec![crate::topology::PatchTri {
                v: [10, 11, 12],
                p: [
                    mid + n * 100.0,
                    mid - n + DVec3::X * 0.01,
                    mid - n - DVec3::Y * 0.01
                ],
            }]);
            let verdict = ix.would_intersect(&patch, 10, 20, 10, mid + n);
            assert_eq!(verdict, Verdict::Crosses);
        }
    }

    /// Legs of 2 along x and y at the origin.
    fn right_triangle() -> [DVec3; 3] {
        [
            DVec3::ZERO,
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        ]
    }

    fn filed(ix: &TriIndex) -> usize {
        ix.levels
            .iter()
            .flat_map(|l| l.cells.values())
            .map(CellList::len)
            .sum()
    }

    /// Cells in use, over every level.
    fn cells(ix: &TriIndex) -> usize {
        ix.levels.iter().map(|l| l.cells.len()).sum()
    }

    #[test]
    fn crossing_and_touching_triangles() {
        let t = right_triangle();
        let s = [
            DVec3::new(0.5, 0.5, -1.0),
            DVec3::new(0.5, 0.5, 1.0),
            DVec3::new(3.0, 3.0, 0.5),
        ];
        let tri = Tri64::new;
        assert!(cross(&tri([0, 1, 2], t), &tri([3, 4, 5], s)));
        assert!(!cross(
            &tri([0, 1, 2], t),
            &tri([3, 4, 5], s.map(|p| p + DVec3::X * 10.0))
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
        assert!(cross(&tri([0, 1, 2], g), &tri([0, 3, 4], f)));
        assert!(!cross(
            &tri([0, 1, 2], g),
            &tri([0, 3, 4], f.map(|p| p + DVec3::Z * 2.0))
        ));
    }

    #[test]
    fn the_index_follows_inserts_updates_and_removals() {
        let mut ix = TriIndex::default();
        let t = right_triangle();
        ix.insert(0, [0, 1, 2], t);
        ix.fix_cell();
        assert!(ix.cell > 0.0);
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

    /// Fuzzing bug: at a spacing of 1e20 every edge's f32 length was infinite, the cells fell
    /// back to 1.0 and a triangle was filed in billions of them (7 GB for 500 faces). The cells
    /// follow the edges at any scale f32 holds.
    #[test]
    fn cells_follow_the_edges_at_any_scale() {
        for scale in [1e-30, 1.0, 1e20, 1e35] {
            let mut ix = TriIndex::default();
            let t = right_triangle().map(|p| p * scale);
            ix.insert(0, [0, 1, 2], t);
            ix.insert(1, [3, 4, 5], t.map(|p| p + DVec3::Z * scale));
            ix.fix_cell();
            let ratio = ix.cell / scale;
            assert!(
                (0.1..100.0).contains(&ratio),
                "scale {scale}: cell {}",
                ix.cell
            );
            assert!(cells(&ix) <= 16, "scale {scale}: {} cells", cells(&ix));
        }
    }

    #[test]
    fn a_large_triangle_takes_few_cells_on_a_higher_level() {
        let mut ix = TriIndex::default();
        let t = right_triangle();
        ix.insert(0, [0, 1, 2], t);
        ix.fix_cell();
        ix.insert(1, [3, 4, 5], t.map(|p| p * 1000.0 + DVec3::Z));
        assert!(filed(&ix) <= 16, "{} cells", filed(&ix));
        assert!(ix.filed[1].level > ix.filed[0].level);
        ix.remove(1);
        assert_eq!(ix.levels.iter().map(|l| l.records).sum::<usize>(), 1);
    }

    /// A needle (60 long, at most 0.5 wide) is filed at the level of its width, in several
    /// cells along its length, not in one cell of a level as wide as it is long; a fan
    /// crossing it anywhere finds it, and reads it once however many of its cells the fan's
    /// box meets.
    #[test]
    fn a_needle_is_filed_by_its_width_along_its_length_and_found_once() {
        let mut ix = TriIndex::default();
        row(&mut ix, 0, 20, 0.0);
        ix.fix_cell();
        let needle = [
            DVec3::new(0.0, 5.0, -30.0),
            DVec3::new(0.5, 5.0, -30.0),
            DVec3::new(0.25, 5.0, 30.0),
        ];
        ix.insert(20, [500, 501, 502], needle);
        let f = ix.filed[20];
        let level = usize::from(f.level);
        let size = ix.cell * f64::from(1u32 << level);
        // Filed by its length, its cells would be at least 120 wide (`LEVEL_ROOM`).
        assert!(size <= 16.0, "cells of {size} for a needle of 60");
        let (lo, hi) = ix.cells_of(level, &f.room);
        assert!(hi[2] - lo[2] >= 3 && hi[0] - lo[0] <= 1, "{lo:?} {hi:?}");
        for z in [-25.0, -2.0, 0.0, size, 20.0] {
            // A fan in the plane x = 0.25 through the needle's plane y = 5 at height z, across
            // a cell wall when z = 0 or `size` (its box then meets two of the needle's cells).
            let v = [1_000_000, 1_000_001, 1_000_002];
            let p = [
                DVec3::new(0.25, 5.0, z + 10.0),
                DVec3::new(0.25, 4.0, z - 0.5),
                DVec3::new(0.25, 6.0, z - 0.5),
            ];
            let before = ix.work().records;
            let top = DVec3::new(0.25, 5.0, z + 0.5);
            assert_eq!(move_corner(&mut ix, v, p, top), Verdict::Crosses, "at {z}");
            assert_eq!(ix.work().records - before, 1, "the needle once, at {z}");
            let beside = p.map(|x| x + DVec3::Y * 2.0);
            assert_eq!(
                move_corner(&mut ix, v, beside, top + DVec3::Y * 2.0),
                Verdict::Clear
            );
        }
    }

    /// A fan whose box spans more cells of level 0 than the level has records reads that
    /// level's records from its own cells, each once (a record straddling two cells too), and
    /// still finds the one it pierces.
    #[test]
    fn a_query_wider_than_its_level_reads_each_record_of_the_level_once() {
        let mut ix = TriIndex::default();
        let n = 20;
        row(&mut ix, 0, n, 0.0);
        ix.fix_cell();
        let far = right_triangle().map(|p| p * 100.0 - DVec3::Z * 500.0);
        ix.insert(n, [900_000, 900_001, 900_002], far);
        assert!(ix.filed[n as usize].level > 0);
        let cell_x = |x: f32| (f64::from(x) / ix.cell).floor();
        assert!(
            (0..n as usize).any(|r| cell_x(ix.filed[r].room.lo.x) != cell_x(ix.filed[r].room.hi.x)),
            "a record in two cells (cells of {})",
            ix.cell
        );
        // A tall thin fan over the whole row, coming down through its last triangle or not.
        let last = 3.0 * f64::from(n - 1);
        let fan = |z: f64| {
            let v = [1_000_000, 1_000_001, 1_000_002];
            let p = [
                DVec3::new(-1.0, 0.5, 0.0),
                DVec3::new(last + 0.5, 0.4, z),
                DVec3::new(last + 0.5, 0.6, z),
            ];
            (v, p)
        };
        let top = DVec3::new(-1.0, 0.5, 400.0);
        let (v, p) = fan(0.5);
        assert_eq!(move_corner(&mut ix, v, p, top), Verdict::Clear);
        // The far record's level is read whole too (the fan's box spans more of its cells than
        // it has records), and a record met is counted whether or not its box meets the fan's.
        assert_eq!(ix.work().records, u64::from(n) + 1, "each record once");
        let (v, p) = fan(-1.0);
        assert_eq!(move_corner(&mut ix, v, p, top), Verdict::Crosses);
    }

    /// The plain test the packed [`meets`] replaces: two quantized boxes of a cell meet.
    fn quantized_meet(a: &Quantized, b: &Quantized) -> bool {
        (0..3).all(|k| a[k] <= b[k + 3] && a[k + 3] >= b[k])
    }

    /// Points on a coarse lattice with a fine offset on one axis now and then: equal
    /// coordinates everywhere, as on upsampled surfaces.
    fn lattice_point() -> impl Strategy<Value = DVec3> {
        (prop::array::uniform3(-2i8..=2), 0usize..4, -3i8..=3).prop_map(|(c, axis, fine)| {
            let mut p = DVec3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2]));
            if axis < 3 {
                p[axis] += f64::from(fine) * 0.375;
            }
            p
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4096))]
        /// The coordinate shortcut never says "on the plane" where the exact predicate does
        /// not, and the exact side is the referee's sign.
        #[test]
        fn the_coordinate_shortcut_agrees_with_the_exact_predicate(
            p in prop::array::uniform3(lattice_point()),
            x in lattice_point(),
        ) {
            let t = Tri64::new([0, 1, 2], p);
            let exact = sign(orient(p[0], p[1], p[2], x));
            if t.on_plane_by_coordinates(x) {
                prop_assert_eq!(exact, 0);
            }
            prop_assert_eq!(t.side_exact(x), exact);
            prop_assert_eq!(t.side(x), exact);
        }
    }

    proptest! {
        #[test]
        fn the_packed_test_is_the_box_and_first_cell_test(
            a in prop::array::uniform6(0u8..=255),
            b in prop::array::uniform6(0u8..=255),
            first in 0u8..8,
            need in 0u8..8,
        ) {
            let plain = first & need == need && quantized_meet(&a, &b);
            prop_assert_eq!(meets(pack(&a, first), probe(&b, need)), plain);
        }
    }

    fn a_box() -> impl Strategy<Value = Aabb> {
        let corner = || prop::array::uniform3(-50.0f32..50.0);
        (corner(), prop::array::uniform3(0.0f32..8.0)).prop_map(|(lo, size)| {
            let lo = Vec3::from(lo);
            Aabb {
                lo,
                hi: lo + Vec3::from(size),
            }
        })
    }

    proptest! {
        #[test]
        fn the_wide_box_test_is_the_box_test(a in a_box(), b in a_box(), touch in any::<bool>()) {
            // Touching boxes half the time: equal faces are where the two could differ.
            let b = if touch { Aabb { lo: Vec3::new(a.hi.x, b.lo.y, b.lo.z), ..b } } else { b };
            prop_assert_eq!(Wide::of(&a).meets(&Wide::of(&b)), a.overlaps(&b));
        }

        /// The query's one-cell rule and the quantized filter together: two boxes that meet
        /// meet, quantized, in the cell of the low corner of their overlap, which both are
        /// filed in (so no record the exact test needs is skipped).
        #[test]
        fn boxes_that_meet_meet_quantized_in_their_first_common_cell(
            a in a_box(),
            b in a_box(),
            level in 0usize..5,
        ) {
            // `b` moved next to `a`, so that most pairs meet.
            let b = Aabb { lo: b.lo * 0.1 + a.lo, hi: b.hi - b.lo + b.lo * 0.1 + a.lo };
            let ix = TriIndex { cell: 0.7, ..TriIndex::default() };
            prop_assume!(a.overlaps(&b));
            let c = ix.key(level, a.lo.max(b.lo).as_dvec3());
            for bx in [a, b] {
                let (lo, hi) = (ix.key(level, bx.lo.as_dvec3()), ix.key(level, bx.hi.as_dvec3()));
                prop_assert!((0..3).all(|k| lo[k] <= c[k] && c[k] <= hi[k]), "filed in the cell");
            }
            let (qa, qb) = (clip(&ix.scaled(level, &a), c), clip(&ix.scaled(level, &b), c));
            prop_assert!(quantized_meet(&qa, &qb));
            prop_assert!(meets(pack(&qa, 0), probe(&qb, 0)));
        }
    }

    proptest! {
        /// The guard's tests (`cross`, and `crosses_fan` with the apex's side computed once)
        /// give the referee's answer on every pair, touching ones included: corners on a coarse
        /// grid of inexact `f64` steps make coincident corners, coplanar quadruples and rounding
        /// in the determinants common.
        #[test]
        fn the_guard_agrees_with_the_referee(
            grid in prop::collection::vec((0u8..4, 0u8..4, 0u8..4), 6),
            shared in 0usize..13,
        ) {
            let p: Vec<DVec3> = grid
                .iter()
                .map(|&(x, y, z)| DVec3::new(f64::from(x), f64::from(y), f64::from(z)) * 0.1)
                .collect();
            // No shared index (9); one, corner `i` of the first as corner `j` of the second, so
            // that `crosses_fan` meets its shared-ring-corner branches too (with `i = 0` the
            // shared corner is the fan's apex); or an edge (10 to 12: folds).
            let ia = [0u32, 1, 2];
            let mut ib = [3u32, 4, 5];
            if shared < 9 {
                ib[shared % 3] = ia[shared / 3];
            } else if shared > 9 {
                // Neighbours across edge `e` of the first, traversed the other way.
                let e = shared - 10;
                ib = [ia[(e + 1) % 3], ia[e], 5];
            }
            let at = |i: [u32; 3]| i.map(|k| p[k as usize]);
            let referee = isostream_meshcheck::triangles_meet(
                ia,
                at(ia).map(|x| x.to_array()),
                ib,
                at(ib).map(|x| x.to_array()),
            );
            let ta = Tri64::new(ia.map(u64::from), at(ia));
            let tb = Tri64::new(ib.map(u64::from), at(ib));
            prop_assert_eq!(cross(&ta, &tb), referee);
            prop_assert_eq!(cross(&tb, &ta), referee);
            prop_assert_eq!(crosses_fan(&ta, tb.side(ta.p[0]), &tb), referee);
            prop_assert_eq!(crosses_fan(&tb, ta.side(tb.p[0]), &ta), referee);
        }
    }

    /// `n` separate right triangles in a row at height `z`, store slots and ids from `first`.
    fn row(ix: &mut TriIndex, first: u32, n: u32, z: f64) {
        for i in 0..n {
            let at = DVec3::new(3.0 * f64::from(i), 0.0, z);
            let id = 3 * u64::from(first + i);
            ix.insert(
                first + i,
                [id, id + 1, id + 2],
                right_triangle().map(|p| p + at),
            );
        }
    }

    /// The patch of one store triangle whose corner `v[0]` is contracted away to `pos`.
    fn move_corner(ix: &mut TriIndex, v: [u64; 3], p: [DVec3; 3], pos: DVec3) -> Verdict {
        let patch = Patch::of([crate::topology::PatchTri { v, p }].into_iter().collect());
        ix.would_intersect(&patch, v[0], u64::MAX, u64::MAX, pos)
    }

    #[test]
    fn ghosts_below_every_resident_triangle_are_dropped_and_their_region_refused() {
        let mut ix = TriIndex::default();
        let live = right_triangle().map(|p| p + DVec3::new(0.0, 10.0, 10.0));
        ix.insert(5000, [90_000, 90_001, 90_002], live);
        let n = SAMPLE as u32 + 100;
        row(&mut ix, 0, n, 0.0);
        ix.fix_cell();
        for t in 0..n {
            ix.emit(t);
        }
        let region = ix.unguarded.expect("ghosts were dropped");
        assert!(region.hi.z < 10.0 && ix.ghosts.len() < n as usize);
        // A corner of the resident triangle moved down into the dropped row's box: refused,
        // though nothing the index still holds is crossed.
        let down = DVec3::new(1.0, 1.0, 0.0);
        let verdict = move_corner(&mut ix, [90_000, 90_001, 90_002], live, down);
        assert_eq!(verdict, Verdict::Unguarded);
        let near = live[0] + DVec3::new(0.1, 0.1, 0.5);
        let verdict = move_corner(&mut ix, [90_000, 90_001, 90_002], live, near);
        assert_eq!(verdict, Verdict::Clear);
    }

    /// A fan moved through a triangle below it: one query, the obstacle read once and tested
    /// against the fan's one triangle; a fan far from everything reads nothing.
    #[test]
    fn queries_count_the_records_and_pairs_they_meet() {
        let mut ix = TriIndex::default();
        let fan = right_triangle().map(|p| p + DVec3::Z);
        ix.insert(
            0,
            [0, 1, 2],
            right_triangle().map(|p| p + DVec3::new(0.2, 0.2, 0.0)),
        );
        ix.insert(1, [3, 4, 5], fan);
        ix.fix_cell();
        let through = DVec3::new(0.5, 0.5, -1.0);
        assert_eq!(
            move_corner(&mut ix, [3, 4, 5], fan, through),
            Verdict::Crosses
        );
        let work = ix.work();
        assert_eq!((work.queries, work.records, work.pairs), (1, 1, 1));
        let away = fan.map(|p| p + DVec3::X * 100.0);
        ix.update(1, [3, 4, 5], away);
        let beside = away[0] + DVec3::new(0.1, 0.1, 0.1);
        assert_eq!(
            move_corner(&mut ix, [3, 4, 5], away, beside),
            Verdict::Clear
        );
        let work = ix.work();
        assert_eq!((work.queries, work.records, work.pairs), (2, 1, 1));
    }

    #[test]
    fn ghosts_within_reach_of_a_resident_triangle_are_kept() {
        let mut ix = TriIndex::default();
        let n = SAMPLE as u32 + 100;
        // Resident triangles at height 0, enough that the limit holds every ghost.
        row(&mut ix, 0, n / GHOST_LIMIT as u32 + 1, 0.0);
        row(&mut ix, 10_000, n, 0.5);
        ix.fix_cell();
        for t in 10_000..10_000 + n {
            ix.emit(t);
        }
        assert_eq!(ix.ghosts.len(), n as usize);
        assert!(ix.unguarded.is_none());
    }

    #[test]
    fn updates_before_the_cell_is_fixed_file_nothing() {
        // A coincident merge may update records before any query fixed the cell: filing then
        // divided by a zero cell and put one triangle in billions of cells.
        let mut ix = TriIndex::default();
        let t = right_triangle();
        ix.insert(0, [0, 1, 2], t);
        ix.update(0, [0, 1, 3], t.map(|p| p + DVec3::X));
        assert_eq!(cells(&ix), 0);
        ix.fix_cell();
        assert!(cells(&ix) > 0 && cells(&ix) < 64);
    }

    #[test]
    fn a_degenerate_record_puts_everything_on_its_plane_yet_its_edge_may_cross() {
        // The record has two coincident corners (distinct ids): every point is at side 0 of
        // it, which for a real plane would mean the pair is coplanar and cannot cross.
        let p = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) * 0.1;
        let ta = Tri64::new(
            [0, 1, 2],
            [p(0.0, 2.0, 1.0), p(0.0, 3.0, 3.0), p(2.0, 2.0, 0.0)],
        );
        let tb = Tri64::new(
            [3, 4, 5],
            [p(1.0, 0.0, 0.0), p(0.0, 3.0, 2.0), p(0.0, 3.0, 2.0)],
        );
        assert_eq!(ta.p.map(|x| tb.side(x)), [0; 3]);
        let referee = isostream_meshcheck::triangles_meet(
            [0, 1, 2],
            ta.p.map(|x| x.to_array()),
            [3, 4, 5],
            tb.p.map(|x| x.to_array()),
        );
        assert!(referee);
        assert!(cross(&ta, &tb));
        assert!(crosses_fan(&ta, tb.side(ta.p[0]), &tb));
    }

    #[test]
    fn the_cell_follows_the_common_triangles_not_the_few_large_or_degenerate_ones() {
        // What a cascade's second stage first sees: dense triangles, a tenth of them collapsed
        // to a point (coincident vertices), and a few large ones of a decimated cap.
        let mut ix = TriIndex::default();
        let t = right_triangle();
        let n = SAMPLE as u32;
        for i in 0..n {
            let at = DVec3::new(3.0 * f64::from(i), 0.0, 0.0);
            let scale = match i % 100 {
                0 => 50.0,
                1..=10 => 0.0,
                _ => 1.0,
            };
            let id = 3 * u64::from(i);
            ix.insert(i, [id, id + 1, id + 2], t.map(|p| at + scale * p));
        }
        assert!(ix.cell > 0.0, "fixed once the sample is in");
        let common = CELL_EDGES * t[0].distance(t[1]).min(t[1].distance(t[2]));
        assert!(
            ix.cell >= common && ix.cell <= 2.0 * common,
            "cell {} for edges of {}",
            ix.cell,
            common / CELL_EDGES
        );
    }
}
