//! `isostream serve`: a durable queue of isostream jobs, submitted and watched over HTTP.
//!
//! This crate owns the network and the async runtime (tokio + axum) so that no other crate has to:
//! each job runs through the same `isostream_pipeline::run` as `isostream run`, on a blocking
//! thread, cancelled through its `AtomicBool` and observed through its progress callback.
//!
//! Everything a job is lives in `STATE/jobs/{id}/` (the rewritten job file, `state.json`, the
//! output and its run summary), so a restarted service picks up where the last one stopped: queued
//! jobs stay queued and a job that was running starts again, from its last checkpoint when it
//! saved one, else from the beginning (the pipeline is deterministic, so the bytes are the same
//! as an uninterrupted run's), unless its run had completed and only its end was not written.
#![deny(unsafe_code)]

mod admission;
mod config;
mod error;
mod http;
mod joblog;
mod listen;
mod metrics;
mod queue;
mod store;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use tokio_util::sync::CancellationToken;
use tracing::info;

pub use config::{ServeFile, parse_listen, read_token_file};
pub use error::ServiceError;
pub use joblog::JobLogLayer;

/// How `isostream serve` was started (the command line, already parsed).
#[derive(Debug, Clone)]
pub struct ServeConfig {
    /// Folder holding `jobs/{id}/`; created when missing, and made canonical at start (a
    /// relative one is relative to the working directory the service starts in).
    pub state_dir: PathBuf,
    pub listen: SocketAddr,
    /// Folders job inputs may be read from; inputs elsewhere are refused. Empty: procedural
    /// volumes only.
    pub allow_input: Vec<PathBuf>,
    /// When set, every request needs `Authorization: Bearer <token>`.
    pub token: Option<String>,
    /// Jobs running at once; each one already keeps its stage threads and extraction pool busy.
    pub max_parallel_jobs: usize,
    /// Jobs waiting to run at once: a submission past it is refused (429) rather than stored.
    pub max_queued_jobs: usize,
    /// Whether SIGHUP stops the service: not when it was started ignoring it (`nohup`).
    pub stop_on_hangup: bool,
}

/// Runs the service until Ctrl-C, SIGTERM or SIGHUP. `ready` is called with the bound address (port 0
/// picks a free one) once requests can be accepted.
///
/// On shutdown, running jobs are interrupted and put back in the queue on disk, so the next
/// start runs them again, from their last checkpoint when they saved one.
pub fn serve(config: ServeConfig, ready: impl FnOnce(SocketAddr)) -> Result<(), ServiceError> {
    check_exposure(&config)?;
    if config.max_parallel_jobs == 0 {
        return Err(ServiceError::NoParallelism);
    }
    if config.max_queued_jobs == 0 {
        return Err(ServiceError::NoQueue);
    }
    let roots = Arc::new(admission::Roots::new(&config.allow_input)?);
    let store = store::Store::open(&config.state_dir)?;
    let state_dir = store.root().to_path_buf();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("isostream-serve")
        .build()
        .map_err(ServiceError::Runtime)?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .map_err(|source| ServiceError::Bind {
                addr: config.listen,
                source,
            })?;
        let addr = listener.local_addr().map_err(|source| ServiceError::Bind {
            addr: config.listen,
            source,
        })?;
        let shutdown = CancellationToken::new();
        let metrics = Arc::new(metrics::Metrics::new());
        let queue = queue::Queue::recover(
            store,
            Arc::clone(&roots),
            queue::Limits {
                running: config.max_parallel_jobs,
                queued: config.max_queued_jobs,
            },
            Arc::clone(&metrics),
            shutdown.clone(),
        );
        tokio::spawn(Arc::clone(&queue).schedule());
        tokio::spawn(stop_on_signal(shutdown.clone(), config.stop_on_hangup));
        let app = http::router(http::AppState {
            queue: Arc::clone(&queue),
            roots,
            token: config.token.map(Arc::from),
            metrics,
            shutdown: shutdown.clone(),
        });
        info!(%addr, state = %state_dir.display(), "listening");
        ready(addr);
        // Running jobs are interrupted as soon as the service stops, while the requests in
        // flight get their grace (`listen::serve`), not after it.
        let stopping = shutdown.clone();
        let (served, ()) = tokio::join!(listen::serve(listener, app, shutdown), async {
            stopping.cancelled().await;
            queue.drain().await;
        });
        served.map_err(ServiceError::Serve)
    })
}

/// A service reachable from other machines runs arbitrary jobs for whoever reaches it: refuse to
/// start without a token unless it listens on loopback only.
fn check_exposure(config: &ServeConfig) -> Result<(), ServiceError> {
    match &config.token {
        Some(t) if t.trim().is_empty() => Err(ServiceError::EmptyToken),
        Some(_) => Ok(()),
        None if config.listen.ip().is_loopback() => Ok(()),
        None => Err(ServiceError::ExposedWithoutToken {
            addr: config.listen,
        }),
    }
}

async fn stop_on_signal(shutdown: CancellationToken, hangup: bool) {
    let ctrl_c = tokio::signal::ctrl_c();
    // SIGTERM (systemd, `kill`) and SIGHUP (the terminal closed) stop it as Ctrl-C does, as
    // they stop `isostream run`: by default SIGHUP killed the process on the spot, leaving its
    // running jobs' temporary files behind. Not SIGHUP when it was ignored at start (`nohup`):
    // listening for it would install a handler over that.
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let hup = if hangup {
            signal(SignalKind::hangup()).ok()
        } else {
            None
        };
        let hung_up = async move {
            match hup {
                Some(mut hup) => {
                    hup.recv().await;
                }
                None => std::future::pending::<()>().await,
            }
        };
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = ctrl_c => {}
                    _ = term.recv() => {}
                    () = hung_up => {}
                }
            }
            Err(_) => {
                let _ = ctrl_c.await;
            }
        }
    }
    #[cfg(not(unix))]
    let _ = (ctrl_c.await, hangup);
    info!("shutting down: running jobs are interrupted and will restart on the next start");
    shutdown.cancel();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(listen: &str, token: Option<&str>) -> ServeConfig {
        ServeConfig {
            state_dir: PathBuf::from("unused"),
            listen: listen.parse().unwrap(),
            allow_input: Vec::new(),
            token: token.map(String::from),
            max_parallel_jobs: 1,
            max_queued_jobs: 1,
            stop_on_hangup: true,
        }
    }

    #[test]
    fn open_address_needs_a_token() {
        assert!(check_exposure(&config("127.0.0.1:0", None)).is_ok());
        assert!(check_exposure(&config("[::1]:0", None)).is_ok());
        let err = check_exposure(&config("0.0.0.0:8440", None)).unwrap_err();
        assert!(err.to_string().contains("--token"), "{err}");
        assert!(check_exposure(&config("0.0.0.0:8440", Some("s3cret"))).is_ok());
        assert!(check_exposure(&config("127.0.0.1:0", Some("  "))).is_err());
    }
}
