//! TIFF stacks: one multi-page `.tif`/`.tiff` (page k = slice z = k) or a directory of
//! single-page TIFFs in natural name order (`slice2.tif` before `slice10.tif`; hidden files,
//! whose names start with '.', are skipped). Grayscale pages of one channel at one time point
//! only. One page is decoded per slice. The voxel size is the first page's ImageJ or OME-XML
//! metadata's (`spacing.rs`: plain resolution tags are a print size, not read), else 1;
//! [`OpenOptions`] overrides it and gives the origin (default 0). WhiteIsZero pages are inverted
//! by the `tiff` decoder (`max - v` for unsigned samples, `1 - v` for floats; signed samples are
//! refused), so they read as the picture looks.

use crate::grid::dims_text;
use crate::source::check_request;
use crate::{Dtype, Grid, OpenOptions, VolumeError, VolumeSource};
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use tiff::ColorType;
use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;

mod spacing;

type TiffDecoder = Decoder<BufReader<File>>;

enum Pages {
    /// One file per slice.
    Files(Vec<PathBuf>),
    /// Pages of one file; the decoder is kept open and seeks between pages.
    MultiPage(Option<Box<TiffDecoder>>),
}

/// A stack of grayscale TIFF pages.
pub(crate) struct TiffStack {
    path: PathBuf,
    grid: Grid,
    dtype: Dtype,
    pages: Pages,
    /// Voxels saturated by the reads so far (`VolumeSource::saturated_voxels`).
    saturated: u64,
    /// What the other pages must match, for messages: "the first page" or the first file.
    like: String,
    /// The voxel size the grid took from the file's metadata, told with its unit in
    /// [`VolumeSource::describe`] (the job's start line and the run summary's `input`): meshes
    /// have no unit field. `None` when the metadata has none or `[input] spacing` overrides it.
    voxel: Option<spacing::FileSpacing>,
}

/// Opens a multi-page TIFF file or a directory of TIFF files.
pub(crate) fn open(path: &Path, opts: &OpenOptions) -> Result<Box<dyn VolumeSource>, VolumeError> {
    // A folder is TIFF only if it holds TIFF files: listed first, so that `dims` given for a
    // folder of something else is not told "this is TIFF".
    let files = path.is_dir().then(|| list_dir(path)).transpose()?;
    opts.reject_raw_params(path, "TIFF")?;
    opts.reject_array(path, "TIFF")?;
    let (first, count, pages) = if let Some(files) = files {
        let first = files[0].clone();
        (first, files.len() as u64, Pages::Files(files))
    } else {
        let mut d = decoder(path)?;
        let mut count = 1u64;
        while d.more_images() {
            d.next_image().map_err(|e| page_err(path, count, e))?;
            count += 1;
        }
        (path.to_path_buf(), count, Pages::MultiPage(None))
    };
    // Decode the first page once: it fixes the slice size and tells the stored type.
    let mut d = decoder(&first)?;
    let desc = description(&mut d);
    refuse_hyperstack(&first, desc.as_deref())?;
    let (w, h) = d.dimensions().map_err(|e| page_err(&first, 0, e))?;
    let dims = [u64::from(w), u64::from(h), count];
    // The grid's own refusal says "check the dims", a key a TIFF has none of: say what the
    // stack holds instead.
    if count < 2 {
        let (held, fix) = match pages {
            Pages::Files(_) => (
                "the folder holds 1 TIFF file",
                "put one file per z slice in it",
            ),
            Pages::MultiPage(_) => (
                "the TIFF holds 1 page",
                "save the stack as a multi-page TIFF or a folder of one file per slice",
            ),
        };
        return Err(VolumeError::Grid {
            origin: path.display().to_string(),
            problem: format!(
                "{held} (a {w}x{h} image) and a volume needs at least 2 z slices; {fix}"
            ),
        });
    }
    // The metadata is not read under an override: `[input] spacing` is the way to run a stack
    // whose metadata is refused.
    let voxel = match opts.spacing {
        Some(_) => None,
        None => spacing::read(&first, desc.as_deref(), &mut d)?,
    };
    // A bad size is named in the file that holds it (a folder's first file).
    let named = if voxel.is_some() { &first } else { path };
    let grid = opts.grid(
        named,
        dims,
        voxel.as_ref().map_or([1.0; 3], |v| v.spacing),
        [0.0; 3],
    )?;
    let like = match pages {
        Pages::Files(_) => format!("the first file, {}", file_name(&first)),
        Pages::MultiPage(_) => "the first page".to_string(),
    };
    // Only the type is needed now: no slice buffer sized from the header's claim (the decoder's
    // limits, scaled to the file, bound what decoding the page may allocate).
    let (dtype, _) = read_page(&first, 0, &mut d, (w, h), &like, &mut [])?;
    Ok(Box::new(TiffStack {
        path: path.to_path_buf(),
        grid,
        dtype,
        pages,
        saturated: 0,
        like,
        voxel,
    }))
}

