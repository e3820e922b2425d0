//! The daemon's TOML configuration. Every key has a default, so an empty file (or no
//! file) runs on emulated hardware with the builtin `gold` scene.
//!
//! ```toml
//! bind = "127.0.0.1:8080"
//! data_dir = "gonio-data"
//! token = "secret"            # else GONIO_TOKEN, else generated into DATA/token
//! max_body_bytes = 65536
//! max_steps_per_request = 10000 # steps one POST may queue (a sweep: all its scans)
//! max_frame_pixels = 100000000  # largest capture decoded (width × height)
//! allowed_hosts = []           # Host names answered besides the bind address, localhost
//! public_read = false          # bound beyond loopback: reads need the token unless true
//! header_timeout_s = 10        # a request's headers must arrive within this
//! idle_timeout_s = 60          # a connection with no request in flight closes after this
//! max_connections = 1024       # open connections (fewer if the fd limit is lower)
//! max_event_streams = 64       # open server-sent event streams
//! reserved_fds = 256           # file descriptors kept for the hardware, database, files
//! white_reflectance = 1.0      # of the white strip where [setup] gives none
//! # [setup] = processing's Setup fields, for real hardware (setup.json of each scan),
//! # white_reflectance among them; emulated scans use the scene's setup
//! # [setup.uncertainty] = setup.json's uncertainty block (standard uncertainties, k = 1)
//!
//! [arm]                        # or: kind = "grbl", path = "/dev/serial/by-id/..."
//! kind = "emulator"
//! time_scale = 0.1             # emulated motion 10× faster than real time
//! # board = "board.toml"       # the emulated board (as `gonio emulate-arm` reads it)
//! axis = "X"                   # what the GRBL board is expected to be:
//! steps_per_deg = 80.0         #   $100
//! max_travel_deg = 180.0       #   $130
//! # max_rate_deg_per_min = 1200.0   $110 (default: any)
//! # accel_deg_per_s2 = 40.0         $120 (default: any)
//! homing = "required"          # $22=1; "off": $22=0, declare the position; "optional"
//! apply_settings = false       # write differing settings instead of refusing the board
//! reply_timeout_s = 2.0        # wait for GRBL's answer to a line (0.1..=60; moves wait longer)
//!
//! [camera]                     # or: kind = "gphoto2"
//! kind = "emulator"
//! scene = "gold"               # builtin scene name or path to a scene TOML
//! sample = "gold"              # the name of the sample `scene` shows, mounted at start
//! samples = {}                 # scenes of other samples by name, e.g. { red = "red.toml" }
//! time_scale = 0.1
//!
//! # [carousel]                 # a sample carousel on a spare axis of the arm's board
//! # axis = "Y"                 #   homed with the arm ($H); the daemon turns it itself
//! # slots = { gold = -10.0, red = -100.0 }   # machine position of each sample
//!
//! [limits]                     # soft limits of θL, degrees
//! min_deg = -90.0
//! max_deg = -1.0
//!
//! [retry]                      # device faults: attempts and first backoff (doubles)
//! attempts = 4
//! backoff_ms = 200
//!
//! [processing]
//! max_backlog = 2              # captured brackets not yet processed before the arm waits
//! timing_probe = true          # measure processing costs at the first start (time left)
//!
//! [storage]
//! reserve_bytes = 67108864     # free space kept for the journal: no step runs below it
//! journal_reserve_bytes = 16777216  # held in DATA/journal.reserve, freed when the disk is full
//!
//! [downloads]
//! max_archives = 4             # archives written at once (another: 503, Retry-After)
//! stall_timeout_s = 30         # a download whose client reads nothing this long is cut
//! max_thumbnail_decodes = 2    # thumbnails decoded at once
//! thumbnail_wait_s = 5         # a thumbnail waits this long for a decode, then 503
//!
//! # [notify]                   # run when a scan waits for its sample, fails, or a sweep ends
//! # command = "echo \"$GONIO_REASON\" | mail -s \"gonio: $GONIO_EVENT\" lab@example.org"
//! # timeout_s = 30             # killed (with its process group) after this
//!
//! [emulator]
//! fault_injection = false      # test hook: POST /api/emulator/fault
//! # free_space_file = "free"   # test hook: the data directory's free bytes, read from it
//! ```

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_drivers::grbl::{ArmAxis, GrblArmConfig};
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_processing::geometry::Setup;
use serde::Deserialize;

