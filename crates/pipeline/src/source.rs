//! Turns `[input]` into a volume source.

use isostream_volume::{Procedural, Upsampled, VolumeSource};

use crate::config::InputConfig;
use crate::error::RunError;

/// Opens the volume a job names: a procedural shape, or a file in any format `volume` reads,
/// seen through `upsample` when the job asks for it.
pub fn open_source(input: &InputConfig) -> Result<Box<dyn VolumeSource>, RunError> {
    let source = open_stored(input)?;
    check_slice_memory(source.as_ref(), crate::rss::physical_memory_bytes())?;
    upsampled(source, input)
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
    let Some(physical) = physical else {
        return Ok(());
    };
    let dims = source.grid().dims;
    let need = dims[0]
        .saturating_mul(dims[1])
        .saturating_mul(4 * SLICES_HELD);
    if need <= physical {
        return Ok(());
    }
    Err(RunError::SliceMemory {
        input: source.describe(),
        nx: dims[0],
        ny: dims[1],
        slices: SLICES_HELD,
        need_gib: need as f64 / f64::from(1u32 << 30),
        physical_gib: physical as f64 / f64::from(1u32 << 30),
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
    use isostream_volume::Shape;

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
}
