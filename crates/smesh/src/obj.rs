//! Wavefront OBJ: reading (by hand, see [`read`]); writing as a stream sink.
//!
//! OBJ lets `v` and `f` lines interleave as long as a face follows its vertices, so a stream
//! maps straight onto it: no spill, no second pass. OBJ has no per-vertex attributes; the sink
//! drops them (their names go into a comment so the loss is visible).

use std::path::Path;

use crate::atomic::AtomicFile;
use crate::sink::{Completed, MeshSink, Saved, SinkCore, SinkState};
use crate::{Header, IndexedMesh, SmeshError};

/// The header comment saying which attributes were not written: a fact about this file, not a
/// comment to carry on, so the reader leaves it out.
const ATTRIBUTES_NOT_STORED: &str = "per-vertex attributes not stored (OBJ has none):";

/// Streaming OBJ writer.
pub struct ObjSink {
    core: SinkCore,
    out: AtomicFile,
}

impl ObjSink {
    /// Starts writing `path` (via a temporary file beside it); fails naming `path` if its
    /// directory is missing or not writable.
    pub fn create(path: &Path, header: &Header) -> Result<ObjSink, SmeshError> {
        let core = SinkCore::new(path, header)?;
        let mut out = AtomicFile::create(path)?;
        let mut text: String = header.comments.iter().map(|c| format!("# {c}\n")).collect();
        if !header.attribute_names.is_empty() {
            text.push_str(&format!(
                "# {ATTRIBUTES_NOT_STORED} {}\n",
                header.attribute_names.join(" ")
            ));
        }
        out.write_all(text.as_bytes())?;
        Ok(ObjSink { core, out })
    }

    /// Continues a checkpointed sink (see [`MeshSink::checkpoint`]).
    pub(crate) fn resume(
        path: &Path,
        header: &Header,
        state: SinkState,
    ) -> Result<ObjSink, SmeshError> {
        let (core, out, _) = state.reopen_one(path, header, |f| matches!(f, Saved::Obj), "OBJ")?;
        Ok(ObjSink { core, out })
    }
}

impl MeshSink for ObjSink {
    fn vertex(&mut self, pos: [f32; 3], attrs: &[f32]) -> Result<(), SmeshError> {
        self.core.vertex(pos, attrs)?;
        let line = format!("v {} {} {}\n", pos[0], pos[1], pos[2]);
        self.out.write_all(line.as_bytes())
    }

    fn triangle(&mut self, v: [u64; 3], last_use: [bool; 3]) -> Result<(), SmeshError> {
        self.core.triangle(v, last_use)?;
        let line = format!("f {} {} {}\n", v[0] + 1, v[1] + 1, v[2] + 1);
        self.out.write_all(line.as_bytes())
    }

    fn finalize(&mut self, v: u64) -> Result<(), SmeshError> {
        self.core.finalize(v)
    }

    fn complete(self: Box<Self>) -> Result<Completed, SmeshError> {
        self.core.finish()?;
        let ObjSink { core, out, .. } = *self;
        Completed::new(out, Vec::new(), |bytes| core.stats(bytes))
    }

    fn checkpoint(&mut self) -> Result<SinkState, SmeshError> {
        SinkState::of_one(&mut self.out, &self.core, Saved::Obj)
    }
}

