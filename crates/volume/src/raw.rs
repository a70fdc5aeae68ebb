//! Headerless (or fixed-header) binary volumes, memory-mapped.
//!
//! Memory mapping lets the kernel do read-ahead and keeps our copy to one slice of f32; releasing
//! pages behind the sweep front keeps resident memory flat however large the file is. The same
//! reader serves every format whose payload is an uncompressed block at a known offset (NRRD raw,
//! VTK legacy binary, NIfTI `.nii`).
#![allow(unsafe_code)]

use crate::dtype::{Scale, decode, decoded_range};
use crate::grid::dims_text;
use crate::source::check_request;
use crate::{Dtype, Endian, Grid, Orientation, VolumeError, VolumeSource};
use memmap2::Mmap;
use std::fs::File;
use std::io::{BufRead, Read};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Everything needed to read a headerless binary volume.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RawSpec {
    pub path: PathBuf,
    pub dims: [u64; 3],
    pub dtype: Dtype,
    #[serde(default)]
    pub endian: Endian,
    pub spacing: [f64; 3],
    pub origin: [f64; 3],
    /// Bytes to skip before the first voxel.
    #[serde(default)]
    pub header_bytes: u64,
}

/// Where the voxels of an already-parsed container sit: used by the format readers, which word
/// their own hints and may tolerate bytes after the payload (VTK legacy files carry more arrays).
pub(crate) struct Payload<'a> {
    pub path: &'a Path,
    pub grid: Grid,
    pub dtype: Dtype,
    pub endian: Endian,
    pub offset: u64,
    pub trailing_ok: bool,
    pub hint: &'static str,
    /// What the header's axis directions say that the grid dropped.
    pub orientation: Orientation,
}

/// A memory-mapped raw volume.
pub struct RawVolume {
    path: PathBuf,
    grid: Grid,
    dtype: Dtype,
    endian: Endian,
    offset: usize,
    slice_bytes: usize,
    map: Mmap,
    /// The mapped file, to check its size again before touching a slice's pages: a file
    /// truncated while mapped would otherwise kill the process with SIGBUS.
    file: File,
    /// Bytes at the start of the map already handed back to the kernel.
    released: usize,
    orientation: Orientation,
    /// Voxels saturated by the reads so far (`VolumeSource::saturated_voxels`).
    saturated: u64,
    /// The header's scaling (NIfTI), applied as the voxels are decoded.
    scale: Option<Scale>,
}

impl RawVolume {
    /// Opens and validates `spec`: the file must exist and hold exactly
    /// `header_bytes + product(dims) * dtype size` bytes.
    pub fn open(spec: &RawSpec) -> Result<Self, VolumeError> {
        let name = spec.path.display().to_string();
        let grid =
            Grid::new(spec.dims, spec.spacing, spec.origin).map_err(|e| e.in_origin(&name))?;
        Self::open_payload(Payload {
            path: &spec.path,
            grid,
            dtype: spec.dtype,
            endian: spec.endian,
            offset: spec.header_bytes,
            trailing_ok: false,
            hint: "check [input] dims, dtype and header_bytes",
            orientation: Orientation::Aligned,
        })
    }

    pub(crate) fn open_payload(p: Payload<'_>) -> Result<Self, VolumeError> {
        let name = p.path.display().to_string();
        let expected = checked_payload(p.path, p.grid.dims, p.dtype, p.offset, "the dims")?;
        let file = File::open(p.path).map_err(|e| VolumeError::io(p.path, "open", e))?;
        let actual = file
            .metadata()
            .map_err(|e| VolumeError::io(p.path, "read its size", e))?
            .len();
        if actual < expected || (actual > expected && !p.trailing_ok) {
            return Err(VolumeError::SizeMismatch {
                file: name,
                actual,
                expected,
                dims: dims_text(p.grid.dims),
                dtype: p.dtype.name(),
                header_bytes: p.offset,
                hint: p.hint,
            });
        }
        // SAFETY: the map is read-only and private to this struct. As with any file mapping, a
        // process truncating the file while we read would fault (SIGBUS); `read_slice` checks
        // the file's size before touching each slice, which leaves only a truncation racing that
        // check.
        let map = unsafe { Mmap::map(&file) }.map_err(|e| VolumeError::io(p.path, "map", e))?;
        let too_big = || VolumeError::Grid {
            origin: name.clone(),
            problem: "the volume does not fit this platform's address space; use a 64-bit build"
                .to_string(),
        };
        let slice_bytes = p
            .grid
            .slice_len()
            .checked_mul(p.dtype.size_bytes())
            .ok_or_else(too_big)?;
        Ok(RawVolume {
            path: p.path.to_path_buf(),
            grid: p.grid,
            dtype: p.dtype,
            endian: p.endian,
            offset: usize::try_from(p.offset).map_err(|_| too_big())?,
            slice_bytes,
            map,
            file,
            released: 0,
            orientation: p.orientation,
            saturated: 0,
            scale: None,
        })
    }

