use super::*;
use crate::open_path;
use crate::testutil::read_all;
use tiff::encoder::{Rational, TiffEncoder, colortype};
use tiff::tags::{ResolutionUnit, Tag};

/// Writes 16-bit pages of 3x2 pixels valued z * 100 + i.
fn pages(path: &Path, n: u16) {
    let mut e = TiffEncoder::new(File::create(path).unwrap()).unwrap();
    for z in 0..n {
        let data: Vec<u16> = (0..6).map(|i| z * 100 + i).collect();
        e.write_image::<colortype::Gray16>(3, 2, &data).unwrap();
    }
}

fn want(n: u16) -> Vec<f32> {
    (0..n)
        .flat_map(|z| (0..6).map(move |i| f32::from(z * 100 + i)))
        .collect()
}

/// Finite f64 samples beyond f32's range read as ±f32::MAX and are counted.
#[test]
fn f64_samples_beyond_f32_are_saturated_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("stack.tif");
    let (values, want, n) = crate::testutil::beyond_f32();
    let mut e = TiffEncoder::new(File::create(&p).unwrap()).unwrap();
    for page in values.chunks(6) {
        e.write_image::<colortype::Gray64Float>(3, 2, page).unwrap();
    }
    drop(e);
    let (got, saturated) =
        crate::testutil::read_all_saturated(&p, &crate::OpenOptions::default()).unwrap();
    assert!(crate::testutil::same_values(&got, &want), "{got:?}");
    assert_eq!(saturated, n);
}

#[test]
fn multi_page_file_and_directory() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("stack.tif");
    pages(&p, 4);
    let opts = OpenOptions {
        spacing: Some([0.5, 0.5, 2.0]),
        ..Default::default()
    };
    assert_eq!(read_all(&p, &opts).unwrap(), want(4));
    let mut v = open_path(&p, &opts).unwrap();
    assert_eq!(v.grid().dims, [3, 2, 4]);
    assert_eq!(v.grid().spacing, [0.5, 0.5, 2.0]);
    assert_eq!(v.dtype(), Some(Dtype::U16));
    // Going back works.
    let mut out = [0.0f32; 6];
    v.read_slice(3, &mut out).unwrap();
    v.read_slice(1, &mut out).unwrap();
    assert_eq!(out[0], 100.0);

    let stack = dir.path().join("slices");
    std::fs::create_dir(&stack).unwrap();
    for z in 0..12u16 {
        let mut e =
            TiffEncoder::new(File::create(stack.join(format!("s{z}.tiff"))).unwrap()).unwrap();
        let data: Vec<f32> = (0..6).map(|i| f32::from(z * 100 + i)).collect();
        e.write_image::<colortype::Gray32Float>(3, 2, &data)
            .unwrap();
    }
    std::fs::write(stack.join("notes.txt"), "ignored").unwrap();
    assert_eq!(read_all(&stack, &OpenOptions::default()).unwrap(), want(12));
    assert_eq!(
        open_path(&stack, &OpenOptions::default()).unwrap().dtype(),
        Some(Dtype::F32)
    );
}

#[test]
fn natural_order() {
    let mut names = vec!["s10.tif", "s2.tif", "s1.tif", "a.tif"];
    names.sort_by_key(|n| natural_key(n));
    assert_eq!(names, ["a.tif", "s1.tif", "s2.tif", "s10.tif"]);
}

