//! Output files that appear under their final name only when complete.
//!
//! Data goes to a temporary file in the destination directory (same file system, so the final
//! rename is atomic); `complete` flushes and fsyncs, `persist` renames (two steps, so that the
//! pipeline can record between them that its run is done: see `sink::Completed`). Dropping an
//! unfinished `AtomicFile` deletes the temporary file, so a crash or an error never leaves a
//! half-written mesh that a later stage could mistake for a result.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use tempfile::TempPath;

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

/// A file under a temporary name next to the path it is for (`.NAME.XXXXXX.tmp`, the name
/// `stale_temp_files` of the pipeline recognises), deleted when dropped, until a checkpoint
/// refers to it: from then on it must survive a failure or a kill, for the resumed run.
pub(crate) struct TempFile {
    path: PathBuf,
    out: BufWriter<File>,
    /// Deletes the file on drop; `None` once a checkpoint refers to it.
    guard: Option<TempPath>,
}

impl TempFile {
    /// A new empty file beside `target`.
    fn create(target: &Path) -> io::Result<TempFile> {
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let (file, guard) = output_builder(&format!(".{name}."))
            .tempfile_in(dir_of(target))?
            .into_parts();
        Ok(TempFile {
            path: guard.to_path_buf(),
            out: BufWriter::with_capacity(1 << 16, file),
            guard: Some(guard),
        })
    }

    /// The file a checkpoint recorded, cut back to the length it had then.
    fn reopen(mark: &FileMark) -> io::Result<TempFile> {
        let mut file = OpenOptions::new().read(true).write(true).open(&mark.path)?;
        mark.holds(file.metadata()?.len())?;
        file.set_len(mark.len)?;
        file.seek(SeekFrom::Start(mark.len))?;
        Ok(TempFile {
            path: mark.path.clone(),
            out: BufWriter::with_capacity(1 << 16, file),
            guard: None,
        })
    }

    /// Flushes and fsyncs; from now on the file outlives a failure (a checkpoint names it).
    fn mark(&mut self) -> io::Result<FileMark> {
        self.out.flush()?;
        let f = self.out.get_mut();
        f.sync_data()?;
        let len = f.stream_position()?;
        self.keep()?;
        Ok(FileMark {
            path: self.path.clone(),
            len,
        })
    }

    /// From now on the file outlives a failure: nothing removes it on drop.
    fn keep(&mut self) -> io::Result<()> {
        if let Some(guard) = self.guard.take() {
            guard.keep().map_err(|e| e.error)?;
        }
        Ok(())
    }

    /// Flushes and rewinds for reading back (a spill); returns the length.
    fn rewind(&mut self) -> io::Result<u64> {
        self.out.flush()?;
        let f = self.out.get_mut();
        let len = f.stream_position()?;
        f.seek(SeekFrom::Start(0))?;
        Ok(len)
    }

    /// Flushes and fsyncs the whole file; returns its size.
    fn complete(&mut self) -> io::Result<u64> {
        self.out.flush()?;
        let f = self.out.get_mut();
        f.sync_all()?;
        Ok(f.metadata()?.len())
    }

    /// Renames the file to `target`.
    fn persist(mut self, target: &Path) -> io::Result<()> {
        match self.guard.take() {
            Some(guard) => guard.persist(target).map_err(|e| e.error)?,
            None => std::fs::rename(&self.path, target)?,
        }
        Ok(())
    }

    /// Removes the file, even one a checkpoint referred to (its run is complete).
    fn discard(mut self) {
        if self.guard.take().is_none() {
            // Best effort: a leftover scratch file is reported as stale by the next run.
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// A file of a sink as a checkpoint saw it: its temporary name and how many bytes of it count.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FileMark {
    pub path: PathBuf,
    pub len: u64,
}

impl FileMark {
    /// Whether the file is still there with at least the bytes that count (what a resume cuts
    /// it back to); `NotFound` or `UnexpectedEof` when not.
    pub fn check(&self) -> io::Result<()> {
        let len = std::fs::metadata(&self.path)
            .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", self.path.display())))?
            .len();
        self.holds(len)
    }

    /// Whether `len` bytes hold the bytes that count.
    fn holds(&self, len: u64) -> io::Result<()> {
        match len < self.len {
            true => Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!(
                    "{} has {len} bytes, fewer than the {} the checkpoint recorded",
                    self.path.display(),
                    self.len
                ),
            )),
            false => Ok(()),
        }
    }
}

