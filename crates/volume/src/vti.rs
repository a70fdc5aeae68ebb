//! VTK XML ImageData (`.vti`): one piece, point data arrays in `ascii`, `binary` (base64) or
//! `appended` (raw or base64) form, optionally zlib-compressed (`vtkZLibDataCompressor`), with
//! `header_type` UInt32 or UInt64 and either byte order.
//!
//! Nothing here loads the whole array: uncompressed appended raw data is memory-mapped like a raw
//! file; every other form streams through base64 / zlib-block decoders that keep one block
//! (VTK writes 32 KiB blocks) in memory. `Direction` is not applied (grids are axis-aligned): the
//! source reports its flips or rotation ([`VolumeSource::orientation`]).

use crate::codec::{AsciiValues, Base64Reader, ZlibBlocks, ZlibLayout};
use crate::raw::{MappedFile, Payload, RangeReader, RawVolume, checked_payload, map_file};
use crate::stream::{Stream, StreamSpec, StreamVolume};
use crate::xml::{Tag, Tags};
use crate::{Dtype, Endian, Grid, OpenOptions, Orientation, VolumeError, VolumeSource};
use std::io::Read;
use std::path::Path;
use std::sync::Arc;

/// How the chosen array's bytes are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Form {
    Ascii,
    /// Base64 text starting at a byte offset of the file.
    Base64,
    /// Raw bytes starting at a byte offset of the file.
    Raw,
}

/// Everything needed to open a payload stream again.
#[derive(Debug, Clone, Copy)]
struct Layout {
    form: Form,
    start: usize,
    endian: Endian,
    header_u64: bool,
    compressed: bool,
}

/// Opens a `.vti` file.
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_raw_params(path, "VTK XML ImageData")?;
    let map = map_file(path)?;
    let doc = Doc::scan(path, &map)?;
    let (endian, header_u64, compressed) = file_settings(path, &doc.root)?;
    let (grid, orientation) = image_grid(path, &doc, opts)?;
    let array = doc.pick(path, opts.array.as_deref())?;
    let at = format!("DataArray {:?}", array.attr("Name").unwrap_or(""));
    let (dtype, form, start) = array_form(path, &at, &array, doc.appended, map.len())?;
    let layout = Layout {
        form,
        start,
        endian,
        header_u64,
        compressed: compressed && form != Form::Ascii,
    };
    let payload = checked_payload(path, grid.dims, dtype, 0, "WholeExtent")?;
    // Read the block header once now, so a broken header fails at open time with its own message.
    let data_start = check_header(path, &at, &map, layout, payload)?;
    if layout.form == Form::Raw && !layout.compressed {
        return Ok(Box::new(RawVolume::open_payload(Payload {
            path,
            grid,
            dtype,
            endian,
            offset: data_start as u64,
            trailing_ok: true,
            hint: "check WholeExtent, the DataArray type and offset",
            orientation,
        })?));
    }
    let (decode_as, what) = match (layout.form, layout.compressed) {
        (Form::Ascii, _) => (Dtype::F64, "ascii VTI array"),
        (_, true) => (dtype, "zlib VTI array"),
        _ => (dtype, "base64 VTI array"),
    };
    let owned = path.to_path_buf();
    Ok(Box::new(StreamVolume::new(StreamSpec {
        path: path.to_path_buf(),
        what,
        grid,
        dtype: decode_as,
        stored: dtype,
        // AsciiValues emits little-endian f64 whatever the file's byte order.
        endian: if form == Form::Ascii {
            Endian::Little
        } else {
            endian
        },
        open: Box::new(move || open_stream(&owned, &at, &map, layout, payload).map(|(s, _)| s)),
        exact_end: false,
        orientation,
    })?))
}

/// Byte order, header word size and compression from the `VTKFile` tag.
fn file_settings(path: &Path, root: &Tag) -> Result<(Endian, bool, bool), VolumeError> {
    let err =
        |expected: &str, found: &str| VolumeError::format(path, "VTKFile tag", expected, found);
    if root.attr("type") != Some("ImageData") {
        return Err(err(
            "type=\"ImageData\"",
            root.attr("type").unwrap_or("none"),
        ));
    }
    let endian = match root.attr("byte_order") {
        None | Some("LittleEndian") => Endian::Little,
        Some("BigEndian") => Endian::Big,
        Some(o) => return Err(err("byte_order LittleEndian or BigEndian", o)),
    };
    let header_u64 = match root.attr("header_type") {
        None | Some("UInt32") => false,
        Some("UInt64") => true,
        Some(h) => return Err(err("header_type UInt32 or UInt64", h)),
    };
    let compressed = match root.attr("compressor") {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(c) => return Err(err("no compressor or vtkZLibDataCompressor", c)),
    };
    Ok((endian, header_u64, compressed))
}

