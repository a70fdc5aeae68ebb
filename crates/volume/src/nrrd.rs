//! NRRD (teem's "nearly raw raster data"): attached (`.nrrd`) and detached (`.nhdr`) headers,
//! encodings raw, gzip and ascii, one or many data files (`data file: name.%d first last step`
//! and `data file: LIST`). No NRRD crate exists, and the header is a short line-based text, so we
//! parse it here. Raw single-file payloads are memory-mapped; everything else streams.
//!
//! Orientation: `space directions` (and negative `spacings`) contribute only their lengths (the
//! spacing); isostream grids are axis-aligned, so a flipped, rotated or sheared volume is meshed
//! in index-aligned physical units from `space origin`, and the source reports what it dropped
//! ([`VolumeSource::orientation`]).

use crate::codec::{AsciiValues, GzipMembers};
use crate::grid::dims_text;
use crate::orientation::step_length;
use crate::raw::{Payload, RawVolume, checked_payload};
use crate::stream::{Opener, Stream, StreamSpec, StreamVolume, open_at, skip_bytes};
use crate::{Dtype, Endian, Grid, OpenOptions, Orientation, VolumeError, VolumeSource};
use std::io::{self, BufRead, Read};
use std::path::{Path, PathBuf};

/// Longest header we read before deciding the file is not NRRD text.
const MAX_HEADER: u64 = 1 << 20;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Raw,
    Gzip,
    Ascii,
}

#[derive(Debug)]
struct Header {
    dims: [u64; 3],
    dtype: Dtype,
    endian: Option<Endian>,
    encoding: Encoding,
    spacing: [f64; 3],
    origin: [f64; 3],
    /// Flips or rotation of `space directions` / signs of `spacings`, dropped from the grid.
    orientation: Orientation,
    /// Empty when the data is attached.
    files: Vec<PathBuf>,
    line_skip: u64,
    /// -1 means "the payload is the last bytes of the file" (raw only).
    byte_skip: i64,
    /// Bytes of header text (start of attached data).
    len: u64,
}

/// Opens an NRRD file (attached or detached header).
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_raw_params(path, "NRRD")?;
    opts.reject_array(path, "NRRD")?;
    let h = parse(path)?;
    let grid = opts.grid(path, h.dims, h.spacing, h.origin)?;
    let endian = match (h.endian, h.dtype.size_bytes(), h.encoding) {
        (Some(e), _, _) => e,
        (None, 1, _) | (None, _, Encoding::Ascii) => Endian::Little,
        (None, _, _) => {
            return Err(VolumeError::format(
                path,
                "header",
                format!("an \"endian: little|big\" line for type {}", h.dtype),
                "none",
            ));
        }
    };
    let payload = checked_payload(path, h.dims, h.dtype, 0, "the sizes line")?;
    let attached = h.files.is_empty();
    let files: Vec<PathBuf> = if attached {
        vec![path.to_path_buf()]
    } else {
        h.files.clone()
    };
    let mut lens = Vec::with_capacity(files.len());
    for f in &files {
        // A detached data file may be a FIFO or device too: refuse it before opening.
        crate::open::check_file_type(f)?;
        let meta = std::fs::metadata(f).map_err(|e| VolumeError::io(f, "read its size", e))?;
        lens.push(meta.len());
    }
    let start = if attached { h.len } else { 0 };
    if h.encoding == Encoding::Raw && files.len() == 1 && h.line_skip == 0 {
        let offset = if h.byte_skip < 0 {
            lens[0].saturating_sub(payload).max(start)
        } else {
            start.saturating_add(h.byte_skip as u64)
        };
        return Ok(Box::new(RawVolume::open_payload(Payload {
            path: &files[0],
            grid,
            dtype: h.dtype,
            endian,
            offset,
            // Data beyond what `sizes` describes means the header is wrong (as for raw files);
            // only `byte skip: -1` (the payload is the file's last bytes) skips a prefix.
            trailing_ok: h.byte_skip < 0,
            hint: "check the NRRD header's sizes, type, byte skip and data file",
            orientation: h.orientation,
        })?));
    }
    // The memory-mapped path above handled the one case where teem allows -1.
    if h.byte_skip < 0 {
        return Err(VolumeError::format(
            path,
            "byte skip line",
            "byte skip -1 only with raw encoding, one data file and no line skip",
            h.byte_skip.to_string(),
        ));
    }
    if h.encoding == Encoding::Raw {
        let skip = start.saturating_add(h.byte_skip as u64);
        let total = lens
            .iter()
            .fold(0u64, |t, len| t.saturating_add(len.saturating_sub(skip)));
        if total < payload || (total > payload && h.line_skip == 0) {
            return Err(VolumeError::format(
                path,
                "data file line",
                format!(
                    "{payload} payload bytes in {} file(s) for dims {} of {}",
                    files.len(),
                    dims_text(h.dims),
                    h.dtype
                ),
                format!("{total} bytes"),
            ));
        }
    }
    Ok(Box::new(streamed(path, &h, grid, endian, files, start)?))
}

