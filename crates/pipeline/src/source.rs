//! Turns `[input]` into a volume source.

use isostream_volume::{Procedural, VolumeSource};

use crate::config::InputConfig;
use crate::error::RunError;

/// Opens the volume a job names: a procedural shape, or a file in any format `volume` reads.
pub fn open_source(input: &InputConfig) -> Result<Box<dyn VolumeSource>, RunError> {
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
