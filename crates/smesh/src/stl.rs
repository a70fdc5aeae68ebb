//! Binary STL: an 80-byte header, a u32 triangle count, then per triangle a unit normal, three
//! corner positions (f32) and a u16 attribute byte count of 0.
//!
//! STL stores positions per triangle, so the sink needs the positions of active vertices only:
//! the tracker keeps them until finalization, memory stays bounded by the stream width. The count
//! is patched in place on finish. Reading goes through `stl_io` (ascii or binary), which welds
//! identical corners back into shared vertices.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use crate::atomic::AtomicFile;
use crate::sink::{Completed, MeshSink, Saved, SinkCore, SinkState};
use crate::{Header, IndexedMesh, SmeshError};

const COUNT_AT: u64 = 80;
/// How the header of a binary STL this crate wrote begins; parts follow, each after `; `.
const SIGNATURE: &str = "binary STL by isostream";
/// The header part naming the attributes not written: a fact about this file, not a comment.
const ATTRIBUTES_DROPPED: &str = "attributes dropped: ";

/// Streaming binary STL writer. Attributes are dropped (STL has none); the header text names
/// them, as OBJ's comment does, so the loss is visible in the file.
pub struct StlSink {
    core: SinkCore,
    out: AtomicFile,
}

impl StlSink {
    /// Starts writing `path` (via a temporary file beside it); fails naming `path` if its
    /// directory is missing or not writable.
    pub fn create(path: &Path, header: &Header) -> Result<StlSink, SmeshError> {
        let core = SinkCore::new(path, header)?;
        let mut out = AtomicFile::create(path)?;
        // Must not start with "solid": readers would take the file for ASCII STL.
        let mut text = String::from(SIGNATURE);
        // The loss is stated before the comments, which the 80 bytes may cut.
        if !header.attribute_names.is_empty() {
            text.push_str("; ");
            text.push_str(ATTRIBUTES_DROPPED);
            text.push_str(&header.attribute_names.join(" "));
        }
        // Each comment whole or not at all: `read` takes them back, and a cut one would come
        // back as another comment (a path cut short).
        for c in &header.comments {
            if text.len() + 2 + c.len() <= 80 {
                text.push_str("; ");
                text.push_str(c);
            }
        }
        let mut head = [b' '; 80];
        let n = text.len().min(80);
        head[..n].copy_from_slice(&text.as_bytes()[..n]);
        out.write_all(&head)?;
        out.write_all(&0u32.to_le_bytes())?;
        Ok(StlSink { core, out })
    }

    /// Continues a checkpointed sink (see [`MeshSink::checkpoint`]).
    pub(crate) fn resume(
        path: &Path,
        header: &Header,
        state: SinkState,
    ) -> Result<StlSink, SmeshError> {
        let (core, out, _) = state.reopen_one(path, header, |f| matches!(f, Saved::Stl), "STL")?;
        Ok(StlSink { core, out })
    }
}

/// Unit normal of a counter-clockwise triangle (zero for a degenerate one), computed in f64.
pub(crate) fn face_normal(c: [[f32; 3]; 3]) -> [f64; 3] {
    let p = c.map(|v| v.map(f64::from));
    let u = [0, 1, 2].map(|i| p[1][i] - p[0][i]);
    let w = [0, 1, 2].map(|i| p[2][i] - p[0][i]);
    [
        u[1] * w[2] - u[2] * w[1],
        u[2] * w[0] - u[0] * w[2],
        u[0] * w[1] - u[1] * w[0],
    ]
}

pub(crate) fn normalized(n: [f64; 3]) -> Option<[f32; 3]> {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    (len > 0.0 && len.is_finite()).then(|| n.map(|x| (x / len) as f32))
}

