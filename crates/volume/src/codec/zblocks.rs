//! VTK's zlib block framing (`compressor="vtkZLibDataCompressor"`): the array is cut into blocks
//! of `block_size` bytes (the last may be shorter), each compressed on its own. Decoding block by
//! block keeps one block in memory, so compressed VTI arrays stream like the rest.

use super::invalid;
use flate2::read::ZlibDecoder;
use std::io::{self, Read};

/// Sizes from the block header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ZlibLayout {
    pub block_size: u64,
    /// Uncompressed size of the last block (VTK writes 0 when it is a full block).
    pub last_size: u64,
    pub compressed: Vec<u64>,
}

impl ZlibLayout {
    /// Largest block we agree to decode: VTK uses 32 KiB; far larger values mean a corrupt header.
    pub(crate) const MAX_BLOCK: u64 = 1 << 28;

    /// Uncompressed total, or None on overflow.
    pub(crate) fn total(&self) -> Option<u64> {
        let n = self.compressed.len() as u64;
        if n == 0 {
            return Some(0);
        }
        self.block_size.checked_mul(n - 1)?.checked_add(self.last())
    }

    fn last(&self) -> u64 {
        if self.last_size == 0 {
            self.block_size
        } else {
            self.last_size
        }
    }
}

pub(crate) struct ZlibBlocks<R> {
    inner: R,
    layout: ZlibLayout,
    next_block: usize,
    block: Vec<u8>,
    pos: usize,
}

impl<R: Read> ZlibBlocks<R> {
    /// `inner` is positioned at the first compressed block.
    pub(crate) fn new(inner: R, layout: ZlibLayout) -> Self {
        ZlibBlocks {
            inner,
            layout,
            next_block: 0,
            block: Vec::new(),
            pos: 0,
        }
    }

    fn load_next(&mut self) -> io::Result<bool> {
        let i = self.next_block;
        let Some(&csize) = self.layout.compressed.get(i) else {
            return Ok(false);
        };
        let want = if i + 1 == self.layout.compressed.len() {
            self.layout.last()
        } else {
            self.layout.block_size
        };
        let mut raw = (&mut self.inner).take(csize);
        self.block.clear();
        let got = ZlibDecoder::new(&mut raw)
            .take(want.saturating_add(1))
            .read_to_end(&mut self.block)
            .map_err(|e| {
                // The file's own error (a map reader finding it truncated) goes out as it is,
                // whole: wrapped in the block's message it was cut short.
                if e.get_ref()
                    .is_some_and(|inner| inner.is::<crate::VolumeError>())
                {
                    e
                } else {
                    invalid(format!("zlib block {i}: {e}"))
                }
            })?;
        if got as u64 != want {
            return Err(invalid(format!(
                "zlib block {i} to inflate to {want} bytes, found {got}"
            )));
        }
        // Keep the framing aligned even if the decoder stopped before the block's last byte.
        io::copy(&mut raw, &mut io::sink())?;
        if raw.limit() > 0 {
            return Err(io::ErrorKind::UnexpectedEof.into());
        }
        self.next_block += 1;
        self.pos = 0;
        Ok(true)
    }
}

impl<R: Read> Read for ZlibBlocks<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.pos == self.block.len() && !self.load_next()? {
            return Ok(0);
        }
        let n = buf.len().min(self.block.len() - self.pos);
        buf[..n].copy_from_slice(&self.block[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use flate2::Compression;
    use flate2::write::ZlibEncoder;
    use std::io::Write;

    /// VTK-style framing of `data`: returns the layout and the concatenated compressed blocks.
    pub(crate) fn compress(data: &[u8], block_size: usize) -> (ZlibLayout, Vec<u8>) {
        let mut compressed = Vec::new();
        let mut sizes = Vec::new();
        for chunk in data.chunks(block_size) {
            let mut e = ZlibEncoder::new(Vec::new(), Compression::default());
            e.write_all(chunk).unwrap();
            let c = e.finish().unwrap();
            sizes.push(c.len() as u64);
            compressed.extend(c);
        }
        let last = data.len() % block_size;
        let layout = ZlibLayout {
            block_size: block_size as u64,
            last_size: last as u64,
            compressed: sizes,
        };
        (layout, compressed)
    }

    #[test]
    fn round_trips_with_short_last_block() {
        let data: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        let (layout, c) = compress(&data, 64);
        assert_eq!(layout.total(), Some(1000));
        let mut out = Vec::new();
        ZlibBlocks::new(&c[..], layout)
            .read_to_end(&mut out)
            .unwrap();
        assert_eq!(out, data);
    }

    #[test]
    fn corrupt_block_is_invalid_data() {
        let data = vec![5u8; 300];
        let (layout, mut c) = compress(&data, 100);
        let second = layout.compressed[0] as usize;
        c[second + 3] ^= 0xFF;
        c[second + 4] ^= 0xFF;
        let mut out = Vec::new();
        let e = ZlibBlocks::new(&c[..], layout)
            .read_to_end(&mut out)
            .unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
        assert!(e.to_string().starts_with("zlib block 1"), "{e}");
    }

    /// The file's own error from under the decoder (a mapped file truncated while read) comes
    /// out whole, not cut short inside a block's message.
    #[test]
    fn the_files_own_error_passes_through() {
        struct Truncated;
        impl Read for Truncated {
            fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
                Err(io::Error::other(crate::VolumeError::Format {
                    file: "v.vti".into(),
                    at: "byte 7".into(),
                    expected: "at least 9 bytes".into(),
                    found: "7 bytes: the file was truncated while being read".into(),
                }))
            }
        }
        let (layout, _) = compress(&[5u8; 300], 100);
        let e = ZlibBlocks::new(Truncated, layout)
            .read_to_end(&mut Vec::new())
            .unwrap_err();
        let inner = e
            .into_inner()
            .unwrap()
            .downcast::<crate::VolumeError>()
            .unwrap();
        assert!(
            inner.to_string().contains("truncated while being read"),
            "{inner}"
        );
    }

    #[test]
    fn wrong_block_size_is_reported() {
        let data = vec![5u8; 300];
        let (mut layout, c) = compress(&data, 100);
        layout.block_size = 99;
        let mut out = Vec::new();
        let e = ZlibBlocks::new(&c[..], layout)
            .read_to_end(&mut out)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "zlib block 0 to inflate to 99 bytes, found 100"
        );
    }
}
