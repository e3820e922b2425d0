//! gonio-server: the measurement daemon behind `gonio serve`. HTTP handlers (tokio +
//! axum) queue scans in a durable SQLite store; a hardware lane and a processing lane
//! run their steps (docs/ARCHITECTURE.md, "Daemon"). Captures are decoded in child
//! processes ([`decode_workers`]).
#![doc = include_str!("daemon.md")]
#![doc = include_str!("storage.md")]
#![doc = include_str!("lanes/hardware.md")]
#![doc = include_str!("limits.md")]
#![doc = include_str!("api.md")]
#![doc = include_str!("web.md")]

mod answers;
mod api;
mod archive;
mod calibration;
mod config;
mod connections;
pub mod decode_workers;
mod devices;
mod downloads_config;
mod files;
mod fit_cache;
mod health;
mod lanes;
mod mount;
mod notices;
mod notify;
mod openapi;
mod plan;
mod preview;
mod process;
mod progress;
mod queued_times;
mod sample_waits;
mod scan_colour;
mod scan_files;
mod scan_report;
pub mod schemas;
mod shared;
mod step_guard;
mod storage;
mod store;
mod sweep_state;
mod sync;
mod thumbnails;
mod timing;
mod validate;
mod view;
mod web;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;
use gonio_drivers::ArmState;
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use tokio::sync::broadcast;

use config::Config;
use shared::{ArmView, CameraView, HardwareStatus, Shared};
use store::Store;
use sync::{lock, Mailbox};

/// How long requests in flight may take to finish once a stop is asked for.
const SHUTDOWN_GRACE: std::time::Duration = std::time::Duration::from_secs(2);

/// Shutter range (s) assumed until the camera has told its own.
const UNKNOWN_SHUTTER_RANGE_S: (f64, f64) = (1.0 / 8000.0, 30.0);

/// What `gonio serve` is started with; every field falls back on the configuration
/// file, then on the defaults.
#[derive(Debug, Default)]
pub struct Options {
    /// Configuration file (TOML, every key optional); without one the daemon runs on
    /// emulated hardware with the builtin `gold` scene.
    pub config: Option<PathBuf>,
    /// Listen address (default 127.0.0.1:8080; port 0 picks a free port).
    pub bind: Option<std::net::SocketAddr>,
    /// Data directory: database, token, scans (default ./gonio-data).
    pub data: Option<PathBuf>,
}

/// Runs the daemon until `stop` ends (it names what stopped it: a signal, say); the
/// steps running then are redone at the next start.
pub fn run<S>(args: Options, stop: S) -> anyhow::Result<()>
where
    S: std::future::Future<Output = &'static str> + Send,
{
    let mut config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    if let Some(bind) = args.bind {
        config.bind = bind;
    }
    if let Some(data) = args.data {
        config.data_dir = data;
    }
    // The port first: a daemon that cannot listen creates nothing (no data directory,
    // no token) and has started no step.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let listener = {
        let _context = runtime.enter();
        listen(config.bind).with_context(|| format!("binding {}", config.bind))?
    };
    private_data_dir(&config.data_dir)?;
    gonio_processing::capture::set_max_pixels(config.max_frame_pixels);
    // One daemon per data directory: an OS lock (flock) on the directory itself, which
    // no file's removal can undo; the OS drops it when the process ends, however it
    // ends.
    let lock_dir = std::fs::File::open(&config.data_dir)
        .with_context(|| format!("opening {}", config.data_dir.display()))?;
    match lock_dir.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => anyhow::bail!(
            "another gonio serve is using {} (it holds the directory's lock)",
            config.data_dir.display()
        ),
        Err(std::fs::TryLockError::Error(err)) => {
            return Err(err).with_context(|| format!("locking {}", config.data_dir.display()))
        }
    }
    let token = token(&config)?;
    let fault = step_guard::record_faults(&config.data_dir)?;

    let db_path = config.data_dir.join("gonio.sqlite");
    // SQLite gives its journal files the database's mode.
    make_private(&db_path).with_context(|| format!("creating {}", db_path.display()))?;
    let mut api_store =
        Store::open(&db_path).with_context(|| format!("opening {}", db_path.display()))?;
    let boot = api_store.begin_boot()?;
    let devices = devices::open(&config)?;

    let (events, _) = broadcast::channel(256);
    let shared = Arc::new(Shared {
        token,
        boot,
        store: Mutex::new(api_store),
        events,
        changed: Mailbox::default(),
        hardware_wake: Mailbox::default(),
        processing_wake: Mailbox::default(),
        hardware: Mutex::new(HardwareStatus {
            arm: ArmView {
                state: ArmState::Disconnected,
                angle_deg: None,
                homed: false,
                device: devices.arm.path().display().to_string(),
                error: None,
                settings: Vec::new(),
                homes: config.arm.homing != config::HomingMode::Off,
                carousel_travel: None,
            },
            camera: CameraView {
                model: None,
                port: None,
                state: "idle",
                shutter_min_s: UNKNOWN_SHUTTER_RANGE_S.0,
                shutter_max_s: UNKNOWN_SHUTTER_RANGE_S.1,
                error: None,
            },
        }),
        estop: Mutex::new(None),
        arm_angle: Mutex::new(None),
        stops: AtomicU64::new(0),
        halted: AtomicBool::new(false),
        arm_position: Mutex::new(None),
        home_requested: AtomicBool::new(false),
        arm_reconnect: AtomicBool::new(false),
        confirming: tokio::sync::Mutex::new(()),
        timing: devices.timing,
        costs: std::sync::OnceLock::new(),
        queued_times: Default::default(),
        emulators: devices.emulators.clone(),
        mount: devices.mount.clone(),
        storage: storage::Probe {
            dir: config.data_dir.clone(),
            reserve_bytes: config.storage.reserve_bytes,
            emulated: config.emulator.free_space_file.clone(),
            journal_reserve_bytes: config.storage.journal_reserve_bytes,
        },
        config,
    });
    if let Err(err) = shared.storage.keep_journal_reserve() {
        tracing::warn!("the journal's reserve file could not be made: {err}");
    }
    // The publisher first, so that a scan failed for its crashes is noticed.
    view::start_publisher(shared.clone(), &db_path)?;
    step_guard::fail_crash_looping_scans(&shared, &mut lock(&shared.store), fault.as_ref())?;
    lanes::start(shared.clone(), devices, &db_path)?;

    // Stopped on a signal: the steps running are redone at the next start.
    let served = runtime.block_on(serve(shared.clone(), listener, stop));
    drop(lock_dir);
    served
}

