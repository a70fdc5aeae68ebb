//! Past 32 bits: every count on the path is `u64` (or a 64-bit `usize`), but SMB holds i32
//! indices, PLY and GLB u32 ones, and binary STL a u32 triangle count. A job whose output could
//! pass its format's limit is refused before any work, with the fix, instead of failing hours
//! later at the vertex or triangle that does not fit.

use std::path::Path;

use isostream_extract::table::MAX_TRIANGLES;

use crate::config::{JobConfig, Mode};
use crate::error::RunError;

// Counts of faces and vertices are `usize` in the simplifier and the formats' in-memory parts.
const _: () = assert!(usize::BITS >= 64, "isostream needs a 64-bit target");

/// What a format's limit counts: indexed formats number their vertices, while STL repeats the
/// corners of every triangle and numbers only the triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Counted {
    Vertices,
    Triangles,
}

impl Counted {
    /// The most the extractor can make of it per voxel: every surface vertex lies on its own
    /// grid edge (3 per voxel), and a cube's case holds at most `MAX_TRIANGLES` triangles.
    fn per_voxel(self) -> u64 {
        match self {
            Counted::Vertices => 3,
            Counted::Triangles => MAX_TRIANGLES as u64,
        }
    }
}

impl std::fmt::Display for Counted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Counted::Vertices => "vertices",
            Counted::Triangles => "triangles",
        })
    }
}

/// A format's 32-bit limit: what it counts, how many, the field that holds the count (with
/// its verb, for the error) and the formats to write instead.
struct Limit {
    counted: Counted,
    most: u64,
    what: &'static str,
    instead: &'static str,
}

/// The limit of a file of this name; `None` for formats without one (SMA and OBJ write
/// indices as text).
fn limit(output: &Path) -> Option<Limit> {
    let ext = output.extension()?.to_str()?.to_ascii_lowercase();
    let indices = |most, what| Limit {
        counted: Counted::Vertices,
        most,
        what,
        instead: ".sma (64-bit indices)",
    };
    match ext.as_str() {
        "smb" => Some(indices(i32::MAX as u64, "SMB's 32-bit signed indices hold")),
        "ply" => Some(indices(
            u64::from(u32::MAX),
            "PLY's 32-bit unsigned indices hold",
        )),
        "glb" => Some(indices(
            u64::from(u32::MAX),
            "glTF's 32-bit unsigned indices hold",
        )),
        "stl" => Some(Limit {
            counted: Counted::Triangles,
            most: u64::from(u32::MAX),
            what: "binary STL's 32-bit triangle count holds",
            instead: ".sma or .obj (no count limit)",
        }),
        _ => None,
    }
}

/// Most vertices or triangles the job could write: the extractor's most per voxel (see
/// [`Counted::per_voxel`]); a rate keeps that share of them; a face target `N` needs about
/// `N / 2` vertices on a closed surface and `N` triangles, bounded here by `N`.
fn bound(job: &JobConfig, voxels: u64, rate: f64, counted: Counted) -> u64 {
    let most = voxels.saturating_mul(counted.per_voxel());
    match (job.simplify.mode, job.output.faces) {
        (Mode::Rate, Some(faces)) => faces.min(most),
        (Mode::Rate, None) => (rate * most as f64).ceil() as u64,
        _ => most,
    }
}

/// Refuses a job on a grid of `voxels` whose output format cannot count what it could write.
pub(crate) fn check_job(job: &JobConfig, voxels: u64) -> Result<(), RunError> {
    check(job, voxels, job.simplify.rate())
}

/// Refuses a job on a grid of `voxels`, simplified at `rate`, whose output format cannot
/// count what it could write.
fn check(job: &JobConfig, voxels: u64, rate: f64) -> Result<(), RunError> {
    let Some(limit) = limit(&job.output.path) else {
        return Ok(());
    };
    let bound = bound(job, voxels, rate, limit.counted);
    if bound <= limit.most {
        return Ok(());
    }
    Err(RunError::IndexLimit {
        output: job.output.path.clone(),
        bound,
        counted: limit.counted,
        limit: limit.most,
        what: limit.what,
        instead: limit.instead,
        lower: match job.simplify.mode {
            Mode::Rate => "lower the output with [output] faces or a lower [simplify] rate",
            _ => "simplify it to a face count: [simplify] mode = \"rate\" with [output] faces",
        },
    })
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
        let e = check(&none, huge, 1.0).unwrap_err().to_string();
        assert!(
            e.contains("x.smb")
                && e.contains(".sma")
                && e.contains("mode = \"rate\" with [output] faces"),
            "{e}"
        );
        let sma = job("/tmp/x.sma", "[simplify]\nmode = \"none\"");
        check(&sma, huge, 1.0).unwrap();
        let low = job("/tmp/x.smb", "[simplify]\nrate = 0.001");
        check(&low, huge, 0.001).unwrap();
        let ply = job("/tmp/x.ply", "[simplify]\nrate = 0.1");
        assert!(check(&ply, huge, 0.1).is_err());
        let small = job("/tmp/x.smb", "[simplify]\nmode = \"none\"");
        check(&small, 700_000_000, 1.0).unwrap();
    }

    /// Binary STL counts triangles, not vertices: 1000^3 voxels kept whole could make 5 G of
    /// them, past its u32 count, and were refused only at the triangle that did not fit.
    #[test]
    fn refuses_what_could_pass_stls_triangle_count() {
        let voxels = 1_000_000_000;
        let none = job("/tmp/x.stl", "[simplify]\nmode = \"none\"");
        let e = check(&none, voxels, 1.0).unwrap_err().to_string();
        assert!(
            e.contains("output.path")
                && e.contains("x.stl")
                && e.contains("triangles")
                && e.contains(".obj")
                && e.contains("mode = \"rate\" with [output] faces"),
            "{e}"
        );
        let rate = job("/tmp/x.stl", "[simplify]\nrate = 0.9");
        let e = check(&rate, voxels, 0.9).unwrap_err().to_string();
        assert!(e.contains("a lower [simplify] rate"), "{e}");
        let low = job("/tmp/x.stl", "[simplify]\nrate = 0.5");
        check(&low, voxels, 0.5).unwrap();
        let mut target = job("/tmp/x.stl", "");
        target.output.faces = Some(1_000_000);
        check(&target, voxels, 1.0).unwrap();
        let obj = job("/tmp/x.obj", "[simplify]\nmode = \"none\"");
        check(&obj, voxels, 1.0).unwrap();
    }
}
