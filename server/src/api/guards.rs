//! The checks every request passes before its handler (docs/ARCHITECTURE.md, "HTTP
//! API"): the Host (421), a body's size (413), the bearer token (401), a JSON body's
//! `Content-Type` (415) and its arrival in time (408), and every error answer in the API's JSON shape. Each check's
//! answer is described once, for the routes behind it, in `openapi`.

use std::time::Duration;

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{header, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::answers::{ApiError, AppState};
use crate::config::Config;

/// Most bytes of an oversized body read and discarded before its 413: a client still
/// sending it then reads the answer instead of a reset connection. Larger bodies are
/// answered at once.
const DRAIN_CAP: u64 = 1 << 20;

/// 413 for a body whose declared length is over `max_body_bytes`, after draining it
/// (up to [`DRAIN_CAP`]); the connection closes after the answer.
pub(super) async fn refuse_oversized(
    State(shared): AppState,
    request: Request,
    next: Next,
) -> Response {
    let limit = shared.config.max_body_bytes as u64;
    let declared = request
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    let Some(length) = declared.filter(|&n| n > limit) else {
        return next.run(request).await;
    };
    if length <= DRAIN_CAP {
        let _ = axum::body::to_bytes(request.into_body(), DRAIN_CAP as usize).await;
    }
    let mut answer = ApiError::new(
        StatusCode::PAYLOAD_TOO_LARGE,
        format!("request body of {length} bytes is over max_body_bytes ({limit})"),
    )
    .into_response();
    answer
        .headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    answer
}

/// Whether read routes need the token: bound beyond loopback without `public_read`.
pub(super) fn reads_need_token(config: &Config) -> bool {
    !config.bind.ip().is_loopback() && !config.public_read
}

/// Whether the daemon answers to `Host` (port ignored): the bind address, `localhost`,
/// a loopback address, a name of `allowed_hosts`, or, when bound to every interface,
/// any IP address (a DNS-rebinding page always sends a name, never an address).
fn host_allowed(config: &Config, host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(rest) => rest.split_once(']').map_or("", |(name, _)| name),
        None => host.rsplit_once(':').map_or(host, |(name, _)| name),
    };
    if name.eq_ignore_ascii_case("localhost")
        || config
            .allowed_hosts
            .iter()
            .any(|h| h.eq_ignore_ascii_case(name))
    {
        return true;
    }
    let bind = config.bind.ip();
    name.parse::<std::net::IpAddr>()
        .is_ok_and(|ip| ip == bind || ip.is_loopback() || bind.is_unspecified())
}

/// Whether a request may come from a browser's page of another site: it has no
/// `Origin` (curl, scripts), or its `Origin` is a host the daemon answers to (its own
/// page). For the one change that needs no token (the emergency stop), so that no page
/// of another site can make it.
pub(super) fn from_own_page(config: &Config, headers: &axum::http::HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return true;
    };
    let authority = origin
        .to_str()
        .ok()
        .and_then(|o| {
            o.strip_prefix("http://")
                .or_else(|| o.strip_prefix("https://"))
        })
        .map(|rest| rest.split('/').next().unwrap_or(""));
    authority.is_some_and(|a| !a.is_empty() && host_allowed(config, a))
}

/// 421 for a request whose Host the daemon does not answer to (DNS rebinding).
pub(super) async fn check_host(State(shared): AppState, request: Request, next: Next) -> Response {
    let host = request
        .headers()
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .or_else(|| request.uri().authority().map(|a| a.as_str()))
        .unwrap_or("");
    if host_allowed(&shared.config, host) {
        return next.run(request).await;
    }
    ApiError::new(
        StatusCode::MISDIRECTED_REQUEST,
        format!(
            "Host {host:?} is not this daemon's: use its address, localhost, or a name of \
             allowed_hosts"
        ),
    )
    .into_response()
}