use super::downloads_config::DownloadsConfig;
use super::files::is_safe_name;
use super::notify::NotifyConfig;

/// The whole configuration file.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Address the HTTP server listens on.
    pub bind: SocketAddr,
    /// Directory of the database, the token and the scans.
    pub data_dir: PathBuf,
    /// Bearer token of the mutating routes; `None` falls back to `GONIO_TOKEN`, then to a
    /// generated one.
    pub token: Option<String>,
    /// Largest accepted request body, bytes.
    pub max_body_bytes: usize,
    /// Most steps one request may queue (a sweep: all its scans together).
    pub max_steps_per_request: usize,
    /// Largest capture decoded, pixels (width × height as stored in the file).
    pub max_frame_pixels: u64,
    /// Host names (without port) answered besides the bind address and `localhost`.
    pub allowed_hosts: Vec<String>,
    /// When bound beyond loopback: whether reads are open without the token.
    pub public_read: bool,
    /// Seconds a client has to send a request's headers.
    pub header_timeout_s: f64,
    /// Seconds a connection may stay open with no request in flight.
    pub idle_timeout_s: f64,
    /// Most open connections (lowered to fit the file-descriptor limit).
    pub max_connections: usize,
    /// Most open server-sent event streams.
    pub max_event_streams: usize,
    /// File descriptors kept free of connections, for the devices, database and files.
    pub reserved_fds: u64,
    pub arm: ArmConfig,
    #[serde(deserialize_with = "camera_of_any_kind")]
    pub camera: CameraConfig,
    /// A sample carousel on a spare axis of the arm's board, if there is one.
    pub carousel: Option<CarouselConfig>,
    pub limits: Limits,
    pub retry: RetryConfig,
    pub processing: ProcessingConfig,
    pub storage: StorageConfig,
    pub downloads: DownloadsConfig,
    pub emulator: EmulatorConfig,
    /// A command run when a scan starts waiting for its sample, fails, or a sweep ends.
    pub notify: Option<NotifyConfig>,
    /// Reflectance of the white reference strip of the real setup (1 = perfect
    /// reflecting diffuser) where `[setup]` gives none; emulated scans take the scene's.
    pub white_reflectance: f64,
    /// Geometry, white reflectance and standard uncertainties (`[setup.uncertainty]`)
    /// of the real setup (written to each scan's setup.json); emulated scans take the
    /// scene's.
    pub setup: Option<Setup>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data_dir: PathBuf::from("gonio-data"),
            token: None,
            max_body_bytes: 64 * 1024,
            max_steps_per_request: 10_000,
            max_frame_pixels: gonio_processing::capture::DEFAULT_MAX_PIXELS,
            allowed_hosts: Vec::new(),
            public_read: false,
            header_timeout_s: 10.0,
            idle_timeout_s: 60.0,
            max_connections: 1024,
            max_event_streams: 64,
            reserved_fds: 256,
            arm: ArmConfig::default(),
            camera: CameraConfig::default(),
            carousel: None,
            limits: Limits::default(),
            retry: RetryConfig::default(),
            processing: ProcessingConfig::default(),
            storage: StorageConfig::default(),
            downloads: DownloadsConfig::default(),
            emulator: EmulatorConfig::default(),
            notify: None,
            white_reflectance: 1.0,
            setup: None,
        }
    }
}

/// Where the light arm's GRBL controller is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ArmKind {
    /// A board on the serial port at `path`.
    Grbl,
    /// The GRBL emulator, in this process.
    Emulator,
}

