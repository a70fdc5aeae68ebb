//! Binary glTF 2.0 (`.glb`): one mesh, one triangle primitive with `POSITION`, optional `NORMAL`,
//! one `_NAME` float accessor per vertex attribute, and u32 indices.
//!
//! The GLB's JSON chunk (with byte lengths, counts and the position bounds) precedes the binary
//! chunk, so the sink spills vertex records (x y z and attributes, interleaved in one strided
//! buffer view), normals and indices to scratch files and assembles the file on finish.
//!
//! Normals are area-weighted sums of the face normals around a vertex, complete when the vertex
//! is finalized. They are computed in f64 for active vertices only and written in vertex order;
//! a normal finished before an older vertex's waits in a reorder buffer, whose size is the
//! stream's finalization lag (small for the pipeline's sweep-ordered output). A vertex without
//! any non-degenerate triangle gets +z, since glTF requires unit normals.
//!
//! Reading goes through the `gltf` crate, which validates the document.

use std::collections::BTreeMap;

use rustc_hash::FxHashMap;
use std::io::Write;
use std::path::Path;

use serde_json::json;

use crate::atomic::{AtomicFile, Spill};
use crate::sink::{MeshSink, Saved, SinkCore, SinkState, mismatch};
use crate::stl::{face_normal, normalized};
use crate::{Header, IndexedMesh, SmeshError, WriteStats};

const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// glTF caps a buffer view's byte stride at 252: x y z plus at most 60 attributes interleaved.
const MAX_ATTRIBUTES: usize = 60;

/// Accumulates area-weighted normals of active vertices and emits them in vertex order.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Normals {
    sums: FxHashMap<u64, [f64; 3]>,
    ready: BTreeMap<u64, [f32; 3]>,
    next: u64,
}

impl Normals {
    fn add(&mut self, v: [u64; 3], corners: [[f32; 3]; 3]) {
        // The cross product's length is twice the area: the weighting comes for free.
        let n = face_normal(corners);
        for x in v {
            let s = self.sums.entry(x).or_insert([0.0; 3]);
            (0..3).for_each(|i| s[i] += n[i]);
        }
    }

    fn done(&mut self, v: u64, out: &mut impl Write) -> std::io::Result<()> {
        let sum = self.sums.remove(&v).unwrap_or([0.0; 3]);
        self.ready
            .insert(v, normalized(sum).unwrap_or([0.0, 0.0, 1.0]));
        while let Some(n) = self.ready.remove(&self.next) {
            n.iter().try_for_each(|x| out.write_all(&x.to_le_bytes()))?;
            self.next += 1;
        }
        Ok(())
    }
}

/// Streaming GLB writer (see the module docs).
pub struct GlbSink {
    core: SinkCore,
    out: AtomicFile,
    header: Header,
    vertices: Spill,
    indices: Spill,
    normals: Option<(Normals, Spill)>,
}

impl GlbSink {
    /// `normals`: also write per-vertex normals.
    pub fn create(path: &Path, header: &Header, normals: bool) -> Result<GlbSink, SmeshError> {
        let core = SinkCore::new(path, header)?;
        if header.attribute_names.len() > MAX_ATTRIBUTES {
            return Err(SmeshError::Unsupported {
                path: path.to_path_buf(),
                message: format!(
                    "{} vertex attributes exceed the {MAX_ATTRIBUTES} a GLB vertex record can hold",
                    header.attribute_names.len()
                ),
            });
        }
        let out = AtomicFile::create(path)?;
        let normals = if normals {
            Some((Normals::default(), Spill::create(path)?))
        } else {
            None
        };
        Ok(GlbSink {
            core,
            out,
            header: header.clone(),
            vertices: Spill::create(path)?,
            indices: Spill::create(path)?,
            normals,
        })
    }

    /// Continues a checkpointed sink (see [`MeshSink::checkpoint`]); `normals` as in `create`.
    pub(crate) fn resume(
        path: &Path,
        header: &Header,
        normals: bool,
        state: SinkState,
    ) -> Result<GlbSink, SmeshError> {
        let Saved::Glb(saved) = &state.format else {
            return Err(mismatch(path, "GLB"));
        };
        let (out, vertices, indices, normals) = match (saved, normals) {
            (Some(n), true) => {
                let [out, vertices, indices, spill] = state.marks::<4>(path)?;
                (
                    out,
                    vertices,
                    indices,
                    Some((n.clone(), Spill::reopen(path, spill)?)),
                )
            }
            (None, false) => {
                let [out, vertices, indices] = state.marks::<3>(path)?;
                (out, vertices, indices, None)
            }
            _ => return Err(mismatch(path, "GLB normals")),
        };
        Ok(GlbSink {
            out: AtomicFile::reopen(path, out)?,
            vertices: Spill::reopen(path, vertices)?,
            indices: Spill::reopen(path, indices)?,
            normals,
            header: header.clone(),
            core: SinkCore::resume(path, header, state.tracker.clone())?,
        })
    }

