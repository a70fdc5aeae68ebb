//! Where the simplified stream goes. Streaming formats (SMB, SMA) are written directly; any other
//! format `smesh` supports is produced by writing SMB to a temporary file beside the target and
//! converting it at the end, so the stage itself stays streaming.

use std::path::{Path, PathBuf};

use isostream_simplify::OutBatch;
use isostream_smesh::{Format, Header, StreamWriter, WriteStats};

use crate::error::RunError;

#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct SinkStats {
    pub vertices: u64,
    pub triangles: u64,
    pub bytes: u64,
    /// Most vertices active (written, not yet finalized) at once: the stream width.
    pub max_active_vertices: u64,
    pub path: PathBuf,
}

pub(crate) struct Sink {
    writer: StreamWriter,
    attributes: usize,
    /// Final target when the stream is converted at the end.
    convert_to: Option<(tempfile::TempPath, PathBuf)>,
}

impl Sink {
    pub fn create(path: &Path, header: &Header) -> Result<Self, RunError> {
        let attributes = header.attribute_names.len();
        match Format::from_path(path)? {
            Format::Sma | Format::Smb => Ok(Self {
                writer: StreamWriter::create(path, header)?,
                attributes,
                convert_to: None,
            }),
            _ => {
                let dir = path
                    .parent()
                    .filter(|d| !d.as_os_str().is_empty())
                    .unwrap_or(Path::new("."));
                let tmp = tempfile::Builder::new()
                    .prefix(".isostream-")
                    .suffix(if attributes > 0 { ".sma" } else { ".smb" })
                    .tempfile_in(dir)
                    .map_err(|e| RunError::Summary {
                        path: path.to_path_buf(),
                        reason: format!("cannot create a temporary stream beside it: {e}"),
                    })?
                    .into_temp_path();
                let writer = StreamWriter::create(&tmp, header)?;
                Ok(Self {
                    writer,
                    attributes,
                    convert_to: Some((tmp, path.to_path_buf())),
                })
            }
        }
    }

    pub fn write(&mut self, batch: &OutBatch) -> Result<(), RunError> {
        crate::stages::write_elements(&mut self.writer, batch, self.attributes)?;
        Ok(())
    }

    pub fn finish(self) -> Result<SinkStats, RunError> {
        let WriteStats {
            vertices,
            triangles,
            bytes,
            max_active_vertices,
            ..
        } = self.writer.finish()?;
        let mut stats = SinkStats {
            vertices,
            triangles,
            bytes,
            max_active_vertices,
            path: PathBuf::new(),
        };
        match self.convert_to {
            None => {}
            Some((tmp, target)) => {
                isostream_smesh::convert(&tmp, &target)?;
                stats.bytes = std::fs::metadata(&target).map(|m| m.len()).unwrap_or(0);
                stats.path = target;
            }
        }
        Ok(stats)
    }
}