/// The grid of the `ImageData` tag, with the job's overrides. VTK places point (i, j, k) of the extent at
/// Origin + Spacing * (x0 + i, y0 + j, z0 + k), so the extent start moves the origin; with the
/// `Direction` (row-major, column k axis k's direction) it drops.
fn image_grid(
    path: &Path,
    doc: &Doc,
    opts: &OpenOptions,
) -> Result<(Grid, Orientation), VolumeError> {
    let err =
        |expected: &str, found: &str| VolumeError::format(path, "ImageData tag", expected, found);
    let image = doc
        .image
        .as_ref()
        .ok_or_else(|| VolumeError::format(path, "document", "an ImageData tag", "none"))?;
    let attr = |key: &str, default: &str, expected: &str| -> Result<Vec<f64>, VolumeError> {
        let text = image.attr(key).unwrap_or(default);
        text.split_whitespace()
            .map(|t| t.parse().ok())
            .collect::<Option<Vec<f64>>>()
            .filter(|v| v.len() == expected.split(' ').count())
            .ok_or_else(|| err(&format!("{key}=\"{expected}\""), text))
    };
    let extent = attr("WholeExtent", "", "x0 x1 y0 y1 z0 z1")?;
    let spacing = attr("Spacing", "1 1 1", "sx sy sz")?;
    let origin = attr("Origin", "0 0 0", "x y z")?;
    let direction = attr(
        "Direction",
        "1 0 0 0 1 0 0 0 1",
        "d00 d01 d02 d10 d11 d12 d20 d21 d22",
    )?;
    // Axis k steps by `Direction` column k times `Spacing[k]`: a negative spacing (how VTK
    // before 9 wrote a flipped axis) flips it like a negative direction.
    let orientation = Orientation::of_columns(
        [0, 1, 2]
            .map(|k| [direction[k], direction[3 + k], direction[6 + k]].map(|d| d * spacing[k])),
    );
    if doc.pieces != 1 {
        return Err(err("exactly one Piece", &doc.pieces.to_string()));
    }
    // Extents are integers in the file; as f64 they stay exact up to 2^53.
    let dims = [0, 1, 2].map(|a| {
        let n = extent[2 * a + 1] - extent[2 * a] + 1.0;
        if n.fract() == 0.0 && n >= 0.0 && n < u64::MAX as f64 {
            n as u64
        } else {
            0
        }
    });
    // Voxel (0, 0, 0) is the extent's first point: VTK puts point (x0, y0, z0) at `Origin +
    // Direction (Spacing * (x0, y0, z0))`, so on a flipped axis the extent's start steps
    // backwards too (cropped or `vtkExtractVOI` output; the flip is applied downstream).
    let origin = [0, 1, 2].map(|a| {
        origin[a]
            + (0..3)
                .map(|b| direction[3 * a + b] * spacing[b] * extent[2 * b])
                .sum::<f64>()
    });
    let grid = opts.grid(
        path,
        dims,
        [spacing[0].abs(), spacing[1].abs(), spacing[2].abs()],
        origin,
    )?;
    Ok((grid, orientation))
}

/// The stored type of the chosen array, its form and where its bytes start in the file.
fn array_form(
    path: &Path,
    at: &str,
    array: &Tag,
    appended: Option<(usize, bool)>,
    file_len: usize,
) -> Result<(Dtype, Form, usize), VolumeError> {
    let err = |expected: &str, found: &str| VolumeError::format(path, at, expected, found);
    let ty = array.attr("type").unwrap_or("none");
    let dtype = vti_type(ty).ok_or_else(|| {
        err(
            "type Int8/UInt8/Int16/UInt16/Int32/UInt32/Float32/Float64",
            ty,
        )
    })?;
    if let Some(c) = array.attr("NumberOfComponents").filter(|c| *c != "1") {
        return Err(err("NumberOfComponents=\"1\" (a scalar array)", c));
    }
    let (form, start) = match array.attr("format") {
        Some("ascii") => (Form::Ascii, array.end),
        Some("binary") => (Form::Base64, array.end),
        Some("appended") => {
            let (base, raw) = appended
                .ok_or_else(|| err("an AppendedData section for format=\"appended\"", "none"))?;
            let off = array.attr("offset").unwrap_or("0");
            let start = off
                .parse::<usize>()
                .ok()
                .and_then(|o| base.checked_add(o))
                .filter(|&s| s <= file_len)
                .ok_or_else(|| err(&format!("an offset inside the {file_len}-byte file"), off))?;
            (if raw { Form::Raw } else { Form::Base64 }, start)
        }
        other => {
            return Err(err(
                "format ascii, binary or appended",
                other.unwrap_or("none"),
            ));
        }
    };
    Ok((dtype, form, start))
}

