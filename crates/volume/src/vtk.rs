//! VTK legacy `.vtk` files, `DATASET STRUCTURED_POINTS` only, BINARY (big-endian by definition
//! of the format) or ASCII. Binary payloads are memory-mapped at their offset; ASCII streams.
//! A file may carry several `SCALARS` arrays: [`OpenOptions::array`] picks one by name, otherwise
//! the first is used. `COLOR_SCALARS name 1` (what vtkStructuredPointsWriter writes for unsigned
//! char scalars) is read as u8: raw bytes in binary files, values in [0, 1] in ASCII ones, scaled
//! back to 0..255.

use crate::codec::AsciiValues;
use crate::grid::dims_text;
use crate::raw::{Payload, RawVolume, payload_bytes};
use crate::stream::{Stream, StreamSpec, StreamVolume, skip_bytes};
use crate::{Dtype, Endian, OpenOptions, Orientation, VolumeError, VolumeSource};
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
    /// `COLOR_SCALARS`: ASCII values are v / 255.
    color: bool,
}

/// Opens a VTK legacy structured-points file.
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_raw_params(path, "VTK legacy")?;
    let want = opts.array.clone();
    let (h, mut reader) = locate(path, want.as_deref())?;
    // A negative SPACING is how VTK before 9 stored a flipped axis (the origin is voxel 0's
    // position, the axis steps backwards): the grid takes its length, the pipeline the flip.
    let orientation = Orientation::from_flips(h.spacing.map(|s| s < 0.0));
    let grid = opts.grid(path, h.dims, h.spacing.map(f64::abs), h.origin)?;
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
            orientation,
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
            let (h, r) = locate(&owned, want.as_deref())?;
            let values = AsciiValues::new(r, None);
            Ok(Box::new(if h.color {
                values.unit_to_byte()
            } else {
                values
            }) as Stream)
        }),
        exact_end: false,
        orientation,
    })?))
}

/// The header's lines, numbered for messages.
struct Lines<'a> {
    path: &'a Path,
    r: BufReader<File>,
    n: usize,
}

impl Lines<'_> {
    fn err(&self, expected: &str, found: &str) -> VolumeError {
        VolumeError::format(self.path, format!("line {}", self.n), expected, found)
    }

    fn io(&self, e: std::io::Error) -> VolumeError {
        VolumeError::io(self.path, "read", e)
    }

    /// The next line, trimmed; blank lines are skipped after the title. None at end of file.
    fn next(&mut self) -> Result<Option<String>, VolumeError> {
        loop {
            let mut raw = Vec::new();
            let got = (&mut self.r)
                .take(MAX_LINE)
                .read_until(b'\n', &mut raw)
                .map_err(|e| self.io(e))?;
            if got == 0 {
                return Ok(None);
            }
            self.n += 1;
            let line = String::from_utf8_lossy(&raw).trim().to_string();
            if !line.is_empty() || self.n <= 2 {
                return Ok(Some(line));
            }
        }
    }

    /// Consumes a `LOOKUP_TABLE` line if one follows (the format makes it optional).
    fn skip_lookup_table(&mut self) -> Result<(), VolumeError> {
        let before = self.r.stream_position().map_err(|e| self.io(e))?;
        let mut peek = Vec::new();
        (&mut self.r)
            .take(MAX_LINE)
            .read_until(b'\n', &mut peek)
            .map_err(|e| self.io(e))?;
        let text = String::from_utf8_lossy(&peek)
            .trim_start()
            .to_ascii_uppercase();
        if text.starts_with("LOOKUP_TABLE") {
            self.n += 1;
            return Ok(());
        }
        self.r
            .seek(std::io::SeekFrom::Start(before))
            .map(|_| ())
            .map_err(|e| self.io(e))
    }
}

