//! The `codecs` list of an array: parsed once at open time, then applied in reverse to every
//! stored chunk (bytes-to-bytes codecs, then the array-to-bytes `bytes` codec, then transposes).
//!
//! Supported: `transpose`, `bytes`, `gzip`, `zstd`, `blosc` (decoded in pure Rust, `blosc.rs`),
//! `crc32c` (verified) and `sharding_indexed` (as the array's only codec, with an index of
//! `bytes` + optional `crc32c`). A Zarr v2 array's `compressor` and `order` become the same kind
//! of chain ([`v2`]).

use super::blosc;
use super::json::J;
use crate::{Endian, VolumeError};
use std::io::Read;
use std::path::Path;

/// Largest chunk (or inner chunk) decoded at once. A corrupt or absurd chunk shape must fail at
/// open time, not in the allocator; decoding may briefly hold two copies (transpose), and real
/// stores use chunks of a few MiB.
pub(crate) const MAX_CHUNK_BYTES: u64 = 1 << 29;

/// A codec chain without sharding: what one stored (inner) chunk goes through.
#[derive(Debug, Clone)]
pub(crate) struct Chain {
    /// `transpose` orders in encoding order: encoded axis i is decoded axis `order[i]`.
    transposes: Vec<Vec<usize>>,
    /// Byte order of the decoded elements (`bytes` codec; irrelevant for 1-byte types).
    pub(crate) endian: Endian,
    /// Bytes-to-bytes codecs in encoding order.
    bytes: Vec<BytesCodec>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BytesCodec {
    Gzip,
    Zstd,
    Crc32c,
    Blosc,
    /// A zlib stream (Zarr v2's `zlib` compressor).
    Zlib,
    /// numcodecs' `lz4`: the decoded size (u32, little-endian), then one LZ4 block.
    Lz4,
}

/// How an array's chunks are stored.
#[derive(Debug, Clone)]
pub(crate) enum Codecs {
    Plain(Chain),
    Sharded(Box<Sharding>),
}

/// `sharding_indexed`: each stored chunk (a shard) holds a grid of inner chunks plus an index of
/// (offset, length) pairs, so a reader fetches only the inner chunks it needs.
#[derive(Debug, Clone)]
pub(crate) struct Sharding {
    pub(crate) inner_shape: Vec<u64>,
    /// Inner chunks per shard along each axis.
    pub(crate) grid: Vec<u64>,
    pub(crate) inner: Chain,
    index_endian: Endian,
    index_crc: bool,
    pub(crate) index_at_end: bool,
}

/// Where a codec list sits: the array's own list may shard, the lists inside a shard may not.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Level {
    Array,
    Inner,
    Index,
}

/// Parses the array's `codecs` for chunks of `chunk_shape` holding `elem`-byte values.
pub(crate) fn parse(j: &J, chunk_shape: &[u64], elem: usize) -> Result<Codecs, VolumeError> {
    let items = j.items("a list of codecs")?;
    let sharded = items
        .iter()
        .position(|c| name(c).ok() == Some("sharding_indexed"));
    match sharded {
        Some(i) if items.len() > 1 => Err(items[i].problem(
            "sharding_indexed must be the array's only codec (put the others in its \"codecs\")",
        )),
        Some(i) => Ok(Codecs::Sharded(Box::new(sharding(
            &items[i],
            chunk_shape,
            elem,
        )?))),
        None => {
            check_chunk_size(j, chunk_shape, elem)?;
            Ok(Codecs::Plain(chain(j, chunk_shape.len(), Level::Array)?))
        }
    }
}

fn name<'a>(c: &J<'a>) -> Result<&'a str, VolumeError> {
    // A codec is {"name": ..., "configuration": ...}; a bare name string is accepted too.
    match c.value.as_str() {
        Some(n) => Ok(n),
        None => c.get("name").str("a codec name"),
    }
}

fn check_chunk_size(j: &J, shape: &[u64], elem: usize) -> Result<(), VolumeError> {
    let bytes = shape
        .iter()
        .try_fold(elem as u64, |a, &n| a.checked_mul(n))
        .filter(|&b| b <= MAX_CHUNK_BYTES);
    match bytes {
        Some(_) => Ok(()),
        None => Err(j.problem(&format!(
            "chunks of shape {shape:?} are larger than the {} MiB this reader decodes at once; re-chunk the array",
            MAX_CHUNK_BYTES >> 20
        ))),
    }
}