#[test]
fn bad_stacks_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let name = |p: &Path| p.display().to_string();
    // Not a TIFF.
    let p = dir.path().join("x.tif");
    std::fs::write(&p, b"not a tiff at all").unwrap();
    let e = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with(&format!(
            "{}: file header: expected a TIFF file, found ",
            name(&p)
        )),
        "{e}"
    );
    // Colour pages.
    let mut enc = TiffEncoder::new(File::create(&p).unwrap()).unwrap();
    enc.write_image::<colortype::RGB8>(2, 2, &[0u8; 12])
        .unwrap();
    enc.write_image::<colortype::RGB8>(2, 2, &[0u8; 12])
        .unwrap();
    drop(enc);
    let e = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: page 0: expected a single-channel grayscale page, found RGB(8); convert the stack to single-channel grayscale, one channel per stack (Fiji: Image > Color > Split Channels, or Image > Type > 8-bit)",
            name(&p)
        )
    );
    // Pages of different sizes.
    let mut enc = TiffEncoder::new(File::create(&p).unwrap()).unwrap();
    enc.write_image::<colortype::Gray8>(2, 2, &[0u8; 4])
        .unwrap();
    enc.write_image::<colortype::Gray8>(3, 2, &[0u8; 6])
        .unwrap();
    drop(enc);
    let e = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: page 1: expected 2x2 pixels like the first page, found \"3x2\"",
            name(&p)
        )
    );
    // A truncated file.
    pages(&p, 3);
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with(&name(&p)) && !e.contains('\n'), "{e}");
    // Empty directory, raw-only options.
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let e = read_all(&empty, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: directory: expected at least one .tif or .tiff file, found \"none\"",
            name(&empty)
        )
    );
    let opts = OpenOptions {
        dtype: Some(Dtype::U8),
        ..Default::default()
    };
    // A folder without TIFF files is not told "this is TIFF" (a user trial gave a folder as a
    // raw input's path, with its dims and dtype): the folder's content is the error.
    let e = read_all(&empty, &opts).unwrap_err().to_string();
    assert!(
        e.contains("expected at least one .tif or .tiff file") && !e.contains("this is TIFF"),
        "{e}"
    );
}

/// Writes `n` 16-bit pages of 3x2 pixels valued z * 100 + i, the first with ImageDescription
/// `desc`, as ImageJ and tifffile write hyperstacks.
fn described(path: &Path, n: u16, desc: &str) {
    tagged(path, n, Some(desc), None);
}

/// [`described`] with an optional description and resolution tags on every page (the `tiff`
/// encoder's default is 1 pixel per nothing).
fn tagged(path: &Path, n: u16, desc: Option<&str>, resolution: Option<(ResolutionUnit, u32, u32)>) {
    let mut e = TiffEncoder::new(File::create(path).unwrap()).unwrap();
    for z in 0..n {
        let data: Vec<u16> = (0..6).map(|i| z * 100 + i).collect();
        let mut page = e.new_image::<colortype::Gray16>(3, 2).unwrap();
        if let (0, Some(desc)) = (z, desc) {
            page.encoder()
                .write_tag(Tag::ImageDescription, desc)
                .unwrap();
        }
        if let Some((unit, n, d)) = resolution {
            page.resolution(unit, Rational { n, d });
        }
        page.write_data(&data).unwrap();
    }
}

/// ImageJ hyperstacks and OME-TIFF store channels and time points as interleaved pages, which
/// were read as z slices (two channels: twice the depth).
#[test]
fn channels_or_time_points_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("ij.tif");
    let ij = "ImageJ=1.11a\nimages=4\nchannels=2\nslices=2\nhyperstack=true\nmode=grayscale\n";
    described(&p, 4, ij);
    let e = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: ImageDescription: ImageJ metadata declares 2 channels, but one 3-D volume is read (its pages would be taken as interleaved z slices); save one channel at one time point as its own stack (Fiji: Image > Color > Split Channels; tifffile: imwrite(path, data[:, c]) of ZCYX data)",
            p.display()
        )
    );
    let ome = r#"<?xml version="1.0" encoding="UTF-8"?><OME><Image ID="Image:0"><Pixels ID="Pixels:0" DimensionOrder="XYCZT" Type="uint16" SizeX="3" SizeY="2" SizeC="2" SizeZ="1" SizeT="2"><TiffData IFD="0" PlaneCount="4"/></Pixels></Image></OME>"#;
    described(&p, 4, ome);
    let e = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            ": ImageDescription: OME-XML metadata declares 2 channels and 2 time points, but"
        ),
        "{e}"
    );
    // One channel at one time point, as ImageJ and tifffile write plain stacks, reads as before.
    described(
        &p,
        4,
        "ImageJ=1.11a\nimages=4\nchannels=1\nslices=4\nframes=1\n",
    );
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want(4));
    described(
        &p,
        4,
        &ome.replace("SizeC=\"2\"", "SizeC=\"1\"")
            .replace("SizeT=\"2\"", "SizeT=\"1\"")
            .replace("SizeZ=\"1\"", "SizeZ=\"4\""),
    );
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want(4));
    described(&p, 4, "a scan of channels=2 written by hand");
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want(4));
}

