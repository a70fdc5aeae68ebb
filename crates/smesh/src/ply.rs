//! PLY: reading any PLY through `ply-rs-bw`; writing binary little-endian or ASCII as a stream
//! sink.
//!
//! PLY needs both counts in the header and all vertices before all faces, while a stream
//! interleaves them. The sink therefore spills vertex records and face records to two anonymous
//! scratch files next to the output (memory stays bounded by the stream width) and, on finish,
//! writes the header and appends both: for binary output the spilled records already are the
//! final bytes. Per-vertex attributes become extra `float` vertex properties.

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{Encoding, Property, PropertyAccess, PropertyAccessResult, PropertyType};

use crate::atomic::{AtomicFile, Spill};
use crate::sink::{Completed, MeshSink, Saved, SinkCore, SinkState, mismatch};
use crate::{Header, IndexedMesh, SmeshError};

/// How a PLY body is encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlyEncoding {
    /// Compact and fast; the default.
    #[default]
    BinaryLittleEndian,
    /// Human-readable, for small meshes and debugging.
    Ascii,
}

/// Streaming PLY writer (see the module docs for how it orders the output).
pub struct PlySink {
    core: SinkCore,
    out: AtomicFile,
    encoding: PlyEncoding,
    header: Header,
    vertices: Spill,
    faces: Spill,
}

impl PlySink {
    /// Starts writing `path` (via a temporary file beside it); fails naming `path` if its
    /// directory is missing or not writable.
    pub fn create(
        path: &Path,
        header: &Header,
        encoding: PlyEncoding,
    ) -> Result<PlySink, SmeshError> {
        let core = SinkCore::new(path, header)?;
        let out = AtomicFile::create(path)?;
        Ok(PlySink {
            core,
            out,
            encoding,
            header: header.clone(),
            vertices: Spill::create(path)?,
            faces: Spill::create(path)?,
        })
    }

    /// Continues a checkpointed sink (see [`MeshSink::checkpoint`]).
    pub(crate) fn resume(
        path: &Path,
        header: &Header,
        encoding: PlyEncoding,
        state: SinkState,
    ) -> Result<PlySink, SmeshError> {
        let [out, vertices, faces] = state.marks::<3>(path)?;
        if !matches!(state.format, Saved::Ply) {
            return Err(mismatch(path, "PLY"));
        }
        Ok(PlySink {
            out: AtomicFile::reopen(path, out)?,
            vertices: Spill::reopen(path, vertices)?,
            faces: Spill::reopen(path, faces)?,
            encoding,
            header: header.clone(),
            core: SinkCore::resume(path, header, state.tracker.clone())?,
        })
    }

    fn header_text(&self) -> String {
        let format = match self.encoding {
            PlyEncoding::BinaryLittleEndian => "binary_little_endian",
            PlyEncoding::Ascii => "ascii",
        };
        let mut h = format!("ply\nformat {format} 1.0\n");
        for c in &self.header.comments {
            h.push_str(&format!("comment {c}\n"));
        }
        h.push_str(&format!(
            "element vertex {}\n",
            self.core.tracker.vertices()
        ));
        for name in ["x", "y", "z"]
            .into_iter()
            .chain(self.header.attribute_names.iter().map(String::as_str))
        {
            h.push_str(&format!("property float {name}\n"));
        }
        h.push_str(&format!("element face {}\n", self.core.tracker.triangles()));
        h.push_str("property list uchar uint vertex_indices\nend_header\n");
        h
    }
}

/// Reads the spilled little-endian records back and writes them as ASCII lines.
fn ascii_from_spill(
    out: &mut AtomicFile,
    spill: &mut File,
    record: usize,
    line: impl Fn(&[u8], &mut String),
) -> Result<(), SmeshError> {
    let mut input = BufReader::with_capacity(1 << 16, spill);
    let mut buf = vec![0u8; record];
    let mut text = String::new();
    loop {
        match input.read_exact(&mut buf) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(out.io_error(e)),
        }
        text.clear();
        line(&buf, &mut text);
        out.write_all(text.as_bytes())?;
    }
}

fn le_words(b: &[u8]) -> impl Iterator<Item = [u8; 4]> + '_ {
    b.chunks_exact(4).map(|w| [w[0], w[1], w[2], w[3]])
}

