//! Turns `[input]` into a volume source.

use isostream_volume::{Procedural, RawSpec, RawVolume, VolumeError, VolumeSource};

use crate::config::InputConfig;
use crate::error::{ConfigError, RunError};

/// Opens the volume a job names. Raw files need `dims` and `dtype`; procedural shapes `size`.
pub fn open_source(
    input: &InputConfig,
    job: &std::path::Path,
) -> Result<Box<dyn VolumeSource>, RunError> {
    if let Some(shape) = input.shape {
        let size = input.size.unwrap_or([2; 3]);
        let p = Procedural::new(shape, size, input.spacing, input.origin)?;
        return Ok(Box::new(p));
    }
    let path = input.path.clone().unwrap_or_default();
    let missing = |key: &str, what: &str| {
        RunError::Config(ConfigError::Invalid {
            path: job.to_path_buf(),
            key: format!("input.{key}"),
            expected: format!("{what} for the raw file {}", path.display()),
            got: "nothing".into(),
        })
    };
    let dims = input.dims.ok_or_else(|| missing("dims", "[nx, ny, nz]"))?;
    let dtype = input
        .dtype
        .ok_or_else(|| missing("dtype", "one of u8 i8 u16 i16 u32 i32 f32 f64"))?;
    let spec = RawSpec {
        path,
        dims,
        dtype,
        endian: input.endian,
        spacing: input.spacing,
        origin: input.origin,
        header_bytes: input.header_bytes,
    };
    let raw: Result<RawVolume, VolumeError> = RawVolume::open(&spec);
    Ok(Box::new(raw?))
}
