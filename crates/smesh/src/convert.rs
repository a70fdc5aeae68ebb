//! Conversion between all supported formats through `MeshSink`s.
//!
//! Streaming inputs (SMA/SMB) are piped element by element into the output sink, so memory stays
//! bounded by the stream width whatever the output (PLY spills to scratch files, see `ply`).
//! Other inputs are loaded whole (they are not streams: PLY puts all faces after all vertices)
//! and re-emitted in compact pre-order.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::SinkState;

use crate::obj::ObjSink;
use crate::ply::{PlyEncoding, PlySink};
use crate::validate::CheckedStream;
use crate::{
    Element, Format, GlbSink, Header, MeshSink, SmeshError, StlSink, StreamWriter, WriteStats,
    read_indexed,
};

/// Choices that only some output formats have.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ConvertOptions {
    /// PLY body encoding (default binary little-endian).
    pub ply_encoding: PlyEncoding,
    /// GLB: also write area-weighted per-vertex normals (default off: viewers then shade flat,
    /// which shows the simplified triangles as they are).
    pub normals: bool,
}

/// What `convert` did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvertStats {
    pub input: Format,
    pub output: Format,
    pub written: WriteStats,
    /// Vertices of a non-streaming input that no triangle uses; they cannot be finalized in a
    /// stream and are not written.
    pub dropped_vertices: u64,
    /// Triangles of a non-streaming input that use a vertex twice (no area; an STL triangle
    /// with two equal corners reads as one): a streaming mesh cannot hold them, so they are
    /// not written.
    pub dropped_triangles: u64,
}

/// A sink writing `path` in the format its extension names.
pub fn create_sink(
    path: &Path,
    header: &Header,
    options: &ConvertOptions,
) -> Result<Box<dyn MeshSink>, SmeshError> {
    Ok(match Format::from_path(path)? {
        Format::Sma | Format::Smb => Box::new(StreamWriter::create(path, header)?),
        Format::Ply => Box::new(PlySink::create(path, header, options.ply_encoding)?),
        Format::Obj => Box::new(ObjSink::create(path, header)?),
        Format::Stl => Box::new(StlSink::create(path, header)?),
        Format::Glb => Box::new(GlbSink::create(path, header, options.normals)?),
    })
}

/// A sink continuing a checkpointed one (see [`MeshSink::checkpoint`]): its temporary files are
/// reopened and cut back to their checkpointed lengths, so it goes on writing the same bytes as
/// the sink that was checkpointed. `header` and `options` must be the ones it was created with.
pub fn resume_sink(
    path: &Path,
    header: &Header,
    options: &ConvertOptions,
    state: SinkState,
) -> Result<Box<dyn MeshSink>, SmeshError> {
    Ok(match Format::from_path(path)? {
        Format::Sma | Format::Smb => Box::new(StreamWriter::resume(path, header, state)?),
        Format::Ply => Box::new(PlySink::resume(path, header, options.ply_encoding, state)?),
        Format::Obj => Box::new(ObjSink::resume(path, header, state)?),
        Format::Stl => Box::new(StlSink::resume(path, header, state)?),
        Format::Glb => Box::new(GlbSink::resume(path, header, options.normals, state)?),
    })
}

/// Converts between SMA, SMB, PLY (binary little-endian), OBJ, STL and GLB, streaming when the
/// input is a streaming mesh; the output is written temp-then-rename.
pub fn convert(input: &Path, output: &Path) -> Result<ConvertStats, SmeshError> {
    convert_with(input, output, &ConvertOptions::default())
}

/// `convert` with format options.
pub fn convert_with(
    input: &Path,
    output: &Path,
    options: &ConvertOptions,
) -> Result<ConvertStats, SmeshError> {
    convert_until(input, output, options, &AtomicBool::new(false))
}

/// Elements converted between two looks at the stop flag.
const STOP_EVERY: u64 = 1 << 16;

/// `convert_with` that gives up once `stop` is raised (a signal handler's flag): the sink is
/// dropped unfinished, which removes its temporary file, and the answer is
/// [`SmeshError::Interrupted`]. Killed by the signal instead, a conversion left its temporary
/// file behind.
pub fn convert_until(
    input: &Path,
    output: &Path,
    options: &ConvertOptions,
    stop: &AtomicBool,
) -> Result<ConvertStats, SmeshError> {
    let stopped = || -> Result<(), SmeshError> {
        match stop.load(Ordering::Relaxed) {
            true => Err(SmeshError::Interrupted {
                path: output.to_path_buf(),
            }),
            false => Ok(()),
        }
    };
    let input_format = Format::from_path(input)?;
    let output_format = Format::from_path(output)?;
    let (written, dropped_vertices, dropped_triangles) = if input_format.is_streaming() {
        let mut stream = CheckedStream::open(input)?;
        let header = Header {
            comments: crate::sma::carried_comments(&stream.header().comments),
            attribute_names: stream.header().attribute_names.clone(),
        };
        let mut sink = create_sink(output, &header, options)?;
        let mut elements = 0u64;
        while let Some(e) = stream.next_element() {
            match e? {
                Element::Vertex { pos, attrs } => sink.vertex(pos, &attrs)?,
                Element::Triangle { v, finalized } => sink.triangle(v, finalized)?,
                Element::Finalize(v) => sink.finalize(v)?,
            }
            elements += 1;
            if elements.is_multiple_of(STOP_EVERY) {
                stopped()?;
            }
        }
        stream.finish()?;
        stopped()?;
        (sink.finish()?, 0, 0)
    } else {
        let mut mesh = read_indexed(input)?;
        stopped()?;
        let before = mesh.triangles.len();
        mesh.triangles
            .retain(|t| t[0] != t[1] && t[1] != t[2] && t[2] != t[0]);
        let degenerate = (before - mesh.triangles.len()) as u64;
        let header = Header {
            comments: mesh.comments.clone(),
            attribute_names: mesh.attribute_names.clone(),
        };
        let mut sink = create_sink(output, &header, options)?;
        let dropped = mesh.stream_into(sink.as_mut())?;
        stopped()?;
        (sink.finish()?, dropped, degenerate)
    };
    Ok(ConvertStats {
        input: input_format,
        output: output_format,
        written,
        dropped_vertices,
        dropped_triangles,
    })
}
