//! What the report reads: the run summary (`<output>.run.json`) and, optionally, the JSON of
//! `isostream measure --json`. Only the fields the report shows are read and every other one is
//! ignored, so summaries of older or newer versions still make a report (a summary without a time
//! series gets a page that says so instead of the sweep plots).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use isostream_pipeline::TimeSeries;
use serde::Deserialize;

use crate::ReportError;

/// The run summary, as far as the report is concerned: the fields of `RunSummary` it shows,
/// read on their own (not `RunSummary` itself, which also holds every stage's statistics), so a
/// summary of another version still makes a page.
#[derive(Debug, Clone, Deserialize)]
pub struct Run {
    pub input: String,
    pub dims: [u64; 3],
    pub voxels: u64,
    pub iso: f64,
    pub mode: String,
    pub output: PathBuf,
    pub faces_extracted: u64,
    /// `[simplify] min_component_faces`: what was dropped (absent when nothing was pruned).
    #[serde(default)]
    pub prune: Option<Pruned>,
    pub target_faces: Option<u64>,
    pub faces_written: u64,
    pub vertices_written: u64,
    pub seconds: f64,
    /// Busy seconds by stage name (whatever stages the run had).
    pub stage_seconds: BTreeMap<String, f64>,
    pub peak_rss_bytes: Option<u64>,
    pub peak_resident_faces: u64,
    /// The slab a resumed run continued from (absent or null when it started at the beginning):
    /// its times cover that run only, its counters the whole job.
    #[serde(default)]
    pub resumed_at_slab: Option<u64>,
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Absent in summaries written before the series existed.
    pub series: Option<TimeSeries>,
}

/// The components dropped before simplifying, as far as the report is concerned.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct Pruned {
    pub min_component_faces: u64,
    pub components_pruned: u64,
    pub faces_pruned: u64,
}

/// `(bin start, count)` pairs.
pub type Bins = Vec<(f64, u64)>;

/// The measure report, as far as the report is concerned.
#[derive(Debug, Clone, Deserialize)]
pub struct Measure {
    pub quality: Quality,
    pub distances: Option<Distances>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Quality {
    pub triangles: u64,
    pub closed: bool,
    pub euler: i64,
    pub min_angle_histogram: Bins,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Distances {
    pub full_to_output: Directed,
    pub output_to_full: Directed,
    pub max_distance: f64,
    pub rms_pct: f64,
    pub hausdorff_pct: f64,
    /// Absent in reports of versions before the percentile existed.
    #[serde(default)]
    pub p999_pct: Option<f64>,
    /// Output samples counted at the search radius by versions before the second pass over the
    /// surface: their output -> full distances, and the Hausdorff distance and the 99.9 %
    /// figure, are then lower bounds (the page says "at least"). Absent (0) in newer reports,
    /// which measure those samples exactly (`far_samples`).
    #[serde(default)]
    pub clipped_samples: u64,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Directed {
    pub mean: f64,
    pub rms: f64,
    pub hausdorff: f64,
    /// Absent in reports of versions before the percentile existed.
    #[serde(default)]
    pub p999: Option<f64>,
    /// Absent in reports of versions before the histogram existed.
    #[serde(default)]
    pub histogram: Bins,
}

impl Run {
    /// Reads `<output>.run.json`.
    pub fn load(path: &Path) -> Result<Run, ReportError> {
        serde_json::from_slice(&read(path)?).map_err(|e| ReportError::NotRun {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })
    }
}

impl Measure {
    /// Reads the output of `isostream measure --json`.
    pub fn load(path: &Path) -> Result<Measure, ReportError> {
        serde_json::from_slice(&read(path)?).map_err(|e| ReportError::NotMeasure {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })
    }
}

impl Measure {
    /// Refuses the measure of another mesh than the run wrote (by the triangle count): the page
    /// showed "2016 written" beside "measured mesh 4348 triangles" and the other mesh's
    /// distances as the run's. `path` and `run_path` name the two files in the error.
    pub fn check_of(&self, path: &Path, run: &Run, run_path: &Path) -> Result<(), ReportError> {
        if self.quality.triangles == run.faces_written {
            return Ok(());
        }
        Err(ReportError::OtherMesh {
            measure: path.to_path_buf(),
            triangles: self.quality.triangles,
            run: run_path.to_path_buf(),
            faces_written: run.faces_written,
        })
    }
}

/// The file's bytes: a file that is not text (a mesh given by mistake) is then told apart as
/// "not a run summary" by the parser, not as a failed read.
fn read(path: &Path) -> Result<Vec<u8>, ReportError> {
    std::fs::read(path).map_err(|source| ReportError::Read {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A measure of the run's face count is the run's; another count is refused with both files
    /// and both counts.
    #[test]
    fn a_measure_of_another_mesh_is_refused() {
        let run: Run = serde_json::from_value(serde_json::json!({
            "input": "sphere", "dims": [8, 8, 8], "voxels": 512, "iso": 0.0, "mode": "rate",
            "output": "o.smb", "faces_extracted": 100, "faces_written": 20,
            "vertices_written": 12, "seconds": 0.1, "stage_seconds": {},
            "peak_resident_faces": 100
        }))
        .unwrap();
        let measure = |triangles: u64| -> Measure {
            serde_json::from_value(serde_json::json!({
                "quality": {"triangles": triangles, "closed": true, "euler": 2,
                            "min_angle_histogram": []},
                "distances": null
            }))
            .unwrap()
        };
        let (m, r) = (Path::new("m.json"), Path::new("o.smb.run.json"));
        assert!(measure(20).check_of(m, &run, r).is_ok());
        let e = measure(4348).check_of(m, &run, r).unwrap_err().to_string();
        assert!(
            e.starts_with(
                "m.json: measures a mesh of 4348 triangles, but the run of o.smb.run.json wrote 20;"
            ),
            "{e}"
        );
    }
}
