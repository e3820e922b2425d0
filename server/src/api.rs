//! The HTTP API (docs/ARCHITECTURE.md, "HTTP API"): JSON under `/api`, the web page at `/`.
//! Mutating routes need the bearer token; reads are open.

use std::convert::Infallible;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, post};
use axum::{Json, Router};
use futures_util::{Stream, StreamExt};
use serde_json::{json, Value};
use tokio_stream::wrappers::BroadcastStream;

use super::answers::{
    db, internal, load_scan, without_absolute_paths, without_server_paths, ApiError, ApiResult,
    AppState,
};
use super::calibration;
use super::config::Config;
use super::devices::InjectedFault;
use super::preview;
use super::scan_files;
use super::scan_report;
use super::shared::Shared;
use super::store::{NewScan, ScanState, Store, StoreError};
use super::sync::{lock, Slots};
use super::thumbnails;
use super::validate::{self, Bounds};
use super::view::{applies_to, rfc3339, scan_view};

mod arm;

use arm::{declare_arm_position, hardware, hardware_log, home_arm, reconnect_arm, stop_arm};

/// The routes of the daemon. Every request first passes the Host check; mutating
/// routes need the token (reads too when bound beyond loopback without
/// `public_read`); JSON bodies need `Content-Type: application/json`; every error
/// answer is JSON.
pub fn router(shared: Arc<Shared>) -> Router {
    let token = || middleware::from_fn_with_state(shared.clone(), require_token);
    let json_bodies = Router::new()
        .route("/api/scans", post(create_scan))
        .route("/api/sweeps", post(create_sweep))
        .route("/api/arm/position", post(declare_arm_position))
        .route("/api/emulator/fault", post(inject_fault))
        .route_layer(middleware::from_fn(require_json));
    let mutating = Router::new()
        .route("/api/scans/{id}/pause", post(pause_scan))
        .route("/api/scans/{id}/resume", post(resume_scan))
        .route("/api/scans/{id}/cancel", post(cancel_scan))
        .route("/api/scans/{id}/confirm", post(confirm_scan))
        .route("/api/scans/{id}/calibrate", post(calibrate_scan))
        .route("/api/setup", delete(forget_calibration))
        .route("/api/arm/stop", post(stop_arm))
        .route("/api/arm/home", post(home_arm))
        .route("/api/arm/reconnect", post(reconnect_arm))
        .merge(json_bodies)
        .route_layer(token());
    let reads = Router::new()
        .route("/api/hardware", get(hardware))
        .route("/api/hardware/log", get(hardware_log))
        .route("/api/scans", get(list_scans))
        .route("/api/scans/{id}", get(get_scan))
        .route("/api/scans/{id}/steps", get(scan_steps))
        .route("/api/scans/{id}/events", get(scan_events))
        .route("/api/scans/{id}/thumbnail.png", get(thumbnails::thumbnail))
        .route("/api/scans/{id}/plot", get(plot))
        .route("/api/scans/{id}/report", get(scan_report::report))
        .route("/api/scans/{id}/files", get(scan_files::list_files))
        .route("/api/scans/{id}/files/{*path}", get(scan_files::get_file))
        .route("/api/scans/{id}/archive", get(scan_files::scan_archive))
        .route("/api/sweeps", get(list_sweeps))
        .route("/api/sweeps/{id}", get(get_sweep));
    let reads = if reads_need_token(&shared.config) {
        reads.route_layer(token())
    } else {
        reads
    };
    Router::new()
        .route("/", get(super::web::index))
        .route("/page/{file}", get(super::web::page_file))
        .route("/api/openapi.json", get(super::web::openapi))
        .route("/api/health", get(super::health::health))
        .merge(reads)
        .merge(mutating)
        .fallback(|| async { ApiError::not_found("no such route:") })
        .layer(DefaultBodyLimit::max(shared.config.max_body_bytes))
        .layer(middleware::from_fn_with_state(
            shared.clone(),
            refuse_oversized,
        ))
        .layer(middleware::from_fn(json_errors))
        .layer(middleware::from_fn_with_state(shared.clone(), check_host))
        .with_state(shared)
}

/// Most bytes of an oversized body read and discarded before its 413: a client still
/// sending it then reads the answer instead of a reset connection. Larger bodies are
/// answered at once.
const DRAIN_CAP: u64 = 1 << 20;

