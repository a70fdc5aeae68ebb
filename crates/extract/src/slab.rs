//! Streaming extraction: one slab (the cubes between two consecutive slices) at a time, emitted
//! as batches of whole rows.
//!
//! This is the hot loop of the whole service (it runs over every voxel of gigavoxel volumes), so:
//! the 8-bit case index is built incrementally along x (the inside bits of a column of four
//! voxels are computed once, in a vectorisable loop, and shared by the two cubes beside it),
//! runs of empty or full cubes are skipped eight at a time, nothing is allocated per cube
//! (each batch gets its buffers once, sized like the largest batch so far), and an edge's
//! position is computed only in the cubes that use it (a vertex shared by several cubes is
//! computed once per cube; the detector deduplicates by [`EdgeKey`]).
//!
//! `cargo run --release -p isostream-extract --example extract_throughput` measures it.

use glam::DVec3;
use isostream_volume::{Grid, SlabBounds};
use serde::Serialize;

use crate::cube::{corner_offset, edge_axis, edge_corners};
use crate::interp::{EdgePlacement, is_inside};
use crate::key::EdgeKey;
use crate::table;

/// A surface vertex: the grid edge it lies on and its physical position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeVertex {
    pub key: EdgeKey,
    pub pos: DVec3,
}

/// One non-empty cube of a batch: its minimum voxel and its ranges in the batch's vertices and
/// triangles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cube {
    pub coord: [u64; 3],
    pub first_vertex: u32,
    pub vertex_count: u8,
    pub first_triangle: u32,
    pub triangle_count: u8,
}

/// Non-empty cubes of consecutive rows of one slab, in traversal order (x fastest, then y,
/// then z). Triangles index the cube's own vertex range (local 0..vertex_count),
/// counter-clockwise seen from outside. The end of the volume is not a batch's business: the
/// stream's consumer knows it (the pipeline's channels end with an end message).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CubeBatch {
    pub slab: u64,
    pub cubes: Vec<Cube>,
    pub vertices: Vec<EdgeVertex>,
    pub triangles: Vec<[u8; 3]>,
    /// Attribute values per vertex (the same count for every vertex, vertex-major), filled by
    /// [`Extractor::extract_slab_with_attributes`]; empty without attributes.
    pub attrs: Vec<f32>,
    pub end_of_slab: bool,
    /// The last batch of its group: the batches of a slab come in groups of whole rows holding
    /// at least `max_triangles` each (the last group of a slab may hold fewer), and an extractor
    /// [`Extractor::chunked`] cuts a group into batches of about its chunk size. A consumer that
    /// wants the group (the pipeline's detector makes one delta of each) closes it here. Always
    /// set with `end_of_slab`; set on every batch of an extractor that is not chunked.
    pub ends_group: bool,
    /// Rows of cubes of the slab extracted with this batch, counted from the slab's first (all
    /// of them with `end_of_slab`): what follows lies in later rows or slabs, which lets the
    /// simplifier's front move within a slab (`isostream_simplify::Front`).
    pub rows_done: u64,
}

impl CubeBatch {
    /// Empties the batch (keeping its allocations) and resets the slab and flags.
    pub fn clear(&mut self) {
        self.slab = 0;
        self.cubes.clear();
        self.vertices.clear();
        self.triangles.clear();
        self.attrs.clear();
        self.end_of_slab = false;
        self.ends_group = false;
        self.rows_done = 0;
    }

    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The vertices of one of this batch's cubes; local vertex `i` is element `i`.
    pub fn cube_vertices(&self, cube: &Cube) -> &[EdgeVertex] {
        let first = cube.first_vertex as usize;
        &self.vertices[first..first + cube.vertex_count as usize]
    }

    /// The triangles of one of this batch's cubes, as local vertex indices.
    pub fn cube_triangles(&self, cube: &Cube) -> &[[u8; 3]] {
        let first = cube.first_triangle as usize;
        &self.triangles[first..first + cube.triangle_count as usize]
    }

