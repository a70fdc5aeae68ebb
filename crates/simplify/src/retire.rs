//! Retirement and emission in compact pre-order.
//!
//! A vertex retires when its highest preimage rank falls `retire_lag` slabs behind the front, or
//! early when the memory budget is exceeded (oldest first). Only modifiable vertices retire: a
//! vertex that may still receive triangles could not be finalized. A triangle is emitted once its
//! three vertices are retired; each vertex goes out right before its first triangle, and is freed
//! with `last_use` set on its last one (Isenburg and Lindstrom's streaming meshes).

use std::collections::VecDeque;

use crate::band::Band;
use crate::store::{Store, TriId};
use crate::{Cascade, OutBatch, OutElement, SimplifyStats};

/// Vertices filed by highest rank in a ring of per-rank lists. A contraction that raises a
/// vertex's rank files it again; the old entry goes stale and is skipped (the vertex records its
/// current bucket).
///
/// Stale entries (vertices contracted away, filed again, retired) are dropped whenever they
/// outnumber the live vertices ([`COMPACT_SHARE`]): in rate mode the buckets are popped only by
/// the memory budget, so without that they held an entry for every vertex the run ever added
/// (22 MiB of a 107 MiB run at 511^3, growing with the surface instead of the band).
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct RankBuckets {
    base: u32,
    lists: VecDeque<Vec<u64>>,
    /// Entries in `lists`, stale ones included.
    entries: usize,
}

/// The buckets are compacted when they hold more than this many entries per live vertex (and
/// [`COMPACT_MIN`]): the compaction's cost, linear in the entries, is paid once per that many
/// pushes, and the buckets stay within this multiple of the resident vertices.
const COMPACT_SHARE: usize = 2;
const COMPACT_MIN: usize = 4096;

impl RankBuckets {
    /// Files `id` under `rank`, clamped to the oldest open bucket.
    pub(crate) fn push(&mut self, rank: u32, id: u64, store: &mut Store) {
        if self.lists.is_empty() {
            self.base = rank;
        }
        let key = rank.max(self.base);
        let i = (key - self.base) as usize;
        if self.lists.len() <= i {
            self.lists.resize_with(i + 1, Vec::new);
        }
        self.lists[i].push(id);
        self.entries += 1;
        if let Some(v) = store.vertex_mut(id) {
            v.bucket = key;
        }
        if self.entries > (COMPACT_SHARE * store.live_vertices()).max(COMPACT_MIN) {
            self.compact(store);
        }
    }

    /// Drops the stale entries, keeping the others in order (so the buckets pop the same live
    /// vertices in the same order), and gives their memory back. An entry that is stale stays
    /// stale: a vertex is filed again only under a higher key, retirement and removal are final,
    /// and a reused slot has a new handle.
    fn compact(&mut self, store: &Store) {
        let base = self.base;
        for (key, list) in (base..).zip(self.lists.iter_mut()) {
            list.retain(|&id| is_filed(store, id, key));
            list.shrink_to_fit();
        }
        self.entries = self.lists.iter().map(Vec::len).sum();
    }

    /// The oldest bucket, if its rank is below `limit`.
    fn pop_below(&mut self, limit: u32) -> Option<(u32, Vec<u64>)> {
        if self.base >= limit {
            return None;
        }
        let ids = self.lists.pop_front()?;
        self.entries -= ids.len();
        let key = self.base;
        self.base += 1;
        Some((key, ids))
    }

    /// Puts back the unprocessed rest of the bucket just popped.
    fn restore(&mut self, key: u32, ids: Vec<u64>) {
        self.entries += ids.len();
        self.lists.push_front(ids);
        self.base = key;
    }
}

/// A bucket entry is current when the vertex lives, is unretired and still filed there.
fn is_filed(store: &Store, id: u64, key: u32) -> bool {
    store.vertex(id).is_some_and(|v| v.bucket == key) && !store.is_retired(id)
}

/// Retirement and emission: what leaves the band, in streaming order. It owns only the output's
/// numbering and the vertices due before they could leave; the band's rank buckets say who is
/// oldest.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Retirer {
    /// Vertices due to retire that were not modifiable yet (they retire at the next call).
    deferred: Vec<u64>,
    /// The next output vertex number.
    next_out: u64,
    /// A cascade's first stage: each written vertex carries its state for the second.
    states: bool,
}

impl Retirer {
    pub(crate) fn new(cascade: Cascade) -> Self {
        Self {
            states: cascade == Cascade::First,
            ..Self::default()
        }
    }

    /// Retires the vertices with `rank_max < limit`, and the earlier ones that were due but not
    /// yet modifiable.
    pub(crate) fn retire_below(
        &mut self,
        band: &mut Band,
        limit: u32,
        out: &mut OutBatch,
        stats: &mut SimplifyStats,
    ) {
        self.retire_deferred(band, out, stats);
        while let Some((key, ids)) = band.buckets.pop_below(limit) {
            for id in ids {
                if is_filed(&band.store, id, key) {
                    self.try_retire(band, id, out, stats);
                }
            }
        }
    }

    /// Retires the oldest vertices with `rank_max < limit` until at most `goal` faces are
    /// resident (or nothing is left to retire), the deferred ones first.
    pub(crate) fn retire_until(
        &mut self,
        band: &mut Band,
        goal: usize,
        limit: u32,
        out: &mut OutBatch,
        stats: &mut SimplifyStats,
    ) {
        self.retire_deferred(band, out, stats);
        while band.resident() > goal {
            let Some((key, ids)) = band.buckets.pop_below(limit) else {
                break;
            };
            let mut ids = ids.into_iter();
            for id in ids.by_ref() {
                if is_filed(&band.store, id, key) && self.try_retire(band, id, out, stats) {
                    stats.forced_retirements += 1;
                }
                if band.resident() <= goal {
                    break;
                }
            }
            let rest: Vec<u64> = ids.collect();
            if !rest.is_empty() {
                band.buckets.restore(key, rest);
            }
        }
    }

