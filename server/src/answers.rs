//! What every HTTP handler shares: the error answer (`{"error": "...", "field": ...}`
//! with its status), the database off the async workers, and loading a scan.

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::State;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use serde_json::Value;
use utoipa::ToSchema;

pub use super::files::without_server_paths;
use super::shared::Shared;
use super::store::{ScanRecord, Store, StoreError};
use super::sync::lock;
use super::validate::FieldError;

/// The body of every error answer.
#[derive(Serialize, ToSchema)]
#[schema(as = Error)]
pub struct ErrorBody {
    /// What is wrong, one line.
    pub error: String,
    /// The invalid field, e.g. `theta_l[2]` or `bracket.shutter_s`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
}

/// An error answer: status and `{"error": "...", "field": ...}`.
pub struct ApiError {
    pub status: StatusCode,
    pub message: String,
    pub field: Option<String>,
}

impl ApiError {
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
            field: None,
        }
    }

    pub fn not_found(what: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::NOT_FOUND, format!("{what} not found"))
    }

    /// 503 with `Retry-After: retry_after_s`: the daemon is at a cap a client may wait
    /// out.
    pub fn busy(message: impl Into<String>, retry_after_s: u64) -> Response {
        let mut answer = Self::new(StatusCode::SERVICE_UNAVAILABLE, message).into_response();
        answer
            .headers_mut()
            .insert(header::RETRY_AFTER, HeaderValue::from(retry_after_s));
        answer
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        // One line, whatever a cause's message holds.
        let body = ErrorBody {
            error: gonio_processing::guard::one_line(&self.message),
            field: self.field,
        };
        (self.status, Json(body)).into_response()
    }
}

impl From<StoreError> for ApiError {
    /// A journal that finds the disk full is a state, not a fault: 503 saying so (the
    /// lanes log it, once).
    fn from(err: StoreError) -> Self {
        if err.is_disk_full() {
            return Self::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "the disk is full: the journal cannot be written; \
                 try again once space is freed on the data directory's disk",
            );
        }
        tracing::error!("store: {err}");
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, err.to_string())
    }
}

impl From<FieldError> for ApiError {
    fn from(err: FieldError) -> Self {
        Self {
            status: StatusCode::UNPROCESSABLE_ENTITY,
            message: err.to_string(),
            field: Some(err.field),
        }
    }
}

/// `message` with every absolute path in it (a word starting with `/`, up to a space,
/// a quote, a colon or a comma) cut to its file name: `scene red.toml`, not `scene
/// /etc/gonio/red.toml`.
pub fn without_absolute_paths(message: &str) -> String {
    let ends = |c: char| c.is_whitespace() || matches!(c, '"' | '\'' | ':' | ',' | ')');
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find('/') {
        let starts_word = rest[..at]
            .chars()
            .next_back()
            .is_none_or(|c| ends(c) || matches!(c, '(' | '='));
        if !starts_word {
            out.push_str(&rest[..=at]);
            rest = &rest[at + 1..];
            continue;
        }
        out.push_str(&rest[..at]);
        let path = &rest[at..];
        let end = path.find(ends).unwrap_or(path.len());
        let name = path[..end].rsplit('/').find(|part| !part.is_empty());
        out.push_str(name.unwrap_or("/"));
        rest = &path[end..];
    }
    out.push_str(rest);
    out
}

pub fn internal(err: impl std::fmt::Display) -> ApiError {
    ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, err.to_string())
}

pub type ApiResult<T> = Result<T, ApiError>;
pub type AppState = State<Arc<Shared>>;

/// Runs `f` with the handlers' database connection off the async workers.
pub async fn db<T: Send + 'static>(
    shared: &Arc<Shared>,
    f: impl FnOnce(&Shared, &mut Store) -> Result<T, StoreError> + Send + 'static,
) -> ApiResult<T> {
    let shared = shared.clone();
    tokio::task::spawn_blocking(move || {
        let mut store = lock(&shared.store);
        f(&shared, &mut store)
    })
    .await
    .map_err(internal)?
    .map_err(ApiError::from)
}

pub async fn load_scan(shared: &Arc<Shared>, id: i64) -> ApiResult<ScanRecord> {
    db(shared, move |_, store| store.scan(id))
        .await?
        .ok_or_else(|| ApiError::not_found(format!("scan {id}")))
}

/// A request body parsed as JSON; 400 naming what is wrong otherwise.
pub fn parse_json(body: &Bytes) -> ApiResult<Value> {
    serde_json::from_slice(body).map_err(|e| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            format!("body is not valid JSON: {e}"),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absolute_paths_are_cut_to_their_file_names() {
        assert_eq!(
            without_absolute_paths(
                "cannot mount sample red: scene of sample red: /tmp/x/red.toml: \
                 No such file or directory (os error 2); 'a/b' kept, (/etc/passwd)"
            ),
            "cannot mount sample red: scene of sample red: red.toml: \
             No such file or directory (os error 2); 'a/b' kept, (passwd)"
        );
        assert_eq!(without_absolute_paths("/ and x/y"), "/ and x/y");
    }
}
