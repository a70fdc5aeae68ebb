//! What every mesh writer shares: the element calls of a streaming mesh (so the pipeline and
//! `convert` can write any format the same way) and the checks behind them.

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use crate::atomic::{AtomicFile, FileMark, Spill};
use crate::track::Tracker;
use crate::{Place, SmeshError, StreamFault, Subject};

/// Metadata written at the top of an output file.
#[derive(Debug, Clone, Default)]
pub struct Header {
    /// Free text, one line each (no line breaks).
    pub comments: Vec<String>,
    /// Names of the per-vertex attributes passed to `vertex`: unique, not x/y/z, no whitespace.
    pub attribute_names: Vec<String>,
}

/// `text` with every character outside printable ASCII written as its Rust escape (`é` as
/// `\u{e9}`, a line break as `\u{a}`), for header comments: a PLY header is ASCII (readers such
/// as python's plyfile refused an `é`), every format holds a comment of one line only (a run's
/// input path with a line break failed it when the output was made), and a NUL in an OBJ makes
/// it binary to our reader. The comment naming a run's input and those `convert` carries from
/// another tool's file (`sma::carried_comment`) go through it. Printable ASCII is kept as
/// written, so a comment escaped once is escaped again to itself.
pub fn printable_ascii(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            ' '..='~' => c.to_string(),
            _ => c.escape_unicode().to_string(),
        })
        .collect()
}

/// What a finished writer wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteStats {
    pub vertices: u64,
    pub triangles: u64,
    /// Size of the final file.
    pub bytes: u64,
    /// Stream width: the most vertices written but not yet finalized at any time.
    pub max_active_vertices: u64,
}

/// A destination for a streaming mesh: vertices numbered 0, 1, 2, ... in call order, triangles
/// referring to them by absolute index and saying which use is a vertex's last.
///
/// Every implementation checks the streaming rules (index written, not yet finalized, all
/// finalized at the end) and writes temp-then-rename, so an invalid or unfinished output never
/// appears under its final name.
pub trait MeshSink: Send {
    fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError>;
    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError>;
    /// Finalizes a vertex without a triangle (an SMA `x` line; an isolated vertex).
    fn finalize(&mut self, v: u64) -> Result<(), SmeshError>;
    /// Checks the end of the stream, writes what is left (header counts, the parts kept in
    /// scratch files) and fsyncs the output, still under its temporary name.
    fn complete(self: Box<Self>) -> Result<Completed, SmeshError>;
    /// [`MeshSink::complete`], then [`Completed::persist`]: the output under its final name.
    fn finish(self: Box<Self>) -> Result<WriteStats, SmeshError> {
        self.complete()?.persist()
    }
    /// Flushes and fsyncs every file of the sink and returns where it stands, for a checkpoint:
    /// [`crate::resume_sink`] continues from there after a crash, writing the same bytes. From
    /// the first checkpoint on, a failed or killed run leaves its temporary files in place (the
    /// checkpoint needs them); a finished run removes them.
    fn checkpoint(&mut self) -> Result<SinkState, SmeshError>;
}

/// An output complete under its temporary name (written, flushed and fsynced) that has not been
/// given its final name yet. The pipeline records between the two steps that its run is done, so
/// that a kill right after the rename leaves a state `--resume` finishes without computing
/// anything again. Dropped, it removes its files as an unfinished sink does (none that a
/// checkpoint refers to).
pub struct Completed {
    out: AtomicFile,
    /// The scratch files the output was assembled from (PLY, GLB), removed once it is in place.
    scratch: Vec<Spill>,
    stats: WriteStats,
}

impl Completed {
    /// Completes `out` (flush, fsync); `stats` gets its size.
    pub(crate) fn new(
        mut out: AtomicFile,
        scratch: Vec<Spill>,
        stats: impl FnOnce(u64) -> WriteStats,
    ) -> Result<Completed, SmeshError> {
        let bytes = out.complete()?;
        Ok(Completed {
            out,
            scratch,
            stats: stats(bytes),
        })
    }

    pub fn stats(&self) -> WriteStats {
        self.stats
    }

    /// The temporary name the complete output is under.
    pub fn temp_path(&self) -> &Path {
        self.out.temp_path()
    }

    /// The scratch files [`Completed::persist`] removes.
    pub fn scratch_paths(&self) -> Vec<PathBuf> {
        self.scratch
            .iter()
            .map(|s| s.path().to_path_buf())
            .collect()
    }

