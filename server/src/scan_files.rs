//! The routes that read a scan's files (docs/ARCHITECTURE.md, "HTTP API", "Limits and
//! access"): the listing, one file (streamed, with byte ranges) and the whole scan as
//! one tar archive (streamed). Each serves exactly the files `files::servable_files`
//! visits, opened by handle below the scan directory. A download is fed through a
//! small buffer: a client that reads nothing for `downloads.stall_timeout_s` has its
//! download cut, and at most `downloads.max_archives` archives are written at once.

use std::io::{self, Write};
use std::os::unix::ffi::OsStrExt;
use std::path::Path as FsPath;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncSeekExt};
use tokio::sync::mpsc;

use super::answers::{db, internal, load_scan, ApiError, ApiResult, AppState, ErrorBody};
use super::archive::{file_name_part, TarWriter};
use super::files::{open_under, servable_files};
use super::shared::Shared;
use super::sync::Slots;

/// Bytes of one chunk of a download.
const CHUNK: usize = 64 << 10;
/// Chunks a download may have ahead of its client.
const CHUNKS_AHEAD: usize = 2;
/// Seconds a client refused an archive (all slots taken) is told to wait.
const ARCHIVE_RETRY_AFTER_S: u64 = 10;

/// Archives being written by this process.
static ARCHIVES: Slots = Slots::new();

/// The end of a download that feeds it, chunk by chunk.
struct Feed {
    chunks: mpsc::Sender<Bytes>,
    /// Set once everything was sent: a feed dropped before is a cut download.
    whole: Arc<AtomicBool>,
    stall: Duration,
}

impl Feed {
    /// A feed and the response body it feeds; the body ends with an error (the
    /// connection is cut) unless [`Feed::finish`] was called.
    fn new(stall: Duration) -> (Feed, Body) {
        let (chunks, receiver) = mpsc::channel(CHUNKS_AHEAD);
        let whole = Arc::new(AtomicBool::new(false));
        let stream = futures_util::stream::unfold(
            (receiver, whole.clone(), false),
            |(mut receiver, whole, ended)| async move {
                if ended {
                    return None;
                }
                match receiver.recv().await {
                    Some(chunk) => Some((Ok(chunk), (receiver, whole, false))),
                    None if whole.load(Ordering::Acquire) => None,
                    None => Some((
                        Err(io::Error::other("the download was cut")),
                        (receiver, whole, true),
                    )),
                }
            },
        );
        let feed = Feed {
            chunks,
            whole,
            stall,
        };
        (feed, Body::from_stream(stream))
    }

    /// Sends `chunk`; an error once the client has read nothing for the stall timeout
    /// or is gone.
    async fn send(&self, chunk: Bytes) -> io::Result<()> {
        use mpsc::error::SendTimeoutError;
        self.chunks
            .send_timeout(chunk, self.stall)
            .await
            .map_err(|err| match err {
                SendTimeoutError::Timeout(_) => io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "the client read nothing for {:?} (downloads.stall_timeout_s)",
                        self.stall
                    ),
                ),
                SendTimeoutError::Closed(_) => {
                    io::Error::new(io::ErrorKind::BrokenPipe, "the client is gone")
                }
            })
    }

    /// Marks the download whole: the body ends normally once its chunks are read.
    fn finish(self) {
        self.whole.store(true, Ordering::Release);
    }
}

/// A [`Feed`] as a blocking writer, for the archive's writer thread.
struct FeedWriter {
    feed: Feed,
    runtime: tokio::runtime::Handle,
}

impl Write for FeedWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let chunk = Bytes::copy_from_slice(buf);
        self.runtime.block_on(self.feed.send(chunk))?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

fn stall_timeout(shared: &Shared) -> Duration {
    Duration::from_secs_f64(shared.config.downloads.stall_timeout_s)
}

/// The files of a scan a client may read (as the files route serves them), sorted.
/// Names that are not UTF-8 cannot be asked for by path: they are in the archive only.
#[utoipa::path(get, path = "/api/scans/{id}/files",
    summary = "Relative paths of the scan's files the files route serves (regular files with one link, no hidden name, UTF-8 names), sorted",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Paths", body = Vec<String>),
        (status = 404, description = "No such scan", body = ErrorBody),
    ))]
pub async fn list_files(
    State(shared): AppState,
    Path(id): Path<i64>,
) -> ApiResult<Json<Vec<String>>> {
    load_scan(&shared, id).await?;
    let dir = shared.scan_dir(id);
    let files = tokio::task::spawn_blocking(move || {
        let mut files = Vec::new();
        // A scan without a directory yet has no files.
        let _ = servable_files(&dir, &mut |relative, _, _| {
            if let Some(name) = relative.to_str() {
                files.push(name.to_owned());
            }
            Ok(())
        });
        files
    })
    .await
    .map_err(internal)?;
    Ok(Json(files))
}

