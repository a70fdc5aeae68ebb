//! `[[attributes]]`: extra scalar fields sampled at the surface vertices (issue 5), and the
//! reader side that delivers them slice by slice together with the iso volume.
//!
//! Each attribute is a second volume on the same grid (any format the input may have), another
//! array of the input's multi-array file, or derived from the iso volume (`gradient_magnitude`,
//! central differences in physical units). The reader hands the extractor slice `z` of the iso
//! volume with slice `z` of every attribute; a derived gradient needs iso slices `z - 1 .. z + 1`,
//! so the reader reads one slice ahead and keeps one behind (three iso slices in memory instead of
//! one, still independent of the volume's depth).

use std::path::{Path, PathBuf};

use isostream_simplify::Priority;
use std::sync::{Arc, OnceLock};

use isostream_volume::{Dtype, Endian, Grid, OpenOptions, SlabBounds, SliceRows, VolumeSource};
use serde::{Deserialize, Serialize};

use crate::checkpoint;
use crate::config::{InputConfig, JobConfig, PriorityKind};
use crate::error::{ConfigError, RunError};

/// Fields derived from the iso volume itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Derived {
    /// `|grad f|` of the iso volume by central differences (one-sided at the faces), in value
    /// units per physical length (using `spacing`).
    GradientMagnitude,
}

/// One `[[attributes]]` entry.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttributeConfig {
    /// Name written to the output (SMA/PLY property, GLB `_NAME` accessor).
    pub name: String,
    /// Derived from the iso volume instead of read from a file.
    pub derive: Option<Derived>,
    /// A second volume on the same grid. Default: the input file (then `array` names another
    /// of its arrays).
    pub path: Option<PathBuf>,
    /// The array of a multi-array file (VTK).
    pub array: Option<String>,
    /// Raw-file layout of `path`, as in `[input]`.
    pub dims: Option<[u64; 3]>,
    pub dtype: Option<Dtype>,
    pub endian: Option<Endian>,
    pub header_bytes: Option<u64>,
}

impl AttributeConfig {
    pub(crate) fn resolve_path(&mut self, base: &Path) {
        if let Some(p) = &self.path
            && p.is_relative()
        {
            self.path = Some(base.join(p));
        }
    }
}

/// Checks `[[attributes]]` and the values of the attribute keys of `[simplify]` (where each
/// applies is checked with every key the mode or priority reads: `SimplifyConfig::scoped_keys`).
pub(crate) fn validate(job: &JobConfig, origin: &Path) -> Result<(), ConfigError> {
    let bad = |key: String, expected: &str, got: String| ConfigError::Invalid {
        path: origin.to_path_buf(),
        key,
        expected: expected.to_string(),
        got,
    };
    for (i, a) in job.attributes.iter().enumerate() {
        let key = |k: &str| format!("attributes[{i}].{k}");
        if a.name.is_empty()
            || a.name
                .chars()
                .any(|c| !(c.is_ascii_alphanumeric() || c == '_'))
        {
            return Err(bad(
                key("name"),
                "a name of letters, digits and _",
                format!("{:?}", a.name),
            ));
        }
        // The output formats name the position properties x, y and z (PLY, SMA): an attribute
        // of one of those names could not be told from them (the writer refused it only once
        // the run had started).
        if ["x", "y", "z"].contains(&a.name.as_str()) {
            return Err(bad(
                key("name"),
                "a name other than x, y and z (the positions' names in the output)",
                format!("{:?}", a.name),
            ));
        }
        if job.attributes[..i].iter().any(|b| b.name == a.name) {
            return Err(bad(key("name"), "a name used once", a.name.clone()));
        }
        let file_keys = a.path.is_some()
            || a.array.is_some()
            || a.dims.is_some()
            || a.dtype.is_some()
            || a.endian.is_some()
            || a.header_bytes.is_some();
        match (a.derive, file_keys) {
            (Some(_), true) => {
                return Err(bad(
                    key("derive"),
                    "either `derive` or a volume (`path`/`array`), not both",
                    "both".into(),
                ));
            }
            (None, false) => {
                return Err(bad(
                    key("path"),
                    "a volume `path`, an `array` of the input file, or `derive = \"gradient_magnitude\"`",
                    "nothing".into(),
                ));
            }
            (None, true) if a.path.is_none() && job.input.path.is_none() => {
                return Err(bad(
                    key("path"),
                    "a volume file (the input is procedural, it has no other arrays)",
                    "nothing".into(),
                ));
            }
            _ => {}
        }
    }
    let s = &job.simplify;
    if let Some(lambda) = s.lambda.filter(|l| !(0.0..=1.0).contains(l)) {
        return Err(bad(
            "simplify.lambda".into(),
            "a value in [0, 1]",
            lambda.to_string(),
        ));
    }
    if let Some(w) = &s.attribute_weights {
        if w.len() != job.attributes.len() {
            return Err(bad(
                "simplify.attribute_weights".into(),
                "one weight per [[attributes]] entry",
                format!(
                    "{} weights for {} attributes",
                    w.len(),
                    job.attributes.len()
                ),
            ));
        }
        if w.iter().any(|x| !(*x > 0.0 && x.is_finite())) {
            return Err(bad(
                "simplify.attribute_weights".into(),
                "finite values > 0",
                format!("{w:?}"),
            ));
        }
    }
    if s.priority() == PriorityKind::AttributeQuadric && job.attributes.is_empty() {
        return Err(bad(
            "simplify.priority".into(),
            "\"attribute-quadric\" only with at least one [[attributes]] entry",
            "no attributes".into(),
        ));
    }
    // The data-dependent weight is lambda x angle deficit + (1 - lambda) x attribute gradient:
    // without attributes the gradient is 0, so lambda > 0 orders by curvature alone (every such
    // lambda gives the same bytes) and lambda = 0 weighs every edge 0, leaving the order to the
    // queue's ties (engine at R = 0.1: 22 boundary edges left where the geometric order leaves
    // 482). Only that combination means nothing.
    if s.priority() == PriorityKind::DataDependent
        && s.lambda == Some(0.0)
        && job.attributes.is_empty()
    {
        return Err(bad(
            "simplify.lambda".into(),
            "above 0 with priority = \"data-dependent\" and no [[attributes]] entry (lambda = 0 \
             weighs only the attributes' gradient, so every edge would weigh 0: raise lambda to \
             order by curvature, or add an [[attributes]] entry)",
            "0".into(),
        ));
    }
    Ok(())
}