/// A folder's slices: hidden files skipped, a file of two pages refused, and a file of another
/// type named as page 0 of that file (it was "page 13", the slice's index).
#[test]
fn slice_folder_files() {
    let dir = tempfile::tempdir().unwrap();
    let stack = dir.path().join("slices");
    std::fs::create_dir(&stack).unwrap();
    let slice = |z: u16| {
        let mut e =
            TiffEncoder::new(File::create(stack.join(format!("slice{z}.tif"))).unwrap()).unwrap();
        let data: Vec<u16> = (0..6).map(|i| z * 100 + i).collect();
        e.write_image::<colortype::Gray16>(3, 2, &data).unwrap();
    };
    for z in 0..4 {
        slice(z);
    }
    // macOS AppleDouble files beside each copied file: not TIFFs, and hidden.
    std::fs::write(
        stack.join("._slice0.tif"),
        b"\0\x05\x16\x07\0\x02\0\0Mac OS X        ",
    )
    .unwrap();
    pages(&stack.join(".hidden.tif"), 2);
    assert_eq!(read_all(&stack, &OpenOptions::default()).unwrap(), want(4));

    let two = stack.join("slice2.tif");
    pages(&two, 2);
    let e = read_all(&stack, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: holds more than one page, but each file of a slice folder is one z slice; save one page per file, or give a multi-page stack as the input path itself",
            two.display()
        )
    );

    let mut e = TiffEncoder::new(File::create(&two).unwrap()).unwrap();
    e.write_image::<colortype::Gray8>(3, 2, &[0u8; 6]).unwrap();
    drop(e);
    let e = read_all(&stack, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: page 0: expected u16 samples like the first file, slice0.tif, found \"u8\"",
            two.display()
        )
    );
}

/// A valid small multi-page file for the robustness checks.
pub(crate) fn samples() -> Vec<(&'static str, Vec<u8>)> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    let mut e = TiffEncoder::new(&mut bytes).unwrap();
    for z in 0..4u8 {
        e.write_image::<colortype::Gray8>(3, 2, &[z; 6]).unwrap();
    }
    vec![("sample.tif", bytes.into_inner())]
}

/// A damaged tag count (three billion strip offsets in a 30-byte file) is refused by the limits
/// instead of allocating ~100 GB (found by the robustness property in CI).
#[test]
fn huge_tag_counts_are_refused_not_allocated() {
    let mut bytes = b"II*\0".to_vec();
    bytes.extend(8u32.to_le_bytes()); // first IFD
    bytes.extend(1u16.to_le_bytes()); // one entry
    bytes.extend(273u16.to_le_bytes()); // StripOffsets
    bytes.extend(4u16.to_le_bytes()); // LONG
    bytes.extend(3_000_000_000u32.to_le_bytes());
    bytes.extend(0u32.to_le_bytes());
    bytes.extend(0u32.to_le_bytes()); // no next IFD
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("huge.tif");
    std::fs::write(&p, &bytes).unwrap();
    let e = refusal(&p);
    assert!(e.contains("huge.tif") && !e.contains('\n'), "{e}");
}