pub(crate) struct AtomicFile {
    path: PathBuf,
    tmp: TempFile,
}

impl AtomicFile {
    pub(crate) fn create(path: &Path) -> Result<AtomicFile, SmeshError> {
        // Found now rather than when the finished file is renamed over it, after all the work.
        check_replaceable(path)?;
        let tmp = TempFile::create(path).map_err(|e| {
            SmeshError::io(
                path,
                format!("create a temporary file in {}", dir_of(path).display()),
                e,
            )
        })?;
        Ok(AtomicFile {
            path: path.to_path_buf(),
            tmp,
        })
    }

    /// The temporary output of an interrupted run, cut back to its checkpointed length.
    pub(crate) fn reopen(path: &Path, mark: &FileMark) -> Result<AtomicFile, SmeshError> {
        check_replaceable(path)?;
        let tmp = TempFile::reopen(mark).map_err(|e| {
            SmeshError::io(
                path,
                format!(
                    "reopen its checkpointed temporary output {}",
                    mark.path.display()
                ),
                e,
            )
        })?;
        Ok(AtomicFile {
            path: path.to_path_buf(),
            tmp,
        })
    }

    /// Flushes and fsyncs for a checkpoint (see [`TempFile`]).
    pub(crate) fn mark(&mut self) -> Result<FileMark, SmeshError> {
        self.tmp
            .mark()
            .map_err(|e| SmeshError::io(&self.path, "flush for a checkpoint", e))
    }

    /// The final path, for error messages.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    pub(crate) fn write_all(&mut self, bytes: &[u8]) -> Result<(), SmeshError> {
        self.tmp
            .out
            .write_all(bytes)
            .map_err(|e| SmeshError::io(&self.path, "write", e))
    }

    /// A `Write` for formatting code; its errors are turned into ours with `io_error`.
    pub(crate) fn writer(&mut self) -> &mut impl Write {
        &mut self.tmp.out
    }

    pub(crate) fn io_error(&self, e: io::Error) -> SmeshError {
        SmeshError::io(&self.path, "write", e)
    }

    /// Copies a spill (see [`Spill::rewind`]) to the end of the output.
    pub(crate) fn append(&mut self, spill: &mut Spill) -> Result<(), SmeshError> {
        io::copy(spill.tmp.out.get_mut(), &mut self.tmp.out)
            .map(|_| ())
            .map_err(|e| SmeshError::io(&self.path, "copy spilled data into it", e))
    }

    /// Overwrites bytes already written at `offset` (header counts known only at the end).
    pub(crate) fn patch(&mut self, offset: u64, bytes: &[u8]) -> Result<(), SmeshError> {
        let res = (|| {
            self.tmp.out.flush()?;
            let f = self.tmp.out.get_mut();
            let end = f.stream_position()?;
            f.seek(SeekFrom::Start(offset))?;
            f.write_all(bytes)?;
            f.seek(SeekFrom::Start(end))?;
            Ok(())
        })();
        res.map_err(|e| SmeshError::io(&self.path, "patch its header", e))
    }

    /// Cuts the output at `len` bytes (an SMB header without bounding box is shorter).
    pub(crate) fn truncate(&mut self, len: u64) -> Result<(), SmeshError> {
        let res = (|| {
            self.tmp.out.flush()?;
            let f = self.tmp.out.get_mut();
            f.set_len(len)?;
            f.seek(SeekFrom::Start(len))?;
            Ok(())
        })();
        res.map_err(|e| SmeshError::io(&self.path, "truncate", e))
    }

    /// Flushes and fsyncs the complete file, still under its temporary name; returns its size.
    pub(crate) fn complete(&mut self) -> Result<u64, SmeshError> {
        self.tmp
            .complete()
            .map_err(|e| SmeshError::io(&self.path, "flush and fsync its temporary file", e))
    }

    /// Keeps the complete temporary file whatever happens next, a failed rename included.
    pub(crate) fn keep(&mut self) -> Result<(), SmeshError> {
        self.tmp
            .keep()
            .map_err(|e| SmeshError::io(&self.path, "keep its temporary file", e))
    }

    /// The temporary name it is written under.
    pub(crate) fn temp_path(&self) -> &Path {
        &self.tmp.path
    }

    /// Renames the file [`AtomicFile::complete`] made complete to the final name.
    pub(crate) fn persist(self) -> Result<(), SmeshError> {
        let path = self.path;
        self.tmp
            .persist(&path)
            .map_err(|e| SmeshError::io(&path, "rename the temporary file to it", e))?;
        sync_folder(&path)
    }
}