/// Parses the header and returns a reader positioned at the first value of the wanted array.
fn locate(path: &Path, want: Option<&str>) -> Result<(Header, BufReader<File>), VolumeError> {
    let f = File::open(path).map_err(|e| VolumeError::io(path, "open", e))?;
    let mut l = Lines {
        path,
        r: BufReader::new(f),
        n: 0,
    };
    let magic = l.next()?.unwrap_or_default();
    if !magic.starts_with("# vtk DataFile") {
        return Err(l.err("\"# vtk DataFile Version x.x\"", &magic));
    }
    l.next()?; // title
    let binary = match l.next()?.unwrap_or_default().to_ascii_uppercase().as_str() {
        "BINARY" => true,
        "ASCII" => false,
        other => return Err(l.err("ASCII or BINARY", other)),
    };
    let (mut dims, mut spacing, mut origin, mut count) = (None, [1.0; 3], [0.0; 3], None);
    let mut seen = Vec::new();
    while let Some(line) = l.next()? {
        let words: Vec<&str> = line.split_whitespace().collect();
        let (key, args) = (words[0].to_ascii_uppercase(), &words[1..]);
        match key.as_str() {
            "DATASET"
                if args.first().map(|s| s.to_ascii_uppercase()).as_deref()
                    != Some("STRUCTURED_POINTS") =>
            {
                return Err(l.err("DATASET STRUCTURED_POINTS (a regular grid)", &line));
            }
            "DATASET" => {}
            "DIMENSIONS" => {
                dims = Some(three::<u64>(args).ok_or_else(|| l.err("DIMENSIONS nx ny nz", &line))?)
            }
            "SPACING" | "ASPECT_RATIO" => {
                spacing = three::<f64>(args).ok_or_else(|| l.err("SPACING sx sy sz", &line))?
            }
            "ORIGIN" => origin = three::<f64>(args).ok_or_else(|| l.err("ORIGIN x y z", &line))?,
            "POINT_DATA" => {
                let c = args.first().and_then(|c| c.parse::<u64>().ok());
                count = Some(c.ok_or_else(|| l.err("POINT_DATA count", &line))?);
            }
            "SCALARS" | "COLOR_SCALARS" => {
                let d = dims.ok_or_else(|| l.err("DIMENSIONS before the data", &line))?;
                let c = count.ok_or_else(|| l.err("POINT_DATA before SCALARS", &line))?;
                if Some(c) != d[0].checked_mul(d[1]).and_then(|s| s.checked_mul(d[2])) {
                    return Err(l.err(
                        &format!("POINT_DATA equal to dims {}", dims_text(d)),
                        &c.to_string(),
                    ));
                }
                let color = key == "COLOR_SCALARS";
                let (name, dtype) = if color {
                    let [name, components] = args else {
                        return Err(l.err("COLOR_SCALARS name nValues", &line));
                    };
                    if *components != "1" {
                        return Err(l.err(
                            "COLOR_SCALARS with 1 component (isostream meshes one scalar; save one component of the colors as SCALARS)",
                            &line,
                        ));
                    }
                    (name, Dtype::U8)
                } else {
                    let [name, ty, rest @ ..] = args else {
                        return Err(l.err("SCALARS name type", &line));
                    };
                    let dtype = vtk_type(ty).ok_or_else(|| {
                        l.err("a type among unsigned_char/char/unsigned_short/short/unsigned_int/int/float/double", ty)
                    })?;
                    if rest.first().is_some_and(|c| *c != "1") {
                        return Err(l.err("one component per voxel", &line));
                    }
                    l.skip_lookup_table()?;
                    (name, dtype)
                };
                if want.is_none_or(|w| w == *name) {
                    let header = Header {
                        dims: d,
                        spacing,
                        origin,
                        dtype,
                        binary,
                        color,
                    };
                    return Ok((header, l.r));
                }
                seen.push(name.to_string());
                skip_values(&mut l.r, binary, c, dtype)
                    .map_err(|e| l.err(&format!("{c} values of {name}"), &e.to_string()))?;
            }
            _ => {
                return Err(l.err(
                    "DIMENSIONS, SPACING, ORIGIN, POINT_DATA, SCALARS or COLOR_SCALARS",
                    &line,
                ));
            }
        }
    }
    let expected = match want {
        Some(w) => format!("a SCALARS array named {w:?} (arrays: {})", seen.join(", ")),
        None => "a SCALARS array".to_string(),
    };
    Err(VolumeError::format(path, "end of file", expected, "none"))
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