    /// Every triangle of the batch as the edge keys of its vertices, in batch order.
    pub fn keyed_triangles(&self) -> impl Iterator<Item = [EdgeKey; 3]> + '_ {
        self.cubes.iter().flat_map(move |cube| {
            let vertices = self.cube_vertices(cube);
            self.cube_triangles(cube)
                .iter()
                .map(move |t| t.map(|i| vertices[i as usize].key))
        })
    }

    /// A new empty batch for `slab` with room for `sizes` (cubes, vertices, triangles).
    fn with_capacity(slab: u64, sizes: [usize; 3]) -> Self {
        CubeBatch {
            slab,
            cubes: Vec::with_capacity(sizes[0]),
            vertices: Vec::with_capacity(sizes[1]),
            triangles: Vec::with_capacity(sizes[2]),
            attrs: Vec::new(),
            end_of_slab: false,
            ends_group: false,
            rows_done: 0,
        }
    }

    fn sizes(&self) -> [usize; 3] {
        [self.cubes.len(), self.vertices.len(), self.triangles.len()]
    }
}

/// Counters over everything extracted so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct ExtractStats {
    /// Cubes of the slabs extracted (skipped ones included).
    pub cubes: u64,
    /// Cubes in blocks whose value bounds cannot cross the iso value: not looked at.
    pub skipped_cubes: u64,
    /// Cubes with at least one triangle.
    pub active_cubes: u64,
    pub triangles: u64,
    /// NaN or infinite voxels (treated as outside). Slice 0 is counted with slab 0 and every
    /// other slice as the upper slice of its slab, so a full sweep counts each voxel once.
    pub non_finite_voxels: u64,
    /// Attribute values at vertices that came out NaN or infinite and were replaced (see
    /// `attributes::sample`): the attribute volumes' own non-finite voxels next to the surface.
    /// Per surface vertex and attribute, however many cubes list the vertex, so a full sweep
    /// counts each once.
    pub non_finite_attribute_values: u64,
    /// Voxels of the iso volume whose stored values were finite but beyond f32's range (an f64
    /// volume's 1e40), read as `±f32::MAX`: counted by the reader as it converts them (the
    /// extractor sees only f32, where they are ordinary values), with the slab of their slice
    /// like `non_finite_voxels`.
    pub saturated_voxels: u64,
    /// The same in the attribute volumes, all of them together.
    pub saturated_attribute_voxels: u64,
    /// The most triangles one slab had: the size of the sweep front a simplifier holds at once
    /// (a flat face across the sweep puts a whole slice's worth of surface in one slab).
    pub max_slab_triangles: u64,
}

/// What one slab added to an extractor's counters (`after - before`).
impl std::ops::Sub for ExtractStats {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self {
            cubes: self.cubes - o.cubes,
            active_cubes: self.active_cubes - o.active_cubes,
            triangles: self.triangles - o.triangles,
            non_finite_voxels: self.non_finite_voxels - o.non_finite_voxels,
            non_finite_attribute_values: self.non_finite_attribute_values
                - o.non_finite_attribute_values,
            saturated_voxels: self.saturated_voxels - o.saturated_voxels,
            saturated_attribute_voxels: self.saturated_attribute_voxels
                - o.saturated_attribute_voxels,
            skipped_cubes: self.skipped_cubes - o.skipped_cubes,
            // One slab's own triangles are its largest slab.
            max_slab_triangles: self.triangles - o.triangles,
        }
    }
}

/// Counters of several extractors of one stream (slabs extracted in parallel) add up.
impl std::ops::AddAssign for ExtractStats {
    fn add_assign(&mut self, o: Self) {
        self.cubes += o.cubes;
        self.skipped_cubes += o.skipped_cubes;
        self.active_cubes += o.active_cubes;
        self.triangles += o.triangles;
        self.non_finite_voxels += o.non_finite_voxels;
        self.non_finite_attribute_values += o.non_finite_attribute_values;
        self.saturated_voxels += o.saturated_voxels;
        self.saturated_attribute_voxels += o.saturated_attribute_voxels;
        self.max_slab_triangles = self.max_slab_triangles.max(o.max_slab_triangles);
    }
}

/// The streaming marching-cubes extractor of one volume at one iso value.
#[derive(Debug, Clone)]
pub struct Extractor {
    /// The grid, the iso value and where vertices go on a crossing edge.
    place: EdgePlacement,
    stats: ExtractStats,
    /// Per-row scratch: the inside bits of each column of four voxels (reused, never shrinks).
    columns: Vec<u8>,
    /// Largest (cubes, vertices, triangles) of any batch so far: the capacity of new batches.
    /// Batches travel through a channel, so each needs its own buffers; sizing them up front
    /// avoids regrowing them row after row. Bounded by the chunk (or `max_triangles`) plus one
    /// row.
    batch_sizes: [usize; 3],
    /// Most triangles per batch within a group ([`Extractor::chunked`]); `usize::MAX`: a
    /// batch is a whole group.
    chunk_triangles: usize,
    /// Counts the cubes and triangles without making them ([`Extractor::counting`]).
    counting: bool,
}