/// Loads an OBJ file: every `v` line is a vertex, numbered over the whole file as OBJ numbers
/// them (1-based, or negative: relative to the vertices read so far), whatever `g` and `o`
/// groups the faces are in; `f` lines in any corner form (`v`, `v/vt`, `v//vn`, `v/vt/vn`),
/// polygons fanned into triangles; lines continued by a trailing `\`. Vertices no face uses
/// stay (and are dropped and counted by `convert`, as PLY's are). The `#` lines before the first
/// statement are the header's comments, where the sink writes them (the run's provenance); a
/// foreign file's are kept as comments too, and later `#` lines are not comments of the mesh.
///
/// Written by hand: `tobj` numbered the vertices of each object or group apart, so an OBJ with
/// groups came apart into pieces at the group borders (a tetrahedron in two groups measured 8
/// vertices, 2 components, not closed), and it passed over a vertex of fewer than three numbers
/// and a face of fewer than three corners without a word.
pub(crate) fn read(path: &Path) -> Result<IndexedMesh, SmeshError> {
    use std::io::BufRead;
    let file = std::fs::File::open(path).map_err(|e| SmeshError::io(path, "open", e))?;
    let mut reader = Reader {
        path,
        mesh: IndexedMesh::default(),
        farthest: None,
        unknown: None,
    };
    let mut statement = String::new();
    let mut first_line = 0;
    let mut in_header = true;
    for (n, line) in std::io::BufReader::with_capacity(1 << 16, file)
        .split(b'\n')
        .enumerate()
    {
        let line = line.map_err(|e| SmeshError::io(path, "read", e))?;
        // No text has a NUL byte: a PNG or an SMB renamed .obj read as an empty mesh.
        if line.contains(&0) {
            return Err(not_obj(path, format!("binary data on line {}", n + 1)));
        }
        if statement.is_empty() {
            first_line = n as u64 + 1;
        }
        let text = String::from_utf8_lossy(&line);
        if in_header {
            match text.trim().strip_prefix('#') {
                Some(comment) => reader.header_comment(comment.trim()),
                None => in_header = text.trim().is_empty(),
            }
        }
        // The comment first: a `\` ending a comment (`# C:\models\`) continues nothing.
        let text = text.split('#').next().unwrap_or_default().trim_end();
        match text.strip_suffix('\\') {
            Some(head) => {
                statement.push_str(head);
                statement.push(' ');
            }
            None => {
                statement.push_str(text);
                reader.statement(&statement, first_line)?;
                statement.clear();
            }
        }
    }
    reader.statement(&statement, first_line)?;
    reader.finish()
}

/// The statements of the OBJ specification (Wavefront's Appendix B1), kept (`v`, `f`) or passed
/// over (the rest).
const STATEMENTS: &[&str] = &[
    "v",
    "vt",
    "vn",
    "vp",
    "f",
    "fo",
    "l",
    "p",
    "g",
    "o",
    "s",
    "mg",
    "mtllib",
    "usemtl",
    "usemap",
    "maplib",
    "cstype",
    "deg",
    "bmat",
    "step",
    "curv",
    "curv2",
    "surf",
    "parm",
    "trim",
    "hole",
    "scrv",
    "sp",
    "end",
    "con",
    "bevel",
    "c_interp",
    "d_interp",
    "lod",
    "shadow_obj",
    "trace_obj",
    "ctech",
    "stech",
    "call",
    "csh",
];

fn not_obj(path: &Path, found: String) -> SmeshError {
    SmeshError::foreign(
        path,
        format!("not an OBJ file ({found}); is it another format renamed .obj?"),
    )
}

/// A coordinate as `f32` reads it (what the mesh keeps), or, past `f32`'s range, the `f64`
/// value, so that the range check names it as too large rather than as infinite.
fn coordinate(word: &str) -> Option<f64> {
    let single = word.parse::<f32>().ok()?;
    match single.is_finite() {
        true => Some(f64::from(single)),
        false => word.parse::<f64>().ok(),
    }
}

/// The state of an OBJ read: the mesh so far, and the farthest vertex a face named before it
/// was read (OBJ allows that), checked once every vertex is known.
struct Reader<'a> {
    path: &'a Path,
    mesh: IndexedMesh,
    /// (0-based vertex, line of the face naming it).
    farthest: Option<(u64, u64)>,
    /// The first statement that is none of [`STATEMENTS`] (its line and its start). Passed over
    /// in a file with vertices (exporters add their own); in a file without, it says the file
    /// is not an OBJ (a text file "hello" read as an empty mesh). Text that is not UTF-8 is
    /// judged the same way: real OBJs have Latin-1 names and comments.
    unknown: Option<(u64, String)>,
}

