//! Blosc 1 frames (c-blosc's format version 2, what numcodecs' `Blosc` writes), decoded in pure
//! Rust so that OME-Zarr v0.4 data (Blosc lz4 + shuffle by default) reads without a C toolchain.
//!
//! A frame is a 16-byte header (version, compressor version, flags, typesize, decoded size,
//! block size, frame size, the sizes little-endian u32), then either the raw bytes (the
//! "memcpyed" flag: data that did not compress) or one start offset per block followed by the
//! blocks. A block is `typesize` streams (one per byte of the element, after a shuffle) or one
//! stream, each a u32 length and that many bytes compressed by the frame's one internal codec
//! (stored raw when the length equals the stream's decoded size). The decoded block is then
//! un-shuffled: byte shuffle (byte j of every element together) or bit shuffle (bit b of byte j
//! of every element together).
//!
//! Internal codecs: blosclz (decoded here: a FastLZ-style LZ77), lz4 and lz4hc (one block
//! format: `lz4_flex`), zlib (`flate2`) and zstd (`ruzstd`). snappy is refused.
//!
//! Every size comes from the frame and is checked before it is used: the decoded size against
//! the chunk's (so a corrupt header cannot make us allocate gigabytes), every offset and length
//! against the frame, every stream's decoded size against its slot. A frame that fails a check
//! is a [`BloscError`], never a panic.

use crate::VolumeError;
use std::io::Read;
use std::path::Path;

/// Bytes of the frame header.
const HEADER: usize = 16;
/// The one frame format version Blosc 1 writes (and c-blosc 1.x reads).
const VERSION: u8 = 2;
/// Flag bits of the header's third byte.
const BYTE_SHUFFLE: u8 = 0x1;
const MEMCPYED: u8 = 0x2;
const BIT_SHUFFLE: u8 = 0x4;
/// Reserved: set only by formats newer than Blosc 1.
const FUTURE: u8 = 0x8;
const DONT_SPLIT: u8 = 0x10;
/// c-blosc splits a block into one stream per byte of the element only for elements of at most
/// this many bytes, and blocks of at least `MIN_SPLIT_ELEMENTS` elements; frames written before
/// the "don't split" flag existed rely on the same rule.
const MAX_SPLITS: usize = 16;
const MIN_SPLIT_ELEMENTS: usize = 128;

/// Why a Blosc frame was not decoded. Each says what is wrong; [`BloscError::fix`] says what to
/// do about it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum BloscError {
    #[error("{0} bytes, shorter than the 16-byte Blosc header")]
    Short(usize),
    #[error("Blosc format version {0}, but only version 2 (Blosc 1, as numcodecs writes) is read")]
    Version(u8),
    #[error("header flags {0:#04x} set bit 3, which no Blosc 1 writer sets")]
    Flags(u8),
    #[error("internal compressor {0}, which this reader does not decode")]
    Compressor(String),
    #[error("header says {nbytes} decoded bytes but a chunk of this array holds at most {limit}")]
    TooLarge { nbytes: u64, limit: usize },
    #[error("header says the frame is {cbytes} bytes but the chunk file has {len}")]
    Truncated { cbytes: u64, len: usize },
    #[error("header says {0}")]
    Header(String),
    #[error("block {block}: {problem}")]
    Block { block: usize, problem: String },
}

impl BloscError {
    /// What the user can do about it, in one clause.
    pub(crate) fn fix(&self) -> &'static str {
        match self {
            BloscError::Version(_) | BloscError::Flags(_) => {
                "only Blosc 1 frames of format version 2 are read (not Blosc2 frames, not a damaged or foreign chunk); write the array with numcodecs' Blosc (Blosc 1) or zstd"
            }
            BloscError::Compressor(_) => {
                "re-encode the array with Blosc cname lz4, zstd, zlib or blosclz, or with zstd"
            }
            BloscError::TooLarge { .. } => {
                "the chunk does not match the chunk shape and dtype in the array metadata; check them"
            }
            _ => "the chunk file is damaged or truncated; write it again from the source data",
        }
    }
}

impl BloscError {
    /// The crate's error for this frame, naming the chunk file.
    pub(crate) fn in_file(self, file: &Path) -> VolumeError {
        VolumeError::Blosc {
            file: file.display().to_string(),
            problem: self.to_string(),
            fix: self.fix(),
        }
    }
}