/// A list of codecs without sharding, in the order array-to-array, `bytes`, bytes-to-bytes.
fn chain(j: &J, rank: usize, level: Level) -> Result<Chain, VolumeError> {
    let mut transposes = Vec::new();
    let mut endian = None;
    let mut bytes = Vec::new();
    for c in j.items("a list of codecs")? {
        let conf = c.get("configuration");
        let n = name(&c)?;
        let misplaced = |what: &str| c.problem(&format!("{n} must come {what}"));
        match n {
            "transpose" if level != Level::Index => {
                if endian.is_some() {
                    return Err(misplaced("before the bytes codec"));
                }
                transposes.push(transpose_order(&conf.get("order"), rank)?);
            }
            "bytes" => {
                if endian.is_some() {
                    return Err(misplaced("once"));
                }
                endian = Some(match conf.get("endian").value.as_str() {
                    None | Some("little") => Endian::Little,
                    Some("big") => Endian::Big,
                    Some(_) => return Err(conf.get("endian").err("\"little\" or \"big\"")),
                });
            }
            "gzip" | "zstd" | "crc32c" | "blosc" if endian.is_none() => {
                return Err(misplaced("after the bytes codec"));
            }
            "crc32c" => bytes.push(BytesCodec::Crc32c),
            "gzip" if level != Level::Index => bytes.push(BytesCodec::Gzip),
            "zstd" if level != Level::Index => bytes.push(BytesCodec::Zstd),
            "blosc" if level != Level::Index => {
                check_blosc_cname(&conf.get("cname"))?;
                let shuffle = conf.get("shuffle");
                match shuffle.value.as_str() {
                    Some("noshuffle" | "shuffle" | "bitshuffle") => {}
                    None if shuffle.is_null() => {}
                    _ => {
                        return Err(shuffle.err("\"noshuffle\", \"shuffle\" or \"bitshuffle\""));
                    }
                }
                bytes.push(BytesCodec::Blosc);
            }
            "sharding_indexed" => {
                return Err(c.problem("sharding_indexed inside a shard is unsupported"));
            }
            _ if level == Level::Index => {
                return Err(c.problem(&format!(
                    "index codec {n:?} unsupported: a shard index must be bytes (+ crc32c)"
                )));
            }
            _ => {
                return Err(c.problem(&format!(
                    "codec {n:?} unsupported: supported are bytes, transpose, gzip, zstd, blosc, crc32c, sharding_indexed"
                )));
            }
        }
    }
    let endian = endian.ok_or_else(|| j.problem("the codecs lack the bytes codec"))?;
    Ok(Chain {
        transposes,
        endian,
        bytes,
    })
}

/// Refuses at open time a Blosc internal compressor the decoder lacks (snappy), rather than at
/// the first chunk. The frames say their compressor themselves, so an absent name is fine.
fn check_blosc_cname(cname: &J) -> Result<(), VolumeError> {
    match cname.value.as_str() {
        None | Some("blosclz" | "lz4" | "lz4hc" | "zlib" | "zstd") => Ok(()),
        Some(other) => Err(cname.problem(&format!(
            "blosc compressor {other:?} unsupported: re-encode with cname lz4, zstd, zlib or blosclz"
        ))),
    }
}

/// The chain of a Zarr v2 array: its `compressor` (null, `blosc`, `zlib`, `gzip`, `zstd` or
/// `lz4`, as numcodecs writes them), its dtype's byte order, and `order` "F" (chunks stored with
/// the axes reversed) as a transpose of all `rank` axes.
pub(crate) fn v2(
    compressor: &J,
    endian: Endian,
    fortran: bool,
    chunk_shape: &[u64],
    elem: usize,
) -> Result<Codecs, VolumeError> {
    check_chunk_size(compressor, chunk_shape, elem)?;
    let rank = chunk_shape.len();
    let transposes = if fortran {
        vec![(0..rank).rev().collect()]
    } else {
        Vec::new()
    };
    let bytes = if compressor.is_null() {
        Vec::new()
    } else {
        let id = compressor.get("id");
        vec![match id.str("a compressor id")? {
            "blosc" => {
                check_blosc_cname(&compressor.get("cname"))?;
                BytesCodec::Blosc
            }
            "zlib" => BytesCodec::Zlib,
            "gzip" => BytesCodec::Gzip,
            "zstd" => BytesCodec::Zstd,
            "lz4" => BytesCodec::Lz4,
            other => {
                return Err(id.problem(&format!(
                    "compressor {other:?} unsupported: supported are blosc, zlib, gzip, zstd, lz4 (or null); re-encode with one of them"
                )));
            }
        }]
    };
    Ok(Codecs::Plain(Chain {
        transposes,
        endian,
        bytes,
    }))
}

