//! SMB, the binary streaming mesh.
//!
//! Header: u8 version (0, or 1 with attributes), u8 endianness (0 little, 1 big), u8 0, u8 0;
//! i32 comment count, then (i32 length, bytes) per comment; version 1 only: i32 attribute count
//! m, then (i32 length, bytes) per attribute name; i32 nverts, i32 nfaces (-1 if unknown);
//! u8 has_bbox, then 6 f32 (min xyz, max xyz) when 1. Body: blocks of a u32 descriptor (bit i,
//! least significant first: 1 = vertex, 0 = triangle) and up to 32 elements: a vertex is
//! 3 + m f32 (x y z, then its attributes in name order), a triangle 3 i32 indices as in `index`.
//! The last block may be short; its unused descriptor bits are 0.
//!
//! Version 1 is our superset (FORMATS.md). A vertex longer than 12 bytes would be misread by a
//! version-0 reader, so the version byte changes and such readers refuse the file instead; a
//! mesh without attributes is written as version 0, byte for byte what it always was.
//!
//! We write little-endian, with has_bbox = 1 and placeholder counts that `end` patches in place
//! (the header has fixed size once the comments are written). An empty mesh gets has_bbox = 0.
//! SMB has no explicit finalization.
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

/// Bytes of a triangle, and of a vertex's x y z.
const ELEMENT: usize = 12;
const BLOCK: usize = 32;
/// The version byte of files whose header carries an attribute-name table.
const VERSION_ATTRIBUTES: u8 = 1;

/// Appends SMB's length-prefixed strings (comments, attribute names): an i32 count, then
/// (i32 length, bytes) each.
fn put_strings(h: &mut Vec<u8>, strings: &[String]) {
    h.extend((strings.len() as i32).to_le_bytes());
    for c in strings {
        h.extend((c.len() as i32).to_le_bytes());
        h.extend(c.as_bytes());
    }
}

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct SmbEncoder {
    counts_at: u64,
    descriptor: u32,
    elements: usize,
    block: Vec<u8>,
}

impl SmbEncoder {
    pub(crate) fn begin(out: &mut AtomicFile, header: &Header) -> Result<SmbEncoder, SmeshError> {
        let names = &header.attribute_names;
        let version = if names.is_empty() {
            0
        } else {
            VERSION_ATTRIBUTES
        };
        let mut h = vec![version, 0, 0, 0];
        put_strings(&mut h, &header.comments);
        if !names.is_empty() {
            put_strings(&mut h, names);
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
            block: Vec::with_capacity(BLOCK * (ELEMENT + 4 * names.len())),
        })
    }

    fn push(
        &mut self,
        out: &mut AtomicFile,
        vertex: bool,
        words: impl IntoIterator<Item = [u8; 4]>,
    ) -> Result<(), SmeshError> {
        if vertex {
            self.descriptor |= 1 << self.elements;
        }
        self.block.extend(words.into_iter().flatten());
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

    /// `attrs.len()` already checked by the writer against the header's names.
    pub(crate) fn vertex(
        &mut self,
        out: &mut AtomicFile,
        pos: [f32; 3],
        attrs: &[f32],
    ) -> Result<(), SmeshError> {
        let words = pos.iter().chain(attrs).map(|x| x.to_le_bytes());
        self.push(out, true, words)
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

/// Whether `bytes` start like an SMB file: version 0 or 1, endianness 0 or 1, two zero bytes.
pub(crate) fn is_magic(bytes: &[u8]) -> bool {
    bytes.len() >= 4 && bytes[0] <= VERSION_ATTRIBUTES && bytes[1] <= 1 && bytes[2..4] == [0, 0]
}

/// Why no header fits: a file shorter than its own header or than the counts its header
/// declares is truncated ("truncated at byte N of M"); anything else does not fit either order.
fn truncated_or_bad(path: &Path, prefix: &[u8], order: Order, file_len: u64) -> SmeshError {
    let Some(h) = parse_header(prefix, order) else {
        // The header itself is cut (its strings or counts run past the end of the file).
        return SmeshError::Truncated {
            path: path.to_path_buf(),
            place: Place::Byte(file_len),
            expected: "the SMB header (the file is shorter than its own header)".into(),
        };
    };
    if h.nverts >= 0 && h.nfaces >= 0 {
        let (nv, nf) = (h.nverts as u64, h.nfaces as u64);
        let vertex = vertex_size(h.attribute_names.len()) as u64;
        let size = h.len + nv * vertex + nf * ELEMENT as u64 + 4 * (nv + nf).div_ceil(BLOCK as u64);
        if file_len < size {
            return SmeshError::TruncatedAt {
                path: path.to_path_buf(),
                at: file_len,
                of: size,
                detail: format!("the header declares {nv} vertices and {nf} triangles"),
            };
        }
    }
    SmeshError::syntax(
        path,
        Place::Byte(4),
        "an SMB header whose counts match the file size in either byte order",
        format!("{file_len} bytes that fit neither"),
    )
}

/// The header fields as parsed under one byte order.
#[derive(Debug)]
struct Parsed {
    comments: Vec<String>,
    attribute_names: Vec<String>,
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

    /// A count and that many length-prefixed strings (trailing NULs dropped: some writers pad).
    fn strings(&mut self, order: Order) -> Option<Vec<String>> {
        let n = usize::try_from(order.i32(self.word()?)).ok()?;
        let mut out = Vec::new();
        for _ in 0..n {
            let len = usize::try_from(order.i32(self.word()?)).ok()?;
            let text = String::from_utf8_lossy(self.take(len)?);
            out.push(text.trim_end_matches('\0').to_string());
        }
        Some(out)
    }
}

/// Parses the header after the magic under `order`; `None` if it does not fit the prefix.
fn parse_header(bytes: &[u8], order: Order) -> Option<Parsed> {
    let mut p = Prefix { bytes, at: 4 };
    let comments = p.strings(order)?;
    let attribute_names = if bytes[0] == VERSION_ATTRIBUTES {
        p.strings(order)?
    } else {
        Vec::new()
    };
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
        attribute_names,
        nverts,
        nfaces,
        bbox,
        len: p.at as u64,
    })
}