    /// The JSON chunk for `n` vertices and `t` triangles laid out as
    /// [vertex records][normals][indices] in the binary chunk.
    fn document(&self, n: u64, t: u64) -> serde_json::Value {
        let asset = json!({
            "version": "2.0",
            "generator": "isostream-smesh",
            "extras": { "comments": self.header.comments },
        });
        let Some((lo, hi)) = self.core.tracker.bbox().filter(|_| t > 0) else {
            // glTF forbids empty accessors: an empty mesh is a scene without nodes.
            return json!({ "asset": asset, "scene": 0, "scenes": [{ "nodes": [] }] });
        };
        let k = self.header.attribute_names.len() as u64;
        let stride = 4 * (3 + k);
        let vertex_bytes = n * stride;
        let normal_bytes = if self.normals.is_some() { n * 12 } else { 0 };
        let index_bytes = t * 12;
        let mut views = vec![json!({
            "buffer": 0, "byteOffset": 0, "byteLength": vertex_bytes,
            "byteStride": stride, "target": ARRAY_BUFFER,
        })];
        let mut accessors = vec![json!({
            "bufferView": 0, "byteOffset": 0, "componentType": FLOAT, "count": n,
            "type": "VEC3", "min": lo, "max": hi,
        })];
        let mut attributes = serde_json::Map::new();
        attributes.insert("POSITION".into(), json!(0));
        for (i, name) in self.header.attribute_names.iter().enumerate() {
            attributes.insert(format!("_{name}"), json!(accessors.len()));
            accessors.push(json!({
                "bufferView": 0, "byteOffset": 12 + 4 * i, "componentType": FLOAT,
                "count": n, "type": "SCALAR",
            }));
        }
        if normal_bytes > 0 {
            attributes.insert("NORMAL".into(), json!(accessors.len()));
            accessors.push(json!({
                "bufferView": views.len(), "componentType": FLOAT, "count": n, "type": "VEC3",
            }));
            views.push(json!({
                "buffer": 0, "byteOffset": vertex_bytes, "byteLength": normal_bytes,
                "target": ARRAY_BUFFER,
            }));
        }
        let indices = accessors.len();
        accessors.push(json!({
            "bufferView": views.len(), "componentType": UNSIGNED_INT, "count": 3 * t,
            "type": "SCALAR",
        }));
        views.push(json!({
            "buffer": 0, "byteOffset": vertex_bytes + normal_bytes, "byteLength": index_bytes,
            "target": ELEMENT_ARRAY_BUFFER,
        }));
        json!({
            "asset": asset,
            "scene": 0,
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "mesh": 0 }],
            "meshes": [{ "primitives": [{ "attributes": attributes, "indices": indices, "mode": 4 }] }],
            "buffers": [{ "byteLength": vertex_bytes + normal_bytes + index_bytes }],
            "bufferViews": views,
            "accessors": accessors,
        })
    }
}

impl MeshSink for GlbSink {
    fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError> {
        self.core.spill_vertex(self.vertices.writer(), pos, attrs)
    }

    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        let (idx, corners) = self.core.triangle_u32(v, last_use, "glTF's u32 indices")?;
        let mut res = idx
            .iter()
            .try_for_each(|x| self.indices.writer().write_all(&x.to_le_bytes()));
        if let Some((normals, spill)) = &mut self.normals {
            normals.add(v, corners);
            for (i, &x) in v.iter().enumerate() {
                if last_use[i] && !v[..i].contains(&x) {
                    res = res.and_then(|()| normals.done(x, spill.writer()));
                }
            }
        }
        res.map_err(|e| self.core.scratch_error(e))
    }

    fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        self.core.finalize(v)?;
        let res = match &mut self.normals {
            Some((normals, spill)) => normals.done(v, spill.writer()),
            None => Ok(()),
        };
        res.map_err(|e| self.core.scratch_error(e))
    }

    fn finish(self: Box<Self>) -> Result<WriteStats, SmeshError> {
        self.core.finish()?;
        let (n, t) = (self.core.tracker.vertices(), self.core.tracker.triangles());
        let mut json = serde_json::to_vec(&self.document(n, t)).map_err(|e| {
            SmeshError::foreign(&self.core.path, format!("cannot encode glTF JSON: {e}"))
        })?;
        json.resize(json.len().next_multiple_of(4), b' ');
        let GlbSink {
            core,
            mut out,
            vertices,
            indices,
            normals,
            ..
        } = *self;
        let mut parts = vec![vertices];
        parts.extend(normals.map(|(_, spill)| spill));
        parts.push(indices);
        let mut bin_len = 0;
        for p in &mut parts {
            bin_len += p.rewind()?;
        }
        if t == 0 {
            bin_len = 0;
        }
        let bin_chunk = if t > 0 { 8 + bin_len } else { 0 };
        let total = 12 + 8 + json.len() as u64 + bin_chunk;
        let Ok(total) = u32::try_from(total) else {
            return Err(SmeshError::Unsupported {
                path: core.path.clone(),
                message: format!("{total} bytes exceed the 4 GiB a GLB file can hold"),
            });
        };
        out.write_all(b"glTF")?;
        out.write_all(&2u32.to_le_bytes())?;
        out.write_all(&total.to_le_bytes())?;
        out.write_all(&(json.len() as u32).to_le_bytes())?;
        out.write_all(b"JSON")?;
        out.write_all(&json)?;
        if t > 0 {
            out.write_all(&(bin_len as u32).to_le_bytes())?;
            out.write_all(b"BIN\0")?;
            for p in &mut parts {
                out.append(p)?;
            }
        }
        let bytes = out.finish()?;
        parts.into_iter().for_each(Spill::discard);
        Ok(core.stats(bytes))
    }

    fn checkpoint(&mut self) -> Result<SinkState, SmeshError> {
        let mut files = vec![
            self.out.mark()?,
            self.vertices.mark()?,
            self.indices.mark()?,
        ];
        if let Some((_, spill)) = &mut self.normals {
            files.push(spill.mark()?);
        }
        Ok(SinkState {
            files,
            tracker: self.core.tracker.clone(),
            format: Saved::Glb(self.normals.as_ref().map(|(n, _)| n.clone())),
        })
    }
}

