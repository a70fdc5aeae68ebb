//! `StreamWriter`: the pipeline's SMA/SMB output.

use std::path::Path;

use crate::atomic::AtomicFile;
use crate::sink::{Completed, MeshSink, Saved, SinkCore, SinkState};
use crate::sma::SmaEncoder;
use crate::smb::SmbEncoder;
use crate::{Format, Header, Place, SmeshError, StreamFault, Subject, WriteStats, index};

enum Encoder {
    Sma(SmaEncoder),
    Smb(SmbEncoder),
}

/// Streaming writer for SMA/SMB. Writes to a temporary file next to `path` and renames it on
/// `finish()`; dropping it unfinished deletes the temp file, so a half-written file never appears
/// under the final name.
///
/// Every call is checked against the streaming rules before anything is written, so a finished
/// file always passes `validate`. Memory is bounded by the stream width (active vertices).
pub struct StreamWriter {
    core: SinkCore,
    out: AtomicFile,
    encoder: Encoder,
}

impl StreamWriter {
    /// Creates the writer; the format comes from the extension (.sma or .smb). Fails with a
    /// message naming `path` if its directory is missing or not writable.
    pub fn create(path: &Path, header: &Header) -> Result<StreamWriter, SmeshError> {
        let format = Format::from_path(path)?;
        let core = SinkCore::new(path, header)?;
        let mut out = AtomicFile::create(path)?;
        let encoder = match format {
            Format::Sma => Encoder::Sma(SmaEncoder::begin(&mut out, header)?),
            Format::Smb => Encoder::Smb(SmbEncoder::begin(&mut out, header)?),
            other => {
                return Err(SmeshError::Unsupported {
                    path: path.to_path_buf(),
                    message: format!(
                        "StreamWriter writes SMA or SMB, not {other:?} (use convert or create_sink)"
                    ),
                });
            }
        };
        Ok(StreamWriter { core, out, encoder })
    }

    /// Continues a checkpointed writer (see [`MeshSink::checkpoint`]).
    pub(crate) fn resume(
        path: &Path,
        header: &Header,
        state: SinkState,
    ) -> Result<StreamWriter, SmeshError> {
        let format = Format::from_path(path)?;
        let fits = |f: &Saved| {
            matches!(
                (format, f),
                (Format::Sma, Saved::Sma) | (Format::Smb, Saved::Smb(_))
            )
        };
        let (core, out, saved) = state.reopen_one(path, header, fits, "SMA or SMB")?;
        let encoder = match saved {
            Saved::Smb(e) => Encoder::Smb(e),
            _ => Encoder::Sma(SmaEncoder),
        };
        Ok(StreamWriter { core, out, encoder })
    }

    /// Appends a vertex; vertices are numbered 0, 1, 2, ... in call order. SMB holds at most
    /// 2^31 - 1 vertices (i32 indices); SMA is text and writes larger indices as they are
    /// (readable by us, not by 32-bit reference readers). `attrs.len()` must equal
    /// `header.attribute_names.len()`. SMA writes them after x y z on the `v` line, SMB (version
    /// 1, see `smb`) as f32 after x y z in the vertex record.
    pub fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError> {
        let count = self.core.tracker.vertices();
        if count >= index::MAX_VERTICES && matches!(self.encoder, Encoder::Smb(_)) {
            return Err(self.core.fault(
                Subject::Vertex(count, Place::Written),
                StreamFault::TooManyVertices { count },
            ));
        }
        self.core.vertex(pos, attrs)?;
        match &mut self.encoder {
            Encoder::Sma(e) => e.vertex(&mut self.out, pos, attrs),
            Encoder::Smb(e) => e.vertex(&mut self.out, pos, attrs),
        }
    }

    /// Appends a triangle with 0-based absolute vertex indices; `last_use[i]` means this is the
    /// final use of `v[i]` (written as a negative relative index, which finalizes it). Error if an
    /// index was never written or was already finalized.
    pub fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        self.core.triangle(v, last_use)?;
        let available = self.core.tracker.vertices();
        let n = [0, 1, 2].map(|i| index::encode(v[i], last_use[i], available));
        match &mut self.encoder {
            Encoder::Sma(e) => e.triangle(&mut self.out, n),
            Encoder::Smb(e) => e.triangle(&mut self.out, n),
        }
    }

    /// Finalizes a vertex without a triangle: an SMA `x` line. SMB has no such element and
    /// returns an error (in SMB every vertex must be finalized by its last triangle).
    pub fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        let available = self.core.tracker.vertices();
        match &mut self.encoder {
            Encoder::Sma(e) => {
                self.core.finalize(v)?;
                e.finalize(&mut self.out, index::encode(v, true, available))
            }
            Encoder::Smb(_) => Err(self.core.fault(
                Subject::Finalization(Place::Written),
                StreamFault::SmbExplicitFinalize { vertex: v },
            )),
        }
    }

    /// Checks that every vertex was finalized, patches the header counts and bounding box in
    /// place (SMB: fixed offsets; SMA: reserved fixed-width comment lines at the top), flushes,
    /// fsyncs and renames to the final name.
    pub fn finish(self) -> Result<WriteStats, SmeshError> {
        self.complete()?.persist()
    }

    /// [`StreamWriter::finish`] but the rename (see [`Completed`]).
    fn complete(mut self) -> Result<Completed, SmeshError> {
        self.core.finish()?;
        match self.encoder {
            Encoder::Sma(e) => e.end(&mut self.out, &self.core.tracker)?,
            Encoder::Smb(e) => e.end(&mut self.out, &self.core.tracker)?,
        }
        let core = self.core;
        Completed::new(self.out, Vec::new(), |bytes| core.stats(bytes))
    }
}

impl MeshSink for StreamWriter {
    fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError> {
        StreamWriter::vertex(self, pos, attrs)
    }
    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        StreamWriter::triangle(self, v, last_use)
    }
    fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        StreamWriter::finalize(self, v)
    }
    fn complete(self: Box<Self>) -> Result<Completed, SmeshError> {
        StreamWriter::complete(*self)
    }
    fn checkpoint(&mut self) -> Result<SinkState, SmeshError> {
        let format = match &self.encoder {
            Encoder::Sma(_) => Saved::Sma,
            Encoder::Smb(e) => Saved::Smb(e.clone()),
        };
        SinkState::of_one(&mut self.out, &self.core, format)
    }
}
