//! The web page at `/` and the OpenAPI description, both embedded in the binary.

use axum::http::header;
use axum::response::{Html, IntoResponse};

/// The single-page operator interface (plain HTML and JavaScript).
pub async fn index() -> Html<&'static str> {
    Html(include_str!("../assets/index.html"))
}

/// `GET /api/openapi.json`.
pub async fn openapi() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "application/json")],
        include_str!("../assets/openapi.json"),
    )
}
