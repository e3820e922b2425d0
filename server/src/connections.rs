//! The HTTP server's connections (docs/ARCHITECTURE.md, "Limits and access"): each
//! connection must send a request's headers within `header_timeout_s` and is closed
//! once it has had no request in flight for `idle_timeout_s`; at most
//! `max_connections` are open (fewer when the file-descriptor limit, raised to its hard
//! maximum at start, leaves less than `reserved_fds` for the hardware, the database and
//! the files). A new connection beyond the cap is accepted once the connection idle
//! the longest has closed (the next ones wait in the listen backlog meanwhile); with
//! none idle it gets a 503 and is closed. So idle sockets cannot starve the daemon.

use std::collections::HashMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::body::{Body, Bytes};
use axum::Router;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tower::ServiceExt;

use super::sync::lock;

/// What the server enforces on connections.
#[derive(Debug, Clone, Copy)]
pub struct ConnectionLimits {
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
    /// Most open connections.
    pub max_connections: usize,
}

/// Raises the soft file-descriptor limit to the hard one where allowed and returns
/// the connections that fit beside `reserved` descriptors (at least 16).
pub fn connections_within_fd_limit(wanted: usize, reserved: u64) -> usize {
    let soft = raise_fd_limit();
    let fit = soft.saturating_sub(reserved).max(16);
    let cap = wanted.min(usize::try_from(fit).unwrap_or(usize::MAX));
    if cap < wanted {
        tracing::warn!(
            "the file-descriptor limit is {soft}: at most {cap} connections \
             ({reserved} descriptors kept for hardware, database and files)"
        );
    }
    cap
}

/// The soft RLIMIT_NOFILE after raising it to the hard limit (capped at 2^20).
fn raise_fd_limit() -> u64 {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write the struct passed.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) != 0 {
            return 1024;
        }
        let target = limit.rlim_max.min(1 << 20);
        if limit.rlim_cur < target {
            let raised = libc::rlimit {
                rlim_cur: target,
                rlim_max: limit.rlim_max,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
                limit.rlim_cur = target;
            }
        }
    }
    limit.rlim_cur
}

/// One open connection as the registry sees it.
struct Connection {
    /// Requests in flight (a response body still streaming counts).
    busy: AtomicUsize,
    /// When the last request ended, or the connection opened (ms since the server
    /// started).
    idle_since_ms: AtomicU64,
    /// Told to close (evicted, or idle too long), not yet gone.
    closing: AtomicBool,
    close: Notify,
}

impl Connection {
    /// Tells the connection to close once its requests are answered; false if it
    /// already was.
    fn close(&self) -> bool {
        let first = !self.closing.swap(true, Ordering::AcqRel);
        if first {
            self.close.notify_one();
        }
        first
    }
}

struct Registry {
    started: Instant,
    connections: Mutex<HashMap<u64, Arc<Connection>>>,
    /// Signalled when a connection has gone.
    removed: Notify,
}

impl Registry {
    fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    /// How long `c` has been idle; `None` while it has a request in flight or is
    /// closing.
    fn idle_for(&self, c: &Connection) -> Option<Duration> {
        (c.busy.load(Ordering::Acquire) == 0 && !c.closing.load(Ordering::Acquire)).then(|| {
            Duration::from_millis(
                self.now_ms()
                    .saturating_sub(c.idle_since_ms.load(Ordering::Acquire)),
            )
        })
    }

    /// Closes the connection idle the longest; false if none is idle.
    fn evict_oldest_idle(&self) -> bool {
        let connections = lock(&self.connections);
        let oldest = connections
            .values()
            .filter_map(|c| self.idle_for(c).map(|idle| (idle, c)))
            .max_by_key(|(idle, _)| *idle);
        oldest.is_some_and(|(_, c)| c.close())
    }