/// 413 for a body whose declared length is over `max_body_bytes`, after draining it
/// (up to [`DRAIN_CAP`]); the connection closes after the answer.
async fn refuse_oversized(State(shared): AppState, request: Request, next: Next) -> Response {
    let limit = shared.config.max_body_bytes as u64;
    let declared = request
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let Some(length) = declared.filter(|&n| n > limit) else {
        return next.run(request).await;
    };
    if length <= DRAIN_CAP {
        let _ = axum::body::to_bytes(request.into_body(), DRAIN_CAP as usize).await;
    }
    let mut answer = ApiError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!("request body of {length} bytes is over max_body_bytes ({limit})"),
    )
    .into_response();
    answer
        .headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    answer
}

/// Whether read routes need the token: bound beyond loopback without `public_read`.
fn reads_need_token(config: &Config) -> bool {
    !config.bind.ip().is_loopback() && !config.public_read
}

/// Whether the daemon answers to `Host` (port ignored): the bind address, `localhost`,
/// a loopback address, a name of `allowed_hosts`, or, when bound to every interface,
/// any IP address (a DNS-rebinding page always sends a name, never an address).
fn host_allowed(config: &Config, host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(rest) => rest.split_once(']').map_or("", |(name, _)| name),
        None => host.rsplit_once(':').map_or(host, |(name, _)| name),
    };
    if name.eq_ignore_ascii_case("localhost")
        || config
            .allowed_hosts
            .iter()
            .any(|h| h.eq_ignore_ascii_case(name))
    {
        return true;
    }
    let bind = config.bind.ip();
    name.parse::<std::net::IpAddr>()
        .is_ok_and(|ip| ip == bind || ip.is_loopback() || bind.is_unspecified())
}

/// 421 for a request whose Host the daemon does not answer to (DNS rebinding).
async fn check_host(State(shared): AppState, request: Request, next: Next) -> Response {
    let host = request
        .headers()
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .or_else(|| request.uri().authority().map(|a| a.as_str()))
        .unwrap_or("");
    if host_allowed(&shared.config, host) {
        return next.run(request).await;
    }
    ApiError::new(
        StatusCode::MISDIRECTED_REQUEST,
        format!(
            "Host {host:?} is not this daemon's: use its address, localhost, or a name of \
             allowed_hosts"
        ),
    )
    .into_response()
}

/// 415 unless the request says its body is JSON.
async fn require_json(request: Request, next: Next) -> Response {
    let content_type = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let essence = content_type.split(';').next().unwrap_or("").trim();
    if essence.eq_ignore_ascii_case("application/json") {
        return next.run(request).await;
    }
    ApiError::new(
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        format!("Content-Type must be application/json, got {content_type:?}"),
    )
    .into_response()
}

/// Gives every error answer the API's JSON shape: axum's rejections (a bad path
/// parameter, a body over the limit, an unknown method) come as plain text.
async fn json_errors(request: Request, next: Next) -> Response {
    let response = next.run(request).await;
    let status = response.status();
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.unwrap_or_default();
    let text = String::from_utf8_lossy(&text).trim().to_owned();
    let message = if text.is_empty() {
        status
            .canonical_reason()
            .unwrap_or("error")
            .to_ascii_lowercase()
    } else {
        text
    };
    let mut answer = ApiError::new(status, message).into_response();
    for (name, value) in &parts.headers {
        if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
            answer.headers_mut().insert(name.clone(), value.clone());
        }
    }
    answer
}

/// Rejects a request without the right `Authorization: Bearer` token before its body
/// is read, so nothing changes. The scheme is case-insensitive (RFC 9110).
async fn require_token(State(shared): AppState, request: Request, next: Next) -> Response {
    let given = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim_start().split_once(' '))
        .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
        .map(|(_, token)| token.trim());
    if given.is_some_and(|t| constant_time_eq(t.as_bytes(), shared.token.as_bytes())) {
        return next.run(request).await;
    }
    let mut response = ApiError::new(
        StatusCode::UNAUTHORIZED,
        "missing or wrong bearer token (Authorization: Bearer <token>)",
    )
    .into_response();
    response
        .headers_mut()
        .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    response
}

/// Compares two byte strings in time independent of where they differ.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn parse_json(body: &Bytes) -> ApiResult<Value> {
    serde_json::from_slice(body).map_err(|e| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            format!("body is not valid JSON: {e}"),
        )
    })
}

fn bounds(shared: &Shared) -> Bounds {
    let (camera, travel) = {
        let status = lock(&shared.hardware);
        (status.camera.clone(), status.arm.carousel_travel)
    };
    let carousel = shared.config.carousel.as_ref();
    let unreachable = carousel
        .zip(travel)
        .map(|(carousel, travel)| carousel.beyond_travel(travel))
        .unwrap_or_default();
    Bounds {
        limits: shared.config.limits,
        shutter_min_s: camera.shutter_min_s,
        shutter_max_s: camera.shutter_max_s,
        max_steps: shared.config.max_steps_per_request,
        samples: holdable(shared),
        unreachable,
    }
}