/// A `transpose` order: a permutation of the axes (or the older "C" / "F" spelling).
fn transpose_order(j: &J, rank: usize) -> Result<Vec<usize>, VolumeError> {
    let expected = format!("a permutation of 0..{rank}");
    match j.value.as_str() {
        Some("C") => return Ok((0..rank).collect()),
        Some("F") => return Ok((0..rank).rev().collect()),
        _ => {}
    }
    let order = j.u64s(&expected)?;
    let mut seen = vec![false; rank];
    for &a in &order {
        match seen.get_mut(a as usize) {
            Some(s) if !*s => *s = true,
            _ => return Err(j.err(expected)),
        }
    }
    if order.len() != rank {
        return Err(j.err(expected));
    }
    Ok(order.into_iter().map(|a| a as usize).collect())
}

fn sharding(j: &J, shard_shape: &[u64], elem: usize) -> Result<Sharding, VolumeError> {
    let conf = j.get("configuration");
    let cs = conf.get("chunk_shape");
    let inner_shape = cs.u64s("a list of positive integers")?;
    let divides = inner_shape.len() == shard_shape.len()
        && inner_shape
            .iter()
            .zip(shard_shape)
            .all(|(&c, &s)| c > 0 && s % c == 0);
    if !divides {
        return Err(cs.err(format!(
            "one positive size per axis dividing the shard shape {shard_shape:?}"
        )));
    }
    check_chunk_size(&cs, &inner_shape, elem)?;
    let grid = shard_shape
        .iter()
        .zip(&inner_shape)
        .map(|(s, c)| s / c)
        .collect();
    let rank = inner_shape.len();
    let inner = chain(&conf.get("codecs"), rank, Level::Inner)?;
    let index = chain(&conf.get("index_codecs"), rank + 1, Level::Index)?;
    let loc = conf.get("index_location");
    let index_at_end = match loc.value.as_str() {
        None | Some("end") => true,
        Some("start") => false,
        Some(_) => return Err(loc.err("\"start\" or \"end\"")),
    };
    Ok(Sharding {
        inner_shape,
        grid,
        inner,
        index_endian: index.endian,
        index_crc: index.bytes.contains(&BytesCodec::Crc32c),
        index_at_end,
    })
}

impl Sharding {
    /// Inner chunks in one shard, or None when the count overflows (a corrupt shape).
    pub(crate) fn inner_count(&self) -> Option<u64> {
        self.grid.iter().try_fold(1u64, |a, &n| a.checked_mul(n))
    }

    /// Encoded size of the shard index in bytes.
    pub(crate) fn index_len(&self) -> Option<u64> {
        self.inner_count()?
            .checked_mul(16)?
            .checked_add(if self.index_crc { 4 } else { 0 })
    }

    /// Decodes the index: (offset, length) per inner chunk in C order; `u64::MAX` twice means
    /// the inner chunk is empty (fill value).
    pub(crate) fn decode_index(
        &self,
        file: &Path,
        mut bytes: Vec<u8>,
    ) -> Result<Vec<[u64; 2]>, VolumeError> {
        if self.index_crc {
            bytes = check_crc(file, "shard index", bytes)?;
        }
        let word = |b: &[u8]| {
            let a: [u8; 8] = b.try_into().unwrap_or_default();
            match self.index_endian {
                Endian::Little => u64::from_le_bytes(a),
                Endian::Big => u64::from_be_bytes(a),
            }
        };
        Ok(bytes
            .chunks_exact(16)
            .map(|p| [word(&p[..8]), word(&p[8..])])
            .collect())
    }
}