impl MeshSink for PlySink {
    fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError> {
        self.core.spill_vertex(self.vertices.writer(), pos, attrs)
    }

    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        let (idx, _) = self.core.triangle_u32(v, last_use, "PLY's uint")?;
        let mut rec = [3u8; 13];
        for (i, x) in idx.iter().enumerate() {
            rec[1 + 4 * i..5 + 4 * i].copy_from_slice(&x.to_le_bytes());
        }
        let res = self.faces.writer().write_all(&rec);
        res.map_err(|e| self.core.scratch_error(e))
    }

    fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        self.core.finalize(v)
    }

    fn complete(self: Box<Self>) -> Result<Completed, SmeshError> {
        self.core.finish()?;
        let header = self.header_text();
        let this = *self;
        let PlySink {
            core,
            mut out,
            encoding,
            mut vertices,
            mut faces,
            header: meta,
        } = this;
        vertices.rewind()?;
        faces.rewind()?;
        out.write_all(header.as_bytes())?;
        match encoding {
            PlyEncoding::BinaryLittleEndian => {
                out.append(&mut vertices)?;
                out.append(&mut faces)?;
            }
            PlyEncoding::Ascii => {
                let stride = 4 * (3 + meta.attribute_names.len());
                ascii_from_spill(&mut out, vertices.reader(), stride, |b, s| {
                    let vals: Vec<String> = le_words(b)
                        .map(|w| f32::from_le_bytes(w).to_string())
                        .collect();
                    s.push_str(&vals.join(" "));
                    s.push('\n');
                })?;
                ascii_from_spill(&mut out, faces.reader(), 13, |b, s| {
                    let idx: Vec<String> = le_words(&b[1..])
                        .map(|w| u32::from_le_bytes(w).to_string())
                        .collect();
                    s.push_str(&format!("3 {}\n", idx.join(" ")));
                })?;
            }
        }
        Completed::new(out, vec![vertices, faces], |bytes| core.stats(bytes))
    }

    fn checkpoint(&mut self) -> Result<SinkState, SmeshError> {
        Ok(SinkState {
            files: vec![self.out.mark()?, self.vertices.mark()?, self.faces.mark()?],
            tracker: self.core.tracker.clone(),
            format: Saved::Ply,
        })
    }
}

/// Any scalar property as f64 (doubles kept exact).
fn scalar(p: &Property) -> Option<f64> {
    match p {
        Property::Double(d) => Some(*d),
        other => other.to_f32_lossy().map(f64::from),
    }
}

/// A vertex as the parser hands it over: its scalar properties in header order (the parser sets
/// them in that order), without the per-element map `DefaultElement` would allocate.
#[derive(Default)]
struct PlyVertex(Vec<f64>);

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, _name: &str, p: Property) -> PropertyAccessResult {
        match scalar(&p) {
            Some(x) => {
                self.0.push(x);
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::Ignored,
        }
    }
}

/// The names PLY writers give a face's (or a strip's) vertex index list.
fn is_index_list(name: &str) -> bool {
    matches!(name, "vertex_indices" | "vertex_index")
}

/// A face or a triangle strip: its vertex index list, whatever its integer type, signed (a
/// strip's restarts are -1).
#[derive(Default)]
struct PlyList(Option<Vec<i64>>);

impl PropertyAccess for PlyList {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, p: Property) -> PropertyAccessResult {
        if is_index_list(name) {
            self.0 = int_list(&p);
        }
        PropertyAccessResult::Ignored
    }
}

/// Any integer list as i64 (`Property::to_u32_list` refuses the -1 of strips).
fn int_list(p: &Property) -> Option<Vec<i64>> {
    fn wide<T: Copy + Into<i64>>(v: &[T]) -> Vec<i64> {
        v.iter().map(|&x| x.into()).collect()
    }
    Some(match p {
        Property::ListChar(v) => wide(v),
        Property::ListUChar(v) => wide(v),
        Property::ListShort(v) => wide(v),
        Property::ListUShort(v) => wide(v),
        Property::ListInt(v) => wide(v),
        Property::ListUInt(v) => wide(v),
        _ => return None,
    })
}

/// Elements other than vertex and face, read only to get past them.
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

