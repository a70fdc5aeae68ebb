//! Format detection: one entry point from a path (and job-file options) to a source.

use crate::{
    OpenOptions, RawSpec, RawVolume, VolumeError, VolumeSource, nifti, nrrd, tiff, vti, vtk, zarr,
};
use std::io::Read;
use std::path::Path;

/// Formats [`open_path`] recognises.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Raw,
    Nrrd,
    Vtk,
    Vti,
    Nifti,
    Tiff,
    Zarr,
    /// A format users try that no reader here reads (its name): refused by name rather than
    /// read as raw voxels, which asked for dims and then meshed its header as data.
    Unsupported(&'static str),
}

/// What to convert an unsupported format to: the formats read here, as the README lists them.
const SUPPORTED: &str = "NRRD, NIfTI, VTK/VTI, TIFF, Zarr, or raw with [input] dims and dtype";

/// Opens any supported volume file, choosing the reader from the extension, or else from the
/// first bytes. A `.raw` (or unrecognised) file needs `dims` and `dtype` in `opts`.
pub fn open_path(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    check_file_type(path)?;
    match detect(path)? {
        Format::Raw => open_raw(path, opts),
        Format::Nrrd => nrrd::open(path, opts),
        Format::Vtk => vtk::open(path, opts),
        Format::Vti => vti::open(path, opts),
        Format::Nifti => nifti::open(path, opts),
        Format::Tiff => tiff::open(path, opts),
        Format::Zarr => zarr::open(path, opts),
        Format::Unsupported(name) => Err(unsupported(path, name)),
    }
}

/// The one-line refusal of a format no reader here reads, with the conversion to make.
fn unsupported(path: &Path, name: &str) -> VolumeError {
    let fix = match name {
        "MetaImage" => {
            "convert it (e.g. to NRRD or NIfTI), or give a .mhd's data file (ElementDataFile) \
             as a raw path with [input] dims and dtype"
        }
        "DICOM" => "convert the series to one volume file (e.g. NIfTI with dcm2niix)",
        _ => "convert it to one of those (e.g. NRRD or NIfTI)",
    };
    let article = if name == "HDF5" { "an" } else { "a" };
    VolumeError::Format {
        file: path.display().to_string(),
        at: "input".into(),
        expected: format!("a supported volume format ({SUPPORTED})"),
        found: format!("{article} {name} file, which isostream does not read; {fix}"),
    }
}

/// Recognises by their signatures the unsupported formats a raw (or unrecognised) file could
/// be. Checked whatever `dims` and `dtype` say: a raw volume whose first bytes are exactly one
/// of these signatures is implausible, and with matching dims the header was meshed as voxels.
fn unsupported_signature(head: &[u8]) -> Option<Format> {
    if head.starts_with(b"\x89HDF\r\n\x1a\n") {
        Some(Format::Unsupported("HDF5"))
    } else if head.get(128..132) == Some(b"DICM") {
        // Part 10 files: a 128-byte preamble, then the magic.
        Some(Format::Unsupported("DICOM"))
    } else if head.starts_with(b"ObjectType") {
        // A MetaImage text header (.mhd, or a .mha with its data attached).
        Some(Format::Unsupported("MetaImage"))
    } else {
        None
    }
}

/// The first bytes of a file, enough for every signature [`detect`] looks at (DICOM's ends at
/// byte 132); fewer if the file is shorter.
fn read_head(path: &Path) -> std::io::Result<Vec<u8>> {
    let mut head = Vec::with_capacity(132);
    std::fs::File::open(path)?
        .take(132)
        .read_to_end(&mut head)?;
    Ok(head)
}

/// Refuses what is neither a regular file nor a folder (Zarr, TIFF stacks) before anything opens
/// it: opening a FIFO blocks until a writer appears, and a device or socket is no volume.
pub fn check_file_type(path: &Path) -> Result<(), VolumeError> {
    // A missing file is reported by the reader, in its own words (a raw file needs dims first).
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(());
    };
    if meta.is_file() || meta.is_dir() {
        return Ok(());
    }
    let kind = file_kind(&meta);
    Err(VolumeError::Format {
        file: path.display().to_string(),
        at: "input".into(),
        expected: "a regular file (or a Zarr / TIFF folder)".into(),
        found: format!("{kind}; copy the data to a file first"),
    })
}