/// A path's last part as text, for sorting a folder and for messages.
fn file_name(p: &Path) -> std::borrow::Cow<'_, str> {
    p.file_name().unwrap_or_default().to_string_lossy()
}

/// TIFF files of a directory in natural order; at least one. Hidden files (names starting with
/// '.') are skipped: macOS writes an AppleDouble `._slice0.tif` beside each file copied to a
/// foreign disk, which is not a TIFF and aborted the run.
fn list_dir(dir: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    let entries = std::fs::read_dir(dir).map_err(|e| VolumeError::io(dir, "list", e))?;
    let mut files = Vec::new();
    for entry in entries {
        let p = entry.map_err(|e| VolumeError::io(dir, "list", e))?.path();
        let ext = p
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if matches!(ext.as_deref(), Some("tif" | "tiff")) && !file_name(&p).starts_with('.') {
            files.push(p);
        }
    }
    if files.is_empty() {
        return Err(VolumeError::format(
            dir,
            "directory",
            "at least one .tif or .tiff file",
            "none",
        ));
    }
    files.sort_by_key(|p| natural_key(&file_name(p)));
    Ok(files)
}

/// Splits a name into text and number runs so that "s2" sorts before "s10".
fn natural_key(name: &str) -> Vec<(String, u128)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(c) = chars.next() {
        if c.is_ascii_digit() {
            let mut num = c.to_digit(10).map(u128::from).unwrap_or(0);
            while let Some(d) = chars.peek().and_then(|d| d.to_digit(10)) {
                num = num.saturating_mul(10).saturating_add(u128::from(d));
                chars.next();
            }
            key.push((std::mem::take(&mut text), num));
        } else {
            text.push(c);
        }
    }
    key.push((text, 0));
    key
}

fn decoder(path: &Path) -> Result<TiffDecoder, VolumeError> {
    let f = File::open(path).map_err(|e| VolumeError::io(path, "open", e))?;
    let len = f
        .metadata()
        .map_err(|e| VolumeError::io(path, "read its size", e))?
        .len();
    Decoder::new(BufReader::new(f))
        .map(|d| d.with_limits(limits_for(len)))
        .map_err(|e| VolumeError::format(path, "file header", "a TIFF file", e.to_string()))
}

/// Limits scaled to the file: the crate's defaults (256 MiB per decoded buffer) would refuse
/// large slices, while no limit lets a damaged tag count allocate terabytes before the read
/// fails. A decoded page or tag array may be up to 64 times the file (compressed CT slices with
/// empty background reach tens of times), never less than the defaults; a compressed strip can
/// never be larger than the file.
fn limits_for(file_len: u64) -> Limits {
    let file_len = usize::try_from(file_len).unwrap_or(usize::MAX);
    let mut limits = Limits::default();
    limits.decoding_buffer_size = file_len.saturating_mul(64).max(limits.decoding_buffer_size);
    limits.intermediate_buffer_size = file_len.max(limits.intermediate_buffer_size);
    limits.ifd_value_size = file_len.max(limits.ifd_value_size);
    limits
}

/// The current page's ImageDescription. One the decoder cannot read (not UTF-8) declares nothing
/// this reader can use, and the pages are still read.
fn description(d: &mut TiffDecoder) -> Option<String> {
    d.find_tag(Tag::ImageDescription)
        .ok()
        .flatten()
        .and_then(|v| v.into_string().ok())
}