/// The samples the instrument can hold: the carousel's, of those the emulator has a
/// scene for; `None` where any name goes (real hardware without a carousel).
fn holdable(shared: &Shared) -> Option<Vec<String>> {
    let slots = shared
        .config
        .carousel
        .as_ref()
        .map(|c| c.slots.keys().cloned().collect::<Vec<_>>());
    match (slots, shared.mount.holdable()) {
        (Some(slots), Some(scenes)) => Some(
            slots
                .into_iter()
                .filter(|name| scenes.contains(name))
                .collect(),
        ),
        (slots, scenes) => slots.or(scenes),
    }
}

async fn create_scan(State(shared): AppState, body: Bytes) -> ApiResult<impl IntoResponse> {
    let value = parse_json(&body)?;
    let plan = validate::scan_request(&value, &bounds(&shared))?;
    let id = db(&shared, move |shared, store| {
        let id = store.insert_scans(&[NewScan {
            plan,
            sweep_id: None,
            not_before: None,
        }])?[0];
        shared.changed(id);
        Ok(id)
    })
    .await?;
    shared.wake();
    tracing::info!("scan {id} queued");
    Ok((
        StatusCode::CREATED,
        Json(json!({ "id": id, "url": format!("/api/scans/{id}") })),
    ))
}

async fn list_scans(State(shared): AppState) -> ApiResult<Json<Value>> {
    let views = db(&shared, |shared, store| {
        store
            .scans()?
            .iter()
            .map(|s| scan_view(shared, store, s, false))
            .collect()
    })
    .await?;
    Ok(Json(Value::Array(views)))
}

/// The detailed view of scan `id`.
async fn load_view(shared: &Arc<Shared>, id: i64) -> ApiResult<Value> {
    db(shared, move |shared, store| {
        store
            .scan(id)?
            .map(|scan| scan_view(shared, store, &scan, true))
            .transpose()
    })
    .await?
    .ok_or_else(|| ApiError::not_found(format!("scan {id}")))
}

async fn get_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    Ok(Json(load_view(&shared, id).await?))
}

async fn scan_steps(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    load_scan(&shared, id).await?;
    let steps = db(&shared, move |_, store| store.steps(id)).await?;
    Ok(Json(json!(steps)))
}

/// Applies an operator transition to a scan: 409 if its state does not allow it.
async fn control(
    shared: Arc<Shared>,
    id: i64,
    from: &'static [ScanState],
    to: ScanState,
    verb: &'static str,
) -> ApiResult<Json<Value>> {
    let scan = load_scan(&shared, id).await?;
    // The state that refused the control, read in the same call (another control may
    // have changed it since `scan` was loaded).
    let refused_in = db(&shared, move |shared, store| {
        if store.transition(id, from, to, None)? {
            shared.changed(id);
            Ok(None)
        } else {
            Ok(Some(store.scan(id)?.map_or(scan.state, |s| s.state)))
        }
    })
    .await?;
    if let Some(state) = refused_in {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!("scan {id} is {}: cannot {verb} it", state.as_str()),
        ));
    }
    shared.wake();
    tracing::info!("scan {id}: {verb}");
    Ok(Json(load_view(&shared, id).await?))
}

async fn pause_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    control(shared, id, applies_to("pause"), ScanState::Paused, "pause").await
}

async fn resume_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    control(
        shared,
        id,
        applies_to("resume"),
        ScanState::Queued,
        "resume",
    )
    .await
}

async fn cancel_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    control(
        shared,
        id,
        applies_to("cancel"),
        ScanState::Cancelled,
        "cancel",
    )
    .await
}