impl MeshSink for StlSink {
    fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError> {
        self.core.vertex(pos, attrs).map(|_| ())
    }

    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        if self.core.tracker.triangles() >= u64::from(u32::MAX) {
            return Err(SmeshError::Unsupported {
                path: self.core.path.clone(),
                message: "more than 4294967295 triangles do not fit binary STL's u32 count".into(),
            });
        }
        let corners = self.core.triangle(v, last_use)?;
        let normal = normalized(face_normal(corners)).unwrap_or([0.0; 3]);
        let mut rec = [0u8; 50];
        for (i, x) in normal.iter().chain(corners.as_flattened()).enumerate() {
            rec[4 * i..4 * i + 4].copy_from_slice(&x.to_le_bytes());
        }
        self.out.write_all(&rec)
    }

    fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        self.core.finalize(v)
    }

    fn complete(mut self: Box<Self>) -> Result<Completed, SmeshError> {
        self.core.finish()?;
        let count = self.core.tracker.triangles() as u32;
        self.out.patch(COUNT_AT, &count.to_le_bytes())?;
        let StlSink { core, out, .. } = *self;
        Completed::new(out, Vec::new(), |bytes| core.stats(bytes))
    }

    fn checkpoint(&mut self) -> Result<SinkState, SmeshError> {
        SinkState::of_one(&mut self.out, &self.core, Saved::Stl)
    }
}

/// Loads an STL file (ascii or binary) with identical corners welded, and the comments of a
/// header this crate wrote.
pub(crate) fn read(path: &Path) -> Result<IndexedMesh, SmeshError> {
    let mut input = BufReader::new(File::open(path).map_err(|e| SmeshError::io(path, "open", e))?);
    // A file cut short failed with stl_io's bare "failed to fill whole buffer", which said
    // neither what was wrong with the file nor what to do.
    let stl = stl_io::read_stl(&mut input).map_err(|e| {
        let message = match e.kind() {
            std::io::ErrorKind::UnexpectedEof => {
                format!("invalid STL: the file is truncated ({e}); copy or export it again")
            }
            _ => format!("invalid STL: {e}"),
        };
        SmeshError::foreign(path, message)
    })?;
    // Up to 80 bytes: an ASCII STL may be shorter (`solid t\nendsolid t\n`).
    let mut head = Vec::with_capacity(80);
    input
        .seek(SeekFrom::Start(0))
        .and_then(|_| (&mut input).take(80).read_to_end(&mut head))
        .map_err(|e| SmeshError::io(path, "read", e))?;
    let mut mesh = IndexedMesh {
        positions: stl.vertices.iter().map(|v| v.0.map(f64::from)).collect(),
        comments: comments(&head),
        ..IndexedMesh::default()
    };
    for f in &stl.faces {
        let t = f.vertices.map(u32::try_from);
        match t {
            [Ok(a), Ok(b), Ok(c)] => mesh.triangles.push([a, b, c]),
            _ => {
                return Err(SmeshError::foreign(
                    path,
                    "more than 2^32 distinct STL corners",
                ));
            }
        }
    }
    Ok(mesh)
}

/// The comments of an 80-byte header [`StlSink`] wrote (whole, each after `; `, the note on
/// dropped attributes left out); none from another writer's, whose header is free bytes.
fn comments(head: &[u8]) -> Vec<String> {
    let text = String::from_utf8_lossy(head);
    let Some(parts) = text.trim_end().strip_prefix(SIGNATURE) else {
        return Vec::new();
    };
    parts
        .split("; ")
        .skip(1)
        .map(str::trim)
        .filter(|c| !c.starts_with(ATTRIBUTES_DROPPED) && crate::sma::free_comment(c))
        .map(str::to_string)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A binary STL cut inside its triangles, and an ASCII one cut inside a facet, are named
    /// truncated, with the fix.
    #[test]
    fn a_truncated_stl_is_named_truncated() {
        let dir = tempfile::tempdir().unwrap();
        let mut binary = vec![0u8; 80];
        binary.extend_from_slice(&2u32.to_le_bytes());
        binary.extend_from_slice(&[0u8; 50 + 20]);
        let ascii = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n";
        for (name, bytes) in [("b.stl", binary), ("a.stl", ascii.as_bytes().to_vec())] {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            let e = read(&p).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!(
                    "{}: invalid STL: the file is truncated (",
                    p.display()
                )) && e.ends_with("); copy or export it again"),
                "{name}: {e}"
            );
        }
    }
}
