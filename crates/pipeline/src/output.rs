//! Output path checks done before a run starts, so a bad path fails in milliseconds, not after
//! an hour of extraction.

use std::path::Path;

/// Ok when the file format is known and its folder exists and is writable.
pub fn check_output_path(path: &Path) -> Result<(), String> {
    isostream_smesh::Format::from_path(path).map_err(|e| e.to_string())?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(format!(
            "{}: folder {} does not exist; create it or change the path",
            path.display(),
            dir.display()
        ));
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