/// How the arm gets a known position (docs/ARCHITECTURE.md, "GRBL arm").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HomingMode {
    /// `$22=1`: the homing cycle references the arm.
    Required,
    /// Homing if the board has it, else a declared position.
    Optional,
    /// `$22=0`: the operator declares the position (`POST /api/arm/position`).
    Off,
}

/// The light arm: the GRBL controller, real or emulated, and what the driver expects of
/// it. The emulated board is set up as these keys expect unless `board` names a file.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ArmConfig {
    pub kind: ArmKind,
    /// Serial device of a real board, e.g. `/dev/serial/by-id/usb-…-if00-port0`.
    pub path: Option<PathBuf>,
    /// Emulator: real seconds per emulated second (1.0 = real time, 0.1 = 10× faster).
    pub time_scale: f64,
    /// Emulator: the board's own configuration (the file `gonio emulate-arm --config`
    /// reads), e.g. a stock board; its `time_scale` is replaced by the one above.
    pub board: Option<PathBuf>,
    /// The controller axis the arm is on: `X`, `Y` or `Z`.
    pub axis: String,
    /// Expected `$100` (steps per degree) and `$130` (travel, degrees).
    pub steps_per_deg: f64,
    pub max_travel_deg: f64,
    /// Expected `$110` (degrees/min) and `$120` (degrees/s²); unset: any positive.
    pub max_rate_deg_per_min: Option<f64>,
    pub accel_deg_per_s2: Option<f64>,
    pub homing: HomingMode,
    /// Write the settings that differ (`$N=`) and read them back, instead of refusing.
    pub apply_settings: bool,
    /// How long the driver waits for the answer to a line that does not wait for
    /// motion, seconds (moves and homing get their own, longer, waits).
    pub reply_timeout_s: f64,
}

impl Default for ArmConfig {
    fn default() -> Self {
        ArmConfig {
            kind: ArmKind::Emulator,
            path: None,
            time_scale: default_time_scale(),
            board: None,
            axis: "X".to_owned(),
            steps_per_deg: 80.0,
            max_travel_deg: 180.0,
            max_rate_deg_per_min: None,
            accel_deg_per_s2: None,
            homing: HomingMode::Required,
            apply_settings: false,
            // The driver's own default.
            reply_timeout_s: GrblArmConfig::default().reply_timeout.as_secs_f64(),
        }
    }
}

/// The bounds of `[arm] reply_timeout_s`, seconds.
const REPLY_TIMEOUT_RANGE_S: std::ops::RangeInclusive<f64> = 0.1..=60.0;

/// The camera: a gphoto2 body, or the emulator rendering a scene.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum CameraConfig {
    Gphoto2 {
        /// ISO set before each exposure.
        #[serde(default = "default_iso")]
        iso: u32,
        /// Camera model to pick when several are connected (libgphoto2 name).
        model: Option<String>,
        /// libgphoto2 port, e.g. `usb:001,004`.
        port: Option<String>,
    },
    Emulator {
        /// Builtin scene name (`gold`, `red`, `blue-green`, `opal`) or path to a scene
        /// TOML: the scene of the sample mounted when the daemon starts.
        #[serde(default = "default_scene")]
        scene: String,
        /// The name of the sample `scene` shows.
        #[serde(default = "default_scene")]
        sample: String,
        /// Scenes (builtin name or path) of the other samples the emulated instrument
        /// holds, by sample name; a builtin scene's name is a sample of its own.
        #[serde(default)]
        samples: BTreeMap<String, String>,
        /// Real seconds per emulated second.
        #[serde(default = "default_time_scale")]
        time_scale: f64,
    },
}

