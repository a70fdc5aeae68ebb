//! Turns `[input]` into a volume source.

use isostream_volume::{Grid, Procedural, Upsampled, VolumeError, VolumeSource};

use crate::config::{InputConfig, JobConfig};
use crate::error::RunError;

/// Opens the volume a job names: a procedural shape, or a file in any format `volume` reads,
/// seen through `upsample` when the job asks for it.
pub fn open_source(input: &InputConfig) -> Result<Box<dyn VolumeSource>, RunError> {
    let source = crate::mirror::Mirrored::wrap(open_stored(input)?);
    check_slice_memory(source.as_ref(), crate::rss::physical_memory_bytes())?;
    let source = upsampled(source, input)?;
    check_f32_positions(&source.grid()).map_err(|problem| VolumeError::Grid {
        origin: source.describe(),
        problem,
    })?;
    Ok(source)
}

/// Everything a job's inputs can be checked for before any work, as `run` checks it: the
/// volume opens (with `upsample`), its attribute volumes open on its grid, and the output
/// format can index as many vertices as the job could write. `isostream validate` and the
/// service's admission call this, so neither accepts a job that `run` refuses at once.
pub fn preflight(job: &JobConfig) -> Result<Box<dyn VolumeSource>, RunError> {
    let source = open_source(&job.input)?;
    if !job.attributes.is_empty() {
        crate::attributes::SliceReader::open(job)?;
    }
    check_against_input(job, source.as_ref())?;
    Ok(source)
}

/// What the job is checked for against its opened input before any work, by `run` and by
/// [`preflight`] alike: the output format can index as many vertices as the job could write,
/// and `[extract] iso` is one the input's stored type allows a surface at (unless `[output]
/// allow_empty`): iso 300 on u8 data passed `validate`, and `run` read the whole volume before
/// saying that its surface was empty.
pub(crate) fn check_against_input(
    job: &JobConfig,
    source: &dyn VolumeSource,
) -> Result<(), RunError> {
    crate::index_limit::check_job(job, source.grid().voxel_count())?;
    let iso = job.extract.iso;
    let why = source
        .stored_range()
        .filter(|_| !job.output.allow_empty)
        .and_then(|range| {
            let dtype = source.dtype().map_or("stored".into(), |d| d.to_string());
            crate::range::ruled_out_by_type(iso, &dtype, range)
        });
    match why {
        Some(why) => Err(RunError::EmptySurface {
            input: source.describe(),
            iso,
            why,
        }),
        None => Ok(()),
    }
}

/// The warning for a rotation of the input's header, which the grid drops (axis flips are
/// applied, `mirror.rs`); `None` otherwise. `run` logs it and puts it in the run summary,
/// `validate` prints it.
pub fn orientation_warning(source: &dyn VolumeSource) -> Option<String> {
    let dropped = source.orientation().dropped()?;
    Some(format!(
        "{}: {dropped}; see config/README.md, Orientation",
        source.describe()
    ))
}

/// The coarsest `f32` step, as a share of an axis's spacing, that positions along that axis
/// may have. Meshes are written in `f32` (and the simplifier keeps `f32`-exact positions): a
/// volume far from the origin at a fine spacing had its vertices rounded onto a few positions
/// (a sphere at x = 1e9 with spacing 0.5 came out flat; at 4e6 with spacing 0.1, 85 % of the
/// triangles had no area), with no error. Past an eighth of a voxel the mesh is visibly
/// rounded; finer is accepted, since real data lives there: UTM eastings (5e5 m at 1 m: steps
/// of 1/32) and microscope stage coordinates (5e4 um at 0.1 um: 1/25) must run.
const MIN_VOXEL_STEPS: f64 = 8.0;

const AXES: [char; 3] = ['x', 'y', 'z'];

