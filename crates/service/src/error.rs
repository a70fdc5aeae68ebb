//! Errors: why the service cannot start (`ServiceError`, one line each, naming the flag or path to
//! fix) and why a request is refused (`ApiError`, an HTTP status with a one-line JSON reason).

use std::net::SocketAddr;
use std::path::PathBuf;

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};

/// Why `isostream serve` could not start or stopped.
///
/// [`ServiceError::is_bad_config`] separates a configuration to fix (the binary exits with 2, and
/// the systemd unit does not restart it) from a failure of the environment (exit 1).
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(
        "refusing to listen on {addr} without a token: anyone who can reach it could run jobs; pass --token-file FILE (or --token), or listen on 127.0.0.1"
    )]
    ExposedWithoutToken { addr: SocketAddr },
    #[error("the token is empty: put a long random string in --token-file")]
    EmptyToken,
    #[error(
        "--token-file {}: {reason}; give a readable file holding the token (a long random string)",
        path.display()
    )]
    TokenFile { path: PathBuf, reason: String },
    #[error("--max-parallel-jobs must be at least 1")]
    NoParallelism,
    #[error("--max-queued-jobs must be at least 1")]
    NoQueue,
    #[error("--allow-input {}: {reason}", path.display())]
    AllowInput { path: PathBuf, reason: String },
    #[error("state folder {}: {reason}; choose a writable --state folder", path.display())]
    State { path: PathBuf, reason: String },
    #[error(
        "state folder {}: another isostream serve is using it; stop that service or choose another --state folder",
        path.display()
    )]
    StateInUse { path: PathBuf },
    #[error("{}: {reason} (the keys are those of docs/service.md's flags)", path.display())]
    Config { path: PathBuf, reason: String },
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("cannot start the async runtime: {0}")]
    Runtime(std::io::Error),
    #[error("the HTTP server stopped: {0}")]
    Serve(std::io::Error),
}

impl ServiceError {
    /// The flags or the config file must change before a start can succeed.
    pub fn is_bad_config(&self) -> bool {
        matches!(
            self,
            ServiceError::ExposedWithoutToken { .. }
                | ServiceError::EmptyToken
                | ServiceError::TokenFile { .. }
                | ServiceError::NoParallelism
                | ServiceError::NoQueue
                | ServiceError::AllowInput { .. }
                | ServiceError::Config { .. }
        )
    }
}

/// A refused request: the status and a one-line reason, sent as `{"error": reason}`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ApiError {
    pub status: StatusCode,
    pub reason: String,
}

impl ApiError {
    pub fn new(status: StatusCode, reason: impl Into<String>) -> Self {
        Self {
            status,
            reason: reason.into(),
        }
    }

    pub fn bad_job(reason: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, reason)
    }

    pub fn not_found(id: &str) -> Self {
        Self::new(StatusCode::NOT_FOUND, format!("no job {id}"))
    }

    pub fn internal(reason: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, reason)
    }
}

/// The label counted in `isostream_errors_total{kind}` for a refused request, by its status.
pub(crate) fn request_error_kind(status: StatusCode) -> Option<&'static str> {
    Some(match status {
        StatusCode::BAD_REQUEST => "bad_job",
        StatusCode::UNAUTHORIZED => "unauthorized",
        StatusCode::FORBIDDEN => "forbidden_input",
        StatusCode::NOT_FOUND => "not_found",
        StatusCode::CONFLICT => "conflict",
        StatusCode::PAYLOAD_TOO_LARGE => "too_large",
        StatusCode::TOO_MANY_REQUESTS => "queue_full",
        s if s.is_client_error() => "bad_request",
        s if s.is_server_error() => "internal",
        _ => return None,
    })
}

/// Seconds a client refused for a full queue is told to wait (`Retry-After`): about what a
/// small job takes to start, and a hint only (the queue has no schedule to promise one).
const RETRY_AFTER_SECONDS: &str = "10";

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = Json(serde_json::json!({ "error": self.reason.replace('\n', " ") }));
        if self.status == StatusCode::TOO_MANY_REQUESTS {
            return (
                self.status,
                [(axum::http::header::RETRY_AFTER, RETRY_AFTER_SECONDS)],
                body,
            )
                .into_response();
        }
        (self.status, body).into_response()
    }
}
