//! NIfTI-1 single files (`.nii`, `.nii.gz`) and `.hdr`/`.img` pairs (or `.hdr.gz`/`.img.gz`), with `scl_slope` /
//! `scl_inter` scaling and `pixdim` voxel sizes.
//!
//! The header is a fixed 348-byte struct, so we read the dozen fields we need by offset instead
//! of pulling the `nifti` crate, whose ndarray dependency would pin ndarray for the whole workspace
//! and whose volume API loads whole arrays. `.nii` payloads are memory-mapped; `.nii.gz` streams.
//!
//! Placement follows nibabel and the NIfTI-1 standard: the sform when `sform_code > 0` (spacing
//! its columns' lengths, origin its translation: tools that rewrite only the sform leave a stale
//! `pixdim`), else the qform when `qform_code > 0` (`pixdim` and `qoffset`), else `pixdim` from
//! 0. Axis flips and rotations are not applied (isostream grids are axis-aligned): meshes come
//! out in voxel-index orientation from that origin, and the source reports what it dropped
//! ([`VolumeSource::orientation`]).

use crate::dtype::Scale;
use crate::orientation::step_length;
use crate::raw::{Payload, RawVolume};
use crate::stream::{Stream, StreamSpec, StreamVolume, open_at, skip_bytes};
use crate::{Dtype, Endian, Grid, OpenOptions, Orientation, VolumeError, VolumeSource};
use flate2::read::MultiGzDecoder;
use std::io::Read;
use std::path::Path;

const HEADER: usize = 348;

#[derive(Debug)]
struct Header {
    endian: Endian,
    dims: [u64; 3],
    dtype: Dtype,
    spacing: [f64; 3],
    origin: [f64; 3],
    orientation: Orientation,
    vox_offset: u64,
    slope: f32,
    inter: f32,
    /// `ni1`: the voxels are in a separate `.img` file.
    pair: bool,
}

/// Opens a NIfTI-1 file; `.gz` names are decompressed as a stream.
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    opts.reject_raw_params(path, "NIfTI-1")?;
    opts.reject_array(path, "NIfTI-1")?;
    let gz = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gz"));
    let mut bytes = [0u8; HEADER];
    let read = |r: &mut dyn Read, bytes: &mut [u8]| {
        r.read_exact(bytes).map_err(|e| {
            VolumeError::format(path, "header", "a 348-byte NIfTI-1 header", e.to_string())
        })
    };
    if gz {
        read(&mut MultiGzDecoder::new(open_at(path, 0)?), &mut bytes)?;
    } else {
        read(&mut open_at(path, 0)?, &mut bytes)?;
    }
    let h = parse(path, &bytes)?;
    let grid = opts.grid(path, h.dims, h.spacing, h.origin)?;
    // A pair's voxels are in the `.img` beside the `.hdr`, both gzipped when the header is
    // (nibabel writes `.hdr.gz` with `.img.gz`).
    let data = match (h.pair, gz) {
        (false, _) => path.to_path_buf(),
        (true, false) => path.with_extension("img"),
        (true, true) => path.with_extension("").with_extension("img.gz"),
    };
    // scl_slope 0 means "no scaling" in NIfTI-1; identity scaling is skipped for speed.
    let scale = (h.slope != 0.0 && h.slope.is_finite() && !(h.slope == 1.0 && h.inter == 0.0))
        .then(|| Scale {
            slope: h.slope,
            inter: if h.inter.is_finite() { h.inter } else { 0.0 },
            header: path.to_path_buf(),
        });
    if gz {
        let skip = h.vox_offset;
        let stream = StreamVolume::new(StreamSpec {
            path: data.clone(),
            what: "gzip NIfTI voxels",
            grid,
            dtype: h.dtype,
            stored: h.dtype,
            endian: h.endian,
            open: Box::new(move || {
                let mut s: Stream = Box::new(MultiGzDecoder::new(open_at(&data, 0)?));
                skip_bytes(&mut s, skip).map_err(|e| {
                    VolumeError::format(
                        &data,
                        "vox_offset",
                        format!("{skip} header bytes"),
                        e.to_string(),
                    )
                })?;
                Ok(s)
            }),
            exact_end: false,
            orientation: h.orientation,
        })?;
        Ok(Box::new(stream.with_scale(scale)))
    } else {
        Ok(Box::new(raw(&data, &h, grid)?.with_scale(scale)))
    }
}

fn raw(data: &Path, h: &Header, grid: Grid) -> Result<RawVolume, VolumeError> {
    RawVolume::open_payload(Payload {
        path: data,
        grid,
        dtype: h.dtype,
        endian: h.endian,
        offset: h.vox_offset,
        trailing_ok: true,
        hint: "check the NIfTI header's dim, datatype and vox_offset",
        orientation: h.orientation,
    })
}

