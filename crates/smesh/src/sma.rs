//! SMA, the ASCII streaming mesh: `v x y z`, `f a b c` (indices as in `index`), `x k` (explicit
//! finalization), `#` comments; header comments `# nverts N`, `# nfaces N`, `# bb_min x y z`,
//! `# bb_max x y z`.
//!
//! Our superset: a `# vertex_attributes name...` header line names extra values that follow
//! x y z on every `v` line. Reference readers take only three floats from a `v` line and skip
//! comments, so such files stay readable by them; likewise our reader ignores extra values on
//! `v` lines of files that declare no attributes.
//!
//! The writer learns the counts and bounding box only at the end, so it reserves the four header
//! lines at the top with fixed width (space padded) and overwrites them in place on finish: no
//! second pass, no rewrite. An empty mesh gets blank `#` lines instead of a bounding box.

use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use crate::atomic::AtomicFile;
use crate::reader::{Element, ReadHeader};
use crate::track::Tracker;
use crate::{Format, Header, Place, SmeshError, Subject, index};

/// Width of the value field of the reserved lines: 20 digits hold any u64; a bounding-box corner
/// is three `{:e}` f32s of at most 15 characters each.
const COUNT_WIDTH: usize = 20;
const BBOX_WIDTH: usize = 50;
const ATTRIBUTES_KEY: &str = "vertex_attributes";

/// Header comment keys the reader interprets; a free comment must not start with one.
const KEYS: [&str; 5] = ["nverts", "nfaces", "bb_min", "bb_max", ATTRIBUTES_KEY];

/// A comment read from a file's header (another tool's as well as ours) as every format can
/// carry it: trimmed and escaped to printable ASCII (`crate::printable_ascii`: another tool's
/// `é`, control character or line break went into the output as it was, making a PLY header
/// that is not ASCII or an OBJ our reader takes for binary), and `None` when it is empty or
/// starts with a key SMA readers interpret, which the SMA writer refuses (a foreign PLY's
/// `comment nverts 3` would otherwise fail a conversion to SMA that succeeded before comments
/// were carried).
pub(crate) fn carried_comment(c: &str) -> Option<String> {
    let c = crate::printable_ascii(c.trim());
    (!c.is_empty() && !starts_with_key(&c)).then_some(c)
}

/// [`carried_comment`] of each of a header's comments (a PLY's, or an SMA's or SMB's, which
/// other tools write too: an SMB's comment table may hold a line break, which failed the
/// conversion).
pub(crate) fn carried_comments(comments: &[String]) -> Vec<String> {
    comments.iter().filter_map(|c| carried_comment(c)).collect()
}

fn starts_with_key(c: &str) -> bool {
    KEYS.contains(&c.split_whitespace().next().unwrap_or(""))
}

/// Writes SMA; the reserved header block starts the file (offset 0).
pub(crate) struct SmaEncoder;

/// One reserved header line: `# key value`, padded; `#` and spaces when there is no value.
fn reserved_line(key: &str, value: Option<String>, width: usize) -> String {
    let full = 2 + key.len() + 1 + width;
    let mut line = match value {
        Some(v) => format!("# {key} {v}"),
        None => "#".to_string(),
    };
    debug_assert!(line.len() <= full);
    line.extend(std::iter::repeat_n(' ', full - line.len()));
    line.push('\n');
    line
}

fn corner(c: [f32; 3]) -> String {
    format!("{:e} {:e} {:e}", c[0], c[1], c[2])
}

fn reserved_block(counts: Option<(u64, u64)>, bbox: Option<([f32; 3], [f32; 3])>) -> String {
    let count = |i: usize| counts.map(|c| if i == 0 { c.0 } else { c.1 }.to_string());
    [
        reserved_line("nverts", count(0), COUNT_WIDTH),
        reserved_line("nfaces", count(1), COUNT_WIDTH),
        reserved_line("bb_min", bbox.map(|b| corner(b.0)), BBOX_WIDTH),
        reserved_line("bb_max", bbox.map(|b| corner(b.1)), BBOX_WIDTH),
    ]
    .concat()
}

