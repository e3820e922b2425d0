//! The sweeps' routes (docs/ARCHITECTURE.md, "HTTP API"): batches of scans for
//! unattended runs, queued together, shown with their summed progress and the sample
//! changes they will wait for, paused, resumed or cancelled as a whole, and given
//! another start time while scheduled.

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
use crate::sample_waits::{planned_waits, PlannedWait};
use crate::schemas::{PlannedWaitView, SweepRequest, SweepSchedule, SweepView};
use crate::shared::Shared;
use crate::store::{now_unix, Rescheduled, ScanRecord, ScanState, Store, StoreError};
use crate::sweep_state::sweep_state;
use crate::validate;
use crate::view::{applies_to, rfc3339, scan_view};

/// The answer to a queued sweep.
#[derive(Serialize, ToSchema)]
pub(super) struct SweepQueued {
    id: i64,
    /// The ids of its scans, in the order they run.
    scans: Vec<i64>,
    /// The sweep's URL.
    url: String,
    /// The sample changes its scans will wait for, with when each wait is expected to
    /// begin (empty: the sweep runs through without a person).
    waits: Vec<PlannedWaitView>,
}

/// The planned waits of sweep `id` among `waits`, as the API shows them.
fn waits_of(waits: &[PlannedWait], id: i64) -> Vec<PlannedWaitView> {
    waits
        .iter()
        .filter(|w| w.sweep_id == Some(id))
        .map(|w| PlannedWaitView {
            scan_id: w.scan_id,
            sample: w.sample.clone(),
            at: rfc3339(w.at).unwrap_or_default(),
            waiting: w.waiting,
        })
        .collect()
}

/// The waits the queue will make, planned from now.
fn waits_now(shared: &Shared, store: &Store) -> Result<Vec<PlannedWait>, StoreError> {
    planned_waits(shared, store, time::OffsetDateTime::now_utc())
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
    let (id, scans, waits) = db(&shared, move |shared, store| {
        let (id, scans) = store.insert_sweep(&value, sweep.start_at, sweep.scans)?;
        Ok((id, scans, waits_of(&waits_now(shared, store)?, id)))
    })
    .await?;
    shared.wake();
    tracing::info!(
        "sweep {id} queued: {} scans, {} sample change(s) to wait for",
        scans.len(),
        waits.len()
    );
    Ok((
        StatusCode::CREATED,
        Json(SweepQueued {
            id,
            scans,
            url: format!("/api/sweeps/{id}"),
            waits,
        }),
    ))
}

/// The states of a sweep's scans a control `verb` moves: those it applies to for a
/// scan, the ended ones left out.
fn verb_states(verb: &str) -> Vec<ScanState> {
    applies_to(verb)
        .iter()
        .copied()
        .filter(|s| !s.is_final())
        .collect()
}

/// The control verbs a sweep whose scans are `scans` allows: those that move one of
/// them (a scan waiting for its sample is only cancelled), and `reschedule` while it
/// is scheduled.
fn sweep_actions(scans: &[ScanRecord], state: &str) -> Vec<&'static str> {
    let mut verbs: Vec<&str> = SWEEP_VERBS
        .iter()
        .filter(|(verb, _)| {
            let states = verb_states(verb);
            scans
                .iter()
                .any(|s| states.contains(&s.state) && (*verb == "cancel" || !s.waits_for_sample()))
        })
        .map(|(verb, _)| *verb)
        .collect();
    if state == "scheduled" {
        verbs.push("reschedule");
    }
    verbs
}

/// A sweep's control verbs and the state each moves its scans to.
const SWEEP_VERBS: [(&str, ScanState); 3] = [
    ("pause", ScanState::Paused),
    ("resume", ScanState::Queued),
    ("cancel", ScanState::Cancelled),
];

/// One view of a sweep: its scans, their summed progress, what the operator can do
/// with it and the sample changes it will wait for (among `waits`).
fn sweep_view(
    shared: &Shared,
    store: &Store,
    id: i64,
    waits: &[PlannedWait],
) -> Result<Option<Value>, StoreError> {
    let Some(sweep) = store.sweep(id)? else {
        return Ok(None);
    };
    let scans = store.scans_of_sweep(id)?;
    let done: u32 = scans.iter().map(|s| s.done).sum();
    let total: u32 = scans.iter().map(|s| s.total).sum();
    let count = |state: ScanState| scans.iter().filter(|s| s.state == state).count();
    let state = sweep_state(&scans, sweep.start_at, now_unix());
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
        "actions": sweep_actions(&scans, state),
        "waits": waits_of(waits, id),
        "scans": scans
            .iter()
            .map(|s| scan_view(shared, store, s, false))
            .collect::<Result<Vec<_>, _>>()?,
    })))
}

/// The view of sweep `id` now; 404 if there is none.
async fn load_sweep(shared: &std::sync::Arc<Shared>, id: i64) -> ApiResult<Json<Value>> {
    db(shared, move |shared, store| {
        sweep_view(shared, store, id, &waits_now(shared, store)?)
    })
    .await?
    .map(Json)
    .ok_or_else(|| ApiError::not_found(format!("sweep {id}")))
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
    load_sweep(&shared, id).await
}

#[utoipa::path(get, path = "/api/sweeps",
    summary = "All sweeps",
    responses((status = 200, description = "Sweeps", body = Vec<SweepView>)))]
