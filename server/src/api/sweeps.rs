//! The sweeps' routes (docs/ARCHITECTURE.md, "HTTP API"): batches of scans for
//! unattended runs, queued together and shown with their summed progress.

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::IntoResponse;
use axum::Json;
use serde::Serialize;
use serde_json::{json, Value};
use utoipa::ToSchema;

use super::bounds::bounds;
use crate::answers::{db, parse_json, ApiError, ApiResult, AppState, ErrorBody};
use crate::schemas::{SweepRequest, SweepView};
use crate::shared::Shared;
use crate::store::{ScanState, Store, StoreError};
use crate::validate;
use crate::view::{rfc3339, scan_view};

/// The answer to a queued sweep.
#[derive(Serialize, ToSchema)]
pub(super) struct SweepQueued {
    id: i64,
    /// The ids of its scans, in the order they run.
    scans: Vec<i64>,
    /// The sweep's URL.
    url: String,
}

#[utoipa::path(post, path = "/api/sweeps",
    summary = "Queue samples × θL sets × repeats scans, optionally not before start_at",
    request_body = SweepRequest,
    responses(
        (status = 201, description = "Queued", body = SweepQueued),
        (status = 400, description = "The body is not valid JSON; nothing changed", body = ErrorBody),
        (status = 422, description = "An invalid field, named in `field`; nothing queued", body = ErrorBody),
        (status = 503, description = "The disk is full and the journal cannot be written; nothing changed. Try again once space is freed", body = ErrorBody),
    ))]
pub(super) async fn create_sweep(
    State(shared): AppState,
    body: Bytes,
) -> ApiResult<impl IntoResponse> {
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
        Json(SweepQueued {
            id,
            scans,
            url: format!("/api/sweeps/{id}"),
        }),
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

#[utoipa::path(get, path = "/api/sweeps/{id}",
    summary = "A sweep: summed progress and its scans",
    params(("id" = i64, Path, description = "The sweep's id")),
    responses(
        (status = 200, description = "Sweep", body = SweepView),
        (status = 404, description = "No such sweep", body = ErrorBody),
    ))]
pub(super) async fn get_sweep(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Json<Value>> {
    db(&shared, move |shared, store| sweep_view(shared, store, id))
        .await?
        .map(Json)
        .ok_or_else(|| ApiError::not_found(format!("sweep {id}")))
}

#[utoipa::path(get, path = "/api/sweeps",
    summary = "All sweeps",
    responses((status = 200, description = "Sweeps", body = Vec<SweepView>)))]
pub(super) async fn list_sweeps(State(shared): AppState) -> ApiResult<Json<Value>> {
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