/// The 12-byte GLB header's total length must cover the header and fit the file: the `gltf`
/// crate subtracts 12 from it unchecked (a panic found by `tools/fuzz.sh`, mesh_formats).
fn check_glb_header(path: &Path, bytes: &[u8]) -> Result<(), SmeshError> {
    if !bytes.starts_with(b"glTF") {
        return Ok(()); // a glTF JSON document; gltf parses it
    }
    let declared = bytes
        .get(8..12)
        .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]) as u64);
    match declared {
        Some(n) if n >= 12 && n <= bytes.len() as u64 => Ok(()),
        Some(n) => Err(SmeshError::foreign(
            path,
            format!(
                "invalid GLB: its header declares {n} bytes but the file has {} (at least 12 needed)",
                bytes.len()
            ),
        )),
        None => Err(SmeshError::Truncated {
            path: path.to_path_buf(),
            place: crate::Place::Byte(bytes.len() as u64),
            expected: "the 12-byte GLB header".into(),
        }),
    }
}

/// Loads a GLB file: every triangle primitive of every mesh (node transforms ignored), with the
/// `_NAME` float attributes of the first primitive as per-vertex attributes.
pub(crate) fn read(path: &Path) -> Result<IndexedMesh, SmeshError> {
    let bytes = std::fs::read(path).map_err(|e| SmeshError::io(path, "read", e))?;
    check_glb_header(path, &bytes)?;
    let gltf = gltf::Gltf::from_slice(&bytes)
        .map_err(|e| SmeshError::foreign(path, format!("invalid glTF: {e}")))?;
    let blob = gltf.blob.as_deref();
    let buffers = |b: gltf::Buffer| match b.source() {
        gltf::buffer::Source::Bin => blob,
        gltf::buffer::Source::Uri(_) => None,
    };
    let bad = |m: String| SmeshError::foreign(path, m);
    let mut mesh = IndexedMesh::default();
    let mut first = true;
    for (p, prim) in gltf.meshes().flat_map(|m| m.primitives()).enumerate() {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            return Err(bad(format!("primitive {p} is not made of triangles")));
        }
        let reader = prim.reader(buffers);
        let base = mesh.positions.len();
        let positions = reader
            .read_positions()
            .ok_or_else(|| bad(format!("primitive {p} has no embedded POSITION data")))?;
        mesh.positions.extend(positions.map(|x| x.map(f64::from)));
        let n = mesh.positions.len() - base;
        if first {
            mesh.attribute_names = prim
                .attributes()
                .filter_map(|(s, _)| match s {
                    gltf::Semantic::Extras(name) => Some(name),
                    _ => None,
                })
                .collect();
            first = false;
        }
        let k = mesh.attribute_names.len();
        let mut values = vec![0f32; n * k];
        for (j, name) in mesh.attribute_names.iter().enumerate() {
            let accessor = prim
                .get(&gltf::Semantic::Extras(name.clone()))
                .ok_or_else(|| bad(format!("primitive {p} lacks attribute _{name}")))?;
            let it = gltf::accessor::Iter::<f32>::new(accessor, buffers).ok_or_else(|| {
                bad(format!(
                    "primitive {p}: attribute _{name} is not embedded float data"
                ))
            })?;
            for (i, x) in it.take(n).enumerate() {
                values[i * k + j] = x;
            }
        }
        mesh.attrs.extend(values);
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..n as u32).collect(),
        };
        if let Some(&v) = indices.iter().find(|&&v| v as usize >= n) {
            return Err(bad(format!(
                "primitive {p} references vertex {v} but has {n} vertices"
            )));
        }
        let base = base as u32;
        mesh.triangles.extend(
            indices
                .chunks_exact(3)
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fuzz crash (mesh_formats): a GLB header declaring a length below 12 panicked in gltf.
    #[test]
    fn short_declared_length_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.glb");
        let mut bytes = b"glTF\x00\x00\x20\x00".to_vec();
        bytes.extend([0u8; 120]);
        std::fs::write(&p, &bytes).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.contains("declares 0 bytes"), "{e}");
        std::fs::write(&p, b"glTF\x02\x00").unwrap();
        assert!(read(&p).is_err());
    }
}