/// Bytes of one vertex: x y z and `attributes` values, all f32.
fn vertex_size(attributes: usize) -> usize {
    ELEMENT + 4 * attributes
}

/// Whether `h` describes the file's size: counts not below -1, and known counts matching the
/// file size exactly.
fn fits_size(h: &Parsed, file_len: u64) -> bool {
    if h.nverts < -1 || h.nfaces < -1 {
        return false;
    }
    let data = file_len.saturating_sub(h.len);
    let vertex = vertex_size(h.attribute_names.len());
    if h.nverts >= 0 && h.nfaces >= 0 {
        let (nv, nf) = (h.nverts as u64, h.nfaces as u64);
        let body = nv * vertex as u64 + nf * ELEMENT as u64;
        if data != body + 4 * (nv + nf).div_ceil(BLOCK as u64) {
            return false;
        }
    }
    true
}

/// Whether the triangles of the first block (as far as it is in the prefix) use valid indices
/// under `order`.
fn first_block_decodes(h: &Parsed, order: Order, bytes: &[u8]) -> bool {
    let vertex = vertex_size(h.attribute_names.len());
    let mut p = Prefix {
        bytes,
        at: h.len as usize,
    };
    let Some(descriptor) = p.word().map(|w| order.u32(w)) else {
        return true;
    };
    let mut vertices = 0u64;
    for bit in 0..BLOCK {
        if descriptor >> bit & 1 == 1 {
            if p.take(vertex).is_none() {
                break;
            }
            vertices += 1;
            continue;
        }
        let Some(e) = p.take(ELEMENT) else { break };
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

/// The byte order the file is in, and its header under it: of the orders whose header fits the
/// file size (the declared one first), the first whose first block decodes, or else the first,
/// whose bad element the decoder then names. Requiring the first block to decode outright made
/// one bad index there a "counts do not match the file size" error about an intact header.
fn choose_order(
    path: &Path,
    prefix: &[u8],
    declared: Order,
    file_len: u64,
) -> Result<(Parsed, Order), SmeshError> {
    let other = match declared {
        Order::Little => Order::Big,
        Order::Big => Order::Little,
    };
    let mut fitting: Vec<(Parsed, Order)> = [declared, other]
        .into_iter()
        .filter_map(|o| parse_header(prefix, o).map(|h| (h, o)))
        .filter(|(h, _)| fits_size(h, file_len))
        .collect();
    if fitting.is_empty() {
        return Err(truncated_or_bad(path, prefix, declared, file_len));
    }
    let pick = fitting
        .iter()
        .position(|(h, o)| first_block_decodes(h, *o, prefix))
        .unwrap_or(0);
    Ok(fitting.swap_remove(pick))
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
    /// The bytes of the descriptor or element last read (a vertex is longer than a triangle
    /// when there are attributes).
    element: Vec<u8>,
    attributes: usize,
}

/// What the decoder reads next.
#[derive(Debug, Clone, Copy)]
enum Part {
    Descriptor,
    Vertex,
    Triangle,
}

impl Part {
    fn len(self, attributes: usize) -> usize {
        match self {
            Part::Descriptor => 4,
            Part::Vertex => vertex_size(attributes),
            Part::Triangle => ELEMENT,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Part::Descriptor => "a block descriptor",
            Part::Vertex => "a vertex",
            Part::Triangle => "a triangle",
        }
    }
}

impl SmbDecoder {
    pub(crate) fn open(
        path: &Path,
        mut file: File,
    ) -> Result<(SmbDecoder, ReadHeader), SmeshError> {
        let io_err = |e| SmeshError::io(path, "read its SMB header", e);
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
        let (h, order) = choose_order(path, &prefix, declared, file_len)?;
        // NaN compares false with every coordinate, so a NaN box held every vertex and
        // `check` passed it.
        if let Some((lo, hi)) = h.bbox
            && !lo.iter().chain(&hi).all(|x| x.is_finite())
        {
            return Err(SmeshError::syntax(
                path,
                Place::Byte(h.len - 24),
                "a bounding box of six finite numbers",
                format!("{lo:?}..{hi:?}"),
            ));
        }
        file.seek(SeekFrom::Start(h.len)).map_err(io_err)?;
        let count = |n: i32| u64::try_from(n).ok();
        let header = ReadHeader {
            format: Format::Smb,
            nverts: count(h.nverts),
            nfaces: count(h.nfaces),
            bbox: h.bbox,
            comments: h.comments,
            attribute_names: h.attribute_names,
        };
        let attributes = header.attribute_names.len();
        let dec = SmbDecoder {
            input: BufReader::with_capacity(1 << 16, file),
            order,
            offset: h.len,
            descriptor: 0,
            left_in_block: 0,
            declared: header.nverts.zip(header.nfaces),
            vertices: 0,
            triangles: 0,
            element: Vec::with_capacity(vertex_size(attributes)),
            attributes,
        };
        Ok((dec, header))
    }

    /// Reads the next `part` into `self.element`; `Ok(false)` on a clean end of file before its
    /// first byte.
    fn read(&mut self, path: &Path, part: Part) -> Result<bool, SmeshError> {
        let len = part.len(self.attributes);
        self.element.resize(len, 0);
        let mut got = 0;
        while got < len {
            match self.input.read(&mut self.element[got..]) {
                Ok(0) if got == 0 => return Ok(false),
                Ok(0) => {
                    return Err(SmeshError::Truncated {
                        path: path.to_path_buf(),
                        place: Place::Byte(self.offset + got as u64),
                        expected: format!("{} ({len} bytes)", part.name()),
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
        self.offset += len as u64;
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
            match self.read(path, Part::Descriptor) {
                Ok(true) => {}
                Ok(false) => return self.end(path),
                Err(e) => return Some(Err(e)),
            }
            let w = &self.element;
            self.descriptor = self.order.u32([w[0], w[1], w[2], w[3]]);
            self.left_in_block = BLOCK;
        }
        let is_vertex = self.descriptor & 1 == 1;
        self.descriptor >>= 1;
        self.left_in_block -= 1;
        let place = Place::Byte(self.offset);
        let part = if is_vertex {
            Part::Vertex
        } else {
            Part::Triangle
        };
        match self.read(path, part) {
            Ok(true) => {}
            Ok(false) => return self.end(path),
            Err(e) => return Some(Err(e)),
        }
        Some(self.decode(path, place, is_vertex).map(|el| (el, place)))
    }

    /// The element in `self.element` as a vertex or a triangle.
    fn decode(
        &mut self,
        path: &Path,
        place: Place,
        is_vertex: bool,
    ) -> Result<Element, SmeshError> {
        let order = self.order;
        let mut values = self
            .element
            .chunks_exact(4)
            .map(|w| [w[0], w[1], w[2], w[3]]);
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
            let mut f = values.map(|w| order.f32(w));
            let pos = [0; 3].map(|_| f.next().unwrap_or_default());
            return Ok(Element::Vertex {
                pos,
                attrs: f.collect(),
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
        let n = [0; 3].map(|_| values.next().map_or(0, |w| order.i32(w)));
        let mut v = [0; 3];
        let mut finalized = [false; 3];
        for i in 0..3 {
            (v[i], finalized[i]) = match index::decode(i64::from(n[i]), self.vertices) {
                None => {
                    return Err(SmeshError::syntax(
                        path,
                        place,
                        "nonzero triangle indices (1-based, or negative relative)",
                        format!("{n:?}"),
                    ));
                }
                Some(r) => r.map_err(|f| SmeshError::stream(path, subject, f))?,
            };
        }
        self.triangles += 1;
        Ok(Element::Triangle { v, finalized })
    }
}