/// A `[camera]` table; without `kind`, the emulator's (every key is optional).
fn camera_of_any_kind<'de, D: serde::Deserializer<'de>>(d: D) -> Result<CameraConfig, D::Error> {
    let mut table = toml::Table::deserialize(d)?;
    table
        .entry("kind")
        .or_insert_with(|| toml::Value::String("emulator".to_owned()));
    toml::Value::Table(table)
        .try_into()
        .map_err(|e: toml::de::Error| serde::de::Error::custom(e.message()))
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig::Emulator {
            scene: default_scene(),
            sample: default_scene(),
            samples: BTreeMap::new(),
            time_scale: default_time_scale(),
        }
    }
}

/// A sample carousel on a spare axis of the arm's GRBL board: the daemon turns it to a
/// scan's sample itself instead of waiting for the operator (server/src/lanes/hardware.md,
/// "Sample changes").
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CarouselConfig {
    /// The controller axis it is on: `X`, `Y` or `Z`, not the arm's.
    pub axis: String,
    /// Each sample's slot: the machine position of the axis (its units, degrees for a
    /// turntable; on [−`$13N`, 0] after homing) that brings it before the camera.
    pub slots: BTreeMap<String, f64>,
}

impl CarouselConfig {
    /// The axis as the driver names it.
    pub fn axis(&self) -> ArmAxis {
        ArmAxis::from_letter(&self.axis).unwrap_or(ArmAxis::Y)
    }

    /// The slot of `sample`, if the carousel holds it.
    pub fn slot(&self, sample: &str) -> Option<f64> {
        self.slots.get(sample).copied()
    }

    fn check(&self, arm: &ArmConfig) -> anyhow::Result<()> {
        let axis = ArmAxis::from_letter(&self.axis)
            .with_context(|| format!("carousel.axis must be X, Y or Z, got {:?}", self.axis))?;
        anyhow::ensure!(
            axis != arm.axis(),
            "carousel.axis {} is the arm's axis",
            self.axis
        );
        anyhow::ensure!(
            arm.homing == HomingMode::Required,
            "carousel: needs arm.homing = \"required\" (the homing cycle references it)"
        );
        anyhow::ensure!(!self.slots.is_empty(), "carousel.slots is empty");
        for (sample, slot) in &self.slots {
            anyhow::ensure!(
                is_safe_name(sample),
                "carousel.slots: {sample:?} is not a sample name \
                 (1-64 letters, digits, '-', '_' or '.', not starting with '.')"
            );
            anyhow::ensure!(
                slot.is_finite() && *slot <= 0.0,
                "carousel.slots.{sample} must be a machine position at or below 0, got {slot}"
            );
        }
        Ok(())
    }

    /// Each slot beyond an axis travel of `travel` (positions on [−travel, 0]): its
    /// sample, and why it cannot be reached.
    pub fn beyond_travel(&self, travel: f64) -> Vec<(String, String)> {
        let axis = self.axis();
        self.slots
            .iter()
            .filter(|(_, slot)| **slot < -travel)
            .map(|(sample, slot)| {
                let why = format!(
                    "carousel.slots.{sample} = {slot} is beyond the board's travel of the \
                     {} axis (${}: positions on [-{travel}, 0])",
                    axis.letter(),
                    130 + axis.index()
                );
                (sample.clone(), why)
            })
            .collect()
    }

    /// Refuses a slot beyond an axis travel of `travel`.
    pub fn check_travel(&self, travel: f64) -> anyhow::Result<()> {
        match self.beyond_travel(travel).into_iter().next() {
            Some((_, why)) => anyhow::bail!("{why}"),
            None => Ok(()),
        }
    }
}

/// Soft limits of the light angle θL, degrees.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Limits {
    pub min_deg: f64,
    pub max_deg: f64,
}

impl Default for Limits {
    /// A margin inside the arm's travel: off the home switch at 0.
    fn default() -> Self {
        Self {
            min_deg: -90.0,
            max_deg: -1.0,
        }
    }
}

/// Bounded retries of transient device faults: `attempts` tries in all, waiting
/// `backoff_ms` after the first failure and twice as long after each further one.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RetryConfig {
    pub attempts: u32,
    pub backoff_ms: u64,
}

