//! `serve`: turns the flags into an `isostream_service::ServeConfig` and runs the service.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use isostream_pipeline::LogConfig;

#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Folder holding the jobs (default: $STATE_DIRECTORY under systemd, else ./isostream-state).
    #[arg(long)]
    pub state: Option<PathBuf>,
    /// Address to listen on; a non-loopback address needs a token.
    #[arg(long, default_value = "127.0.0.1:8440")]
    pub listen: SocketAddr,
    /// A folder job inputs may be read from (repeatable); without any, only procedural shapes.
    #[arg(long = "allow-input", value_name = "DIR")]
    pub allow_input: Vec<PathBuf>,
    /// Require `Authorization: Bearer T` on every request (visible in `ps`: prefer --token-file).
    #[arg(long, conflicts_with = "token_file")]
    pub token: Option<String>,
    /// Read the token from a file (surrounding whitespace ignored).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// Jobs running at once (each already keeps its stage threads and extraction pool busy).
    #[arg(long, default_value_t = 1)]
    pub max_parallel_jobs: usize,
}

pub fn serve(args: ServeArgs) -> anyhow::Result<()> {
    crate::logging::init(&LogConfig::default());
    let token = match (&args.token, &args.token_file) {
        (_, Some(file)) => Some(
            std::fs::read_to_string(file)
                .with_context(|| format!("--token-file {}", file.display()))?
                .trim()
                .to_string(),
        ),
        (token, None) => token.clone(),
    };
    // systemd's StateDirectory= exports the folder it made for us.
    let state_dir = args
        .state
        .or_else(|| std::env::var_os("STATE_DIRECTORY").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("isostream-state"));
    let config = isostream_service::ServeConfig {
        state_dir,
        listen: args.listen,
        allow_input: args.allow_input,
        token,
        max_parallel_jobs: args.max_parallel_jobs,
    };
    isostream_service::serve(config, |addr| {
        // One line on stdout that scripts (and the tests) wait for; logs go to stderr.
        println!("isostream serve: listening on http://{addr}");
        let _ = std::io::stdout().flush();
    })?;
    Ok(())
}
