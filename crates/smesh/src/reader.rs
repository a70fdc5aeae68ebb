//! Streaming reader for SMA and SMB: one element at a time, memory independent of the mesh size.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use crate::sma::SmaDecoder;
use crate::smb::SmbDecoder;
use crate::{Format, Place, SmeshError};

/// One element of a streaming mesh, indices 0-based absolute.
#[derive(Debug, Clone, PartialEq)]
pub enum Element {
    /// The next vertex (numbered in order of appearance) and its values of the header's
    /// attributes (empty when the file names none).
    Vertex { pos: [f32; 3], attrs: Vec<f32> },
    /// `finalized[i]`: this triangle is the last use of `v[i]`.
    Triangle { v: [u64; 3], finalized: [bool; 3] },
    /// Explicit finalization of a vertex (SMA `x` line).
    Finalize(u64),
}

/// What a streaming mesh file says about itself before its elements.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadHeader {
    pub format: Format,
    /// Declared counts, `None` when unknown (-1 or absent).
    pub nverts: Option<u64>,
    pub nfaces: Option<u64>,
    /// Declared bounding box (min, max).
    pub bbox: Option<([f32; 3], [f32; 3])>,
    pub comments: Vec<String>,
    /// Per-vertex attribute names (SMA `# vertex_attributes`, the SMB version-1 name table).
    pub attribute_names: Vec<String>,
}

impl ReadHeader {
    pub(crate) fn new(format: Format) -> ReadHeader {
        ReadHeader {
            format,
            nverts: None,
            nfaces: None,
            bbox: None,
            comments: Vec::new(),
            attribute_names: Vec::new(),
        }
    }
}

enum Decoder {
    Sma(SmaDecoder),
    Smb(SmbDecoder),
}

/// Iterator over the elements of an SMA or SMB file. It decodes indices but does not enforce the
/// finalization rules (that is `validate`'s job); after the first error it yields nothing more.
pub struct StreamReader {
    path: PathBuf,
    header: ReadHeader,
    decoder: Decoder,
    place: Place,
    failed: bool,
}

impl StreamReader {
    /// Opens `path`; the format comes from the extension (.sma, .smb) or, for other names, from the
    /// first bytes (an SMB magic, otherwise SMA).
    pub fn open(path: &Path) -> Result<StreamReader, SmeshError> {
        crate::input::regular_file(path)?;
        let mut file = File::open(path).map_err(|e| SmeshError::io(path, "open", e))?;
        let format = match Format::from_path(path) {
            Ok(f @ (Format::Sma | Format::Smb)) => f,
            Ok(other) => {
                let name = format!("{other:?}").to_uppercase();
                return Err(SmeshError::Unsupported {
                    path: path.to_path_buf(),
                    message: format!(
                        "{name} is not a streaming mesh format (SMA or SMB); `isostream convert` makes one"
                    ),
                });
            }
            Err(_) => {
                let mut magic = [0xffu8; 4];
                let n = file
                    .read(&mut magic)
                    .map_err(|e| SmeshError::io(path, "read", e))?;
                let file = &mut file;
                std::io::Seek::rewind(file).map_err(|e| SmeshError::io(path, "rewind", e))?;
                if crate::smb::is_magic(&magic[..n]) {
                    Format::Smb
                } else {
                    Format::Sma
                }
            }
        };
        let len = file
            .metadata()
            .map_err(|e| SmeshError::io(path, "read its size", e))?
            .len();
        if len == 0 {
            return Err(SmeshError::Unsupported {
                path: path.to_path_buf(),
                message:
                    "the file is empty (0 bytes), not a streaming mesh; was it written completely?"
                        .into(),
            });
        }
        let (decoder, header) = match format {
            Format::Smb => {
                let (d, h) = SmbDecoder::open(path, file)?;
                (Decoder::Smb(d), h)
            }
            _ => {
                let (d, h) = SmaDecoder::open(path, file)?;
                (Decoder::Sma(d), h)
            }
        };
        Ok(StreamReader {
            path: path.to_path_buf(),
            header,
            decoder,
            place: Place::Byte(0),
            failed: false,
        })
    }

    pub fn header(&self) -> &ReadHeader {
        &self.header
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Where the element last returned was found (byte offset for SMB, line for SMA).
    pub fn place(&self) -> Place {
        self.place
    }
}

impl Iterator for StreamReader {
    type Item = Result<Element, SmeshError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        let next = match &mut self.decoder {
            Decoder::Sma(d) => d.next(&self.path),
            Decoder::Smb(d) => d.next(&self.path),
        };
        Some(match next? {
            Ok((element, place)) => {
                self.place = place;
                Ok(element)
            }
            Err(e) => {
                self.failed = true;
                Err(e)
            }
        })
    }
}
