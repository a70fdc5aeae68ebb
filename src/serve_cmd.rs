//! `serve`: merges the flags with `--config FILE` into an `isostream_service::ServeConfig` and
//! runs the service.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use isostream_pipeline::{LogConfig, LogFormat};
use isostream_service::ServeFile;

const DEFAULT_LISTEN: &str = "127.0.0.1:8440";
/// Jobs waiting at once by default: far more than a day of real jobs, far fewer than would fill
/// a disk with job files of up to 1 MiB.
const DEFAULT_MAX_QUEUED: usize = 1000;

#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// A TOML file with any of the keys below (state, listen, allow_input, token_file,
    /// max_parallel_jobs, max_queued_jobs, log_format); flags given here win. Example:
    /// config/serve.toml.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Folder holding the jobs (default: $STATE_DIRECTORY under systemd, else ./isostream-state).
    #[arg(long)]
    pub state: Option<PathBuf>,
    /// Address to listen on (default 127.0.0.1:8440); a non-loopback address needs a token.
    #[arg(long, value_parser = isostream_service::parse_listen)]
    pub listen: Option<SocketAddr>,
    /// A folder job inputs may be read from (repeatable; adds to the config file's); without
    /// any, only procedural shapes.
    #[arg(long = "allow-input", value_name = "DIR")]
    pub allow_input: Vec<PathBuf>,
    /// Require `Authorization: Bearer T` on every request (visible in `ps`: prefer --token-file).
    #[arg(long, conflicts_with = "token_file")]
    pub token: Option<String>,
    /// Read the token from a file (surrounding whitespace ignored).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// Jobs running at once (default 1: each already keeps its stage threads and extraction
    /// pool busy).
    #[arg(long)]
    pub max_parallel_jobs: Option<usize>,
    /// Jobs waiting to run at once (default 1000); a submission past it is refused with 429.
    #[arg(long)]
    pub max_queued_jobs: Option<usize>,
    /// Log lines as `text` (default) or `json` (one object per line, the job id in its span).
    #[arg(long, value_parser = ["text", "json"])]
    pub log_format: Option<String>,
}

pub fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let file = match &args.config {
        Some(path) => ServeFile::load(path)?,
        None => ServeFile::default(),
    };
    let format = match args.log_format.as_deref() {
        Some("json") => LogFormat::Json,
        Some(_) => LogFormat::Text,
        None => file.log_format.unwrap_or_default(),
    };
    let token = match (
        &args.token,
        args.token_file.as_ref().or(file.token_file.as_ref()),
    ) {
        (Some(token), _) => Some(token.clone()),
        (None, Some(file)) => Some(isostream_service::read_token_file(file)?),
        (None, None) => None,
    };
    // systemd's StateDirectory= exports the folder it made for us.
    let state_dir = args
        .state
        .or(file.state)
        .or_else(|| std::env::var_os("STATE_DIRECTORY").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("isostream-state"));
    // Absolute from here on, for the job log files too: the service stores paths under it
    // (`Store::open` makes it canonical once it exists).
    let state_dir = std::path::absolute(&state_dir)
        .with_context(|| format!("--state {}", state_dir.display()))?;
    crate::logging::init(
        &LogConfig {
            format,
            ..LogConfig::default()
        },
        Some(isostream_service::JobLogLayer::new(&state_dir)),
    );
    let listen = args
        .listen
        .or(file.listen)
        .unwrap_or_else(|| DEFAULT_LISTEN.parse().expect("a valid address"));
    let mut allow_input = file.allow_input;
    allow_input.extend(args.allow_input);
    let config = isostream_service::ServeConfig {
        stop_on_hangup: !crate::hangup_ignored(),
        state_dir,
        listen,
        allow_input,
        token,
        max_parallel_jobs: args
            .max_parallel_jobs
            .or(file.max_parallel_jobs)
            .unwrap_or(1),
        max_queued_jobs: args
            .max_queued_jobs
            .or(file.max_queued_jobs)
            .unwrap_or(DEFAULT_MAX_QUEUED),
    };
    isostream_service::serve(config, |addr| {
        // One line on stdout that scripts (and the tests) wait for; logs go to stderr. A
        // stdout nobody reads (closed, full) must not stop the service: the line is a courtesy.
        let _ = crate::stdout::line(format_args!("isostream serve: listening on http://{addr}"));
    })?;
    Ok(())
}