/// The operator confirms that the sample a waiting scan asks for is on the cylinder:
/// it is recorded as mounted (on the emulator, its scene is mounted) and the scan is
/// queued again. 409 unless the scan waits for its sample.
async fn confirm_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    let _one_at_a_time = shared.confirming.lock().await;
    let scan = load_scan(&shared, id).await?;
    let not_waiting = |state: ScanState| {
        ApiError::new(
            StatusCode::CONFLICT,
            format!(
                "scan {id} is {}: it does not wait for a sample to be mounted",
                state.as_str()
            ),
        )
    };
    if !scan.waits_for_sample() {
        return Err(not_waiting(scan.state));
    }
    let sample = scan.plan.sample.clone();
    let mounting = shared.clone();
    let mounted = sample.clone();
    // A sample the configuration cannot show (its scene file missing or bad) is the
    // operator's to fix: 409 naming the file, not where it is on the server.
    tokio::task::spawn_blocking(move || mounting.mount.mount(&mounted))
        .await
        .map_err(internal)?
        .map_err(|e| {
            ApiError::new(
                StatusCode::CONFLICT,
                without_absolute_paths(&format!("cannot mount sample {sample}: {e:#}")),
            )
        })?;
    let refused_in = db(&shared, move |shared, store| {
        let Some(scan) = store.scan(id)? else {
            return Ok(Some(ScanState::Cancelled));
        };
        store.log(
            shared.boot,
            Some(id),
            "mount",
            &format!(
                "sample {} confirmed mounted by the operator",
                scan.plan.sample
            ),
        )?;
        if scan.waits_for_sample()
            && store.transition(id, &[ScanState::Waiting], ScanState::Queued, None)?
        {
            shared.changed(id);
            Ok(None)
        } else {
            Ok(Some(scan.state))
        }
    })
    .await?;
    if let Some(state) = refused_in {
        return Err(not_waiting(state));
    }
    shared.wake();
    tracing::info!("scan {id}: sample {} mounted", scan.plan.sample);
    Ok(Json(load_view(&shared, id).await?))
}

/// Calibrates the setup from a scan that is no longer running and stores it as the
/// setup of later scans (see `calibration`).
async fn calibrate_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    let scan = load_scan(&shared, id).await?;
    if !matches!(
        scan.state,
        ScanState::Done | ScanState::Failed | ScanState::Cancelled
    ) {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!(
                "scan {id} is {}: calibrate from a scan that has ended",
                scan.state.as_str()
            ),
        ));
    }
    let (dir, data) = (shared.scan_dir(id), shared.config.data_dir.clone());
    let (scan_dir, data_dir) = (dir.clone(), data.clone());
    let stored =
        tokio::task::spawn_blocking(move || calibration::calibrate_and_store(&dir, &data, id))
            .await
            .map_err(internal)?
            .map_err(|e| {
                let message = format!("calibrating from scan {id}: {e:#}");
                ApiError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    without_server_paths(&message, &[&scan_dir, &data_dir]),
                )
            })?;
    Ok(Json(stored))
}

/// Forgets the calibrated setup: later scans use the configured (or scene) setup.
async fn forget_calibration(State(shared): AppState) -> ApiResult<Json<Value>> {
    let data = shared.config.data_dir.clone();
    let removed = tokio::task::spawn_blocking(move || calibration::forget(&data))
        .await
        .map_err(internal)?
        .map_err(internal)?;
    Ok(Json(json!({ "removed": removed })))
}

async fn create_sweep(State(shared): AppState, body: Bytes) -> ApiResult<impl IntoResponse> {
    let value = parse_json(&body)?;
    let sweep = validate::sweep_request(&value, &bounds(&shared))?;
    let (id, scans) = db(&shared, move |_, store| {
        store.insert_sweep(&value, sweep.start_at, sweep.scans)
    })
    .await?;
    shared.wake();
    tracing::info!("sweep {id} queued: {} scans", scans.len());
    Ok((
        StatusCode::CREATED,
        Json(json!({ "id": id, "scans": scans, "url": format!("/api/sweeps/{id}") })),
    ))
}

/// One view of a sweep: its scans and their summed progress.
fn sweep_view(shared: &Shared, store: &Store, id: i64) -> Result<Option<Value>, StoreError> {
    let Some(sweep) = store.sweep(id)? else {
        return Ok(None);
    };
    let scans = store.scans_of_sweep(id)?;
    let done: u32 = scans.iter().map(|s| s.done).sum();
    let total: u32 = scans.iter().map(|s| s.total).sum();
    let count = |state: ScanState| scans.iter().filter(|s| s.state == state).count();
    let state = if scans.iter().all(|s| s.state.is_final()) {
        if count(ScanState::Done) == scans.len() {
            "done"
        } else {
            "finished"
        }
    } else if scans.iter().any(|s| s.state == ScanState::Running) {
        "running"
    } else {
        "waiting"
    };
    let states: serde_json::Map<String, Value> = [
        ScanState::Queued,
        ScanState::Running,
        ScanState::Paused,
        ScanState::Done,
        ScanState::Failed,
        ScanState::Cancelled,
        ScanState::Interrupted,
        ScanState::Waiting,
    ]
    .into_iter()
    .map(|s| (s.as_str().to_owned(), json!(count(s))))
    .collect();
    Ok(Some(json!({
        "id": sweep.id,
        "created": sweep.created,
        "start_at": sweep.start_at.and_then(rfc3339),
        "request": sweep.request,
        "state": state,
        "progress": { "done": done, "total": total },
        "scans_by_state": states,
        "scans": scans
            .iter()
            .map(|s| scan_view(shared, store, s, false))
            .collect::<Result<Vec<_>, _>>()?,
    })))
}

