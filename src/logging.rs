//! tracing setup: text or JSON lines on stderr, filter from RUST_LOG or the job's `[log] level`.

use std::io::IsTerminal;

use isostream_pipeline::{LogConfig, LogFormat};
use tracing_subscriber::EnvFilter;

pub fn init(log: &LogConfig) {
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
        LogFormat::Text => builder.try_init(),
        LogFormat::Json => builder.json().try_init(),
    };
}
