//! Zarr v3 and v2 arrays, OME-Zarr v0.5 and v0.4 images, read one row of chunks at a time.
//!
//! A store is a directory with a `zarr.json` (Zarr v3), or a `.zarray` or `.zgroup` (Zarr v2,
//! attributes in `.zattrs`); the path of that file works too. It is an array, a group whose child
//! array is named by `[input] array`, or an OME-Zarr multiscale group (v0.5: `multiscales` under
//! `attributes.ome` of `zarr.json`; v0.4: `multiscales` in `.zattrs`, read by the same code),
//! where `datasets[0]` (full resolution) is read unless `[input] array` names another level's
//! `path`, and the voxel size and origin come from the `coordinateTransformations` (scale,
//! translation) of that level and of the multiscale, last three values.
//!
//! Axes: Zarr is C order (last axis fastest), so an array of shape `[Z, Y, X]` is our grid with
//! x fastest; of more axes, the last three are z, y, x and the leading ones (OME-Zarr's t, c) must
//! have size 1. Types int8..uint64, float32 and float64; `regular` chunk grids; `default` and
//! `v2` chunk keys with either separator; missing chunk files read as `fill_value`; codecs
//! `bytes`, `transpose`, `gzip`, `zstd`, `blosc`, `crc32c` (verified) and `sharding_indexed`
//! (index at either end; only the inner chunks a row needs are read). Zarr v2 arrays: numpy
//! dtypes (`<u2`, `>f4`, `|u1`, ...), order C or F, compressor null, `blosc`, `zlib`, `gzip`,
//! `zstd` or `lz4`, no filters, keys `i.j.k` or `i/j/k`, fill value null read as 0.
//!
//! Blosc (`zarr/blosc.rs`, the default compressor of OME-Zarr v0.4 data) is decoded in pure
//! Rust: its own blosclz by hand, lz4 through `lz4_flex`, zlib and zstd through `flate2` and
//! `ruzstd`; a frame's sizes are checked against the chunk's before anything is allocated.
//!
//! Memory: the reader decodes the chunks (inner chunks of shards) that intersect the current
//! z range, serves their slices, and drops them when the front moves on, so it holds one row of
//! chunks (chunk depth x a full slice) plus one slice. Chunks missing from the store cost nothing.
//! Only a chunk as deep as the whole volume makes that row the whole volume, which
//! [`VolumeSource::loads_whole_volume`] then reports.
//!
//! Written by hand rather than with the `zarrs` crate: reading is a JSON file, a codec chain and
//! chunk files, while `zarrs` brings a large dependency tree (async stores, many codecs and their C
//! libraries) into a workspace that so far needs no C toolchain. zstd is `ruzstd` and lz4
//! `lz4_flex` (pure Rust) for the same reason.

mod blosc;
mod codec;
mod dtype;
mod json;
mod meta;

use crate::source::check_request;
use crate::stream::zeroed;
use crate::{Dtype, Endian, Grid, OpenOptions, VolumeError, VolumeSource};
use codec::{Codecs, Sharding};
use meta::ArrayMeta;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// The files that make a directory a Zarr node: v3's, then v2's.
pub(crate) const NODE_FILES: [&str; 4] = ["zarr.json", ".zarray", ".zgroup", ".zattrs"];

/// Opens a Zarr store directory (or its `zarr.json`, `.zarray`, `.zgroup` or `.zattrs`).
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_raw_params(path, "Zarr")?;
    let dir = match path.parent() {
        Some(parent)
            if path
                .file_name()
                .is_some_and(|n| NODE_FILES.iter().any(|f| n == *f)) =>
        {
            parent
        }
        _ => path,
    };
    let meta = meta::resolve(dir, opts.array.as_deref())?;
    Ok(Box::new(ZarrVolume::new(meta, opts)?))
}

/// A Zarr array streamed one row of chunks at a time.
struct ZarrVolume {
    meta: ArrayMeta,
    grid: Grid,
    /// Shape of what is decoded at once: the chunk, or the inner chunk of a shard.
    block: Vec<u64>,
    /// Its z, y, x extents, and blocks per row along y and x.
    extent: [u64; 3],
    across: [u64; 2],
    endian: Endian,
    row: Option<Row>,
    /// The last slice of the previous row: a re-read of z - 1 just after the front crossed a row
    /// boundary must not decode that row again.
    prev: Option<(u64, Vec<f32>)>,
    /// Voxels saturated by the reads so far (`VolumeSource::saturated_voxels`).
    saturated: u64,
}

/// The decoded blocks of one z range, y-major; None where the store has no chunk (fill value).
struct Row {
    index: u64,
    blocks: Vec<Option<Vec<u8>>>,
}