/// The simplifier's priority for a job.
pub(crate) fn priority(job: &JobConfig) -> Priority {
    let s = &job.simplify;
    match s.priority() {
        PriorityKind::Geometric => Priority::Geometric,
        PriorityKind::DataDependent => Priority::DataDependent {
            lambda: s.lambda.unwrap_or(crate::config::DEFAULT_LAMBDA),
        },
        PriorityKind::AttributeQuadric => Priority::AttributeQuadric {
            weights: s
                .attribute_weights
                .clone()
                .unwrap_or_else(|| vec![1.0; job.attributes.len()]),
        },
    }
}

/// Where one attribute's slices come from.
pub(crate) enum Source {
    Volume(Box<dyn VolumeSource>),
    Gradient,
}

/// Opens every attribute's volume and checks that its grid matches the iso volume's: the same
/// dims and, when both have a header, the same axis flips (values are paired by voxel index, and
/// an attribute stored with other flips than the iso volume's would pair mirrored voxels). A raw
/// file (`dims`, which only raw files take) or a procedural shape has no header and states no
/// axis directions: a raw attribute takes the input's, as it takes its spacing and origin, and a
/// raw input pairs with an attribute of any orientation, whose header places nothing (the mesh
/// is the input's). Refusing those pairs refused a raw attribute beside every LPS NRRD.
pub(crate) fn open(
    attributes: &[AttributeConfig],
    input: &InputConfig,
    grid: Grid,
    orientation: isostream_volume::Orientation,
) -> Result<Vec<Source>, RunError> {
    attributes
        .iter()
        .map(|a| {
            if a.derive.is_some() {
                return Ok(Source::Gradient);
            }
            let (path, options) = match &a.path {
                Some(p) => (
                    p.clone(),
                    OpenOptions {
                        dims: a.dims,
                        dtype: a.dtype,
                        endian: a.endian,
                        header_bytes: a.header_bytes,
                        spacing: input.spacing,
                        origin: input.origin,
                        array: a.array.clone(),
                    },
                ),
                None => (
                    input.path.clone().unwrap_or_default(),
                    OpenOptions {
                        array: a.array.clone(),
                        ..input.open_options()
                    },
                ),
            };
            let source =
                crate::source::upsampled(isostream_volume::open_path(&path, &options)?, input)?;
            if source.grid().dims != grid.dims {
                return Err(RunError::Volume(isostream_volume::VolumeError::Grid {
                    origin: path.display().to_string(),
                    problem: format!(
                        "attribute `{}` has dims {:?} but the iso volume has {:?}; attributes need the same grid",
                        a.name,
                        source.grid().dims,
                        grid.dims
                    ),
                }));
            }
            let headerless =
                a.dims.is_some() || input.dims.is_some() || input.shape.is_some();
            if !headerless && source.orientation() != orientation {
                return Err(RunError::Volume(isostream_volume::VolumeError::Grid {
                    origin: path.display().to_string(),
                    problem: format!(
                        "attribute `{}` has orientation {:?} but the iso volume has {:?}; attributes need the same axis directions (resample one onto the other's)",
                        a.name,
                        source.orientation(),
                        orientation
                    ),
                }));
            }
            Ok(Source::Volume(source))
        })
        .collect()
}