pub(super) async fn list_sweeps(State(shared): AppState) -> ApiResult<Json<Value>> {
    let sweeps = db(&shared, |shared, store| {
        let waits = waits_now(shared, store)?;
        store
            .sweep_ids()?
            .into_iter()
            .filter_map(|id| sweep_view(shared, store, id, &waits).transpose())
            .collect::<Result<Vec<_>, _>>()
    })
    .await?;
    Ok(Json(Value::Array(sweeps)))
}

/// Applies control `verb` to every scan of sweep `id` not ended that it applies to, in
/// one transaction: 409 if none.
async fn control_sweep(
    shared: std::sync::Arc<Shared>,
    id: i64,
    (verb, to): (&'static str, ScanState),
) -> ApiResult<Json<Value>> {
    let outcome = db(&shared, move |shared, store| {
        if store.sweep(id)?.is_none() {
            return Ok(None);
        }
        let moved = store.transition_sweep(id, &verb_states(verb), to, verb == "cancel")?;
        for scan in &moved {
            shared.changed(*scan);
        }
        let waiting = store
            .scans_of_sweep(id)?
            .into_iter()
            .find(ScanRecord::waits_for_sample);
        Ok(Some((moved, waiting)))
    })
    .await?;
    let Some((moved, waiting)) = outcome else {
        return Err(ApiError::not_found(format!("sweep {id}")));
    };
    if moved.is_empty() {
        let why = match waiting {
            Some(scan) => format!(
                "its scan {} waits for sample {} to be mounted (confirm or cancel it)",
                scan.id, scan.plan.sample
            ),
            None => "it has no scan that can be".to_owned(),
        };
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!("cannot {verb} sweep {id}: {why}"),
        ));
    }
    shared.wake();
    tracing::info!("sweep {id}: {verb} scans {moved:?}");
    load_sweep(&shared, id).await
}

#[utoipa::path(post, path = "/api/sweeps/{id}/pause",
    summary = "Pause every scan of the sweep not ended (at the next step boundary); a scan waiting for its sample is left waiting",
    params(("id" = i64, Path, description = "The sweep's id")),
    responses(crate::schemas::SweepControlAnswers))]
pub(super) async fn pause_sweep(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Json<Value>> {
    control_sweep(shared, id, SWEEP_VERBS[0]).await
}

#[utoipa::path(post, path = "/api/sweeps/{id}/resume",
    summary = "Queue again every paused scan of the sweep (and those waiting for a device); failed scans are resumed one by one",
    params(("id" = i64, Path, description = "The sweep's id")),
    responses(crate::schemas::SweepControlAnswers))]
pub(super) async fn resume_sweep(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Json<Value>> {
    control_sweep(shared, id, SWEEP_VERBS[1]).await
}

#[utoipa::path(post, path = "/api/sweeps/{id}/cancel",
    summary = "Cancel every scan of the sweep not ended (a running one at the next step boundary)",
    params(("id" = i64, Path, description = "The sweep's id")),
    responses(crate::schemas::SweepControlAnswers))]
pub(super) async fn cancel_sweep(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Json<Value>> {
    control_sweep(shared, id, SWEEP_VERBS[2]).await
}

#[utoipa::path(patch, path = "/api/sweeps/{id}",
    summary = "Change the start time of a scheduled sweep (its start time ahead, none of its scans started)",
    params(("id" = i64, Path, description = "The sweep's id")),
    request_body = SweepSchedule,
    responses(
        (status = 200, description = "The sweep with its new start time", body = SweepView),
        (status = 400, description = "The body is not valid JSON; nothing changed", body = ErrorBody),
        (status = 404, description = "No such sweep", body = ErrorBody),
        (status = 409, description = "The sweep is not scheduled (its start time has come, or a scan of it has started, or none is queued)", body = ErrorBody),
        (status = 422, description = "`start_at` is not an RFC 3339 time or null (`field`: `start_at`)", body = ErrorBody),
        (status = 503, description = "The disk is full and the journal cannot be written; nothing changed. Try again once space is freed", body = ErrorBody),
    ))]
pub(super) async fn reschedule_sweep(
    State(shared): AppState,
    Path(id): Path<i64>,
    body: Bytes,
) -> ApiResult<Json<Value>> {
    let start_at = validate::sweep_schedule(&parse_json(&body)?)?;
    let outcome = db(&shared, move |shared, store| {
        let outcome = store.reschedule_sweep(id, start_at, now_unix())?;
        if outcome == Rescheduled::Done {
            for scan in store.scans_of_sweep(id)? {
                shared.changed(scan.id);
            }
        }
        Ok(outcome)
    })
    .await?;
    match outcome {
        Rescheduled::Done => {}
        Rescheduled::NoSuchSweep => return Err(ApiError::not_found(format!("sweep {id}"))),
        Rescheduled::NotScheduled => {
            return Err(ApiError::new(
                StatusCode::CONFLICT,
                format!(
                    "sweep {id} is not scheduled (its start time has come, a scan of it has \
                     started, or none of its scans is queued: a paused sweep is resumed \
                     first): its start time cannot change now"
                ),
            ))
        }
    }
    shared.wake();
    tracing::info!(
        "sweep {id}: start time now {}",
        start_at.and_then(rfc3339).as_deref().unwrap_or("now")
    );
    load_sweep(&shared, id).await
}