impl ZarrVolume {
    fn new(meta: ArrayMeta, opts: &OpenOptions) -> Result<Self, VolumeError> {
        let r = meta.shape.len();
        let dims = [meta.shape[r - 1], meta.shape[r - 2], meta.shape[r - 3]];
        let grid = opts.grid(
            &meta.dir,
            dims,
            meta.spacing.unwrap_or([1.0; 3]),
            meta.origin.unwrap_or([0.0; 3]),
        )?;
        let (block, endian) = match &meta.codecs {
            Codecs::Plain(chain) => (meta.chunk_shape.clone(), chain.endian),
            Codecs::Sharded(s) => (s.inner_shape.clone(), s.inner.endian),
        };
        let extent = [block[r - 3], block[r - 2], block[r - 1]];
        let across = [dims[1].div_ceil(extent[1]), dims[0].div_ceil(extent[2])];
        Ok(ZarrVolume {
            meta,
            grid,
            block,
            extent,
            across,
            endian,
            row: None,
            prev: None,
            saturated: 0,
        })
    }

    /// Grid coordinates (all axes) of block (z, y, x) of the last three axes.
    fn coords(&self, z: u64, y: u64, x: u64) -> Vec<u64> {
        let mut c = vec![0; self.block.len()];
        let r = c.len();
        c[r - 3..].copy_from_slice(&[z, y, x]);
        c
    }

    /// Decodes every stored block of row `bz`.
    fn load_row(&self, bz: u64) -> Result<Vec<Option<Vec<u8>>>, VolumeError> {
        let [ny, nx] = self.across;
        let elem = self.meta.ztype.size();
        let mut blocks = zeroed((ny * nx) as usize).ok_or_else(|| VolumeError::Grid {
            origin: self.meta.dir.display().to_string(),
            problem: format!("{ny}x{nx} chunks per slice are more than this machine can track; re-chunk the array"),
        })?;
        match &self.meta.codecs {
            Codecs::Plain(chain) => {
                for by in 0..ny {
                    for bx in 0..nx {
                        let path = self.chunk_path(bz, by, bx);
                        if let Some(data) = read_chunk(&path)? {
                            let block = chain.decode(&path, data, &self.block, elem)?;
                            blocks[(by * nx + bx) as usize] = Some(block);
                        }
                    }
                }
            }
            Codecs::Sharded(sh) => {
                let r = sh.grid.len();
                let [gz, gy, gx] = [sh.grid[r - 3], sh.grid[r - 2], sh.grid[r - 1]];
                for sy in 0..ny.div_ceil(gy) {
                    for sx in 0..nx.div_ceil(gx) {
                        let path = self.chunk_path(bz / gz, sy, sx);
                        let Some(mut shard) = Shard::open(path, sh)? else {
                            continue;
                        };
                        let (y_end, x_end) = (((sy + 1) * gy).min(ny), ((sx + 1) * gx).min(nx));
                        for by in sy * gy..y_end {
                            for bx in sx * gx..x_end {
                                // Leading inner coordinates are 0: they add nothing to the index.
                                let inner = ((bz % gz) * gy + by % gy) * gx + bx % gx;
                                if let Some(data) = shard.read(inner)? {
                                    let block =
                                        sh.inner.decode(&shard.path, data, &self.block, elem)?;
                                    blocks[(by * nx + bx) as usize] = Some(block);
                                }
                            }
                        }
                    }
                }
            }
        }
        Ok(blocks)
    }

    /// The file of chunk (or shard) (z, y, x) of the last three axes.
    fn chunk_path(&self, z: u64, y: u64, x: u64) -> PathBuf {
        self.meta
            .dir
            .join(self.meta.keys.key(&self.coords(z, y, x)))
    }

    /// Copies slice `z` (inside `row`) to `out`, converting to f32; returns how many voxels were
    /// saturated (`VolumeSource::saturated_voxels`).
    fn serve(&self, row: &Row, z: u64, out: &mut [f32]) -> u64 {
        let mut saturated = 0;
        let [cz, cy, cx] = self.extent;
        let [nx, ny] = [self.grid.dims[0], self.grid.dims[1]];
        let elem = self.meta.ztype.size();
        let zl = z - row.index * cz;
        for (i, block) in row.blocks.iter().enumerate() {
            let (y0, x0) = (
                (i as u64 / self.across[1]) * cy,
                (i as u64 % self.across[1]) * cx,
            );
            let width = cx.min(nx - x0) as usize;
            for yl in 0..cy.min(ny - y0) {
                let at = ((y0 + yl) * nx + x0) as usize;
                let dst = &mut out[at..at + width];
                match block {
                    Some(b) => {
                        let src = ((zl * cy + yl) * cx) as usize * elem;
                        saturated +=
                            self.meta
                                .ztype
                                .decode(self.endian, &b[src..src + width * elem], dst);
                    }
                    None => {
                        dst.fill(self.meta.fill);
                        if self.meta.fill_saturated {
                            saturated += width as u64;
                        }
                    }
                }
            }
        }
        saturated
    }
}