/// The frame's internal codec (header flags bits 5 to 7).
#[derive(Debug, Clone, Copy)]
enum Internal {
    BloscLz,
    /// lz4 and lz4hc: one block format.
    Lz4,
    Zlib,
    Zstd,
}

/// The header fields decoding needs.
struct Header {
    flags: u8,
    typesize: usize,
    nbytes: usize,
    blocksize: usize,
    cbytes: usize,
}

fn le32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Decodes one Blosc frame. `limit` is the most a chunk may decode to (the array's chunk bytes,
/// plus any checksum still inside): the header's decoded size is checked against it before
/// anything is allocated.
pub(crate) fn decompress(frame: &[u8], limit: usize) -> Result<Vec<u8>, BloscError> {
    let h = header(frame, limit)?;
    let mut out = Vec::new();
    out.try_reserve_exact(h.nbytes)
        .map_err(|e| BloscError::Header(format!("{} decoded bytes ({e})", h.nbytes)))?;
    out.resize(h.nbytes, 0);
    if h.nbytes == 0 {
        return Ok(out);
    }
    let frame = &frame[..h.cbytes];
    if h.flags & MEMCPYED != 0 {
        // Stored as is (c-blosc requires the frame to be exactly header + data).
        if h.cbytes != HEADER + h.nbytes {
            return Err(BloscError::Header(format!(
                "a stored (memcpyed) frame of {} bytes for {} decoded bytes",
                h.cbytes, h.nbytes
            )));
        }
        out.copy_from_slice(&frame[HEADER..]);
        return Ok(out);
    }
    let codec = match h.flags >> 5 {
        0 => Internal::BloscLz,
        1 => Internal::Lz4,
        2 => return Err(BloscError::Compressor("snappy".into())),
        3 => Internal::Zlib,
        4 => Internal::Zstd,
        n => return Err(BloscError::Compressor(format!("code {n}"))),
    };
    let nblocks = h.nbytes.div_ceil(h.blocksize);
    if HEADER + 4 * nblocks > h.cbytes {
        return Err(BloscError::Header(format!(
            "{nblocks} blocks, whose offsets alone do not fit in the {}-byte frame",
            h.cbytes
        )));
    }
    let mut scratch = vec![0u8; h.blocksize];
    for (block, dest) in out.chunks_mut(h.blocksize).enumerate() {
        let start = le32(frame, HEADER + 4 * block) as usize;
        decode_block(frame, start, &h, codec, dest, &mut scratch)
            .map_err(|problem| BloscError::Block { block, problem })?;
    }
    Ok(out)
}

fn header(frame: &[u8], limit: usize) -> Result<Header, BloscError> {
    if frame.len() < HEADER {
        return Err(BloscError::Short(frame.len()));
    }
    if frame[0] != VERSION {
        return Err(BloscError::Version(frame[0]));
    }
    let flags = frame[2];
    if flags & FUTURE != 0 {
        return Err(BloscError::Flags(flags));
    }
    let [nbytes, blocksize, cbytes] = [4, 8, 12].map(|at| le32(frame, at));
    if nbytes as u64 > limit as u64 {
        return Err(BloscError::TooLarge {
            nbytes: nbytes.into(),
            limit,
        });
    }
    if cbytes as usize > frame.len() || (cbytes as usize) < HEADER {
        return Err(BloscError::Truncated {
            cbytes: cbytes.into(),
            len: frame.len(),
        });
    }
    let typesize = frame[3] as usize;
    // c-blosc refuses these too (its caller's buffer holds exactly the decoded size).
    if nbytes > 0 && (typesize == 0 || blocksize == 0 || blocksize > nbytes) {
        return Err(BloscError::Header(format!(
            "typesize {typesize} and block size {blocksize} for {nbytes} decoded bytes"
        )));
    }
    Ok(Header {
        flags,
        typesize,
        nbytes: nbytes as usize,
        blocksize: blocksize as usize,
        cbytes: cbytes as usize,
    })
}

/// Decodes the block starting at byte `start` of `frame` into `dest` (its decoded length: the
/// block size, or what is left for the last block). `scratch` holds a shuffled block.
fn decode_block(
    frame: &[u8],
    start: usize,
    h: &Header,
    codec: Internal,
    dest: &mut [u8],
    scratch: &mut [u8],
) -> Result<(), String> {
    let bsize = dest.len();
    let ts = h.typesize;
    // The rules of c-blosc's blosc_d: a short last block is never split, nor shuffled by bytes
    // for 1-byte elements, nor by bits when smaller than one element.
    let leftover = bsize < h.blocksize;
    let split = h.flags & DONT_SPLIT == 0
        && ts <= MAX_SPLITS
        && bsize / ts >= MIN_SPLIT_ELEMENTS
        && !leftover;
    let nsplits = if split { ts } else { 1 };
    if !bsize.is_multiple_of(nsplits) {
        return Err(format!(
            "{bsize} bytes do not split into {nsplits} streams (block size not a multiple of typesize {ts})"
        ));
    }
    let byte_shuffle = h.flags & BYTE_SHUFFLE != 0 && ts > 1;
    let bit_shuffle = !byte_shuffle && h.flags & BIT_SHUFFLE != 0 && bsize >= ts;
    let neblock = bsize / nsplits;
    let target: &mut [u8] = if byte_shuffle || bit_shuffle {
        &mut scratch[..bsize]
    } else {
        &mut *dest
    };
    let mut pos = start;
    for (j, part) in target.chunks_mut(neblock).enumerate() {
        let len = pos
            .checked_add(4)
            .filter(|&e| e <= frame.len())
            .map(|_| le32(frame, pos) as usize)
            .ok_or_else(|| {
                format!(
                    "stream {j} starts at byte {pos}, past the end of the {}-byte frame",
                    frame.len()
                )
            })?;
        let body = (pos + 4)
            .checked_add(len)
            .and_then(|end| frame.get(pos + 4..end))
            .ok_or_else(|| {
                format!(
                    "stream {j} of {len} bytes at byte {} runs past the end of the {}-byte frame",
                    pos + 4,
                    frame.len()
                )
            })?;
        if len == neblock {
            part.copy_from_slice(body);
        } else {
            let n = match codec {
                Internal::BloscLz => blosclz(body, part)?,
                Internal::Lz4 => {
                    lz4_flex::block::decompress_into(body, part).map_err(|e| format!("lz4: {e}"))?
                }
                Internal::Zlib => fill("zlib", flate2::read::ZlibDecoder::new(body), part)?,
                Internal::Zstd => {
                    if !body.starts_with(&[0x28, 0xB5, 0x2F, 0xFD]) {
                        return Err("zstd: no frame magic number".into());
                    }
                    let d = ruzstd::decoding::StreamingDecoder::new(body)
                        .map_err(|e| format!("zstd: {e}"))?;
                    fill("zstd", d, part)?
                }
            };
            if n != neblock {
                return Err(format!(
                    "stream {j} decoded to {n} bytes instead of {neblock}"
                ));
            }
        }
        pos += 4 + len;
    }
    if byte_shuffle {
        unshuffle(ts, &scratch[..bsize], dest);
    } else if bit_shuffle {
        bit_unshuffle(ts, &scratch[..bsize], dest);
    }
    Ok(())
}

/// Reads a decompressor into `out`; returns how many bytes it gave, and refuses more than fit.
fn fill(what: &str, mut r: impl Read, out: &mut [u8]) -> Result<usize, String> {
    let mut n = 0;
    while n < out.len() {
        match r.read(&mut out[n..]) {
            Ok(0) => return Ok(n),
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(format!("{what}: {e}")),
        }
    }
    let mut extra = [0u8; 1];
    match r.read(&mut extra) {
        Ok(0) => Ok(n),
        Ok(_) => Err(format!(
            "{what}: more than the {} bytes expected",
            out.len()
        )),
        Err(e) => Err(format!("{what}: {e}")),
    }
}

/// blosclz, Blosc's own LZ77 (derived from FastLZ): a stream of instructions, each a literal
/// run (control byte below 32: copy control + 1 bytes) or a match (top three bits the length,
/// 7 meaning more length bytes follow until one is not 255; the low five bits and the next byte
/// the distance, 31 and 255 meaning a 16-bit distance follows, counted beyond 8191). The first
/// byte's top three bits are a level marker. Written from the format, as c-blosc 1.21 decodes
/// it; returns the bytes written (the caller checks the count).
fn blosclz(src: &[u8], dst: &mut [u8]) -> Result<usize, String> {
    const FAR: usize = 8191;
    let early = || "blosclz: data ends inside an instruction".to_string();
    let Some(&first) = src.first() else {
        return Ok(0);
    };
    let mut ip = 1;
    let mut op = 0;
    let mut ctrl = usize::from(first & 31);
    loop {
        if ctrl >= 32 {
            let mut len = (ctrl >> 5) - 1;
            let ofs = (ctrl & 31) << 8;
            // Each length byte, and the distance byte, must leave at least one byte after it.
            if len == 6 {
                loop {
                    if ip + 1 >= src.len() {
                        return Err(early());
                    }
                    let code = src[ip];
                    ip += 1;
                    len += usize::from(code);
                    if code != 255 {
                        break;
                    }
                }
            } else if ip + 1 >= src.len() {
                return Err(early());
            }
            let code = usize::from(src[ip]);
            ip += 1;
            len += 3;
            let mut dist = ofs + code + 1;
            if code == 255 && ofs == 31 << 8 {
                if ip + 1 >= src.len() {
                    return Err(early());
                }
                dist = ((usize::from(src[ip]) << 8) | usize::from(src[ip + 1])) + FAR + 1;
                ip += 2;
            }
            if op + len > dst.len() {
                return Err(format!(
                    "blosclz: a match of {len} bytes at {op} runs past the {}-byte output",
                    dst.len()
                ));
            }
            if dist > op {
                return Err(format!(
                    "blosclz: a match at {op} refers {dist} bytes back, before the start"
                ));
            }
            // As in c-blosc: a match with nothing after it ends the stream uncopied (valid
            // streams end with literals), so the caller's size check refuses it.
            if ip >= src.len() {
                break;
            }
            ctrl = usize::from(src[ip]);
            ip += 1;
            if dist >= len {
                dst.copy_within(op - dist..op - dist + len, op);
            } else {
                // Overlapping: each byte may be one this match just wrote (runs).
                for k in op..op + len {
                    dst[k] = dst[k - dist];
                }
            }
            op += len;
        } else {
            let run = ctrl + 1;
            if op + run > dst.len() || ip + run > src.len() {
                return Err(format!(
                    "blosclz: a literal run of {run} bytes at {op} runs past the input or the {}-byte output",
                    dst.len()
                ));
            }
            dst[op..op + run].copy_from_slice(&src[ip..ip + run]);
            op += run;
            ip += run;
            if ip >= src.len() {
                break;
            }
            ctrl = usize::from(src[ip]);
            ip += 1;
        }
    }
    Ok(op)
}

/// Undoes Blosc's byte shuffle of a block of `ts`-byte elements: the shuffled block holds byte 0
/// of every element, then byte 1, and so on; trailing bytes short of an element are as stored.
fn unshuffle(ts: usize, src: &[u8], dest: &mut [u8]) {
    let n = src.len() / ts;
    if n == 0 {
        dest.copy_from_slice(src);
        return;
    }
    for (j, plane) in src[..n * ts].chunks_exact(n).enumerate() {
        for (i, &b) in plane.iter().enumerate() {
            dest[i * ts + j] = b;
        }
    }
    dest[n * ts..].copy_from_slice(&src[n * ts..]);
}

/// Undoes Blosc's bit shuffle (the bitshuffle library's transform, as c-blosc's
/// bitshuffle-generic.c does it) of a block of `ts`-byte elements. The shuffled block is
/// `8 * ts` rows of `n / 8` bytes: row `8 j + b` holds bit `b` of byte `j` of element `i` at bit
/// `i % 8` of its byte `i / 8`. Only a whole number of 8 elements is shuffled: a block of
/// another count is stored as is, and bytes short of an element stay as stored.
fn bit_unshuffle(ts: usize, src: &[u8], dest: &mut [u8]) {
    let n = src.len() / ts;
    if n == 0 || !n.is_multiple_of(8) {
        dest.copy_from_slice(src);
        return;
    }
    let body = n * ts;
    dest[..body].fill(0);
    for (row, bits) in src[..body].chunks_exact(n / 8).enumerate() {
        let (j, b) = (row / 8, row % 8);
        for (k, &byte) in bits.iter().enumerate() {
            for m in 0..8 {
                if byte >> m & 1 != 0 {
                    dest[(k * 8 + m) * ts + j] |= 1 << b;
                }
            }
        }
    }
    dest[body..].copy_from_slice(&src[body..]);
}

#[cfg(test)]
mod tests {
    //! Against frames written by the reference implementation (numcodecs 0.15's c-blosc 1.21,
    //! `tools/make_zarr_fixtures.py`, committed under `tests/data/zarr/blosc`).

    use super::*;
    use proptest::prelude::*;
    use std::path::PathBuf;

    const CNAMES: [&str; 5] = ["blosclz", "lz4", "lz4hc", "zlib", "zstd"];
    const SHUFFLES: [&str; 3] = ["noshuffle", "shuffle", "bitshuffle"];
    const TYPESIZES: [usize; 4] = [1, 2, 4, 8];

    fn data(name: &str) -> Vec<u8> {
        let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/zarr/blosc")
            .join(name);
        std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
    }

    /// The generator's `block_data`: value i is (i / 3) % 200 + i % 7, as uint8, uint16,
    /// float32 or float64, little-endian, 270000 bytes.
    fn block_data(ts: usize) -> Vec<u8> {
        let v = |i: usize| (i / 3) % 200 + i % 7;
        (0..270000 / ts)
            .flat_map(|i| match ts {
                1 => vec![v(i) as u8],
                2 => (v(i) as u16).to_le_bytes().to_vec(),
                4 => (v(i) as f32).to_le_bytes().to_vec(),
                _ => (v(i) as f64).to_le_bytes().to_vec(),
            })
            .collect()
    }

    /// Every committed frame with the bytes it must decode to.
    fn frames() -> Vec<(String, Vec<u8>, Vec<u8>)> {
        let mut all = Vec::new();
        for ts in TYPESIZES {
            let raw = data(&format!("data_t{ts}.raw"));
            for cname in CNAMES {
                for shuffle in SHUFFLES {
                    let name = format!("{cname}_{shuffle}_t{ts}");
                    all.push((name.clone(), data(&format!("{name}.blosc")), raw.clone()));
                    let blocks = if cname == "zstd" {
                        Some(raw.clone())
                    } else {
                        (ts <= 2).then(|| block_data(ts))
                    };
                    if let Some(want) = blocks {
                        let name = format!("{name}_blocks");
                        all.push((name.clone(), data(&format!("{name}.blosc")), want));
                    }
                }
            }
            all.push((
                format!("memcpyed_t{ts}"),
                data(&format!("memcpyed_t{ts}.blosc")),
                raw,
            ));
        }
        all.push(("random".into(), data("random.blosc"), data("random.raw")));
        all
    }

    #[test]
    fn every_reference_frame_decodes_to_its_bytes() {
        // (compressor code, split, memcpyed, several blocks, shuffle flags) seen, to show the
        // fixtures reach every path.
        let mut seen = std::collections::BTreeSet::new();
        for (name, frame, want) in frames() {
            let got = decompress(&frame, want.len()).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(got == want, "{name}: decoded bytes differ");
            let nbytes = le32(&frame, 4);
            seen.insert((
                frame[2] >> 5,
                frame[2] & DONT_SPLIT == 0,
                frame[2] & MEMCPYED != 0,
                nbytes > le32(&frame, 8),
                frame[2] & (BYTE_SHUFFLE | BIT_SHUFFLE),
            ));
        }
        for code in [0, 1, 3, 4] {
            for shuffle in [0, BYTE_SHUFFLE, BIT_SHUFFLE] {
                assert!(
                    seen.iter().any(|s| s.0 == code && !s.2 && s.4 == shuffle),
                    "no compressed frame of compressor {code} with shuffle flags {shuffle}"
                );
            }
            assert!(
                seen.iter().any(|s| s.0 == code && !s.2 && s.3),
                "no multi-block {code}"
            );
        }
        assert!(seen.iter().any(|s| s.1 && !s.2), "no split frame");
        assert!(seen.iter().any(|s| !s.1 && !s.2), "no unsplit frame");
        assert!(seen.iter().any(|s| s.2), "no memcpyed frame");
    }

    /// A header whose decoded size exceeds the chunk is refused before anything is allocated.
    #[test]
    fn a_frame_larger_than_its_chunk_is_refused() {
        let frame = data("lz4_shuffle_t2.blosc");
        assert_eq!(
            decompress(&frame, 3999),
            Err(BloscError::TooLarge {
                nbytes: 4000,
                limit: 3999
            })
        );
        let mut huge = frame.clone();
        huge[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            decompress(&huge, 4000),
            Err(BloscError::TooLarge { .. })
        ));
    }

    #[test]
    fn unknown_formats_and_compressors_are_refused() {
        let frame = data("lz4_shuffle_t2.blosc");
        let with = |at: usize, v: u8| {
            let mut f = frame.clone();
            f[at] = v;
            decompress(&f, 4000)
        };
        assert_eq!(with(0, 3), Err(BloscError::Version(3)));
        assert_eq!(
            with(2, frame[2] | FUTURE),
            Err(BloscError::Flags(frame[2] | FUTURE))
        );
        assert_eq!(
            with(2, (frame[2] & 31) | 2 << 5),
            Err(BloscError::Compressor("snappy".into()))
        );
        assert_eq!(
            with(2, (frame[2] & 31) | 6 << 5),
            Err(BloscError::Compressor("code 6".into()))
        );
        assert_eq!(decompress(&frame[..10], 4000), Err(BloscError::Short(10)));
        let e = BloscError::Compressor("snappy".into()).in_file(Path::new("s0/0/0/0"));
        assert_eq!(
            e.to_string(),
            "s0/0/0/0: blosc chunk: internal compressor snappy, which this reader does not decode; re-encode the array with Blosc cname lz4, zstd, zlib or blosclz, or with zstd"
        );
    }

    /// A chunk file cut short (the header's frame size then exceeds the file), or cut and
    /// patched to look whole, is an error naming the block, never a panic.
    #[test]
    fn truncated_frames_are_errors() {
        for (name, frame, want) in frames() {
            for cut in [frame.len() - 1, frame.len() / 2, 17] {
                let short = &frame[..cut];
                assert!(
                    matches!(
                        decompress(short, want.len()),
                        Err(BloscError::Truncated { .. })
                    ),
                    "{name} cut to {cut}"
                );
                let mut patched = short.to_vec();
                patched[12..16].copy_from_slice(&(cut as u32).to_le_bytes());
                assert!(
                    decompress(&patched, want.len()).is_err(),
                    "{name} patched to {cut}"
                );
            }
        }
        let frame = data("blosclz_shuffle_t4.blosc");
        let mut patched = frame[..frame.len() - 40].to_vec();
        let len = patched.len() as u32;
        patched[12..16].copy_from_slice(&len.to_le_bytes());
        let e = decompress(&patched, 4000).unwrap_err();
        assert!(matches!(e, BloscError::Block { block: 0, .. }), "{e}");
        assert_eq!(
            e.fix(),
            "the chunk file is damaged or truncated; write it again from the source data"
        );
    }

    #[test]
    fn blosclz_runs_far_matches_and_bad_references() {
        // Literal "ab", then a match of (3 - 1) + 3 = 5 bytes at distance 1 + 1 (overlapping:
        // "ababa"), then literal "z".
        let stream = [1, b'a', b'b', 3 << 5, 1, 0, b'z'];
        let mut out = [0u8; 8];
        assert_eq!(blosclz(&stream, &mut out), Ok(8));
        assert_eq!(&out, b"abababaz");
        // A match reaching before the output's start.
        let mut out = [0u8; 8];
        assert!(blosclz(&[1, b'a', b'b', 3 << 5, 5, 0, b'z'], &mut out).is_err());
        // A far match: 8192 literal bytes, then 4 bytes from the start, spelled with the 16-bit
        // distance escape (low bits 31, distance byte 255, then 0x0000: 8191 + 0 + 1 back).
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for k in 0..256 {
            stream.push(31);
            let run: Vec<u8> = (0..32).map(|i| (k * 32 + i) as u8 ^ (k as u8)).collect();
            stream.extend_from_slice(&run);
            want.extend_from_slice(&run);
        }
        stream.extend_from_slice(&[(2 << 5) | 31, 255, 0, 0, 0, b'!']);
        want.extend_from_within(..4);
        want.push(b'!');
        let mut out = vec![0u8; want.len()];
        assert_eq!(blosclz(&stream, &mut out), Ok(want.len()));
        assert_eq!(out, want);
    }

    /// A frame made by hand: stored (uncompressed) streams, one per block.
    fn stored_frame(flags: u8, ts: u8, blocksize: u32, blocks: &[&[u8]]) -> Vec<u8> {
        let nbytes: usize = blocks.iter().map(|b| b.len()).sum();
        let mut f = vec![VERSION, 1, flags, ts];
        f.extend_from_slice(&(nbytes as u32).to_le_bytes());
        f.extend_from_slice(&blocksize.to_le_bytes());
        f.extend_from_slice(&[0; 4]);
        let mut at = HEADER + 4 * blocks.len();
        for b in blocks {
            f.extend_from_slice(&(at as u32).to_le_bytes());
            at += 4 + b.len();
        }
        for b in blocks {
            f.extend_from_slice(&(b.len() as u32).to_le_bytes());
            f.extend_from_slice(b);
        }
        let len = f.len() as u32;
        f[12..16].copy_from_slice(&len.to_le_bytes());
        f
    }

    /// A last block shorter than one element (a size that is no multiple of the typesize) is
    /// stored as is under either shuffle, as c-blosc does (it was a panic: chunks of 0 bytes).
    #[test]
    fn a_block_shorter_than_an_element_is_kept_as_stored() {
        for shuffle in [BYTE_SHUFFLE, BIT_SHUFFLE] {
            let f = stored_frame(
                shuffle | DONT_SPLIT,
                4,
                8,
                &[&[0, 2, 4, 6, 1, 3, 5, 7], &[9, 8]],
            );
            let want: &[u8] = if shuffle == BYTE_SHUFFLE {
                &[0, 4, 1, 5, 2, 6, 3, 7, 9, 8]
            } else {
                // Two elements: not a multiple of 8, so bit shuffle left them as they were.
                &[0, 2, 4, 6, 1, 3, 5, 7, 9, 8]
            };
            assert_eq!(decompress(&f, 10).as_deref(), Ok(want), "flags {shuffle}");
        }
    }

    #[test]
    fn shuffles_invert() {
        // Byte shuffle of three 4-byte elements plus 2 trailing bytes.
        let src = [0, 4, 8, 1, 5, 9, 2, 6, 10, 3, 7, 11, 12, 13];
        let mut dest = [0u8; 14];
        unshuffle(4, &src, &mut dest);
        assert_eq!(dest, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]);
        // Bit shuffle of 8 one-byte elements: row b holds bit b of each, element i at bit i.
        let elements = [0b1000_0001u8, 2, 4, 8, 16, 32, 64, 128];
        let mut rows = [0u8; 8];
        for (i, e) in elements.iter().enumerate() {
            for (b, row) in rows.iter_mut().enumerate() {
                *row |= (e >> b & 1) << i;
            }
        }
        let mut dest = [0u8; 8];
        bit_unshuffle(1, &rows, &mut dest);
        assert_eq!(dest, elements);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// Random byte changes anywhere in a frame (header included) give an error or some
        /// bytes, never a panic or an allocation beyond the limit.
        #[test]
        fn mutated_frames_never_panic(
            pick in 0usize..12,
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        ) {
            let names = [
                "blosclz_shuffle_t4", "blosclz_noshuffle_t1_blocks", "lz4_shuffle_t2",
                "lz4hc_bitshuffle_t8", "zlib_shuffle_t2_blocks", "zstd_bitshuffle_t4_blocks",
                "lz4_bitshuffle_t1_blocks", "blosclz_bitshuffle_t2", "zlib_noshuffle_t8",
                "zstd_shuffle_t8", "memcpyed_t2", "lz4hc_shuffle_t1_blocks",
            ];
            let mut frame = data(&format!("{}.blosc", names[pick]));
            let limit = le32(&frame, 4) as usize;
            for (at, v) in edits {
                let i = at.index(frame.len());
                frame[i] = v;
            }
            if let Ok(out) = decompress(&frame, limit) {
                prop_assert!(out.len() <= limit);
            }
        }
    }
}
