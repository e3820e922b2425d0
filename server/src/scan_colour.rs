//! `GET /api/scans/{id}/colour` and `GET /api/scans/{id}/compare/{batch}`: a scan's
//! multi-angle colour as its report states it (CIELAB at ASTM E2539's aspecular angles,
//! D65/10°, values ± U), and a batch judged against it as `gonio compare` judges it with
//! its default tolerances (docs/ARCHITECTURE.md, "Multi-angle colour").

use std::sync::Arc;

use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::Json;
use gonio_processing::color::observer::Observer;
use gonio_processing::color::srgb::swatch;
use gonio_processing::multi_angle::compare::{compare as judge, Mounting, Tolerances};
use gonio_processing::multi_angle::ColourReport;
use gonio_report::ReportError;
use serde_json::{json, Value};

use super::answers::{
    internal, load_scan, without_server_paths, ApiError, ApiResult, AppState, ErrorBody,
};
use super::shared::Shared;

/// The colour of scan `id`, or the answer why it has none.
async fn scan_colour(shared: &Arc<Shared>, id: i64) -> ApiResult<ColourReport> {
    load_scan(shared, id).await?;
    let dir = shared.scan_dir(id);
    let read = dir.clone();
    tokio::task::spawn_blocking(move || gonio_report::multi_angle_colour(&read))
        .await
        .map_err(internal)?
        .map_err(|e| match e {
            ReportError::Empty { .. } | ReportError::NoFit { .. } => ApiError::new(
                StatusCode::CONFLICT,
                format!("scan {id} has no fit yet: no colour to state"),
            ),
            _ => internal(without_server_paths(&e.to_string(), &[&dir])),
        })
}

/// The report as JSON (colour.json's layout), each angle with the sRGB display colour
/// of its L*a*b* (`swatch`: `hex`, `in_gamut`).
fn with_swatches(report: &ColourReport) -> ApiResult<Value> {
    let white = Observer::new(report.conditions).white();
    let mut value = serde_json::to_value(report).map_err(internal)?;
    if let Some(angles) = value["angles"].as_array_mut() {
        for (angle, measured) in angles.iter_mut().zip(&report.angles) {
            let shown = swatch(measured.lab(), white);
            angle["swatch"] = json!({ "hex": shown.hex(), "in_gamut": shown.in_gamut });
            // The lines of each value's budget stay in colour.json and the report.
            if let Some(angle) = angle.as_object_mut() {
                angle.remove("lines");
            }
        }
    }
    Ok(value)
}

/// The scan's multi-angle colour.
#[utoipa::path(get, path = "/api/scans/{id}/colour",
    summary = "The scan's multi-angle colour: CIELAB at ASTM E2539's aspecular angles, values ± U",
    description = "45° illumination, D65 and the 10° observer; per angle L*, a*, b*, C*, h with their expanded uncertainty (k = 2), whether the geometry lies inside the measured range (`origin`: data) or the model extrapolates (model), `beyond_data` when a model value is brighter than the measured columns support there (the model's guess, not a reading), and an sRGB swatch marked when out of gamut; the flop index. As `gonio colour SCAN_DIR` computes it, without each value's budget lines.",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "The colour", body = Object),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 409, description = "The scan has no fit yet", body = ErrorBody),
        (status = 500, description = "A file of the scan could not be read", body = ErrorBody),
    ))]
pub async fn colour(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Json<Value>> {
    let report = scan_colour(&shared, id).await?;
    Ok(Json(with_swatches(&report)?))
}

/// Scan `batch` judged against scan `id` as its standard.
#[utoipa::path(get, path = "/api/scans/{id}/compare/{batch}",
    summary = "A batch scan judged against this scan as its standard, per aspecular angle",
    description = "As `gonio compare` with its default tolerances, each scan of its own mounting: per angle ΔL*, ΔC*, ΔH* and ΔE00 with their expanded uncertainty (the white's and the colour transform's errors, which both scans share, cancel; the geometry's are each scan's own), the tolerance and the verdict (pass, fail, or undecided when the interval straddles the tolerance); the flop index's difference; the overall verdict.",
    params(
        ("id" = i64, Path, description = "The standard's scan id"),
        ("batch" = i64, Path, description = "The batch's scan id"),
    ),
    responses(
        (status = 200, description = "The comparison", body = Object),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 409, description = "A scan has no fit yet", body = ErrorBody),
        (status = 422, description = "The two scans cannot be compared", body = ErrorBody),
        (status = 500, description = "A file of a scan could not be read", body = ErrorBody),
    ))]
pub async fn compare(
    State(shared): AppState,
    Path((id, batch)): Path<(i64, i64)>,
) -> ApiResult<Json<Value>> {
    let standard = scan_colour(&shared, id).await?;
    let judged = scan_colour(&shared, batch).await?;
    let comparison = judge(
        &standard,
        &judged,
        &Tolerances::default(),
        Mounting::Separate,
    )
    .map_err(|e| ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, e.to_string()))?;
    let mut value = serde_json::to_value(&comparison).map_err(internal)?;
    value["standard"] = json!(id);
    value["batch"] = json!(batch);
    Ok(Json(value))
}