    /// Reads the voxels through the header's scaling, if it has one.
    pub(crate) fn with_scale(mut self, scale: Option<Scale>) -> Self {
        self.scale = scale;
        self
    }

    /// Tells the kernel the bytes before slice `keep_from` will not be read again, so resident
    /// memory tracks the sweep front instead of the file size.
    fn release_before(&mut self, keep_from: u64) {
        let end = (keep_from as usize)
            .saturating_mul(self.slice_bytes)
            .saturating_add(self.offset);
        self.released = drop_pages(&self.map, self.released, end);
    }
}

/// The error for a mapped file found shorter than `need` bytes at `at` (it had `opened` when
/// mapped, `now` now): reading on would touch pages past its end, which is SIGBUS.
fn truncated(path: &Path, at: String, need: u64, opened: usize, now: u64) -> VolumeError {
    VolumeError::Format {
        file: path.display().to_string(),
        at,
        expected: format!("at least {need} bytes (the file had {opened} when opened)"),
        found: format!(
            "{now} bytes: the file was truncated while being read; rerun on a complete file"
        ),
    }
}

/// The page size `madvise` works in.
const PAGE: usize = 4096;

/// Hands the whole pages of `map` between byte `from` (page-aligned, what an earlier call
/// returned) and byte `to` back to the kernel; returns the new page-aligned start. Only whole
/// pages go (madvise rounds), and a re-read simply faults a page back in from the file.
fn drop_pages(map: &Mmap, from: usize, to: usize) -> usize {
    let end = to.min(map.len()) / PAGE * PAGE;
    if end <= from {
        return from;
    }
    #[cfg(target_os = "linux")]
    {
        // SAFETY: MADV_DONTNEED on a read-only MAP_SHARED file mapping (what `Mmap::map`
        // creates) only drops cached pages; later reads repopulate them from the file, so no
        // value observed through the map changes. The caller holds no borrow into the range.
        let _ = unsafe {
            map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, from, end - from)
        };
    }
    end
}

/// A whole file mapped read-only, with the open file beside it: the VTI reader parses its
/// header from the map and reads payload streams through the file ([`RangeReader`]) at
/// computed offsets. Sharing one between reopened streams needs the `Arc`.
pub(crate) struct MappedFile {
    map: Mmap,
    file: File,
    path: PathBuf,
}

impl std::ops::Deref for MappedFile {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        &self.map
    }
}

/// Maps the file at `path` (see [`MappedFile`]).
pub(crate) fn map_file(path: &Path) -> Result<Arc<MappedFile>, VolumeError> {
    let file = File::open(path).map_err(|e| VolumeError::io(path, "open", e))?;
    // SAFETY: as in `RawVolume::open_payload`: read-only map of an input treated as immutable.
    // Only the header is parsed from the map, when the volume is opened; payload streams read
    // through the file (`RangeReader`), so a truncation during the run cannot fault here.
    let map = unsafe { Mmap::map(&file) }.map_err(|e| VolumeError::io(path, "map", e))?;
    Ok(Arc::new(MappedFile {
        map,
        file,
        path: path.to_path_buf(),
    }))
}