/// The one-line error opening `p` with default options gives.
fn refusal(p: &Path) -> String {
    open_path(p, &OpenOptions::default())
        .err()
        .expect("refused")
        .to_string()
}

/// The stack's grid and description as opened with `opts`.
fn opened(p: &Path, opts: &OpenOptions) -> (Grid, String) {
    let v = open_path(p, opts).unwrap();
    (v.grid(), v.describe())
}

fn close(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter()
        .zip(b)
        .all(|(x, y)| (x - y).abs() <= 1e-12 * y.abs())
}

/// ImageJ: x and y are 1 / XResolution, YResolution in `unit=` (ResolutionUnit none, as ImageJ
/// writes it), z is `spacing=`; the unit is told in the description; `[input] spacing` wins and
/// the metadata is then not told.
#[test]
fn imagej_spacing_and_unit_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("ij.tif");
    let ij = "ImageJ=1.54f\nimages=4\nslices=4\nunit=micron\nspacing=2.5\nloop=false\n";
    tagged(&p, 4, Some(ij), Some((ResolutionUnit::None, 2, 1)));
    let (grid, describe) = opened(&p, &OpenOptions::default());
    assert_eq!(grid.spacing, [0.5, 0.5, 2.5]);
    assert_eq!(grid.origin, [0.0; 3]);
    assert_eq!(
        describe,
        format!(
            "{} (3x2x4 TIFF stack, voxel 0.5 x 0.5 x 2.5 um from its ImageJ metadata)",
            p.display()
        )
    );
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want(4));
    let given = OpenOptions {
        spacing: Some([1.0, 1.0, 1.0]),
        ..Default::default()
    };
    let (grid, describe) = opened(&p, &given);
    assert_eq!(grid.spacing, [1.0; 3]);
    assert_eq!(describe, format!("{} (3x2x4 TIFF stack)", p.display()));

    // Axes in other length units are brought to x's; the description's unit is every axis's,
    // as ImageJ reads it.
    tagged(
        &p,
        4,
        Some(&format!("{ij}zunit=nm\n")),
        Some((ResolutionUnit::None, 4, 1)),
    );
    let (grid, _) = opened(&p, &OpenOptions::default());
    assert!(close(grid.spacing, [0.25, 0.25, 0.0025]), "{grid:?}");
    tagged(
        &p,
        4,
        Some("ImageJ=1.54f\nimages=4\nslices=4\nunit=mm\nspacing=0.5\n"),
        Some((ResolutionUnit::Centimeter, 1000, 1)),
    );
    let (grid, describe) = opened(&p, &OpenOptions::default());
    assert!(close(grid.spacing, [0.001, 0.001, 0.5]), "{grid:?}");
    assert!(
        describe.ends_with(" mm from its ImageJ metadata)"),
        "{describe}"
    );
    // ImageJ's two exceptions: a centimetre tag under a micrometre unit is converted (x
    // 10,000), and 72 per inch (a print size other writers leave) is no calibration.
    for (tag, per, spacing) in [
        (ResolutionUnit::Centimeter, 5000, [2.0, 2.0, 2.0]),
        (ResolutionUnit::Inch, 72, [1.0, 1.0, 2.0]),
    ] {
        tagged(
            &p,
            4,
            Some("ImageJ=1.54f\nimages=4\nslices=4\nunit=micron\nspacing=2\n"),
            Some((tag, per, 1)),
        );
        let (grid, _) = opened(&p, &OpenOptions::default());
        assert!(close(grid.spacing, spacing), "{grid:?}");
    }
    // An axis in a unit that is no length is refused in one line naming the override, which
    // runs it.
    tagged(
        &p,
        4,
        Some(&format!("{ij}zunit=frame\n")),
        Some((ResolutionUnit::None, 2, 1)),
    );
    let e = refusal(&p);
    assert_eq!(
        e,
        format!(
            "{}: ImageDescription: the ImageJ metadata gives the voxel size in \"um\" along x but in \"frame\" along z, which do not convert; set [input] spacing",
            p.display()
        )
    );
    assert_eq!(opened(&p, &given).0.spacing, [1.0; 3]);
    // An uncalibrated ImageJ stack (no unit, no spacing) has no voxel size.
    described(&p, 4, "ImageJ=1.54f\nimages=4\nslices=4\n");
    assert_eq!(
        opened(&p, &OpenOptions::default()),
        (
            Grid::new([3, 2, 4], [1.0; 3], [0.0; 3]).unwrap(),
            format!("{} (3x2x4 TIFF stack)", p.display())
        )
    );
}