/// What an output written by temporary file and rename may replace, checked before any work: a
/// rename puts a regular file in place of whatever is there, so a device (`-o /dev/full`
/// replaced the machine's), a FIFO, a socket or a folder is refused (`SmeshError::NotAFile`).
/// So is a symbolic link: the rename would replace the link itself, and following it would
/// leave the output's lock, checkpoint and stale-file scan (all named after the path given)
/// beside the link while the file written is elsewhere, so two runs through two names could
/// write one file and one could delete the other's live temporary file as stale (found by
/// review). A link in a folder of the path is followed as the kernel follows it. Nothing there
/// is fine: the rename makes it.
pub fn check_replaceable(path: &Path) -> Result<(), SmeshError> {
    let meta = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        // Nothing there (or a file where a folder should be, which creating the output's folder
        // reports): the rename makes it.
        Err(e)
            if matches!(
                e.kind(),
                io::ErrorKind::NotFound | io::ErrorKind::NotADirectory
            ) =>
        {
            return Ok(());
        }
        Err(e) => return Err(SmeshError::io(path, "look at the output path", e)),
    };
    let kind = meta.file_type();
    if kind.is_file() {
        return Ok(());
    }
    let what = if kind.is_symlink() {
        let to = std::fs::read_link(path).unwrap_or_default();
        format!(
            "a link (to {}); give the file's own path, as the lock, checkpoint and temporary \
             files are named after the path given",
            to.display()
        )
    } else if kind.is_dir() {
        "a folder; name a file (in it, or beside it)".to_string()
    } else {
        format!("{}, not a file; give a file path", file_kind(&kind))
    };
    Err(SmeshError::NotAFile {
        path: path.to_path_buf(),
        what: format!("it is {what}"),
    })
}

