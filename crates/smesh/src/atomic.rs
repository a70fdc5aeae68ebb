//! Output files that appear under their final name only when complete.
//!
//! Data goes to a temporary file in the destination directory (same file system, so the final
//! rename is atomic); `finish` flushes, fsyncs and renames. Dropping an unfinished `AtomicFile`
//! deletes the temporary file, so a crash or an error never leaves a half-written mesh that a later
//! stage could mistake for a result.

use std::fs::File;
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use tempfile::NamedTempFile;

use crate::SmeshError;

/// A temporary-file builder for outputs: `tempfile` creates files `0o600`, which the rename
/// would carry to the result; outputs get the usual `0o666` less the umask, like any file a user
/// creates.
pub fn output_builder(prefix: &str) -> tempfile::Builder<'_, 'static> {
    let mut b = tempfile::Builder::new();
    b.prefix(prefix).suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b
}

pub(crate) struct AtomicFile {
    path: PathBuf,
    out: BufWriter<NamedTempFile>,
}

impl AtomicFile {
    pub(crate) fn create(path: &Path) -> Result<AtomicFile, SmeshError> {
        let dir = dir_of(path);
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = output_builder(&format!(".{name}."))
            .tempfile_in(dir)
            .map_err(|e| {
                SmeshError::io(
                    path,
                    format!("create a temporary file in {}", dir.display()),
                    e,
                )
            })?;
        Ok(AtomicFile {
            path: path.to_path_buf(),
            out: BufWriter::with_capacity(1 << 16, tmp),
        })
    }

    /// The final path, for error messages.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    pub(crate) fn write_all(&mut self, bytes: &[u8]) -> Result<(), SmeshError> {
        self.out
            .write_all(bytes)
            .map_err(|e| SmeshError::io(&self.path, "write", e))
    }

    /// A `Write` for formatting code; its errors are turned into ours with `io_error`.
    pub(crate) fn writer(&mut self) -> &mut impl Write {
        &mut self.out
    }

    pub(crate) fn io_error(&self, e: io::Error) -> SmeshError {
        SmeshError::io(&self.path, "write", e)
    }

    /// Copies the rest of `spill` (see `rewind_spill`) to the end of the output.
    pub(crate) fn append(&mut self, spill: &mut File) -> Result<(), SmeshError> {
        io::copy(spill, &mut self.out)
            .map(|_| ())
            .map_err(|e| SmeshError::io(&self.path, "copy spilled data into", e))
    }

    /// Overwrites bytes already written at `offset` (header counts known only at the end).
    pub(crate) fn patch(&mut self, offset: u64, bytes: &[u8]) -> Result<(), SmeshError> {
        let res = (|| {
            self.out.flush()?;
            let f = self.out.get_mut().as_file_mut();
            let end = f.stream_position()?;
            f.seek(SeekFrom::Start(offset))?;
            f.write_all(bytes)?;
            f.seek(SeekFrom::Start(end))?;
            Ok(())
        })();
        res.map_err(|e| SmeshError::io(&self.path, "patch the header of", e))
    }

    /// Cuts the output at `len` bytes (an SMB header without bounding box is shorter).
    pub(crate) fn truncate(&mut self, len: u64) -> Result<(), SmeshError> {
        let res = (|| {
            self.out.flush()?;
            let f = self.out.get_mut().as_file_mut();
            f.set_len(len)?;
            f.seek(SeekFrom::Start(len))?;
            Ok(())
        })();
        res.map_err(|e| SmeshError::io(&self.path, "truncate", e))
    }

    /// Flushes, fsyncs, renames to the final name; returns the file size.
    pub(crate) fn finish(self) -> Result<u64, SmeshError> {
        let path = self.path;
        let tmp = self
            .out
            .into_inner()
            .map_err(|e| SmeshError::io(&path, "flush", e.into_error()))?;
        tmp.as_file()
            .sync_all()
            .map_err(|e| SmeshError::io(&path, "fsync", e))?;
        let bytes = tmp
            .as_file()
            .metadata()
            .map_err(|e| SmeshError::io(&path, "stat", e))?
            .len();
        tmp.persist(&path)
            .map_err(|e| SmeshError::io(&path, "rename the temporary file to", e.error))?;
        // Make the rename itself durable. Best effort: not every platform can open a directory.
        #[cfg(unix)]
        if let Ok(dir) = File::open(dir_of(&path)) {
            dir.sync_all()
                .map_err(|e| SmeshError::io(&path, "fsync the directory of", e))?;
        }
        Ok(bytes)
    }
}

/// The directory `path` is in ("." for a bare file name).
fn dir_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// An anonymous scratch file next to `path` (same disk as the output), deleted when dropped:
/// where converters park data that must come later in the output than it arrives.
pub(crate) fn spill_file(path: &Path) -> Result<BufWriter<File>, SmeshError> {
    let dir = dir_of(path);
    tempfile::tempfile_in(dir)
        .map(|f| BufWriter::with_capacity(1 << 16, f))
        .map_err(|e| {
            SmeshError::io(
                path,
                format!("create a scratch file in {}", dir.display()),
                e,
            )
        })
}

/// Flushes a spill and rewinds it for reading back; returns it with its length.
pub(crate) fn rewind_spill(path: &Path, spill: BufWriter<File>) -> Result<(File, u64), SmeshError> {
    let res = spill
        .into_inner()
        .map_err(|e| e.into_error())
        .and_then(|mut f| {
            let len = f.stream_position()?;
            f.seek(SeekFrom::Start(0))?;
            Ok((f, len))
        });
    res.map_err(|e| SmeshError::io(path, "read back scratch data for", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Finished outputs carry the permissions of any file the user creates (umask applied), not
    /// the temporary file's owner-only `0o600`.
    #[cfg(unix)]
    #[test]
    fn outputs_get_ordinary_permissions() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        let plain = dir.path().join("plain");
        File::create(&plain).unwrap();
        let out = dir.path().join("mesh.sma");
        let mut f = AtomicFile::create(&out).unwrap();
        f.write_all(b"x").unwrap();
        f.finish().unwrap();
        assert_eq!(mode(&out), mode(&plain));
    }
}