/// A `BufRead` over a byte range of a mapped file that reads through the file, not the map:
/// streams start anywhere in the file, a window of [`RangeReader::WINDOW`] bytes at a time.
///
/// Touching a page of a map past the end of a file truncated meanwhile is SIGBUS, and no
/// check before reading closes that race: the zlib streams of a compressed VTI decode a window
/// over seconds, so a file cut short during the run killed the process (and the service with
/// every job it ran) in 11 of 11 trials, where a check of the size before each window (the
/// forty-eighth session's fix) had caught only cuts landing between windows. A read of the
/// file (`pread`) into an owned window meets a short file as a short read, which is reported
/// as the truncation it is, naming the file. The window is read once and dropped, so nothing
/// of the file stays resident (a map read front to back kept every page of bonsai's 3.3 MB
/// file resident until its pages were handed back).
pub(crate) struct RangeReader {
    file: Arc<MappedFile>,
    /// File offset of `window[0]`.
    at: usize,
    window: Vec<u8>,
    /// Bytes of `window` consumed.
    used: usize,
}

impl RangeReader {
    /// Bytes read at a time.
    const WINDOW: usize = 1 << 20;

    /// Reads from `pos` to the end the file had when mapped (an out-of-range `pos` reads
    /// nothing).
    pub(crate) fn new(file: Arc<MappedFile>, pos: usize) -> Self {
        RangeReader {
            at: pos.min(file.len()),
            file,
            window: Vec::new(),
            used: 0,
        }
    }

    /// The next window. What a file cut short still holds is handed out first; the read after
    /// it finds nothing and says the file was truncated.
    fn refill(&mut self) -> std::io::Result<()> {
        self.at += self.window.len();
        self.used = 0;
        let want = Self::WINDOW.min(self.file.len() - self.at);
        self.window.resize(want, 0);
        let mut got = 0;
        while got < want {
            match read_at(
                &self.file.file,
                &mut self.window[got..],
                (self.at + got) as u64,
            ) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    // Nothing of the old window may pass for bytes at the new offset.
                    self.window.clear();
                    return Err(e);
                }
            }
        }
        self.window.truncate(got);
        if got == 0 && want > 0 {
            let now = self.file.file.metadata()?.len();
            return Err(std::io::Error::other(truncated(
                &self.file.path,
                format!("byte {}", self.at),
                (self.at + want) as u64,
                self.file.len(),
                now,
            )));
        }
        Ok(())
    }
}

/// Reads into `buf` from `offset` of `file`, wherever the file's cursor is (the file is shared
/// by every stream of it, each at its own offset).
#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(file, buf, offset)
}

#[cfg(windows)]
fn read_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<usize> {
    std::os::windows::fs::FileExt::seek_read(file, buf, offset)
}