fn content_type(path: &FsPath) -> &'static str {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("json") => "application/json",
        Some("csv") => "text/csv; charset=utf-8",
        Some("tif" | "tiff") => "image/tiff",
        Some("exr") => "image/x-exr",
        Some("png") => "image/png",
        Some("svg") => "image/svg+xml",
        _ => "application/octet-stream",
    }
}

/// What a `Range` header asks of a file of some length.
#[derive(Debug, PartialEq, Eq)]
enum Wanted {
    /// The whole file: no range, or one this route ignores (several, or not bytes).
    Whole,
    /// Bytes `start..end`.
    Part { start: u64, end: u64 },
    /// A range that starts beyond the end (416).
    Unsatisfiable,
}

/// The part of a file of `len` bytes a `Range` header value asks for: one range of
/// bytes (`a-b`, `a-` or the last `-n`); anything else is ignored, as RFC 9110 allows.
fn wanted(range: Option<&HeaderValue>, len: u64) -> Wanted {
    let Some(spec) = range
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().strip_prefix("bytes="))
    else {
        return Wanted::Whole;
    };
    if spec.contains(',') {
        return Wanted::Whole;
    }
    let Some((first, last)) = spec.trim().split_once('-') else {
        return Wanted::Whole;
    };
    let number = |text: &str| text.trim().parse::<u64>().ok();
    let (start, end) = match (first.trim().is_empty(), number(first), number(last)) {
        (true, _, Some(suffix)) if suffix > 0 => (len.saturating_sub(suffix), len),
        (true, _, _) => return Wanted::Unsatisfiable,
        (false, Some(start), Some(last)) if last >= start => (start, len.min(last + 1)),
        (false, Some(start), None) if last.trim().is_empty() => (start, len),
        _ => return Wanted::Whole,
    };
    if start >= len {
        return Wanted::Unsatisfiable;
    }
    Wanted::Part { start, end }
}

/// One file of a scan, streamed, with `Accept-Ranges: bytes`: 206 with
/// `Content-Range` for one range of bytes, 416 for a range beyond its end.
#[utoipa::path(get, path = "/api/scans/{id}/files/{*path}",
    summary = "A file of the scan: captures (TIFF + JSON sidecar), hdr/*.exr, setup.json, samples.csv, fit-*.json; downloaded as `<id>-<sample>-<path with / as ->` (Content-Disposition); streamed, with `Accept-Ranges: bytes` and `Content-Length`; one range of bytes (`Range: bytes=a-b`, `a-`, `-n`) gets 206, others are ignored",
    params(
        ("id" = i64, Path, description = "The scan's id"),
        ("path" = String, Path, description = "The file's path below the scan directory, as the files list gives it"),
        ("Range" = Option<String>, Header, description = "One range of bytes, e.g. `bytes=0-1023`, `bytes=1024-`, `bytes=-512`; several ranges or another unit are ignored (the whole file)"),
    ),
    responses(
        (status = 200, description = "File", content_type = "application/octet-stream", body = Vec<u8>,
            headers(("Accept-Ranges" = String, description = "`bytes`"), ("Content-Length" = u64), ("Content-Disposition" = String, description = "`attachment; filename=\"<id>-<sample>-<path, / as ->\"`"))),
        (status = 206, description = "The range asked for", content_type = "application/octet-stream", body = Vec<u8>,
            headers(("Content-Range" = String, description = "`bytes a-b/length`"), ("Accept-Ranges" = String, description = "`bytes`"))),
        (status = 404, description = "No such regular file below the scan directory (links, FIFOs, devices, hidden names and files with more than one hard link are not served)", body = ErrorBody),
        (status = 416, description = "The range starts beyond the end of the file", body = ErrorBody,
            headers(("Content-Range" = String, description = "`bytes */length`"))),
    ))]