/// 415 unless the request says its body is JSON: for the methods that send one (POST
/// and PATCH, what these routes serve); another method goes on to the routes' own
/// answer (405 with the methods allowed). The body must then arrive whole within
/// `header_timeout_s`: a client that stops sending gets 408 and the connection closes
/// (a handler never waits on a body without end).
pub(super) async fn require_json(
    State(shared): AppState,
    request: Request,
    next: Next,
) -> Response {
    if !matches!(*request.method(), Method::POST | Method::PATCH) {
        return next.run(request).await;
    }
    let content_type = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let essence = content_type.split(';').next().unwrap_or("").trim();
    if !essence.eq_ignore_ascii_case("application/json") {
        return ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            format!("Content-Type must be application/json, got {content_type:?}"),
        )
        .into_response();
    }
    let (parts, body) = request.into_parts();
    let (limit, wait) = (
        shared.config.max_body_bytes,
        Duration::from_secs_f64(shared.config.header_timeout_s),
    );
    let closing = |status, message: String| {
        let mut answer = ApiError::new(status, message).into_response();
        answer
            .headers_mut()
            .insert(header::CONNECTION, HeaderValue::from_static("close"));
        answer
    };
    match tokio::time::timeout(wait, axum::body::to_bytes(body, limit)).await {
        Ok(Ok(bytes)) => {
            next.run(Request::from_parts(parts, Body::from(bytes)))
                .await
        }
        Ok(Err(_)) => closing(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("request body over max_body_bytes ({limit}), or cut short"),
        ),
        Err(_) => closing(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the request body did not arrive within header_timeout_s ({} s)",
                shared.config.header_timeout_s
            ),
        ),
    }
}

/// Gives every error answer the API's JSON shape: axum's rejections (a bad path
/// parameter, a body over the limit, an unknown method) come as plain text.
pub(super) async fn json_errors(request: Request, next: Next) -> Response {
    let response = next.run(request).await;
    let status = response.status();
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (parts, body) = response.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.unwrap_or_default();
    let text = String::from_utf8_lossy(&text).trim().to_owned();
    let message = if text.is_empty() {
        status
            .canonical_reason()
            .unwrap_or("error")
            .to_ascii_lowercase()
    } else {
        text
    };
    let mut answer = ApiError::new(status, message).into_response();
    for (name, value) in &parts.headers {
        if name != header::CONTENT_TYPE && name != header::CONTENT_LENGTH {
            answer.headers_mut().insert(name.clone(), value.clone());
        }
    }
    answer
}

/// Rejects a request without the right `Authorization: Bearer` token before its body
/// is read, so nothing changes. The scheme is case-insensitive (RFC 9110).
pub(super) async fn require_token(
    State(shared): AppState,
    request: Request,
    next: Next,
) -> Response {
    let given = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim_start().split_once(' '))
        .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
        .map(|(_, token)| token.trim());
    if given.is_some_and(|t| constant_time_eq(t.as_bytes(), shared.token.as_bytes())) {
        return next.run(request).await;
    }
    let mut response = ApiError::new(
        StatusCode::UNAUTHORIZED,
        "missing or wrong bearer token (Authorization: Bearer <token>)",
    )
    .into_response();
    response
        .headers_mut()
        .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    response
}

/// Compares two byte strings in time independent of where they differ.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_check_answers_the_bind_address_localhost_and_allowed_names() {
        let mut config = Config {
            allowed_hosts: vec!["gonio.lab".into()],
            ..Config::default()
        };
        for host in [
            "127.0.0.1:8080",
            "localhost",
            "LOCALHOST:1",
            "[::1]:8080",
            "gonio.lab:80",
        ] {
            assert!(host_allowed(&config, host), "{host}");
        }
        for host in [
            "evil.example",
            "evil.example:8080",
            "192.168.1.9",
            "",
            "[::1",
        ] {
            assert!(!host_allowed(&config, host), "{host}");
        }
        config.bind = "0.0.0.0:8080".parse().unwrap();
        assert!(host_allowed(&config, "192.168.1.9:8080"));
        assert!(!host_allowed(&config, "rebind.evil.example"));
        assert!(reads_need_token(&config));
        config.public_read = true;
        assert!(!reads_need_token(&config));
    }
}