/// The bytes of a chunk file, or None when the store does not have it.
fn read_chunk(path: &Path) -> Result<Option<Vec<u8>>, VolumeError> {
    match std::fs::read(path) {
        Ok(b) => Ok(Some(b)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(VolumeError::io(path, "read", e)),
    }
}

/// An open shard file and its decoded index.
struct Shard {
    path: PathBuf,
    file: File,
    len: u64,
    index: Vec<[u64; 2]>,
}

impl Shard {
    /// Opens a shard and reads its index; None when the shard is missing (all fill value).
    fn open(path: PathBuf, sh: &Sharding) -> Result<Option<Shard>, VolumeError> {
        let mut file = match File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(VolumeError::io(&path, "open", e)),
        };
        let len = file
            .metadata()
            .map_err(|e| VolumeError::io(&path, "read", e))?
            .len();
        let index_len = sh.index_len().filter(|&n| n <= len).ok_or_else(|| {
            VolumeError::format(
                &path,
                "shard index",
                format!(
                    "an index for {} inner chunks",
                    sh.inner_count().map_or("2^64+".into(), |n| n.to_string())
                ),
                format!("a {len}-byte file (truncated shard?)"),
            )
        })?;
        let start = if sh.index_at_end { len - index_len } else { 0 };
        let bytes = read_range(&mut file, &path, start, index_len)?;
        let index = sh.decode_index(&path, bytes)?;
        Ok(Some(Shard {
            path,
            file,
            len,
            index,
        }))
    }

    /// The stored bytes of inner chunk `i`, or None when it is empty.
    fn read(&mut self, i: u64) -> Result<Option<Vec<u8>>, VolumeError> {
        let [offset, n] = self.index.get(i as usize).copied().unwrap_or_default();
        if [offset, n] == [u64::MAX; 2] {
            return Ok(None);
        }
        if offset.checked_add(n).is_none_or(|end| end > self.len) {
            return Err(VolumeError::format(
                &self.path,
                format!("shard index entry {i}"),
                format!("a byte range inside the {}-byte shard", self.len),
                format!("offset {offset} length {n}"),
            ));
        }
        read_range(&mut self.file, &self.path, offset, n).map(Some)
    }
}

fn read_range(file: &mut File, path: &Path, start: u64, n: u64) -> Result<Vec<u8>, VolumeError> {
    let mut buf = vec![0u8; n as usize];
    file.seek(SeekFrom::Start(start))
        .and_then(|_| file.read_exact(&mut buf))
        .map_err(|e| VolumeError::io(path, "read", e))?;
    Ok(buf)
}

impl VolumeSource for ZarrVolume {
    fn grid(&self) -> Grid {
        self.grid
    }

    fn describe(&self) -> String {
        self.meta.dir.display().to_string()
    }

    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        check_request(self, z, out)?;
        let depth = self.extent[0];
        let bz = z / depth;
        if self.row.as_ref().map(|r| r.index) != Some(bz) {
            if let Some((pz, s)) = &self.prev
                && *pz == z
            {
                out.copy_from_slice(s);
                return Ok(());
            }
            if let Some(row) = self.row.take()
                && row.index + 1 == bz
            {
                let mut last = match self.prev.take() {
                    Some((_, s)) => s,
                    None => vec![0.0; out.len()],
                };
                // Kept for a re-read: its voxels were counted when it was served.
                self.serve(&row, bz * depth - 1, &mut last);
                self.prev = Some((bz * depth - 1, last));
            }
            // The old row is gone before the new one is decoded: never two rows at once.
            self.row = Some(Row {
                index: bz,
                blocks: self.load_row(bz)?,
            });
        }
        if let Some(row) = &self.row {
            self.saturated += self.serve(row, z, out);
        }
        Ok(())
    }

    fn saturated_voxels(&self) -> u64 {
        self.saturated
    }

    fn dtype(&self) -> Option<Dtype> {
        self.meta.ztype.dtype()
    }

    fn loads_whole_volume(&self) -> bool {
        self.extent[0] >= self.grid.dims[2]
    }
}