impl SmaEncoder {
    pub(crate) fn begin(out: &mut AtomicFile, header: &Header) -> Result<SmaEncoder, SmeshError> {
        if let Some(c) = header.comments.iter().find(|c| starts_with_key(c)) {
            return Err(SmeshError::Unsupported {
                path: out.path().to_path_buf(),
                message: format!("header comment {c:?} starts with a key SMA readers interpret"),
            });
        }
        out.write_all(reserved_block(None, None).as_bytes())?;
        let mut text = String::new();
        if !header.attribute_names.is_empty() {
            text.push_str(&format!(
                "# {ATTRIBUTES_KEY} {}\n",
                header.attribute_names.join(" ")
            ));
        }
        for c in &header.comments {
            text.push_str(&format!("# {c}\n"));
        }
        out.write_all(text.as_bytes())?;
        Ok(SmaEncoder)
    }

    pub(crate) fn vertex(
        &mut self,
        out: &mut AtomicFile,
        pos: [f32; 3],
        attrs: &[f32],
    ) -> Result<(), SmeshError> {
        let w = out.writer();
        let res = write!(w, "v {} {} {}", pos[0], pos[1], pos[2])
            .and_then(|_| attrs.iter().try_for_each(|a| write!(w, " {a}")))
            .and_then(|_| w.write_all(b"\n"));
        res.map_err(|e| out.io_error(e))
    }

    pub(crate) fn triangle(&mut self, out: &mut AtomicFile, n: [i64; 3]) -> Result<(), SmeshError> {
        let res = writeln!(out.writer(), "f {} {} {}", n[0], n[1], n[2]);
        res.map_err(|e| out.io_error(e))
    }

    pub(crate) fn finalize(&mut self, out: &mut AtomicFile, n: i64) -> Result<(), SmeshError> {
        let res = writeln!(out.writer(), "x {n}");
        res.map_err(|e| out.io_error(e))
    }

    pub(crate) fn end(self, out: &mut AtomicFile, tracker: &Tracker) -> Result<(), SmeshError> {
        let block = reserved_block(
            Some((tracker.vertices(), tracker.triangles())),
            tracker.bbox(),
        );
        out.patch(0, block.as_bytes())
    }
}

pub(crate) struct SmaDecoder {
    input: BufReader<File>,
    line: String,
    line_no: u64,
    /// The first element line, read while looking for the end of the header.
    pending: bool,
    attributes: usize,
    vertices: u64,
    triangles: u64,
}

impl SmaDecoder {
    pub(crate) fn open(path: &Path, file: File) -> Result<(SmaDecoder, ReadHeader), SmeshError> {
        let mut dec = SmaDecoder {
            input: BufReader::with_capacity(1 << 16, file),
            line: String::new(),
            line_no: 0,
            pending: false,
            attributes: 0,
            vertices: 0,
            triangles: 0,
        };
        let mut header = ReadHeader::new(Format::Sma);
        let mut bb_min = None;
        let mut bb_max = None;
        while dec.read_line(path)? {
            let line = dec.line.trim();
            let Some(comment) = line.strip_prefix('#') else {
                if line.is_empty() {
                    continue;
                }
                dec.pending = true;
                break;
            };
            let comment = comment.trim();
            let (key, rest) = comment
                .split_once(char::is_whitespace)
                .unwrap_or((comment, ""));
            let place = Place::Line(dec.line_no);
            match key {
                "" => {}
                "nverts" => header.nverts = parse_count(path, place, rest)?,
                "nfaces" => header.nfaces = parse_count(path, place, rest)?,
                "bb_min" => bb_min = Some(parse_corner(path, place, rest)?),
                "bb_max" => bb_max = Some(parse_corner(path, place, rest)?),
                ATTRIBUTES_KEY => {
                    header.attribute_names = rest.split_whitespace().map(String::from).collect()
                }
                _ => header.comments.push(comment.to_string()),
            }
        }
        header.bbox = bb_min.zip(bb_max);
        dec.attributes = header.attribute_names.len();
        Ok((dec, header))
    }

    /// Reads the next line into `self.line`; false at end of file.
    fn read_line(&mut self, path: &Path) -> Result<bool, SmeshError> {
        self.line.clear();
        let n = self
            .input
            .read_line(&mut self.line)
            .map_err(|e| SmeshError::io(path, format!("read line {}", self.line_no + 1), e))?;
        self.line_no += 1;
        Ok(n > 0)
    }

    pub(crate) fn next(&mut self, path: &Path) -> Option<Result<(Element, Place), SmeshError>> {
        loop {
            if !self.pending {
                match self.read_line(path) {
                    Ok(true) => {}
                    Ok(false) => return None,
                    Err(e) => return Some(Err(e)),
                }
            }
            self.pending = false;
            let line = self.line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let place = Place::Line(self.line_no);
            return Some(self.element(path, place).map(|e| (e, place)));
        }
    }

