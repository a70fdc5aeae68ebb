//! Output path checks done before a run starts, so a bad path fails in milliseconds, not after
//! an hour of extraction.

use std::fs::{File, OpenOptions, TryLockError};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::error::RunError;

/// Ok when the file format is known and its folder exists and is writable (or can be created).
pub fn check_output_path(path: &Path) -> Result<(), String> {
    isostream_smesh::Format::from_path(path).map_err(|e| e.to_string())?;
    if path.is_dir() {
        return Err(format!(
            "{} is a folder; give a file name inside it, such as {}",
            path.display(),
            path.join("mesh.smb").display()
        ));
    }
    // A device, FIFO or socket there would be replaced by the finished file's rename.
    isostream_smesh::check_replaceable(path).map_err(|e| e.to_string())?;
    // The run summary is written (and an earlier one removed) after the whole job: a folder in
    // its place failed the run only then.
    let summary = crate::summary_path(path);
    if summary.is_dir() {
        return Err(format!(
            "{}: its run summary {} is a folder; move that folder away or choose another output name",
            path.display(),
            summary.display()
        ));
    }
    isostream_smesh::check_replaceable(&summary).map_err(|e| e.to_string())?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // The closest existing ancestor must be a folder: `a.txt/out.smb` can never be created.
    if let Some(file) = dir.ancestors().find(|d| d.exists() && !d.is_dir()) {
        return Err(format!(
            "{}: {} is a file, not a folder; choose another output folder",
            path.display(),
            file.display()
        ));
    }
    // A missing folder is created at run time; what must be writable is its closest existing
    // ancestor. Probed the way the run writes, by making a file there, whether or not the
    // folder exists: its mode bits said nothing of root, a read-only mount or an ACL, and the
    // ancestor of a missing folder was not probed at all (`validate` passed an output the run
    // then could not create the folder of).
    let existing = dir
        .ancestors()
        .find(|d| d.is_dir())
        .unwrap_or(Path::new("."));
    probe_writable(existing).map_err(|e| {
        let missing = match existing == dir {
            true => String::new(),
            false => format!(", so {} cannot be created", dir.display()),
        };
        format!(
            "{}: folder {} is not writable{missing} ({e}); choose another output folder",
            path.display(),
            existing.display()
        )
    })
}

/// Whether a file can be made in `dir`. The file has no name (Linux's `O_TMPFILE`; elsewhere,
/// or where the file system lacks it, one removed as soon as it is made): a named probe, made
/// then removed, was left behind as `.tmpXXXXXX` by a `kill -9` between the two, which nothing
/// reports or removes.
fn probe_writable(dir: &Path) -> std::io::Result<()> {
    tempfile::tempfile_in(dir).map(drop)
}

/// Whether `a` and `b` name one existing file (by their canonical paths: links and `..` seen
/// through); a path that does not exist is no other file.
pub fn one_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Creates the output's folder when it does not exist yet.
pub fn create_output_dir(path: &Path) -> std::io::Result<()> {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => std::fs::create_dir_all(d),
        _ => Ok(()),
    }
}

/// The folder `path` is in ("." for a bare file name).
fn dir_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Temporary files that an interrupted run writing `output` may have left next to it (a killed
/// process cannot remove them): `.NAME.XXXXXX.tmp` (the mesh and its scratch files, see
/// `smesh::output_builder`), `.NAME.run.json.XXXXXX.tmp` (the run summary) and
/// `.NAME.ckpt.XXXXXX.tmp` (a checkpoint being written). Files the output's checkpoint refers to
/// are not stale: `--resume` needs them. Sorted; empty when the folder is unreadable.
pub fn stale_temp_files(output: &Path) -> Vec<PathBuf> {
    let Some(name) = output.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Vec::new();
    };
    let prefix = format!(".{name}.");
    let Ok(entries) = std::fs::read_dir(dir_of(output)) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .filter(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            let Some(mid) = n
                .strip_prefix(&prefix)
                .and_then(|rest| rest.strip_suffix(".tmp"))
            else {
                return false;
            };
            let mid = mid
                .strip_prefix("run.json.")
                .or_else(|| mid.strip_prefix("ckpt."))
                .unwrap_or(mid);
            mid.len() == 6 && mid.chars().all(|c| c.is_ascii_alphanumeric())
        })
        .map(|e| e.path())
        .collect();
    let kept = crate::checkpoint::referenced_files(output);
    found.retain(|p| !kept.iter().any(|k| same_path(k, p)));
    found.sort();
    found
}

