//! `measure`: quality of an output mesh against the full-resolution surface of its job's volume.

use std::path::Path;

pub fn measure(
    _job: &Path,
    _mesh: &Path,
    _json: bool,
    _samples_per_area: Option<f64>,
    _seed: u64,
) -> anyhow::Result<()> {
    anyhow::bail!("measure is not wired yet")
}