#[cfg(unix)]
fn file_kind(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_fifo() {
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
fn file_kind(_meta: &std::fs::Metadata) -> &'static str {
    "a special file"
}

fn detect(path: &Path) -> Result<Format, VolumeError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let by_ext = [
        (".nrrd", Format::Nrrd),
        (".nhdr", Format::Nrrd),
        (".raw", Format::Raw),
        (".vtk", Format::Vtk),
        (".vti", Format::Vti),
        (".nii", Format::Nifti),
        (".nii.gz", Format::Nifti),
        (".hdr", Format::Nifti),
        (".hdr.gz", Format::Nifti),
        (".tif", Format::Tiff),
        (".tiff", Format::Tiff),
        (".h5", Format::Unsupported("HDF5")),
        (".hdf5", Format::Unsupported("HDF5")),
        (".mha", Format::Unsupported("MetaImage")),
        (".mhd", Format::Unsupported("MetaImage")),
        (".dcm", Format::Unsupported("DICOM")),
    ];
    match by_ext.iter().find(|(ext, _)| name.ends_with(ext)) {
        // A `.raw` file that cannot be opened is reported by the raw reader, which asks for
        // dims first.
        Some((_, Format::Raw)) => {
            let head = read_head(path).unwrap_or_default();
            return Ok(unsupported_signature(&head).unwrap_or(Format::Raw));
        }
        Some((_, f)) => return Ok(*f),
        None => {}
    }
    // A Zarr store is a directory with zarr.json (v3), or .zarray / .zgroup (v2), or that file.
    let zarr_files = zarr::NODE_FILES;
    if zarr_files.contains(&name.as_str()) || zarr_files[..3].iter().any(|f| path.join(f).is_file())
    {
        return Ok(Format::Zarr);
    }
    if path.is_dir() {
        return Ok(Format::Tiff);
    }
    let head = read_head(path).map_err(|e| VolumeError::io(path, "open", e))?;
    Ok(if let Some(f) = unsupported_signature(&head) {
        f
    } else if head.starts_with(b"NRRD000") {
        Format::Nrrd
    } else if head.starts_with(b"# vtk DataFile") {
        Format::Vtk
    } else if head.starts_with(b"<?xml") || head.starts_with(b"<VTKFile") {
        Format::Vti
    } else if head.starts_with(&348i32.to_le_bytes()) || head.starts_with(&348i32.to_be_bytes()) {
        Format::Nifti
    } else if [b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"]
        .iter()
        .any(|m| head.starts_with(*m))
    {
        // Classic and BigTIFF, both byte orders.
        Format::Tiff
    } else {
        Format::Raw
    })
}

fn starts_with_gzip(path: &Path) -> bool {
    let mut head = [0u8; 2];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| head == [0x1f, 0x8b])
}