    /// Open connections, and how many of them are closing.
    fn counts(&self) -> (usize, usize) {
        let connections = lock(&self.connections);
        let closing = connections
            .values()
            .filter(|c| c.closing.load(Ordering::Acquire))
            .count();
        (connections.len(), closing)
    }

    /// Waits until fewer than `max` connections are open, closing the connection idle
    /// the longest (one more each 100 ms that none goes) and waiting for it to go, so
    /// the process never holds more than `max` (and the one being accepted). Returns
    /// false if every connection is busy and none is closing.
    async fn make_room(&self, max: usize) -> bool {
        loop {
            let (open, closing) = self.counts();
            if open < max {
                return true;
            }
            if !self.evict_oldest_idle() && closing == 0 {
                return false;
            }
            let _ = tokio::time::timeout(Duration::from_millis(100), self.removed.notified()).await;
        }
    }

    /// Closes every connection idle longer than `timeout`.
    fn close_idle(&self, timeout: Duration) {
        for c in lock(&self.connections).values() {
            if self.idle_for(c).is_some_and(|idle| idle >= timeout) {
                c.close();
            }
        }
    }
}

/// Marks a request in flight on its connection until dropped (with the response body).
struct Busy {
    registry: Arc<Registry>,
    connection: Arc<Connection>,
}

impl Busy {
    fn new(registry: Arc<Registry>, connection: Arc<Connection>) -> Self {
        connection.busy.fetch_add(1, Ordering::AcqRel);
        Self {
            registry,
            connection,
        }
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.connection
            .idle_since_ms
            .store(self.registry.now_ms(), Ordering::Release);
        self.connection.busy.fetch_sub(1, Ordering::AcqRel);
    }
}

/// A response body that keeps its connection busy until it is sent or dropped.
struct BusyBody {
    inner: Body,
    _busy: Busy,
}

impl http_body::Body for BusyBody {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// The answer to a connection beyond the cap when none can be closed.
const BUSY_RESPONSE: &[u8] = b"HTTP/1.1 503 Service Unavailable\r\n\
Content-Type: application/json\r\nContent-Length: 57\r\nConnection: close\r\n\r\n\
{\"error\":\"too many open connections, try again shortly\"}\n";

/// Serves `router` on `listener` under `limits` until `shutdown` completes; then tells
/// every connection to close once its request in flight is answered, and waits for them
/// at most `grace` (an event stream never ends by itself).
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: ConnectionLimits,
    shutdown: impl Future<Output = ()>,
    grace: Duration,
) {
    let registry = Arc::new(Registry {
        started: Instant::now(),
        connections: Mutex::new(HashMap::new()),
        removed: Notify::new(),
    });
    let reaper = {
        let registry = registry.clone();
        let period =
            (limits.idle_timeout / 4).clamp(Duration::from_millis(50), Duration::from_secs(1));
        tokio::spawn(async move {
            loop {
                tokio::time::sleep(period).await;
                registry.close_idle(limits.idle_timeout);
            }
        })
    };
    tokio::pin!(shutdown);
    let mut next_id = 0u64;
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            () = &mut shutdown => break,
        };
        let stream = match accepted {
            Ok((stream, _)) => stream,
            Err(err) => {
                // Out of descriptors (EMFILE/ENFILE) or a connection reset before accept:
                // free an idle connection and wait a little rather than spin.
                tracing::warn!("accept: {err}");
                registry.evict_oldest_idle();
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        // Room for it: meanwhile the next connections wait in the listen backlog,
        // which costs the process no descriptor.
        let room = tokio::select! {
            room = registry.make_room(limits.max_connections) => room,
            () = &mut shutdown => break,
        };
        if !room {
            let _ = stream.try_write(BUSY_RESPONSE);
            continue;
        }
        next_id += 1;
        let connection = Arc::new(Connection {
            busy: AtomicUsize::new(0),
            idle_since_ms: AtomicU64::new(registry.now_ms()),
            closing: AtomicBool::new(false),
            close: Notify::new(),
        });
        lock(&registry.connections).insert(next_id, connection.clone());
        tokio::spawn(serve_connection(
            next_id,
            stream,
            router.clone(),
            registry.clone(),
            connection,
            limits,
        ));
    }
    reaper.abort();
    drop(listener);
    for connection in lock(&registry.connections).values() {
        connection.close();
    }
    let drained = tokio::time::timeout(grace, async {
        loop {
            let open = lock(&registry.connections).len();
            if open == 0 {
                break;
            }
            let _ =
                tokio::time::timeout(Duration::from_millis(100), registry.removed.notified()).await;
        }
    })
    .await;
    if drained.is_err() {
        tracing::info!("closing the connections still open");
    }
}