/// The four rows of voxels holding the corners of one row of cubes, indexed by `c >> 1` for
/// corner `c`: (y, z), (y + 1, z), (y, z + 1), (y + 1, z + 1).
pub type RowQuad<'a> = [&'a [f32]; 4];

/// A slab's voxels, row by row ([`Extractor::extract_slab_rows`]).
pub trait SlabRows {
    /// The rows of voxels of the row of cubes `y` ([`RowQuad`]: rows y and y + 1 of the lower
    /// slice, then of the upper one), `grid.dims[0]` values each. Asked for in increasing y.
    fn quad(&mut self, y: u64) -> RowQuad<'_>;
}

/// Two whole slices.
struct WholeSlices<'a> {
    lower: &'a [f32],
    upper: &'a [f32],
    nx: usize,
}

impl SlabRows for WholeSlices<'_> {
    fn quad(&mut self, y: u64) -> RowQuad<'_> {
        let (y0, y1) = (y as usize * self.nx, (y as usize + 1) * self.nx);
        [
            &self.lower[y0..y1],
            &self.lower[y1..y1 + self.nx],
            &self.upper[y0..y1],
            &self.upper[y1..y1 + self.nx],
        ]
    }
}

impl Extractor {
    pub fn new(grid: Grid, iso: f32) -> Self {
        Extractor {
            place: EdgePlacement::new(grid, iso),
            stats: ExtractStats::default(),
            columns: Vec::new(),
            batch_sizes: [0; 3],
            chunk_triangles: usize::MAX,
            counting: false,
        }
    }

    /// This extractor, counting the non-empty cubes and their triangles in its
    /// [`ExtractStats`] without making them: its batches carry no cube, vertex or triangle
    /// (only their end flags). The count is exact (a cube's triangles are its case's), and it
    /// is what a face target needs: the first pass over an upsampled volume of 65.6 Gvoxels
    /// takes 4.7-5.0 s against 8.6 s when it made them (the vertices' interpolation, their keys
    /// and the batches through the channels).
    pub fn counting(self) -> Self {
        Extractor {
            counting: true,
            ..self
        }
    }

    /// This extractor, cutting each group of `max_triangles` (see [`CubeBatch::ends_group`])
    /// into batches of whole rows holding at least `chunk_triangles` each (the last of a group
    /// may hold fewer). The groups are the
    /// same, so a consumer joining each group's batches sees what an unchunked extractor
    /// sends; the batches in flight between threads are smaller: on 2041^2 slices a group of
    /// 8,192 triangles is about 0.8 MB of cubes and duplicated vertices, and the extraction
    /// workers and slab replies hold several at once (docs/scale.md).
    pub fn chunked(self, chunk_triangles: usize) -> Self {
        Extractor {
            chunk_triangles: chunk_triangles.max(1),
            ..self
        }
    }

    /// An extractor continuing a sweep (after a checkpoint) whose counters so far are `stats`:
    /// a slab's batches depend on its two slices only, so nothing else carries over.
    pub fn resume(grid: Grid, iso: f32, stats: ExtractStats) -> Self {
        Extractor {
            stats,
            ..Extractor::new(grid, iso)
        }
    }

    /// Extracts slab z (cubes between slices z and z+1, z in `0..dims[2] - 1`). Emits batches
    /// holding whole rows, closing a group when it reaches `max_triangles` (at least one row per
    /// batch, and never an empty batch before the last; a batch is a whole group unless the
    /// extractor is [`Extractor::chunked`]); the last batch of the slab has
    /// `end_of_slab = true` (an empty one if needed). Slabs are independent: extracting them in
    /// any order (or on several extractors) gives the same batches. The first error returned by
    /// `emit` stops the slab and is returned.
    ///
    /// # Panics
    /// If z is not a slab of the grid or a slice does not hold `grid.slice_len()` values.
    pub fn extract_slab<E>(
        &mut self,
        z: u64,
        lower: &[f32],
        upper: &[f32],
        max_triangles: usize,
        emit: impl FnMut(CubeBatch) -> Result<(), E>,
    ) -> Result<(), E> {
        self.extract_slab_skipping(z, lower, upper, None, max_triangles, emit)
    }