    /// Retires vertices `ids` (those not modifiable yet are deferred, as always).
    pub(crate) fn retire_vertices(
        &mut self,
        band: &mut Band,
        ids: Vec<u64>,
        out: &mut OutBatch,
        stats: &mut SimplifyStats,
    ) {
        for id in ids {
            self.try_retire(band, id, out, stats);
        }
    }

    fn retire_deferred(&mut self, band: &mut Band, out: &mut OutBatch, stats: &mut SimplifyStats) {
        for id in std::mem::take(&mut self.deferred) {
            self.try_retire(band, id, out, stats);
        }
    }

    /// Retires `id` if it is modifiable, else defers it. Returns whether it retired.
    fn try_retire(
        &mut self,
        band: &mut Band,
        id: u64,
        out: &mut OutBatch,
        stats: &mut SimplifyStats,
    ) -> bool {
        let store = &mut band.store;
        let Some(v) = store.vertex(id) else {
            return false;
        };
        if store.is_retired(id) {
            return false;
        }
        if !store.is_modifiable(id) {
            self.deferred.push(id);
            return false;
        }
        let tris = v.tris.clone();
        store.retire(id);
        if tris.is_empty() {
            store.remove_vertex(id);
        }
        for t in tris {
            let store = &band.store;
            if store.tri(t).v.iter().all(|&x| store.is_retired(x)) {
                self.emit(band, t, out, stats);
            }
        }
        true
    }

    /// Emits a triangle with all three vertices retired, preceded by its vertices that did not go
    /// out yet; frees the vertices it used for the last time.
    fn emit(&mut self, band: &mut Band, t: TriId, out: &mut OutBatch, stats: &mut SimplifyStats) {
        band.guard.emit(t);
        let store = &mut band.store;
        let tri = store.remove_triangle(t);
        let mut v = [0; 3];
        let mut last_use = [false; 3];
        for (i, &id) in tri.v.iter().enumerate() {
            let pos = store.pos(id);
            let Some(x) = store.vertex_mut(id) else {
                continue;
            };
            last_use[i] = x.tris.is_empty();
            if let Some(o) = x.out() {
                v[i] = o;
                continue;
            }
            let o = self.next_out;
            self.next_out += 1;
            x.set_out(o);
            if self.states {
                out.states.push(crate::VertexState {
                    quadric: x.quadric,
                    area: x.area,
                    rank_min: x.rank_min,
                    rank_max: x.rank_max,
                });
            }
            out.elements.push(OutElement::Vertex { pos });
            out.attrs.extend_from_slice(store.attrs(id));
            stats.vertices_out += 1;
            v[i] = o;
        }
        out.elements.push(OutElement::Triangle { v, last_use });
        stats.faces_out += 1;
        for (id, last) in tri.v.into_iter().zip(last_use) {
            if last {
                store.remove_vertex(id);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::store::Vertex;

    fn store(ranks: &[u32]) -> Store {
        let mut s = Store::default();
        for (id, &r) in ranks.iter().enumerate() {
            s.insert_vertex(id as u64, DVec3::ZERO, Vertex::new(r), &[]);
        }
        s
    }

    #[test]
    fn buckets_pop_in_rank_order_below_the_limit() {
        let mut s = store(&[3, 5, 3, 4]);
        let mut b = RankBuckets::default();
        for (id, r) in [(0, 3), (1, 5), (2, 3), (3, 4)] {
            b.push(r, id, &mut s);
        }
        assert_eq!(b.pop_below(4), Some((3, vec![0, 2])));
        assert_eq!(b.pop_below(4), None);
        assert_eq!(b.pop_below(u32::MAX), Some((4, vec![3])));
        b.restore(4, vec![3]);
        assert_eq!(b.pop_below(5), Some((4, vec![3])));
    }

    #[test]
    fn ranks_behind_the_oldest_bucket_are_clamped_and_recorded() {
        let mut s = store(&[7, 2]);
        let mut b = RankBuckets::default();
        b.push(7, 0, &mut s);
        b.push(2, 1, &mut s);
        assert_eq!(s.vertex(1).map(|v| v.bucket), Some(7));
        assert_eq!(b.pop_below(8), Some((7, vec![0, 1])));
    }

    #[test]
    fn stale_entries_are_dropped_and_the_live_ones_pop_in_the_same_order() {
        let mut s = Store::default();
        let mut b = RankBuckets::default();
        // Many vertices added and removed (contracted away), a few kept: the buckets stay within
        // a multiple of the live vertices instead of growing with every vertex ever added.
        let mut kept = Vec::new();
        for i in 0..20 * COMPACT_MIN as u64 {
            let rank = (i / 1000) as u32;
            let h = s.insert_vertex(i, DVec3::ZERO, Vertex::new(rank), &[]);
            b.push(rank, h, &mut s);
            if i % 97 == 0 {
                kept.push((rank, h));
            } else {
                s.remove_vertex(h);
            }
            assert!(b.entries <= (COMPACT_SHARE * s.live_vertices()).max(COMPACT_MIN));
        }
        assert_eq!(b.entries, b.lists.iter().map(Vec::len).sum::<usize>());
        let mut popped = Vec::new();
        while let Some((key, ids)) = b.pop_below(u32::MAX) {
            popped.extend(
                ids.into_iter()
                    .filter(|&id| is_filed(&s, id, key))
                    .map(|id| (key, id)),
            );
        }
        assert_eq!(popped, kept);
        assert_eq!(b.entries, 0);
    }
}