impl Reader<'_> {
    fn invalid(&self, line: u64, message: impl std::fmt::Display) -> SmeshError {
        SmeshError::foreign(self.path, format!("invalid OBJ at line {line}: {message}"))
    }

    fn expected(&self, line: u64, expected: &str, found: &str) -> SmeshError {
        self.invalid(
            line,
            format!(
                "expected {expected}, found {:?} (truncated file?)",
                found.trim()
            ),
        )
    }

    /// A `#` line of the header as other formats can hold it, unless it is the sink's note on
    /// attributes or a comment they cannot.
    fn header_comment(&mut self, comment: &str) {
        if !comment.starts_with(ATTRIBUTES_NOT_STORED)
            && let Some(c) = crate::sma::carried_comment(comment)
        {
            self.mesh.comments.push(c);
        }
    }

    /// One statement (a line, continuations joined, comments stripped).
    fn statement(&mut self, text: &str, line: u64) -> Result<(), SmeshError> {
        let mut words = text.split_whitespace();
        match words.next() {
            Some("v") => {
                let numbers: Vec<f64> = words.map_while(coordinate).collect();
                let [x, y, z] = match numbers[..] {
                    [x, y, z, ..] => [x, y, z],
                    _ => return Err(self.expected(line, "a vertex of three numbers", text)),
                };
                // `v x y z w`, a weight (four numbers; six or seven are a colour): the position
                // is x/w, y/w, z/w, as tobj read it.
                let position = match numbers[..] {
                    [_, _, _, 0.0] => {
                        return Err(self.invalid(line, "a vertex of weight 0 has no position"));
                    }
                    [_, _, _, w] => [x / w, y / w, z / w],
                    _ => [x, y, z],
                };
                self.mesh.positions.push(position);
            }
            Some("f") => {
                let corners = words
                    .map(|w| self.corner(w, line))
                    .collect::<Result<Vec<u32>, _>>()?;
                if corners.len() < 3 {
                    return Err(self.expected(line, "a face of at least three corners", text));
                }
                for k in 2..corners.len() {
                    let t = [corners[0], corners[k - 1], corners[k]];
                    self.mesh.triangles.push(t);
                }
            }
            Some(word) if self.unknown.is_none() && !STATEMENTS.contains(&word) => {
                self.unknown = Some((line, text.trim().chars().take(40).collect()));
            }
            _ => {}
        }
        Ok(())
    }

    /// A face corner's 0-based vertex: the first number of `v`, `v/vt`, `v//vn` or `v/vt/vn`.
    fn corner(&mut self, word: &str, line: u64) -> Result<u32, SmeshError> {
        let first = word.split('/').next().unwrap_or_default();
        let read = self.mesh.positions.len() as u64;
        let vertex = match first.parse::<i64>() {
            Ok(n @ 1..) => {
                let v = n as u64 - 1;
                if v >= read && self.farthest.is_none_or(|(f, _)| v > f) {
                    self.farthest = Some((v, line));
                }
                v
            }
            Ok(n @ ..=-1) => read.checked_sub(n.unsigned_abs()).ok_or_else(|| {
                self.invalid(
                    line,
                    format!("relative vertex index {n} but only {read} vertices precede it"),
                )
            })?,
            _ => {
                return Err(self.invalid(
                    line,
                    format!(
                        "expected a face corner `v`, `v/vt`, `v//vn` or `v/vt/vn` with a nonzero vertex index, found {word:?}"
                    ),
                ));
            }
        };
        u32::try_from(vertex)
            .map_err(|_| self.invalid(line, format!("vertex {} is beyond 2^32", vertex + 1)))
    }

    fn finish(self) -> Result<IndexedMesh, SmeshError> {
        let n = self.mesh.positions.len() as u64;
        let empty = n == 0 && self.mesh.triangles.is_empty();
        if let (true, Some((line, found))) = (empty, &self.unknown) {
            return Err(not_obj(
                self.path,
                format!("found {found:?} on line {line}, and not one vertex or face"),
            ));
        }
        match self.farthest {
            Some((v, line)) if v >= n => Err(self.invalid(
                line,
                format!("a face uses vertex {} but the file has {n} vertices", v + 1),
            )),
            _ => Ok(self.mesh),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_text(text: &str) -> Result<IndexedMesh, String> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.obj");
        std::fs::write(&p, text).unwrap();
        read(&p).map_err(|e| e.to_string().replace(&format!("{}: ", p.display()), ""))
    }

    /// A tetrahedron whose faces are in two groups keeps its 4 vertices (tobj gave 8).
    #[test]
    fn groups_share_the_file_s_vertices() {
        for group in ["g", "o"] {
            let m = read_text(&format!(
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n{group} a\nf 1 3 2\nf 1 2 4\n{group} b\nf 1 4 3\nf 2 3 4\n"
            ))
            .unwrap();
            assert_eq!(m.positions.len(), 4);
            assert_eq!(m.triangles, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]);
        }
    }

    #[test]
    fn corner_forms_relative_indices_continuations_and_polygons() {
        let m = read_text(
            "# square and an unused vertex\nv 0 0 0\nv 1 0 0 1.0\nv 1 1 0\nv 0 1 0\nv 9 9 9\n\
             vt 0 0\nvn 0 0 1\nf 1/1/1 2//1 \\\n  3/1 -2\nf -5 -3 -2\n",
        )
        .unwrap();
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.triangles, [[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
    }

    /// A comment ending in `\\` (a Windows path) continues nothing: the next line is read.
    #[test]
    fn a_comment_ending_in_a_backslash_is_only_a_comment() {
        let m = read_text(
            "# exported from C:\\models\\\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n\
             f 1 3 2 # C:\\tmp\\\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
        )
        .unwrap();
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles.len(), 4);
    }

    /// `v x y z w` is the point (x/w, y/w, z/w), as tobj read it; six numbers are a colour; a
    /// weight of 0 is refused; past f32's range is kept as the number, for the range check.
    #[test]
    fn vertex_weights_colours_and_large_coordinates() {
        let m = read_text("v 2 0 0 2\nv 1 2 3 0.5 0.5 0.5\nv 1e39 0 0\n").unwrap();
        assert_eq!(
            m.positions,
            [[1.0, 0.0, 0.0], [1.0, 2.0, 3.0], [1e39, 0.0, 0.0]]
        );
        let e = read_text("v 1 2 3 0\n").unwrap_err();
        assert!(e.contains("line 1: a vertex of weight 0"), "{e}");
    }

    /// Files that are not OBJs (binary, or text without one OBJ statement) read as an empty
    /// mesh, exit 0; OBJs with statements of their own still read.
    #[test]
    fn a_file_that_is_not_an_obj_is_refused() {
        let e = read_text("\u{89}PNG\r\n\u{1a}\n\0\0\0\rIHDR").unwrap_err();
        assert_eq!(
            e,
            "not an OBJ file (binary data on line 3); is it another format renamed .obj?"
        );
        let e = read_text("hello\n").unwrap_err();
        assert_eq!(
            e,
            "not an OBJ file (found \"hello\" on line 1, and not one vertex or face); is it another format renamed .obj?"
        );
        let e = read_text("# a comment\n\nmtllib a.mtl\nply\nformat ascii 1.0\n").unwrap_err();
        assert!(e.contains("found \"ply\" on line 4"), "{e}");
        // Exporters' own statements pass, and so do Latin-1 names and an empty file.
        let m = read_text("mtllib a.mtl\nusemtl caf\u{e9}\nexporter_tag 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\ns off\nl 1 2\np 3\nf 1 2 3\n")
            .unwrap();
        assert_eq!(m.triangles.len(), 1);
        read_text("v 0 0 0\nfoo bar\n").unwrap();
        assert!(read_text("").unwrap().positions.is_empty());
        assert!(
            read_text("# only a comment\ng empty\n")
                .unwrap()
                .positions
                .is_empty()
        );
    }

    #[test]
    fn faces_may_name_vertices_read_after_them() {
        let m = read_text("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
        assert_eq!(m.triangles, [[0, 1, 2]]);
    }

    #[test]
    fn bad_lines_are_named_by_number() {
        let cases = [
            (
                "v 0 0 0\nv 1 0\n",
                "line 2: expected a vertex of three numbers, found \"v 1 0\"",
            ),
            (
                "v 0 0 0\nf 1 1\n",
                "line 2: expected a face of at least three corners",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 0 1 2\n",
                "line 5: expected a face corner",
            ),
            (
                "v 0 0 0\nv 1 0 0\nf -1 -2 -3\n",
                "line 3: relative vertex index -3 but only 2",
            ),
            (
                "v 0 0 0\nv 1 0 0\nf 1 \\\n 2 7\nv 0 1 0\n",
                "line 3: a face uses vertex 7 but the file has 3 vertices",
            ),
        ];
        for (text, needle) in cases {
            let e = read_text(text).unwrap_err();
            assert!(
                e.starts_with("invalid OBJ at ") && e.contains(needle),
                "{e}"
            );
        }
    }
}
