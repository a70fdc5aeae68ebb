//! tracing setup: text or JSON lines on stderr, filter from RUST_LOG or the job's `[log] level`.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};

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
        // Its own failures would be printed with `eprintln!` on the stderr that just failed,
        // a panic when that is a closed pipe (`LogWriter` drops what stderr refuses).
        .log_internal_errors(false)
        .with_target(false);
    // A second init (tests, repeated calls) is harmless: keep the first subscriber.
    let installed = match log.format {
        LogFormat::Text => builder.finish().with(jobs).try_init(),
        LogFormat::Json => builder.json().finish().with(jobs).try_init(),
    };
    if installed.is_ok() {
        JSON_LINES.store(log.format == LogFormat::Json, Ordering::Relaxed);
    }
}

/// Whether stderr carries JSON lines (`[log] format = "json"` once the job was read).
static JSON_LINES: AtomicBool = AtomicBool::new(false);

/// The line a failed command ends with: `error: ...`, or with JSON logs an object shaped like
/// the log lines before it (level `ERROR`, the message and the exit code among its fields), so
/// that a log pipeline reading one JSON object per line reads the error too. Printed whatever
/// the log level: the error is the command's answer, not a log line a filter may drop.
pub fn error_line(message: &str, exit_code: u8) -> String {
    if !JSON_LINES.load(Ordering::Relaxed) {
        return format!("error: {message}");
    }
    use tracing_subscriber::fmt::format::Writer;
    use tracing_subscriber::fmt::time::{FormatTime, SystemTime};
    let mut timestamp = String::new();
    let _ = SystemTime.format_time(&mut Writer::new(&mut timestamp));
    serde_json::json!({
        "timestamp": timestamp,
        "level": "ERROR",
        "fields": { "message": message, "exit_code": exit_code },
    })
    .to_string()
}
