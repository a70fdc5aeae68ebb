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
//! Reading goes through the `gltf` crate, which validates the document; the node transforms
//! are applied by hand (`instances`), since the crate leaves them to the caller.

use std::collections::BTreeMap;

use rustc_hash::FxHashMap;
use std::io::Write;
use std::path::Path;

use serde_json::json;

use crate::atomic::{AtomicFile, Spill};
use crate::sink::{Completed, MeshSink, Saved, SinkCore, SinkState, mismatch};
use crate::stl::{face_normal, normalized};
use crate::{Header, IndexedMesh, SmeshError};

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

    fn complete(self: Box<Self>) -> Result<Completed, SmeshError> {
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
        Completed::new(out, parts, |bytes| core.stats(bytes))
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

/// Parses the document and validates it, after checking what the `gltf` crate's validation
/// takes for granted: it indexes the accessors a primitive's `POSITION` names without a bounds
/// check (a panic found by `tools/fuzz.sh`), so every accessor a primitive names must exist.
fn parse(path: &Path, bytes: &[u8]) -> Result<gltf::Gltf, SmeshError> {
    use gltf::json::validation::Validate;
    // A validation error's text starts with "invalid glTF:" already.
    let invalid = |e: gltf::Error| match e {
        gltf::Error::Validation(_) => SmeshError::foreign(path, e),
        _ => SmeshError::foreign(path, format!("invalid glTF: {e}")),
    };
    let gltf = gltf::Gltf::from_slice_without_validation(bytes).map_err(invalid)?;
    let root = gltf.as_json();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (j, prim) in mesh.primitives.iter().enumerate() {
            let named = prim
                .attributes
                .iter()
                .map(|(s, a)| (format!("attribute {}", s.to_string()), a.value()))
                .chain(prim.indices.map(|a| ("indices".to_string(), a.value())));
            for (what, a) in named {
                if a >= root.accessors.len() {
                    return Err(SmeshError::foreign(
                        path,
                        format!(
                            "invalid glTF: mesh {m} primitive {j} {what} names accessor {a}, but the file has {} accessors",
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    let mut errors = Vec::new();
    root.validate(root, gltf::json::Path::new, &mut |p, e| {
        errors.push((p(), e))
    });
    if !errors.is_empty() {
        return Err(invalid(gltf::Error::Validation(errors)));
    }
    Ok(gltf)
}

/// What an accessor read from a primitive must hold: the `gltf` crate reads it as that type
/// without checking, and panics (or reads garbage) on any other.
#[derive(Clone, Copy)]
enum Element {
    /// `POSITION`: a float VEC3.
    Vec3,
    /// A `_NAME` attribute: a float SCALAR.
    Float,
    /// Triangle indices: an unsigned byte, short or int SCALAR.
    Index,
}

/// Refuses an accessor the `gltf` crate would panic on or read wrongly: the wrong type for its
/// use (float indices hit an `unreachable!`), a buffer view stride below the element size (an
/// assertion), or elements beyond its buffer view or the view beyond the GLB's binary chunk
/// (indices then silently read as absent, i.e. 0, 1, 2, ...).
fn check_accessor(
    path: &Path,
    accessor: &gltf::Accessor,
    what: &str,
    element: Element,
    blob: Option<&[u8]>,
) -> Result<(), SmeshError> {
    use gltf::accessor::{DataType, Dimensions};
    let a = accessor.index();
    let bad =
        |m: String| SmeshError::foreign(path, format!("invalid glTF: accessor {a} ({what}) {m}"));
    let (ty, dims) = (accessor.data_type(), accessor.dimensions());
    let fits = match element {
        Element::Vec3 => ty == DataType::F32 && dims == Dimensions::Vec3,
        Element::Float => ty == DataType::F32 && dims == Dimensions::Scalar,
        Element::Index => {
            matches!(ty, DataType::U8 | DataType::U16 | DataType::U32) && dims == Dimensions::Scalar
        }
    };
    if !fits {
        let expected = match element {
            Element::Vec3 => "F32 Vec3",
            Element::Float => "F32 Scalar",
            Element::Index => "U8, U16 or U32 Scalar",
        };
        return Err(bad(format!(
            "holds {ty:?} {dims:?}, but must hold {expected}"
        )));
    }
    let size = accessor.size();
    let count = accessor.count();
    // Validation requires a buffer view unless the accessor is sparse.
    if let Some(view) = accessor.view() {
        check_span(&bad, view, accessor.offset(), count, size, blob)?;
    }
    if let Some(sparse) = accessor.sparse() {
        let (indices, values) = (sparse.indices(), sparse.values());
        let n = sparse.count();
        let index_size = indices.index_type().size();
        check_span(&bad, indices.view(), indices.offset(), n, index_size, blob)?;
        check_span(&bad, values.view(), values.offset(), n, size, blob)?;
    }
    Ok(())
}

/// Checks that `count` elements of `size` bytes from `offset` lie within `view`, at a stride no
/// smaller than `size`, and `view` within the GLB's binary chunk, in u64 (the `gltf` crate's
/// usize arithmetic overflows on huge counts).
fn check_span(
    bad: &dyn Fn(String) -> SmeshError,
    view: gltf::buffer::View,
    offset: usize,
    count: usize,
    size: usize,
    blob: Option<&[u8]>,
) -> Result<(), SmeshError> {
    let v = view.index();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(bad(format!(
            "reads bufferView {v} of byteStride {stride}, less than its {size}-byte elements"
        )));
    }
    if count == 0 {
        return Err(bad("has count 0 (glTF requires at least 1)".into()));
    }
    let end = (stride as u64)
        .checked_mul(count as u64 - 1)
        .and_then(|x| x.checked_add(offset as u64 + size as u64));
    let length = view.length() as u64;
    if end.is_none_or(|end| end > length) {
        return Err(bad(format!(
            "has {count} elements from byte {offset}, which reach past the {length} bytes of bufferView {v}"
        )));
    }
    let chunk = match view.buffer().source() {
        gltf::buffer::Source::Bin => blob,
        gltf::buffer::Source::Uri(_) => None,
    };
    let Some(chunk) = chunk else {
        return Err(bad(format!(
            "reads bufferView {v}, which is not in the GLB's binary chunk"
        )));
    };
    let view_end = view.offset() as u64 + length;
    if view_end > chunk.len() as u64 {
        return Err(bad(format!(
            "reads bufferView {v}, which ends at byte {view_end} of a {}-byte binary chunk",
            chunk.len()
        )));
    }
    Ok(())
}

/// A 4 x 4 matrix, glTF's column-major layout (`m[column][row]`), in f64.
type Matrix = [[f64; 4]; 4];

const IDENTITY: Matrix = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

fn multiply(a: &Matrix, b: &Matrix) -> Matrix {
    std::array::from_fn(|c| std::array::from_fn(|r| (0..4).map(|k| a[k][r] * b[c][k]).sum()))
}

fn apply(m: &Matrix, p: [f32; 3]) -> [f64; 3] {
    let v = [p[0], p[1], p[2], 1.0].map(f64::from);
    std::array::from_fn(|r| (0..4).map(|c| m[c][r] * v[c]).sum())
}

/// Whether `m` mirrors: a negative determinant of its linear part turns counter-clockwise
/// triangles clockwise, so their winding must be swapped to keep the surface facing out.
fn mirrors(m: &Matrix) -> bool {
    let d = m[0][0] * (m[1][1] * m[2][2] - m[2][1] * m[1][2])
        - m[1][0] * (m[0][1] * m[2][2] - m[2][1] * m[0][2])
        + m[2][0] * (m[0][1] * m[1][2] - m[1][1] * m[0][2]);
    d < 0.0
}

/// Every mesh instance the file shows, with its node's world transform: the node hierarchy of
/// the default scene, or of the first scene when none is the default (as viewers show it;
/// every scene at once put a node listed in two scenes twice on top of itself). A document
/// without scenes shows no nodes; its meshes are taken as they are, untransformed.
fn instances<'a>(
    path: &Path,
    gltf: &'a gltf::Gltf,
) -> Result<Vec<(gltf::Mesh<'a>, Matrix)>, SmeshError> {
    if gltf.scenes().len() == 0 {
        return Ok(gltf.meshes().map(|m| (m, IDENTITY)).collect());
    }
    let mut out = Vec::new();
    if let Some(scene) = gltf.default_scene().or_else(|| gltf.scenes().next()) {
        // A node met twice in one scene has two parents or is its own ancestor, which glTF
        // forbids but the `gltf` crate does not check: a cycle would never end, and shared
        // subtrees could multiply the work without bound.
        let mut seen = vec![false; gltf.nodes().len()];
        let mut todo: Vec<(gltf::Node, Matrix)> = scene.nodes().map(|n| (n, IDENTITY)).collect();
        todo.reverse();
        while let Some((node, parent)) = todo.pop() {
            if std::mem::replace(&mut seen[node.index()], true) {
                return Err(SmeshError::foreign(
                    path,
                    format!(
                        "invalid glTF: node {} appears twice in scene {} (the node hierarchy must be a tree)",
                        node.index(),
                        scene.index()
                    ),
                ));
            }
            let local = local_matrix(path, &node)?;
            let world = multiply(&parent, &local);
            if let Some(mesh) = node.mesh() {
                out.push((mesh, world));
            }
            let first_child = todo.len();
            todo.extend(node.children().map(|c| (c, world)));
            todo[first_child..].reverse();
        }
    }
    Ok(out)
}

/// Vertices plus triangles a scene may instance: [`MAX_INSTANCED_PER_BYTE`] per byte of the
/// file, and at least this many (about 400 MB once loaded and measured).
const MIN_INSTANCED_LIMIT: u64 = 1 << 22;
/// A file without instancing holds at least 3 bytes per vertex or triangle (u8 indices), so 16
/// per byte is only reached by instancing; 5000 nodes showing a mesh of 1000 primitives of one
/// tetrahedron are 141 KB of JSON and 20 million vertices (2.3 GB in `measure`).
const MAX_INSTANCED_PER_BYTE: u64 = 16;

/// Refuses a scene whose instances would load far more vertices and triangles than the file
/// could hold (a decompression bomb), before any of them is read: node and primitive lists
/// multiply, and a small file could otherwise ask for any amount of memory.
fn check_instanced_size(
    path: &Path,
    file_bytes: u64,
    instances: &[(gltf::Mesh, Matrix)],
) -> Result<(), SmeshError> {
    let (mut vertices, mut triangles) = (0u64, 0u64);
    for (mesh, _) in instances {
        for prim in mesh.primitives() {
            let n = prim
                .get(&gltf::Semantic::Positions)
                .map_or(0, |a| a.count()) as u64;
            let corners = prim.indices().map_or(n, |a| a.count() as u64);
            vertices = vertices.saturating_add(n);
            triangles = triangles.saturating_add(corners / 3);
        }
    }
    let limit = MIN_INSTANCED_LIMIT.max(MAX_INSTANCED_PER_BYTE.saturating_mul(file_bytes));
    if vertices.saturating_add(triangles) > limit {
        return Err(SmeshError::foreign(
            path,
            format!(
                "the scene's {} mesh instances hold {vertices} vertices and {triangles} triangles, more than the {limit} in all a {file_bytes}-byte GLB may expand to ({MAX_INSTANCED_PER_BYTE} per byte, at least {MIN_INSTANCED_LIMIT}); export the scene with fewer instances",
                instances.len()
            ),
        ));
    }
    Ok(())
}

/// A node's own transform. glTF requires unit rotation quaternions but the `gltf` crate takes
/// them as they are, and one of length 2 scaled the mesh by 4: normalised here, and one of
/// length 0 (no rotation at all) refused.
fn local_matrix(path: &Path, node: &gltf::Node) -> Result<Matrix, SmeshError> {
    let transform = match node.transform() {
        gltf::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => {
            let length = rotation.iter().map(|q| q * q).sum::<f32>().sqrt();
            if !(length.is_finite() && length > 0.0) {
                return Err(SmeshError::foreign(
                    path,
                    format!(
                        "invalid glTF: node {} has rotation {rotation:?}, not a unit quaternion",
                        node.index()
                    ),
                ));
            }
            gltf::scene::Transform::Decomposed {
                translation,
                rotation: rotation.map(|q| q / length),
                scale,
            }
        }
        matrix => matrix,
    };
    Ok(transform.matrix().map(|c| c.map(f64::from)))
}

/// The strings of `asset.extras.comments`, where [`GlbSink`] writes the header's comments (other
/// values there, and comments other formats cannot hold, are passed over).
fn comments(gltf: &gltf::Gltf) -> Vec<String> {
    let Some(extras) = &gltf.as_json().asset.extras else {
        return Vec::new();
    };
    let extras: serde_json::Value = serde_json::from_str(extras.get()).unwrap_or_default();
    extras["comments"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|c| c.as_str())
        .filter_map(crate::sma::carried_comment)
        .collect()
}

/// Loads a GLB file: every triangle primitive of every mesh instance of the scene, placed by
/// its node's world transform (see [`instances`]; a mesh two nodes show comes out twice, each
/// where its node puts it), with the `_NAME` float attributes of the first primitive as
/// per-vertex attributes.
pub(crate) fn read(path: &Path) -> Result<IndexedMesh, SmeshError> {
    let bytes = std::fs::read(path).map_err(|e| SmeshError::io(path, "read", e))?;
    check_glb_header(path, &bytes)?;
    let gltf = parse(path, &bytes)?;
    let comments = comments(&gltf);
    let blob = gltf.blob.as_deref();
    let buffers = |b: gltf::Buffer| match b.source() {
        gltf::buffer::Source::Bin => blob,
        gltf::buffer::Source::Uri(_) => None,
    };
    let bad = |m: String| SmeshError::foreign(path, m);
    let mut mesh = IndexedMesh {
        comments,
        ..IndexedMesh::default()
    };
    let mut first = true;
    let instances = instances(path, &gltf)?;
    // Accessor counts are trusted below (the size check, then reading) once checked here,
    // once per mesh however often it is instanced.
    let mut checked = vec![false; gltf.meshes().len()];
    for (mesh, _) in &instances {
        if std::mem::replace(&mut checked[mesh.index()], true) {
            continue;
        }
        for prim in mesh.primitives() {
            if let Some(position) = prim.get(&gltf::Semantic::Positions) {
                check_accessor(path, &position, "POSITION", Element::Vec3, blob)?;
            }
            if let Some(indices) = prim.indices() {
                check_accessor(path, &indices, "indices", Element::Index, blob)?;
            }
        }
    }
    check_instanced_size(path, bytes.len() as u64, &instances)?;
    let primitives = instances
        .iter()
        .flat_map(|(m, world)| m.primitives().map(move |p| (p, world)));
    for (p, (prim, world)) in primitives.enumerate() {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            return Err(bad(format!("primitive {p} is not made of triangles")));
        }
        let reader = prim.reader(buffers);
        let base = mesh.positions.len();
        let positions = reader
            .read_positions()
            .ok_or_else(|| bad(format!("primitive {p} has no embedded POSITION data")))?;
        mesh.positions.extend(positions.map(|x| apply(world, x)));
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
            check_accessor(path, &accessor, &format!("_{name}"), Element::Float, blob)?;
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
        // Instancing can repeat a mesh past what u32 indices reach: refused, not wrapped.
        let base = u32::try_from(mesh.positions.len())
            .map(|_| base as u32)
            .map_err(|_| {
                bad(format!(
                    "the scene's mesh instances hold more than {} vertices",
                    u32::MAX
                ))
            })?;
        let mirrored = mirrors(world);
        mesh.triangles.extend(indices.chunks_exact(3).map(|t| {
            let [a, b, c] = [t[0], t[1], t[2]].map(|v| v + base);
            if mirrored { [a, c, b] } else { [a, b, c] }
        }));
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

    /// A GLB of one tetrahedron mesh (outward, volume 1/6) and the given scene part of the
    /// document (`scene`, `scenes`, `nodes`).
    fn tetrahedra(dir: &Path, scenes: serde_json::Value) -> std::path::PathBuf {
        let mut bin = Vec::new();
        for c in [0f32, 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.] {
            bin.extend(c.to_le_bytes());
        }
        for i in [0u16, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3] {
            bin.extend(i.to_le_bytes());
        }
        let mut doc = json!({
            "asset": { "version": "2.0" },
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
            "buffers": [{ "byteLength": 72 }],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": 48 },
                { "buffer": 0, "byteOffset": 48, "byteLength": 24 },
            ],
            "accessors": [
                { "bufferView": 0, "componentType": FLOAT, "count": 4, "type": "VEC3",
                  "min": [0, 0, 0], "max": [1, 1, 1] },
                { "bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR" },
            ],
        });
        for (k, v) in scenes.as_object().unwrap() {
            doc[k] = v.clone();
        }
        write_glb(dir, &doc, &bin)
    }

    /// Writes `doc` and the binary chunk `bin` (72 bytes) as `dir/t.glb`.
    fn write_glb(dir: &Path, doc: &serde_json::Value, bin: &[u8]) -> std::path::PathBuf {
        let mut json = serde_json::to_vec(&doc).unwrap();
        json.resize(json.len().next_multiple_of(4), b' ');
        let mut bytes = b"glTF".to_vec();
        bytes.extend(2u32.to_le_bytes());
        bytes.extend((12 + 8 + json.len() as u32 + 8 + 72).to_le_bytes());
        bytes.extend((json.len() as u32).to_le_bytes());
        bytes.extend(b"JSON");
        bytes.extend(json);
        bytes.extend(72u32.to_le_bytes());
        bytes.extend(b"BIN\0");
        bytes.extend(bin);
        let p = dir.join("t.glb");
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// Fuzz crashes (mesh_formats): accessors the `gltf` crate panicked on are refused with one
    /// line each, and the tetrahedron they were made from still reads.
    #[test]
    fn accessors_gltf_would_panic_on_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let scene = json!({ "scene": 0, "scenes": [{ "nodes": [0] }], "nodes": [{ "mesh": 0 }] });
        let good = read(&tetrahedra(dir.path(), scene.clone())).unwrap();
        assert_eq!((good.positions.len(), good.triangles.len()), (4, 4));
        let cases = [
            (
                "/meshes/0/primitives/0/attributes/POSITION",
                json!(5),
                "primitive 0 attribute POSITION names accessor 5, but the file has 2 accessors",
            ),
            (
                "/accessors/1/componentType",
                json!(FLOAT),
                "must hold U8, U16 or U32 Scalar",
            ),
            (
                "/accessors/1/type",
                json!("VEC2"),
                "must hold U8, U16 or U32 Scalar",
            ),
            (
                "/accessors/0/componentType",
                json!(5123),
                "must hold F32 Vec3",
            ),
            (
                "/bufferViews/0/byteStride",
                json!(4),
                "byteStride 4, less than its 12-byte",
            ),
            (
                "/bufferViews/0/byteStride",
                json!(8),
                "byteStride 8, less than its 12-byte",
            ),
            (
                "/accessors/0/count",
                json!(5),
                "reach past the 48 bytes of bufferView 0",
            ),
            (
                "/accessors/1/count",
                json!(1u64 << 62),
                "reach past the 24 bytes",
            ),
            ("/accessors/1/count", json!(0), "count 0"),
            (
                "/bufferViews/1/byteLength",
                json!(40),
                "ends at byte 88 of a 72-byte binary chunk",
            ),
        ];
        for (pointer, value, expected) in cases {
            let p = tetrahedra(dir.path(), scene.clone());
            let bytes = std::fs::read(&p).unwrap();
            let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
            let mut doc: serde_json::Value =
                serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
            let (parent, key) = pointer.rsplit_once('/').unwrap();
            doc.pointer_mut(parent).unwrap()[key] = value;
            let p = write_glb(dir.path(), &doc, &bytes[20 + json_len + 8..]);
            let e = read(&p).unwrap_err().to_string();
            assert!(e.contains(expected) && !e.contains('\n'), "{pointer}: {e}");
        }
    }

    /// Fuzz blow-up: nodes times primitives multiplied a small file into millions of vertices;
    /// a scene expanding past 16 per byte of the file (and past 2^22) is refused before reading.
    #[test]
    fn instancing_bombs_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let scene = |nodes: usize| {
            json!({
                "scene": 0,
                "scenes": [{ "nodes": (0..nodes).collect::<Vec<_>>() }],
                "nodes": vec![json!({ "mesh": 0 }); nodes],
            })
        };
        let p = tetrahedra(dir.path(), scene(1000));
        assert_eq!(read(&p).unwrap().positions.len(), 4000);
        let bytes = std::fs::read(&p).unwrap();
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let mut doc: serde_json::Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
        let prim = doc["meshes"][0]["primitives"][0].clone();
        doc["meshes"][0]["primitives"] = json!(vec![prim; 2000]);
        let p = write_glb(dir.path(), &doc, &bytes[20 + json_len + 8..]);
        let e = read(&p).unwrap_err().to_string();
        assert!(
            e.contains("1000 mesh instances hold 8000000 vertices and 8000000 triangles")
                && !e.contains("\n"),
            "{e}"
        );
    }

    /// Six times the signed volume enclosed by the triangles: positive when they face out.
    fn volume6(m: &IndexedMesh) -> f64 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| m.positions[v as usize]);
                a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0])
            })
            .sum()
    }

    /// A translated node moves its mesh; a mesh shown by two nodes comes out twice, each where
    /// its node (and its parents) put it, and a mirroring node's triangles still face out.
    /// Scenes other than the default one are not shown.
    #[test]
    fn node_transforms_place_every_instance() {
        let dir = tempfile::tempdir().unwrap();
        let scenes = json!({
            "scene": 0,
            "scenes": [{ "nodes": [0, 1] }, { "nodes": [3] }],
            "nodes": [
                { "mesh": 0, "translation": [10, 0, 0] },
                { "children": [2], "translation": [0, 5, 0] },
                { "mesh": 0, "matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1] },
                { "mesh": 0, "translation": [0, 0, 99] },
            ],
        });
        let m = read(&tetrahedra(dir.path(), scenes)).unwrap();
        assert_eq!(m.positions.len(), 8);
        assert_eq!(
            m.positions[..4],
            [[10., 0., 0.], [11., 0., 0.], [10., 1., 0.], [10., 0., 1.]]
        );
        assert_eq!(
            m.positions[4..],
            [[0., 5., 0.], [-1., 5., 0.], [0., 6., 0.], [0., 5., 1.]]
        );
        assert_eq!(
            m.triangles[..4],
            [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
        );
        assert_eq!(
            m.triangles[4..],
            [[4, 5, 6], [4, 7, 5], [4, 6, 7], [5, 7, 6]]
        );
        assert!((volume6(&m) - 2.0).abs() < 1e-12, "{}", volume6(&m));

        // Without a default scene the first is shown (as viewers show it), its rotation
        // quaternion normalised (one of length 2 scaled the mesh by 4).
        let first = json!({
            "scenes": [{ "nodes": [1] }, { "nodes": [0] }],
            "nodes": [
                { "mesh": 0, "translation": [10, 0, 0] },
                { "mesh": 0, "rotation": [0, 0, 2, 0], "scale": [1, 1, 2] },
            ],
        });
        let m = read(&tetrahedra(dir.path(), first)).unwrap();
        assert_eq!(
            m.positions,
            [[0., 0., 0.], [-1., 0., 0.], [0., -1., 0.], [0., 0., 2.]]
        );
        assert!((volume6(&m) - 2.0).abs() < 1e-6, "{}", volume6(&m));
        let no_rotation = json!({
            "scene": 0,
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "mesh": 0, "rotation": [0, 0, 0, 0] }],
        });
        let e = read(&tetrahedra(dir.path(), no_rotation))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a unit quaternion"), "{e}");

        // A node that is its own ancestor is refused rather than followed for ever.
        let cycle = json!({
            "scene": 0,
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "children": [1] }, { "mesh": 0, "children": [0] }],
        });
        let e = read(&tetrahedra(dir.path(), cycle))
            .unwrap_err()
            .to_string();
        assert!(e.contains("node 0 appears twice in scene 0"), "{e}");
    }
}
