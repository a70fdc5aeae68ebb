//! The HTTP API (axum): routes, the bearer-token guard, the body limit, and the job handlers.
//!
//! Every refusal is a JSON object `{"error": "<one line>"}` with the status saying what kind it
//! is (400 bad job, 401 no or wrong token, 403 input outside the allowed folders, 404 unknown id,
//! 408 body not sent in time, 409 not possible in the job's state, 413 body too large, 429 the
//! queue is full).

use std::convert::Infallible;
use std::sync::Arc;

use axum::Json;
use axum::Router;
use axum::body::Body;
use axum::extract::rejection::StringRejection;
use axum::extract::{DefaultBodyLimit, FromRequest, FromRequestParts, Path, Request, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, Method, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use futures_util::{Stream, StreamExt};
use subtle::ConstantTimeEq;
use tokio_util::io::ReaderStream;
use tokio_util::sync::CancellationToken;

use crate::admission::{self, Roots};
use crate::error::{ApiError, request_error_kind};
use crate::metrics::Metrics;
use crate::queue::{DeleteOutcome, JobView, Queue, SubmitError};
use crate::store::JobState;

/// A job file is a few hundred bytes; anything near this is not one.
const MAX_BODY: usize = 1 << 20;

/// Largest body read (and dropped) to answer 413 (see `job_text`).
const DRAIN_MAX: u64 = 16 << 20;

/// Time a submission's body has once its head arrived (the head's own deadline is
/// `listen::HEAD_DEADLINE`): a megabyte in 10 s is 100 kB/s.
const BODY_DEADLINE: std::time::Duration = std::time::Duration::from_secs(10);

#[derive(Clone)]
pub(crate) struct AppState {
    pub queue: Arc<Queue>,
    pub roots: Arc<Roots>,
    pub token: Option<Arc<str>>,
    pub metrics: Arc<Metrics>,
    pub shutdown: CancellationToken,
}

pub(crate) fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics))
        .route("/jobs", get(list).post(submit))
        .route("/jobs/{id}", get(show).delete(delete))
        .route("/jobs/{id}/events", get(events))
        .route("/jobs/{id}/output", get(output))
        .route("/jobs/{id}/report", get(report))
        .route("/jobs/{id}/log", get(log))
        .fallback(no_route)
        .method_not_allowed_fallback(wrong_method)
        .layer(DefaultBodyLimit::max(MAX_BODY))
        // Outermost: the token is checked before a body is read.
        .layer(middleware::from_fn_with_state(state.clone(), guard))
        .with_state(state)
}

/// Checks the bearer token and counts refused requests by kind.
///
/// `GET /` is exempt: it is a static page with no data in it, and a browser cannot add a header
/// to a navigation; its script sends the token (taken from the URL fragment, which browsers do
/// not send) on every request it makes.
async fn guard(State(s): State<AppState>, req: Request, next: Next) -> Response {
    // With a token, a request carrying it cannot come from another site's page (a page cannot
    // send it), and one without it is refused below: a reverse proxy forwarding its public
    // name (`Host`, and the browser's `Origin`) must work then.
    if s.token.is_none()
        && let Err(refused) = same_site(req.headers())
    {
        s.metrics.error("foreign_site");
        return refused.into_response();
    }
    let static_page = req.method() == Method::GET && req.uri().path() == "/";
    if let Some(token) = &s.token
        && !static_page
        && !authorized(req.headers(), token)
    {
        s.metrics.error("unauthorized");
        let refused = ApiError::new(
            StatusCode::UNAUTHORIZED,
            "this service needs `Authorization: Bearer <token>` (the --token of `isostream serve`)",
        );
        return ([(header::WWW_AUTHENTICATE, "Bearer")], refused).into_response();
    }
    let response = next.run(req).await;
    if let Some(kind) = request_error_kind(response.status()) {
        s.metrics.error(kind);
    }
    response
}

