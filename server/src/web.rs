//! The web page at `/`, embedded in the binary.

use axum::response::Html;

/// The single-page operator interface (plain HTML and JavaScript).
#[utoipa::path(get, path = "/",
    summary = "The operator's page: one HTML file with its script, needing no network",
    responses((status = 200, description = "The page", content_type = "text/html", body = String)))]
pub async fn index() -> Html<&'static str> {
    Html(include_str!("../assets/index.html"))
}
