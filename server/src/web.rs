//! The web page at `/` with its stylesheet and ES modules under `/page/`, and the
//! OpenAPI description: all embedded in the binary, so the page needs no build step
//! and no network beyond the daemon.

use axum::extract::Path;
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};

use super::answers::ApiError;

/// The operator page's markup (`server/assets/page/index.html`).
pub async fn index() -> Html<&'static str> {
    Html(include_str!("../assets/page/index.html"))
}

/// A file the page loads, by the name it is served under: its content type and text.
struct PageFile {
    name: &'static str,
    content_type: &'static str,
    text: &'static str,
}

const CSS: &str = "text/css; charset=utf-8";
const JAVASCRIPT: &str = "text/javascript; charset=utf-8";

/// Every file under `/page/` besides the markup: the stylesheet and the ES modules.
const PAGE_FILES: [PageFile; 6] = [
    PageFile {
        name: "page.css",
        content_type: CSS,
        text: include_str!("../assets/page/page.css"),
    },
    PageFile {
        name: "main.js",
        content_type: JAVASCRIPT,
        text: include_str!("../assets/page/main.js"),
    },
    PageFile {
        name: "state.js",
        content_type: JAVASCRIPT,
        text: include_str!("../assets/page/state.js"),
    },
    PageFile {
        name: "render.js",
        content_type: JAVASCRIPT,
        text: include_str!("../assets/page/render.js"),
    },
    PageFile {
        name: "plot.js",
        content_type: JAVASCRIPT,
        text: include_str!("../assets/page/plot.js"),
    },
    PageFile {
        name: "text.js",
        content_type: JAVASCRIPT,
        text: include_str!("../assets/page/text.js"),
    },
];

/// `GET /page/{file}`: the page's stylesheet or one of its modules; 404 for any
/// other name.
pub async fn page_file(Path(file): Path<String>) -> Response {
    match PAGE_FILES.iter().find(|f| f.name == file) {
        Some(f) => ([(header::CONTENT_TYPE, f.content_type)], f.text).into_response(),
        None => ApiError::not_found(format!("page file {file:?}")).into_response(),
    }
}

/// `GET /api/openapi.json`.
pub async fn openapi() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "application/json")],
        include_str!("../assets/openapi.json"),
    )
}