impl Chain {
    /// Decodes one stored chunk of `shape` into C-order elements in `self.endian`.
    pub(crate) fn decode(
        &self,
        file: &Path,
        mut data: Vec<u8>,
        shape: &[u64],
        elem: usize,
    ) -> Result<Vec<u8>, VolumeError> {
        // Sizes were checked against MAX_CHUNK_BYTES when the metadata was read.
        let expected = shape.iter().product::<u64>() as usize * elem;
        // Decompressed sizes may exceed the array by the checksums still inside them.
        let crcs = self
            .bytes
            .iter()
            .filter(|&&c| c == BytesCodec::Crc32c)
            .count();
        let limit = expected + 4 * crcs;
        for codec in self.bytes.iter().rev() {
            data = match codec {
                BytesCodec::Crc32c => check_crc(file, "chunk", data)?,
                BytesCodec::Gzip => inflate(
                    file,
                    "gzip",
                    limit,
                    |d| Ok(Box::new(flate2::read::MultiGzDecoder::new(d))),
                    &data,
                )?,
                BytesCodec::Zstd => inflate(
                    file,
                    "zstd",
                    limit,
                    |d| {
                        // ruzstd reports a bad magic number only in Debug form: say it plainly.
                        if !d.starts_with(&[0x28, 0xB5, 0x2F, 0xFD]) {
                            return Err("no zstd frame magic number".into());
                        }
                        ruzstd::decoding::StreamingDecoder::new(d)
                            .map(|s| Box::new(s) as Box<dyn Read + '_>)
                            .map_err(|e| e.to_string())
                    },
                    &data,
                )?,
                BytesCodec::Zlib => inflate(
                    file,
                    "zlib",
                    limit,
                    |d| Ok(Box::new(flate2::read::ZlibDecoder::new(d))),
                    &data,
                )?,
                BytesCodec::Blosc => {
                    blosc::decompress(&data, limit).map_err(|e| e.in_file(file))?
                }
                BytesCodec::Lz4 => lz4_sized(file, &data, limit)?,
            };
        }
        if data.len() != expected {
            return Err(VolumeError::format(
                file,
                "decoded chunk",
                format!("{expected} bytes (shape {shape:?} of {elem}-byte values)"),
                format!("{} bytes", data.len()),
            ));
        }
        // Undo the transposes, last applied first, tracking the shape each one produced.
        let mut shapes = vec![shape.to_vec()];
        for order in &self.transposes {
            let prev = &shapes[shapes.len() - 1];
            shapes.push(order.iter().map(|&a| prev[a]).collect());
        }
        for (order, enc_shape) in self.transposes.iter().zip(&shapes[1..]).rev() {
            data = untranspose(&data, enc_shape, order, elem);
        }
        Ok(data)
    }
}

/// Runs a decompressor over `data`, refusing output beyond `limit` bytes (a corrupt or hostile
/// chunk must not grow without bound).
fn inflate<'d>(
    file: &Path,
    what: &str,
    limit: usize,
    open: impl FnOnce(&'d [u8]) -> Result<Box<dyn Read + 'd>, String>,
    data: &'d [u8],
) -> Result<Vec<u8>, VolumeError> {
    let bad = |e: String| {
        VolumeError::format(
            file,
            format!("{what} chunk"),
            format!("valid {what} data"),
            e,
        )
    };
    let mut out = Vec::new();
    out.try_reserve_exact(limit + 1)
        .map_err(|e| bad(e.to_string()))?;
    open(data)
        .map_err(bad)?
        .take(limit as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| bad(innermost(&e)))?;
    if out.len() > limit {
        return Err(VolumeError::format(
            file,
            format!("{what} chunk"),
            format!("at most {limit} decompressed bytes"),
            "more",
        ));
    }
    Ok(out)
}

/// Decodes numcodecs' `lz4` (the decoded size as a little-endian u32, then an LZ4 block); the
/// size is checked against `limit` before anything is allocated.
fn lz4_sized(file: &Path, data: &[u8], limit: usize) -> Result<Vec<u8>, VolumeError> {
    let bad =
        |expected: String, found: String| VolumeError::format(file, "lz4 chunk", expected, found);
    let Some((size, block)) = data.split_first_chunk::<4>() else {
        return Err(bad(
            "a 4-byte size and an LZ4 block".into(),
            format!("{} bytes in all", data.len()),
        ));
    };
    let size = u32::from_le_bytes(*size) as usize;
    if size > limit {
        return Err(bad(
            format!("at most {limit} decompressed bytes"),
            format!("a header saying {size}"),
        ));
    }
    let mut out = vec![0u8; size];
    match lz4_flex::block::decompress_into(block, &mut out) {
        Ok(n) if n == size => Ok(out),
        Ok(n) => Err(bad(format!("{size} decompressed bytes"), format!("{n}"))),
        Err(e) => Err(bad("a valid LZ4 block".into(), e.to_string())),
    }
}

/// A decoder's read error in words: ruzstd's own Display shows its inner errors in Debug form
/// ("BlockContentReadError(Error { ..."), so the innermost cause is said instead, and a chunk
/// that ends early as such.
fn innermost(e: &std::io::Error) -> String {
    let mut cause: &dyn std::error::Error = e;
    while let Some(next) = cause.source() {
        cause = next;
    }
    match cause
        .downcast_ref::<std::io::Error>()
        .map(std::io::Error::kind)
    {
        Some(std::io::ErrorKind::UnexpectedEof) => {
            "data that ends early (a truncated chunk)".into()
        }
        _ => cause.to_string(),
    }
}

/// Checks and strips the little-endian CRC-32C that the `crc32c` codec appends.
fn check_crc(file: &Path, what: &str, mut data: Vec<u8>) -> Result<Vec<u8>, VolumeError> {
    let Some(body_len) = data.len().checked_sub(4) else {
        return Err(VolumeError::format(
            file,
            format!("{what} checksum"),
            "a 4-byte crc32c",
            format!("{} bytes in all", data.len()),
        ));
    };
    let stored = u32::from_le_bytes([
        data[body_len],
        data[body_len + 1],
        data[body_len + 2],
        data[body_len + 3],
    ]);
    let actual = crc32c(&data[..body_len]);
    if stored != actual {
        return Err(VolumeError::format(
            file,
            format!("{what} checksum"),
            format!("crc32c {actual:#010x}"),
            format!("{stored:#010x} (corrupt data)"),
        ));
    }
    data.truncate(body_len);
    Ok(data)
}

/// CRC-32C (Castagnoli), as the `crc32c` codec defines it; table-driven, table built at compile time.
pub(crate) fn crc32c(data: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 {
                    (c >> 1) ^ 0x82F6_3B78
                } else {
                    c >> 1
                };
                k += 1;
            }
            t[i] = c;
            i += 1;
        }
        t
    };
    !data.iter().fold(!0u32, |c, &b| {
        TABLE[((c ^ u32::from(b)) & 0xff) as usize] ^ (c >> 8)
    })
}

