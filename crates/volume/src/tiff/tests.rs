use super::*;
use crate::open_path;
use crate::testutil::read_all;
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

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
            "{}: page 0: expected a single-channel grayscale page, found \"RGB(8)\"",
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
    assert!(
        read_all(&empty, &opts)
            .unwrap_err()
            .to_string()
            .contains("apply only to .raw files")
    );
}

/// Writes `n` 16-bit pages of 3x2 pixels valued z * 100 + i, the first with ImageDescription
/// `desc`, as ImageJ and tifffile write hyperstacks.
fn described(path: &Path, n: u16, desc: &str) {
    let mut e = TiffEncoder::new(File::create(path).unwrap()).unwrap();
    for z in 0..n {
        let data: Vec<u16> = (0..6).map(|i| z * 100 + i).collect();
        let mut page = e.new_image::<colortype::Gray16>(3, 2).unwrap();
        if z == 0 {
            page.encoder()
                .write_tag(Tag::ImageDescription, desc)
                .unwrap();
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
    let e = open_path(&p, &OpenOptions::default())
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("huge.tif") && !e.contains('\n'), "{e}");
}