/// A source reading the data files one after the other through the header's encoding.
fn streamed(
    path: &Path,
    h: &Header,
    grid: Grid,
    endian: Endian,
    files: Vec<PathBuf>,
    start: u64,
) -> Result<StreamVolume, VolumeError> {
    let (encoding, line_skip, byte_skip) = (h.encoding, h.line_skip, h.byte_skip.max(0) as u64);
    let open_one = move |f: &Path| -> Result<Stream, VolumeError> {
        let mut r = open_at(f, start)?;
        for _ in 0..line_skip {
            let mut line = Vec::new();
            r.read_until(b'\n', &mut line)
                .map_err(|e| VolumeError::io(f, "read", e))?;
        }
        let mut s: Stream = match encoding {
            Encoding::Raw => Box::new(r),
            // Whitespace after the stream (a final newline) is not data.
            Encoding::Gzip => Box::new(GzipMembers::new(r)),
            Encoding::Ascii => Box::new(AsciiValues::new(r, None)),
        };
        // Byte skip counts decoded bytes (teem applies it after decompression).
        skip_bytes(&mut s, byte_skip).map_err(|e| {
            VolumeError::format(
                f,
                "byte skip",
                format!("{byte_skip} bytes to skip"),
                e.to_string(),
            )
        })?;
        Ok(s)
    };
    let open: Opener = Box::new(move || {
        Ok(Box::new(FileChain {
            files: files.clone(),
            next: 0,
            current: None,
            open_one,
        }) as Stream)
    });
    // AsciiValues re-emits text numbers as little-endian f64.
    let (what, dtype, endian) = match encoding {
        Encoding::Raw => ("raw NRRD payload", h.dtype, endian),
        Encoding::Gzip => ("gzip NRRD payload", h.dtype, endian),
        Encoding::Ascii => ("ascii NRRD payload", Dtype::F64, Endian::Little),
    };
    StreamVolume::new(StreamSpec {
        path: path.to_path_buf(),
        what,
        grid,
        dtype,
        stored: h.dtype,
        endian,
        open,
        // `sizes` describe the whole payload: more data means they are wrong (the raw
        // encoding's file size is checked at open).
        exact_end: true,
        orientation: h.orientation,
    })
}

/// Reads the data files one after the other, opening each only when the previous one is done
/// (a stack of thousands of slice files never holds thousands of descriptors).
struct FileChain<F> {
    files: Vec<PathBuf>,
    next: usize,
    current: Option<Stream>,
    open_one: F,
}

impl<F: Fn(&Path) -> Result<Stream, VolumeError>> Read for FileChain<F> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            if let Some(r) = &mut self.current {
                let n = r.read(buf)?;
                if n > 0 || buf.is_empty() {
                    return Ok(n);
                }
                self.current = None;
            }
            let Some(f) = self.files.get(self.next) else {
                return Ok(0);
            };
            self.next += 1;
            self.current = Some((self.open_one)(f).map_err(io::Error::other)?);
        }
    }
}