/// OME-TIFF: the first `Pixels` element's PhysicalSize X/Y/Z (µm by default; image 0 is what
/// is read), whatever the second image or the resolution tags say.
#[test]
fn ome_physical_sizes_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.ome.tif");
    let image = |id: u32, x: &str, z: &str| {
        format!(
            r#"<Image ID="Image:{id}"><Pixels ID="Pixels:{id}" DimensionOrder="XYZCT" Type="uint16" SizeX="3" SizeY="2" SizeZ="4" SizeC="1" SizeT="1" PhysicalSizeX="{x}" PhysicalSizeY='{x}' {z}><TiffData IFD="0" PlaneCount="4"/></Pixels></Image>"#
        )
    };
    let ome = |first: &str| {
        format!(
            r#"<?xml version="1.0" encoding="UTF-8"?><!-- <Pixels PhysicalSizeX="9"> --><OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06">{first}{}</OME>"#,
            image(1, "7", r#"PhysicalSizeZ="7""#)
        )
    };
    let plain = image(0, "0.3", r#"PhysicalSizeZ="1.2""#);
    tagged(
        &p,
        4,
        Some(&ome(&plain)),
        Some((ResolutionUnit::Centimeter, 5, 1)),
    );
    let (grid, describe) = opened(&p, &OpenOptions::default());
    assert_eq!(grid.spacing, [0.3, 0.3, 1.2]);
    assert!(
        describe
            .ends_with("(3x2x4 TIFF stack, voxel 0.3 x 0.3 x 1.2 um from its OME-XML metadata)"),
        "{describe}"
    );
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want(4));
    // Units per axis, converted to x's (the `tiff` encoder writes ASCII descriptions only: no µ).
    let nm = image(
        0,
        "300",
        r#"PhysicalSizeXUnit="nm" PhysicalSizeYUnit="nm" PhysicalSizeZ="0.0012" PhysicalSizeZUnit="mm""#,
    );
    tagged(&p, 4, Some(&ome(&nm)), None);
    let (grid, describe) = opened(&p, &OpenOptions::default());
    assert!(close(grid.spacing, [300.0, 300.0, 1200.0]), "{grid:?}");
    assert!(describe.contains(" nm from its OME-XML"), "{describe}");
    // No PhysicalSize at all: no voxel size, as before.
    let none = image(0, "0.3", "").replace(r#" PhysicalSizeX="0.3" PhysicalSizeY='0.3'"#, "");
    tagged(&p, 4, Some(&ome(&none)), None);
    assert_eq!(opened(&p, &OpenOptions::default()).0.spacing, [1.0; 3]);
}

/// Plain resolution tags (no ImageJ or OME description) are a print size: 72 dpi, or a
/// scanner's 1000 per cm, gives no voxel size.
#[test]
fn plain_resolution_tags_are_not_a_voxel_size() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("scan.tif");
    for (unit, n) in [
        (ResolutionUnit::Inch, 72),
        (ResolutionUnit::Centimeter, 1000),
    ] {
        tagged(&p, 4, None, Some((unit, n, 1)));
        assert_eq!(
            opened(&p, &OpenOptions::default()),
            (
                Grid::new([3, 2, 4], [1.0; 3], [0.0; 3]).unwrap(),
                format!("{} (3x2x4 TIFF stack)", p.display())
            )
        );
        tagged(&p, 4, Some("scanned by hand"), Some((unit, n, 1)));
        assert_eq!(opened(&p, &OpenOptions::default()).0.spacing, [1.0; 3]);
    }
}

