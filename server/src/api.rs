//! The HTTP API (docs/ARCHITECTURE.md, "HTTP API"): JSON under `/api`, the web page at `/`.
//! Mutating routes need the bearer token; reads are open.

use std::convert::Infallible;
use std::sync::{Arc, LazyLock};

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, State};
use axum::http::{header, StatusCode};
use axum::middleware;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::IntoResponse;
use axum::{Json, Router};
use futures_util::{Stream, StreamExt};
use serde::Serialize;
use serde_json::Value;
use tokio_stream::wrappers::BroadcastStream;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::answers::{
    db, internal, load_scan, parse_json, without_absolute_paths, without_server_paths, ApiError,
    ApiResult, AppState, ErrorBody,
};
use super::calibration;
use super::devices::InjectedFault;
use super::health;
use super::openapi::{self, Access};
use super::preview;
use super::scan_colour;
use super::scan_files;
use super::scan_report;
use super::schemas::{ScanRequest, ScanView};
use super::shared::Shared;
use super::store::{NewScan, ScanState, StepRecord};
use super::sync::Slots;
use super::thumbnails;
use super::validate;
use super::view::{applies_to, scan_view};
use super::web;

mod arm;
mod bounds;
mod guards;
mod sweeps;

/// Routes with their description, before the state is given.
type Routes = OpenApiRouter<Arc<Shared>>;

/// Every route of the daemon by group, each registered with its description
/// (`routes!` takes the route and its description from the handler's
/// `#[utoipa::path]`: no route goes undescribed); `guard` puts a group behind its
/// checks, whose answers `openapi::describe_access` adds to the group's description.
fn routes(guard: &dyn Fn(Access, Routes) -> Routes) -> Routes {
    let group = |access, mut routes: Routes| {
        openapi::describe_access(access, routes.get_openapi_mut());
        guard(access, routes)
    };
    let open = Routes::new()
        .routes(routes!(web::index))
        .routes(routes!(web::page_file))
        .routes(routes!(description))
        .routes(routes!(health::health))
        // Anyone at the instrument can stop it: no token (what it holds ends only by
        // a change that needs one).
        .routes(routes!(arm::stop_arm));
    let reads = Routes::new()
        .routes(routes!(arm::hardware))
        .routes(routes!(arm::hardware_log))
        .routes(routes!(list_scans))
        .routes(routes!(get_scan))
        .routes(routes!(scan_steps))
        .routes(routes!(scan_events))
        .routes(routes!(thumbnails::thumbnail))
        .routes(routes!(plot))
        .routes(routes!(scan_report::report))
        .routes(routes!(scan_colour::colour))
        .routes(routes!(scan_colour::compare))
        .routes(routes!(scan_files::list_files))
        .routes(routes!(scan_files::get_file))
        .routes(routes!(scan_files::scan_archive))
        .routes(routes!(sweeps::list_sweeps))
        .routes(routes!(sweeps::get_sweep));
    let mutating = Routes::new()
        .routes(routes!(pause_scan))
        .routes(routes!(resume_scan))
        .routes(routes!(cancel_scan))
        .routes(routes!(confirm_scan))
        .routes(routes!(calibrate_scan))
        .routes(routes!(forget_calibration))
        .routes(routes!(sweeps::pause_sweep))
        .routes(routes!(sweeps::resume_sweep))
        .routes(routes!(sweeps::cancel_sweep))
        .routes(routes!(arm::home_arm))
        .routes(routes!(arm::reconnect_arm));
    let json_bodies = Routes::new()
        .routes(routes!(create_scan))
        .routes(routes!(sweeps::create_sweep))
        .routes(routes!(sweeps::reschedule_sweep))
        .routes(routes!(arm::declare_arm_position))
        .routes(routes!(inject_fault));
    group(Access::Open, open)
        .merge(group(Access::Read, reads))
        .merge(group(Access::Token, mutating))
        .merge(group(Access::TokenJson, json_bodies))
}

/// The routes of the daemon. Every request first passes the Host check; mutating
/// routes need the token (reads too when bound beyond loopback without
/// `public_read`); JSON bodies need `Content-Type: application/json`; every error
/// answer is JSON.
pub fn router(shared: Arc<Shared>) -> Router {
    let token = || middleware::from_fn_with_state(shared.clone(), guards::require_token);
    let reads_need_token = guards::reads_need_token(&shared.config);
    let (routes, _) = routes(&|access, routes| match access {
        Access::Open => routes,
        Access::Read if !reads_need_token => routes,
        Access::Read | Access::Token => routes.route_layer(token()),
        Access::TokenJson => routes
            .route_layer(middleware::from_fn_with_state(
                shared.clone(),
                guards::require_json,
            ))
            .route_layer(token()),
    })
    .split_for_parts();
    routes
        .fallback(|| async { ApiError::not_found("no such route:") })
        .layer(DefaultBodyLimit::max(shared.config.max_body_bytes))
        .layer(middleware::from_fn_with_state(
            shared.clone(),
            guards::refuse_oversized,
        ))
        .layer(middleware::from_fn(guards::json_errors))
        .layer(middleware::from_fn_with_state(
            shared.clone(),
            guards::check_host,
        ))
        .with_state(shared)
}