/// Slice `z` of the iso volume and of every attribute.
#[derive(Clone)]
pub struct Slices {
    pub z: u64,
    /// Empty when `rows` gives the iso slice.
    pub iso: Vec<f32>,
    pub attrs: Vec<Vec<f32>>,
    /// The iso slice as rows computed on demand ([`SliceReader::rows_on_demand`]): it never
    /// exists whole, the extractor works on strips of it.
    pub(crate) rows: Option<Arc<dyn SliceRows>>,
    /// The iso slice's value bounds per block ([`Slices::bounds`]), computed by the first of the
    /// two slabs it belongs to and merged by both.
    bounds: OnceLock<SlabBounds>,
    /// Voxels of the iso slice, and of the attributes' slices together, whose finite values
    /// were beyond f32's range and were saturated (`VolumeSource::saturated_voxels`).
    pub(crate) saturated: u64,
    pub(crate) saturated_attributes: u64,
}

impl Slices {
    /// The iso slice's bounds in blocks of `block` cubes (`SlabBounds::of_slice`), computed once
    /// (every caller asks with the same block). A slab's bounds are its two slices' merged;
    /// computing each slab's from both of its slices paid for every slice twice.
    pub(crate) fn bounds(&self, grid: &Grid, block: [u64; 2]) -> &SlabBounds {
        self.bounds
            .get_or_init(|| SlabBounds::of_slice(grid, block, &self.iso))
    }
}

/// Reads the iso volume and the attributes in z order, one iso slice ahead when a gradient is
/// derived.
pub struct SliceReader {
    iso: Box<dyn VolumeSource>,
    attributes: Vec<Source>,
    grid: Grid,
    next_z: u64,
    /// Iso slices `next_z - 1` and `next_z` (and `next_z + 1` once read ahead, with the
    /// voxels its read saturated).
    prev: Option<Vec<f32>>,
    ahead: Option<(Vec<f32>, u64)>,
    /// Empty-space skipping at this iso value: iso slices are exact only near the surface
    /// (`VolumeSource::read_slice_near`).
    near: Option<f32>,
    /// Iso slices as rows on demand when the volume gives them (`Slices::rows`).
    rows: bool,
}

impl SliceReader {
    pub(crate) fn new(iso: Box<dyn VolumeSource>, attributes: Vec<Source>) -> Self {
        let grid = iso.grid();
        Self {
            iso,
            attributes,
            grid,
            next_z: 0,
            prev: None,
            ahead: None,
            near: None,
            rows: false,
        }
    }

    /// Gives iso slices as rows computed on demand (`Slices::rows`) when the volume can
    /// (`VolumeSource::slice_rows`: an upsampled input) and no attribute needs whole slices:
    /// the extraction then works on strips and a gigavoxel slice never exists whole.
    pub(crate) fn rows_on_demand(mut self) -> Self {
        self.rows = self.attributes.is_empty();
        self
    }

    /// Reads iso slices exact only near the surface at `iso` (empty-space skipping). Ignored
    /// when a gradient is derived: it needs the neighbours of every surface voxel.
    pub(crate) fn skip_empty(mut self, iso: f32) -> Self {
        if !self
            .attributes
            .iter()
            .any(|a| matches!(a, Source::Gradient))
        {
            self.near = Some(iso);
        }
        self
    }

    /// Value bounds of slab z's blocks when the iso volume knows them without its voxels.
    pub(crate) fn slab_bounds(
        &mut self,
        z: u64,
    ) -> Result<Option<std::sync::Arc<isostream_volume::SlabBounds>>, RunError> {
        Ok(self.iso.slab_bounds(z)?)
    }

    /// Iso slice `z`, and how many of its voxels were saturated (`VolumeSource::saturated_voxels`
    /// around this read; the reader reads each slice once in a sweep).
    fn read_iso(&mut self, z: u64) -> Result<(Vec<f32>, u64), RunError> {
        let mut s = vec![0f32; self.grid.slice_len()];
        let before = self.iso.saturated_voxels();
        match self.near {
            Some(iso) => self.iso.read_slice_near(z, iso, &mut s)?,
            None => self.iso.read_slice(z, &mut s)?,
        }
        Ok((s, self.iso.saturated_voxels() - before))
    }

