//! `GET /api/scans/{id}/report`: the scan's report (docs/ARCHITECTURE.md, "Scan
//! report"), made by `gonio_report` from the scan directory and the daemon's record.

use axum::extract::{Path, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};

use super::answers::{
    internal, load_scan, without_server_paths, ApiError, ApiResult, AppState, ErrorBody,
};

/// The scan's report: one self-contained, printable HTML file (`gonio report`'s, with
/// what the daemon knows of the scan). 409 while the scan has no samples or fit yet.
#[utoipa::path(get, path = "/api/scans/{id}/report",
    summary = "The scan's report: one self-contained, printable HTML file",
    description = "Sample, dates, plan, setup with the source of each value, the chosen model with its parameters, uncertainty budget (GUM layout) and held-out errors, plots as inline SVG, the software version. Needs no network to open.",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "The report", content_type = "text/html", body = String),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 409, description = "The scan has no samples or fit to report yet", body = ErrorBody),
        (status = 500, description = "A file of the scan could not be read", body = ErrorBody),
    ))]
pub async fn report(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Response> {
    let scan = load_scan(&shared, id).await?;
    let dir = shared.scan_dir(id);
    let facts = gonio_report::ScanFacts {
        id: Some(id),
        sample: Some(scan.plan.sample.clone()),
        state: Some(scan.state.as_str().to_owned()),
        created: Some(scan.created.clone()),
        started: scan.started.clone(),
        finished: scan.finished.clone(),
        notes: None,
    };
    let render_dir = dir.clone();
    let html = tokio::task::spawn_blocking(move || {
        gonio_report::render(
            &render_dir,
            &facts,
            env!("CARGO_PKG_VERSION"),
            &crate::store::now_rfc3339(),
        )
    })
    .await
    .map_err(internal)?
    .map_err(|e| {
        let message = without_server_paths(&e.to_string(), &[&dir]);
        match e {
            gonio_report::ReportError::Empty { .. } => ApiError::new(
                StatusCode::CONFLICT,
                format!("scan {id} has no samples or fit to report yet"),
            ),
            _ => internal(message),
        }
    })?;
    Ok((
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8".to_owned()),
            (
                header::CONTENT_DISPOSITION,
                format!("inline; filename=\"gonio-scan-{id}-report.html\""),
            ),
        ],
        html,
    )
        .into_response())
}