/// Refuses a job grid whose positions `f32` cannot hold (past its range) or cannot tell apart
/// at a 1/[`MIN_VOXEL_STEPS`] of the spacing, axis by axis: each coordinate is rounded on its
/// own, so a northing of 4.1e6 at 25 m (steps of 0.25 m) is fine beside heights in metres near
/// 0 (the smallest spacing of all axes against the largest position refused such UTM grids).
/// A job's grid, not every `Grid`: the volume crate's grids go to 2^64 voxels, and only what
/// is written must fit `f32`.
fn check_f32_positions(grid: &Grid) -> Result<(), String> {
    let move_origin = "move the origin near 0 ([input] origin = [0, 0, 0]) and add the offset \
                       back to the mesh afterwards, or check the origin and spacing";
    for (k, axis) in AXES.iter().enumerate() {
        let end = grid.origin[k] + grid.spacing[k] * grid.dims[k].saturating_sub(1) as f64;
        let far = grid.origin[k].abs().max(end.abs());
        // Where the extent, not the origin, makes the positions unrepresentable, moving the
        // origin cannot help (a spacing of 1e-300 underflows f32 wherever the grid lies).
        let fix = if grid.origin[k].abs() * 2.0 < far {
            format!(
                "give [input] spacing in a unit where it is nearer 1 (the {axis} spacing is {})",
                number(grid.spacing[k])
            )
        } else {
            move_origin.to_string()
        };
        if far >= f64::from(f32::MAX) {
            return Err(format!(
                "{axis} positions reach {far:e}, past what an f32 mesh can hold; {fix}"
            ));
        }
        let at = far as f32;
        let step = f64::from(at.next_up() - at);
        let spacing = grid.spacing[k];
        if step * MIN_VOXEL_STEPS > spacing {
            return Err(format!(
                "{axis} positions reach {}, where the f32 coordinates of the mesh step by {}, \
                 more than 1/{MIN_VOXEL_STEPS} of the {axis} spacing {}: the surface would be \
                 rounded onto a few positions; {fix}",
                number(far),
                number(step),
                number(spacing)
            ));
        }
    }
    Ok(())
}