/// Loads a PLY file (ascii or binary, any scalar types): `x y z` and every other scalar vertex
/// property as an attribute (f32, refused when out of its range); faces from `vertex_indices`
/// (or `vertex_index`), polygons fanned into triangles; `tristrips` as triangle strips. The
/// elements may come in any order (the faces are checked against the vertices at the end).
pub(crate) fn read(path: &Path) -> Result<IndexedMesh, SmeshError> {
    let file = File::open(path).map_err(|e| SmeshError::io(path, "open", e))?;
    let mut input = Reader::new(BufReader::with_capacity(1 << 16, file));
    let invalid =
        |e: ply_rs_bw::parser::ParseError| SmeshError::foreign(path, format!("invalid PLY: {e}"));
    let bad = |m: String| SmeshError::foreign(path, m);
    let header = Parser::<Skip>::new()
        .read_header(&mut input)
        .map_err(invalid)?;
    let mut mesh = IndexedMesh {
        comments: crate::sma::carried_comments(&header.comments),
        ..IndexedMesh::default()
    };
    let mut faces = Vec::new();
    let mut strips = Vec::new();
    let has_faces = header
        .elements
        .keys()
        .any(|k| k == "face" || k == "tristrips");
    for (name, def) in &header.elements {
        match name.as_str() {
            "vertex" => {
                let scalars: Vec<&str> = def
                    .properties
                    .iter()
                    .filter(|(_, p)| matches!(p.data_type, PropertyType::Scalar(_)))
                    .map(|(k, _)| k.as_str())
                    .collect();
                let slot = |k: &str| {
                    scalars
                        .iter()
                        .position(|s| *s == k)
                        .ok_or_else(|| bad(format!("PLY vertices have no scalar `{k}`")))
                };
                let xyz = [slot("x")?, slot("y")?, slot("z")?];
                let attrs: Vec<usize> = (0..scalars.len()).filter(|i| !xyz.contains(i)).collect();
                mesh.attribute_names = attrs.iter().map(|&i| scalars[i].to_string()).collect();
                let vertices = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut input, def, &header)
                    .map_err(invalid)?;
                for (n, v) in vertices.into_iter().enumerate() {
                    mesh.positions.push(xyz.map(|i| v.0[i]));
                    for &i in &attrs {
                        // `as` would make a finite double beyond f32's range infinite, and
                        // `convert` wrote that inf without a word.
                        let (x, f) = (v.0[i], v.0[i] as f32);
                        if x.is_finite() && !f.is_finite() {
                            return Err(bad(format!(
                                "vertex {n}: attribute `{}` is {x:e}, beyond the range of f32 (about ±3.4e38) that attributes are held in; rescale it",
                                scalars[i]
                            )));
                        }
                        mesh.attrs.push(f);
                    }
                }
            }
            "face" | "tristrips" => {
                let lists = Parser::<PlyList>::new()
                    .read_payload_for_element(&mut input, def, &header)
                    .map_err(invalid)?;
                let lists = lists.into_iter().map(|l| l.0);
                match name.as_str() {
                    "face" => faces.extend(lists),
                    _ => strips.extend(lists),
                }
            }
            _ => {
                // In a file without `face` or `tristrips`, faces under another name would be
                // lost without a word; beside them, an index list is something else (edges,
                // lines) and is passed over.
                if let Some((list, _)) = def.properties.iter().find(|(k, p)| {
                    !has_faces && is_index_list(k) && matches!(p.data_type, PropertyType::List(..))
                }) {
                    return Err(bad(format!(
                        "element `{name}` has a vertex index list `{list}` but only `face` and `tristrips` elements are read; convert it to faces first"
                    )));
                }
                Parser::<Skip>::new()
                    .read_payload_for_element(&mut input, def, &header)
                    .map_err(invalid)?;
            }
        }
    }
    past_the_elements(path, input.get_mut(), header.encoding == Encoding::Ascii)?;
    let n = mesh.positions.len();
    let vertex = |what: &str, i: usize, v: i64| match usize::try_from(v) {
        Ok(v) if v < n => Ok(v as u32),
        _ => Err(bad(format!(
            "{what} {i} references vertex {v} but the file has {n} vertices"
        ))),
    };
    for (i, list) in faces.into_iter().enumerate() {
        let list = list.filter(|l| l.iter().all(|&v| v >= 0)).ok_or_else(|| {
            bad(format!(
                "face {i} has no list `vertex_indices` of non-negative integers"
            ))
        })?;
        // Dropping it would lose part of the surface without a word.
        if list.len() < 3 {
            return Err(bad(format!(
                "face {i} has {} vertices; a face needs at least 3",
                list.len()
            )));
        }
        let list = list
            .iter()
            .map(|&v| vertex("face", i, v))
            .collect::<Result<Vec<u32>, _>>()?;
        for k in 2..list.len() {
            mesh.triangles.push([list[0], list[k - 1], list[k]]);
        }
    }
    for (i, list) in strips.into_iter().enumerate() {
        let list = list.ok_or_else(|| {
            bad(format!(
                "tristrips {i} has no list `vertex_indices` of integers"
            ))
        })?;
        // The restart is -1, or its bits read as an unsigned index.
        for run in list.split(|&v| v == -1 || v == i64::from(u32::MAX)) {
            let run = run
                .iter()
                .map(|&v| vertex("tristrips", i, v))
                .collect::<Result<Vec<u32>, _>>()?;
            for (k, t) in run.windows(3).enumerate() {
                // Every other triangle of a strip turns the other way; a triangle with a
                // repeated corner is the strip's way of turning a corner, not a surface.
                let t = if k % 2 == 0 {
                    [t[0], t[1], t[2]]
                } else {
                    [t[1], t[0], t[2]]
                };
                if t[0] != t[1] && t[1] != t[2] && t[2] != t[0] {
                    mesh.triangles.push(t);
                }
            }
        }
    }
    Ok(mesh)
}