/// The header's lines up to the blank line that starts attached data (or the end of a detached
/// header), and the byte length of that text.
fn header_lines(path: &Path) -> Result<(Vec<String>, u64), VolumeError> {
    let f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, "open", e))?;
    let mut r = io::BufReader::new(f).take(MAX_HEADER);
    let err = |n: usize, expected: &str, found: &str| {
        VolumeError::format(path, format!("header line {n}"), expected, found)
    };
    let mut len: u64 = 0;
    let mut lines = Vec::new();
    loop {
        let mut raw = Vec::new();
        let got = r
            .read_until(b'\n', &mut raw)
            .map_err(|e| VolumeError::io(path, "read", e))?;
        if got == 0 {
            break;
        }
        len += got as u64;
        let text = String::from_utf8_lossy(&raw);
        let text = text.trim_end_matches(['\n', '\r']).to_string();
        if lines.is_empty() && !text.starts_with("NRRD000") {
            return Err(err(1, "the NRRD magic \"NRRD0001\"..\"NRRD0005\"", &text));
        }
        if text.is_empty() {
            break;
        }
        if len >= MAX_HEADER {
            return Err(err(
                lines.len() + 1,
                "a header shorter than 1 MiB",
                "more text",
            ));
        }
        lines.push(text);
    }
    if lines.is_empty() {
        return Err(err(
            1,
            "the NRRD magic \"NRRD0001\"..\"NRRD0005\"",
            "an empty file",
        ));
    }
    Ok((lines, len))
}