    /// [`Self::extract_slab`], skipping the blocks of cubes that `bounds` (the slab's value
    /// bounds, from the volume) proves cannot cross the iso value: their voxels are not read,
    /// their cubes are counted in [`ExtractStats::skipped_cubes`], and the batches are the same
    /// as without `bounds`, since such cubes have no triangle.
    ///
    /// # Panics
    /// As `extract_slab`.
    pub fn extract_slab_skipping<E>(
        &mut self,
        z: u64,
        lower: &[f32],
        upper: &[f32],
        bounds: Option<&SlabBounds>,
        max_triangles: usize,
        emit: impl FnMut(CubeBatch) -> Result<(), E>,
    ) -> Result<(), E> {
        let n = self.grid().slice_len();
        assert!(
            lower.len() == n && upper.len() == n,
            "slices must hold {n} values"
        );
        let mut rows = WholeSlices {
            lower,
            upper,
            nx: self.grid().dims[0] as usize,
        };
        self.extract_slab_rows(z, &mut rows, bounds, max_triangles, emit)
    }

    /// [`Self::extract_slab_skipping`] with the slab's voxels asked for row by row (`rows`), in
    /// increasing y: a source that computes rows on demand never holds its slices whole, and the
    /// batches are the same as from whole slices (the batching depends on the rows' cubes only).
    ///
    /// # Panics
    /// If z is not a slab of the grid or a row does not hold `grid.dims[0]` values.
    pub fn extract_slab_rows<E>(
        &mut self,
        z: u64,
        rows: &mut impl SlabRows,
        bounds: Option<&SlabBounds>,
        max_triangles: usize,
        mut emit: impl FnMut(CubeBatch) -> Result<(), E>,
    ) -> Result<(), E> {
        let [nx, ny, nz] = self.grid().dims;
        assert!(z + 1 < nz, "slab {z} outside a grid of {nz} slices");
        self.stats.cubes += nx.saturating_sub(1) * ny.saturating_sub(1);

        let cube_rows = ny.saturating_sub(1);
        let triangles_before = self.stats.triangles;
        let mut batch = CubeBatch::with_capacity(z, self.batch_sizes);
        // The group's cubes and triangles in the batches already sent.
        let (mut group_cubes, mut group_triangles) = (0, 0);
        for y in 0..cube_rows {
            // A row of cubes none of whose blocks may cross is not even asked for: an upsampled
            // source then computes none of its voxels. Its voxels need no counting either: a
            // non-finite voxel leaves its blocks unbounded, so every row of cubes holding one is
            // asked for (block bounds include their border rows).
            if let Some(b) = bounds
                && !b.row_may_cross((y / b.block()[1]) as usize, self.iso())
            {
                self.stats.skipped_cubes += nx.saturating_sub(1);
                continue;
            }
            let quad = rows.quad(y);
            assert!(
                quad.iter().all(|r| r.len() == nx as usize),
                "rows must hold {nx} values"
            );
            // Every voxel once: rows y + 1 here, row 0 with the first row of cubes; the lower
            // slice only in slab 0 (every other slice is the upper slice of a slab).
            let new_rows = if y == 0 { 0..2 } else { 1..2 };
            for r in new_rows {
                if z == 0 {
                    self.stats.non_finite_voxels += count_non_finite(quad[r]);
                }
                self.stats.non_finite_voxels += count_non_finite(quad[2 + r]);
            }
            match bounds {
                None => self.extract_row([0, y, z], quad, &mut batch),
                Some(b) => self.extract_row_blocks(b, [y, z], quad, &mut batch),
            }
            let ends_group = group_cubes + batch.cubes.len() > 0
                && group_triangles + batch.triangles.len() >= max_triangles;
            let chunk_full =
                !batch.cubes.is_empty() && batch.triangles.len() >= self.chunk_triangles;
            if (ends_group || chunk_full) && y + 1 < cube_rows {
                if ends_group {
                    (group_cubes, group_triangles) = (0, 0);
                } else {
                    group_cubes += batch.cubes.len();
                    group_triangles += batch.triangles.len();
                }
                self.remember_sizes(&batch);
                let next = CubeBatch::with_capacity(z, self.batch_sizes);
                batch.ends_group = ends_group;
                batch.rows_done = y + 1;
                emit(std::mem::replace(&mut batch, next))?;
            }
        }
        self.remember_sizes(&batch);
        let slab_triangles = self.stats.triangles - triangles_before;
        self.stats.max_slab_triangles = self.stats.max_slab_triangles.max(slab_triangles);
        batch.end_of_slab = true;
        batch.ends_group = true;
        batch.rows_done = cube_rows;
        emit(batch)
    }