    /// Keeps the complete output's temporary file on disk whatever happens next: a record of
    /// the finished run is about to name it, and a rename that then failed removed it, leaving
    /// the record pointing at nothing (`--resume` said to `--restart`, the whole job again).
    pub fn keep(&mut self) -> Result<(), SmeshError> {
        self.out.keep()
    }

    /// Renames the output to its final name (durably), then removes its scratch files.
    pub fn persist(self) -> Result<WriteStats, SmeshError> {
        self.out.persist()?;
        self.scratch.into_iter().for_each(Spill::discard);
        Ok(self.stats)
    }
}

/// Where a sink stood at a checkpoint: its files (temporary output, scratch files) with the
/// lengths that count, the streaming-rule bookkeeping, and what the format keeps in memory
/// (SMB's partial block, GLB's pending normals). Serializable; no path in it is final.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SinkState {
    pub(crate) files: Vec<FileMark>,
    pub(crate) tracker: Tracker,
    pub(crate) format: Saved,
}

/// The format-specific part of a [`SinkState`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) enum Saved {
    Sma,
    Smb(crate::smb::SmbEncoder),
    Ply,
    Obj,
    Stl,
    Glb(Option<crate::glb::Normals>),
}

impl SinkState {
    /// The temporary files the state refers to (they must survive until the run completes).
    pub fn files(&self) -> impl Iterator<Item = &Path> {
        self.files.iter().map(|f| f.path.as_path())
    }

    /// Whether those files are all still there with the bytes that count ([`FileMark::check`]).
    pub fn check_files(&self) -> io::Result<()> {
        self.files.iter().try_for_each(FileMark::check)
    }

    /// Triangles written when the checkpoint was taken.
    pub fn triangles(&self) -> u64 {
        self.tracker.triangles()
    }

    /// The state of a sink that writes its output and nothing else.
    pub(crate) fn of_one(
        out: &mut AtomicFile,
        core: &SinkCore,
        format: Saved,
    ) -> Result<SinkState, SmeshError> {
        Ok(SinkState {
            files: vec![out.mark()?],
            tracker: core.tracker.clone(),
            format,
        })
    }

    /// The core and the reopened output of a sink that writes its output and nothing else, and
    /// its format's part; `fits` says whether that part is the sink's (`name` when not).
    pub(crate) fn reopen_one(
        self,
        path: &Path,
        header: &Header,
        fits: impl Fn(&Saved) -> bool,
        name: &str,
    ) -> Result<(SinkCore, AtomicFile, Saved), SmeshError> {
        let [mark] = self.marks::<1>(path)?;
        if !fits(&self.format) {
            return Err(mismatch(path, name));
        }
        let out = AtomicFile::reopen(path, mark)?;
        let core = SinkCore::resume(path, header, self.tracker)?;
        Ok((core, out, self.format))
    }

    /// The files in order, when there are `n` of them (else the state is not this format's).
    pub(crate) fn marks<const N: usize>(&self, path: &Path) -> Result<&[FileMark; N], SmeshError> {
        <&[FileMark; N]>::try_from(self.files.as_slice())
            .map_err(|_| mismatch(path, "its number of files"))
    }
}

/// A checkpointed state that does not belong to this output's format.
pub(crate) fn mismatch(path: &Path, what: &str) -> SmeshError {
    SmeshError::Unsupported {
        path: path.to_path_buf(),
        message: format!("the checkpointed writer state does not fit this output format ({what})"),
    }
}

/// The rule checking and bookkeeping embedded in every sink.
#[derive(Debug)]
pub(crate) struct SinkCore {
    pub(crate) path: PathBuf,
    pub(crate) tracker: Tracker,
    attributes: usize,
}

impl SinkCore {
    pub(crate) fn new(path: &Path, header: &Header) -> Result<SinkCore, SmeshError> {
        let unsupported = |message: String| SmeshError::Unsupported {
            path: path.to_path_buf(),
            message,
        };
        if let Some(c) = header.comments.iter().find(|c| c.contains(['\n', '\r'])) {
            return Err(unsupported(format!(
                "header comment {c:?} contains a line break; comments are one line each"
            )));
        }
        if let Some(n) = header
            .attribute_names
            .iter()
            .find(|n| n.is_empty() || n.contains(char::is_whitespace))
        {
            return Err(unsupported(format!(
                "attribute name {n:?} must be non-empty without whitespace"
            )));
        }
        let names = &header.attribute_names;
        if let Some((i, n)) = names
            .iter()
            .enumerate()
            .find(|(i, n)| ["x", "y", "z"].contains(&n.as_str()) || names[..*i].contains(n))
        {
            return Err(unsupported(format!(
                "attribute name {n:?} (number {i}) repeats a coordinate or an earlier attribute"
            )));
        }
        Ok(SinkCore {
            path: path.to_path_buf(),
            tracker: Tracker::default(),
            attributes: header.attribute_names.len(),
        })
    }