pub async fn get_file(
    State(shared): AppState,
    Path((id, rel)): Path<(i64, String)>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let stall = stall_timeout(&shared);
    let dir = shared.scan_dir(id);
    let not_found = || ApiError::not_found(format!("file {rel:?} of scan {id}"));
    let wanted_path = rel.clone();
    let (file, len) = tokio::task::spawn_blocking(move || {
        let file = open_under(&dir, &wanted_path)?;
        let len = file.metadata().ok()?.len();
        Some((file, len))
    })
    .await
    .map_err(internal)?
    .ok_or_else(not_found)?;
    let sample = load_scan(&shared, id).await?.plan.sample;
    let (status, start, end) = match wanted(headers.get(header::RANGE), len) {
        Wanted::Whole => (StatusCode::OK, 0, len),
        Wanted::Part { start, end } => (StatusCode::PARTIAL_CONTENT, start, end),
        Wanted::Unsatisfiable => {
            let mut answer = ApiError::new(
                StatusCode::RANGE_NOT_SATISFIABLE,
                format!("the range asked for is beyond the file's {len} bytes"),
            )
            .into_response();
            let range = HeaderValue::from_str(&format!("bytes */{len}")).map_err(internal)?;
            answer.headers_mut().insert(header::CONTENT_RANGE, range);
            return Ok(answer);
        }
    };
    let (feed, body) = Feed::new(stall);
    tokio::spawn(async move {
        let mut file = tokio::fs::File::from_std(file);
        let sent = async {
            file.seek(io::SeekFrom::Start(start)).await?;
            let mut left = end - start;
            let mut buf = vec![0u8; CHUNK];
            while left > 0 {
                let want = buf.len().min(usize::try_from(left).unwrap_or(usize::MAX));
                let n = file.read(&mut buf[..want]).await?;
                if n == 0 {
                    return Err(io::Error::new(
                        io::ErrorKind::UnexpectedEof,
                        "the file shrank while it was sent",
                    ));
                }
                feed.send(Bytes::copy_from_slice(&buf[..n])).await?;
                left -= n as u64;
            }
            Ok::<_, io::Error>(())
        }
        .await;
        match sent {
            Ok(()) => feed.finish(),
            Err(err) => tracing::info!("file of scan {id} cut: {err}"),
        }
    });
    let name = format!(
        "{id}-{}-{}",
        file_name_part(&sample),
        file_name_part(&rel.replace('/', "-"))
    );
    let mut answer = (
        status,
        [
            (
                header::CONTENT_TYPE,
                content_type(FsPath::new(&rel)).to_owned(),
            ),
            (header::CONTENT_DISPOSITION, attachment(&name)),
            (header::ACCEPT_RANGES, "bytes".to_owned()),
            (header::CONTENT_LENGTH, (end - start).to_string()),
        ],
        body,
    )
        .into_response();
    if status == StatusCode::PARTIAL_CONTENT {
        let range = format!("bytes {start}-{}/{len}", end - 1);
        answer.headers_mut().insert(
            header::CONTENT_RANGE,
            HeaderValue::from_str(&range).map_err(internal)?,
        );
    }
    Ok(answer)
}

/// `Content-Disposition` of a download named `name` (made of safe characters).
fn attachment(name: &str) -> String {
    format!("attachment; filename=\"{name}\"")
}

/// Seconds since the Unix epoch of a file's last change (0 if unknown).
fn mtime(meta: &std::fs::Metadata) -> u64 {
    meta.modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_secs())
}

/// The whole scan as one tar archive, streamed: every file the files route serves
/// (captures, maps, samples, fits, setup, each read from the handle its walk opened)
/// and `log.json` (its journal and its entries of the hardware log), under
/// `<id>-<sample>/`. 503 with `Retry-After` while `downloads.max_archives` are being
/// written.
#[utoipa::path(get, path = "/api/scans/{id}/archive",
    summary = "The whole scan as one tar archive, streamed: exactly the files the files route serves (captures and sidecars, HDR maps, samples, fits, setup.json, truth.json), each read from the handle its walk opened, plus files whose names are not UTF-8, and log.json (its step journal and its hardware-log entries), under `<id>-<sample>/`; downloaded as `<id>-<sample>.tar`. A download whose client reads nothing for `downloads.stall_timeout_s` is cut",
    params(("id" = i64, Path, description = "The scan's id")),
    responses(
        (status = 200, description = "Archive (POSIX pax: a name over 100 bytes or a size of 8 GiB or more in a pax extended header)", content_type = "application/x-tar", body = Vec<u8>),
        (status = 404, description = "No such scan", body = ErrorBody),
        (status = 503, description = "`downloads.max_archives` archives are being written; ask again after Retry-After seconds", body = ErrorBody,
            headers(("Retry-After" = u64, description = "Seconds to wait before asking again"))),
    ))]