    fn remember_sizes(&mut self, batch: &CubeBatch) {
        let sizes = batch.sizes();
        for (kept, size) in self.batch_sizes.iter_mut().zip(sizes) {
            *kept = (*kept).max(size);
        }
    }

    pub fn grid(&self) -> Grid {
        self.place.grid()
    }

    pub fn iso(&self) -> f32 {
        self.place.iso()
    }

    /// Where this extractor's vertices go on their edges (the attributes are sampled there).
    pub(crate) fn placement(&self) -> &EdgePlacement {
        &self.place
    }

    /// Counters over every slab extracted so far.
    pub fn stats(&self) -> ExtractStats {
        self.stats
    }

    /// Counts attribute values replaced for being non-finite (`attributes::sample`).
    pub(crate) fn add_non_finite_attribute_values(&mut self, n: u64) {
        self.stats.non_finite_attribute_values += n;
    }

    /// Counts the voxels the reader saturated in a slab's slices
    /// ([`ExtractStats::saturated_voxels`], [`ExtractStats::saturated_attribute_voxels`]), so
    /// that they are summed and checkpointed with the slab's other counters.
    pub fn add_saturated_voxels(&mut self, iso: u64, attributes: u64) {
        self.stats.saturated_voxels += iso;
        self.stats.saturated_attribute_voxels += attributes;
    }

    /// Appends the non-empty cubes of row `y` of slab `z` that lie in blocks of `bounds` that may
    /// cross the iso value (runs of such blocks at once).
    fn extract_row_blocks(
        &mut self,
        bounds: &SlabBounds,
        [y, z]: [u64; 2],
        quad: RowQuad<'_>,
        batch: &mut CubeBatch,
    ) {
        let cubes = quad[0].len() - 1;
        let [bw, bh] = bounds.block();
        let by = (y / bh) as usize;
        let bw = bw as usize;
        let mut bx = 0;
        while bx < bounds.count()[0] {
            let active = |b: usize| bounds.may_cross(b, by, self.iso());
            let first = bx;
            while bx < bounds.count()[0] && active(bx) == active(first) {
                bx += 1;
            }
            let (x0, x1) = (first * bw, (bx * bw).min(cubes));
            if active(first) {
                let part = quad.map(|row| &row[x0..=x1]);
                self.extract_row([x0 as u64, y, z], part, batch);
            } else {
                self.stats.skipped_cubes += (x1 - x0) as u64;
            }
        }
    }

    /// Appends the non-empty cubes of the row of cubes whose voxels `quad` holds, starting at
    /// voxel `start`.
    fn extract_row(&mut self, start: [u64; 3], quad: RowQuad<'_>, batch: &mut CubeBatch) {
        let iso = self.iso();
        // The case index is built incrementally along x: the inside bits of the four voxels of
        // column x, placed at the corner bits of a cube's x = 0 face (corner 2j for row j), are
        // computed once and serve as the x = 1 face (shifted left by one) of cube x - 1 and the
        // x = 0 face of cube x. This branch-free loop vectorises.
        self.columns.clear();
        self.columns
            .extend(quad[0].iter().zip(quad[1]).zip(quad[2]).zip(quad[3]).map(
                |(((&v0, &v1), &v2), &v3)| {
                    u8::from(is_inside(v0, iso))
                        | (u8::from(is_inside(v1, iso)) << 2)
                        | (u8::from(is_inside(v2, iso)) << 4)
                        | (u8::from(is_inside(v3, iso)) << 6)
                },
            ));
        let columns = &self.columns;
        let (cubes_before, triangles_before) = (batch.cubes.len(), batch.triangles.len());
        let mut x = 0;
        while x + 1 < columns.len() {
            // Most of a volume is empty or full: skip 8 cubes at once when their 9 columns are
            // all outside or all inside.
            if let Some(run) = columns.get(x..x + 9) {
                let word = u64::from_le_bytes(run[..8].try_into().expect("8 bytes"));
                if (word == 0 || word == ALL_INSIDE_RUN) && run[8] == run[0] {
                    x += 8;
                    continue;
                }
            }
            let index = columns[x] | (columns[x + 1] << 1);
            if index != 0 && index != 0xff {
                if self.counting {
                    self.stats.active_cubes += 1;
                    self.stats.triangles += table::case(index).triangles().len() as u64;
                } else {
                    let coord = [start[0] + x as u64, start[1], start[2]];
                    push_cube(&self.place, (coord, x), index, &quad, batch);
                }
            }
            x += 1;
        }
        self.stats.active_cubes += (batch.cubes.len() - cubes_before) as u64;
        self.stats.triangles += (batch.triangles.len() - triangles_before) as u64;
    }
}

