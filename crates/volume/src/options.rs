//! What a job file can say about an input besides its path: raw layout (a raw file has no header)
//! and overrides for header-carrying formats.

use crate::grid::spacing_problem;
use crate::{Dtype, Endian, Grid, VolumeError};
use std::path::Path;

/// Parameters for [`crate::open_path`]. `dims`, `dtype`, `endian` and `header_bytes` describe a
/// headerless `.raw` file and are rejected for other formats (their headers say it);
/// `spacing` and `origin` override any header; `array` picks one array of a multi-array file
/// (VTK: a DataArray name; Zarr: a child array of a group, or an OME-Zarr level's `path`).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpenOptions {
    pub dims: Option<[u64; 3]>,
    pub dtype: Option<Dtype>,
    pub endian: Option<Endian>,
    pub header_bytes: Option<u64>,
    pub spacing: Option<[f64; 3]>,
    pub origin: Option<[f64; 3]>,
    pub array: Option<String>,
}

impl OpenOptions {
    /// Errors if raw-only parameters were given for a format whose header defines them.
    pub(crate) fn reject_raw_params(&self, path: &Path, format: &str) -> Result<(), VolumeError> {
        let given: Vec<&str> = [
            ("dims", self.dims.is_some()),
            ("dtype", self.dtype.is_some()),
            ("endian", self.endian.is_some()),
            ("header_bytes", self.header_bytes.is_some()),
        ]
        .iter()
        .filter(|(_, set)| *set)
        .map(|(k, _)| *k)
        .collect();
        let (verb, them) = match given.len() {
            0 => return Ok(()),
            1 => ("applies", "it"),
            _ => ("apply", "them"),
        };
        Err(VolumeError::Grid {
            origin: path.display().to_string(),
            problem: format!(
                "{} {verb} only to .raw files but this is {format}, whose header defines {them}; remove {them} from [input]",
                given.join(", ")
            ),
        })
    }

    /// Builds the grid of a file from its header values and these overrides. A header's spacing
    /// that no grid can have (a zero `pixdim`, a degenerate sform) names `[input] spacing`, the
    /// way to run the file without editing it.
    pub(crate) fn grid(
        &self,
        path: &Path,
        dims: [u64; 3],
        spacing: [f64; 3],
        origin: [f64; 3],
    ) -> Result<Grid, VolumeError> {
        let header_problem = match self.spacing {
            None => spacing_problem(spacing, "fix the header or set [input] spacing"),
            Some(_) => None,
        };
        if let Some(problem) = header_problem {
            return Err(VolumeError::Grid {
                origin: path.display().to_string(),
                problem: format!("the header's {problem}"),
            });
        }
        Grid::new(
            dims,
            self.spacing.unwrap_or(spacing),
            self.origin.unwrap_or(origin),
        )
        .map_err(|e| e.in_origin(&path.display().to_string()))
    }

    /// Errors if an array was asked for in a format that holds one unnamed array.
    pub(crate) fn reject_array(&self, path: &Path, format: &str) -> Result<(), VolumeError> {
        match &self.array {
            None => Ok(()),
            Some(name) => Err(VolumeError::Grid {
                origin: path.display().to_string(),
                problem: format!(
                    "array {name:?} was requested but {format} files hold a single unnamed array; remove [input] array"
                ),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_params_rejected_for_headered_formats() {
        let o = OpenOptions {
            dims: Some([2, 2, 2]),
            header_bytes: Some(4),
            ..Default::default()
        };
        let e = o
            .reject_raw_params(Path::new("a.nrrd"), "NRRD")
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "a.nrrd: dims, header_bytes apply only to .raw files but this is NRRD, whose header defines them; remove them from [input]"
        );
        let one = OpenOptions {
            endian: Some(Default::default()),
            ..Default::default()
        };
        assert_eq!(
            one.reject_raw_params(Path::new("a.nrrd"), "NRRD")
                .unwrap_err()
                .to_string(),
            "a.nrrd: endian applies only to .raw files but this is NRRD, whose header defines it; remove it from [input]"
        );
        assert!(
            OpenOptions::default()
                .reject_raw_params(Path::new("a"), "x")
                .is_ok()
        );
    }

    #[test]
    fn overrides_win_over_header() {
        let o = OpenOptions {
            spacing: Some([2.0, 2.0, 2.0]),
            ..Default::default()
        };
        let g = o
            .grid(Path::new("a"), [2, 3, 4], [1.0; 3], [5.0; 3])
            .unwrap();
        assert_eq!((g.spacing, g.origin), ([2.0; 3], [5.0; 3]));
    }

    /// A header's impossible spacing names the override; the override itself is checked as any
    /// grid's.
    #[test]
    fn a_bad_header_spacing_names_the_override() {
        let none = OpenOptions::default();
        let e = none
            .grid(Path::new("a.nii"), [2; 3], [1.0, 0.0, 1.0], [0.0; 3])
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "a.nii: the header's spacing [1.0, 0.0, 1.0] must be finite and > 0 on every axis; fix the header or set [input] spacing"
        );
        let given = OpenOptions {
            spacing: Some([1.0; 3]),
            ..Default::default()
        };
        assert!(
            given
                .grid(Path::new("a.nii"), [2; 3], [1.0, 0.0, 1.0], [0.0; 3])
                .is_ok()
        );
    }

    #[test]
    fn options_deserialize_strictly() {
        let o: OpenOptions =
            serde_json::from_str(r#"{"dims":[2,3,4],"dtype":"u16","endian":"big","array":"v"}"#)
                .unwrap();
        assert_eq!(o.dims, Some([2, 3, 4]));
        assert_eq!(o.endian, Some(Endian::Big));
        assert!(serde_json::from_str::<OpenOptions>(r#"{"dimz":[2,3,4]}"#).is_err());
    }
}