/// The values of an ImageJ description's `key=value` lines.
fn imagej_values<'a>(desc: &'a str, key: &'a str) -> impl Iterator<Item = &'a str> {
    desc.lines()
        .filter_map(move |l| l.strip_prefix(key)?.strip_prefix('='))
}

/// Refuses a file whose ImageDescription declares more than one channel or time point: ImageJ
/// hyperstacks and OME-TIFF store them as interleaved pages, which were read as z slices (two
/// channels doubled the depth).
fn refuse_hyperstack(path: &Path, desc: Option<&str>) -> Result<(), VolumeError> {
    let Some(desc) = desc else {
        return Ok(());
    };
    let (writer, extra) = hyperstack_extents(desc);
    if extra.is_empty() {
        return Ok(());
    }
    Err(VolumeError::Grid {
        origin: path.display().to_string(),
        problem: format!(
            "ImageDescription: {writer} metadata declares {}, but one 3-D volume is read (its pages would be taken as interleaved z slices); save one channel at one time point as its own stack (Fiji: Image > Color > Split Channels; tifffile: imwrite(path, data[:, c]) of ZCYX data)",
            extra.join(" and ")
        ),
    })
}

/// Channel and time-point counts above 1 that an ImageJ (`channels=`, `frames=`) or OME-XML
/// (`SizeC`, `SizeT`; the largest of its images) description declares, with the writer's name.
fn hyperstack_extents(desc: &str) -> (&'static str, Vec<String>) {
    let (writer, counts) = if desc.starts_with("ImageJ=") {
        let count = |key: &str| {
            imagej_values(desc, key)
                .filter_map(|v| v.trim().parse::<u64>().ok())
                .max()
        };
        ("ImageJ", [count("channels"), count("frames")])
    } else if desc.contains("<OME") {
        let count = |key: &str| {
            desc.split(key)
                .skip(1)
                .filter_map(|rest| rest.strip_prefix("=\"")?.split('"').next())
                .filter_map(|v| v.trim().parse::<u64>().ok())
                .max()
        };
        ("OME-XML", [count("SizeC"), count("SizeT")])
    } else {
        return ("", Vec::new());
    };
    let extra = counts
        .iter()
        .zip(["channels", "time points"])
        .filter_map(|(n, what)| n.filter(|&n| n > 1).map(|n| format!("{n} {what}")))
        .collect();
    (writer, extra)
}

fn page_err(path: &Path, page: u64, e: tiff::TiffError) -> VolumeError {
    VolumeError::format(
        path,
        format!("page {page}"),
        "a readable TIFF page",
        e.to_string(),
    )
}

