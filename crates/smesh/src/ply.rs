//! PLY: reading any PLY through `ply-rs-bw`; writing binary little-endian or ASCII as a stream
//! sink.
//!
//! PLY needs both counts in the header and all vertices before all faces, while a stream
//! interleaves them. The sink therefore spills vertex records and face records to two anonymous
//! scratch files next to the output (memory stays bounded by the stream width) and, on finish,
//! writes the header and appends both: for binary output the spilled records already are the
//! final bytes. Per-vertex attributes become extra `float` vertex properties.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

use crate::atomic::{AtomicFile, rewind_spill, spill_file};
use crate::sink::{MeshSink, SinkCore};
use crate::{Header, IndexedMesh, SmeshError, WriteStats};

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
    vertices: BufWriter<File>,
    faces: BufWriter<File>,
}

impl PlySink {
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
            vertices: spill_file(path)?,
            faces: spill_file(path)?,
        })
    }

    fn spill_error(&self, e: std::io::Error) -> SmeshError {
        SmeshError::io(&self.core.path, "write scratch data for", e)
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
    spill: File,
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
        self.core.vertex(pos, attrs)?;
        let res = pos
            .iter()
            .chain(attrs)
            .try_for_each(|x| self.vertices.write_all(&x.to_le_bytes()));
        res.map_err(|e| self.spill_error(e))
    }

    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        self.core.triangle(v, last_use)?;
        let Ok(idx) = v
            .map(u32::try_from)
            .into_iter()
            .collect::<Result<Vec<u32>, _>>()
        else {
            return Err(SmeshError::Unsupported {
                path: self.core.path.clone(),
                message: format!("triangle {v:?} needs indices beyond the 32 bits of PLY's uint"),
            });
        };
        let mut rec = [3u8; 13];
        for (i, x) in idx.iter().enumerate() {
            rec[1 + 4 * i..5 + 4 * i].copy_from_slice(&x.to_le_bytes());
        }
        let res = self.faces.write_all(&rec);
        res.map_err(|e| self.spill_error(e))
    }

    fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        self.core.finalize(v)
    }

    fn finish(self: Box<Self>) -> Result<WriteStats, SmeshError> {
        self.core.finish()?;
        let header = self.header_text();
        let this = *self;
        let PlySink {
            core,
            mut out,
            encoding,
            vertices,
            faces,
            header: meta,
        } = this;
        let (mut vertices, _) = rewind_spill(&core.path, vertices)?;
        let (mut faces, _) = rewind_spill(&core.path, faces)?;
        out.write_all(header.as_bytes())?;
        match encoding {
            PlyEncoding::BinaryLittleEndian => {
                out.append(&mut vertices)?;
                out.append(&mut faces)?;
            }
            PlyEncoding::Ascii => {
                let stride = 4 * (3 + meta.attribute_names.len());
                ascii_from_spill(&mut out, vertices, stride, |b, s| {
                    let vals: Vec<String> = le_words(b)
                        .map(|w| f32::from_le_bytes(w).to_string())
                        .collect();
                    s.push_str(&vals.join(" "));
                    s.push('\n');
                })?;
                ascii_from_spill(&mut out, faces, 13, |b, s| {
                    let idx: Vec<String> = le_words(&b[1..])
                        .map(|w| u32::from_le_bytes(w).to_string())
                        .collect();
                    s.push_str(&format!("3 {}\n", idx.join(" ")));
                })?;
            }
        }
        let bytes = out.finish()?;
        Ok(core.stats(bytes))
    }
}

/// Any scalar property as f64 (doubles kept exact).
fn scalar(p: &Property) -> Option<f64> {
    match p {
        Property::Double(d) => Some(*d),
        other => other.to_f32_lossy().map(f64::from),
    }
}

/// Loads a PLY file (ascii or binary, any scalar types): `x y z` and every other scalar vertex
/// property as an attribute; faces from `vertex_indices` (or `vertex_index`), polygons fanned
/// into triangles.
pub(crate) fn read(path: &Path) -> Result<IndexedMesh, SmeshError> {
    let file = File::open(path).map_err(|e| SmeshError::io(path, "open", e))?;
    let mut input = BufReader::new(file);
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut input)
        .map_err(|e| SmeshError::foreign(path, format!("invalid PLY: {e}")))?;
    let bad = |what: String| SmeshError::Foreign {
        path: path.to_path_buf(),
        message: what,
    };
    let mut mesh = IndexedMesh::default();
    let vertex_def = ply
        .header
        .elements
        .get("vertex")
        .ok_or_else(|| bad("PLY has no `vertex` element".into()))?;
    let is_scalar = |k: &str| {
        matches!(
            vertex_def.properties[k].data_type,
            ply_rs_bw::ply::PropertyType::Scalar(_)
        )
    };
    mesh.attribute_names = vertex_def
        .properties
        .keys()
        .filter(|k| !["x", "y", "z"].contains(&k.as_str()) && is_scalar(k))
        .cloned()
        .collect();
    let empty = Vec::new();
    for (i, v) in ply
        .payload
        .get("vertex")
        .unwrap_or(&empty)
        .iter()
        .enumerate()
    {
        let get = |k: &str| {
            v.get(k)
                .and_then(scalar)
                .ok_or_else(|| bad(format!("vertex {i} has no scalar `{k}`")))
        };
        mesh.positions.push([get("x")?, get("y")?, get("z")?]);
        for name in &mesh.attribute_names {
            mesh.attrs.push(get(name)? as f32);
        }
    }
    let n = mesh.positions.len();
    for (i, f) in ply.payload.get("face").unwrap_or(&empty).iter().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(Property::to_u32_list)
            .ok_or_else(|| bad(format!("face {i} has no integer list `vertex_indices`")))?;
        if let Some(&v) = list.iter().find(|&&v| v as usize >= n) {
            return Err(bad(format!(
                "face {i} references vertex {v} but the file has {n} vertices"
            )));
        }
        for k in 2..list.len() {
            mesh.triangles.push([list[0], list[k - 1], list[k]]);
        }
    }
    Ok(mesh)
}
