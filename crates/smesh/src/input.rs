//! The one check every mesh reader makes before it opens its input.

use std::path::Path;

use crate::SmeshError;

/// Refuses an input that is not a regular file, before anything opens it: a FIFO blocks
/// `open` until a writer comes (deaf to Ctrl-C and SIGTERM, so `convert` held its output's lock
/// until `kill -9`), and a device reads as endless bytes (`/dev/zero` was "empty (0 bytes)" by
/// its size). A missing file is left to `open`, which names it in its own words.
pub(crate) fn regular_file(path: &Path) -> Result<(), SmeshError> {
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(());
    };
    if meta.is_file() {
        return Ok(());
    }
    Err(SmeshError::Unsupported {
        path: path.to_path_buf(),
        message: format!(
            "expected a regular file, found {}; copy the mesh to a file first",
            kind(&meta)
        ),
    })
}

#[cfg(unix)]
fn kind(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
fn kind(meta: &std::fs::Metadata) -> &'static str {
    if meta.is_dir() {
        "a folder"
    } else {
        "a special file"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_files_and_missing_ones_pass_others_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.smb");
        std::fs::write(&file, b"x").unwrap();
        regular_file(&file).unwrap();
        regular_file(&dir.path().join("missing.smb")).unwrap();
        let e = regular_file(dir.path()).unwrap_err().to_string();
        assert!(
            e.ends_with("expected a regular file, found a folder; copy the mesh to a file first"),
            "{e}"
        );
        #[cfg(unix)]
        {
            let e = regular_file(Path::new("/dev/zero"))
                .unwrap_err()
                .to_string();
            assert!(e.contains("found a character device"), "{e}");
        }
    }
}
