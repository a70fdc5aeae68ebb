//! Past 32 bits: every count on the path is `u64` (or a 64-bit `usize`), but SMB holds i32
//! indices and PLY and GLB u32 ones. A job whose output could pass that limit is refused before
//! any work, with the fix, instead of failing hours later at the vertex that does not fit.

use std::path::Path;

use crate::config::{JobConfig, Mode};
use crate::error::RunError;

// Counts of faces and vertices are `usize` in the simplifier and the formats' in-memory parts.
const _: () = assert!(usize::BITS >= 64, "isostream needs a 64-bit target");

/// The most vertices a file of this name can index, and the index type's name; `None` for
/// formats without a limit (SMA and OBJ write indices as text, STL has none).
fn vertex_limit(output: &Path) -> Option<(u64, &'static str)> {
    let ext = output.extension()?.to_str()?.to_ascii_lowercase();
    match ext.as_str() {
        "smb" => Some((i32::MAX as u64, "SMB's 32-bit signed indices")),
        "ply" => Some((u64::from(u32::MAX), "PLY's 32-bit unsigned indices")),
        "glb" => Some((u64::from(u32::MAX), "glTF's 32-bit unsigned indices")),
        _ => None,
    }
}

/// Most vertices the job could write: every surface vertex lies on its own grid edge (3 per
/// voxel at most); a rate keeps that share of them; a face target `N` needs about `N / 2`
/// vertices on a closed surface, bounded here by `N`.
fn vertex_bound(job: &JobConfig, voxels: u64, rate: f64) -> u64 {
    let edges = voxels.saturating_mul(3);
    match (job.simplify.mode, job.output.faces) {
        (Mode::Rate, Some(faces)) => faces.min(edges),
        (Mode::Rate, None) => (rate * edges as f64).ceil() as u64,
        _ => edges,
    }
}

/// Refuses a job on a grid of `voxels` whose output format cannot index the vertices it could
/// write.
pub(crate) fn check_job(job: &JobConfig, voxels: u64) -> Result<(), RunError> {
    check(job, vertex_bound(job, voxels, job.simplify.rate()))
}

/// Refuses a job whose output format cannot index `bound` vertices.
fn check(job: &JobConfig, bound: u64) -> Result<(), RunError> {
    match vertex_limit(&job.output.path) {
        Some((limit, what)) if bound > limit => Err(RunError::IndexLimit {
            output: job.output.path.clone(),
            bound,
            limit,
            what,
        }),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(output: &str, extra: &str) -> JobConfig {
        let text = format!(
            "[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\n[extract]\niso = 0.0\n{extra}\n[output]\npath = \"{output}\"\n"
        );
        JobConfig::parse(&text, Path::new("job.toml")).unwrap()
    }

    #[test]
    fn refuses_what_could_pass_the_format() {
        let huge = 1u64 << 34; // 16 Gvoxels
        let none = job("/tmp/x.smb", "[simplify]\nmode = \"none\"");
        let e = check(&none, vertex_bound(&none, huge, 1.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.smb") && e.contains(".sma") && e.contains("faces"),
            "{e}"
        );
        let sma = job("/tmp/x.sma", "[simplify]\nmode = \"none\"");
        check(&sma, vertex_bound(&sma, huge, 1.0)).unwrap();
        let low = job("/tmp/x.smb", "[simplify]\nrate = 0.001");
        check(&low, vertex_bound(&low, huge, 0.001)).unwrap();
        let ply = job("/tmp/x.ply", "[simplify]\nrate = 0.1");
        assert!(check(&ply, vertex_bound(&ply, huge, 0.1)).is_err());
        let small = job("/tmp/x.smb", "[simplify]\nmode = \"none\"");
        check(&small, vertex_bound(&small, 700_000_000, 1.0)).unwrap();
    }
}
