//! SMB, the binary streaming mesh.
//!
//! Header: u8 version 0, u8 endianness (0 little, 1 big), u8 0, u8 0; i32 comment count, then
//! (i32 length, bytes) per comment; i32 nverts, i32 nfaces (-1 if unknown); u8 has_bbox, then
//! 6 f32 (min xyz, max xyz) when 1. Body: blocks of a u32 descriptor (bit i, least significant
//! first: 1 = vertex, 0 = triangle) and up to 32 elements of 12 bytes (3 f32 or 3 i32 indices as
//! in `index`). The last block may be short; its unused descriptor bits are 0.
//!
//! We write little-endian, with has_bbox = 1 and placeholder counts that `end` patches in place
//! (the header has fixed size once the comments are written). An empty mesh gets has_bbox = 0.
//! SMB has no per-vertex attributes and no explicit finalization.
//!
//! Reading checks the declared byte order for plausibility and falls back to the other one:
//! reference writers on x86_64 may declare 1 (big) while writing little-endian data.

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use crate::atomic::AtomicFile;
use crate::reader::{Element, ReadHeader};
use crate::track::Tracker;
use crate::{Format, Header, Place, SmeshError, StreamFault, Subject, index};

const ELEMENT: usize = 12;
const BLOCK: usize = 32;

pub(crate) struct SmbEncoder {
    counts_at: u64,
    descriptor: u32,
    elements: usize,
    block: Vec<u8>,
}

impl SmbEncoder {
    pub(crate) fn begin(out: &mut AtomicFile, header: &Header) -> Result<SmbEncoder, SmeshError> {
        let mut h = vec![0u8, 0, 0, 0];
        h.extend((header.comments.len() as i32).to_le_bytes());
        for c in &header.comments {
            h.extend((c.len() as i32).to_le_bytes());
            h.extend(c.as_bytes());
        }
        let counts_at = h.len() as u64;
        h.extend((-1i32).to_le_bytes());
        h.extend((-1i32).to_le_bytes());
        h.push(1);
        h.extend([0u8; 24]);
        out.write_all(&h)?;
        Ok(SmbEncoder {
            counts_at,
            descriptor: 0,
            elements: 0,
            block: Vec::with_capacity(BLOCK * ELEMENT),
        })
    }

    fn push(
        &mut self,
        out: &mut AtomicFile,
        vertex: bool,
        bytes: [[u8; 4]; 3],
    ) -> Result<(), SmeshError> {
        if vertex {
            self.descriptor |= 1 << self.elements;
        }
        self.block.extend(bytes.as_flattened());
        self.elements += 1;
        if self.elements == BLOCK {
            self.flush_block(out)?;
        }
        Ok(())
    }

    fn flush_block(&mut self, out: &mut AtomicFile) -> Result<(), SmeshError> {
        if self.elements > 0 {
            out.write_all(&self.descriptor.to_le_bytes())?;
            out.write_all(&self.block)?;
            self.block.clear();
            self.descriptor = 0;
            self.elements = 0;
        }
        Ok(())
    }

    pub(crate) fn vertex(&mut self, out: &mut AtomicFile, pos: [f32; 3]) -> Result<(), SmeshError> {
        self.push(out, true, pos.map(f32::to_le_bytes))
    }

    /// `n` already range-checked by the writer to fit i32.
    pub(crate) fn triangle(&mut self, out: &mut AtomicFile, n: [i64; 3]) -> Result<(), SmeshError> {
        self.push(out, false, n.map(|x| (x as i32).to_le_bytes()))
    }

    pub(crate) fn end(mut self, out: &mut AtomicFile, tracker: &Tracker) -> Result<(), SmeshError> {
        self.flush_block(out)?;
        let mut h = Vec::with_capacity(33);
        h.extend((tracker.vertices() as i32).to_le_bytes());
        h.extend((tracker.triangles() as i32).to_le_bytes());
        match tracker.bbox() {
            Some((lo, hi)) => {
                h.push(1);
                for x in lo.iter().chain(&hi) {
                    h.extend(x.to_le_bytes());
                }
                out.patch(self.counts_at, &h)
            }
            None => {
                h.push(0);
                out.patch(self.counts_at, &h)?;
                out.truncate(self.counts_at + h.len() as u64)
            }
        }
    }
}

/// Whether `bytes` start like an SMB file: version 0, endianness 0 or 1, two zero bytes.
pub(crate) fn is_magic(bytes: &[u8]) -> bool {
    bytes.len() >= 4 && bytes[0] == 0 && bytes[1] <= 1 && bytes[2..4] == [0, 0]
}

/// The header fields as parsed under one byte order.
#[derive(Debug)]
struct Parsed {
    comments: Vec<String>,
    nverts: i32,
    nfaces: i32,
    bbox: Option<([f32; 3], [f32; 3])>,
    len: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Order {
    Little,
    Big,
}

impl Order {
    fn i32(self, b: [u8; 4]) -> i32 {
        match self {
            Order::Little => i32::from_le_bytes(b),
            Order::Big => i32::from_be_bytes(b),
        }
    }