/// The API's OpenAPI description, made from the routes once.
fn openapi_json() -> &'static str {
    static JSON: LazyLock<String> = LazyLock::new(|| {
        let api = openapi::finish(routes(&|_, routes| routes).into_openapi());
        serde_json::to_string(&api).expect("the OpenAPI description serializes")
    });
    &JSON
}

/// This description.
#[utoipa::path(get, path = "/api/openapi.json",
    summary = "This description of the API (OpenAPI 3.1), generated from the handlers",
    responses((status = 200, description = "The description", content_type = "application/json", body = Object)))]
async fn description() -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "application/json")], openapi_json())
}

/// The answer to a queued scan.
#[derive(Serialize, ToSchema)]
struct Queued {
    id: i64,
    /// The scan's URL.
    url: String,
}

#[utoipa::path(post, path = "/api/scans",
    summary = "Queue a scan (validated, planned and stored before anything moves)",
    request_body = ScanRequest,
    responses(
        (status = 201, description = "Queued", body = Queued),
        (status = 400, description = "The body is not valid JSON; nothing changed", body = ErrorBody),
        (status = 422, description = "An invalid field, named in `field`; nothing queued", body = ErrorBody),
        (status = 503, description = "The disk is full and the journal cannot be written; nothing changed. Try again once space is freed", body = ErrorBody),
    ))]
async fn create_scan(State(shared): AppState, body: Bytes) -> ApiResult<impl IntoResponse> {
    let value = parse_json(&body)?;
    let plan = validate::scan_request(&value, &bounds::bounds(&shared))?;
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
        Json(Queued {
            id,
            url: format!("/api/scans/{id}"),
        }),
    ))
}

#[utoipa::path(get, path = "/api/scans",
    summary = "All scans, oldest first",
    responses((status = 200, description = "Scans", body = Vec<ScanView>)))]
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

#[utoipa::path(get, path = "/api/scans/{id}",
    summary = "One scan",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Scan", body = ScanView),
        (status = 404, description = "No such scan", body = ErrorBody),
    ))]
async fn get_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    Ok(Json(load_view(&shared, id).await?))
}

#[utoipa::path(get, path = "/api/scans/{id}/steps",
    summary = "The scan's plan: every step with its state and result",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Steps", body = Vec<StepRecord>),
        (status = 404, description = "No such scan", body = ErrorBody),
    ))]
async fn scan_steps(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Json<Vec<StepRecord>>> {
    load_scan(&shared, id).await?;
    let steps = db(&shared, move |_, store| store.steps(id)).await?;
    Ok(Json(steps))
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
    // The scan as it refused the control, read in the same call (another control may
    // have changed it since `scan` was loaded). A scan waiting for its sample is only
    // confirmed or cancelled: resuming it would queue it only to wait again.
    let refused_by = db(&shared, move |shared, store| {
        if store.control(id, from, to, verb == "cancel")? {
            shared.changed(id);
            Ok(None)
        } else {
            Ok(Some(store.scan(id)?.unwrap_or(scan)))
        }
    })
    .await?;
    if let Some(scan) = refused_by {
        let message = if scan.waits_for_sample() {
            format!(
                "scan {id} waits for sample {} to be mounted: confirm it once the sample \
                 is on the cylinder, or cancel it; it is not {verb}d",
                scan.plan.sample
            )
        } else {
            format!("scan {id} is {}: cannot {verb} it", scan.state.as_str())
        };
        return Err(ApiError::new(StatusCode::CONFLICT, message));
    }
    shared.wake();
    tracing::info!("scan {id}: {verb}");
    Ok(Json(load_view(&shared, id).await?))
}

#[utoipa::path(post, path = "/api/scans/{id}/pause",
    summary = "Pause at the next step boundary (queued, running or interrupted scans)",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(super::schemas::ControlAnswers))]
async fn pause_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    control(shared, id, applies_to("pause"), ScanState::Paused, "pause").await
}

#[utoipa::path(post, path = "/api/scans/{id}/resume",
    summary = "Re-queue a paused scan, or retry a failed one from its first step not done",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(super::schemas::ControlAnswers))]