impl Read for RangeReader {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let window = self.fill_buf()?;
        let n = window.len().min(buf.len());
        buf[..n].copy_from_slice(&window[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl BufRead for RangeReader {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.used == self.window.len() && self.at + self.window.len() < self.file.len() {
            self.refill()?;
        }
        Ok(&self.window[self.used..])
    }
    fn consume(&mut self, amt: usize) {
        self.used = (self.used + amt).min(self.window.len());
    }
}

/// Payload size in bytes, or None on overflow.
pub(crate) fn payload_bytes(dims: [u64; 3], dtype: Dtype) -> Option<u64> {
    dims[0]
        .checked_mul(dims[1])?
        .checked_mul(dims[2])?
        .checked_mul(dtype.size_bytes() as u64)
}

/// [`payload_bytes`] plus `offset`, or the error naming `path` and the header field to `check`.
pub(crate) fn checked_payload(
    path: &Path,
    dims: [u64; 3],
    dtype: Dtype,
    offset: u64,
    check: &str,
) -> Result<u64, VolumeError> {
    payload_bytes(dims, dtype)
        .and_then(|b| b.checked_add(offset))
        .ok_or_else(|| VolumeError::Grid {
            origin: path.display().to_string(),
            problem: format!(
                "dims {} of {dtype} need more than 2^64 bytes; check {check}",
                dims_text(dims)
            ),
        })
}

impl VolumeSource for RawVolume {
    fn grid(&self) -> Grid {
        self.grid
    }

    fn describe(&self) -> String {
        self.path.display().to_string()
    }

    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        check_request(self, z, out)?;
        // In range: open_payload checked the file holds offset + dims[2] slices. The file may
        // have shrunk since (another process): touching pages past its end is SIGBUS, so check
        // its size first (one fstat per slice).
        let start = self.offset + z as usize * self.slice_bytes;
        let now = self
            .file
            .metadata()
            .map_err(|e| VolumeError::io(&self.path, "read its size", e))?
            .len();
        let need = (start + self.slice_bytes) as u64;
        if now < need {
            return Err(truncated(
                &self.path,
                format!("slice {z}"),
                need,
                self.map.len(),
                now,
            ));
        }
        let bytes = &self.map[start..start + self.slice_bytes];
        self.saturated += match &self.scale {
            None => decode(self.dtype, self.endian, bytes, out),
            Some(scale) => scale.decode(self.dtype, self.endian, bytes, out, z)?,
        };
        self.release_before(z.saturating_sub(1));
        Ok(())
    }

    fn dtype(&self) -> Option<Dtype> {
        Some(self.dtype)
    }

    fn stored_range(&self) -> Option<(f32, f32)> {
        decoded_range(self.dtype, self.scale.as_ref())
    }

    fn saturated_voxels(&self) -> u64 {
        self.saturated
    }

    fn orientation(&self) -> Orientation {
        self.orientation
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dtype::tests::{ALL, encode, sample_values};
    use std::io::Write;

    fn spec(path: &Path, dims: [u64; 3], dtype: Dtype, endian: Endian, header: u64) -> RawSpec {
        RawSpec {
            path: path.to_path_buf(),
            dims,
            dtype,
            endian,
            spacing: [1.0, 2.0, 3.0],
            origin: [0.5, 0.0, 0.0],
            header_bytes: header,
        }
    }

    fn write(bytes: &[u8]) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().unwrap();
        f.write_all(bytes).unwrap();
        f.flush().unwrap();
        f
    }

    /// Finite f64 values beyond f32's range read as ±f32::MAX and are counted, each read.
    #[test]
    fn f64_beyond_f32_is_saturated_and_counted() {
        let (values, want, n) = crate::testutil::beyond_f32();
        for endian in [Endian::Little, Endian::Big] {
            let f = write(&encode(Dtype::F64, endian, &values));
            let mut v = RawVolume::open(&spec(f.path(), [3, 2, 4], Dtype::F64, endian, 0)).unwrap();
            let mut all = Vec::new();
            let mut out = vec![0.0f32; 6];
            for z in 0..4u64 {
                v.read_slice(z, &mut out).unwrap();
                all.extend_from_slice(&out);
            }
            assert!(crate::testutil::same_values(&all, &want), "{all:?}");
            assert_eq!(v.saturated_voxels(), n, "{endian:?}");
            // Slice 0 holds two: read again, counted again.
            v.read_slice(0, &mut out).unwrap();
            assert_eq!(v.saturated_voxels(), n + 2);
        }
    }

    #[test]
    fn every_dtype_and_endian_round_trips_with_header() {
        let dims = [3, 2, 4];
        for dtype in ALL {
            for endian in [Endian::Little, Endian::Big] {
                for header in [0u64, 7] {
                    let values = sample_values(dtype, 24);
                    let mut bytes = vec![0xAB; header as usize];
                    bytes.extend(encode(dtype, endian, &values));
                    let f = write(&bytes);
                    let mut v =
                        RawVolume::open(&spec(f.path(), dims, dtype, endian, header)).unwrap();
                    assert_eq!(v.grid().spacing, [1.0, 2.0, 3.0]);
                    let mut out = vec![0.0f32; 6];
                    for z in 0..4u64 {
                        v.read_slice(z, &mut out).unwrap();
                        let want: Vec<f32> = values[z as usize * 6..][..6]
                            .iter()
                            .map(|&x| x as f32)
                            .collect();
                        assert_eq!(out, want, "{dtype} {endian:?} header {header} z {z}");
                    }
                }
            }
        }
    }

    /// A file truncated after it was mapped: an error naming the slice, not SIGBUS.
    #[test]
    fn truncated_while_mapped_is_an_error() {
        let f = write(&[7u8; 4 * 4 * 4]);
        let mut v =
            RawVolume::open(&spec(f.path(), [4, 4, 4], Dtype::U8, Endian::Little, 0)).unwrap();
        let mut out = vec![0.0f32; 16];
        v.read_slice(0, &mut out).unwrap();
        f.as_file().set_len(20).unwrap();
        let e = v.read_slice(2, &mut out).unwrap_err().to_string();
        assert!(e.contains("slice 2") && e.contains("truncated"), "{e}");
    }

    #[test]
    fn re_reading_a_released_slice_still_works() {
        // Slices of 64 KiB so release_before really drops pages.
        let dims = [256, 256, 4];
        let bytes: Vec<u8> = (0..256 * 256 * 4).map(|i| (i / 65536) as u8 + 1).collect();
        let f = write(&bytes);
        let mut v = RawVolume::open(&spec(f.path(), dims, Dtype::U8, Endian::Little, 0)).unwrap();
        let mut out = vec![0.0f32; 65536];
        for z in 0..4 {
            v.read_slice(z, &mut out).unwrap();
            assert!(out.iter().all(|&x| x == z as f32 + 1.0));
        }
        // Slices 0 and 1 are behind the front after reading slice 3.
        assert_eq!(v.released, 2 * 65536);
        v.read_slice(0, &mut out).unwrap();
        assert!(out.iter().all(|&x| x == 1.0));
    }

    /// A range read front to back through `Read`, and the whole file through `BufRead` by a
    /// second reader of the same file, in windows and chunks that do not divide each other.
    #[test]
    fn a_range_reader_reads_its_range_whole() {
        let len = 6 * RangeReader::WINDOW + 12_345;
        let bytes: Vec<u8> = (0..len).map(|i| (i % 251) as u8).collect();
        let f = write(&bytes);
        let map = map_file(f.path()).unwrap();
        let mut reader = RangeReader::new(map.clone(), 100);
        let mut seen = Vec::new();
        let mut chunk = vec![0u8; 70_000];
        loop {
            let n = reader.read(&mut chunk).unwrap();
            if n == 0 {
                break;
            }
            seen.extend_from_slice(&chunk[..n]);
        }
        assert_eq!(seen, bytes[100..]);
        let mut again = RangeReader::new(map, 0);
        let mut all = Vec::new();
        while let Ok(buf) = again.fill_buf() {
            if buf.is_empty() {
                break;
            }
            let n = buf.len().min(4097);
            all.extend_from_slice(&buf[..n]);
            again.consume(n);
        }
        assert_eq!(all, bytes);
    }

    /// The file cut inside the next window: the part it still holds is handed out (a short
    /// read), then the truncation is reported.
    #[test]
    fn a_short_window_is_handed_out_before_the_truncation() {
        let w = RangeReader::WINDOW;
        let bytes: Vec<u8> = (0..3 * w).map(|i| (i % 239) as u8).collect();
        let f = write(&bytes);
        let mut reader = RangeReader::new(map_file(f.path()).unwrap(), 0);
        let mut head = vec![0u8; w];
        reader.read_exact(&mut head).unwrap();
        f.as_file().set_len((w + w / 2) as u64).unwrap();
        let mut rest = Vec::new();
        let e = reader.read_to_end(&mut rest).unwrap_err();
        assert_eq!(rest, bytes[w..w + w / 2]);
        assert!(e.to_string().contains("truncated while being read"), "{e}");
    }

    /// A mapped file truncated while a stream reads it: the stream stops at the new end and
    /// reports the truncation, naming the file, instead of faulting (SIGBUS) on a page past it.
    #[test]
    fn a_range_reader_truncated_while_reading_reports_it() {
        let len = 3 * RangeReader::WINDOW;
        let bytes: Vec<u8> = (0..len).map(|i| (i % 253) as u8).collect();
        let f = write(&bytes);
        let map = map_file(f.path()).unwrap();
        let mut reader = RangeReader::new(map, 0);
        let mut head = vec![0u8; RangeReader::WINDOW + RangeReader::WINDOW / 2];
        reader.read_exact(&mut head).unwrap();
        assert_eq!(head, bytes[..head.len()]);
        f.as_file().set_len(2 * RangeReader::WINDOW as u64).unwrap();
        let mut rest = Vec::new();
        let e = reader.read_to_end(&mut rest).unwrap_err();
        assert_eq!(
            rest,
            bytes[head.len()..2 * RangeReader::WINDOW],
            "up to the new end"
        );
        let inner = e.into_inner().unwrap().downcast::<VolumeError>().unwrap();
        let text = inner.to_string();
        assert!(
            text.starts_with(&f.path().display().to_string())
                && text.contains("truncated while being read"),
            "{text}"
        );
    }

    /// The file cut short inside the window being read: what was read is handed out, then the
    /// truncation is reported. Reading that window from the map after checking the file's size
    /// once faulted (SIGBUS) here, killing the test process: the decoder of a compressed VTI
    /// reads a window over seconds.
    #[test]
    fn a_file_cut_short_inside_the_window_being_read_is_an_error() {
        let len = 3 * RangeReader::WINDOW;
        let bytes: Vec<u8> = (0..len).map(|i| (i % 241) as u8).collect();
        let f = write(&bytes);
        let mut reader = RangeReader::new(map_file(f.path()).unwrap(), 0);
        let mut head = vec![0u8; RangeReader::WINDOW / 2];
        reader.read_exact(&mut head).unwrap();
        f.as_file().set_len(RangeReader::WINDOW as u64 / 4).unwrap();
        let mut rest = Vec::new();
        let e = reader.read_to_end(&mut rest).unwrap_err();
        assert_eq!(
            rest,
            bytes[head.len()..RangeReader::WINDOW],
            "the window read"
        );
        assert!(e.to_string().contains("truncated while being read"), "{e}");
    }

    #[test]
    fn size_mismatch_names_both_numbers() {
        let f = write(&vec![0u8; 8388607]);
        let e = RawVolume::open(&spec(
            f.path(),
            [256, 256, 128],
            Dtype::U8,
            Endian::Little,
            0,
        ))
        .err()
        .unwrap();
        let name = f.path().display();
        assert_eq!(
            e.to_string(),
            format!(
                "{name}: file is 8388607 bytes but dims 256x256x128 of u8 plus 0 header bytes need 8388608; check [input] dims, dtype and header_bytes"
            )
        );
        // Too long is as wrong as too short for a raw file.
        let f = write(&[0u8; 17]);
        assert!(matches!(
            RawVolume::open(&spec(f.path(), [2, 2, 2], Dtype::U16, Endian::Big, 0)),
            Err(VolumeError::SizeMismatch {
                actual: 17,
                expected: 16,
                ..
            })
        ));
    }

    #[test]
    fn missing_file_and_overflow() {
        let e = RawVolume::open(&spec(
            Path::new("/no/such/dir/v.raw"),
            [2, 2, 2],
            Dtype::U8,
            Endian::Little,
            0,
        ))
        .err()
        .unwrap();
        assert_eq!(
            e.to_string(),
            "/no/such/dir/v.raw: no such file; check the input path"
        );
        let e = RawVolume::open(&spec(
            Path::new("/no/v.raw"),
            [1 << 32, 1 << 32, 2],
            Dtype::F64,
            Endian::Little,
            0,
        ))
        .err()
        .unwrap();
        assert!(e.to_string().starts_with("/no/v.raw: dims"), "{e}");
        assert!(e.to_string().contains("overflow"), "{e}");
        let e = RawVolume::open(&spec(
            Path::new("/no/v.raw"),
            [1 << 21, 1 << 20, 1 << 20],
            Dtype::F64,
            Endian::Little,
            0,
        ))
        .err()
        .unwrap();
        assert_eq!(
            e.to_string(),
            "/no/v.raw: dims 2097152x1048576x1048576 of f64 need more than 2^64 bytes; check the dims"
        );
    }
}
