//! Checking a streaming mesh file against the rules, and the checked element stream that every
//! file-driven consumer (validate, read_indexed, convert) reads through.

use std::path::Path;

use crate::track::Tracker;
use crate::{Element, Format, ReadHeader, SmeshError, StreamFault, StreamReader, Subject};

/// What `validate` found in a valid stream.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidationReport {
    pub format: Format,
    pub vertices: u64,
    pub triangles: u64,
    /// Stream width: the most vertices active (read, not yet finalized) at once.
    pub max_active_vertices: u64,
    /// The farthest a triangle reaches back: vertices read so far minus one minus the oldest
    /// index it uses (0 for a triangle on the latest vertices).
    pub max_triangle_skip: u64,
    pub header: ReadHeader,
}

/// A `StreamReader` whose elements have passed the rules: indices refer to vertices already read
/// and not finalized. `finish` adds the end-of-stream rules.
pub(crate) struct CheckedStream {
    reader: StreamReader,
    tracker: Tracker,
}

impl CheckedStream {
    pub(crate) fn open(path: &Path) -> Result<CheckedStream, SmeshError> {
        Ok(CheckedStream {
            reader: StreamReader::open(path)?,
            tracker: Tracker::default(),
        })
    }

    pub(crate) fn header(&self) -> &ReadHeader {
        self.reader.header()
    }

    pub(crate) fn next_element(&mut self) -> Option<Result<Element, SmeshError>> {
        let element = match self.reader.next()? {
            Ok(e) => e,
            Err(e) => return Some(Err(e)),
        };
        let place = self.reader.place();
        let checked = match &element {
            Element::Vertex { pos, .. } => {
                if pos.iter().all(|c| c.is_finite()) {
                    self.tracker.vertex(*pos);
                    Ok(())
                } else {
                    Err((
                        Subject::Vertex(self.tracker.vertices(), place),
                        StreamFault::NonFinite {
                            coords: format!("{}, {}, {}", pos[0], pos[1], pos[2]),
                        },
                    ))
                }
            }
            Element::Triangle { v, finalized } => {
                let subject = Subject::Triangle(self.tracker.triangles(), place);
                self.tracker
                    .triangle(*v, *finalized)
                    .map(|_| ())
                    .map_err(|f| (subject, f))
            }
            Element::Finalize(v) => self
                .tracker
                .finalize(*v)
                .map_err(|f| (Subject::Finalization(place), f)),
        };
        Some(
            checked
                .map(|()| element)
                .map_err(|(s, f)| SmeshError::stream(self.reader.path(), s, f)),
        )
    }

    /// End-of-stream rules: declared counts match, the declared bounding box holds every vertex,
    /// every vertex finalized.
    pub(crate) fn finish(self) -> Result<(ReadHeader, Tracker), SmeshError> {
        let path = self.reader.path();
        let header = self.reader.header();
        let fault = |f| SmeshError::stream(path, Subject::EndOfStream, f);
        for (what, declared, found) in [
            ("vertices", header.nverts, self.tracker.vertices()),
            ("triangles", header.nfaces, self.tracker.triangles()),
        ] {
            if let Some(declared) = declared.filter(|&d| d != found) {
                return Err(fault(StreamFault::CountMismatch {
                    what,
                    declared,
                    found,
                }));
            }
        }
        // A box that leaves vertices out misleads whoever culls or frames by it (a box of 0..1
        // around data spanning 60..220 passed); a looser one is allowed.
        if let (Some((lo, hi)), Some((vlo, vhi))) = (header.bbox, self.tracker.bbox())
            && (0..3).any(|k| vlo[k] < lo[k] || vhi[k] > hi[k])
        {
            return Err(fault(StreamFault::BoundingBox {
                declared: format!("{lo:?}..{hi:?}"),
                found: format!("{vlo:?}..{vhi:?}"),
            }));
        }
        self.tracker.finish().map_err(fault)?;
        Ok((header.clone(), self.tracker))
    }
}

/// Checks a streaming mesh: indices in range, nothing referenced before it appears, every vertex
/// finalized exactly once and never used after, header counts match. Also reports the stream
/// width (max active vertices) and the max triangle skip. Memory is bounded by the width.
pub fn validate(path: &Path) -> Result<ValidationReport, SmeshError> {
    let mut stream = CheckedStream::open(path)?;
    while let Some(e) = stream.next_element() {
        e?;
    }
    let (header, tracker) = stream.finish()?;
    Ok(ValidationReport {
        format: header.format,
        vertices: tracker.vertices(),
        triangles: tracker.triangles(),
        max_active_vertices: tracker.max_active(),
        max_triangle_skip: tracker.max_skip(),
        header,
    })
}
