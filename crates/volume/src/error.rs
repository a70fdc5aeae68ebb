//! The crate's one error type. Every message is a single line that names the file (or the
//! procedural/in-memory origin) and says what to check, because these messages end up verbatim in
//! job logs read by people who did not write the reader.

use std::path::Path;

/// Everything that can go wrong while describing or reading a volume.
#[derive(Debug, thiserror::Error)]
pub enum VolumeError {
    /// The file does not exist.
    #[error("{file}: no such file; check the input path")]
    NotFound { file: String },

    /// An I/O call failed for another reason (permissions, device errors, ...).
    #[error("{file}: cannot {action}: {source}; check the file is readable and not being modified")]
    Io {
        file: String,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },

    /// A raw payload does not have the size the grid and voxel type require.
    #[error(
        "{file}: file is {actual} bytes but dims {dims} of {dtype} plus {header_bytes} header bytes need {expected}; {hint}"
    )]
    SizeMismatch {
        file: String,
        actual: u64,
        expected: u64,
        dims: String,
        dtype: &'static str,
        header_bytes: u64,
        /// What to check, in the vocabulary of the format (job file keys, header fields).
        hint: &'static str,
    },

    /// The grid itself is impossible (too few voxels, overflowing sizes, bad spacing).
    #[error("{origin}: {problem}")]
    Grid { origin: String, problem: String },

    /// A header or payload does not follow its format: `at` says where (header line, byte offset).
    #[error("{file}: {at}: expected {expected}, found {found}")]
    Format {
        file: String,
        at: String,
        expected: String,
        found: String,
    },

    /// A Blosc-compressed chunk that cannot be decoded: what is wrong with it, then what to do.
    #[error("{file}: blosc chunk: {problem}; {fix}")]
    Blosc {
        file: String,
        problem: String,
        fix: &'static str,
    },

    /// The caller broke the `read_slice` contract (slice index or buffer length).
    #[error("{origin}: {problem}; this is a bug in the caller of read_slice")]
    Contract { origin: String, problem: String },
}

impl VolumeError {
    /// Replaces the generic "grid" origin of a [`VolumeError::Grid`] with the file or source
    /// that produced the impossible grid, so the message points at what to fix.
    pub(crate) fn in_origin(self, origin: &str) -> Self {
        match self {
            VolumeError::Grid { problem, .. } => VolumeError::Grid {
                origin: origin.to_string(),
                problem,
            },
            other => other,
        }
    }

    pub(crate) fn io(path: &Path, action: &'static str, source: std::io::Error) -> Self {
        if source.kind() == std::io::ErrorKind::NotFound {
            VolumeError::NotFound {
                file: path.display().to_string(),
            }
        } else {
            VolumeError::Io {
                file: path.display().to_string(),
                action,
                source,
            }
        }
    }

    /// A format error; `found` is shortened and escaped so the message stays on one line.
    pub(crate) fn format(
        file: &Path,
        at: impl Into<String>,
        expected: impl Into<String>,
        found: impl AsRef<str>,
    ) -> Self {
        VolumeError::Format {
            file: file.display().to_string(),
            at: at.into(),
            expected: expected.into(),
            found: one_line(found.as_ref()),
        }
    }

    /// Checks the two `read_slice` preconditions every source shares.
    pub(crate) fn check_slice_request(
        origin: impl FnOnce() -> String,
        z: u64,
        nz: u64,
        got_len: usize,
        want_len: usize,
    ) -> Result<(), Self> {
        if z >= nz {
            return Err(VolumeError::Contract {
                origin: origin(),
                problem: format!("slice {z} requested but the volume has {nz} slices"),
            });
        }
        if got_len != want_len {
            return Err(VolumeError::Contract {
                origin: origin(),
                problem: format!("output buffer has {got_len} values but a slice has {want_len}"),
            });
        }
        Ok(())
    }
}

/// Quotes `s` (escaping control characters) and cuts it to a readable length.
fn one_line(s: &str) -> String {
    const MAX: usize = 60;
    let mut cut: String = s.chars().take(MAX).collect();
    if s.chars().count() > MAX {
        cut.push_str("...");
    }
    format!("{cut:?}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_error_stays_on_one_line() {
        let e = VolumeError::format(Path::new("a.nrrd"), "header line 3", "a field", "x\ny\0z");
        let msg = e.to_string();
        assert!(!msg.contains('\n'), "{msg}");
        assert_eq!(
            msg,
            r#"a.nrrd: header line 3: expected a field, found "x\ny\0z""#
        );
    }

    #[test]
    fn long_found_text_is_cut() {
        let e = VolumeError::format(Path::new("f"), "byte 0", "x", "a".repeat(500));
        assert!(e.to_string().len() < 120);
        assert!(e.to_string().contains("..."));
    }

    #[test]
    fn missing_file_maps_to_not_found() {
        let err = std::io::Error::from(std::io::ErrorKind::NotFound);
        let e = VolumeError::io(Path::new("/nope.raw"), "open", err);
        assert_eq!(
            e.to_string(),
            "/nope.raw: no such file; check the input path"
        );
    }
}
