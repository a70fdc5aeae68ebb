//! Gzip payloads of NRRD files: concatenated members (as `MultiGzDecoder` reads them) that may
//! be followed by whitespace. pynrrd and teem-era writers end a file with a newline after the
//! stream, which teem, pynrrd and vtkNrrdReader read; `MultiGzDecoder` took that newline for the
//! start of another member and failed on it.

use flate2::bufread::GzDecoder;
use std::io::{self, BufRead, Read};

/// Decodes gzip members one after the other; whitespace between or after them is skipped, so
/// the stream ends at whitespace-only trailing bytes. Anything else starts another member, and
/// a broken one is an error as before.
pub(crate) struct GzipMembers<R> {
    /// `None` once the input is over.
    current: Option<GzDecoder<R>>,
}

impl<R: BufRead> GzipMembers<R> {
    pub(crate) fn new(inner: R) -> Self {
        GzipMembers {
            current: Some(GzDecoder::new(inner)),
        }
    }
}

impl<R: BufRead> Read for GzipMembers<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            let Some(member) = self.current.as_mut() else {
                return Ok(0);
            };
            let n = member.read(buf)?;
            if n > 0 || buf.is_empty() {
                return Ok(n);
            }
            // The member is over (its CRC checked): skip whitespace, then end or go on.
            let Some(mut inner) = self.current.take().map(GzDecoder::into_inner) else {
                return Ok(0);
            };
            loop {
                let rest = inner.fill_buf()?;
                if rest.is_empty() {
                    return Ok(0);
                }
                let blank = rest.iter().take_while(|b| b.is_ascii_whitespace()).count();
                let more = blank < rest.len();
                inner.consume(blank);
                if more {
                    break;
                }
            }
            self.current = Some(GzDecoder::new(inner));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::gzip;

    fn decode(bytes: &[u8]) -> io::Result<Vec<u8>> {
        let mut out = Vec::new();
        GzipMembers::new(bytes).read_to_end(&mut out)?;
        Ok(out)
    }

    #[test]
    fn members_and_trailing_whitespace() {
        let two = [gzip(b"abc"), gzip(b"def")].concat();
        assert_eq!(decode(&two).unwrap(), b"abcdef");
        let trailing = [gzip(b"abc"), b"\n \r\n".to_vec()].concat();
        assert_eq!(decode(&trailing).unwrap(), b"abc");
        let between = [gzip(b"abc"), b"\n".to_vec(), gzip(b"d"), b"\n".to_vec()].concat();
        assert_eq!(decode(&between).unwrap(), b"abcd");
        let garbage = [gzip(b"abc"), b"\ngarbage".to_vec()].concat();
        assert!(decode(&garbage).is_err());
    }
}
