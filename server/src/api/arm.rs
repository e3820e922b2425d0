//! The arm's routes (docs/ARCHITECTURE.md, "HTTP API"): its state and log, the
//! emergency stop, homing, reconnecting and declaring its position.

use std::sync::atomic::Ordering;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::IntoResponse;
use axum::Json;
use gonio_drivers::ArmState;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use crate::answers::{db, internal, parse_json, ApiError, ApiResult, AppState, ErrorBody};
use crate::config::HomingMode;
use crate::schemas::ArmPosition;
use crate::shared::{ArmView, CameraView, PositionRequest, Shared, EMERGENCY_STOP};
use crate::store::{LogEntry, ScanState};
use crate::sync::lock;
use crate::validate;

/// The scan running now, if any (the hardware lane is busy with it).
async fn running_scan(shared: &Arc<Shared>) -> ApiResult<Option<i64>> {
    db(shared, |_, store| {
        Ok(store
            .scans()?
            .iter()
            .find(|s| s.state == ScanState::Running)
            .map(|s| s.id))
    })
    .await
}

/// The arm stopped.
#[derive(Serialize, ToSchema)]
pub(super) struct Stopped {
    stopped: bool,
    /// The scans it paused.
    paused: Vec<i64>,
}

/// Stops the arm at once (feed hold, then reset), pauses the running scan and holds the
/// instrument ([`Shared::halted`]).
#[utoipa::path(post, path = "/api/arm/stop",
    summary = "Stop the arm at once (feed hold, then reset) and pause the running scan; always allowed. The instrument then holds: no other scan starts and the arm does not move until the operator homes the arm (POST /api/arm/home), declares its position (POST /api/arm/position) or resumes a scan; /api/hardware shows `halted`",
    responses(
        (status = 200, description = "Stopped", body = Stopped),
        (status = 403, description = "Sent by a browser from a page of another site (its `Origin` is not a host the daemon answers to); nothing changed", body = ErrorBody),
        (status = 503, description = "Arm not connected (the running scan is paused all the same), or the disk is full", body = ErrorBody),
    ))]
pub(super) async fn stop_arm(
    State(shared): AppState,
    headers: axum::http::HeaderMap,
) -> ApiResult<Json<Stopped>> {
    if !super::guards::from_own_page(&shared.config, &headers) {
        return Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "a page of another site cannot stop the arm (its Origin is not this daemon's)",
        ));
    }
    shared.stops.fetch_add(1, Ordering::AcqRel);
    shared.halted.store(true, Ordering::Release);
    // A homing asked for and not begun is dropped; one under way is abandoned.
    shared.home_requested.store(false, Ordering::Release);
    let estop = lock(&shared.estop).clone();
    let stopped = match estop {
        Some(estop) => tokio::task::spawn_blocking(move || estop.stop())
            .await
            .map_err(internal)?
            .map_err(|e| ApiError::new(StatusCode::SERVICE_UNAVAILABLE, format!("arm stop: {e}"))),
        None => Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "arm stop: the arm is not connected",
        )),
    };
    let paused = db(&shared, |shared, store| {
        let ids =
            store.transition_all(ScanState::Running, ScanState::Paused, Some(EMERGENCY_STOP))?;
        store.log(shared.boot, None, "stop", "emergency stop")?;
        for id in &ids {
            shared.changed(*id);
        }
        Ok(ids)
    })
    .await?;
    // The stop resets the board: the carousel is turned to its slot again before the
    // next capture.
    shared.carousel_moved();
    stopped?;
    tracing::warn!("emergency stop; paused scans {paused:?}");
    Ok(Json(Stopped {
        stopped: true,
        paused,
    }))
}

/// Homes the arm (after a stop, a reset or a failed homing): 202 at once, the hardware
/// lane clears an alarm (soft reset) and homes the arm before it runs anything else;
/// 409 with the reason where it cannot (a scan runs, the board was refused, the
/// controller does not home), 503 without an arm.
#[utoipa::path(post, path = "/api/arm/home",
    summary = "Home the arm (after STOP ARM, a reset or a failed homing): answered at once, the arm homes before anything else runs, an alarm first cleared with a soft reset; /api/hardware shows `homing`, then `idle` at its angle; the hardware log says what was done (`home`: `asked by the operator: alarm cleared (soft reset), then $H`). An emergency stop's hold ends once the arm is homed; a STOP ARM before then drops the homing, or abandons it under way (`home abandoned`). With a carousel, the next capture turns it back to its slot first",
    responses(
        (status = 202, description = "Homing", body = Homing),
        (status = 409, description = "Home cannot run, with the reason: a scan is running (pause or cancel it first), the arm homes already, the board was refused (its settings differ: change them, then POST /api/arm/reconnect), or the controller does not home (homing = \"off\" or $22=0: declare its position, POST /api/arm/position)", body = ErrorBody),
        (status = 503, description = "Arm not connected", body = ErrorBody),
    ))]