/// For a service without a token: refuses what a web page on another site can make a browser
/// send, a request naming another origin (`Origin`, which browsers add to every cross-site
/// request that could change something: a form or `fetch` posting a job as `text/plain` needs
/// no preflight), and a `Host` that is not a loopback name (DNS rebinding: a hostile name
/// re-pointed at 127.0.0.1 makes the browser treat this service as that site's). Clients that
/// are not browsers send no `Origin`.
fn same_site(headers: &HeaderMap) -> Result<(), ApiError> {
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
    if let Some(origin) = headers.get(header::ORIGIN) {
        let authority = origin
            .to_str()
            .ok()
            .and_then(|o| o.split_once("://"))
            .map(|(_, a)| a);
        if authority.is_none()
            || !host
                .zip(authority)
                .is_some_and(|(h, a)| h.eq_ignore_ascii_case(a))
        {
            return Err(ApiError::new(
                StatusCode::FORBIDDEN,
                format!(
                    "a request from another site (Origin {}) is refused: submit from a program (curl, a script) or from this service's own page",
                    String::from_utf8_lossy(origin.as_bytes())
                ),
            ));
        }
    }
    match host {
        Some(h) if !is_loopback_host(h) => Err(ApiError::new(
            StatusCode::FORBIDDEN,
            format!(
                "Host {h} is not a loopback name, and this service has no --token: reach it as 127.0.0.1, [::1] or localhost, or start it with --token to serve other names (behind a reverse proxy too)"
            ),
        )),
        _ => Ok(()),
    }
}

/// `localhost`, a `127.x.y.z` address or `[::1]`, with or without a port.
fn is_loopback_host(host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(v6) => v6.split_once(']').map_or(v6, |(ip, _)| ip),
        None => host.rsplit_once(':').map_or(host, |(name, _)| name),
    };
    name.eq_ignore_ascii_case("localhost")
        || name
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// Constant-time comparison, so response timing does not reveal how much of a guess was right.
fn authorized(headers: &HeaderMap, token: &str) -> bool {
    headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        // The scheme's name is case-insensitive (RFC 9110, 11.1).
        .and_then(|v| {
            v.split_once(' ')
                .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
        })
        .map(|(_, given)| given)
        .is_some_and(|given| bool::from(given.trim().as_bytes().ct_eq(token.as_bytes())))
}

/// 128 random bits from the OS as hex: ids are capabilities of sorts (whoever knows one can
/// fetch the output), so they must not be guessable.
fn new_id() -> Result<String, ApiError> {
    let mut bytes = [0u8; 16];
    getrandom::fill(&mut bytes)
        .map_err(|e| ApiError::internal(format!("no randomness for a job id: {e}")))?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// The `{id}` of a job's route. axum's `Path` refused an id that is not UTF-8 once decoded
/// (`GET /jobs/%ff%fe`) with a plain-text 400; this answers in the API's JSON, as every other
/// refusal does.
struct JobId(String);

impl<S: Send + Sync> FromRequestParts<S> for JobId {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        match Path::<String>::from_request_parts(parts, state).await {
            Ok(Path(id)) => Ok(JobId(id)),
            Err(r) => Err(ApiError::new(
                r.status(),
                format!(
                    "{}: {}; a job id is the one POST /jobs answered (GET /jobs lists them)",
                    parts.uri.path(),
                    r.body_text()
                ),
            )),
        }
    }
}

/// Unknown paths answer in the API's JSON, as every other refusal does.
async fn no_route(method: Method, uri: axum::http::Uri) -> ApiError {
    ApiError::new(
        StatusCode::NOT_FOUND,
        format!(
            "no such route: {method} {}; the API is GET /, /healthz, /metrics, GET and POST /jobs, GET and DELETE /jobs/{{id}}, GET /jobs/{{id}}/events, /output, /report, /log (docs/service.md)",
            uri.path()
        ),
    )
}

async fn wrong_method(method: Method, uri: axum::http::Uri) -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        format!(
            "{method} is not allowed on {}: see docs/service.md for the methods of each route",
            uri.path()
        ),
    )
}

async fn page() -> Html<&'static str> {
    Html(include_str!("status.html"))
}

