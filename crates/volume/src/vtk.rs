//! VTK legacy `.vtk` files, `DATASET STRUCTURED_POINTS` only, BINARY (big-endian by definition
//! of the format) or ASCII. Binary payloads are memory-mapped at their offset; ASCII streams.
//! A file may carry several `SCALARS` arrays: [`OpenOptions::array`] picks one by name, otherwise
//! the first is used.

use crate::codec::AsciiValues;
use crate::grid::dims_text;
use crate::raw::{Payload, RawVolume, payload_bytes};
use crate::stream::{Stream, StreamSpec, StreamVolume, skip_bytes};
use crate::{Dtype, Endian, OpenOptions, VolumeError, VolumeSource};
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Seek};
use std::path::{Path, PathBuf};

/// Longest header line we accept (titles are at most 256 characters in the format).
const MAX_LINE: u64 = 1024;

struct Header {
    dims: [u64; 3],
    spacing: [f64; 3],
    origin: [f64; 3],
    dtype: Dtype,
    binary: bool,
}

/// Opens a VTK legacy structured-points file.
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_raw_params(path, "VTK legacy")?;
    let want = opts.array.clone();
    let (h, mut reader) = locate(path, want.as_deref())?;
    let grid = opts.grid(path, h.dims, h.spacing, h.origin)?;
    if h.binary {
        let offset = reader
            .stream_position()
            .map_err(|e| VolumeError::io(path, "read", e))?;
        return Ok(Box::new(RawVolume::open_payload(Payload {
            path,
            grid,
            dtype: h.dtype,
            endian: Endian::Big,
            offset,
            trailing_ok: true,
            hint: "check the DIMENSIONS and SCALARS lines against the data",
        })?));
    }
    drop(reader);
    let owned: PathBuf = path.to_path_buf();
    Ok(Box::new(StreamVolume::new(StreamSpec {
        path: path.to_path_buf(),
        what: "ascii VTK scalars",
        grid,
        dtype: Dtype::F64,
        stored: h.dtype,
        endian: Endian::Little,
        open: Box::new(move || {
            let (_, r) = locate(&owned, want.as_deref())?;
            Ok(Box::new(AsciiValues::new(r, None)) as Stream)
        }),
    })?))
}