pub async fn scan_archive(State(shared): AppState, Path(id): Path<i64>) -> ApiResult<Response> {
    let scan = load_scan(&shared, id).await?;
    let max = shared.config.downloads.max_archives;
    let Some(slot) = ARCHIVES.take(max) else {
        return Ok(ApiError::busy(
            format!(
                "{max} archives are being written, the most allowed \
                 (downloads.max_archives): try again later"
            ),
            ARCHIVE_RETRY_AFTER_S,
        ));
    };
    let (steps, log) = db(&shared, move |_, store| {
        let log: Vec<_> = store
            .hardware_log(0)?
            .into_iter()
            .filter(|e| e.scan_id == Some(id))
            .collect();
        Ok((store.steps(id)?, log))
    })
    .await?;
    let log = serde_json::to_vec_pretty(&json!({ "steps": steps, "hardware_log": log }))
        .map_err(internal)?;
    let top = format!("{id}-{}", file_name_part(&scan.plan.sample));
    let dir = shared.scan_dir(id);
    let (feed, body) = Feed::new(stall_timeout(&shared));
    let runtime = tokio::runtime::Handle::current();
    let root = top.clone();
    tokio::task::spawn_blocking(move || {
        let _slot = slot;
        let mut tar = TarWriter::new(io::BufWriter::with_capacity(
            CHUNK,
            FeedWriter { feed, runtime },
        ));
        let name = |relative: &[u8]| [root.as_bytes(), b"/", relative].concat();
        let walked = servable_files(&dir, &mut |relative, mut file, meta| {
            let name = name(relative.as_os_str().as_bytes());
            tar.append(&name, meta.len(), mtime(&meta), &mut file)
        });
        let written = match walked {
            // A scan not started yet has no directory: its archive is its log alone.
            Err(e) if e.kind() == io::ErrorKind::NotFound && !dir.exists() => Ok(()),
            other => other,
        }
        .and_then(|()| {
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            tar.append(
                &name(b"log.json"),
                log.len() as u64,
                now,
                &mut log.as_slice(),
            )
        })
        .and_then(|()| tar.finish())
        .and_then(|out| out.into_inner().map_err(|e| e.into_error()));
        match written {
            Ok(writer) => writer.feed.finish(),
            // The client sees a cut archive, never a silently short one.
            Err(err) => tracing::warn!("archive of scan {id} cut: {err}"),
        }
    });
    Ok((
        [
            (header::CONTENT_TYPE, "application/x-tar".to_owned()),
            (
                header::CONTENT_DISPOSITION,
                attachment(&format!("{top}.tar")),
            ),
        ],
        body,
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_of_bytes_as_rfc_9110_reads_them() {
        let range = |text: &str| wanted(Some(&HeaderValue::from_str(text).unwrap()), 100);
        assert_eq!(wanted(None, 100), Wanted::Whole);
        assert_eq!(range("bytes=0-9"), Wanted::Part { start: 0, end: 10 });
        assert_eq!(
            range("bytes=90-"),
            Wanted::Part {
                start: 90,
                end: 100
            }
        );
        assert_eq!(
            range("bytes=90-500"),
            Wanted::Part {
                start: 90,
                end: 100
            }
        );
        assert_eq!(
            range("bytes=-10"),
            Wanted::Part {
                start: 90,
                end: 100
            }
        );
        assert_eq!(range("bytes=-500"), Wanted::Part { start: 0, end: 100 });
        assert_eq!(range("bytes=100-"), Wanted::Unsatisfiable);
        assert_eq!(range("bytes=-0"), Wanted::Unsatisfiable);
        for ignored in ["bytes=0-1,5-6", "items=0-1", "bytes=5-1", "bytes=x-"] {
            assert_eq!(range(ignored), Wanted::Whole, "{ignored}");
        }
        assert_eq!(
            wanted(Some(&HeaderValue::from_static("bytes=0-")), 0),
            Wanted::Unsatisfiable
        );
    }

    #[test]
    fn a_feed_cut_before_it_finished_ends_its_body_with_an_error() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async {
            let (feed, body) = Feed::new(Duration::from_secs(5));
            feed.send(Bytes::from_static(b"ab")).await.unwrap();
            drop(feed);
            assert!(axum::body::to_bytes(body, 1 << 20).await.is_err());
            let (feed, body) = Feed::new(Duration::from_secs(5));
            feed.send(Bytes::from_static(b"ab")).await.unwrap();
            feed.finish();
            let bytes = axum::body::to_bytes(body, 1 << 20).await.unwrap();
            assert_eq!(&bytes[..], b"ab");
        });
    }

    #[test]
    fn a_client_that_reads_nothing_times_the_feed_out() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async {
            let (feed, _body) = Feed::new(Duration::from_millis(50));
            let mut sent = 0;
            let err = loop {
                match feed.send(Bytes::from_static(b"x")).await {
                    Ok(()) => sent += 1,
                    Err(err) => break err,
                }
            };
            assert_eq!(sent, CHUNKS_AHEAD);
            assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        });
    }
}