async fn healthz() -> Json<serde_json::Value> {
    Json(serde_json::json!({ "status": "ok" }))
}

async fn metrics(State(s): State<AppState>) -> impl IntoResponse {
    let text = s.metrics.render(&s.queue.snapshot());
    (
        [(
            header::CONTENT_TYPE,
            "application/openmetrics-text; version=1.0.0; charset=utf-8",
        )],
        text,
    )
}

async fn list(State(s): State<AppState>) -> Json<serde_json::Value> {
    Json(serde_json::json!({ "jobs": s.queue.list() }))
}

async fn show(State(s): State<AppState>, JobId(id): JobId) -> Result<Json<JobView>, ApiError> {
    s.queue
        .get(&id)
        .map(Json)
        .ok_or_else(|| ApiError::not_found(&id))
}

async fn submit(State(s): State<AppState>, req: Request) -> Result<Response, ApiError> {
    let text = job_text(req).await?;
    let id = new_id()?;
    let queue = Arc::clone(&s.queue);
    let roots = Arc::clone(&s.roots);
    // Admission opens the input (file headers) and storing fsyncs: both block.
    let view = tokio::task::spawn_blocking(move || {
        let admitted = admission::admit(&text, &queue.job_dir(&id), &roots)?;
        queue.submit(id, admitted).map_err(|e| match e {
            SubmitError::Full(waiting) => ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "{waiting} jobs are waiting already (--max-queued-jobs); submit again once \
                     some have started, or cancel some"
                ),
            ),
            SubmitError::Io(e) => ApiError::internal(format!("cannot store the job: {e}")),
        })
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))??;
    let body = Json(serde_json::json!({ "id": view.record.id, "url": view.url }));
    Ok((
        StatusCode::CREATED,
        [(header::LOCATION, view.url.clone())],
        body,
    )
        .into_response())
}

/// The job file a submission carries. A body that does not arrive within [`BODY_DEADLINE`]
/// is refused then: without a deadline, a client sending less than its `Content-Length` held
/// the request open forever. A body declared larger than [`MAX_BODY`] is read and dropped
/// before the 413, so that a client that writes its whole body before reading (most do) gets
/// the answer rather than a reset connection; one declared larger than [`DRAIN_MAX`] is
/// refused before any of it is read.
async fn job_text(req: Request) -> Result<String, ApiError> {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    let too_large = |n: u64| {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("a body of {n} bytes: a job file is at most {MAX_BODY} bytes"),
        )
    };
    if let Some(n) = declared.filter(|&n| n > DRAIN_MAX) {
        return Err(too_large(n));
    }
    let read = async {
        if let Some(n) = declared.filter(|&n| n > MAX_BODY as u64) {
            let mut body = req.into_body().into_data_stream();
            while let Some(Ok(_)) = body.next().await {}
            return Err(too_large(n));
        }
        String::from_request(req, &())
            .await
            .map_err(|r: StringRejection| match r {
                StringRejection::InvalidUtf8(_) => ApiError::bad_job(format!(
                    "{}: the job file is not UTF-8 text; send it as UTF-8 TOML",
                    admission::ORIGIN
                )),
                r if r.status() == StatusCode::PAYLOAD_TOO_LARGE => ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    format!("a body over {MAX_BODY} bytes: a job file is at most {MAX_BODY} bytes"),
                ),
                r => ApiError::new(r.status(), r.body_text()),
            })
    };
    tokio::time::timeout(BODY_DEADLINE, read)
        .await
        .map_err(|_| {
            ApiError::new(
                StatusCode::REQUEST_TIMEOUT,
                format!(
                    "the job did not arrive within {} s of its headers; send the whole job file",
                    BODY_DEADLINE.as_secs()
                ),
            )
        })?
}

