//! The voxel size a TIFF stack's own metadata gives, so that microscopy stacks mesh in physical
//! units as every other reader's header does (z steps are usually 2-10 times the pixel size: in
//! voxel units the mesh came out squashed).
//!
//! - OME-TIFF: the first `Pixels` element of the OME-XML in the first page's ImageDescription
//!   (image 0, the series this reader reads), `PhysicalSizeX/Y/Z` in `PhysicalSizeXUnit` etc.
//!   (µm when absent, the OME schema's default). The resolution tags are not read: OME says it.
//! - ImageJ (a description starting `ImageJ=`): x and y from the XResolution / YResolution tags
//!   (pixels per unit: spacing = 1 / resolution), z from `spacing=`, in `unit=` (`yunit=`,
//!   `zunit=` when ImageJ's axes differ), or in inches / centimetres when ResolutionUnit says so.
//!   A description with neither `unit=` nor `spacing=` is an uncalibrated image (ImageJ writes
//!   them only for a calibrated one): no voxel size.
//! - Any other TIFF: no voxel size, even with resolution tags. They are a print size (scanners
//!   and image libraries write 72 or 300 dpi, the `tiff` crate 1 per nothing, whatever the
//!   pixels are), and they never say the z step: x and y in centimetres beside a z of 1 voxel
//!   gave a mesh stretched ten thousand times along z, worse than the voxel units it replaced.
//!
//! An axis the metadata gives no size is 1 in the x axis's unit (ImageJ's own default for its
//! pixel depth). The three sizes are brought to the x axis's unit when the axes' units differ
//! and are lengths this module knows; other mixes are refused. Sizes are kept as the file says
//! them (a value that is not a number, a zero resolution): [`crate::OpenOptions::grid`] refuses
//! one that is not finite and > 0 as it refuses any header's, naming `[input] spacing`.

use super::TiffDecoder;
use crate::VolumeError;
use crate::xml::Tags;
use std::path::Path;
use tiff::decoder::ifd::Value;
use tiff::tags::Tag;

/// A voxel size read from a TIFF's metadata, all three axes in one unit.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FileSpacing {
    pub spacing: [f64; 3],
    /// The unit of all three: a known length's name in ASCII ("um", "angstrom": the stack's
    /// description goes into every mesh header, and PLY readers take its header as ASCII), else
    /// the file's own word for it ("pixel"). Meshes carry no unit, so it is only told.
    pub unit: String,
    /// Which metadata said it: "ImageJ" or "OME-XML".
    pub from: &'static str,
}

impl std::fmt::Display for FileSpacing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.spacing;
        write!(
            f,
            "voxel {x} x {y} x {z} {} from its {} metadata",
            self.unit, self.from
        )
    }
}

/// The voxel size the first page's metadata gives (`desc`: its ImageDescription), if any.
pub(crate) fn read(
    path: &Path,
    desc: Option<&str>,
    d: &mut TiffDecoder,
) -> Result<Option<FileSpacing>, VolumeError> {
    match desc {
        Some(desc) if desc.starts_with("ImageJ=") => imagej(path, desc, d),
        Some(desc) if desc.contains("<OME") => ome(path, desc),
        _ => Ok(None),
    }
}