fn parse(path: &Path, b: &[u8; HEADER]) -> Result<Header, VolumeError> {
    let at = |field: &str| format!("header field {field}");
    let err = |field: &str, expected: &str, found: String| {
        VolumeError::format(path, at(field), expected, found)
    };
    let le = i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    let endian = match (le, i32::from_be_bytes([b[0], b[1], b[2], b[3]])) {
        (348, _) => Endian::Little,
        (_, 348) => Endian::Big,
        (540, _) | (_, 540) => {
            return Err(err(
                "sizeof_hdr",
                "348 (NIfTI-1; NIfTI-2 is not supported)",
                "540".into(),
            ));
        }
        _ => return Err(err("sizeof_hdr", "348 (NIfTI-1)", le.to_string())),
    };
    let i16_at = |o: usize| {
        let a = [b[o], b[o + 1]];
        match endian {
            Endian::Little => i16::from_le_bytes(a),
            Endian::Big => i16::from_be_bytes(a),
        }
    };
    let f32_at = |o: usize| {
        let a = [b[o], b[o + 1], b[o + 2], b[o + 3]];
        match endian {
            Endian::Little => f32::from_le_bytes(a),
            Endian::Big => f32::from_be_bytes(a),
        }
    };
    let magic = &b[344..348];
    let pair = match magic {
        b"n+1\0" => false,
        b"ni1\0" => true,
        _ => {
            return Err(err(
                "magic",
                "\"n+1\" or \"ni1\"",
                String::from_utf8_lossy(magic).into_owned(),
            ));
        }
    };
    let dim: Vec<i16> = (0..8).map(|k| i16_at(40 + 2 * k)).collect();
    let rank = dim[0];
    if !(3..=7).contains(&rank) || dim[4..rank as usize + 1].iter().any(|&d| d != 1) {
        return Err(err(
            "dim",
            "a 3D volume (dim[0] >= 3 and dim[4..] = 1)",
            format!("{:?}", &dim[..(rank.clamp(0, 7) as usize + 1)]),
        ));
    }
    let mut dims = [0u64; 3];
    for a in 0..3 {
        dims[a] = u64::try_from(dim[a + 1])
            .map_err(|_| err("dim", "positive sizes", format!("{:?}", &dim[1..4])))?;
    }
    let code = i16_at(70);
    let dtype = match code {
        2 => Dtype::U8,
        4 => Dtype::I16,
        8 => Dtype::I32,
        16 => Dtype::F32,
        64 => Dtype::F64,
        256 => Dtype::I8,
        512 => Dtype::U16,
        768 => Dtype::U32,
        _ => {
            return Err(err(
                "datatype",
                "a scalar type code (2, 4, 8, 16, 64, 256, 512, 768)",
                code.to_string(),
            ));
        }
    };
    let vox = f32_at(108);
    let min_offset = if pair { 0.0 } else { HEADER as f32 };
    if !vox.is_finite() || vox < min_offset || vox.fract() != 0.0 {
        return Err(err(
            "vox_offset",
            &format!("a whole number of bytes >= {min_offset}"),
            vox.to_string(),
        ));
    }
    let f64_at = |o: usize| f64::from(f32_at(o));
    let pixdim = [1, 2, 3].map(|k| f64_at(76 + 4 * k).abs());
    let (spacing, origin, orientation) = if i16_at(254) > 0 {
        // srow_x, srow_y, srow_z: the affine's rows; column k is index axis k's step.
        let rows = [280, 296, 312].map(|o| [0, 1, 2, 3].map(|c| f64_at(o + 4 * c)));
        let columns = [0, 1, 2].map(|k| rows.map(|r| r[k]));
        (
            columns.map(step_length),
            rows.map(|r| r[3]),
            Orientation::of_columns(columns),
        )
    } else if i16_at(252) > 0 {
        let origin = [268, 272, 276].map(f64_at);
        (pixdim, origin, qform_orientation(&f64_at))
    } else {
        (pixdim, [0.0; 3], Orientation::Aligned)
    };
    Ok(Header {
        endian,
        dims,
        dtype,
        spacing,
        origin,
        orientation,
        vox_offset: vox as u64,
        slope: f32_at(112),
        inter: f32_at(116),
        pair,
    })
}

/// The axes of the qform (NIfTI-1 method 2): the rotation of the quaternion (b, c, d) at bytes
/// 256..268, its z column negated when `qfac` (`pixdim[0]`) is negative. Lengths do not matter:
/// only the directions are compared with the axes.
fn qform_orientation(f64_at: &dyn Fn(usize) -> f64) -> Orientation {
    let [b, c, d] = [256, 260, 264].map(f64_at);
    let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
    let r = [
        [
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
        ],
        [
            2.0 * (b * c + a * d),
            a * a + c * c - b * b - d * d,
            2.0 * (c * d - a * b),
        ],
        [
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a + d * d - c * c - b * b,
        ],
    ];
    let qfac = if f64_at(76) < 0.0 { -1.0 } else { 1.0 };
    Orientation::of_columns([0, 1, 2].map(|k| {
        let sign = if k == 2 { qfac } else { 1.0 };
        r.map(|row| row[k] * sign)
    }))
}

#[cfg(test)]
pub(crate) mod tests;
