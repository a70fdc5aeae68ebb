//! Whitespace-separated numbers (NRRD `encoding: ascii`, VTK legacy ASCII, VTI `format="ascii"`)
//! re-emitted as little-endian f64 bytes, so ASCII payloads reuse the binary slice decoder.

use super::invalid;
use std::io::{self, BufRead, Read};

/// Reads numbers from text and yields each as 8 little-endian f64 bytes.
pub(crate) struct AsciiValues<R> {
    inner: R,
    /// Encoded bytes of the current number and how many of them were handed out.
    pending: [u8; 8],
    used: usize,
    /// Numbers read so far, for error messages.
    count: u64,
    /// Byte that ends the text (e.g. `<` in XML); None reads to the end of the stream.
    stop: Option<u8>,
    /// Values are colors in [0, 1] of bytes (VTK legacy `COLOR_SCALARS` in ASCII): re-emitted
    /// as `round(v * 255)`, the bytes they were written from.
    unit_to_byte: bool,
    /// An error met after some bytes of a `read` call were produced, reported by the next call
    /// so the caller sees exactly how many values were good.
    deferred: Option<io::Error>,
}

impl<R: BufRead> AsciiValues<R> {
    pub(crate) fn new(inner: R, stop: Option<u8>) -> Self {
        AsciiValues {
            inner,
            pending: [0; 8],
            used: 8,
            count: 0,
            stop,
            unit_to_byte: false,
            deferred: None,
        }
    }

    /// Reads values in [0, 1] back as the bytes 0..255 they were written from.
    pub(crate) fn unit_to_byte(self) -> Self {
        AsciiValues {
            unit_to_byte: true,
            ..self
        }
    }

    /// Next whitespace-separated token, or None at the end of the text.
    fn token(&mut self) -> io::Result<Option<String>> {
        let mut tok = Vec::new();
        loop {
            let buf = self.inner.fill_buf()?;
            if buf.is_empty() {
                break;
            }
            let mut consumed = 0;
            let mut done = false;
            for &b in buf {
                if Some(b) == self.stop {
                    done = true;
                    break;
                }
                consumed += 1;
                if b.is_ascii_whitespace() {
                    if !tok.is_empty() {
                        done = true;
                        break;
                    }
                } else if tok.len() < 64 {
                    tok.push(b);
                } else {
                    return Err(invalid(format!(
                        "a number as value {}, found a token longer than 64 characters",
                        self.count
                    )));
                }
            }
            self.inner.consume(consumed);
            if done {
                break;
            }
        }
        if tok.is_empty() {
            return Ok(None);
        }
        Ok(Some(String::from_utf8_lossy(&tok).into_owned()))
    }
}

impl<R: BufRead> Read for AsciiValues<R> {
    fn read(&mut self, out: &mut [u8]) -> io::Result<usize> {
        if let Some(e) = self.deferred.take() {
            return Err(e);
        }
        let mut written = 0;
        while written < out.len() {
            if self.used == 8 {
                let next = self.token().and_then(|tok| match tok {
                    None => Ok(None),
                    Some(tok) => tok.parse::<f64>().map(Some).map_err(|_| {
                        invalid(format!("a number as value {}, found {tok:?}", self.count))
                    }),
                });
                let v = match next {
                    Ok(Some(v)) => v,
                    Ok(None) => break,
                    Err(e) if written > 0 => {
                        self.deferred = Some(e);
                        break;
                    }
                    Err(e) => return Err(e),
                };
                self.count += 1;
                let v = if self.unit_to_byte {
                    (v * 255.0).round()
                } else {
                    v
                };
                self.pending = v.to_le_bytes();
                self.used = 0;
            }
            let n = (8 - self.used).min(out.len() - written);
            out[written..written + n].copy_from_slice(&self.pending[self.used..self.used + n]);
            self.used += n;
            written += n;
        }
        Ok(written)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(text: &str, stop: Option<u8>) -> io::Result<Vec<f64>> {
        let mut bytes = Vec::new();
        AsciiValues::new(text.as_bytes(), stop).read_to_end(&mut bytes)?;
        Ok(bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }

    #[test]
    fn parses_numbers_across_whitespace() {
        assert_eq!(
            values(" 1 -2.5\n\t3e2  \r\n4", None).unwrap(),
            [1.0, -2.5, 300.0, 4.0]
        );
        assert_eq!(values("7 8 </DataArray>", Some(b'<')).unwrap(), [7.0, 8.0]);
        assert_eq!(values("", None).unwrap(), Vec::<f64>::new());
    }

    #[test]
    fn unit_values_back_to_bytes() {
        let mut bytes = Vec::new();
        AsciiValues::new("0 0.00392157 0.501961 1".as_bytes(), None)
            .unit_to_byte()
            .read_to_end(&mut bytes)
            .unwrap();
        let v: Vec<f64> = bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(v, [0.0, 1.0, 128.0, 255.0]);
    }

    #[test]
    fn bad_token_is_invalid_data() {
        let e = values("1 2 x3", None).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
        assert_eq!(e.to_string(), "a number as value 2, found \"x3\"");
    }
}
