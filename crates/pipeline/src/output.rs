//! Output path checks done before a run starts, so a bad path fails in milliseconds, not after
//! an hour of extraction.

use std::path::Path;

/// Ok when the file format is known and its folder exists and is writable (or can be created).
pub fn check_output_path(path: &Path) -> Result<(), String> {
    isostream_smesh::Format::from_path(path).map_err(|e| e.to_string())?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // A missing folder is created at run time; what must be writable is its closest existing
    // ancestor.
    let existing = dir
        .ancestors()
        .find(|d| d.is_dir())
        .unwrap_or(Path::new("."));
    if existing
        .metadata()
        .is_ok_and(|m| m.permissions().readonly())
    {
        return Err(format!(
            "{}: folder {} is read-only; choose another output folder",
            path.display(),
            existing.display()
        ));
    }
    if existing != dir {
        return Ok(());
    }
    // Probe writability the way the writer will write: a temporary file in that folder.
    tempfile::NamedTempFile::new_in(dir).map(drop).map_err(|e| {
        format!(
            "{}: folder {} is not writable ({e}); choose another output folder",
            path.display(),
            dir.display()
        )
    })
}

/// Creates the output's folder when it does not exist yet.
pub fn create_output_dir(path: &Path) -> std::io::Result<()> {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => std::fs::create_dir_all(d),
        _ => Ok(()),
    }
}
