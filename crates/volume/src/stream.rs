//! Sources whose payload can only be read front to back: compressed (gzip, zlib blocks), encoded
//! (base64, ASCII numbers) or split over many files. They decode one slice at a time from a
//! `Read`, so memory stays at two slices of bytes whatever the volume size.

use crate::dtype::{Scale, decode, decoded_range};
use crate::grid::dims_text;
use crate::source::check_request;
use crate::{Dtype, Endian, Grid, Orientation, VolumeError, VolumeSource};
use std::io::{self, Read};
use std::path::{Path, PathBuf};

/// A payload stream positioned at the first voxel.
pub(crate) type Stream = Box<dyn Read + Send>;

/// Re-creates the payload stream from its start: needed only when a caller goes back more than
/// one slice, which the pipeline never does, but the trait allows.
pub(crate) type Opener = Box<dyn Fn() -> Result<Stream, VolumeError> + Send>;

/// Streams slices out of a sequential payload.
pub(crate) struct StreamVolume {
    path: PathBuf,
    /// What the payload is ("gzip NRRD payload"), for error messages.
    what: &'static str,
    grid: Grid,
    /// How the payload bytes are decoded (f64 for ASCII text) and what the file stores.
    dtype: Dtype,
    stored: Dtype,
    endian: Endian,
    open: Opener,
    /// The payload must end with the last slice (NRRD: its `sizes` describe all of it).
    exact_end: bool,
    orientation: Orientation,
    reader: Option<Stream>,
    /// Slice index the reader is positioned at.
    next_z: u64,
    /// Bytes of slices `next_z - 1` and `next_z - 2`: a caller going back to the slice before
    /// the one it just read (as a two-slice sweep may) gets it without reopening the stream.
    bytes: Vec<u8>,
    prev: Vec<u8>,
    /// Voxels saturated by the reads so far (`VolumeSource::saturated_voxels`).
    saturated: u64,
    /// The header's scaling (NIfTI), applied as the voxels are decoded.
    scale: Option<Scale>,
}

pub(crate) struct StreamSpec {
    pub path: PathBuf,
    pub what: &'static str,
    pub grid: Grid,
    pub dtype: Dtype,
    pub stored: Dtype,
    pub endian: Endian,
    pub open: Opener,
    /// Data past the last slice is an error (formats whose header describes the whole payload;
    /// not NIfTI or VTK, whose files may go on past the volume).
    pub exact_end: bool,
    /// What the header's axis directions say that the grid dropped.
    pub orientation: Orientation,
}

impl StreamVolume {
    pub(crate) fn new(spec: StreamSpec) -> Result<Self, VolumeError> {
        let slice_bytes = spec
            .grid
            .slice_len()
            .checked_mul(spec.dtype.size_bytes())
            .ok_or_else(|| VolumeError::Grid {
                origin: spec.path.display().to_string(),
                problem: format!(
                    "a slice of dims {} does not fit in memory; check the dims",
                    dims_text(spec.grid.dims)
                ),
            })?;
        // No buffer from the header's claim: the slice buffers grow as decoded bytes arrive
        // (`read_growing`), and the first slice is read now, so a tiny file claiming a huge grid
        // fails at open (validate included) after reading what it holds, instead of anyone
        // allocating gigabytes for it. The pipeline's first `read_slice(0)` reuses these bytes.
        let _ = slice_bytes;
        let mut v = StreamVolume {
            path: spec.path,
            what: spec.what,
            grid: spec.grid,
            dtype: spec.dtype,
            stored: spec.stored,
            endian: spec.endian,
            open: spec.open,
            exact_end: spec.exact_end,
            orientation: spec.orientation,
            reader: None,
            next_z: 0,
            bytes: Vec::new(),
            prev: Vec::new(),
            saturated: 0,
            scale: None,
        };
        v.advance()?;
        Ok(v)
    }

    /// Reads the voxels through the header's scaling, if it has one.
    pub(crate) fn with_scale(mut self, scale: Option<Scale>) -> Self {
        self.scale = scale;
        self
    }

    /// Reads slice `next_z` into `self.bytes`, turning I/O failures into format errors that say
    /// which slice and byte of the payload broke.
    fn advance(&mut self) -> Result<(), VolumeError> {
        let reader = match &mut self.reader {
            Some(r) => r,
            None => self.reader.insert((self.open)()?),
        };
        let z = self.next_z;
        std::mem::swap(&mut self.bytes, &mut self.prev);
        let slice_bytes = self.grid.slice_len() * self.dtype.size_bytes();
        if let Err((filled, e)) = read_growing(reader, &mut self.bytes, slice_bytes) {
            // Start over on the next request: the buffers hold a partial slice.
            self.reader = None;
            self.next_z = 0;
            let slice_len = self.grid.slice_len();
            let voxel = z
                .saturating_mul(slice_len as u64)
                .saturating_add((filled / self.dtype.size_bytes()) as u64);
            let at = format!("{} voxel {voxel} (slice {z})", self.what);
            let kind = e.kind();
            // A multi-file stream reports a missing or unreadable part as our own error.
            let e = match e.into_inner() {
                Some(inner) => match inner.downcast::<VolumeError>() {
                    Ok(ve) => return Err(*ve),
                    Err(other) => io::Error::new(kind, other),
                },
                None => io::Error::from(kind),
            };
            return Err(match kind {
                io::ErrorKind::UnexpectedEof => VolumeError::format(
                    &self.path,
                    at,
                    format!(
                        "{} voxels of {} for dims {}",
                        self.grid.voxel_count(),
                        self.stored,
                        dims_text(self.grid.dims)
                    ),
                    "end of data (truncated file?)",
                ),
                io::ErrorKind::InvalidData | io::ErrorKind::InvalidInput => {
                    VolumeError::format(&self.path, at, "valid encoded data", e.to_string())
                }
                _ => VolumeError::io(&self.path, "read", e),
            });
        }
        self.next_z += 1;
        if self.exact_end && self.next_z == self.grid.dims[2] {
            self.check_end()?;
        }
        Ok(())
    }