fn imagej(
    path: &Path,
    desc: &str,
    d: &mut TiffDecoder,
) -> Result<Option<FileSpacing>, VolumeError> {
    let value = |key: &'static str| super::imagej_values(desc, key).next();
    if value("unit").is_none() && value("spacing").is_none() {
        return Ok(None);
    }
    // ImageJ's own reading (`FileOpener.decodeDescriptionString`, `TiffDecoder`), which is what
    // a user compares the mesh with in Fiji: the description's unit wins for every axis; the
    // resolution tags are numbers in it, but for a centimetre tag under a micrometre unit (a
    // tag unit ImageJ converts, x 10,000) and 72 per inch, the print size other writers leave,
    // which ImageJ takes as uncalibrated. (Taking the tag's unit for x and y made a file re-saved
    // with 72 dpi 353 um wide a pixel where ImageJ shows 1 um.)
    let tag_unit = d
        .find_tag_unsigned::<u16>(Tag::ResolutionUnit)
        .ok()
        .flatten();
    let base = value("unit").map(unit).unwrap_or_else(|| unit("pixel"));
    let xy_scale = if tag_unit == Some(3) && base.name == "um" {
        1e4
    } else {
        1.0
    };
    let y_unit = value("yunit").map(unit).unwrap_or_else(|| base.clone());
    let z_unit = value("zunit").map(unit).unwrap_or_else(|| base.clone());
    let mut xy = |tag: Tag| {
        resolution(d, tag)
            .filter(|&s| !(tag_unit == Some(2) && s == 1.0 / 72.0))
            .map(|s| s * xy_scale)
    };
    let sizes = [
        (xy(Tag::XResolution), base),
        (xy(Tag::YResolution), y_unit),
        (value("spacing").map(number), z_unit),
    ];
    in_x_unit(path, "ImageJ", sizes).map(Some)
}

/// 1 / a resolution tag (pixels per unit), `None` when absent or unreadable. A zero numerator
/// gives an infinite size, a zero denominator 0 or NaN: refused with the other bad sizes.
fn resolution(d: &mut TiffDecoder, tag: Tag) -> Option<f64> {
    match d.find_tag(tag).ok().flatten()? {
        Value::Rational(n, per) => Some(f64::from(per) / f64::from(n)),
        other => other.into_f64().ok().map(|r| 1.0 / r),
    }
}

fn ome(path: &Path, desc: &str) -> Result<Option<FileSpacing>, VolumeError> {
    // The crate's XML tag scanner rather than a text search: attributes of the first `Pixels`
    // element only (a text search for "PhysicalSizeX" finds any image's, or the unit's), in
    // either quote, with or without a namespace prefix. XML it cannot read before that element
    // leaves the stack without a voxel size, as before this reader took one.
    let Some(pixels) = Tags::new(desc.as_bytes())
        .map_while(Result::ok)
        .find(|t| !t.closing && (t.name == "Pixels" || t.name.ends_with(":Pixels")))
    else {
        return Ok(None);
    };
    let axis = |a: &str| {
        (
            pixels.attr(&format!("PhysicalSize{a}")).map(number),
            unit(pixels.attr(&format!("PhysicalSize{a}Unit")).unwrap_or("µm")),
        )
    };
    let sizes = [axis("X"), axis("Y"), axis("Z")];
    if sizes.iter().all(|(size, _)| size.is_none()) {
        return Ok(None);
    }
    in_x_unit(path, "OME-XML", sizes).map(Some)
}

/// A size as written; NaN when it is not a number, so that the grid's check refuses it with the
/// other impossible sizes.
fn number(text: &str) -> f64 {
    text.trim().parse().unwrap_or(f64::NAN)
}

/// A unit as a file names it, with its length in metres when it is one we know.
#[derive(Debug, Clone, PartialEq)]
struct Unit {
    name: String,
    metres: Option<f64>,
}