impl Default for RetryConfig {
    fn default() -> Self {
        Self {
            attempts: 4,
            backoff_ms: 200,
        }
    }
}

/// The processing lane.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProcessingConfig {
    /// Captured brackets waiting for processing before the hardware lane waits to
    /// start the next one (back-pressure).
    pub max_backlog: usize,
    /// Whether the daemon measures what processing costs on this machine at its first
    /// start on a data directory, for the time left (else the stated defaults hold
    /// until scans measure their own steps).
    pub timing_probe: bool,
}

impl Default for ProcessingConfig {
    fn default() -> Self {
        Self {
            max_backlog: 2,
            timing_probe: true,
        }
    }
}

/// The data directory's disk.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StorageConfig {
    /// Free space kept for the journal, bytes: a step runs only while its output fits
    /// above it (else its scan waits for space).
    pub reserve_bytes: u64,
    /// Space held for the journal in `DATA/journal.reserve`, bytes, against other
    /// processes that fill the disk: deleted when the journal finds the disk full, made
    /// again once it fits above `reserve_bytes`; 0 for none.
    pub journal_reserve_bytes: u64,
}

impl Default for StorageConfig {
    fn default() -> Self {
        Self {
            // The journal (SQLite and its write-ahead log) and the daemon's small files.
            reserve_bytes: 64 << 20,
            // Thousands of journal transactions.
            journal_reserve_bytes: 16 << 20,
        }
    }
}

/// Emulator-only switches.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Enables `POST /api/emulator/fault`, which injects faults into the emulated
    /// devices. A test hook: leave off in the lab.
    pub fault_injection: bool,
    /// A file holding the data directory's free space in bytes, read instead of the
    /// filesystem's: a test hook emulating a disk that fills up and empties.
    pub free_space_file: Option<PathBuf>,
}

fn default_time_scale() -> f64 {
    0.1
}

fn default_scene() -> String {
    "gold".to_owned()
}

fn default_iso() -> u32 {
    100
}