    /// After the last slice: the payload must be over (one byte more means the header's dims do
    /// not describe the data).
    fn check_end(&mut self) -> Result<(), VolumeError> {
        let Some(reader) = self.reader.as_mut() else {
            return Ok(());
        };
        let mut byte = [0u8; 1];
        let more = loop {
            match reader.read(&mut byte) {
                Ok(n) => break n > 0,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(VolumeError::format(
                        &self.path,
                        format!("{} after the last slice", self.what),
                        "the end of the data",
                        format!("more bytes, not decodable: {e}"),
                    ));
                }
            }
        };
        if more {
            return Err(VolumeError::format(
                &self.path,
                format!("{} after the last slice", self.what),
                format!(
                    "the end of the data for dims {} ({} voxels of {})",
                    dims_text(self.grid.dims),
                    self.grid.voxel_count(),
                    self.stored
                ),
                "more data (check the header's sizes)",
            ));
        }
        Ok(())
    }
}

/// Reads exactly `len` bytes into `buf` (replacing its contents), growing it only as the data
/// arrives (at most doubling what was read so far), so a header's claim is never allocated
/// before the stream proves it. Reports a short stream as `UnexpectedEof` and passes decoder
/// errors through, with the number of bytes read before the failure.
fn read_growing(r: &mut Stream, buf: &mut Vec<u8>, len: usize) -> Result<(), (usize, io::Error)> {
    buf.clear();
    while buf.len() < len {
        let step = (len - buf.len()).min(buf.len().max(1 << 16));
        let before = buf.len();
        if buf.try_reserve(step).is_err() {
            return Err((
                before,
                io::Error::new(
                    io::ErrorKind::OutOfMemory,
                    format!("cannot allocate a slice of {len} bytes"),
                ),
            ));
        }
        match r.by_ref().take(step as u64).read_to_end(buf) {
            Ok(0) => return Err((before, io::ErrorKind::UnexpectedEof.into())),
            Ok(_) => {}
            Err(e) => return Err((buf.len(), e)),
        }
    }
    Ok(())
}
impl VolumeSource for StreamVolume {
    fn grid(&self) -> Grid {
        self.grid
    }

    fn describe(&self) -> String {
        self.path.display().to_string()
    }

    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        check_request(self, z, out)?;
        let bytes = if z + 2 == self.next_z {
            &self.prev
        } else {
            if z + 1 < self.next_z {
                self.reader = None;
                self.next_z = 0;
            }
            while self.next_z <= z {
                self.advance()?;
            }
            &self.bytes
        };
        self.saturated += match &self.scale {
            None => decode(self.dtype, self.endian, bytes, out),
            Some(scale) => scale.decode(self.dtype, self.endian, bytes, out, z)?,
        };
        Ok(())
    }

    fn dtype(&self) -> Option<Dtype> {
        Some(self.stored)
    }

    /// The decoded type's, not the declared one's: an ASCII payload (decoded as f64) may hold
    /// any number whatever type its header declares.
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

/// A zero-filled buffer, or None when the allocator refuses: dims from a corrupt header must end
/// in an error, not an abort.
pub(crate) fn zeroed<T: Clone + Default>(n: usize) -> Option<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).ok()?;
    v.resize(n, T::default());
    Some(v)
}

/// Opens `path` and skips `skip` bytes: the start of most streams.
pub(crate) fn open_at(path: &Path, skip: u64) -> Result<io::BufReader<std::fs::File>, VolumeError> {
    use std::io::{Seek, SeekFrom};
    let mut f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, "open", e))?;
    f.seek(SeekFrom::Start(skip))
        .map_err(|e| VolumeError::io(path, "seek in it", e))?;
    Ok(io::BufReader::with_capacity(1 << 16, f))
}

