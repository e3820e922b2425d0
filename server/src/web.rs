//! The web page at `/` with its stylesheet and ES modules under `/page/`, and the
//! OpenAPI description: all embedded in the binary, so the page needs no build step
//! and no network beyond the daemon.

use axum::extract::Path;
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};

use super::answers::ApiError;

/// The operator page's markup (`server/assets/page/index.html`).
#[utoipa::path(get, path = "/",
    summary = "The operator's page: its markup, loading its stylesheet and modules from /page/; no network beyond the daemon",
    responses((status = 200, description = "The page", content_type = "text/html", body = String)))]
pub async fn index() -> Html<&'static str> {
    Html(include_str!("../assets/page/index.html"))
}

/// Every file under `/page/` besides the markup, by the name it is served under: the
/// stylesheet and the ES modules.
const PAGE_FILES: [(&str, &str); 7] = [
    ("page.css", include_str!("../assets/page/page.css")),
    ("main.js", include_str!("../assets/page/main.js")),
    ("state.js", include_str!("../assets/page/state.js")),
    ("render.js", include_str!("../assets/page/render.js")),
    ("plot.js", include_str!("../assets/page/plot.js")),
    ("text.js", include_str!("../assets/page/text.js")),
    ("colour.js", include_str!("../assets/page/colour.js")),
];

/// `GET /page/{file}`: the page's stylesheet (`text/css`) or one of its modules
/// (`text/javascript`); 404 for any other name.
#[utoipa::path(get, path = "/page/{file}",
    summary = "A file of the operator's page: its stylesheet or one of its ES modules",
    params(("file" = String, Path, description = "page.css, main.js, state.js, render.js, plot.js or text.js")),
    responses(
        (status = 200, description = "The file", content_type = "text/javascript", body = String),
        (status = 404, description = "No page file of that name", body = crate::answers::ErrorBody)))]
pub async fn page_file(Path(file): Path<String>) -> Response {
    let Some((name, text)) = PAGE_FILES.iter().find(|(name, _)| *name == file) else {
        return ApiError::not_found(format!("page file {file:?}")).into_response();
    };
    let content_type = if name.ends_with(".css") {
        "text/css; charset=utf-8"
    } else {
        "text/javascript; charset=utf-8"
    };
    ([(header::CONTENT_TYPE, content_type)], *text).into_response()
}

#[cfg(test)]
mod tests {
    use super::PAGE_FILES;

    /// Every file in `assets/page/` is served: a new module added there without an
    /// entry in [`PAGE_FILES`] would fail to load in the browser.
    #[test]
    fn every_file_of_the_page_is_served() {
        let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/page");
        let mut on_disk: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|name| name != "index.html")
            .collect();
        on_disk.sort();
        let mut served: Vec<String> = PAGE_FILES.iter().map(|(n, _)| n.to_string()).collect();
        served.sort();
        assert_eq!(served, on_disk);
    }
}