impl Config {
    /// Reads and checks a configuration file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = read_input_to_string(path, MAX_SMALL_FILE_BYTES)
            .with_context(|| format!("reading config {}", path.display()))?;
        Self::from_toml_str(&text).with_context(|| format!("config {}", path.display()))
    }

    /// Parses and checks configuration text.
    pub fn from_toml_str(text: &str) -> anyhow::Result<Self> {
        let config: Config = toml::from_str(text)
            .map_err(|e| anyhow::anyhow!(gonio_mock_hw::toml_error::one_line(text, &e)))?;
        config.check()?;
        Ok(config)
    }

    fn check(&self) -> anyhow::Result<()> {
        let Limits { min_deg, max_deg } = self.limits;
        anyhow::ensure!(
            min_deg.is_finite() && max_deg.is_finite() && min_deg < max_deg,
            "limits: min_deg ({min_deg}) must be below max_deg ({max_deg})"
        );
        anyhow::ensure!(
            self.white_reflectance.is_finite() && self.white_reflectance > 0.0,
            "white_reflectance must be positive, got {}",
            self.white_reflectance
        );
        anyhow::ensure!(
            self.retry.attempts >= 1,
            "retry.attempts must be at least 1"
        );
        anyhow::ensure!(
            self.processing.max_backlog >= 1,
            "processing.max_backlog must be at least 1"
        );
        anyhow::ensure!(
            self.max_body_bytes >= 1024,
            "max_body_bytes must be at least 1024"
        );
        if let Some(setup) = self.setup() {
            setup
                .validate()
                .map_err(|e| anyhow::anyhow!("[setup]: {e}"))?;
        }
        self.arm.check()?;
        self.downloads.check()?;
        if let Some(notify) = &self.notify {
            notify.check()?;
        }
        if let Some(carousel) = &self.carousel {
            carousel.check(&self.arm)?;
        }
        for (key, value) in [
            ("max_steps_per_request", self.max_steps_per_request as u64),
            ("max_frame_pixels", self.max_frame_pixels),
            ("max_connections", self.max_connections as u64),
            ("max_event_streams", self.max_event_streams as u64),
        ] {
            anyhow::ensure!(value >= 1, "{key} must be at least 1");
        }
        for (key, value) in [
            ("header_timeout_s", self.header_timeout_s),
            ("idle_timeout_s", self.idle_timeout_s),
        ] {
            anyhow::ensure!(
                value.is_finite() && value > 0.0 && value <= 86_400.0,
                "{key} must be a positive number of seconds (at most a day), got {value}"
            );
        }
        if let Some(bad) = self
            .allowed_hosts
            .iter()
            .find(|h| h.is_empty() || h.contains(|c: char| c.is_whitespace() || c == '/'))
        {
            anyhow::bail!("allowed_hosts: {bad:?} is not a host name");
        }
        for (what, scale) in [
            ("arm.time_scale", self.arm_time_scale()),
            ("camera.time_scale", self.camera_time_scale()),
        ] {
            if let Some(scale) = scale {
                anyhow::ensure!(
                    scale.is_finite() && scale > 0.0,
                    "{what} must be positive, got {scale}"
                );
            }
        }
        Ok(())
    }

    /// The real setup of `[setup]`, its white reflectance from the top-level key when it
    /// gives none.
    pub fn setup(&self) -> Option<Setup> {
        self.setup.clone().map(|mut setup| {
            setup
                .white_reflectance
                .get_or_insert(self.white_reflectance);
            setup
        })
    }

    fn arm_time_scale(&self) -> Option<f64> {
        (self.arm.kind == ArmKind::Emulator).then_some(self.arm.time_scale)
    }

    fn camera_time_scale(&self) -> Option<f64> {
        match self.camera {
            CameraConfig::Emulator { time_scale, .. } => Some(time_scale),
            CameraConfig::Gphoto2 { .. } => None,
        }
    }
}

impl ArmConfig {
    fn check(&self) -> anyhow::Result<()> {
        match (self.kind, &self.path, &self.board) {
            (ArmKind::Grbl, None, _) => anyhow::bail!("arm: kind \"grbl\" needs path"),
            (ArmKind::Grbl, _, Some(_)) => {
                anyhow::bail!("arm: board is for kind \"emulator\", not \"grbl\"")
            }
            _ => {}
        }
        anyhow::ensure!(
            ArmAxis::from_letter(&self.axis).is_some(),
            "arm.axis must be X, Y or Z, got {:?}",
            self.axis
        );
        for (what, value) in [
            ("arm.steps_per_deg", Some(self.steps_per_deg)),
            ("arm.max_travel_deg", Some(self.max_travel_deg)),
            ("arm.max_rate_deg_per_min", self.max_rate_deg_per_min),
            ("arm.accel_deg_per_s2", self.accel_deg_per_s2),
        ] {
            if let Some(value) = value {
                anyhow::ensure!(
                    value.is_finite() && value > 0.0,
                    "{what} must be positive, got {value}"
                );
            }
        }
        anyhow::ensure!(
            REPLY_TIMEOUT_RANGE_S.contains(&self.reply_timeout_s),
            "arm.reply_timeout_s must be {} to {} seconds, got {}",
            REPLY_TIMEOUT_RANGE_S.start(),
            REPLY_TIMEOUT_RANGE_S.end(),
            self.reply_timeout_s
        );
        Ok(())
    }

    /// How long the driver waits for the answer to a line.
    pub fn reply_timeout(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.reply_timeout_s)
    }

    /// The axis as the driver names it.
    pub fn axis(&self) -> ArmAxis {
        ArmAxis::from_letter(&self.axis).unwrap_or(ArmAxis::X)
    }
}

#[cfg(test)]
mod tests;