/// Checks the array's header against the grid; returns where uncompressed raw data starts.
fn check_header(
    path: &Path,
    at: &str,
    map: &Arc<MappedFile>,
    layout: Layout,
    payload: u64,
) -> Result<usize, VolumeError> {
    open_stream(path, at, map, layout, payload).map(|(_, start)| start)
}

/// Opens the payload stream of the array, after reading and checking its block header.
/// Also returns the file offset of the first data byte (meaningful for raw forms only).
fn open_stream(
    path: &Path,
    at: &str,
    map: &Arc<MappedFile>,
    l: Layout,
    payload: u64,
) -> Result<(Stream, usize), VolumeError> {
    let reader = RangeReader::new(map.clone(), l.start);
    let mut encoded: Stream = match l.form {
        Form::Ascii => return Ok((Box::new(AsciiValues::new(reader, Some(b'<'))), l.start)),
        Form::Base64 => Box::new(Base64Reader::new(reader)),
        Form::Raw => Box::new(reader),
    };
    let word = if l.header_u64 { 8 } else { 4 };
    let herr = |what: String, found: String| {
        VolumeError::format(path, format!("{at} header"), what, found)
    };
    let next = |r: &mut Stream| -> Result<u64, VolumeError> {
        let mut b = [0u8; 8];
        r.read_exact(&mut b[..word])
            .map_err(|e| herr(format!("a {}-byte block header", word), e.to_string()))?;
        let v = match (l.endian, l.header_u64) {
            (Endian::Little, true) => u64::from_le_bytes(b),
            (Endian::Big, true) => u64::from_be_bytes(b),
            (Endian::Little, false) => u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            (Endian::Big, false) => u64::from(u32::from_be_bytes([b[0], b[1], b[2], b[3]])),
        };
        Ok(v)
    };
    if !l.compressed {
        let n = next(&mut encoded)?;
        if n != payload {
            return Err(herr(format!("{payload} bytes of data"), format!("{n}")));
        }
        return Ok((encoded, l.start + word));
    }
    let blocks = next(&mut encoded)?;
    let block_size = next(&mut encoded)?;
    let last_size = next(&mut encoded)?;
    // Every block needs a header word: more blocks than the file has bytes is a corrupt header.
    if blocks.saturating_mul(word as u64) > map.len() as u64
        || block_size > ZlibLayout::MAX_BLOCK
        || (blocks > 0 && block_size == 0)
    {
        return Err(herr(
            "a plausible zlib block header".into(),
            format!("{blocks} blocks of {block_size} bytes"),
        ));
    }
    let mut compressed = Vec::with_capacity(blocks as usize);
    for _ in 0..blocks {
        compressed.push(next(&mut encoded)?);
    }
    let zl = ZlibLayout {
        block_size,
        last_size,
        compressed,
    };
    if zl.total() != Some(payload) {
        return Err(herr(
            format!("{payload} uncompressed bytes"),
            format!("{blocks} blocks of {block_size} bytes, last {last_size}"),
        ));
    }
    Ok((Box::new(ZlibBlocks::new(encoded, zl)), l.start))
}

/// The tags of a VTI document that matter.
struct Doc {
    root: Tag,
    image: Option<Tag>,
    pieces: usize,
    /// Scalars attribute of PointData.
    scalars: Option<String>,
    arrays: Vec<Tag>,
    /// Names of CellData arrays, to tell a file of cell data why it is refused.
    cell_arrays: Vec<String>,
    /// File offset just after the `_` that starts appended data, and whether it is raw.
    appended: Option<(usize, bool)>,
}

