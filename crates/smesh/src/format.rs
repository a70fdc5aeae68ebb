//! Mesh file formats, chosen by file extension.

use std::path::Path;

use crate::SmeshError;

/// A mesh file format. New formats may be added, hence `non_exhaustive`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Format {
    /// Streaming mesh, ASCII (Isenburg and Lindstrom 2005), with our per-vertex attribute superset.
    Sma,
    /// Streaming mesh, binary (version 1, our superset, when it carries attributes).
    Smb,
    /// Stanford PLY (written binary little-endian by default, or ASCII).
    Ply,
    /// Wavefront OBJ (positions and triangles only).
    Obj,
    /// Binary STL (triangles as corner positions; read back with identical corners welded).
    Stl,
    /// Binary glTF 2.0: positions, indices, optional normals, attributes as `_NAME` accessors.
    Glb,
}

impl Format {
    /// The format named by `path`'s extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Format, SmeshError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("sma") => Ok(Format::Sma),
            Some("smb") => Ok(Format::Smb),
            Some("ply") => Ok(Format::Ply),
            Some("obj") => Ok(Format::Obj),
            Some("stl") => Ok(Format::Stl),
            Some("glb") => Ok(Format::Glb),
            _ => Err(SmeshError::UnknownFormat {
                path: path.to_path_buf(),
            }),
        }
    }

    /// Whether the format stores per-vertex attributes (OBJ and STL have no place for them).
    pub fn keeps_attributes(self) -> bool {
        !matches!(self, Format::Obj | Format::Stl)
    }

    /// Whether the format is a streaming mesh (elements interleaved, vertices finalized), which
    /// can be read and converted with memory bounded by the stream width.
    pub fn is_streaming(self) -> bool {
        matches!(self, Format::Sma | Format::Smb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extension_decides_case_insensitively() {
        assert_eq!(
            Format::from_path(Path::new("a/b.SMB")).unwrap(),
            Format::Smb
        );
        assert_eq!(Format::from_path(Path::new("b.sma")).unwrap(), Format::Sma);
        assert_eq!(Format::from_path(Path::new("b.ply")).unwrap(), Format::Ply);
        assert_eq!(Format::from_path(Path::new("b.obj")).unwrap(), Format::Obj);
        assert_eq!(Format::from_path(Path::new("b.stl")).unwrap(), Format::Stl);
        assert_eq!(Format::from_path(Path::new("b.glb")).unwrap(), Format::Glb);
        let err = Format::from_path(Path::new("out/b.txt")).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("out/b.txt: unknown mesh format")
        );
    }
}