/// `x` as written by hand: plain where that is short, in exponent form far from 1 (a spacing
/// of 1e-300 printed plainly made a 1,000-character error line).
fn number(x: f64) -> String {
    if x == 0.0 || (1e-4..1e9).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Whole slices in memory at once, at the least, when a volume is read slice by slice (the
/// reader's next slice and the two of the slab being extracted, plus one ahead).
const SLICES_HELD: u64 = 4;

/// Refuses a volume whose slices could not be held in this machine's memory. Slices are read
/// whole as `f32` (an upsampled volume gives its slices row by row, and its source's slices are
/// what is checked): a 100,000 x 100,000 procedural shape asked for 40 GB at its first slice
/// and the allocation aborted the process (a service with it, at every restart), and on a
/// machine that overcommits, a slice that fits the address space but not the memory ends in the
/// kernel's out-of-memory kill instead. Checked where the volume is opened, so that
/// `validate`, the service's admission and `run` all say it before any work.
fn check_slice_memory(source: &dyn VolumeSource, physical: Option<u64>) -> Result<(), RunError> {
    slices_fit(
        &source.describe(),
        source.grid().dims,
        SLICES_HELD,
        "use a smaller grid ([input] size, or a cropped file), or see a coarser volume through [input] upsample (read row by row)",
        physical,
    )
}

/// With `[[attributes]]`, the iso volume's slices and every attribute's are held whole, on
/// the upsampled grid when there is one (`SliceReader`): checked on that grid, for all of them.
pub(crate) fn check_attribute_slice_memory(
    iso: &dyn VolumeSource,
    attributes: usize,
    physical: Option<u64>,
) -> Result<(), RunError> {
    if attributes == 0 {
        return Ok(());
    }
    slices_fit(
        &iso.describe(),
        iso.grid().dims,
        SLICES_HELD * (1 + attributes as u64),
        "use a smaller grid or upsampling factor, or fewer [[attributes]] (with attributes, upsampled slices are held whole too)",
        physical,
    )
}

/// Whether `slices` whole `f32` slices of `dims` fit in `physical` bytes (unknown: yes).
fn slices_fit(
    input: &str,
    dims: [u64; 3],
    slices: u64,
    fix: &'static str,
    physical: Option<u64>,
) -> Result<(), RunError> {
    let Some(physical) = physical else {
        return Ok(());
    };
    let need = dims[0]
        .saturating_mul(dims[1])
        .saturating_mul(4u64.saturating_mul(slices));
    if need <= physical {
        return Ok(());
    }
    Err(RunError::SliceMemory {
        input: input.to_string(),
        nx: dims[0],
        ny: dims[1],
        slices,
        need_gib: need as f64 / f64::from(1u32 << 30),
        physical_gib: physical as f64 / f64::from(1u32 << 30),
        fix,
    })
}

/// `source` through `[input] upsample` (unchanged without it): attribute volumes go through it
/// too, so they stay on the iso volume's grid.
pub(crate) fn upsampled(
    source: Box<dyn VolumeSource>,
    input: &InputConfig,
) -> Result<Box<dyn VolumeSource>, RunError> {
    Ok(match input.upsample {
        Some(k) if k != [1, 1, 1] => Box::new(Upsampled::new(source, k)?),
        _ => source,
    })
}

fn open_stored(input: &InputConfig) -> Result<Box<dyn VolumeSource>, RunError> {
    if let Some(shape) = input.shape {
        let size = input.size.unwrap_or([2; 3]);
        let p = Procedural::new(
            shape,
            size,
            input.spacing.unwrap_or([1.0; 3]),
            input.origin.unwrap_or([0.0; 3]),
        )?;
        return Ok(Box::new(p));
    }
    let path = input.path.clone().unwrap_or_default();
    Ok(isostream_volume::open_path(&path, &input.open_options())?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use isostream_volume::{Orientation, Shape};

    /// A procedural volume whose "header" said `orientation`.
    struct Oriented(Procedural, Orientation);

    impl VolumeSource for Oriented {
        fn grid(&self) -> Grid {
            self.0.grid()
        }
        fn describe(&self) -> String {
            "lps.nrrd".into()
        }
        fn read_slice(&mut self, z: u64, out: &mut [f32]) -> Result<(), VolumeError> {
            self.0.read_slice(z, out)
        }
        fn orientation(&self) -> Orientation {
            self.1
        }
    }

    /// A rotation (not applied) is one warning naming the file; axis flips are applied, so
    /// they are none.
    #[test]
    fn a_rotation_is_one_warning_naming_the_file_and_flips_none() {
        let sphere = || Procedural::new(Shape::Sphere, [8; 3], [1.0; 3], [0.0; 3]).unwrap();
        assert_eq!(orientation_warning(&sphere()), None);
        let flipped = Orientation::Flipped([true, false, false]);
        assert_eq!(orientation_warning(&Oriented(sphere(), flipped)), None);
        let w = orientation_warning(&Oriented(sphere(), Orientation::Rotated)).unwrap();
        assert!(
            w.starts_with("lps.nrrd: the header rotates")
                && w.ends_with("see config/README.md, Orientation")
                && !w.contains('\n'),
            "{w}"
        );
        // Through `upsample` too.
        let up: Box<dyn VolumeSource> = Box::new(
            Upsampled::new(
                Box::new(Oriented(sphere(), Orientation::Rotated)),
                [2, 1, 1],
            )
            .unwrap(),
        );
        assert!(orientation_warning(up.as_ref()).is_some());
    }

    #[test]
    fn slices_larger_than_the_memory_are_refused_up_front() {
        let wide =
            Procedural::new(Shape::Sphere, [100_000, 100_000, 4], [1.0; 3], [0.0; 3]).unwrap();
        let err = check_slice_memory(&wide, Some(24 << 30))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("100000 x 100000")
                && err.contains("149.0 GiB")
                && err.contains("24.0 GiB"),
            "{err}"
        );
        assert!(!err.contains('\n'), "{err}");
        let fine = Procedural::new(Shape::Sphere, [4096, 4096, 4], [1.0; 3], [0.0; 3]).unwrap();
        assert!(check_slice_memory(&fine, Some(24 << 30)).is_ok());
        assert!(
            check_slice_memory(&wide, None).is_ok(),
            "unknown memory: not refused"
        );
    }

    /// With attributes, upsampled slices are held whole, the attributes' too: checked on the
    /// upsampled grid (a 20,000^2 sphere upsampled 4x with one attribute passed before).
    #[test]
    fn attribute_slices_are_checked_on_the_upsampled_grid() {
        let source =
            Procedural::new(Shape::Sphere, [20_000, 20_000, 4], [1.0; 3], [0.0; 3]).unwrap();
        assert!(
            check_slice_memory(&source, Some(64 << 30)).is_ok(),
            "the source fits"
        );
        let up = Upsampled::new(Box::new(source), [4, 4, 1]).unwrap();
        let err = check_attribute_slice_memory(&up, 1, Some(64 << 30))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("79997 x 79997") && err.contains("fewer [[attributes]]"),
            "{err}"
        );
        assert!(
            check_attribute_slice_memory(&up, 0, Some(64 << 30)).is_ok(),
            "rows on demand without them"
        );
    }

    /// Positions an `f32` mesh cannot hold, or cannot tell apart at a fraction of a voxel, are
    /// refused: they came out flattened or with most triangles of no area.
    #[test]
    fn positions_f32_cannot_resolve_are_refused() {
        for (spacing, origin) in [
            ([0.5; 3], [1e9, 0.0, 0.0]),
            ([0.1; 3], [4e6; 3]),
            ([1.0; 3], [1e39, 0.0, 0.0]),
        ] {
            let e = check_f32_positions(&Grid {
                dims: [40; 3],
                spacing,
                origin,
            })
            .unwrap_err();
            assert!(
                e.contains("f32") && e.contains("[input] origin") && e.starts_with('x'),
                "{e}"
            );
        }
        // A spacing f32 cannot resolve anywhere: short numbers, and the spacing is the fix.
        for spacing in [[1e-300; 3], [1e300; 3], [1e37, 1.0, 1.0]] {
            let e = check_f32_positions(&Grid {
                dims: [40; 3],
                spacing,
                origin: [0.0; 3],
            })
            .unwrap_err();
            assert!(e.len() < 300, "{} characters: {e}", e.len());
            assert!(
                e.contains("give [input] spacing in a unit") && !e.contains("origin near 0"),
                "{e}"
            );
        }
        // Real grids: CT in millimetres, UTM metres, microscope stage micrometres, a long axis
        // from 0, an upsampled volume.
        for (dims, spacing, origin) in [
            ([512, 512, 2000], [0.3, 0.3, 0.5], [-150.0, -150.0, -800.0]),
            ([500, 500, 100], [1.0; 3], [5e5, 4e5, 0.0]),
            ([1000, 1000, 200], [0.1; 3], [5e4, 5e4, 0.0]),
            // UTM at 25 m with heights in metres; a tiny x spacing beside a huge z one.
            ([40, 40, 40], [25.0, 25.0, 1.0], [5e5, 4.1e6, -100.0]),
            ([17, 33, 9], [0.001, 1.0, 1000.0], [0.0; 3]),
            ([16384, 64, 64], [1.0; 3], [0.0; 3]),
            ([4081, 4081, 4081], [0.0625; 3], [0.0; 3]),
        ] {
            let grid = Grid {
                dims,
                spacing,
                origin,
            };
            assert!(check_f32_positions(&grid).is_ok(), "{grid:?}");
        }
    }
}