impl Doc {
    fn scan(path: &Path, map: &[u8]) -> Result<Doc, VolumeError> {
        let bad = |off: usize| {
            VolumeError::format(
                path,
                format!("byte offset {off}"),
                "a well-formed XML tag",
                "something else",
            )
        };
        let mut root = None;
        let mut image = None;
        let (mut pieces, mut scalars, mut arrays, mut appended) = (0, None, Vec::new(), None);
        let mut in_point_data = false;
        let (mut in_cell_data, mut cell_arrays) = (false, Vec::new());
        for tag in Tags::new(map) {
            let tag = tag.map_err(bad)?;
            if root.is_none() {
                if tag.name != "VTKFile" {
                    let found =
                        String::from_utf8_lossy(&map[tag.start..tag.end.min(tag.start + 40)])
                            .into_owned();
                    return Err(VolumeError::format(
                        path,
                        "first tag",
                        "<VTKFile ...> (a VTK XML file)",
                        found,
                    ));
                }
                root = Some(tag);
                continue;
            }
            match (tag.name.as_str(), tag.closing) {
                ("ImageData", false) => image = Some(tag),
                ("Piece", false) => pieces += 1,
                ("PointData", closing) => {
                    in_point_data = !closing;
                    if !closing {
                        scalars = tag.attr("Scalars").map(str::to_string);
                    }
                }
                ("CellData", closing) => in_cell_data = !closing,
                ("DataArray", false) if in_point_data => arrays.push(tag),
                ("DataArray", false) if in_cell_data => {
                    cell_arrays.push(tag.attr("Name").unwrap_or("").to_string())
                }
                ("AppendedData", false) => {
                    let raw = tag.attr("encoding") == Some("raw");
                    let underscore =
                        map[tag.end..]
                            .iter()
                            .position(|&b| b == b'_')
                            .ok_or_else(|| {
                                VolumeError::format(
                                    path,
                                    format!("byte offset {}", tag.end),
                                    "'_' starting the appended data",
                                    "none",
                                )
                            })?;
                    appended = Some((tag.end + underscore + 1, raw));
                    // Binary data follows: no more tags to read.
                    break;
                }
                _ => {}
            }
        }
        let root = root.ok_or_else(|| {
            VolumeError::format(
                path,
                "byte offset 0",
                "<VTKFile ...> (a VTK XML file)",
                "no tags",
            )
        })?;
        Ok(Doc {
            root,
            image,
            pieces,
            scalars,
            arrays,
            cell_arrays,
            appended,
        })
    }

    /// The array named by the job, else PointData's active scalars, else the first array.
    fn pick(&self, path: &Path, wanted: Option<&str>) -> Result<Tag, VolumeError> {
        let names: Vec<&str> = self
            .arrays
            .iter()
            .map(|a| a.attr("Name").unwrap_or(""))
            .collect();
        let want = wanted.or(self.scalars.as_deref());
        let found = match want {
            Some(w) => self.arrays.iter().find(|a| a.attr("Name") == Some(w)),
            None => self.arrays.first(),
        };
        let in_cells = match want {
            Some(w) => self.cell_arrays.iter().any(|c| c == w),
            None => !self.cell_arrays.is_empty(),
        };
        if found.is_none() && in_cells {
            return Err(VolumeError::format(
                path,
                "CellData",
                "point data (isostream meshes values at the grid's points; convert the cells with VTK's vtkCellDataToPointData)",
                format!("cell data arrays [{}]", self.cell_arrays.join(", ")),
            ));
        }
        found.cloned().ok_or_else(|| {
            VolumeError::format(
                path,
                "PointData",
                match want {
                    Some(w) => format!("a DataArray named {w:?}"),
                    None => "a DataArray".to_string(),
                },
                format!("arrays [{}]", names.join(", ")),
            )
        })
    }
}

fn vti_type(s: &str) -> Option<Dtype> {
    Some(match s {
        "Int8" | "Char" => Dtype::I8,
        "UInt8" | "UnsignedChar" => Dtype::U8,
        "Int16" => Dtype::I16,
        "UInt16" => Dtype::U16,
        "Int32" => Dtype::I32,
        "UInt32" => Dtype::U32,
        "Float32" => Dtype::F32,
        "Float64" => Dtype::F64,
        _ => return None,
    })
}

#[cfg(test)]
pub(crate) mod tests;