async fn serve_connection(
    id: u64,
    stream: TcpStream,
    router: Router,
    registry: Arc<Registry>,
    connection: Arc<Connection>,
    limits: ConnectionLimits,
) {
    let service = {
        let (registry, connection) = (registry.clone(), connection.clone());
        hyper::service::service_fn(move |request: hyper::Request<Incoming>| {
            let busy = Busy::new(registry.clone(), connection.clone());
            let router = router.clone();
            async move {
                let response = router.oneshot(request.map(Body::new)).await?;
                Ok::<_, std::convert::Infallible>(
                    response.map(|inner| BusyBody { inner, _busy: busy }),
                )
            }
        })
    };
    let mut served = Box::pin(
        hyper::server::conn::http1::Builder::new()
            .timer(TokioTimer::new())
            .header_read_timeout(limits.header_timeout)
            .serve_connection(TokioIo::new(JsonParseErrors::new(stream)), service),
    );
    tokio::select! {
        _ = served.as_mut() => {}
        () = connection.close.notified() => {
            served.as_mut().graceful_shutdown();
            let _ = tokio::time::timeout(Duration::from_secs(5), served.as_mut()).await;
        }
    }
    // The socket is closed before the connection leaves the count.
    drop(served);
    lock(&registry.connections).remove(&id);
    registry.removed.notify_one();
}

/// A connection's socket on which hyper's own answers to requests it cannot parse
/// (400 bad request line or header, 414 URI too long, 431 headers too large) get the
/// API's error shape `{"error": …}` instead of an empty body. They are recognised as
/// the heads hyper writes for them: one of those statuses, `content-length: 0` and no
/// content type, which no answer of the router has (every error of the router is
/// JSON). The rewritten answer closes the connection, as hyper does after it.
struct JsonParseErrors {
    inner: TcpStream,
    /// A rewritten answer, and how much of it is written.
    pending: Vec<u8>,
    written: usize,
}

impl JsonParseErrors {
    fn new(inner: TcpStream) -> Self {
        Self {
            inner,
            pending: Vec::new(),
            written: 0,
        }
    }

    /// Writes what is left of a rewritten answer.
    fn poll_pending(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        while self.written < self.pending.len() {
            let n = std::task::ready!(
                Pin::new(&mut self.inner).poll_write(cx, &self.pending[self.written..])
            )?;
            if n == 0 {
                return Poll::Ready(Err(std::io::ErrorKind::WriteZero.into()));
            }
            self.written += n;
        }
        self.pending.clear();
        self.written = 0;
        Poll::Ready(Ok(()))
    }

    /// Takes `bytes` (hyper's next write) in place of writing them when they are one of
    /// hyper's own error heads, queueing their JSON form; returns how many were taken.
    fn take_parse_error(&mut self, cx: &mut Context<'_>, bytes: &[u8]) -> Option<usize> {
        self.pending = json_parse_error(bytes)?;
        // Started now; the rest goes with the next write, flush or shutdown.
        let _ = self.poll_pending(cx);
        Some(bytes.len())
    }
}