/// Inverse of `transpose(order)`: `data` is C-order over `enc_shape`, where encoded axis i is
/// decoded axis `order[i]`; returns the C-order decoded array.
fn untranspose(data: &[u8], enc_shape: &[u64], order: &[usize], elem: usize) -> Vec<u8> {
    let rank = enc_shape.len();
    let mut dec_shape = vec![0u64; rank];
    for (i, &a) in order.iter().enumerate() {
        dec_shape[a] = enc_shape[i];
    }
    let mut dec_stride = vec![1u64; rank];
    for a in (0..rank.saturating_sub(1)).rev() {
        dec_stride[a] = dec_stride[a + 1] * dec_shape[a + 1];
    }
    // Stride in the decoded array of a step along each encoded axis.
    let step: Vec<u64> = order.iter().map(|&a| dec_stride[a]).collect();
    let mut out = vec![0u8; data.len()];
    let mut idx = vec![0u64; rank];
    let mut off = 0u64;
    for src in data.chunks_exact(elem) {
        let o = off as usize * elem;
        out[o..o + elem].copy_from_slice(src);
        // Advance the encoded multi-index in C order, keeping `off` in step.
        for a in (0..rank).rev() {
            idx[a] += 1;
            off += step[a];
            if idx[a] < enc_shape[a] {
                break;
            }
            off -= step[a] * idx[a];
            idx[a] = 0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A truncated zstd chunk's error was ruzstd's Debug text ("BlockContentReadError(Error {
    /// ...").
    #[test]
    fn a_truncated_zstd_chunk_is_said_in_words() {
        let values: Vec<u8> = (0..4096u32).map(|i| (i * 7 % 251) as u8).collect();
        let frame = ruzstd::encoding::compress_to_vec(
            &values[..],
            ruzstd::encoding::CompressionLevel::Fastest,
        );
        let cut = &frame[..frame.len() / 2];
        let e = inflate(
            Path::new("c/0/0/0"),
            "zstd",
            1 << 20,
            |d| {
                Ok(Box::new(
                    ruzstd::decoding::StreamingDecoder::new(d).unwrap(),
                ))
            },
            cut,
        )
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            r#"c/0/0/0: zstd chunk: expected valid zstd data, found "data that ends early (a truncated chunk)""#
        );
    }

    #[test]
    fn crc32c_check_value() {
        // The standard check value of CRC-32C.
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
    }

    #[test]
    fn untranspose_inverts_numpy_transpose() {
        // Decoded a[z][y][x] = 100z + 10y + x, shape (2, 3, 4); encoded = a.transpose(2, 0, 1),
        // shape (4, 2, 3): e[x][z][y] = a[z][y][x].
        let mut enc = Vec::new();
        for x in 0..4u8 {
            for z in 0..2u8 {
                for y in 0..3u8 {
                    enc.push(100 * z + 10 * y + x);
                }
            }
        }
        let dec = untranspose(&enc, &[4, 2, 3], &[2, 0, 1], 1);
        let want: Vec<u8> = (0..2u8)
            .flat_map(|z| (0..3u8).flat_map(move |y| (0..4u8).map(move |x| 100 * z + 10 * y + x)))
            .collect();
        assert_eq!(dec, want);
    }
}