/// Eight column codes with all four voxels inside.
const ALL_INSIDE_RUN: u64 = u64::from_le_bytes([0b0101_0101; 8]);

/// Appends one non-empty cube (its minimum voxel, and its x in `quad`): its crossing edges'
/// vertices and its triangles.
fn push_cube(
    place: &EdgePlacement,
    (coord, x): ([u64; 3], usize),
    index: u8,
    quad: &RowQuad<'_>,
    batch: &mut CubeBatch,
) {
    let case = table::case(index);
    let value = |c: u8| quad[(c >> 1) as usize][x + (c & 1) as usize];
    let first_vertex = batch.vertices.len();
    for &e in case.edges() {
        let (a, b) = edge_corners(e);
        let o = corner_offset(a);
        let voxel = [0, 1, 2].map(|i| coord[i] + u64::from(o[i]));
        let axis = edge_axis(e);
        batch.vertices.push(EdgeVertex {
            key: EdgeKey::new(voxel[0], voxel[1], voxel[2], axis, place.grid().dims),
            pos: place.position(voxel, axis, value(a), value(b)),
        });
    }
    let first_triangle = batch.triangles.len();
    batch.triangles.extend_from_slice(case.triangles());
    batch.cubes.push(Cube {
        coord,
        first_vertex: u32::try_from(first_vertex).expect("batch vertex count fits u32"),
        vertex_count: case.edges().len() as u8,
        first_triangle: u32::try_from(first_triangle).expect("batch triangle count fits u32"),
        triangle_count: case.triangles().len() as u8,
    });
}