/// A single page (or a folder of one file) is refused saying what the stack holds, not with the
/// grid's "check the dims" (a TIFF has no dims key).
#[test]
fn a_single_page_is_refused_as_one_slice() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("one.tif");
    pages(&p, 1);
    assert_eq!(
        refusal(&p),
        format!(
            "{}: the TIFF holds 1 page (a 3x2 image) and a volume needs at least 2 z slices; save the stack as a multi-page TIFF or a folder of one file per slice",
            p.display()
        )
    );
    let folder = dir.path().join("slices");
    std::fs::create_dir(&folder).unwrap();
    pages(&folder.join("s0.tif"), 1);
    assert_eq!(
        refusal(&folder),
        format!(
            "{}: the folder holds 1 TIFF file (a 3x2 image) and a volume needs at least 2 z slices; put one file per z slice in it",
            folder.display()
        )
    );
}

/// A zero resolution (an infinite pixel size), or a size that is not a number, is refused as
/// any header's impossible spacing is, naming `[input] spacing`, which runs the stack.
#[test]
fn impossible_sizes_are_refused_naming_the_override() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("zero.tif");
    let ij = "ImageJ=1.54f\nimages=4\nslices=4\nunit=micron\nspacing=2.5\n";
    tagged(&p, 4, Some(ij), Some((ResolutionUnit::None, 0, 1)));
    let e = refusal(&p);
    assert_eq!(
        e,
        format!(
            "{}: the header's spacing [inf, inf, 2.5] must be finite and > 0 on every axis; fix the header or set [input] spacing",
            p.display()
        )
    );
    let given = OpenOptions {
        spacing: Some([0.5, 0.5, 2.5]),
        ..Default::default()
    };
    assert_eq!(opened(&p, &given).0.spacing, [0.5, 0.5, 2.5]);
    let ome = r#"<OME><Image><Pixels SizeX="3" SizeY="2" SizeZ="4" PhysicalSizeX="0.3" PhysicalSizeY="0.3" PhysicalSizeZ="0"/></Image></OME>"#;
    described(&p, 4, ome);
    let e = refusal(&p);
    assert!(
        e.contains(": the header's spacing [0.3, 0.3, 0.0] must be finite and > 0"),
        "{e}"
    );
    described(&p, 4, &ome.replace("\"0\"", "\"1,2\""));
    let e = refusal(&p);
    assert!(e.contains("spacing [0.3, 0.3, NaN]"), "{e}");
}

/// A folder of slices takes the first file's metadata (as ImageJ's image sequence saves it: one
/// image each, no `spacing=`, so z is 1 in the unit), and names that file when it is refused.
#[test]
fn a_slice_folder_takes_the_first_files_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let stack = dir.path().join("slices");
    std::fs::create_dir(&stack).unwrap();
    let ij = "ImageJ=1.54f\nunit=micron\n";
    for z in 0..4u16 {
        let res = if z == 0 { 4 } else { 1 };
        tagged(
            &stack.join(format!("s{z}.tif")),
            1,
            Some(ij),
            Some((ResolutionUnit::None, res, 1)),
        );
    }
    let (grid, describe) = opened(&stack, &OpenOptions::default());
    assert_eq!(grid.spacing, [0.25, 0.25, 1.0]);
    assert!(describe.contains("voxel 0.25 x 0.25 x 1 um"), "{describe}");
    tagged(
        &stack.join("s0.tif"),
        1,
        Some(ij),
        Some((ResolutionUnit::None, 0, 1)),
    );
    let e = refusal(&stack);
    assert!(
        e.starts_with(&format!(
            "{}: the header's spacing [inf, inf, 1.0]",
            stack.join("s0.tif").display()
        )),
        "{e}"
    );
}