pub(super) async fn home_arm(State(shared): AppState) -> ApiResult<impl IntoResponse> {
    if let Some(id) = running_scan(&shared).await? {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!("scan {id} is running: pause or cancel it before homing the arm"),
        ));
    }
    let arm = lock(&shared.hardware).arm.clone();
    let conflict = |message: &str| Err(ApiError::new(StatusCode::CONFLICT, message));
    match arm.state {
        ArmState::Disconnected => {
            return Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "arm not connected: nothing to home",
            ))
        }
        ArmState::Refused => {
            return conflict(
                "the arm's board was refused (its settings differ, see /api/hardware): \
                 change them on the board, then POST /api/arm/reconnect",
            )
        }
        ArmState::Homing => return conflict("the arm is homing already"),
        _ if shared.config.arm.homing == HomingMode::Off
            || !arm.homes
            || arm.state == ArmState::NeedsPosition =>
        {
            return conflict(
                "this controller does not home: declare the arm's position \
                 (POST /api/arm/position)",
            )
        }
        _ => {}
    }
    let clears_alarm = arm.state == ArmState::Alarm;
    shared.home_requested.store(true, Ordering::Release);
    // The hardware lane homes even in an emergency stop's hold, and ends the hold
    // once the arm is homed.
    shared.wake();
    tracing::info!("homing asked by the operator");
    Ok((
        StatusCode::ACCEPTED,
        Json(Homing {
            homing: true,
            clears_alarm,
        }),
    ))
}

/// Homing is asked for.
#[derive(Serialize, ToSchema)]
pub(super) struct Homing {
    homing: bool,
    /// The arm is in alarm: it is cleared with a soft reset before `$H`.
    clears_alarm: bool,
}

/// The arm is opened again at the hardware lane's next pass.
#[derive(Serialize, ToSchema)]
pub(super) struct Reconnecting {
    reconnecting: bool,
}

/// Opens the arm again now: one that is disconnected (instead of waiting for its next
/// try) or refused for its settings (after they were changed on the board). 409 while
/// the arm is connected: reopening would reset it.
#[utoipa::path(post, path = "/api/arm/reconnect",
    summary = "Open the arm again now: a disconnected one without waiting for its next try, or one refused for its settings (after they were changed on the board); the board resets as it opens. /api/hardware shows the outcome",
    responses(
        (status = 200, description = "The hardware lane opens the arm at its next pass", body = Reconnecting),
        (status = 409, description = "The arm is connected: nothing to reconnect", body = ErrorBody),
    ))]
pub(super) async fn reconnect_arm(State(shared): AppState) -> ApiResult<Json<Reconnecting>> {
    let state = lock(&shared.hardware).arm.state;
    if !matches!(state, ArmState::Disconnected | ArmState::Refused) {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            "the arm is connected: nothing to reconnect (opening it again would reset it)",
        ));
    }
    shared.arm_reconnect.store(true, Ordering::Release);
    shared.wake();
    tracing::info!("arm reconnect asked for");
    Ok(Json(Reconnecting { reconnecting: true }))
}

/// The position is declared.
#[derive(Serialize, ToSchema)]
pub(super) struct Declared {
    /// θL, degrees.
    angle: f64,
    declared: bool,
}

/// How long a declared position may wait for the hardware lane (busy with a step).
const DECLARE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(30);

/// Declares where the arm is, for controllers without homing (`{"angle": degrees}`);
/// the hardware lane applies it (`G92`), records it in the hardware log and queues the
/// waiting scans again.
#[utoipa::path(post, path = "/api/arm/position",
    summary = "Declare where the arm is, for controllers without homing ([arm] homing = \"off\" or \"optional\"): the hardware lane sets it with G92, records it in the hardware log, and queues the waiting scans again",
    request_body = ArmPosition,
    responses(
        (status = 200, description = "Declared", body = Declared),
        (status = 400, description = "The body is not valid JSON; nothing changed", body = ErrorBody),
        (status = 409, description = "Refused: homing is required, a scan is running, the arm is moving, homing or in hold (a position is declared only while the arm is at rest), or another declaration is under way", body = ErrorBody),
        (status = 422, description = "Invalid angle (the field is named)", body = ErrorBody),
        (status = 503, description = "Arm not connected, or the hardware is busy", body = ErrorBody),
    ))]