    fn element(&mut self, path: &Path, place: Place) -> Result<Element, SmeshError> {
        let line = self.line.trim();
        let (kind, rest) = line.split_once(char::is_whitespace).unwrap_or((line, ""));
        match kind {
            "v" => {
                let values = rest
                    .split_whitespace()
                    .map(str::parse::<f32>)
                    .collect::<Result<Vec<f32>, _>>();
                match values {
                    // Without declared attributes, extra values are ignored as reference readers
                    // do; with them, the count must match.
                    Ok(mut values)
                        if values.len() == 3 + self.attributes
                            || (self.attributes == 0 && values.len() > 3) =>
                    {
                        values.truncate(3 + self.attributes);
                        let attrs = values.split_off(3);
                        self.vertices += 1;
                        Ok(Element::Vertex {
                            pos: [values[0], values[1], values[2]],
                            attrs,
                        })
                    }
                    _ => Err(SmeshError::syntax(
                        path,
                        place,
                        format!("`v x y z` with {} attribute values", self.attributes),
                        line,
                    )),
                }
            }
            "f" => {
                let n: [i64; 3] = parse_n(rest).ok_or_else(|| {
                    SmeshError::syntax(path, place, "`f a b c` with three nonzero integers", line)
                })?;
                let subject = Subject::Triangle(self.triangles, place);
                let mut v = [0; 3];
                let mut finalized = [false; 3];
                for i in 0..3 {
                    (v[i], finalized[i]) = self.decode(path, (subject, place), n[i], line)?;
                }
                self.triangles += 1;
                Ok(Element::Triangle { v, finalized })
            }
            "x" => {
                let [n]: [i64; 1] = parse_n(rest).ok_or_else(|| {
                    SmeshError::syntax(path, place, "`x k` with one nonzero integer", line)
                })?;
                let (v, _) = self.decode(path, (Subject::Finalization(place), place), n, line)?;
                Ok(Element::Finalize(v))
            }
            _ => Err(SmeshError::syntax(
                path,
                place,
                "a `v`, `f`, `x` or `#` line",
                line,
            )),
        }
    }

    fn decode(
        &self,
        path: &Path,
        (subject, place): (Subject, Place),
        n: i64,
        line: &str,
    ) -> Result<(u64, bool), SmeshError> {
        match index::decode(n, self.vertices) {
            None => Err(SmeshError::syntax(
                path,
                place,
                "nonzero indices (1-based, or negative relative)",
                line,
            )),
            Some(r) => r.map_err(|f| SmeshError::stream(path, subject, f)),
        }
    }
}

fn parse_count(path: &Path, place: Place, s: &str) -> Result<Option<u64>, SmeshError> {
    match s.trim().parse::<i64>() {
        Ok(-1) => Ok(None),
        Ok(n) if n >= 0 => Ok(Some(n as u64)),
        _ => Err(SmeshError::syntax(path, place, "a count (or -1)", s.trim())),
    }
}

/// A corner of the bounding box: three finite floats (a NaN compares false with every
/// coordinate, so a NaN box held every vertex and `check` passed it).
fn parse_corner(path: &Path, place: Place, s: &str) -> Result<[f32; 3], SmeshError> {
    parse_n::<f32, 3>(s)
        .filter(|c| c.iter().all(|x| x.is_finite()))
        .ok_or_else(|| SmeshError::syntax(path, place, "three finite floats", s.trim()))
}

/// Exactly `N` whitespace-separated values.
fn parse_n<T: std::str::FromStr + Copy + Default, const N: usize>(s: &str) -> Option<[T; N]> {
    let mut out = [T::default(); N];
    let mut it = s.split_whitespace();
    for o in &mut out {
        *o = it.next()?.parse().ok()?;
    }
    it.next().is_none().then_some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reserved_lines_have_fixed_width() {
        let empty = reserved_block(None, None);
        let full = reserved_block(
            Some((u64::MAX, 0)),
            Some(([-f32::MIN_POSITIVE; 3], [f32::MAX; 3])),
        );
        assert_eq!(empty.len(), full.len());
        assert!(full.starts_with("# nverts 18446744073709551615\n"));
    }
}