async fn serve<S>(
    shared: Arc<Shared>,
    listener: tokio::net::TcpListener,
    stop: S,
) -> anyhow::Result<()>
where
    S: std::future::Future<Output = &'static str> + Send,
{
    let addr = listener.local_addr()?;
    println!("gonio: listening on http://{addr}");
    std::io::stdout().flush()?;
    tracing::info!(
        "data in {}, boot {}, {} hardware",
        shared.config.data_dir.display(),
        shared.boot,
        if shared.emulators.is_some() {
            "emulated"
        } else {
            "real"
        }
    );
    let config = &shared.config;
    let limits = connections::ConnectionLimits {
        header_timeout: Duration::from_secs_f64(config.header_timeout_s),
        idle_timeout: Duration::from_secs_f64(config.idle_timeout_s),
        max_connections: connections::connections_within_fd_limit(
            config.max_connections,
            config.reserved_fds,
        ),
    };
    tracing::info!(
        "at most {} connections, headers within {:?}, idle ones closed after {:?}",
        limits.max_connections,
        limits.header_timeout,
        limits.idle_timeout
    );
    let stop = async {
        let signal = stop.await;
        tracing::info!(
            "{signal}: stopping; a scan in progress resumes at its first unfinished step \
             when gonio serve starts again"
        );
    };
    connections::serve(listener, api::router(shared), limits, stop, SHUTDOWN_GRACE).await;
    Ok(())
}

/// Connections the kernel queues while the server is busy (or at its connection cap:
/// a connection beyond it waits there, costing no descriptor).
const LISTEN_BACKLOG: u32 = 1024;

/// A listener on `addr` with a backlog of [`LISTEN_BACKLOG`] (tokio's `bind` asks for
/// 128, which a burst of connections fills while the server is loaded).
fn listen(addr: std::net::SocketAddr) -> std::io::Result<tokio::net::TcpListener> {
    let socket = if addr.is_ipv4() {
        tokio::net::TcpSocket::new_v4()?
    } else {
        tokio::net::TcpSocket::new_v6()?
    };
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(LISTEN_BACKLOG)
}

/// The bearer token: from the config, else `GONIO_TOKEN`, else the one in DATA/token,
/// else a new random one written there (mode 600). One in DATA/token is printed at every
/// start (the operator reads it there or in this line).
fn token(config: &Config) -> anyhow::Result<String> {
    if let Some(token) = config.token.clone().filter(|t| !t.is_empty()) {
        return Ok(token);
    }
    if let Some(token) = std::env::var("GONIO_TOKEN").ok().filter(|t| !t.is_empty()) {
        return Ok(token);
    }
    let path = config.data_dir.join("token");
    if let Ok(existing) = read_input_to_string(&path, MAX_SMALL_FILE_BYTES) {
        let existing = existing.trim().to_owned();
        if !existing.is_empty() {
            println!("gonio: token {existing} (from {})", path.display());
            return Ok(existing);
        }
    }
    let mut bytes = [0u8; 24];
    getrandom::fill(&mut bytes).map_err(|e| anyhow::anyhow!("random token: {e}"))?;
    let token: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
    write_private(&path, &token)?;
    println!("gonio: token {token} (saved in {})", path.display());
    Ok(token)
}

/// Creates the data directory (the token, the journal, every scan) accessible to its
/// owner only (0700), and makes an existing one so.
fn private_data_dir(dir: &Path) -> anyhow::Result<()> {
    use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
    let context = || format!("creating data directory {}", dir.display());
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .with_context(context)?;
    let mode = std::fs::metadata(dir)
        .with_context(context)?
        .permissions()
        .mode()
        & 0o777;
    if mode != 0o700 {
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))
            .with_context(|| format!("making {} private (mode 700)", dir.display()))?;
        tracing::info!("{}: mode {mode:o} made 700", dir.display());
    }
    Ok(())
}

/// Creates `path` if missing, and makes it readable and writable by its owner only.
fn make_private(path: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
    std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .mode(0o600)
        .open(path)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))
}

/// Writes a file readable by its owner only.
fn write_private(path: &Path, text: &str) -> anyhow::Result<()> {
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut file = options
        .open(path)
        .with_context(|| format!("writing {}", path.display()))?;
    file.write_all(text.as_bytes())?;
    file.sync_all()?;
    Ok(())
}