fn open_raw(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_array(path, "raw")?;
    let (Some(dims), Some(dtype)) = (opts.dims, opts.dtype) else {
        // A gzip file of no known name (a pair's `.img.gz`, a `.raw.gz`) is no raw volume:
        // asking for dims would mislead.
        if starts_with_gzip(path) {
            return Err(VolumeError::Format {
                file: path.display().to_string(),
                at: "input".into(),
                expected: "a volume format (gzip is read in .nii.gz, a .hdr.gz with its .img.gz, and NRRD)".into(),
                found: "a gzip file; for a NIfTI pair give its .hdr.gz, else decompress it (gunzip) and set [input] dims and dtype".into(),
            });
        }
        return Err(VolumeError::Grid {
            origin: path.display().to_string(),
            problem: "a raw file (or one of unknown format) has no header; set [input] dims and dtype (and endian, header_bytes if needed)".to_string(),
        });
    };
    Ok(Box::new(RawVolume::open(&RawSpec {
        path: path.to_path_buf(),
        dims,
        dtype,
        endian: opts.endian.unwrap_or_default(),
        spacing: opts.spacing.unwrap_or([1.0; 3]),
        origin: opts.origin.unwrap_or([0.0; 3]),
        header_bytes: opts.header_bytes.unwrap_or(0),
    })?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Dtype;

    #[test]
    fn raw_needs_dims_and_dtype() {
        let e = open_path(Path::new("/tmp/x.raw"), &OpenOptions::default())
            .err()
            .unwrap();
        assert_eq!(
            e.to_string(),
            "/tmp/x.raw: a raw file (or one of unknown format) has no header; set [input] dims and dtype (and endian, header_bytes if needed)"
        );
    }

    #[test]
    fn gzip_of_unknown_format_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v.img.gz");
        std::fs::write(&p, crate::testutil::gzip(&[0u8; 8])).unwrap();
        let e = open_path(&p, &OpenOptions::default())
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("found a gzip file; for a NIfTI pair give its .hdr.gz") && !e.contains('\n'),
            "{e}"
        );
    }

    /// HDF5, DICOM and MetaImage files are refused by name, by extension or by signature, even
    /// with dims and dtype that fit their size (they were read as raw and their headers meshed).
    #[test]
    fn unsupported_formats_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let mut dicom = vec![0u8; 128];
        dicom.extend_from_slice(b"DICM");
        dicom.resize(136, 0);
        let mut hdf5 = b"\x89HDF\r\n\x1a\n".to_vec();
        hdf5.resize(136, 0);
        let mut mha = b"ObjectType = Image\nNDims = 3\n".to_vec();
        mha.resize(136, 0);
        let fits = OpenOptions {
            dims: Some([2, 4, 17]),
            dtype: Some(Dtype::U8),
            ..Default::default()
        };
        for (file, bytes, name, fix) in [
            ("x.h5", &hdf5, "an HDF5", "convert it to one of those"),
            ("x.raw", &hdf5, "an HDF5", "convert it to one of those"),
            ("x", &hdf5, "an HDF5", "convert it to one of those"),
            ("x.dcm", &dicom, "a DICOM", "dcm2niix"),
            ("IM0001", &dicom, "a DICOM", "dcm2niix"),
            ("x.mha", &mha, "a MetaImage", "ElementDataFile"),
            ("x.mhd", &vec![0u8; 136], "a MetaImage", "ElementDataFile"),
            ("header", &mha, "a MetaImage", "ElementDataFile"),
        ] {
            let p = dir.path().join(file);
            std::fs::write(&p, bytes).unwrap();
            for opts in [&OpenOptions::default(), &fits] {
                let e = open_path(&p, opts).err().unwrap().to_string();
                assert!(
                    e.starts_with(&format!("{}: input: expected a supported volume format (NRRD, NIfTI, VTK/VTI, TIFF, Zarr, or raw with [input] dims and dtype), found {name} file, which isostream does not read; ", p.display()))
                        && e.contains(fix)
                        && !e.contains('\n'),
                    "{file}: {e}"
                );
            }
        }
        // The signatures elsewhere in a raw file are voxels.
        let p = dir.path().join("v.raw");
        let mut bytes = vec![0u8; 136];
        bytes[1..9].copy_from_slice(b"\x89HDF\r\n\x1a\n");
        bytes[129..133].copy_from_slice(b"DICM");
        std::fs::write(&p, &bytes).unwrap();
        assert!(open_path(&p, &fits).is_ok());
    }

    #[test]
    fn raw_with_options_opens() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("v.raw");
        std::fs::write(&p, [1u8, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        let opts = OpenOptions {
            dims: Some([2, 2, 2]),
            dtype: Some(Dtype::U8),
            spacing: Some([0.5; 3]),
            ..Default::default()
        };
        let mut v = open_path(&p, &opts).unwrap();
        assert_eq!(v.grid().spacing, [0.5; 3]);
        assert_eq!(v.dtype(), Some(Dtype::U8));
        let mut out = [0.0f32; 4];
        v.read_slice(1, &mut out).unwrap();
        assert_eq!(out, [5.0, 6.0, 7.0, 8.0]);
        let named = OpenOptions {
            array: Some("a".into()),
            ..opts
        };
        assert!(open_path(&p, &named).is_err());
    }
}