    /// Opens a job's iso volume and attributes (`[input]`, `[[attributes]]`).
    ///
    /// # Errors
    /// A volume cannot be opened, an attribute's grid differs from the iso volume's, or the
    /// slices held whole do not fit the machine's memory.
    pub fn open(job: &JobConfig) -> Result<Self, RunError> {
        let iso = crate::open_source(&job.input)?;
        crate::source::check_attribute_slice_memory(
            iso.as_ref(),
            job.attributes.len(),
            crate::rss::physical_memory_bytes(),
        )?;
        let attributes = open(&job.attributes, &job.input, iso.grid(), iso.orientation())?;
        Ok(Self::new(iso, attributes))
    }

    pub fn grid(&self) -> Grid {
        self.grid
    }

    /// Hash of the stored values of `slices`' iso slice (`checkpoint::hash_slice`): the values
    /// held when they exist whole, else the source slices it is computed from
    /// (`VolumeSource::identity_values`), never a pass over a fine slice given as rows, which
    /// can be days long.
    pub(crate) fn hash(&mut self, slices: &Slices) -> Result<u64, RunError> {
        Ok(match slices.rows {
            Some(_) => checkpoint::hash_slice(&self.iso.identity_values(slices.z)?),
            None => checkpoint::hash_slice(&slices.iso),
        })
    }

    /// The iso volume, as its errors name it (a path, or a procedural shape).
    pub(crate) fn describe(&self) -> String {
        self.iso.describe()
    }

    /// Makes slice `z` the next one (resuming at a checkpoint): what `next_slices` returns from
    /// here is what it returned when it got to `z` the first time.
    ///
    /// # Errors
    /// Reading slice `z - 1` for a derived gradient failed.
    pub(crate) fn seek(&mut self, z: u64) -> Result<(), RunError> {
        let gradient = self
            .attributes
            .iter()
            .any(|a| matches!(a, Source::Gradient));
        // Slice z - 1's voxels were counted before the checkpoint.
        self.prev = match z {
            1.. if gradient => Some(self.read_iso(z - 1)?.0),
            _ => None,
        };
        self.ahead = None;
        self.next_z = z;
        Ok(())
    }

    /// The next slice, `None` after the last.
    ///
    /// # Errors
    /// Reading a volume failed.
    pub fn next_slices(&mut self) -> Result<Option<Slices>, RunError> {
        let z = self.next_z;
        let nz = self.grid.dims[2];
        if z >= nz {
            return Ok(None);
        }
        let before = self.iso.saturated_voxels();
        if self.rows
            && let Some(rows) = self.iso.slice_rows(z, self.near)?
        {
            self.next_z += 1;
            return Ok(Some(Slices {
                z,
                iso: Vec::new(),
                attrs: Vec::new(),
                rows: Some(rows),
                bounds: OnceLock::new(),
                saturated: self.iso.saturated_voxels() - before,
                saturated_attributes: 0,
            }));
        }
        let (cur, saturated) = match self.ahead.take() {
            Some(s) => s,
            None => self.read_iso(z)?,
        };
        let gradient = self
            .attributes
            .iter()
            .any(|a| matches!(a, Source::Gradient));
        let next = if gradient && z + 1 < nz {
            Some(self.read_iso(z + 1)?)
        } else {
            None
        };
        let mut grad: Option<Vec<f32>> = None;
        let mut attrs = Vec::with_capacity(self.attributes.len());
        let mut saturated_attributes = 0;
        for a in &mut self.attributes {
            match a {
                Source::Volume(v) => {
                    let mut s = vec![0f32; self.grid.slice_len()];
                    let before = v.saturated_voxels();
                    v.read_slice(z, &mut s)?;
                    saturated_attributes += v.saturated_voxels() - before;
                    attrs.push(s);
                }
                Source::Gradient => {
                    let g = grad.get_or_insert_with(|| {
                        let mut out = vec![0f32; cur.len()];
                        isostream_extract::attributes::gradient_magnitude_slice(
                            &self.grid,
                            self.prev.as_deref(),
                            &cur,
                            next.as_ref().map(|(s, _)| s.as_slice()),
                            &mut out,
                        );
                        out
                    });
                    attrs.push(g.clone());
                }
            }
        }
        if gradient {
            self.prev = Some(cur.clone());
        }
        self.ahead = next;
        self.next_z += 1;
        Ok(Some(Slices {
            z,
            iso: cur,
            attrs,
            rows: None,
            bounds: OnceLock::new(),
            saturated,
            saturated_attributes,
        }))
    }
}
