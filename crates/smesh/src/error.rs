//! One error type for the crate. Every message is a single line that starts with the file it is
//! about, then says where in the file and what was expected, so a CLI can print it as is.

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};

/// Where in a file an element was found: SMB readers know byte offsets, SMA readers line numbers,
/// writers only the call (the element count already says which one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Place {
    Byte(u64),
    Line(u64),
    Written,
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Place::Byte(b) => write!(f, " at byte {b}"),
            Place::Line(l) => write!(f, " on line {l}"),
            Place::Written => Ok(()),
        }
    }
}

/// Which element of a stream an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Subject {
    /// 0-based triangle number.
    Triangle(u64, Place),
    /// An explicit SMA `x` finalization line.
    Finalization(Place),
    /// A 0-based vertex number.
    Vertex(u64, Place),
    /// The checks that can only run once the whole stream was seen.
    EndOfStream,
}

impl fmt::Display for Subject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Subject::Triangle(t, p) => write!(f, "triangle {t}{p}"),
            Subject::Finalization(p) => write!(f, "finalization{p}"),
            Subject::Vertex(v, p) => write!(f, "vertex {v}{p}"),
            Subject::EndOfStream => f.write_str("at end of stream,"),
        }
    }
}

/// A violation of the streaming-mesh rules, independent of the file it was found in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StreamFault {
    #[error(
        "references vertex {vertex} (counting from 0) but only {available} vertices precede it"
    )]
    Forward { vertex: u64, available: u64 },
    #[error("uses relative index {index} but only {available} vertices precede it")]
    BeforeFirst { index: i64, available: u64 },
    #[error("uses vertex {vertex}, which was already finalized")]
    UseAfterFinalize { vertex: u64 },
    #[error("uses vertex {vertex} twice: a triangle needs three distinct vertices")]
    RepeatedVertex { vertex: u64 },
    #[error(
        "the header's bounding box {declared} does not contain the vertices, which span {found}"
    )]
    BoundingBox { declared: String, found: String },
    #[error("vertex {vertex} was never finalized ({others} other vertices neither)")]
    NeverFinalized { vertex: u64, others: u64 },
    #[error("the header declares {declared} {what} but the stream holds {found}{}", if found < declared { " (truncated file?)" } else { "" })]
    CountMismatch {
        what: &'static str,
        declared: u64,
        found: u64,
    },
    #[error("exceeds the {declared} {what} the header declares")]
    BeyondDeclared { what: &'static str, declared: u64 },
    /// NaN or infinite position (the coordinates as written, since f32 is not `Eq`).
    #[error("has a non-finite coordinate ({coords}); the mesh is corrupt")]
    NonFinite { coords: String },
    #[error("has {found} attribute values but the header names {expected} attributes")]
    AttributeCount { expected: usize, found: usize },
    #[error(
        "would be vertex number {count} but SMB indices are 32-bit signed (at most 2147483647 vertices per file; SMA has no such limit)"
    )]
    TooManyVertices { count: u64 },
    #[error(
        "of vertex {vertex} cannot be stored in SMB, which only finalizes a vertex on its last triangle"
    )]
    SmbExplicitFinalize { vertex: u64 },
}

/// Every error of this crate; its message is one line starting with the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum SmeshError {
    #[error("{}: cannot {what}: {source}", path.display())]
    Io {
        path: PathBuf,
        what: String,
        source: io::Error,
    },
    #[error("{}: unknown mesh format: expected extension .sma, .smb, .ply, .obj, .stl or .glb", path.display())]
    UnknownFormat { path: PathBuf },
    #[error("{}: {subject} {fault}", path.display())]
    Stream {
        path: PathBuf,
        subject: Subject,
        fault: StreamFault,
    },
    #[error("{}: {place}: expected {expected}, found {found}", path.display(), place = DisplayPlace(*place))]
    Syntax {
        path: PathBuf,
        place: Place,
        expected: String,
        found: String,
    },
    #[error("{}: file ends{place} in the middle of {expected}", path.display())]
    Truncated {
        path: PathBuf,
        place: Place,
        expected: String,
    },
    #[error("{}: truncated at byte {at} of {of}: {detail}; the file is incomplete (an interrupted write or copy?)", path.display())]
    TruncatedAt {
        path: PathBuf,
        at: u64,
        of: u64,
        detail: String,
    },
    #[error("{}: not an SMB file: first bytes are {found:02x?}, expected version 0 or 1, endianness 0 or 1, then two zero bytes", path.display())]
    BadMagic { path: PathBuf, found: Vec<u8> },
    #[error("{}: {message}", path.display())]
    Unsupported { path: PathBuf, message: String },
    #[error("{}: {message}", path.display())]
    Foreign { path: PathBuf, message: String },
    /// The caller's stop flag was raised (Ctrl-C): the output was not written.
    #[error("{}: interrupted: no output was written (the partial file was removed)", path.display())]
    Interrupted { path: PathBuf },
    /// An output path naming something the final rename would replace with a regular file (a
    /// device, a FIFO, a socket, a folder), or a chain of links that never ends.
    #[error("{}: {what}", path.display())]
    NotAFile { path: PathBuf, what: String },
}

/// A full disk or a file-size limit gets the fix in its message (and loses the temporary file's
/// name that `tempfile` appends: that file is removed by the time anyone reads the message).
fn with_fix(e: io::Error) -> io::Error {
    match e.kind() {
        io::ErrorKind::StorageFull | io::ErrorKind::FileTooLarge | io::ErrorKind::QuotaExceeded => {
            let base = match e.kind() {
                io::ErrorKind::StorageFull => "No space left on device",
                io::ErrorKind::FileTooLarge => "File too large",
                _ => "Disk quota exceeded",
            };
            io::Error::new(
                e.kind(),
                format!("{base}; free space on that disk or choose another output folder"),
            )
        }
        _ => e,
    }
}

/// `Place` without its leading " at"/" on" for the syntax message, which reads "line 7: ...".
struct DisplayPlace(Place);

impl fmt::Display for DisplayPlace {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Place::Byte(b) => write!(f, "byte {b}"),
            Place::Line(l) => write!(f, "line {l}"),
            Place::Written => f.write_str("written element"),
        }
    }
}

impl SmeshError {
    pub(crate) fn io(path: &Path, what: impl Into<String>, source: io::Error) -> Self {
        SmeshError::Io {
            path: path.to_path_buf(),
            what: what.into(),
            source: with_fix(source),
        }
    }

    pub(crate) fn stream(path: &Path, subject: Subject, fault: StreamFault) -> Self {
        SmeshError::Stream {
            path: path.to_path_buf(),
            subject,
            fault,
        }
    }

    pub(crate) fn syntax(
        path: &Path,
        place: Place,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        SmeshError::Syntax {
            path: path.to_path_buf(),
            place,
            expected: expected.into(),
            found: found.into(),
        }
    }

    /// Messages of foreign parsers may span lines; keep ours to one.
    pub(crate) fn foreign(path: &Path, message: impl fmt::Display) -> Self {
        let message = message.to_string();
        let message = message.split_whitespace().collect::<Vec<_>>().join(" ");
        SmeshError::Foreign {
            path: path.to_path_buf(),
            message,
        }
    }
}