/// The JSON form of hyper's own error answer `head`, or `None` for any other bytes.
fn json_parse_error(head: &[u8]) -> Option<Vec<u8>> {
    let head = std::str::from_utf8(head).ok()?.strip_suffix("\r\n\r\n")?;
    let mut lines = head.split("\r\n");
    let status_line = lines.next()?;
    let message = match status_line.strip_prefix("HTTP/1.1 ")?.get(..3)? {
        "400" => "malformed request: its request line or a header cannot be parsed",
        "414" => "URI too long",
        "431" => "request header fields too large",
        _ => return None,
    };
    let headers: Vec<&str> = lines.collect();
    let header = |name: &str| {
        headers
            .iter()
            .filter_map(|h| h.split_once(':'))
            .find(|(n, _)| n.trim().eq_ignore_ascii_case(name))
            .map(|(_, v)| v.trim())
    };
    if header("content-length") != Some("0") || header("content-type").is_some() {
        return None;
    }
    let body = serde_json::json!({ "error": message }).to_string();
    Some(
        format!(
            "{status_line}\r\ncontent-type: application/json\r\ncontent-length: {}\r\n\
             connection: close\r\n\r\n{body}",
            body.len()
        )
        .into_bytes(),
    )
}

impl AsyncRead for JsonParseErrors {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl AsyncWrite for JsonParseErrors {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_pending(cx))?;
        if let Some(taken) = this.take_parse_error(cx, buf) {
            return Poll::Ready(Ok(taken));
        }
        Pin::new(&mut this.inner).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_pending(cx))?;
        if let Some(first) = bufs.iter().find(|b| !b.is_empty()) {
            if let Some(taken) = this.take_parse_error(cx, first) {
                return Poll::Ready(Ok(taken));
            }
        }
        Pin::new(&mut this.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_pending(cx))?;
        Pin::new(&mut this.inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_pending(cx))?;
        Pin::new(&mut this.inner).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use std::io::{ErrorKind, Read, Write};
    use std::net::{SocketAddr, TcpStream as Client};

    use axum::routing::get;

    use super::*;

    /// Serves `/ok` (answered at once) and `/busy` (a body that never ends) under
    /// `limits`, on a runtime of its own; returns the address.
    fn start(limits: ConnectionLimits) -> SocketAddr {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let addr = listener.local_addr().unwrap();
        std::thread::spawn(move || {
            let runtime = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .enable_all()
                .build()
                .unwrap();
            runtime.block_on(async move {
                let never = || futures_util::stream::pending::<Result<Bytes, std::io::Error>>();
                let router = Router::new().route("/ok", get(|| async { "ok" })).route(
                    "/busy",
                    get(move || async move { Body::from_stream(never()) }),
                );
                let listener = TcpListener::from_std(listener).unwrap();
                let grace = Duration::ZERO;
                serve(listener, router, limits, std::future::pending(), grace).await;
            });
        });
        addr
    }

    fn connect(addr: SocketAddr) -> Client {
        let client = Client::connect(addr).unwrap();
        // Generous: the machine may be loaded; a closed connection answers at once.
        client
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        client
    }

    /// Sends `GET path` (keep-alive) and reads the answer's head (and the 2-byte
    /// body of `/ok`).
    fn get_head(client: &mut Client, path: &str) -> String {
        write!(client, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
        let mut head = Vec::new();
        let mut byte = [0u8];
        while !head.ends_with(b"\r\n\r\n") && client.read(&mut byte).unwrap() == 1 {
            head.push(byte[0]);
        }
        if path == "/ok" {
            client.read_exact(&mut [0u8; 2]).unwrap();
        }
        String::from_utf8_lossy(&head).into_owned()
    }

    /// Whether the server closed the connection (within the read timeout).
    fn closed_by_server(client: &mut Client) -> bool {
        let mut buffer = [0u8; 256];
        loop {
            match client.read(&mut buffer) {
                Ok(0) => return true,
                Ok(_) => continue,
                Err(err) if err.kind() == ErrorKind::ConnectionReset => return true,
                Err(_) => return false,
            }
        }
    }

    #[test]
    fn beyond_the_cap_the_longest_idle_connection_closes_and_busy_ones_mean_503() {
        let addr = start(ConnectionLimits {
            header_timeout: Duration::from_secs(30),
            idle_timeout: Duration::from_secs(600),
            max_connections: 2,
        });
        let mut idle = connect(addr);
        assert!(get_head(&mut idle, "/ok").starts_with("HTTP/1.1 200"));
        let mut busy = connect(addr);
        assert!(get_head(&mut busy, "/busy").starts_with("HTTP/1.1 200"));
        // A third connection: the idle one makes room for it.
        let mut third = connect(addr);
        assert!(get_head(&mut third, "/ok").starts_with("HTTP/1.1 200"));
        assert!(closed_by_server(&mut idle));
        // Both open connections busy: the next one is told so and closed.
        assert!(get_head(&mut third, "/busy").starts_with("HTTP/1.1 200"));
        let mut refused = connect(addr);
        let mut answer = String::new();
        refused.read_to_string(&mut answer).unwrap();
        assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
        assert!(answer.contains("too many open connections"), "{answer}");
    }

    #[test]
    fn hyper_s_own_error_answers_are_json() {
        let addr = start(ConnectionLimits {
            header_timeout: Duration::from_secs(30),
            idle_timeout: Duration::from_secs(600),
            max_connections: 16,
        });
        let long_uri = format!("GET /{} HTTP/1.1\r\nHost: x\r\n\r\n", "a".repeat(70_000));
        let many_headers = format!("GET /ok HTTP/1.1\r\n{}\r\n", "X-A: 1\r\n".repeat(200));
        for (request, status) in [
            ("GARBAGE\r\n\r\n".to_owned(), 400),
            ("GET /ok HTTP/1.1\r\nBad Header\r\n\r\n".to_owned(), 400),
            (long_uri, 414),
            (many_headers, 431),
        ] {
            let mut client = connect(addr);
            client.write_all(request.as_bytes()).unwrap();
            let mut answer = String::new();
            client.read_to_string(&mut answer).unwrap();
            let (head, body) = answer.split_once("\r\n\r\n").unwrap();
            assert!(head.starts_with(&format!("HTTP/1.1 {status} ")), "{answer}");
            assert!(head.contains("content-type: application/json"), "{answer}");
            let error: serde_json::Value = serde_json::from_str(body).unwrap();
            assert!(
                error["error"].as_str().is_some_and(|e| !e.is_empty()),
                "{answer}"
            );
        }
        // Answers of the router pass unchanged, on the same connection too.
        let mut client = connect(addr);
        assert!(get_head(&mut client, "/ok").starts_with("HTTP/1.1 200"));
        assert!(get_head(&mut client, "/ok").starts_with("HTTP/1.1 200"));
    }

    #[test]
    fn slow_headers_and_idle_connections_are_closed() {
        let addr = start(ConnectionLimits {
            header_timeout: Duration::from_millis(300),
            idle_timeout: Duration::from_millis(300),
            max_connections: 16,
        });
        let mut slow = connect(addr);
        slow.write_all(b"GET /ok HTTP/1.1\r\nHost: x\r\n").unwrap();
        let mut silent = connect(addr);
        let mut idle = connect(addr);
        assert!(get_head(&mut idle, "/ok").starts_with("HTTP/1.1 200"));
        for (what, client) in [
            ("slow", &mut slow),
            ("silent", &mut silent),
            ("idle", &mut idle),
        ] {
            assert!(closed_by_server(client), "{what} connection left open");
        }
        // A busy connection stays open past both timeouts.
        let mut busy = connect(addr);
        assert!(get_head(&mut busy, "/busy").starts_with("HTTP/1.1 200"));
        busy.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        assert!(!closed_by_server(&mut busy));
    }
}