    fn u32(self, b: [u8; 4]) -> u32 {
        self.i32(b) as u32
    }

    fn f32(self, b: [u8; 4]) -> f32 {
        f32::from_bits(self.u32(b))
    }
}

/// A cursor over the start of the file for trying both byte orders.
struct Prefix<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Prefix<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let s = self.bytes.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }

    fn word(&mut self) -> Option<[u8; 4]> {
        self.take(4).map(|s| [s[0], s[1], s[2], s[3]])
    }
}

/// Parses the header after the magic under `order`; `None` if it does not fit the prefix.
fn parse_header(bytes: &[u8], order: Order) -> Option<Parsed> {
    let mut p = Prefix { bytes, at: 4 };
    let ncomments = order.i32(p.word()?);
    let mut comments = Vec::new();
    for _ in 0..ncomments.max(0) {
        let len = usize::try_from(order.i32(p.word()?)).ok()?;
        let text = String::from_utf8_lossy(p.take(len)?);
        comments.push(text.trim_end_matches('\0').to_string());
    }
    (ncomments >= 0).then_some(())?;
    let nverts = order.i32(p.word()?);
    let nfaces = order.i32(p.word()?);
    let bbox = match p.take(1)?[0] {
        0 => None,
        1 => {
            let mut f = [0f32; 6];
            for x in &mut f {
                *x = order.f32(p.word()?);
            }
            Some(([f[0], f[1], f[2]], [f[3], f[4], f[5]]))
        }
        _ => return None,
    };
    Some(Parsed {
        comments,
        nverts,
        nfaces,
        bbox,
        len: p.at as u64,
    })
}

/// Whether `h` under `order` describes the file: counts not below -1, known counts matching the
/// file size exactly, and the triangles of the first block (if in the prefix) using valid indices.
fn plausible(h: &Parsed, order: Order, bytes: &[u8], file_len: u64) -> bool {
    if h.nverts < -1 || h.nfaces < -1 {
        return false;
    }
    let data = file_len.saturating_sub(h.len);
    if h.nverts >= 0 && h.nfaces >= 0 {
        let n = h.nverts as u64 + h.nfaces as u64;
        if data != n * ELEMENT as u64 + 4 * n.div_ceil(BLOCK as u64) {
            return false;
        }
    }
    let mut p = Prefix {
        bytes,
        at: h.len as usize,
    };
    let Some(descriptor) = p.word().map(|w| order.u32(w)) else {
        return true;
    };
    let mut vertices = 0u64;
    for bit in 0..BLOCK {
        let Some(e) = p.take(ELEMENT) else { break };
        if descriptor >> bit & 1 == 1 {
            vertices += 1;
            continue;
        }
        for w in e.chunks_exact(4) {
            let n = order.i32([w[0], w[1], w[2], w[3]]) as i64;
            match index::decode(n, vertices) {
                Some(Ok((v, _))) if v < vertices => {}
                _ => return false,
            }
        }
    }
    true
}

pub(crate) struct SmbDecoder {
    input: BufReader<File>,
    order: Order,
    offset: u64,
    descriptor: u32,
    left_in_block: usize,
    declared: Option<(u64, u64)>,
    vertices: u64,
    triangles: u64,
}

impl SmbDecoder {
    pub(crate) fn open(
        path: &Path,
        mut file: File,
    ) -> Result<(SmbDecoder, ReadHeader), SmeshError> {
        let io_err = |e| SmeshError::io(path, "read the SMB header of", e);
        let file_len = file.metadata().map_err(io_err)?.len();
        let mut prefix = Vec::new();
        (&mut file)
            .take(1 << 20)
            .read_to_end(&mut prefix)
            .map_err(io_err)?;
        if !is_magic(&prefix) {
            return Err(SmeshError::BadMagic {
                path: path.to_path_buf(),
                found: prefix.iter().take(4).copied().collect(),
            });
        }
        let declared = if prefix[1] == 0 {
            Order::Little
        } else {
            Order::Big
        };
        let other = if declared == Order::Little {
            Order::Big
        } else {
            Order::Little
        };
        let (h, order) = [declared, other]
            .into_iter()
            .find_map(|o| {
                parse_header(&prefix, o)
                    .filter(|h| plausible(h, o, &prefix, file_len))
                    .map(|h| (h, o))
            })
            .ok_or_else(|| {
                SmeshError::syntax(
                    path,
                    Place::Byte(4),
                    "an SMB header whose counts match the file size in either byte order",
                    format!("{file_len} bytes that fit neither"),
                )
            })?;
        file.seek(SeekFrom::Start(h.len)).map_err(io_err)?;
        let count = |n: i32| u64::try_from(n).ok();
        let header = ReadHeader {
            format: Format::Smb,
            nverts: count(h.nverts),
            nfaces: count(h.nfaces),
            bbox: h.bbox,
            comments: h.comments,
            attribute_names: Vec::new(),
        };
        let dec = SmbDecoder {
            input: BufReader::with_capacity(1 << 16, file),
            order,
            offset: h.len,
            descriptor: 0,
            left_in_block: 0,
            declared: header.nverts.zip(header.nfaces),
            vertices: 0,
            triangles: 0,
        };
        Ok((dec, header))
    }

