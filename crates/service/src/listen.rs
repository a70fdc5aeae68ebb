//! The accept loop: the router served over hyper's HTTP/1 with a deadline on request heads.
//!
//! `axum::serve` gives hyper no timer, and without one hyper has no deadline at all: a client
//! that opened a connection and sent half a request head held it, and a task, for as long as it
//! liked (measured: still open after 90 s), so a few thousand such connections would exhaust
//! the service's file descriptors. Here every connection gets hyper's own header deadline
//! ([`HEAD_DEADLINE`]); the body's deadline is the handler's (`http::job_text`), since only it
//! knows a request has one. A response being streamed (an event stream, an output file) has
//! no deadline: it ends with its job, or with the service after its shutdown grace
//! ([`SHUTDOWN_GRACE`]; before, a client stalled mid-request held a stopping service for as
//! long as it kept its connection).

use std::io;
use std::time::Duration;

use axum::Router;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tracing::{debug, warn};

/// Time a client has to send a whole request head (the line and the headers) once its
/// connection is open or its previous response is sent. A head is a few hundred bytes.
pub(crate) const HEAD_DEADLINE: Duration = Duration::from_secs(10);

/// Time the requests in flight get to finish once the service stops (a download of a large
/// output, a head still arriving): the jobs are on disk whatever happens to them, and a client
/// can ask again once the service is back.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(10);

/// Serves `app` on `listener` until `shutdown`, then lets the requests in flight finish for
/// at most [`SHUTDOWN_GRACE`].
pub(crate) async fn serve(
    listener: TcpListener,
    app: Router,
    shutdown: CancellationToken,
) -> io::Result<()> {
    let graceful = GracefulShutdown::new();
    let mut http = http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(HEAD_DEADLINE);
    loop {
        let stream = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => stream,
                Err(e) => {
                    pause_after(&e).await;
                    continue;
                }
            },
            () = shutdown.cancelled() => break,
        };
        let service = TowerToHyperService::new(app.clone());
        let connection = graceful.watch(http.serve_connection(TokioIo::new(stream), service));
        tokio::spawn(async move {
            if let Err(e) = connection.await {
                // A client that went away or missed the head's deadline: its business.
                debug!(error = %e, "connection closed");
            }
        });
    }
    if tokio::time::timeout(SHUTDOWN_GRACE, graceful.shutdown())
        .await
        .is_err()
    {
        warn!("requests still in flight after {SHUTDOWN_GRACE:?} of shutdown: closed");
    }
    Ok(())
}

/// An accept error ends one connection, not the service. Running out of file descriptors (or
/// memory) would fail again at once, so the loop waits a moment before the next accept, as
/// `axum::serve` does.
async fn pause_after(e: &io::Error) {
    let per_connection = matches!(
        e.kind(),
        io::ErrorKind::ConnectionRefused
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::ConnectionReset
    );
    if !per_connection {
        warn!(error = %e, "cannot accept a connection; retrying in 1 s");
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
}