    /// A core continuing from a checkpoint's bookkeeping.
    pub(crate) fn resume(
        path: &Path,
        header: &Header,
        tracker: Tracker,
    ) -> Result<SinkCore, SmeshError> {
        Ok(SinkCore {
            tracker,
            ..SinkCore::new(path, header)?
        })
    }

    /// Checks and registers a vertex; returns its index.
    pub(crate) fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<u64, SmeshError> {
        if attrs.len() != self.attributes {
            return Err(self.fault(
                Subject::Vertex(self.tracker.vertices(), Place::Written),
                StreamFault::AttributeCount {
                    expected: self.attributes,
                    found: attrs.len(),
                },
            ));
        }
        Ok(self.tracker.vertex(pos))
    }

    /// Checks and registers a triangle; returns its corner positions.
    pub(crate) fn triangle(
        &mut self,
        v: [u64; 3],
        last_use: [bool; 3],
    ) -> Result<[[f32; 3]; 3], SmeshError> {
        let subject = Subject::Triangle(self.tracker.triangles(), Place::Written);
        self.tracker
            .triangle(v, last_use)
            .map_err(|f| self.fault(subject, f))
    }

    /// `triangle` for formats with u32 indices (PLY, GLB); returns the indices and corners.
    pub(crate) fn triangle_u32(
        &mut self,
        v: [u64; 3],
        last_use: [bool; 3],
        format: &str,
    ) -> Result<([u32; 3], [[f32; 3]; 3]), SmeshError> {
        let corners = self.triangle(v, last_use)?;
        match v.map(u32::try_from) {
            [Ok(a), Ok(b), Ok(c)] => Ok(([a, b, c], corners)),
            _ => Err(SmeshError::Unsupported {
                path: self.path.clone(),
                message: format!("triangle {v:?} needs indices beyond the 32 bits {format} has"),
            }),
        }
    }

    /// `vertex` plus its little-endian f32 record (x y z attributes) appended to a scratch file:
    /// the vertex layout PLY and GLB share.
    pub(crate) fn spill_vertex(
        &mut self,
        spill: &mut impl Write,
        pos: [f32; 3],
        attrs: &[f32],
    ) -> Result<(), SmeshError> {
        self.vertex(pos, attrs)?;
        let res = pos
            .iter()
            .chain(attrs)
            .try_for_each(|x| spill.write_all(&x.to_le_bytes()));
        res.map_err(|e| self.scratch_error(e))
    }

    pub(crate) fn scratch_error(&self, e: io::Error) -> SmeshError {
        SmeshError::io(&self.path, "write its scratch data", e)
    }

    pub(crate) fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        self.tracker
            .finalize(v)
            .map_err(|f| self.fault(Subject::Finalization(Place::Written), f))
    }

    /// End-of-stream check: every vertex finalized.
    pub(crate) fn finish(&self) -> Result<(), SmeshError> {
        self.tracker
            .finish()
            .map_err(|f| self.fault(Subject::EndOfStream, f))
    }

    pub(crate) fn fault(&self, subject: Subject, fault: StreamFault) -> SmeshError {
        SmeshError::stream(&self.path, subject, fault)
    }

    pub(crate) fn stats(&self, bytes: u64) -> WriteStats {
        WriteStats {
            vertices: self.tracker.vertices(),
            triangles: self.tracker.triangles(),
            bytes,
            max_active_vertices: self.tracker.max_active(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What is not printable ASCII (an input path's, a foreign comment's) is escaped; the rest,
    /// and so a comment escaped before, is kept as written.
    #[test]
    fn comments_are_escaped_to_printable_ascii() {
        let escaped = printable_ascii("/tmp/dir é ü/e\tng\nine.vti~");
        assert_eq!(escaped, "/tmp/dir \\u{e9} \\u{fc}/e\\u{9}ng\\u{a}ine.vti~");
        assert_eq!(printable_ascii(&escaped), escaped);
    }
}