/// Every voxel passes here: counted in `u32` lanes (a row has far fewer than 2^32 voxels), which
/// the compiler vectorizes on any x86-64, where a `u64` count stayed scalar.
fn count_non_finite(row: &[f32]) -> u64 {
    u64::from(row.iter().map(|v| u32::from(!v.is_finite())).sum::<u32>())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3x3x3 grid with only the centre voxel inside: a closed octahedron-like surface made of
    /// 8 corner triangles, one per cube.
    fn blob() -> (Grid, Vec<f32>) {
        let grid = Grid::new([3, 3, 3], [1.0; 3], [0.0; 3]).unwrap();
        let mut data = vec![0.0f32; 27];
        data[13] = 2.0;
        (grid, data)
    }

    fn run(grid: Grid, data: &[f32], max_triangles: usize) -> (Vec<CubeBatch>, ExtractStats) {
        let n = grid.slice_len();
        let mut ex = Extractor::new(grid, 1.0);
        let mut batches = Vec::new();
        for z in 0..grid.dims[2] - 1 {
            let (lower, upper) = (
                &data[z as usize * n..][..n],
                &data[(z as usize + 1) * n..][..n],
            );
            ex.extract_slab(z, lower, upper, max_triangles, |b| {
                batches.push(b);
                Ok::<_, ()>(())
            })
            .unwrap();
        }
        (batches, ex.stats())
    }

    #[test]
    fn single_inside_voxel_gives_one_triangle_per_cube() {
        let (grid, data) = blob();
        let (batches, stats) = run(grid, &data, usize::MAX);
        assert_eq!(batches.len(), 2);
        assert_eq!(
            stats,
            ExtractStats {
                cubes: 8,
                skipped_cubes: 0,
                active_cubes: 8,
                triangles: 8,
                non_finite_voxels: 0,
                non_finite_attribute_values: 0,
                saturated_voxels: 0,
                saturated_attribute_voxels: 0,
                max_slab_triangles: 4,
            }
        );
        for (z, b) in batches.iter().enumerate() {
            assert_eq!(b.slab, z as u64);
            assert!(b.end_of_slab);
            assert_eq!(b.cubes.len(), 4);
            for cube in &b.cubes {
                assert_eq!((cube.vertex_count, cube.triangle_count), (3, 1));
                // Every vertex sits halfway (t = 0.5) on an edge touching the centre voxel.
                for v in b.cube_vertices(cube) {
                    let d = v.pos - DVec3::ONE;
                    assert_eq!(d.abs().max_element(), 0.5, "{:?}", v.pos);
                    assert_eq!(d.abs().min_element(), 0.0);
                }
            }
        }
    }

    #[test]
    fn small_budget_flushes_whole_rows_and_marks_the_last_batch() {
        let (grid, data) = blob();
        let (batches, _) = run(grid, &data, 1);
        // Two rows per slab, two cubes each: one batch per row.
        assert_eq!(batches.len(), 4);
        let flags: Vec<_> = batches
            .iter()
            .map(|b| (b.slab, b.cubes.len(), b.end_of_slab))
            .collect();
        assert_eq!(
            flags,
            [(0, 2, false), (0, 2, true), (1, 2, false), (1, 2, true)]
        );
        // Cubes of a batch come in traversal order.
        assert_eq!(batches[1].cubes[0].coord, [0, 1, 0]);
        assert_eq!(batches[1].cubes[1].coord, [1, 1, 0]);
    }

    #[test]
    fn empty_slabs_still_end_with_a_batch() {
        let grid = Grid::new([3, 3, 3], [1.0; 3], [0.0; 3]).unwrap();
        let mut data = vec![0.0f32; 27];
        data[0] = f32::NAN;
        data[26] = f32::INFINITY;
        let (batches, stats) = run(grid, &data, 0);
        assert_eq!(batches.len(), 2);
        assert!(batches.iter().all(|b| b.cubes.is_empty() && b.end_of_slab));
        assert_eq!(stats.non_finite_voxels, 2);
        assert_eq!(stats.triangles, 0);
    }

    #[test]
    fn emit_errors_stop_the_slab() {
        let (grid, data) = blob();
        let mut ex = Extractor::new(grid, 1.0);
        let mut calls = 0;
        let r = ex.extract_slab(0, &data[..9], &data[9..18], 0, |_| {
            calls += 1;
            Err("channel closed")
        });
        assert_eq!(r, Err("channel closed"));
        assert_eq!(calls, 1);
    }

    #[test]
    fn keyed_triangles_and_clear() {
        let (grid, data) = blob();
        let (mut batches, _) = run(grid, &data, usize::MAX);
        let b = &mut batches[0];
        let tris: Vec<_> = b.keyed_triangles().collect();
        assert_eq!(tris.len(), b.triangle_count());
        // Every vertex of the blob is on an edge touching the centre voxel (1, 1, 1).
        for key in tris.iter().flatten() {
            let (start, axis) = key.decode(grid.dims);
            let mut end = start;
            end[axis as usize] += 1;
            assert!(start == [1, 1, 1] || end == [1, 1, 1], "{start:?} {axis}");
        }
        b.clear();
        assert_eq!(b, &CubeBatch::default());
    }

    #[test]
    fn keys_and_stats_are_64_bit() {
        // A volume far beyond 2^32 voxels: only its last slab is extracted.
        let nz = 1u64 << 33;
        let grid = Grid::new([3, 3, nz], [1.0; 3], [0.0; 3]).unwrap();
        let (_, data) = blob();
        let mut ex = Extractor::new(grid, 1.0);
        let z = nz - 2;
        let mut batches = Vec::new();
        ex.extract_slab(z, &data[9..18], &data[18..], usize::MAX, |b| {
            batches.push(b);
            Ok::<_, ()>(())
        })
        .unwrap();
        assert!(batches[0].end_of_slab);
        for v in &batches[0].vertices {
            assert!(v.key.0 > u64::from(u32::MAX));
            let ([_, _, vz], axis) = v.key.decode(grid.dims);
            assert!(vz == z || (vz == z + 1 && axis != 2), "{vz} {axis}");
            assert!(v.pos.z >= z as f64 && v.pos.z <= (z + 1) as f64);
        }
    }

    #[test]
    fn skipping_blocks_changes_nothing_but_the_work() {
        // A ball of radius 4 in 13 x 11 x 9, plus NaN in a corner: most blocks are skippable.
        let grid = Grid::new([13, 11, 9], [1.0; 3], [0.0; 3]).unwrap();
        let data: Vec<f32> = (0..13 * 11 * 9)
            .map(|i| {
                let [x, y, z] = [i % 13, (i / 13) % 11, i / 143].map(|c| c as f32);
                if i == 0 {
                    return f32::NAN;
                }
                16.0 - ((x - 6.0).powi(2) + (y - 5.0).powi(2) + (z - 4.0).powi(2))
            })
            .collect();
        let n = grid.slice_len();
        for block in [[1, 1], [2, 3], [5, 4], [16, 16]] {
            let (mut plain, mut skip) = (Extractor::new(grid, 0.5), Extractor::new(grid, 0.5));
            let (mut a, mut b) = (Vec::new(), Vec::new());
            for z in 0..8 {
                let (lo, up) = (&data[z * n..][..n], &data[(z + 1) * n..][..n]);
                let bounds = SlabBounds::from_slices(&grid, block, lo, up);
                plain
                    .extract_slab(z as u64, lo, up, 5, |x| {
                        a.push(x);
                        Ok::<_, ()>(())
                    })
                    .unwrap();
                skip.extract_slab_skipping(z as u64, lo, up, Some(&bounds), 5, |x| {
                    b.push(x);
                    Ok::<_, ()>(())
                })
                .unwrap();
            }
            assert_eq!(a, b, "block {block:?}");
            let (p, s) = (plain.stats(), skip.stats());
            assert_eq!((p.active_cubes, p.triangles), (s.active_cubes, s.triangles));
            assert_eq!(p.skipped_cubes, 0);
            // One block of 16 x 16 holds the whole ball: nothing to skip there.
            assert_eq!(s.skipped_cubes > 0, block[0] < 16, "block {block:?}");
            assert!(s.skipped_cubes + s.active_cubes <= s.cubes);
        }
    }

    #[test]
    fn counting_gives_the_counters_of_extracting_and_no_triangle() {
        // A noisy field: many cases, degenerate ones included (values on the iso value).
        let grid = Grid::new([17, 13, 11], [1.0; 3], [0.0; 3]).unwrap();
        let data: Vec<f32> = (0..grid.voxel_count())
            .map(|i| ((i * 7919 % 23) as f32 - 11.0).round())
            .collect();
        let n = grid.slice_len();
        let (mut made, mut counted) = (
            Extractor::new(grid, 0.0).chunked(7),
            Extractor::new(grid, 0.0).chunked(7).counting(),
        );
        for z in 0..10 {
            let (lo, up) = (&data[z * n..][..n], &data[(z + 1) * n..][..n]);
            made.extract_slab(z as u64, lo, up, 40, |_| Ok::<_, ()>(()))
                .unwrap();
            counted
                .extract_slab(z as u64, lo, up, 40, |b| {
                    assert!(b.cubes.is_empty() && b.vertices.is_empty());
                    assert!(b.triangles.is_empty());
                    Ok::<_, ()>(())
                })
                .unwrap();
        }
        assert!(made.stats().triangles > 1000);
        assert_eq!(made.stats(), counted.stats());
    }

    /// The largest slab's triangles, kept across slabs and across the extractors of one stream
    /// (the largest of theirs); a slab's own counters (`after - before`) are its own largest.
    #[test]
    fn the_largest_slab_is_counted() {
        let grid = Grid::new([9, 9, 6], [1.0; 3], [0.0; 3]).unwrap();
        // A ball whose radius shrinks with z: the first slabs hold the most triangles.
        let data: Vec<f32> = (0..grid.voxel_count())
            .map(|i| {
                let (x, y, z) = (i % 9, i / 9 % 9, i / 81);
                let d = |c: u64| (c as f32 - 4.0).powi(2);
                d(x) + d(y) - (12.0 - 2.0 * z as f32)
            })
            .collect();
        let n = grid.slice_len();
        let mut ex = Extractor::new(grid, 0.0);
        let mut per_slab = Vec::new();
        for z in 0..5 {
            let before = ex.stats();
            let (lo, up) = (&data[z * n..][..n], &data[(z + 1) * n..][..n]);
            ex.extract_slab(z as u64, lo, up, 40, |_| Ok::<_, ()>(()))
                .unwrap();
            let slab = ex.stats() - before;
            assert_eq!(slab.max_slab_triangles, slab.triangles);
            per_slab.push(slab.triangles);
        }
        let largest = *per_slab.iter().max().unwrap();
        assert!(
            largest > 0 && per_slab.iter().any(|&t| t < largest),
            "{per_slab:?}"
        );
        assert_eq!(ex.stats().max_slab_triangles, largest);
        let mut sum = ExtractStats::default();
        sum += ex.stats();
        sum += ExtractStats {
            max_slab_triangles: largest - 1,
            ..ExtractStats::default()
        };
        assert_eq!(sum.max_slab_triangles, largest, "the largest of both");
    }

    #[test]
    #[should_panic(expected = "slab 2 outside")]
    fn rejects_slabs_outside_the_grid() {
        let (grid, data) = blob();
        let _ = Extractor::new(grid, 1.0)
            .extract_slab(2, &data[..9], &data[9..18], 1, |_| Ok::<_, ()>(()));
    }
}
