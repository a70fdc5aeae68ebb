//! Turns `[input]` into a volume source.

use isostream_volume::{Procedural, Upsampled, VolumeSource};

use crate::config::InputConfig;
use crate::error::RunError;

/// Opens the volume a job names: a procedural shape, or a file in any format `volume` reads,
/// seen through `upsample` when the job asks for it.
pub fn open_source(input: &InputConfig) -> Result<Box<dyn VolumeSource>, RunError> {
    upsampled(open_stored(input)?, input)
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