async fn get_sweep(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    db(&shared, move |shared, store| sweep_view(shared, store, id))
        .await?
        .map(Json)
        .ok_or_else(|| ApiError::not_found(format!("sweep {id}")))
}

async fn list_sweeps(State(shared): AppState) -> ApiResult<Json<Value>> {
    let sweeps = db(&shared, |shared, store| {
        store
            .sweep_ids()?
            .into_iter()
            .filter_map(|id| sweep_view(shared, store, id).transpose())
            .collect::<Result<Vec<_>, _>>()
    })
    .await?;
    Ok(Json(Value::Array(sweeps)))
}

/// Server-sent events of one scan: its view now, then at every change; the stream
/// ends after a final state (done, failed, cancelled).
async fn scan_events(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Sse<impl Stream<Item = Result<Event, Infallible>>>> {
    load_scan(&shared, id).await?;
    let open = EVENT_STREAMS
        .take(shared.config.max_event_streams)
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "{} event streams are open, the most allowed (max_event_streams): close \
                 one or poll GET /api/scans/{id}",
                    shared.config.max_event_streams
                ),
            )
        })?;
    let updates = BroadcastStream::new(shared.events.subscribe());
    // The publisher sends the view now: every event of the stream comes from it, in
    // order.
    shared.changed(id);
    // The stream ends right after the view of a final state, as it is sent (the slot
    // is released with it).
    let stream = futures_util::stream::unfold(
        (updates, false, open, shared),
        move |(mut updates, ended, open, shared)| async move {
            if ended {
                return None;
            }
            loop {
                match updates.next().await? {
                    Ok(event) if event.id == id => {
                        let ended = event.state.is_final();
                        let view = Event::default().event("progress").data(&*event.view);
                        let item = Ok::<_, Infallible>(view);
                        return Some((item, (updates, ended, open, shared)));
                    }
                    Ok(_) => {}
                    // A lagging subscriber skipped views, maybe the final one: the
                    // publisher sends this scan's view again.
                    Err(_) => shared.changed(id),
                }
            }
        },
    );
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

/// Open server-sent event streams of this process.
static EVENT_STREAMS: Slots = Slots::new();

/// Measured samples and the fitted models' predictions, for the page's plots.
async fn plot(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    load_scan(&shared, id).await?;
    let dir = shared.scan_dir(id);
    let plot = tokio::task::spawn_blocking(move || preview::plot_data(&dir))
        .await
        .map_err(internal)?
        .map_err(|e| ApiError::not_found(format!("plot data: {e}")))?;
    Ok(Json(plot))
}

/// Test hook (only with `emulator.fault_injection = true`): injects a fault into the
/// emulated devices.
async fn inject_fault(State(shared): AppState, body: Bytes) -> ApiResult<Json<Value>> {
    let emulators = match (&shared.emulators, shared.config.emulator.fault_injection) {
        (Some(emulators), true) => emulators.clone(),
        _ => {
            return Err(ApiError::not_found(
                "fault injection (emulator.fault_injection is off)",
            ))
        }
    };
    let fault: InjectedFault = serde_json::from_slice(&body).map_err(|e| ApiError {
        status: StatusCode::UNPROCESSABLE_ENTITY,
        message: format!("fault: {e}"),
        field: Some("fault".into()),
    })?;
    tokio::task::spawn_blocking(move || emulators.inject(&fault))
        .await
        .map_err(internal)?
        .map_err(internal)?;
    Ok(Json(json!({ "injected": true })))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_check_answers_the_bind_address_localhost_and_allowed_names() {
        let mut config = Config {
            allowed_hosts: vec!["gonio.lab".into()],
            ..Config::default()
        };
        for host in [
            "127.0.0.1:8080",
            "localhost",
            "LOCALHOST:1",
            "[::1]:8080",
            "gonio.lab:80",
        ] {
            assert!(host_allowed(&config, host), "{host}");
        }
        for host in [
            "evil.example",
            "evil.example:8080",
            "192.168.1.9",
            "",
            "[::1",
        ] {
            assert!(!host_allowed(&config, host), "{host}");
        }
        config.bind = "0.0.0.0:8080".parse().unwrap();
        assert!(host_allowed(&config, "192.168.1.9:8080"));
        assert!(!host_allowed(&config, "rebind.evil.example"));
        assert!(reads_need_token(&config));
        config.public_read = true;
        assert!(!reads_need_token(&config));
    }
}