/// Cancels a queued or running job; removes a finished one with its output (see
/// [`Queue::delete`]).
async fn delete(State(s): State<AppState>, JobId(id): JobId) -> Result<Response, ApiError> {
    let queue = Arc::clone(&s.queue);
    let job = id.clone();
    let outcome = tokio::task::spawn_blocking(move || queue.delete(&job))
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
        .map_err(|e| {
            ApiError::internal(format!(
                "job {id} is unchanged: cannot write to its folder ({e}); free space on the disk of the service's state folder, or make it writable"
            ))
        })?;
    match outcome {
        DeleteOutcome::Cancelled(view) => Ok((StatusCode::OK, Json(view)).into_response()),
        DeleteOutcome::Stopping(view) => Ok((StatusCode::ACCEPTED, Json(view)).into_response()),
        DeleteOutcome::Removed { leftover } => {
            let mut removed = serde_json::json!({ "id": id, "removed": true });
            if let Some(leftover) = leftover {
                removed["warning"] = format!("job {id} is removed, but {leftover}").into();
            }
            Ok((StatusCode::OK, Json(removed)).into_response())
        }
        DeleteOutcome::NotFound => Err(ApiError::not_found(&id)),
    }
}

/// Where an event stream is: what it sends next.
enum Follow {
    First,
    Change,
    End,
}

/// Server-Sent Events: the job's view now, then at every change, until a final state. A slow
/// reader skips intermediate values instead of slowing the run.
///
/// When the service stops, the stream ends with the job as it is saved for the next start,
/// marked `"shutdown": true`: a running job is interrupted and saved `queued` (`Queue::drain`,
/// within a slice), and the stream waits for that. It ended at once before, its last event
/// `running` while the job was saved `queued`. A run whose end cannot be written stays
/// `running`, as saved: the stream waits for the drain, not for the job to leave `running`.
async fn events(
    State(s): State<AppState>,
    JobId(id): JobId,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let rx = s.queue.watch(&id).ok_or_else(|| ApiError::not_found(&id))?;
    let stream = futures_util::stream::unfold(
        (rx, Follow::First, s.shutdown.clone(), Arc::clone(&s.queue)),
        |(mut rx, next, stop, queue)| async move {
            let stopping = match next {
                Follow::End => return None,
                Follow::First => false,
                Follow::Change => tokio::select! {
                    biased;
                    () = stop.cancelled() => true,
                    changed = rx.changed() => {
                        changed.ok()?;
                        false
                    }
                },
            };
            if stopping {
                queue.drained().await;
            }
            let view = rx.borrow_and_update().clone();
            let end = stopping || view.record.state.is_final();
            let event = serde_json::to_value(&view)
                .map_err(|e| e.to_string())
                .and_then(|mut json| {
                    if stopping {
                        json["shutdown"] = true.into();
                    }
                    Event::default().json_data(json).map_err(|e| e.to_string())
                })
                .unwrap_or_else(|e| Event::default().comment(e));
            let next = if end { Follow::End } else { Follow::Change };
            Some((Ok(event), (rx, next, stop, queue)))
        },
    );
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

/// The job, once it is done; else 404 or 409 saying what exists when.
fn done_job(s: &AppState, id: &str, what: &str) -> Result<JobView, ApiError> {
    let view = s.queue.get(id).ok_or_else(|| ApiError::not_found(id))?;
    let state = view.record.state;
    if state != JobState::Done {
        let when = if state.is_final() {
            // Failed or cancelled: it never will be done.
            "it has none (see its `error` and log; resubmit the job to make one)"
        } else {
            "it exists once the job is done"
        };
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!("job {id} is {}: {what}: {when}", state.name()),
        ));
    }
    Ok(view)
}

/// The run report (`isostream report`'s page) from the run summary in the job's folder.
async fn report(State(s): State<AppState>, JobId(id): JobId) -> Result<Response, ApiError> {
    let view = done_job(&s, &id, "report")?;
    let summary = isostream_pipeline::summary_path(&s.queue.job_dir(&id).join(&view.record.output));
    let page = tokio::task::spawn_blocking(move || {
        let run = isostream_report::Run::load(&summary)?;
        isostream_report::html(&run, None)
    })
    .await
    .map_err(|e| ApiError::internal(e.to_string()))?
    .map_err(|e| ApiError::internal(format!("cannot make the report: {e}")))?;
    Ok(Html(page).into_response())
}

