//! `GET /api/scans/{id}/thumbnail.png`: the latest frame of a scan as a small PNG
//! (docs/ARCHITECTURE.md, "Limits and access"). Thumbnails are kept per frame (the
//! latest [`CACHED`]); at most `downloads.max_thumbnail_decodes` frames are decoded for
//! them at once, each reading only every few rows (`preview::thumbnail_png`); a request
//! that finds no decode free within `downloads.thumbnail_wait_s` gets 503 with
//! `Retry-After`.

use std::collections::VecDeque;
use std::os::unix::fs::MetadataExt;
use std::path::PathBuf;
use std::sync::{Mutex, OnceLock};
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use tokio::sync::Semaphore;

use super::answers::{db, internal, ApiError, ApiResult, AppState};
use super::preview;
use super::sync::lock;
use super::view::latest_frame;

/// Thumbnails kept (a few hundred kilobytes each at most).
const CACHED: usize = 32;
/// Seconds a client refused a thumbnail (no decode free) is told to wait.
const RETRY_AFTER_S: u64 = 2;

/// One version of a frame file: its path, inode, length and modification time (ns).
type FrameKey = (PathBuf, u64, u64, i128);

/// The latest thumbnails made, oldest first.
static CACHE: Mutex<VecDeque<(FrameKey, Bytes)>> = Mutex::new(VecDeque::new());

/// The decodes for thumbnails that may run at once.
static DECODES: OnceLock<Semaphore> = OnceLock::new();

fn cached(key: &FrameKey) -> Option<Bytes> {
    lock(&CACHE)
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, png)| png.clone())
}

fn keep(key: FrameKey, png: Bytes) {
    let mut cache = lock(&CACHE);
    if cache.iter().any(|(k, _)| *k == key) {
        return;
    }
    if cache.len() >= CACHED {
        cache.pop_front();
    }
    cache.push_back((key, png));
}

fn png_answer(png: Bytes) -> Response {
    (
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        png,
    )
        .into_response()
}

/// The latest captured frame of a scan as a small PNG.
#[utoipa::path(get, path = "/api/scans/{id}/thumbnail.png",
    summary = "The latest frame, downscaled, as PNG (kept per frame; at most `downloads.max_thumbnail_decodes` decoded at once)",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "PNG", content_type = "image/png", body = Vec<u8>),
        (status = 404, description = "No frame yet", body = crate::answers::ErrorBody),
        (status = 503, description = "No decode free within `downloads.thumbnail_wait_s`; ask again after Retry-After seconds", body = crate::answers::ErrorBody,
            headers(("Retry-After" = u64, description = "Seconds to wait before asking again"))),
    ))]
pub async fn thumbnail(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Response> {
    let steps = db(&shared, move |_, store| store.steps(id)).await?;
    let latest = latest_frame(&steps)
        .map(|(_, path)| path.to_owned())
        .ok_or_else(|| ApiError::not_found(format!("a frame of scan {id}")))?;
    let path = shared.scan_dir(id).join(&latest);
    let meta = tokio::fs::metadata(&path)
        .await
        .map_err(|_| ApiError::not_found(format!("frame {latest} of scan {id}")))?;
    let key: FrameKey = (
        path.clone(),
        meta.ino(),
        meta.len(),
        i128::from(meta.mtime()) * 1_000_000_000 + i128::from(meta.mtime_nsec()),
    );
    if let Some(png) = cached(&key) {
        return Ok(png_answer(png));
    }
    let downloads = &shared.config.downloads;
    let decodes = DECODES.get_or_init(|| Semaphore::new(downloads.max_thumbnail_decodes));
    let wait = Duration::from_secs_f64(downloads.thumbnail_wait_s);
    let Ok(Ok(_permit)) = tokio::time::timeout(wait, decodes.acquire()).await else {
        return Ok(ApiError::busy(
            format!(
                "{} thumbnails are being decoded, the most allowed \
                 (downloads.max_thumbnail_decodes): try again later",
                downloads.max_thumbnail_decodes
            ),
            RETRY_AFTER_S,
        ));
    };
    // Made meanwhile by the request that held the decode.
    if let Some(png) = cached(&key) {
        return Ok(png_answer(png));
    }
    let png = tokio::task::spawn_blocking(move || preview::thumbnail_png(&path))
        .await
        .map_err(internal)?
        .map_err(internal)?;
    let png = Bytes::from(png);
    keep(key, png.clone());
    Ok(png_answer(png))
}
