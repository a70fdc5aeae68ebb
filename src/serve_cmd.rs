//! `serve`: turns the flags into an `isostream_service::ServeConfig` and runs the service.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use isostream_pipeline::LogConfig;

pub struct ServeArgs {
    pub state: Option<PathBuf>,
    pub listen: SocketAddr,
    pub allow_input: Vec<PathBuf>,
    pub token: Option<String>,
    pub token_file: Option<PathBuf>,
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