/// Whether two paths name the same file (a checkpoint may hold a relative path).
fn same_path(a: &Path, b: &Path) -> bool {
    a == b
        || matches!(
            (std::fs::canonicalize(a), std::fs::canonicalize(b)),
            (Ok(x), Ok(y)) if x == y
        )
}

/// The lock file of an output: `.NAME.lock` next to it.
pub fn lock_path(output: &Path) -> PathBuf {
    let name = output.file_name().unwrap_or_default().to_string_lossy();
    dir_of(output).join(format!(".{name}.lock"))
}

/// An advisory lock on an output, held for the whole run so that two jobs never write the same
/// file (nor take each other's temporary files for stale ones). Dropping it removes the lock file
/// and releases the lock.
#[derive(Debug)]
pub struct OutputLock {
    path: PathBuf,
    _file: File,
}

/// Takes the output's lock (creating the output's folder if needed); `RunError::Locked` when
/// another process holds it (`validate`'s probe, holding it shared for an instant, is waited
/// out), `RunError::OutputFolder` when the folder cannot be created or written (the first file
/// a run makes there is its lock).
pub fn lock_output(output: &Path) -> Result<OutputLock, RunError> {
    let lock = lock_path(output);
    let fail = |what: &'static str, fix: &'static str| {
        let lock = lock.clone();
        move |e: std::io::Error| match unusable(&e) {
            true => RunError::OutputFolder {
                output: output.to_path_buf(),
                folder: dir_of(output).to_path_buf(),
                what,
                fix,
                source: e,
            },
            false => RunError::Lock {
                output: output.to_path_buf(),
                lock: lock.clone(),
                reason: e.to_string(),
            },
        }
    };
    create_output_dir(output).map_err(fail("create its folder", "create it writable"))?;
    // A lock file unlinked by its previous holder between our open and our lock would be a lock
    // nobody else sees: lock, then check the path still names the file we locked.
    for _ in 0..8 {
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&lock)
            .map_err(fail("write in its folder", WRITABLE))?;
        match lock_past_probes(&file) {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                return Err(RunError::Locked {
                    output: output.to_path_buf(),
                    lock,
                });
            }
            Err(TryLockError::Error(e)) => {
                return Err(fail("lock a file in its folder", WRITABLE)(e));
            }
        }
        if same_file(&file, &lock) {
            return Ok(OutputLock {
                path: lock,
                _file: file,
            });
        }
    }
    Err(fail("lock a file in its folder", WRITABLE)(
        std::io::Error::other("the lock file keeps being replaced"),
    ))
}

/// How long a run waits for probes of its output's lock to let go: each holds it shared for an
/// instant ([`output_in_use`]), and a run refused in that instant was refused as if another job
/// wrote the output.
const PROBE_WAIT: Duration = Duration::from_secs(1);

