//! Streaming mesh formats for isostream.
//!
//! A *streaming mesh* (Isenburg and Lindstrom 2005) interleaves vertices and triangles and says
//! when a vertex is used for the last time (*finalized*), so writers and readers need memory only
//! for the active vertices, not for the whole mesh. This crate has:
//!
//! - `StreamWriter` / `StreamReader`: SMA (ASCII) and SMB (binary), see `sma` and `smb` for the
//!   layouts, with per-vertex attributes as our superset of both (an SMA header line, an SMB
//!   version-1 name table);
//! - `validate`: the streaming rules checked on a file, plus stream width and skip;
//! - `MeshSink`: one writing interface for every output format (SMA, SMB, PLY, OBJ, STL, GLB), each written
//!   to a temporary file and renamed when complete;
//! - `convert` and `read_indexed` for moving between formats and loading small meshes.
//!
//! FORMATS.md (next to this crate's Cargo.toml) records the layouts we write and our SMA and SMB
//! supersets.
#![deny(unsafe_code)]

mod atomic;
mod convert;
mod error;
mod format;
mod glb;
mod index;
mod indexed;
mod input;
mod obj;
mod ply;
mod reader;
mod sink;
mod sma;
mod smb;
mod stl;
mod track;
mod validate;
mod writer;

pub use atomic::FileMark;
pub use atomic::{check_replaceable, output_builder, put_in_place};
pub use convert::{
    ConvertOptions, ConvertStats, convert, convert_until, convert_with, create_sink, resume_sink,
};
pub use error::{Place, SmeshError, StreamFault, Subject};
pub use format::Format;
pub use glb::GlbSink;
pub use indexed::{IndexedMesh, read_indexed};
pub use obj::ObjSink;
pub use ply::{PlyEncoding, PlySink};
pub use reader::{Element, ReadHeader, StreamReader};
pub use sink::{Completed, Header, MeshSink, SinkState, WriteStats, printable_ascii};
pub use stl::StlSink;
pub use validate::{ValidationReport, validate};
pub use writer::StreamWriter;
