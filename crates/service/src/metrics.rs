//! `GET /metrics`: Prometheus / OpenMetrics text through `prometheus-client` (no global
//! recorder, so several services in one test process do not share counters).
//!
//! Counters grow as work happens (faces from every progress report, stage seconds when a run
//! ends, errors when they occur); gauges that describe the present (jobs by state, resident
//! faces, peak RSS) are set from the queue at scrape time, so they cannot drift from it.

use std::sync::atomic::AtomicU64;

use isostream_pipeline::StageSeconds;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

use crate::store::JobState;

type Labels = Vec<(String, String)>;

fn label(key: &str, value: &str) -> Labels {
    vec![(key.to_string(), value.to_string())]
}

#[derive(Debug)]
pub(crate) struct Metrics {
    registry: Registry,
    jobs: Family<Labels, Gauge>,
    voxels: Counter,
    faces_in: Counter,
    faces_out: Counter,
    resident_faces: Gauge,
    peak_rss: Gauge,
    stage_busy: Family<Labels, Counter<f64, AtomicU64>>,
    errors: Family<Labels, Counter>,
}

/// The present, as seen by the queue at scrape time.
pub(crate) struct Snapshot {
    pub jobs: Vec<(JobState, usize)>,
    pub resident_faces: u64,
}

impl Metrics {
    pub fn new() -> Self {
        let mut registry = Registry::with_prefix("isostream");
        let m = Metrics {
            registry: Registry::default(),
            jobs: Family::default(),
            voxels: Counter::default(),
            faces_in: Counter::default(),
            faces_out: Counter::default(),
            resident_faces: Gauge::default(),
            peak_rss: Gauge::default(),
            stage_busy: Family::default(),
            errors: Family::default(),
        };
        registry.register("jobs", "Jobs by state", m.jobs.clone());
        registry.register(
            "voxels",
            "Voxels swept by finished runs (counted when a run ends; a resumed run's from its checkpoint on)",
            m.voxels.clone(),
        );
        registry.register(
            "faces_in",
            "Faces extracted by marching cubes, all runs",
            m.faces_in.clone(),
        );
        registry.register(
            "faces_out",
            "Faces written after simplification, all runs",
            m.faces_out.clone(),
        );
        registry.register(
            "resident_faces",
            "Faces held by the simplifiers of the running jobs",
            m.resident_faces.clone(),
        );
        registry.register(
            "peak_rss_bytes",
            "Peak resident set size of the service process",
            m.peak_rss.clone(),
        );
        registry.register(
            "stage_busy_seconds",
            "Busy time of each pipeline stage over finished runs (blocked time excluded)",
            m.stage_busy.clone(),
        );
        registry.register(
            "errors",
            "Refused requests and failed runs, by kind",
            m.errors.clone(),
        );
        Metrics { registry, ..m }
    }

    pub fn faces(&self, more_in: u64, more_out: u64) {
        self.faces_in.inc_by(more_in);
        self.faces_out.inc_by(more_out);
    }

    pub fn voxels(&self, n: u64) {
        self.voxels.inc_by(n);
    }

    /// Every stage of the run summary's `stage_seconds`, labelled with its key there:
    /// `simplify_second` (a cascade's second simplifier, 0 without one) and `prune` (only
    /// from jobs that prune) included.
    pub fn stage_seconds(&self, s: &StageSeconds) {
        let prune = s.prune.map(|secs| ("prune", secs));
        for (stage, secs) in [
            ("read", s.read),
            ("extract", s.extract),
            ("detect", s.detect),
            ("simplify", s.simplify),
            ("simplify_second", s.simplify_second),
            ("write", s.write),
        ]
        .into_iter()
        .chain(prune)
        {
            self.stage_busy
                .get_or_create(&label("stage", stage))
                .inc_by(secs);
        }
    }

    pub fn error(&self, kind: &str) {
        self.errors.get_or_create(&label("kind", kind)).inc();
    }

    pub fn render(&self, now: &Snapshot) -> String {
        for (state, n) in &now.jobs {
            self.jobs
                .get_or_create(&label("state", state.name()))
                .set(*n as i64);
        }
        self.resident_faces
            .set(i64::try_from(now.resident_faces).unwrap_or(i64::MAX));
        let rss = isostream_pipeline::peak_rss_bytes().unwrap_or(0);
        self.peak_rss.set(i64::try_from(rss).unwrap_or(i64::MAX));
        let mut text = String::new();
        // Writing into a String cannot fail.
        let _ = prometheus_client::encoding::text::encode(&mut text, &self.registry);
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The second simplifier of a cascade (the default in mode rate) was left out, and so was
    /// the prune stage: every key of the run summary's `stage_seconds` is a label now.
    #[test]
    fn stage_busy_has_every_stage_of_the_summary() {
        let m = Metrics::new();
        let s = StageSeconds {
            read: 0.25,
            extract: 0.75,
            detect: 1.25,
            prune: Some(1.75),
            simplify: 2.25,
            simplify_second: 2.75,
            write: 3.25,
        };
        m.stage_seconds(&s);
        m.stage_seconds(&s);
        let text = m.render(&Snapshot {
            jobs: Vec::new(),
            resident_faces: 0,
        });
        let summary = serde_json::to_value(s).unwrap();
        let keys = summary.as_object().unwrap();
        assert_eq!(keys.len(), 7, "{summary}");
        let missing: Vec<String> = keys
            .iter()
            .map(|(key, secs)| {
                let twice = 2.0 * secs.as_f64().unwrap();
                format!("isostream_stage_busy_seconds_total{{stage=\"{key}\"}} {twice}")
            })
            .filter(|needle| !text.contains(needle))
            .collect();
        assert!(missing.is_empty(), "{missing:?} missing from\n{text}");
        // Without pruning, no prune series.
        let m = Metrics::new();
        m.stage_seconds(&StageSeconds::default());
        let text = m.render(&Snapshot {
            jobs: Vec::new(),
            resident_faces: 0,
        });
        assert!(
            text.contains("isostream_stage_busy_seconds_total{stage=\"simplify_second\"} 0")
                && !text.contains("stage=\"prune\""),
            "{text}"
        );
    }

    #[test]
    fn text_names_every_family() {
        let m = Metrics::new();
        m.faces(10, 2);
        m.voxels(4096);
        m.error("bad_job");
        m.stage_seconds(&StageSeconds::default());
        let text = m.render(&Snapshot {
            jobs: JobState::ALL.iter().map(|s| (*s, 0)).collect(),
            resident_faces: 5,
        });
        for needle in [
            "isostream_jobs{state=\"queued\"} 0",
            "isostream_faces_in_total 10",
            "isostream_voxels_total 4096",
            "isostream_faces_out_total 2",
            "isostream_resident_faces 5",
            "isostream_peak_rss_bytes",
            "isostream_stage_busy_seconds_total{stage=\"simplify\"}",
            "isostream_stage_busy_seconds_total{stage=\"simplify_second\"}",
            "isostream_errors_total{kind=\"bad_job\"} 1",
        ] {
            assert!(text.contains(needle), "{needle} missing from\n{text}");
        }
    }
}
