//! Where the simplified stream goes: any format `smesh` writes (SMB, SMA, PLY, OBJ, STL, GLB),
//! all as streaming sinks that write to a temporary name and rename when finished.

use std::path::{Path, PathBuf};

use isostream_simplify::{OutBatch, OutElement};
use isostream_smesh::{
    Completed, ConvertOptions, Header, MeshSink, SinkState, SmeshError, WriteStats,
};

use crate::error::RunError;
use crate::mirror::Mirror;

#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct SinkStats {
    pub vertices: u64,
    pub triangles: u64,
    pub bytes: u64,
    /// Most vertices active (written, not yet finalized) at once: the stream width.
    pub max_active_vertices: u64,
    pub path: PathBuf,
}

pub(crate) struct Sink {
    inner: Box<dyn MeshSink>,
    attributes: usize,
    path: PathBuf,
    triangles: u64,
    /// The input's axis flips, undone on every position and triangle written.
    mirror: Mirror,
}

impl Sink {
    pub fn create(path: &Path, header: &Header, mirror: Mirror) -> Result<Self, RunError> {
        Ok(Self {
            inner: isostream_smesh::create_sink(path, header, &ConvertOptions::default())?,
            attributes: header.attribute_names.len(),
            path: path.to_path_buf(),
            triangles: 0,
            mirror,
        })
    }

    /// Continues the sink the checkpoint `checkpoint` saved (its temporary files cut back to the
    /// saved lengths).
    pub fn resume(
        path: &Path,
        header: &Header,
        mirror: Mirror,
        state: SinkState,
        checkpoint: &Path,
    ) -> Result<Self, RunError> {
        let triangles = state.triangles();
        let inner = isostream_smesh::resume_sink(path, header, &ConvertOptions::default(), state)
            .map_err(|e| match &e {
            // Files gone or shorter than the checkpoint says (removed by hand, a tmp
            // cleaner): it cannot be resumed, as a corrupt one cannot (`--restart`, exit
            // 2). Any other failure to reopen them (permissions, a failing disk) is the
            // run's: the files may be fine once that is fixed.
            SmeshError::Io { source, .. } if unusable(source) => RunError::Checkpoint {
                path: checkpoint.to_path_buf(),
                reason: e.to_string(),
            },
            _ => e.into(),
        })?;
        Ok(Self {
            inner,
            attributes: header.attribute_names.len(),
            path: path.to_path_buf(),
            triangles,
            mirror,
        })
    }

    /// Flushes and fsyncs the output's files for a checkpoint; returns where the sink stands.
    pub fn checkpoint(&mut self) -> Result<SinkState, RunError> {
        Ok(self.inner.checkpoint()?)
    }

    /// Triangles written so far.
    pub fn triangles(&self) -> u64 {
        self.triangles
    }

    pub fn write(&mut self, batch: &OutBatch) -> Result<(), RunError> {
        let mut attrs = batch.attrs.chunks(self.attributes.max(1));
        for e in &batch.elements {
            match e {
                OutElement::Vertex { pos } => {
                    let a = match self.attributes {
                        0 => &[][..],
                        _ => attrs.next().unwrap_or(&[]),
                    };
                    // Negating an f64 and rounding it is rounding and negating: the f32 the
                    // simplifier placed, mirrored exactly.
                    let p = self.mirror.position(pos.to_array()).map(|x| x as f32);
                    self.inner.vertex(p, a)?;
                }
                OutElement::Triangle { v, last_use } => {
                    self.inner
                        .triangle(self.mirror.corners(*v), self.mirror.corners(*last_use))?;
                    self.triangles += 1;
                }
            }
        }
        Ok(())
    }

    /// The output complete under its temporary name (the run renames it: see `run_job`).
    pub fn complete(self) -> Result<(SinkStats, Completed), RunError> {
        let completed = self.inner.complete()?;
        let WriteStats {
            vertices,
            triangles,
            bytes,
            max_active_vertices,
            ..
        } = completed.stats();
        let stats = SinkStats {
            vertices,
            triangles,
            bytes,
            max_active_vertices,
            path: self.path,
        };
        Ok((stats, completed))
    }
}

/// Whether an error on a checkpoint's file ([`isostream_smesh::FileMark::check`]) means that it
/// is gone or shorter than recorded: a checkpoint that cannot be resumed.
pub(crate) fn unusable(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::NotFound | std::io::ErrorKind::UnexpectedEof
    )
}
