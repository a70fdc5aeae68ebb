//! tracing setup: text or JSON lines on stderr, filter from RUST_LOG or the job's `[log] level`.

use std::io::IsTerminal;

use isostream_pipeline::{LogConfig, LogFormat};
use isostream_service::JobLogLayer;
use tracing_subscriber::EnvFilter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

/// `jobs`: the service's per-job log files, written next to the usual lines.
pub fn init(log: &LogConfig, jobs: Option<JobLogLayer>) {
    let filter = EnvFilter::try_from_default_env()
        .or_else(|_| EnvFilter::try_new(log.level.as_deref().unwrap_or("info")))
        .unwrap_or_else(|_| EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(|| crate::progress::LogWriter)
        // Colour codes only for a person at a terminal, not in files, pipes or CI logs.
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false);
    // A second init (tests, repeated calls) is harmless: keep the first subscriber.
    let _ = match log.format {
        LogFormat::Text => builder.finish().with(jobs).try_init(),
        LogFormat::Json => builder.json().finish().with(jobs).try_init(),
    };
}