/// Decodes the current page of `d` into `out` (nothing when `out` is empty: the caller only wants
/// the type), checking its size is that of the stack (`like` names the page that set it); returns
/// its type.
fn read_page(
    path: &Path,
    page: u64,
    d: &mut TiffDecoder,
    (w, h): (u32, u32),
    like: &str,
    out: &mut [f32],
) -> Result<(Dtype, u64), VolumeError> {
    let at = || format!("page {page}");
    let size = d.dimensions().map_err(|e| page_err(path, page, e))?;
    if size != (w, h) {
        return Err(VolumeError::format(
            path,
            at(),
            format!("{w}x{h} pixels like {like}"),
            format!("{}x{}", size.0, size.1),
        ));
    }
    let color = d.colortype().map_err(|e| page_err(path, page, e))?;
    if !matches!(color, ColorType::Gray(_)) {
        return Err(VolumeError::Format {
            file: path.display().to_string(),
            at: at(),
            expected: "a single-channel grayscale page".into(),
            found: format!(
                "{color:?}; convert the stack to single-channel grayscale, one channel per \
                 stack (Fiji: Image > Color > Split Channels, or Image > Type > 8-bit)"
            ),
        });
    }
    let image = d.read_image().map_err(|e| page_err(path, page, e))?;
    fn copy<T: Copy>(src: &[T], out: &mut [f32], f: impl Fn(T) -> f32) {
        for (o, &v) in out.iter_mut().zip(src) {
            *o = f(v);
        }
    }
    let (dtype, len) = match &image {
        DecodingResult::U8(v) => (Dtype::U8, v.len()),
        DecodingResult::I8(v) => (Dtype::I8, v.len()),
        DecodingResult::U16(v) => (Dtype::U16, v.len()),
        DecodingResult::I16(v) => (Dtype::I16, v.len()),
        DecodingResult::U32(v) => (Dtype::U32, v.len()),
        DecodingResult::I32(v) => (Dtype::I32, v.len()),
        DecodingResult::F32(v) => (Dtype::F32, v.len()),
        DecodingResult::F64(v) => (Dtype::F64, v.len()),
        other => {
            return Err(VolumeError::format(
                path,
                at(),
                "8/16/32-bit integer or 32/64-bit float samples",
                format!("{:?}", std::mem::discriminant(other)),
            ));
        }
    };
    let want = w as usize * h as usize;
    if len != want || (!out.is_empty() && out.len() != want) {
        return Err(VolumeError::format(
            path,
            at(),
            format!("{want} samples"),
            len.to_string(),
        ));
    }
    match &image {
        DecodingResult::U8(v) => copy(v, out, f32::from),
        DecodingResult::I8(v) => copy(v, out, f32::from),
        DecodingResult::U16(v) => copy(v, out, f32::from),
        DecodingResult::I16(v) => copy(v, out, f32::from),
        DecodingResult::U32(v) => copy(v, out, |x| x as f32),
        DecodingResult::I32(v) => copy(v, out, |x| x as f32),
        DecodingResult::F32(v) => copy(v, out, |x| x),
        DecodingResult::F64(v) => {
            copy(v, out, |x| x as f32);
            return Ok((dtype, crate::dtype::saturate_f64(out, |i| v[i])));
        }
        _ => {}
    }
    Ok((dtype, 0))
}

impl VolumeSource for TiffStack {
    fn grid(&self) -> Grid {
        self.grid
    }

    fn describe(&self) -> String {
        let voxel = match &self.voxel {
            Some(v) => format!(", {v}"),
            None => String::new(),
        };
        format!(
            "{} ({} TIFF stack{voxel})",
            self.path.display(),
            dims_text(self.grid.dims)
        )
    }

    fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
        check_request(self, z, out)?;
        // Grid dims 0 and 1 came from a u32 page size.
        let size = (self.grid.dims[0] as u32, self.grid.dims[1] as u32);
        let like = &self.like;
        // The page within its file: a folder's files hold page 0 only.
        let (file, page, got) = match &mut self.pages {
            Pages::Files(files) => {
                let file = &files[z as usize];
                let mut d = decoder(file)?;
                let (got, saturated) = read_page(file, 0, &mut d, size, like, out)?;
                self.saturated += saturated;
                // A second page was silently ignored: the file is not one slice.
                if d.more_images() {
                    return Err(VolumeError::Grid {
                        origin: file.display().to_string(),
                        problem: "holds more than one page, but each file of a slice folder is one z slice; save one page per file, or give a multi-page stack as the input path itself".into(),
                    });
                }
                (file.clone(), 0, got)
            }
            Pages::MultiPage(slot) => {
                let d = match slot {
                    Some(d) => d,
                    None => slot.insert(Box::new(decoder(&self.path)?)),
                };
                d.seek_to_image(z as usize)
                    .map_err(|e| page_err(&self.path, z, e))?;
                let (got, saturated) = read_page(&self.path, z, d, size, like, out)?;
                self.saturated += saturated;
                (self.path.clone(), z, got)
            }
        };
        if got != self.dtype {
            return Err(VolumeError::format(
                &file,
                format!("page {page}"),
                format!("{} samples like {like}", self.dtype),
                got.name(),
            ));
        }
        Ok(())
    }

    fn dtype(&self) -> Option<Dtype> {
        Some(self.dtype)
    }

    fn saturated_voxels(&self) -> u64 {
        self.saturated
    }
}

#[cfg(test)]
pub(crate) mod tests;
