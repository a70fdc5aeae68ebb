//! Streaming base64 decoding (VTI `format="binary"`). Whitespace is skipped and `=` padding may
//! appear mid-stream: VTK encodes a block's header and its data as two separately padded runs,
//! and decoding quartet by quartet handles both that and a single joint run without knowing which.

use super::invalid;
use std::io::{self, BufRead, Read};

pub(crate) struct Base64Reader<R> {
    inner: R,
    /// Decoded bytes not yet handed out.
    out: [u8; 3],
    out_len: usize,
    out_pos: usize,
    /// Characters consumed, for error messages.
    pos: u64,
    ended: bool,
}

impl<R: BufRead> Base64Reader<R> {
    /// Decodes until the end of `inner` or the first `<` (the closing XML tag).
    pub(crate) fn new(inner: R) -> Self {
        Base64Reader {
            inner,
            out: [0; 3],
            out_len: 0,
            out_pos: 0,
            pos: 0,
            ended: false,
        }
    }

    /// Decodes the next quartet into `out`; false at the end of the text.
    fn next_quartet(&mut self) -> io::Result<bool> {
        let mut quad = [0u8; 4];
        let mut n = 0;
        let mut pads = 0;
        while n < 4 {
            let buf = self.inner.fill_buf()?;
            let Some(&c) = buf.first() else { break };
            if c == b'<' {
                break;
            }
            self.inner.consume(1);
            self.pos += 1;
            if c.is_ascii_whitespace() {
                continue;
            }
            let v = match c {
                b'A'..=b'Z' => c - b'A',
                b'a'..=b'z' => c - b'a' + 26,
                b'0'..=b'9' => c - b'0' + 52,
                b'+' => 62,
                b'/' => 63,
                b'=' if n >= 2 => {
                    pads += 1;
                    0
                }
                _ => {
                    return Err(invalid(format!(
                        "base64 text, found {:?} at character {}",
                        c as char,
                        self.pos - 1
                    )));
                }
            };
            if pads > 0 && c != b'=' {
                return Err(invalid(format!(
                    "base64 padding to end a quartet, found data at character {}",
                    self.pos - 1
                )));
            }
            quad[n] = v;
            n += 1;
        }
        if n == 0 {
            return Ok(false);
        }
        if n == 1 {
            return Err(invalid(format!(
                "a complete base64 quartet, found one lone character before character {}",
                self.pos
            )));
        }
        let bits = (u32::from(quad[0]) << 18)
            | (u32::from(quad[1]) << 12)
            | (u32::from(quad[2]) << 6)
            | u32::from(quad[3]);
        self.out = [(bits >> 16) as u8, (bits >> 8) as u8, bits as u8];
        // A short quartet (missing padding at the very end) decodes like a padded one.
        self.out_len = n - 1 - pads;
        self.out_pos = 0;
        Ok(true)
    }
}

impl<R: BufRead> Read for Base64Reader<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let mut written = 0;
        while written < buf.len() {
            if self.out_pos == self.out_len {
                if self.ended || !self.next_quartet()? {
                    self.ended = true;
                    break;
                }
                continue;
            }
            buf[written] = self.out[self.out_pos];
            self.out_pos += 1;
            written += 1;
        }
        Ok(written)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(text: &str) -> io::Result<Vec<u8>> {
        let mut v = Vec::new();
        Base64Reader::new(text.as_bytes()).read_to_end(&mut v)?;
        Ok(v)
    }

    #[test]
    fn decodes_padded_runs_back_to_back() {
        assert_eq!(decode("aGVsbG8=").unwrap(), b"hello");
        // "hello" and "hi" encoded separately then concatenated, with whitespace and a tag after.
        assert_eq!(decode(" aGVs\nbG8=aGk= </DataArray>").unwrap(), b"hellohi");
        assert_eq!(decode("aGk").unwrap(), b"hi");
        assert_eq!(decode("").unwrap(), b"");
    }

    #[test]
    fn rejects_bad_characters() {
        let e = decode("aGVs*G8=").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
        assert_eq!(e.to_string(), "base64 text, found '*' at character 4");
        assert!(decode("aGVsb").is_err());
        assert!(decode("aG=s").is_err());
    }
}