/// Parses the header text of `path`.
fn parse(path: &Path) -> Result<Header, VolumeError> {
    let (lines, len) = header_lines(path)?;
    let err = |n: usize, expected: &str, found: &str| {
        VolumeError::format(path, format!("header line {n}"), expected, found)
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let unit = unit_axis(&lines);
    let axes = |value: &str| without_axis(value, unit);
    let mut dims = None;
    let mut dtype = None;
    let mut encoding = None;
    let mut endian = None;
    let mut spacing = None;
    let mut directions = None;
    let mut origin = None;
    let mut mins = None;
    let mut cell = [false; 3];
    let mut files = Vec::new();
    let mut line_skip = 0;
    let mut byte_skip = 0;
    let mut i = 1;
    while i < lines.len() {
        let n = i + 1;
        let line = &lines[i];
        i += 1;
        if line.starts_with('#') || line.contains(":=") {
            continue;
        }
        let Some((key, value)) = line.split_once(": ") else {
            return Err(err(n, "\"field: value\"", line));
        };
        let value = value.trim();
        match key.trim() {
            "dimension" if value != "3" && !(value == "4" && unit.is_some()) => {
                return Err(err(
                    n,
                    "dimension: 3 (a scalar volume), or 4 with a first or last axis of size 1 \
                     (save other 4-D data as one 3-D volume per component or time point, e.g. \
                     with unu slice)",
                    value,
                ));
            }
            "sizes" => {
                dims =
                    Some(parse_n::<u64>(&axes(value)).ok_or_else(|| err(n, "three sizes", value))?)
            }
            "type" => {
                dtype = Some(parse_type(value).ok_or_else(|| {
                    err(
                        n,
                        "a type among int8/uint8/int16/uint16/int32/uint32/float/double",
                        value,
                    )
                })?)
            }
            "encoding" => {
                encoding = Some(match value {
                    "raw" => Encoding::Raw,
                    "gzip" | "gz" => Encoding::Gzip,
                    "ascii" | "txt" | "text" => Encoding::Ascii,
                    _ => return Err(err(n, "encoding raw, gzip or ascii", value)),
                })
            }
            "endian" => {
                endian = Some(match value {
                    "little" => Endian::Little,
                    "big" => Endian::Big,
                    _ => return Err(err(n, "endian little or big", value)),
                })
            }
            "spacings" => {
                let s =
                    parse_n::<f64>(&axes(value)).ok_or_else(|| err(n, "three spacings", value))?;
                spacing = Some(s.map(|v| if v.is_nan() { 1.0 } else { v }));
            }
            "space directions" => {
                // `none` (a non-spatial axis) steps by 1 along its own axis.
                let mut d = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
                let kept = axes(value);
                let vecs: Vec<&str> = kept.split_whitespace().collect();
                if vecs.len() != 3 {
                    return Err(err(n, "three space direction vectors", value));
                }
                for (axis, v) in vecs.iter().enumerate() {
                    if *v != "none" {
                        d[axis] =
                            parse_vector(v).ok_or_else(|| err(n, "vectors like (1,0,0)", v))?;
                    }
                }
                directions = Some(d);
            }
            "space origin" => {
                origin = Some(
                    parse_vector(value).ok_or_else(|| err(n, "an origin like (0,0,0)", value))?,
                )
            }
            "axis mins" | "axismins" => {
                let m =
                    parse_n::<f64>(&axes(value)).ok_or_else(|| err(n, "three axis mins", value))?;
                mins = Some(m.map(|v| if v.is_nan() { 0.0 } else { v }));
            }
            "centerings" | "centers" => {
                let kept = axes(value);
                let words: Vec<&str> = kept.split_whitespace().collect();
                let known = ["cell", "node", "???", "none"];
                if words.len() != 3 || words.iter().any(|w| !known.contains(w)) {
                    return Err(err(
                        n,
                        "three centerings among cell, node, ???, none",
                        value,
                    ));
                }
                cell = [0, 1, 2].map(|k| words[k] == "cell");
            }
            "data file" | "datafile" => {
                files = data_files(value, dir, &lines[i..]).ok_or_else(|| {
                    err(
                        n,
                        "a file name, \"LIST\" or \"name.%d first last step\" (a %Nd width of at most 255)",
                        value,
                    )
                })?;
                if value.starts_with("LIST") {
                    i = lines.len();
                }
            }
            "line skip" | "lineskip" => {
                line_skip = value.parse().map_err(|_| err(n, "a line count", value))?
            }
            "byte skip" | "byteskip" => {
                byte_skip = value
                    .parse::<i64>()
                    .ok()
                    .filter(|&b| b >= -1)
                    .ok_or_else(|| err(n, "a byte count or -1", value))?
            }
            // Fields that do not change the sampled values or the grid.
            _ => {}
        }
    }
    // Each axis' step vector: `space directions`, else `spacings` along the axes (a negative
    // spacing is a flip).
    let steps = directions.unwrap_or_else(|| {
        let s = spacing.unwrap_or([1.0; 3]);
        [[s[0], 0.0, 0.0], [0.0, s[1], 0.0], [0.0, 0.0, s[2]]]
    });
    let missing =
        |field: &str| VolumeError::format(path, "header", format!("a \"{field}:\" line"), "none");
    Ok(Header {
        dims: dims.ok_or_else(|| missing("sizes"))?,
        dtype: dtype.ok_or_else(|| missing("type"))?,
        endian,
        encoding: encoding.ok_or_else(|| missing("encoding"))?,
        spacing: steps.map(step_length),
        // Without `space origin`, `axis mins` place the first sample (teem's rule): at the
        // min for node centering (the default), half a step past it for cell centering, where
        // the min is the first cell's edge.
        origin: origin
            .or(mins
                .map(|m| [0, 1, 2].map(|k| m[k] + if cell[k] { steps[k][k] / 2.0 } else { 0.0 })))
            .unwrap_or([0.0; 3]),
        orientation: Orientation::of_columns(steps),
        files,
        line_skip,
        byte_skip,
        len,
    })
}

/// The axis a 4-D header may drop: one of size 1 first or last in `sizes` (the first if both
/// are), as a one-component vector or a one-frame series is written (`sizes: 1 X Y Z`). Such a
/// file is one 3-D volume, and dropping the axis leaves its samples in the same order. `None`
/// unless the header says `dimension: 4`.
fn unit_axis(lines: &[String]) -> Option<usize> {
    let field = |name: &str| {
        lines.iter().skip(1).find_map(|l| {
            let (key, value) = l.split_once(": ")?;
            (key.trim() == name).then(|| value.trim())
        })
    };
    if field("dimension")? != "4" {
        return None;
    }
    match field("sizes")?.split_whitespace().collect::<Vec<_>>()[..] {
        ["1", _, _, _] => Some(0),
        [_, _, _, "1"] => Some(3),
        _ => None,
    }
}

/// A per-axis field's value without the word of the axis [`unit_axis`] drops; a value of
/// another length is left whole for its parser to refuse.
fn without_axis(value: &str, unit: Option<usize>) -> String {
    let words: Vec<&str> = value.split_whitespace().collect();
    match unit {
        Some(k) if words.len() == 4 => {
            let kept: Vec<&str> = (0..4).filter(|&i| i != k).map(|i| words[i]).collect();
            kept.join(" ")
        }
        _ => value.to_string(),
    }
}

fn parse_n<T: std::str::FromStr>(s: &str) -> Option<[T; 3]> {
    let v: Vec<T> = s
        .split_whitespace()
        .map(|t| t.parse().ok())
        .collect::<Option<_>>()?;
    v.try_into().ok()
}

/// "(1.5,0,0)" -> [1.5, 0, 0].
fn parse_vector(s: &str) -> Option<[f64; 3]> {
    let inner = s.trim().strip_prefix('(')?.strip_suffix(')')?;
    let v: Vec<f64> = inner
        .split(',')
        .map(|t| t.trim().parse().ok())
        .collect::<Option<_>>()?;
    v.try_into().ok()
}

fn parse_type(s: &str) -> Option<Dtype> {
    Some(match s {
        "signed char" | "int8" | "int8_t" => Dtype::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => Dtype::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            Dtype::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => Dtype::U16,
        "int" | "signed int" | "int32" | "int32_t" => Dtype::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => Dtype::U32,
        "float" => Dtype::F32,
        "double" => Dtype::F64,
        _ => return None,
    })
}

/// The files of a detached header: one name, a `%d` pattern with first/last/step, or a LIST
/// whose names are the remaining header lines. Relative names are relative to the header.
fn data_files(value: &str, dir: &Path, rest: &[String]) -> Option<Vec<PathBuf>> {
    let parts: Vec<&str> = value.split_whitespace().collect();
    let names: Vec<String> = match parts.as_slice() {
        ["LIST", ..] => rest
            .iter()
            .map(|l| l.trim().to_string())
            .filter(|l| !l.is_empty())
            .collect(),
        [name] => vec![name.to_string()],
        [pattern, first, last, step, ..] => {
            let (first, last, step): (i64, i64, i64) =
                (first.parse().ok()?, last.parse().ok()?, step.parse().ok()?);
            if step == 0 || (last - first).signum() * step.signum() < 0 {
                return None;
            }
            let count = (last - first) / step + 1;
            if count > 1 << 24 {
                return None;
            }
            (0..count)
                .map(|k| printf_d(pattern, first + k * step))
                .collect::<Option<_>>()?
        }
        _ => return None,
    };
    if names.is_empty() {
        return None;
    }
    Some(names.into_iter().map(|n| dir.join(n)).collect())
}

/// The widest `%Nd` a file name can hold: no file system takes a longer name, and `format!`
/// panics past `u16::MAX` ("Formatting argument out of range").
const MAX_NAME_WIDTH: usize = 255;

/// Substitutes `v` for the single `%d`, `%Nd` or `%0Nd` in `pattern`; `None` for a width past
/// [`MAX_NAME_WIDTH`].
fn printf_d(pattern: &str, v: i64) -> Option<String> {
    let start = pattern.find('%')?;
    let rest = &pattern[start + 1..];
    let end = rest.find('d')?;
    let spec = &rest[..end];
    let zero = spec.starts_with('0');
    let width: usize = if spec.is_empty() {
        0
    } else {
        spec.parse().ok().filter(|&w| w <= MAX_NAME_WIDTH)?
    };
    let num = if zero {
        format!("{v:0width$}")
    } else {
        format!("{v:width$}")
    };
    Some(format!("{}{}{}", &pattern[..start], num, &rest[end + 1..]))
}

#[cfg(test)]
pub(crate) mod tests;