/// The job's log lines (every attempt's), as plain text; empty until its first run.
async fn log(State(s): State<AppState>, JobId(id): JobId) -> Result<Response, ApiError> {
    s.queue.get(&id).ok_or_else(|| ApiError::not_found(&id))?;
    let text = match tokio::fs::read(s.queue.job_dir(&id).join(crate::joblog::LOG_FILE)).await {
        Ok(bytes) => bytes,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(ApiError::internal(format!("cannot read the log: {e}"))),
    };
    Ok(([(header::CONTENT_TYPE, "text/plain; charset=utf-8")], text).into_response())
}

/// The mesh, streamed from its file (it may be far larger than memory).
async fn output(State(s): State<AppState>, JobId(id): JobId) -> Result<Response, ApiError> {
    let view = done_job(&s, &id, "output")?;
    let path = s.queue.job_dir(&id).join(&view.record.output);
    let file = tokio::fs::File::open(&path)
        .await
        .map_err(|e| ApiError::internal(format!("cannot open the output: {e}")))?;
    let len = file
        .metadata()
        .await
        .map_err(|e| ApiError::internal(format!("cannot read the output: {e}")))?
        .len();
    let ext = view.record.output.rsplit('.').next().unwrap_or("bin");
    Ok((
        [
            (header::CONTENT_TYPE, "application/octet-stream".to_string()),
            (header::CONTENT_LENGTH, len.to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{id}.{ext}\""),
            ),
        ],
        Body::from_stream(ReaderStream::new(file)),
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bearer_must_match_exactly() {
        let mut h = HeaderMap::new();
        assert!(!authorized(&h, "secret"));
        h.insert(header::AUTHORIZATION, "Bearer secret".parse().unwrap());
        assert!(authorized(&h, "secret"));
        h.insert(header::AUTHORIZATION, "Bearer secre".parse().unwrap());
        assert!(!authorized(&h, "secret"));
        h.insert(header::AUTHORIZATION, "Basic secret".parse().unwrap());
        assert!(!authorized(&h, "secret"));
    }

    #[test]
    fn loopback_names_and_origins() {
        for host in [
            "localhost",
            "LOCALHOST:8440",
            "127.0.0.1",
            "127.3.2.1:80",
            "[::1]",
            "[::1]:8440",
        ] {
            assert!(is_loopback_host(host), "{host}");
        }
        for host in [
            "evil.example",
            "evil.example:8440",
            "10.0.0.1:80",
            "[::2]:1",
            "localhost.evil.example",
        ] {
            assert!(!is_loopback_host(host), "{host}");
        }
        let headers = |pairs: &[(header::HeaderName, &str)]| {
            let mut h = HeaderMap::new();
            for (k, v) in pairs {
                h.insert(k.clone(), v.parse().unwrap());
            }
            h
        };
        let own = headers(&[
            (header::HOST, "127.0.0.1:8440"),
            (header::ORIGIN, "http://127.0.0.1:8440"),
        ]);
        assert!(same_site(&own).is_ok());
        let foreign = headers(&[
            (header::HOST, "127.0.0.1:8440"),
            (header::ORIGIN, "http://evil.example"),
        ]);
        assert!(same_site(&foreign).is_err());
        let null = headers(&[(header::HOST, "127.0.0.1:8440"), (header::ORIGIN, "null")]);
        assert!(same_site(&null).is_err());
        let rebound = headers(&[(header::HOST, "evil.example:8440")]);
        assert!(same_site(&rebound).is_err());
        assert!(same_site(&HeaderMap::new()).is_ok(), "HTTP/1.0 has no Host");
    }

    #[test]
    fn ids_are_128_random_bits_in_hex() {
        let a = new_id().unwrap();
        let b = new_id().unwrap();
        assert!(
            crate::store::is_job_id(&a) && crate::store::is_job_id(&b),
            "{a} {b}"
        );
        assert_ne!(a, b);
    }
}
