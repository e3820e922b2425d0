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
    let ends = |c: char| c.is_whitespace() || matches!(c, '"' | '\'' | '`' | ':' | ',' | ')');
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
/// A key given twice in one object is refused too (JSON leaves it open; serde_json
/// would keep the last, so `{"sample":"gold","sample":"red"}` would queue red).
pub fn parse_json(body: &Bytes) -> ApiResult<Value> {
    let invalid = |e: serde_json::Error| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            format!("body is not valid JSON: {e}"),
        )
    };
    serde_json::from_slice::<UniqueKeys>(body).map_err(invalid)?;
    serde_json::from_slice(body).map_err(invalid)
}

/// A JSON document read only to find a key given twice in one of its objects.
struct UniqueKeys;

impl<'de> serde::Deserialize<'de> for UniqueKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(UniqueKeys)
    }
}

impl<'de> serde::de::Visitor<'de> for UniqueKeys {
    type Value = UniqueKeys;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON value")
    }
    fn visit_bool<E>(self, _: bool) -> Result<Self, E> {
        Ok(self)
    }
    fn visit_i64<E>(self, _: i64) -> Result<Self, E> {
        Ok(self)
    }
    fn visit_u64<E>(self, _: u64) -> Result<Self, E> {
        Ok(self)
    }
    fn visit_f64<E>(self, _: f64) -> Result<Self, E> {
        Ok(self)
    }
    fn visit_str<E>(self, _: &str) -> Result<Self, E> {
        Ok(self)
    }
    fn visit_unit<E>(self) -> Result<Self, E> {
        Ok(self)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self, A::Error> {
        while seq.next_element::<UniqueKeys>()?.is_some() {}
        Ok(self)
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Self, A::Error> {
        let mut keys = std::collections::HashSet::new();
        while let Some(key) = map.next_key::<String>()? {
            if !keys.insert(key.clone()) {
                return Err(serde::de::Error::custom(format!("key `{key}` given twice")));
            }
            map.next_value::<UniqueKeys>()?;
        }
        Ok(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_given_twice_is_refused_at_any_depth() {
        let parsed = |text: &'static str| parse_json(&Bytes::from_static(text.as_bytes()));
        for text in [
            r#"{"sample":"gold","sample":"red"}"#,
            r#"{"bracket":{"shutter_s":[1],"shutter_s":[2]}}"#,
            r#"[{"a":1},{"b":2,"b":3}]"#,
        ] {
            let err = parsed(text).unwrap_err();
            assert!(
                err.message.contains("given twice"),
                "{text}: {}",
                err.message
            );
        }
        let value = parsed(r#"{"a":{"x":1},"b":{"x":[1,"x",null,true,-2.5]}}"#);
        assert!(value.is_ok_and(|v| v["b"]["x"][3] == true));
    }

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
        assert_eq!(
            without_absolute_paths("`/tmp/x/red.toml` is neither a built-in scene"),
            "`red.toml` is neither a built-in scene"
        );
        assert_eq!(without_absolute_paths("/ and x/y"), "/ and x/y");
    }
}