/// Locks `file` exclusively. While only shared holders (probes) hold it, tries again every
/// millisecond for up to [`PROBE_WAIT`]; an exclusive holder (a run) is `WouldBlock` at once.
fn lock_past_probes(file: &File) -> Result<(), TryLockError> {
    let deadline = Instant::now() + PROBE_WAIT;
    loop {
        match file.try_lock() {
            Err(TryLockError::WouldBlock) => {}
            taken => return taken,
        }
        // Taken shared as well, the holders are probes; under a run's lock it would block.
        file.try_lock_shared()?;
        file.unlock().map_err(TryLockError::Error)?;
        if Instant::now() >= deadline {
            return Err(TryLockError::WouldBlock);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// The fix of an output folder that cannot be written.
const WRITABLE: &str = "make it writable";

/// Whether an error on the output's folder means that the path cannot be used, whoever runs
/// the job again (fix the job or the folder: exit 2), rather than a failure of this run (a full
/// or failing disk: exit 1).
fn unusable(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        PermissionDenied | ReadOnlyFilesystem | NotADirectory | NotFound | AlreadyExists
    )
}

/// The lock file of `output` when a live process holds it (a run or a conversion writing that
/// output), found by taking it shared for an instant; `None` when it is free or missing. A run
/// starting in that instant waits it out ([`lock_output`]), and it is not held longer.
pub fn output_in_use(output: &Path) -> Option<PathBuf> {
    let lock = lock_path(output);
    // Opened for reading, never created: a run removes it when it ends.
    let file = File::open(&lock).ok()?;
    match file.try_lock_shared() {
        Err(TryLockError::WouldBlock) => Some(lock),
        // Free (a killed run's file, or one being removed): released as `file` closes.
        _ => None,
    }
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_file: &File, path: &Path) -> bool {
    path.exists()
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Unlink while still holding the lock; the file closes (unlocks) right after.
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stale_files_match_the_temp_name_pattern_only() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("m.smb");
        for n in [
            ".m.smb.abC123.tmp",
            ".m.smb.run.json.x1y2z3.tmp",
            ".m.smb.toolong1.tmp",
            ".m.smbx.abc123.tmp",
            ".m.smb.lock",
            "m.smb",
        ] {
            std::fs::write(dir.path().join(n), b"").unwrap();
        }
        let names: Vec<String> = stale_temp_files(&out)
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, [".m.smb.abC123.tmp", ".m.smb.run.json.x1y2z3.tmp"]);
    }

    /// A run starting while `validate` probes the output (`output_in_use` holds its lock shared
    /// for an instant) waits the probe out instead of being refused as another job: here a
    /// probe held 50 ms. A run holding the lock is still refused at once.
    #[test]
    fn a_probe_of_the_lock_never_refuses_a_run() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("m.smb");
        std::fs::write(lock_path(&out), b"").unwrap();
        let probe = File::open(lock_path(&out)).unwrap();
        probe.try_lock_shared().unwrap();
        let release = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(50));
            drop(probe);
        });
        let run = lock_output(&out).unwrap();
        release.join().unwrap();
        assert_eq!(output_in_use(&out), Some(lock_path(&out)));
        let t = Instant::now();
        assert!(matches!(lock_output(&out), Err(RunError::Locked { .. })));
        assert!(
            t.elapsed() < Duration::from_millis(500),
            "{:?}",
            t.elapsed()
        );
        drop(run);
        assert_eq!(output_in_use(&out), None);
    }

    /// `validate` probing in a loop while runs start and end never makes one refuse.
    #[test]
    fn runs_start_while_validate_probes() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("m.smb");
        let done = std::sync::atomic::AtomicBool::new(false);
        let refused = std::thread::scope(|s| {
            s.spawn(|| {
                while !done.load(std::sync::atomic::Ordering::Relaxed) {
                    let _ = output_in_use(&out);
                }
            });
            let refused = (0..2000).filter(|_| lock_output(&out).is_err()).count();
            done.store(true, std::sync::atomic::Ordering::Relaxed);
            refused
        });
        assert_eq!(refused, 0, "runs refused of 2000");
    }

    #[test]
    fn a_second_lock_is_refused_and_the_file_goes_away() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("sub/m.smb");
        let first = lock_output(&out).unwrap();
        let err = lock_output(&out).unwrap_err().to_string();
        assert!(err.contains("another isostream job"), "{err}");
        drop(first);
        assert!(!lock_path(&out).exists());
        drop(lock_output(&out).unwrap());
    }
}