/// Discards `n` bytes of a stream (headers inside compressed data), reporting a short stream.
pub(crate) fn skip_bytes(r: &mut dyn Read, n: u64) -> io::Result<()> {
    let copied = io::copy(&mut r.take(n), &mut io::sink())?;
    if copied < n {
        return Err(io::ErrorKind::UnexpectedEof.into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    fn volume(bytes: Vec<u8>, dims: [u64; 3]) -> (StreamVolume, Arc<AtomicUsize>) {
        let opens = Arc::new(AtomicUsize::new(0));
        let counter = opens.clone();
        let bytes = Arc::new(bytes);
        let v = StreamVolume::new(StreamSpec {
            path: PathBuf::from("mem.bin"),
            what: "test payload",
            grid: Grid::new(dims, [1.0; 3], [0.0; 3]).unwrap(),
            dtype: Dtype::U8,
            stored: Dtype::U8,
            endian: Endian::Little,
            open: Box::new(move || {
                counter.fetch_add(1, Ordering::SeqCst);
                Ok(Box::new(io::Cursor::new(bytes.as_ref().clone())) as Stream)
            }),
            exact_end: false,
            orientation: Orientation::Aligned,
        })
        .unwrap();
        (v, opens)
    }

    #[test]
    fn back_one_is_cached_and_further_back_rewinds() {
        let (mut v, opens) = volume((0..16).collect(), [2, 2, 4]);
        let mut out = [0.0f32; 4];
        v.read_slice(0, &mut out).unwrap();
        v.read_slice(1, &mut out).unwrap();
        assert_eq!(out, [4.0, 5.0, 6.0, 7.0]);
        v.read_slice(0, &mut out).unwrap();
        assert_eq!(out, [0.0, 1.0, 2.0, 3.0]);
        v.read_slice(2, &mut out).unwrap();
        v.read_slice(3, &mut out).unwrap();
        assert_eq!(out, [12.0, 13.0, 14.0, 15.0]);
        assert_eq!(
            opens.load(Ordering::SeqCst),
            1,
            "z - 1 comes from the cache"
        );
        v.read_slice(1, &mut out).unwrap();
        assert_eq!(out, [4.0, 5.0, 6.0, 7.0]);
        assert_eq!(opens.load(Ordering::SeqCst), 2, "z - 2 re-opens the stream");
    }

    /// A header claiming far more than the stream holds fails at open, having allocated only
    /// about what the stream delivered.
    #[test]
    fn huge_claim_fails_at_open_without_allocating_it() {
        let grid = Grid::new([30_000, 30_000, 30_000], [1.0; 3], [0.0; 3]).unwrap();
        let e = StreamVolume::new(StreamSpec {
            path: PathBuf::from("claim.bin"),
            what: "test payload",
            grid,
            dtype: Dtype::U8,
            stored: Dtype::U8,
            endian: Endian::Little,
            open: Box::new(|| Ok(Box::new(io::Cursor::new(vec![0u8; 92])) as Stream)),
            exact_end: false,
            orientation: Orientation::Aligned,
        })
        .err()
        .unwrap()
        .to_string();
        assert!(
            e.contains("voxel 92 (slice 0)") && e.contains("end of data"),
            "{e}"
        );
    }

    #[test]
    fn truncated_stream_names_slice_and_offset() {
        let (mut v, _) = volume((0..14).collect(), [2, 2, 4]);
        let mut out = [0.0f32; 4];
        v.read_slice(2, &mut out).unwrap();
        let e = v.read_slice(3, &mut out).unwrap_err();
        assert_eq!(
            e.to_string(),
            "mem.bin: test payload voxel 14 (slice 3): expected 16 voxels of u8 for dims 2x2x4, found \"end of data (truncated file?)\""
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]

        /// Any order of slice requests returns the same slices as an in-memory volume; the pipeline's
        /// pattern (forward, sometimes z - 1 again) never reopens the stream.
        #[test]
        fn any_request_order_matches_memory(
            dims in proptest::array::uniform3(2u64..6),
            requests in proptest::collection::vec(0u64..64, 1..20),
        ) {
            let n = (dims[0] * dims[1] * dims[2]) as usize;
            let bytes: Vec<u8> = (0..n).map(|i| (i * 7 % 256) as u8).collect();
            let grid = Grid::new(dims, [1.0; 3], [0.0; 3]).unwrap();
            let mut mem = crate::MemoryVolume::new(grid, bytes.iter().map(|&b| f32::from(b)).collect())
                .unwrap();
            let (mut v, _) = volume(bytes, dims);
            let (mut a, mut b) = (vec![0.0f32; grid.slice_len()], vec![0.0f32; grid.slice_len()]);
            for z in requests.into_iter().map(|z| z % dims[2]) {
                v.read_slice(z, &mut a).unwrap();
                mem.read_slice(z, &mut b).unwrap();
                proptest::prop_assert_eq!(&a, &b);
            }
        }

        #[test]
        fn pipeline_order_opens_once(dims in proptest::array::uniform3(2u64..6)) {
            let n = (dims[0] * dims[1] * dims[2]) as usize;
            let (mut v, opens) = volume(vec![1; n], dims);
            let mut out = vec![0.0f32; (dims[0] * dims[1]) as usize];
            for z in 0..dims[2] {
                v.read_slice(z, &mut out).unwrap();
                v.read_slice(z.saturating_sub(1), &mut out).unwrap();
                v.read_slice(z, &mut out).unwrap();
            }
            proptest::prop_assert_eq!(opens.load(Ordering::SeqCst), 1);
        }
    }
}