pub(super) async fn declare_arm_position(
    State(shared): AppState,
    body: Bytes,
) -> ApiResult<Json<Declared>> {
    let angle = validate::arm_position(&parse_json(&body)?, shared.config.arm.max_travel_deg)?;
    if let Some(id) = running_scan(&shared).await? {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!("scan {id} is running: declare the arm's position while it is at rest"),
        ));
    }
    let state = lock(&shared.hardware).arm.state;
    if matches!(state, ArmState::Moving | ArmState::Homing | ArmState::Hold) {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!(
                "the arm is {}: declare its position while it is at rest",
                format!("{state:?}").to_lowercase()
            ),
        ));
    }
    let (reply, answer) = std::sync::mpsc::sync_channel(1);
    {
        let mut pending = lock(&shared.arm_position);
        if pending.is_some() {
            return Err(ApiError::new(
                StatusCode::CONFLICT,
                "another arm position is being declared",
            ));
        }
        *pending = Some(PositionRequest {
            angle_deg: angle,
            reply,
        });
    }
    shared.wake();
    let answered = tokio::task::spawn_blocking(move || answer.recv_timeout(DECLARE_TIMEOUT))
        .await
        .map_err(internal)?;
    let refused = |status, err: gonio_drivers::DeviceError| {
        ApiError::new(status, format!("arm position not declared: {err}"))
    };
    match answered {
        Ok(Ok(())) => {
            tracing::info!("arm position declared: {angle}°");
            shared.end_hold();
            Ok(Json(Declared {
                angle,
                declared: true,
            }))
        }
        Ok(Err(err @ gonio_drivers::DeviceError::OutOfRange { .. })) => Err(ApiError {
            field: Some("angle".into()),
            ..refused(StatusCode::UNPROCESSABLE_ENTITY, err)
        }),
        Ok(Err(err))
            if err.is_transient() || matches!(err, gonio_drivers::DeviceError::NotFound(_)) =>
        {
            Err(refused(StatusCode::SERVICE_UNAVAILABLE, err))
        }
        Ok(Err(err)) => Err(refused(StatusCode::CONFLICT, err)),
        Err(_) => {
            // Still pending: withdraw it, so it is not applied behind the caller's back.
            lock(&shared.arm_position).take();
            Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "arm position not declared: the hardware is busy, try again",
            ))
        }
    }
}

/// The devices now.
#[derive(Serialize, ToSchema)]
#[schema(as = Hardware)]
pub(super) struct HardwareView {
    arm: ArmView,
    camera: CameraView,
    /// Whether the devices are the emulators.
    emulated: bool,
    /// The daemon's start counter.
    boot: i64,
    /// An emergency stop holds the instrument: no scan starts and the arm does not move
    /// until the operator homes the arm, declares its position or resumes a scan.
    halted: bool,
}

#[utoipa::path(get, path = "/api/hardware",
    summary = "Arm state and angle, camera model and state",
    responses((status = 200, description = "Hardware status", body = HardwareView)))]
pub(super) async fn hardware(State(shared): AppState) -> Json<HardwareView> {
    let mut status = lock(&shared.hardware).clone();
    let live = lock(&shared.arm_angle).as_ref().and_then(|a| a.get());
    // As the arm reported it, also while a move is under way.
    status.arm.angle_deg = status.arm.shown_angle(live.or(status.arm.angle_deg));
    Json(HardwareView {
        arm: status.arm,
        camera: status.camera,
        emulated: shared.emulators.is_some(),
        boot: shared.boot,
        halted: shared.halted.load(Ordering::Acquire),
    })
}

/// Which entries of the hardware log.
#[derive(Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub(super) struct LogQuery {
    /// Only entries with a larger id.
    #[serde(default)]
    #[param(default = 0)]
    after: i64,
}

#[utoipa::path(get, path = "/api/hardware/log",
    summary = "What the hardware lane did (connect, home, move, capture, stop), oldest first",
    params(LogQuery),
    responses((status = 200, description = "Log entries", body = Vec<LogEntry>)))]
pub(super) async fn hardware_log(
    State(shared): AppState,
    Query(query): Query<LogQuery>,
) -> ApiResult<Json<Vec<LogEntry>>> {
    let entries = db(&shared, move |_, store| store.hardware_log(query.after)).await?;
    Ok(Json(entries))
}
