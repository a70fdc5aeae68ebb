//! Per-job log files: every tracing event inside a `job{id=...}` span (the span the queue runs a
//! job in, which the pipeline's stage threads enter too) is also appended to
//! `STATE/jobs/{id}/job.log`. The log lives with the job, keeps every attempt's lines across
//! restarts, and is served by `GET /jobs/{id}/log`.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id};
use tracing::{Event, Subscriber};
use tracing_subscriber::fmt::time::{FormatTime, SystemTime};
use tracing_subscriber::layer::{Context, Layer};
use tracing_subscriber::registry::LookupSpan;

/// The log file's name in a job's folder.
pub(crate) const LOG_FILE: &str = "job.log";

/// A tracing layer writing each job's events to its folder; add it to the process's subscriber.
#[derive(Debug, Clone)]
pub struct JobLogLayer {
    jobs: PathBuf,
}

impl JobLogLayer {
    /// For the service whose state folder is `state_dir`.
    pub fn new(state_dir: &Path) -> Self {
        JobLogLayer {
            jobs: state_dir.join("jobs"),
        }
    }
}

/// The id of a `job` span, kept in the span's extensions.
struct JobId(String);

/// Collects an event's message and fields as `message key=value ...`, or a span's `id`.
#[derive(Default)]
struct Fields {
    message: String,
    rest: String,
    id: Option<String>,
}

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        match field.name() {
            "message" => {
                let _ = write!(self.message, "{value:?}");
            }
            "id" => self.id = Some(format!("{value:?}")),
            name => {
                let _ = write!(self.rest, " {name}={value:?}");
            }
        }
    }

    fn record_str(&mut self, field: &Field, value: &str) {
        match field.name() {
            "message" => self.message.push_str(value),
            "id" => self.id = Some(value.to_string()),
            name => {
                let _ = write!(self.rest, " {name}={value}");
            }
        }
    }
}

impl<S: Subscriber + for<'a> LookupSpan<'a>> Layer<S> for JobLogLayer {
    fn on_new_span(&self, attrs: &Attributes<'_>, id: &Id, ctx: Context<'_, S>) {
        if attrs.metadata().name() != "job" {
            return;
        }
        let mut fields = Fields::default();
        attrs.record(&mut fields);
        // Only the service's own ids (hex) name a folder: nothing else can become a path.
        if let (Some(job), Some(span)) = (fields.id, ctx.span(id))
            && !job.is_empty()
            && job.chars().all(|c| c.is_ascii_hexdigit())
        {
            span.extensions_mut().insert(JobId(job));
        }
    }

    fn on_event(&self, event: &Event<'_>, ctx: Context<'_, S>) {
        let Some(scope) = ctx.event_scope(event) else {
            return;
        };
        let mut job = None;
        let mut spans = Vec::new();
        for span in scope.from_root() {
            match span.extensions().get::<JobId>() {
                Some(JobId(id)) => job = Some(id.clone()),
                None => spans.push(span.name()),
            }
        }
        let Some(job) = job else {
            return;
        };
        let mut fields = Fields::default();
        event.record(&mut fields);
        let mut line = String::new();
        let _ =
            SystemTime.format_time(&mut tracing_subscriber::fmt::format::Writer::new(&mut line));
        let _ = write!(line, " {:>5} ", event.metadata().level());
        for s in spans {
            let _ = write!(line, "{s}: ");
        }
        let _ = writeln!(line, "{}{}", fields.message, fields.rest);
        // Best effort: a log that cannot be written must not fail the job. The folder exists
        // from submission on; a file is never created outside it.
        if let Ok(mut file) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.jobs.join(&job).join(LOG_FILE))
        {
            let _ = file.write_all(line.as_bytes());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    #[test]
    fn events_in_a_job_span_go_to_its_file_only() {
        let dir = tempfile::tempdir().unwrap();
        let job = "00ff";
        std::fs::create_dir_all(dir.path().join("jobs").join(job)).unwrap();
        let subscriber = tracing_subscriber::registry().with(JobLogLayer::new(dir.path()));
        tracing::subscriber::with_default(subscriber, || {
            tracing::info!("outside any job");
            let span = tracing::info_span!("job", id = %job);
            let _in_job = span.enter();
            let stage = tracing::info_span!("stage", stage = "simplify");
            let _in_stage = stage.enter();
            tracing::warn!(slab = 3, eta_s = 1.5, "progress");
            // Not a service id: never a path.
            let odd = tracing::info_span!("job", id = "../x");
            let _odd = odd.enter();
            tracing::info!("nowhere");
        });
        let log =
            std::fs::read_to_string(dir.path().join("jobs").join(job).join(LOG_FILE)).unwrap();
        let lines: Vec<&str> = log.lines().collect();
        assert_eq!(lines.len(), 2, "{log}");
        assert!(
            lines[0].contains(" WARN stage: progress slab=3 eta_s=1.5"),
            "{log}"
        );
        assert!(lines[1].ends_with("stage: job: nowhere"), "{log}");
        assert!(!dir.path().join("jobs/x").exists() && !dir.path().join("x").exists());
    }
}
