//! In-memory indexed meshes: loading any supported format (for tests and `measure`, where meshes
//! are small) and emitting one as a stream in compact pre-order.

use std::path::Path;

use crate::validate::CheckedStream;
use crate::{Element, Format, MeshSink, SmeshError, glb, obj, ply, stl};

/// A whole mesh in memory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IndexedMesh {
    pub positions: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
    pub attribute_names: Vec<String>,
    /// Per-vertex attributes, `attribute_names.len()` values per vertex.
    pub attrs: Vec<f32>,
    /// The file's header comments, one line each (a run writes its provenance there:
    /// `isostream VERSION`, `input PATH iso VALUE`), so that `convert` carries them on; only
    /// those every format can store, as they can store them (`sma::carried_comment`).
    pub comments: Vec<String>,
}

/// In-memory load of a (small) mesh of any supported format: positions, triangles, per-vertex
/// attributes. Streaming inputs are checked against the streaming rules on the way.
pub fn read_indexed(path: &Path) -> Result<IndexedMesh, SmeshError> {
    crate::input::regular_file(path)?;
    let mesh = match Format::from_path(path)? {
        Format::Sma | Format::Smb => return read_stream(path),
        Format::Ply => ply::read(path),
        Format::Obj => obj::read(path),
        Format::Stl => stl::read(path),
        Format::Glb => glb::read(path),
    }?;
    finite(path, mesh)
}

/// Refuses a foreign mesh with a NaN or infinite coordinate, as the streaming formats' check
/// does: every distance, angle and box computed from it would be NaN (`measure` reported a NaN
/// directional bias and carried on). A finite coordinate beyond f32's range (a PLY double) is
/// refused too: every output format holds f32, and `convert` wrote it as inf without a word.
fn finite(path: &Path, mesh: IndexedMesh) -> Result<IndexedMesh, SmeshError> {
    let fits = |c: &f64| (*c as f32).is_finite();
    match mesh.positions.iter().position(|p| !p.iter().all(fits)) {
        None => Ok(mesh),
        Some(i) => {
            let [x, y, z] = mesh.positions[i];
            let message = if mesh.positions[i].iter().all(|c| c.is_finite()) {
                format!(
                    "vertex {i} has a coordinate beyond the range of f32 (about ±3.4e38) that meshes are held in ({x:e}, {y:e}, {z:e}); rescale the mesh"
                )
            } else {
                format!(
                    "vertex {i} has a non-finite coordinate ({x}, {y}, {z}); the mesh is corrupt"
                )
            };
            Err(SmeshError::foreign(path, message))
        }
    }
}

fn read_stream(path: &Path) -> Result<IndexedMesh, SmeshError> {
    let mut stream = CheckedStream::open(path)?;
    let mut mesh = IndexedMesh {
        attribute_names: stream.header().attribute_names.clone(),
        comments: crate::sma::carried_comments(&stream.header().comments),
        ..IndexedMesh::default()
    };
    while let Some(e) = stream.next_element() {
        match e? {
            Element::Vertex { pos, attrs } => {
                mesh.positions.push(pos.map(f64::from));
                mesh.attrs.extend(attrs);
            }
            Element::Triangle { v, .. } => {
                let t = v.map(|x| u32::try_from(x).ok());
                match t {
                    [Some(a), Some(b), Some(c)] => mesh.triangles.push([a, b, c]),
                    _ => {
                        return Err(SmeshError::Unsupported {
                            path: path.to_path_buf(),
                            message: format!(
                                "triangle {v:?} needs indices beyond 32 bits, too large to load in memory"
                            ),
                        });
                    }
                }
            }
            Element::Finalize(_) => {}
        }
    }
    stream.finish()?;
    Ok(mesh)
}

impl IndexedMesh {
    /// Writes the mesh into `sink` in compact pre-order: triangles in their order, each vertex
    /// right before its first triangle, finalized on its last one. Vertices are renumbered in
    /// order of first use; vertices no triangle uses are dropped (SMB could not finalize them).
    /// Returns the number of dropped vertices.
    pub fn stream_into(&self, sink: &mut dyn MeshSink) -> Result<u64, SmeshError> {
        let stride = self.attribute_names.len();
        let mut last = vec![usize::MAX; self.positions.len()];
        for (t, tri) in self.triangles.iter().enumerate() {
            for &v in tri {
                last[v as usize] = t;
            }
        }
        let mut id = vec![u64::MAX; self.positions.len()];
        let mut next = 0u64;
        for (t, tri) in self.triangles.iter().enumerate() {
            for &v in tri {
                let v = v as usize;
                if id[v] == u64::MAX {
                    id[v] = next;
                    next += 1;
                    sink.vertex(
                        self.positions[v].map(|x| x as f32),
                        &self.attrs[v * stride..(v + 1) * stride],
                    )?;
                }
            }
            sink.triangle(
                tri.map(|v| id[v as usize]),
                tri.map(|v| last[v as usize] == t),
            )?;
        }
        Ok(self.positions.len() as u64 - next)
    }
}