/// Refuses data after the last element the header declares: a header that undercounts its
/// faces (`element face 15331` for 215331) gave the first 15331 faces, exit 0. In ASCII, lines
/// left that are not blank; in binary, bytes left that are not ASCII whitespace (some writers
/// end a binary file with a newline, which an undercount would not leave alone).
fn past_the_elements(path: &Path, rest: &mut impl BufRead, ascii: bool) -> Result<(), SmeshError> {
    let read = |e| SmeshError::io(path, "read", e);
    let (left, unit) = if ascii {
        let mut lines = 0u64;
        for line in rest.split(b'\n') {
            lines += u64::from(!line.map_err(read)?.trim_ascii().is_empty());
        }
        (lines, if lines == 1 { "line" } else { "lines" })
    } else {
        let (mut bytes, mut data) = (0u64, false);
        loop {
            let chunk = rest.fill_buf().map_err(read)?;
            if chunk.is_empty() {
                break;
            }
            data |= chunk.iter().any(|b| !b.is_ascii_whitespace());
            bytes += chunk.len() as u64;
            let n = chunk.len();
            rest.consume(n);
        }
        let bytes = if data { bytes } else { 0 };
        (bytes, if bytes == 1 { "byte" } else { "bytes" })
    };
    match left {
        0 => Ok(()),
        _ => Err(SmeshError::foreign(
            path,
            format!(
                "{left} {unit} after the last element the header declares: the header's element counts are wrong; fix its `element` lines"
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const XYZ: &str = "property float x\nproperty float y\nproperty float z\n";

    fn read_text(elements: &str, body: &str) -> Result<IndexedMesh, String> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.ply");
        let text = format!("ply\nformat ascii 1.0\n{elements}end_header\n{body}");
        std::fs::write(&p, text).unwrap();
        read(&p).map_err(|e| e.to_string().replace(&format!("{}: ", p.display()), ""))
    }

    /// A header counting fewer faces than the file holds gave the ones it counted, exit 0.
    #[test]
    fn data_after_the_declared_elements_is_refused() {
        let tetra = "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
        let header = |faces: usize| {
            format!(
                "element vertex 4\n{XYZ}element face {faces}\nproperty list uchar int vertex_indices\n"
            )
        };
        let e = read_text(&header(2), tetra).unwrap_err();
        assert_eq!(
            e,
            "2 lines after the last element the header declares: the header's element counts are wrong; fix its `element` lines"
        );
        // Blank lines at the end are no data.
        assert_eq!(
            read_text(&header(4), &format!("{tetra}\n  \r\n"))
                .unwrap()
                .triangles
                .len(),
            4
        );
        // Binary: the bytes left.
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.ply");
        let mut file = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex 3\n{XYZ}element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        )
        .into_bytes();
        for c in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
            file.extend(c.to_le_bytes());
        }
        let face: Vec<u8> = std::iter::once(3)
            .chain([0i32, 1, 2].into_iter().flat_map(i32::to_le_bytes))
            .collect();
        file.extend(face.repeat(2));
        std::fs::write(&p, &file).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.ends_with("b.ply: 13 bytes after the last element the header declares: the header's element counts are wrong; fix its `element` lines"), "{e}");
        std::fs::write(&p, &file[..file.len() - 13]).unwrap();
        assert_eq!(read(&p).unwrap().triangles, [[0, 1, 2]]);
        // A newline some writers end a binary file with is no data.
        let mut newline = file[..file.len() - 13].to_vec();
        newline.extend(b"\r\n");
        std::fs::write(&p, &newline).unwrap();
        assert_eq!(read(&p).unwrap().triangles, [[0, 1, 2]]);
    }

    /// `convert` turned a double attribute of 1e300 into inf without a word.
    #[test]
    fn attribute_beyond_f32_is_refused() {
        let e = read_text(
            &format!("element vertex 2\n{XYZ}property double t\n"),
            "0 0 0 1\n1 0 0 1e300\n",
        )
        .unwrap_err();
        assert_eq!(
            e,
            "vertex 1: attribute `t` is 1e300, beyond the range of f32 (about ±3.4e38) that attributes are held in; rescale it"
        );
        let m = read_text(
            &format!("element vertex 2\n{XYZ}property double t\n"),
            "0 0 0 -1e30\n1 0 0 2\n",
        )
        .unwrap();
        assert_eq!(m.attrs, [-1e30, 2.0]);
    }

    /// A strip of 4 vertices, a restart, and a strip turning a corner with a repeated vertex.
    #[test]
    fn tristrips_become_triangles_of_alternating_winding() {
        let m = read_text(
            &format!(
                "element vertex 6\n{XYZ}element tristrips 1\nproperty list int int vertex_indices\n"
            ),
            "0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 0 0\n2 1 0\n10 0 1 2 3 -1 1 4 3 3 5\n",
        )
        .unwrap();
        assert_eq!(m.triangles, [[0, 1, 2], [2, 1, 3], [1, 4, 3]]);
    }

    /// PLY lets the face element come first; it was refused ("the file has 0 vertices").
    #[test]
    fn faces_may_precede_vertices() {
        let m = read_text(
            &format!(
                "element face 1\nproperty list uchar int vertex_indices\nelement vertex 3\n{XYZ}"
            ),
            "3 0 1 2\n0 0 0\n1 0 0\n0 1 0\n",
        )
        .unwrap();
        assert_eq!((m.positions.len(), m.triangles), (3, vec![[0, 1, 2]]));
        let e = read_text(
            &format!(
                "element face 1\nproperty list uchar int vertex_indices\nelement vertex 3\n{XYZ}"
            ),
            "3 0 1 3\n0 0 0\n1 0 0\n0 1 0\n",
        )
        .unwrap_err();
        assert_eq!(e, "face 0 references vertex 3 but the file has 3 vertices");
    }

    /// Faces under another element name were skipped: 0 triangles and no error.
    #[test]
    fn other_elements_with_index_lists_are_refused() {
        let e = read_text(
            &format!("element vertex 3\n{XYZ}element triangle 1\nproperty list uchar int vertex_indices\n"),
            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        )
        .unwrap_err();
        assert!(
            e.contains("element `triangle` has a vertex index list")
                && e.contains("convert it to faces first"),
            "{e}"
        );
        // Beside faces, an index list is something else (edges): passed over.
        let m = read_text(
            &format!(
                "element vertex 3\n{XYZ}element face 1\nproperty list uchar int vertex_indices\n\
                 element edge 1\nproperty list uchar int vertex_indices\n"
            ),
            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n2 0 1\n",
        )
        .unwrap();
        assert_eq!(m.triangles, [[0, 1, 2]]);
    }

    /// A strip of unsigned indices restarts at 0xFFFFFFFF, the bits of -1.
    #[test]
    fn an_unsigned_strip_restarts_at_all_ones() {
        let m = read_text(
            &format!(
                "element vertex 4\n{XYZ}element tristrips 1\nproperty list int uint vertex_indices\n"
            ),
            "0 0 0\n1 0 0\n0 1 0\n1 1 0\n7 0 1 2 4294967295 1 3 2\n",
        )
        .unwrap();
        assert_eq!(m.triangles, [[0, 1, 2], [1, 3, 2]]);
    }
}