    /// Reads exactly `buf.len()` bytes; `Ok(false)` on a clean end of file before the first byte.
    fn read(&mut self, path: &Path, buf: &mut [u8], what: &str) -> Result<bool, SmeshError> {
        let mut got = 0;
        while got < buf.len() {
            match self.input.read(&mut buf[got..]) {
                Ok(0) if got == 0 => return Ok(false),
                Ok(0) => {
                    return Err(SmeshError::Truncated {
                        path: path.to_path_buf(),
                        place: Place::Byte(self.offset + got as u64),
                        expected: what.to_string(),
                    });
                }
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(SmeshError::io(
                        path,
                        format!("read byte {} of", self.offset),
                        e,
                    ));
                }
            }
        }
        self.offset += buf.len() as u64;
        Ok(true)
    }

    /// End of data: fine unless the header promised more.
    fn end(&self, path: &Path) -> Option<Result<(Element, Place), SmeshError>> {
        match self.declared {
            Some((nv, nf)) if (self.vertices, self.triangles) != (nv, nf) => {
                Some(Err(SmeshError::Truncated {
                    path: path.to_path_buf(),
                    place: Place::Byte(self.offset),
                    expected: format!(
                        "the stream: {} of {nv} declared vertices and {} of {nf} triangles were read",
                        self.vertices, self.triangles
                    ),
                }))
            }
            _ => None,
        }
    }

    pub(crate) fn next(&mut self, path: &Path) -> Option<Result<(Element, Place), SmeshError>> {
        if self.declared == Some((self.vertices, self.triangles)) {
            return None;
        }
        if self.left_in_block == 0 {
            let mut w = [0u8; 4];
            match self.read(path, &mut w, "a block descriptor (4 bytes)") {
                Ok(true) => {}
                Ok(false) => return self.end(path),
                Err(e) => return Some(Err(e)),
            }
            self.descriptor = self.order.u32(w);
            self.left_in_block = BLOCK;
        }
        let is_vertex = self.descriptor & 1 == 1;
        self.descriptor >>= 1;
        self.left_in_block -= 1;
        let place = Place::Byte(self.offset);
        let mut e = [0u8; ELEMENT];
        let what = if is_vertex {
            "a vertex (12 bytes)"
        } else {
            "a triangle (12 bytes)"
        };
        match self.read(path, &mut e, what) {
            Ok(true) => {}
            Ok(false) => return self.end(path),
            Err(e) => return Some(Err(e)),
        }
        let words: [[u8; 4]; 3] =
            std::array::from_fn(|i| [e[4 * i], e[4 * i + 1], e[4 * i + 2], e[4 * i + 3]]);
        Some(
            self.element(path, place, is_vertex, words)
                .map(|el| (el, place)),
        )
    }

    fn element(
        &mut self,
        path: &Path,
        place: Place,
        is_vertex: bool,
        words: [[u8; 4]; 3],
    ) -> Result<Element, SmeshError> {
        if is_vertex {
            if let Some((nv, _)) = self.declared.filter(|&(nv, _)| self.vertices == nv) {
                return Err(SmeshError::stream(
                    path,
                    Subject::Vertex(self.vertices, place),
                    StreamFault::BeyondDeclared {
                        what: "vertices",
                        declared: nv,
                    },
                ));
            }
            self.vertices += 1;
            return Ok(Element::Vertex {
                pos: words.map(|w| self.order.f32(w)),
                attrs: Vec::new(),
            });
        }
        let subject = Subject::Triangle(self.triangles, place);
        if let Some((_, nf)) = self.declared.filter(|&(_, nf)| self.triangles == nf) {
            return Err(SmeshError::stream(
                path,
                subject,
                StreamFault::BeyondDeclared {
                    what: "triangles",
                    declared: nf,
                },
            ));
        }
        let mut v = [0; 3];
        let mut finalized = [false; 3];
        for i in 0..3 {
            let n = self.order.i32(words[i]) as i64;
            (v[i], finalized[i]) = match index::decode(n, self.vertices) {
                None => {
                    return Err(SmeshError::syntax(
                        path,
                        place,
                        "nonzero triangle indices (1-based, or negative relative)",
                        format!("{:?}", words.map(|w| self.order.i32(w))),
                    ));
                }
                Some(r) => r.map_err(|f| SmeshError::stream(path, subject, f))?,
            };
        }
        self.triangles += 1;
        Ok(Element::Triangle { v, finalized })
    }
}