async fn resume_scan(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    let answer = control(
        Arc::clone(&shared),
        id,
        applies_to("resume"),
        ScanState::Queued,
        "resume",
    )
    .await?;
    shared.end_hold();
    Ok(answer)
}

#[utoipa::path(post, path = "/api/scans/{id}/cancel",
    summary = "Cancel at the next step boundary",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(super::schemas::ControlAnswers))]
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
#[utoipa::path(post, path = "/api/scans/{id}/confirm",
    summary = "Confirm that the sample a waiting scan asks for is mounted: it is recorded as mounted (on the emulator, its scene is mounted) and the scan is queued again",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Scan", body = ScanView),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 409, description = "The scan does not wait for its sample to be mounted, or the sample cannot be mounted (its scene file missing or invalid; the file is named, not its path on the server)", body = ErrorBody),
        (status = 503, description = "The disk is full and the journal cannot be written; nothing changed. Try again once space is freed", body = ErrorBody),
    ))]
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
#[utoipa::path(post, path = "/api/scans/{id}/calibrate",
    summary = "Calibrate the setup from this ended scan's captures (strip rows, camera offset, cylinder tilt, arm zero offset, camera yaw and roll, with standard uncertainties and residuals) and use it as the setup of later scans",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "The stored setup (setup.json fields) with its `calibration` and `provenance` (where each field came from: `calibrated from scan N`, or as the calibrated scan's setup.json said: `emulated scene`, `configuration [setup]`, an earlier calibration; for the `uncertainty` block an object naming each key's source); later scans' setup.json keep both", body = Object),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 409, description = "The scan has not ended", body = ErrorBody),
        (status = 422, description = "The captures do not allow a calibration (the reason is named)", body = ErrorBody),
    ))]
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

/// Whether a calibrated setup was removed.
#[derive(Serialize, ToSchema)]
struct Removed {
    removed: bool,
}

/// Forgets the calibrated setup: later scans use the configured (or scene) setup.
#[utoipa::path(delete, path = "/api/setup",
    summary = "Forget the calibrated setup: later scans use the configured (or emulated scene's) setup",
    responses((status = 200, description = "Whether a calibrated setup was removed", body = Removed)))]
async fn forget_calibration(State(shared): AppState) -> ApiResult<Json<Removed>> {
    let data = shared.config.data_dir.clone();
    let removed = tokio::task::spawn_blocking(move || calibration::forget(&data))
        .await
        .map_err(internal)?
        .map_err(internal)?;
    Ok(Json(Removed { removed }))
}

/// Server-sent events of one scan: its view now, then at every change; the stream
/// ends after a final state (done, failed, cancelled).
#[utoipa::path(get, path = "/api/scans/{id}/events",
    summary = "Server-sent events: `progress` events carrying the Scan JSON now and at every change; the stream ends right after the event of done, failed or cancelled",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Event stream: `event: progress`, `data:` the Scan JSON", content_type = "text/event-stream", body = String),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 503, description = "max_event_streams event streams are open: close one or poll the scan", body = ErrorBody),
    ))]
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
#[utoipa::path(get, path = "/api/scans/{id}/plot",
    summary = "Samples and each fitted model's predicted β at their angles",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Plot data", body = Object),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 409, description = "The scan has no samples yet", body = ErrorBody),
        (status = 500, description = "A file of the scan could not be read", body = ErrorBody),
    ))]
async fn plot(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    load_scan(&shared, id).await?;
    let dir = shared.scan_dir(id);
    if !dir.join("samples.csv").is_file() {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!("scan {id} has no samples to plot yet"),
        ));
    }
    let read = dir.clone();
    let plot = tokio::task::spawn_blocking(move || preview::plot_data(&read))
        .await
        .map_err(internal)?
        .map_err(|e| internal(without_server_paths(&format!("plot data: {e}"), &[&dir])))?;
    Ok(Json(plot))
}

/// The fault is injected.
#[derive(Serialize, ToSchema)]
struct Injected {
    injected: bool,
}

/// Test hook (only with `emulator.fault_injection = true`): injects a fault into the
/// emulated devices.
#[utoipa::path(post, path = "/api/emulator/fault",
    summary = "Test hook, only with `emulator.fault_injection = true`: inject a fault into the emulated devices",
    request_body = InjectedFault,
    responses(
        (status = 200, description = "Injected", body = Injected),
        (status = 404, description = "Fault injection off", body = ErrorBody),
        (status = 422, description = "Not a fault (`field`: `fault`)", body = ErrorBody),
    ))]
async fn inject_fault(State(shared): AppState, body: Bytes) -> ApiResult<Json<Injected>> {
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
    Ok(Json(Injected { injected: true }))
}

#[cfg(test)]
mod described;
