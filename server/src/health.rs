//! `GET /api/health`: liveness, and what keeps the instrument from measuring
//! (docs/ARCHITECTURE.md, "HTTP API").

use axum::extract::State;
use axum::Json;
use gonio_drivers::ArmState;
use serde::Serialize;
use utoipa::ToSchema;

use super::answers::AppState;
use super::shared::Shared;
use super::sync::lock;

/// What keeps the instrument from measuring now, most serious first: `disk_full` (the
/// data directory's free space is below `storage.reserve_bytes`), `arm_alarm`,
/// `arm_disconnected`, `arm_refused`, `camera_disconnected`, `camera_error`.
fn problems(shared: &Shared) -> Vec<&'static str> {
    let mut problems = Vec::new();
    if shared.storage.check(0).is_err() {
        problems.push("disk_full");
    }
    let (arm, camera) = {
        let status = lock(&shared.hardware);
        (status.arm.state, status.camera.state)
    };
    problems.extend(match arm {
        ArmState::Alarm => Some("arm_alarm"),
        ArmState::Disconnected => Some("arm_disconnected"),
        ArmState::Refused => Some("arm_refused"),
        _ => None,
    });
    problems.extend(match camera {
        "disconnected" => Some("camera_disconnected"),
        "error" => Some("camera_error"),
        _ => None,
    });
    problems
}

/// `status` of the health answer: `disk_full` when the disk is full, else `degraded`
/// with any other problem, else `ok`.
fn status(problems: &[&str]) -> &'static str {
    match problems.first() {
        None => "ok",
        Some(&"disk_full") => "disk_full",
        Some(_) => "degraded",
    }
}

/// The health answer.
#[derive(Serialize, ToSchema)]
pub struct Health {
    /// `disk_full` while the data directory's free space is below
    /// `storage.reserve_bytes`; else `degraded` while `problems` names any; else `ok`.
    #[schema(value_type = String, pattern = "^(ok|disk_full|degraded)$")]
    status: &'static str,
    /// What keeps the instrument from measuring now, most serious first (`disk_full`,
    /// `arm_alarm`, `arm_disconnected`, `arm_refused`, `camera_disconnected`,
    /// `camera_error`); empty when `status` is `ok`.
    #[schema(value_type = Vec<String>)]
    problems: Vec<&'static str>,
    /// Bytes free for the daemon on the data directory's filesystem; null when it
    /// cannot be measured.
    disk_free_bytes: Option<u64>,
}

/// Liveness (always 200), the state of the instrument and the data directory's free
/// space (`null` when it cannot be measured).
#[utoipa::path(get, path = "/api/health",
    summary = "Liveness (always 200), what keeps the instrument from measuring, and the data directory's free space",
    responses((status = 200, description = "ok", body = Health)))]
pub async fn health(State(shared): AppState) -> Json<Health> {
    let free = shared.storage.free_bytes().ok();
    let problems = problems(&shared);
    Json(Health {
        status: status(&problems),
        problems,
        disk_free_bytes: free,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_comes_first_and_any_other_problem_degrades() {
        assert_eq!(status(&[]), "ok");
        assert_eq!(status(&["disk_full", "arm_alarm"]), "disk_full");
        assert_eq!(status(&["arm_alarm"]), "degraded");
        assert_eq!(status(&["camera_disconnected"]), "degraded");
    }
}