/// What a file that is neither a regular file, a folder nor a link is, for [`check_replaceable`]'s
/// message.
#[cfg_attr(not(unix), allow(unused_variables))]
fn file_kind(kind: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_char_device() {
            return "a character device";
        }
        if kind.is_block_device() {
            return "a block device";
        }
        if kind.is_fifo() {
            return "a FIFO";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    "not a regular file"
}

/// Renames `temp`, a complete output a checkpointed run left under its temporary name (the
/// pipeline's record of a run that finished its output), to `target` (refused where
/// [`check_replaceable`] refuses), durably.
pub fn put_in_place(temp: &Path, target: &Path) -> Result<(), SmeshError> {
    check_replaceable(target)?;
    std::fs::rename(temp, target).map_err(|e| {
        SmeshError::io(
            target,
            format!(
                "rename its complete temporary file {} to it",
                temp.display()
            ),
            e,
        )
    })?;
    sync_folder(target)
}

/// Makes a rename to `path` durable. Best effort: not every platform can open a directory.
fn sync_folder(path: &Path) -> Result<(), SmeshError> {
    #[cfg(unix)]
    if let Ok(dir) = File::open(dir_of(path)) {
        dir.sync_all()
            .map_err(|e| SmeshError::io(path, "fsync its folder", e))?;
    }
    Ok(())
}

/// The directory `path` is in ("." for a bare file name).
fn dir_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// A scratch file next to the output (same disk): where converters park data that must come
/// later in the output than it arrives. Named like a temporary output, so that a checkpoint
/// can refer to it.
pub(crate) struct Spill {
    /// The output it belongs to, for error messages.
    output: PathBuf,
    tmp: TempFile,
}

impl Spill {
    pub(crate) fn create(output: &Path) -> Result<Spill, SmeshError> {
        let tmp = TempFile::create(output).map_err(|e| {
            SmeshError::io(
                output,
                format!("create a scratch file in {}", dir_of(output).display()),
                e,
            )
        })?;
        Ok(Spill {
            output: output.to_path_buf(),
            tmp,
        })
    }

    pub(crate) fn reopen(output: &Path, mark: &FileMark) -> Result<Spill, SmeshError> {
        let tmp = TempFile::reopen(mark).map_err(|e| {
            SmeshError::io(
                output,
                format!(
                    "reopen its checkpointed scratch file {}",
                    mark.path.display()
                ),
                e,
            )
        })?;
        Ok(Spill {
            output: output.to_path_buf(),
            tmp,
        })
    }

    pub(crate) fn writer(&mut self) -> &mut BufWriter<File> {
        &mut self.tmp.out
    }

    /// Its temporary name.
    pub(crate) fn path(&self) -> &Path {
        &self.tmp.path
    }

    pub(crate) fn mark(&mut self) -> Result<FileMark, SmeshError> {
        self.tmp
            .mark()
            .map_err(|e| SmeshError::io(&self.output, "flush its scratch data for a checkpoint", e))
    }

    /// Flushes and rewinds for reading back; returns the length.
    pub(crate) fn rewind(&mut self) -> Result<u64, SmeshError> {
        self.tmp
            .rewind()
            .map_err(|e| SmeshError::io(&self.output, "read back its scratch data", e))
    }

    /// The rewound data, for reading.
    pub(crate) fn reader(&mut self) -> &mut File {
        self.tmp.out.get_mut()
    }

    /// Removes the file once the output is complete.
    pub(crate) fn discard(self) {
        self.tmp.discard();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rename put a regular file in place of a FIFO (or a device) and of a link itself;
    /// now both are refused before any file is made.
    #[cfg(unix)]
    #[test]
    fn outputs_refuse_a_fifo_and_a_link() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("f.sma");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let err = AtomicFile::create(&fifo).err().unwrap().to_string();
        assert!(
            err.contains("is a FIFO, not a file; give a file path"),
            "{err}"
        );
        std::fs::write(dir.path().join("t.sma"), b"old").unwrap();
        let link = dir.path().join("l.sma");
        std::os::unix::fs::symlink("t.sma", &link).unwrap();
        let err = AtomicFile::create(&link).err().unwrap().to_string();
        assert!(
            err.contains("l.sma: it is a link (to t.sma); give the file's own path"),
            "{err}"
        );
        assert_eq!(std::fs::read(dir.path().join("t.sma")).unwrap(), b"old");
        assert!(link.symlink_metadata().unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
        // A link among the folders is the kernel's to follow.
        let sub = dir.path().join("sub");
        std::fs::create_dir(&sub).unwrap();
        std::os::unix::fs::symlink("sub", dir.path().join("via")).unwrap();
        let mut f = AtomicFile::create(&dir.path().join("via/n.sma")).unwrap();
        f.write_all(b"new").unwrap();
        f.complete().unwrap();
        f.persist().unwrap();
        assert_eq!(std::fs::read(sub.join("n.sma")).unwrap(), b"new");
    }

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
        f.complete().unwrap();
        f.persist().unwrap();
        assert_eq!(mode(&out), mode(&plain));
    }
}