/// Reads a unit's name: OME's symbols, ImageJ's words ("micron", ImageJ's `um` for µm and the
/// `\u00B5m` escape some writers leave in its description), and TIFF's inch and centimetre.
fn unit(text: &str) -> Unit {
    let text = text.trim();
    let known = match text {
        "km" => Some(("km", 1e3)),
        "m" => Some(("m", 1.0)),
        "dm" => Some(("dm", 1e-1)),
        "cm" => Some(("cm", 1e-2)),
        "mm" => Some(("mm", 1e-3)),
        "\u{b5}m" | "\u{3bc}m" | "um" | "\\u00B5m" | "\\u00b5m" | "&#181;m" | "&#xB5;m" => {
            Some(("um", 1e-6))
        }
        "nm" => Some(("nm", 1e-9)),
        "pm" => Some(("pm", 1e-12)),
        "\u{c5}" | "\u{212b}" => Some(("angstrom", 1e-10)),
        "in" => Some(("inch", 0.0254)),
        _ => match text.to_ascii_lowercase().trim_end_matches('s') {
            "meter" | "metre" => Some(("m", 1.0)),
            "centimeter" | "centimetre" => Some(("cm", 1e-2)),
            "millimeter" | "millimetre" => Some(("mm", 1e-3)),
            "micron" | "micrometer" | "micrometre" => Some(("um", 1e-6)),
            "nanometer" | "nanometre" => Some(("nm", 1e-9)),
            "angstrom" => Some(("angstrom", 1e-10)),
            "inch" | "inche" => Some(("inch", 0.0254)),
            _ => None,
        },
    };
    match known {
        Some((name, metres)) => Unit {
            name: name.to_string(),
            metres: Some(metres),
        },
        None => Unit {
            name: text.to_string(),
            metres: None,
        },
    }
}

/// Brings the sizes of x, y and z (`None`: not given, 1 in x's unit) to the x axis's unit.
/// Units that differ convert when both are known lengths; otherwise the stack is refused, naming
/// `[input] spacing`, since a guess would give the mesh a wrong aspect ratio silently.
fn in_x_unit(
    path: &Path,
    from: &'static str,
    sizes: [(Option<f64>, Unit); 3],
) -> Result<FileSpacing, VolumeError> {
    let x = sizes[0].1.clone();
    let mut spacing = [1.0; 3];
    for (k, (size, u)) in sizes.into_iter().enumerate() {
        let Some(size) = size else { continue };
        spacing[k] = if u.name == x.name {
            size
        } else if let (Some(m), Some(mx)) = (u.metres, x.metres) {
            size * m / mx
        } else {
            return Err(VolumeError::Grid {
                origin: path.display().to_string(),
                problem: format!(
                    "ImageDescription: the {from} metadata gives the voxel size in {:?} along x but in {:?} along {}, which do not convert; set [input] spacing",
                    x.name,
                    u.name,
                    ["x", "y", "z"][k]
                ),
            });
        };
    }
    Ok(FileSpacing {
        spacing,
        unit: x.name,
        from,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_names() {
        for (text, name, metres) in [
            ("micron", "um", Some(1e-6)),
            ("Microns", "um", Some(1e-6)),
            ("um", "um", Some(1e-6)),
            ("\\u00B5m", "um", Some(1e-6)),
            ("\u{3bc}m", "um", Some(1e-6)),
            ("\u{b5}m", "um", Some(1e-6)),
            ("\u{212b}", "angstrom", Some(1e-10)),
            (" nm ", "nm", Some(1e-9)),
            ("inches", "inch", Some(0.0254)),
            ("pixel", "pixel", None),
            ("reference frame", "reference frame", None),
        ] {
            assert_eq!(
                unit(text),
                Unit {
                    name: name.into(),
                    metres
                },
                "{text}"
            );
        }
    }

    /// Known lengths convert to x's unit; a missing size is 1 in x's unit; an unknown unit
    /// beside another is refused in one line naming the override.
    #[test]
    fn axes_in_other_units() {
        let p = Path::new("s.tif");
        let got = in_x_unit(
            p,
            "OME-XML",
            [
                (Some(300.0), unit("nm")),
                (Some(0.3), unit("µm")),
                (None, unit("mm")),
            ],
        )
        .unwrap();
        assert_eq!(got.unit, "nm");
        assert_eq!(got.spacing[2], 1.0);
        assert!((got.spacing[1] - 300.0).abs() < 1e-9, "{got:?}");
        let e = in_x_unit(
            p,
            "ImageJ",
            [
                (Some(0.5), unit("micron")),
                (Some(0.5), unit("micron")),
                (Some(2.0), unit("pixel")),
            ],
        )
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            "s.tif: ImageDescription: the ImageJ metadata gives the voxel size in \"um\" along x but in \"pixel\" along z, which do not convert; set [input] spacing"
        );
    }
}
