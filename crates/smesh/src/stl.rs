//! Binary STL: an 80-byte header, a u32 triangle count, then per triangle a unit normal, three
//! corner positions (f32) and a u16 attribute byte count of 0.
//!
//! STL stores positions per triangle, so the sink needs the positions of active vertices only:
//! the tracker keeps them until finalization, memory stays bounded by the stream width. The count
//! is patched in place on finish. Reading goes through `stl_io` (ascii or binary), which welds
//! identical corners back into shared vertices; which of the two a file is, we decide
//! ([`is_ascii`]), since `stl_io` takes a file for ASCII exactly when it starts with `solid `.

use std::fs::File;
use std::io::{self, BufRead, BufReader, Read, Seek, SeekFrom};
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
        // The loss is stated before the comments, which the 80 bytes may leave out.
        if !header.attribute_names.is_empty() {
            text.push_str("; ");
            text.push_str(&dropped_note(&header.attribute_names, 80 - text.len()));
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

/// The header part naming the dropped attributes `names` in at most `room` bytes: the whole
/// names that fit, then how many more there were (cut at 80 bytes, a name came out cut short,
/// read as another name, and the rest unsaid).
fn dropped_note(names: &[String], room: usize) -> String {
    let n = names.len();
    (1..=n)
        .rev()
        .map(|k| match n - k {
            0 => format!("{ATTRIBUTES_DROPPED}{}", names.join(" ")),
            more => format!("{ATTRIBUTES_DROPPED}{} +{more} more", names[..k].join(" ")),
        })
        .find(|note| note.len() <= room)
        .unwrap_or_else(|| format!("{ATTRIBUTES_DROPPED}{n} (too long to name)"))
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
    let read_error = |e| SmeshError::io(path, "read", e);
    let size = input.get_ref().metadata().map_err(read_error)?.len();
    // Up to 84 bytes: an ASCII STL may be shorter (`solid t\nendsolid t\n`).
    let mut head = Vec::with_capacity(84);
    (&mut input)
        .take(84)
        .read_to_end(&mut head)
        .map_err(read_error)?;
    // stl_io is shown the file with its start replaced so that it reads it as we decided: a
    // first line of exactly `solid ` for ASCII (it refused a bare `solid`), a first line that is
    // not for binary (a binary header may start with `solid`).
    input.seek(SeekFrom::Start(0)).map_err(read_error)?;
    let (start, skip) = match is_ascii(&head, size) {
        true => (
            b"solid \n".to_vec(),
            input.skip_until(b'\n').map_err(read_error)?,
        ),
        false => (b"\n".repeat(80), 80),
    };
    // A file cut short failed with stl_io's bare "failed to fill whole buffer", which said
    // neither what was wrong with the file nor what to do.
    let stl = stl_io::read_stl(&mut Spliced::new(start, skip as u64, input)).map_err(|e| {
        let message = match e.kind() {
            io::ErrorKind::UnexpectedEof => {
                format!("invalid STL: the file is truncated ({e}); copy or export it again")
            }
            _ => format!("invalid STL: {e}"),
        };
        SmeshError::foreign(path, message)
    })?;
    let mut mesh = IndexedMesh {
        positions: stl.vertices.iter().map(|v| v.0.map(f64::from)).collect(),
        comments: comments(&head[..head.len().min(80)]),
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

/// Whether an STL file of `size` bytes starting with `head` (its first 84 bytes, fewer in a
/// shorter file) is ASCII: its first line is `solid`, with or without a name (the name is
/// optional; meshio writes a bare `solid`), unless the size is exactly that of a binary STL
/// with the triangle count at byte 80 (84 + 50 per triangle): binary headers are free bytes,
/// and some writers start them with `solid` too. An ASCII file has text at byte 80, which as a
/// count asks for gigabytes to the byte: a real one meets that size only by coincidence.
fn is_ascii(head: &[u8], size: u64) -> bool {
    if let Some(count) = head.get(80..84) {
        let count = u32::from_le_bytes([count[0], count[1], count[2], count[3]]);
        if size == 84 + 50 * u64::from(count) {
            return false;
        }
    }
    let line = head.split(|&b| b == b'\n').next().unwrap_or_default();
    line.split(u8::is_ascii_whitespace)
        .find(|w| !w.is_empty())
        .is_some_and(|w| w == b"solid")
}

/// A file seen with its first `skip` bytes replaced by `start`; seeks go from the start only,
/// as stl_io's (it rewinds after probing the first line).
struct Spliced<R> {
    start: Vec<u8>,
    skip: u64,
    rest: R,
    pos: u64,
}

impl<R: Seek> Spliced<R> {
    fn new(start: Vec<u8>, skip: u64, rest: R) -> Spliced<R> {
        Spliced {
            start,
            skip,
            rest,
            pos: 0,
        }
    }
}

impl<R: Read + Seek> Read for Spliced<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let from_start = self.start.get(self.pos as usize..).unwrap_or_default();
        if from_start.is_empty() {
            let n = self.rest.read(buf)?;
            self.pos += n as u64;
            return Ok(n);
        }
        let n = from_start.len().min(buf.len());
        buf[..n].copy_from_slice(&from_start[..n]);
        self.pos += n as u64;
        if self.pos == self.start.len() as u64 {
            self.rest.seek(SeekFrom::Start(self.skip))?;
        }
        Ok(n)
    }
}

impl<R: Read + Seek> Seek for Spliced<R> {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let SeekFrom::Start(pos) = to else {
            return Err(io::Error::new(
                io::ErrorKind::Unsupported,
                "an STL input is only read from its start",
            ));
        };
        let start = self.start.len() as u64;
        if pos >= start {
            self.rest.seek(SeekFrom::Start(self.skip + pos - start))?;
        }
        self.pos = pos;
        Ok(pos)
    }
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
        .filter(|c| !c.starts_with(ATTRIBUTES_DROPPED))
        .filter_map(crate::sma::carried_comment)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dropped attributes whose names overflow the 80-byte header are named whole as far as
    /// they fit, then counted (the note was cut mid-name, `pressure_pascal`), and a comment
    /// still fits after it.
    #[test]
    fn the_dropped_attributes_note_names_whole_names_and_counts_the_rest() {
        let dir = tempfile::tempdir().unwrap();
        let names = [
            "temperature_celsius",
            "pressure_pascals_abs",
            "velocity_magnitude",
            "density_kg_m3",
        ];
        let header = |names: &[&str]| Header {
            comments: vec!["iso 1".into()],
            attribute_names: names.iter().map(|n| n.to_string()).collect(),
        };
        let long = "a".repeat(60);
        let cases: [(&[&str], &str, &[&str]); 3] = [
            (&names, "temperature_celsius +3 more; iso 1", &["iso 1"]),
            (&names[2..], "velocity_magnitude density_kg_m3", &[]),
            (&[long.as_str()], "1 (too long to name); iso 1", &["iso 1"]),
        ];
        for (names, note, kept) in cases {
            let p = dir.path().join(format!("t{}.stl", names.len()));
            let sink = Box::new(StlSink::create(&p, &header(names)).unwrap());
            let done = sink.complete().unwrap();
            let head = std::fs::read(done.temp_path()).unwrap()[..80].to_vec();
            let text = String::from_utf8(head.clone()).unwrap();
            assert_eq!(
                text.trim_end(),
                format!("{SIGNATURE}; {ATTRIBUTES_DROPPED}{note}")
            );
            assert_eq!(comments(&head), kept);
        }
    }

    /// An ASCII STL whose first line is a bare `solid` (meshio's), with `\n` or `\r\n`, reads:
    /// stl_io wants `solid ` and took it for binary, "truncated".
    #[test]
    fn an_ascii_stl_without_a_name_reads() {
        let dir = tempfile::tempdir().unwrap();
        let facet = " facet normal 0 0 0\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   \
                     vertex 0 1 0\n  endloop\n endfacet\nendsolid\n";
        for (name, first) in [("n.stl", "solid\n"), ("r.stl", "solid\r\n")] {
            let p = dir.path().join(name);
            std::fs::write(&p, format!("{first}{facet}")).unwrap();
            let m = read(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(m.positions, [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
            assert_eq!(m.triangles, [[0, 1, 2]]);
        }
    }

    /// A binary STL whose free header starts with `solid ` reads as binary: its size is
    /// exactly 84 + 50 per triangle (stl_io read it as ASCII and failed).
    #[test]
    fn a_binary_stl_whose_header_starts_with_solid_reads() {
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = b"solid exported by some CAD tool\n".to_vec();
        bytes.resize(80, b' ');
        bytes.extend_from_slice(&1u32.to_le_bytes());
        let corners = [0f32, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        bytes.extend(corners.iter().flat_map(|c| c.to_le_bytes()));
        bytes.extend_from_slice(&[0, 0]);
        let p = dir.path().join("b.stl");
        std::fs::write(&p, bytes).unwrap();
        let m = read(&p).unwrap();
        assert_eq!(m.positions, [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        assert_eq!(m.triangles, [[0, 1, 2]]);
        assert!(m.comments.is_empty());
    }

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