/// Parses the header and returns a reader positioned at the first value of the wanted array.
fn locate(path: &Path, want: Option<&str>) -> Result<(Header, BufReader<File>), VolumeError> {
    let f = File::open(path).map_err(|e| VolumeError::io(path, "open", e))?;
    let mut r = BufReader::new(f);
    let mut n = 0usize;
    let err = |n: usize, expected: &str, found: &str| {
        VolumeError::format(path, format!("line {n}"), expected, found)
    };
    // Reads the next non-blank line; None at end of file.
    let next = |r: &mut BufReader<File>, n: &mut usize| -> Result<Option<String>, VolumeError> {
        loop {
            let mut raw = Vec::new();
            let got = r
                .by_ref()
                .take(MAX_LINE)
                .read_until(b'\n', &mut raw)
                .map_err(|e| VolumeError::io(path, "read", e))?;
            if got == 0 {
                return Ok(None);
            }
            *n += 1;
            let line = String::from_utf8_lossy(&raw).trim().to_string();
            if !line.is_empty() || *n <= 2 {
                return Ok(Some(line));
            }
        }
    };
    let magic = next(&mut r, &mut n)?.unwrap_or_default();
    if !magic.starts_with("# vtk DataFile") {
        return Err(err(1, "\"# vtk DataFile Version x.x\"", &magic));
    }
    next(&mut r, &mut n)?; // title
    let binary = match next(&mut r, &mut n)?
        .unwrap_or_default()
        .to_ascii_uppercase()
        .as_str()
    {
        "BINARY" => true,
        "ASCII" => false,
        other => return Err(err(n, "ASCII or BINARY", other)),
    };
    let (mut dims, mut spacing, mut origin, mut count) = (None, [1.0; 3], [0.0; 3], None);
    let mut seen = Vec::new();
    loop {
        let Some(line) = next(&mut r, &mut n)? else {
            let expected = match want {
                Some(w) => format!("a SCALARS array named {w:?} (arrays: {})", seen.join(", ")),
                None => "a SCALARS array".to_string(),
            };
            return Err(VolumeError::format(path, "end of file", expected, "none"));
        };
        let words: Vec<&str> = line.split_whitespace().collect();
        let key = words[0].to_ascii_uppercase();
        let args = &words[1..];
        match key.as_str() {
            "DATASET" => {
                if args.first().map(|s| s.to_ascii_uppercase()) != Some("STRUCTURED_POINTS".into())
                {
                    return Err(err(n, "DATASET STRUCTURED_POINTS (a regular grid)", &line));
                }
            }
            "DIMENSIONS" => {
                dims = Some(three::<u64>(args).ok_or_else(|| err(n, "DIMENSIONS nx ny nz", &line))?)
            }
            "SPACING" | "ASPECT_RATIO" => {
                spacing = three::<f64>(args).ok_or_else(|| err(n, "SPACING sx sy sz", &line))?
            }
            "ORIGIN" => origin = three::<f64>(args).ok_or_else(|| err(n, "ORIGIN x y z", &line))?,
            "POINT_DATA" => {
                count = Some(
                    args.first()
                        .and_then(|c| c.parse::<u64>().ok())
                        .ok_or_else(|| err(n, "POINT_DATA count", &line))?,
                )
            }
            "SCALARS" => {
                let d = dims.ok_or_else(|| err(n, "DIMENSIONS before the data", &line))?;
                let c = count.ok_or_else(|| err(n, "POINT_DATA before SCALARS", &line))?;
                if Some(c) != d[0].checked_mul(d[1]).and_then(|s| s.checked_mul(d[2])) {
                    return Err(err(
                        n,
                        &format!("POINT_DATA equal to dims {}", dims_text(d)),
                        &c.to_string(),
                    ));
                }
                let [name, ty, rest @ ..] = args else {
                    return Err(err(n, "SCALARS name type", &line));
                };
                let dtype = vtk_type(ty).ok_or_else(|| {
                    err(n, "a type among unsigned_char/char/unsigned_short/short/unsigned_int/int/float/double", ty)
                })?;
                if rest.first().is_some_and(|c| *c != "1") {
                    return Err(err(n, "one component per voxel", &line));
                }
                // An optional LOOKUP_TABLE line precedes the values.
                let before = (
                    r.stream_position()
                        .map_err(|e| VolumeError::io(path, "read", e))?,
                    n,
                );
                let mut peek = Vec::new();
                r.by_ref()
                    .take(MAX_LINE)
                    .read_until(b'\n', &mut peek)
                    .map_err(|e| VolumeError::io(path, "read", e))?;
                if String::from_utf8_lossy(&peek)
                    .trim_start()
                    .to_ascii_uppercase()
                    .starts_with("LOOKUP_TABLE")
                {
                    n += 1;
                } else {
                    r.seek(std::io::SeekFrom::Start(before.0))
                        .map_err(|e| VolumeError::io(path, "seek in", e))?;
                }
                if want.is_none_or(|w| w == *name) {
                    return Ok((
                        Header {
                            dims: d,
                            spacing,
                            origin,
                            dtype,
                            binary,
                        },
                        r,
                    ));
                }
                seen.push(name.to_string());
                skip_values(&mut r, binary, c, dtype)
                    .map_err(|e| err(n, &format!("{c} values of {name}"), &e.to_string()))?;
            }
            _ => {
                return Err(err(
                    n,
                    "DIMENSIONS, SPACING, ORIGIN, POINT_DATA or SCALARS",
                    &line,
                ));
            }
        }
    }
}

/// Skips the values of an array that was not asked for.
fn skip_values(
    r: &mut BufReader<File>,
    binary: bool,
    count: u64,
    dtype: Dtype,
) -> std::io::Result<()> {
    if binary {
        let bytes = payload_bytes([count, 1, 1], dtype).ok_or(std::io::ErrorKind::InvalidInput)?;
        skip_bytes(r, bytes)
    } else {
        skip_bytes(&mut AsciiValues::new(r, None), count.saturating_mul(8))
    }
}

fn three<T: std::str::FromStr>(args: &[&str]) -> Option<[T; 3]> {
    match args {
        [a, b, c] => Some([a.parse().ok()?, b.parse().ok()?, c.parse().ok()?]),
        _ => None,
    }
}

fn vtk_type(s: &str) -> Option<Dtype> {
    Some(match s.to_ascii_lowercase().as_str() {
        "unsigned_char" => Dtype::U8,
        "char" | "signed_char" => Dtype::I8,
        "unsigned_short" => Dtype::U16,
        "short" => Dtype::I16,
        "unsigned_int" => Dtype::U32,
        "int" => Dtype::I32,
        "float" => Dtype::F32,
        "double" => Dtype::F64,
        _ => return None,
    })
}

#[cfg(test)]
pub(crate) mod tests;
