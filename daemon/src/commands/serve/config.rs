//! The daemon's TOML configuration. Every key has a default, so an empty file (or no
//! file) runs on emulated hardware with the builtin `gold` scene.
//!
//! ```toml
//! bind = "127.0.0.1:8080"
//! data_dir = "gonio-data"
//! token = "secret"            # else GONIO_TOKEN, else generated into DATA/token
//! max_body_bytes = 65536
//! white_reflectance = 1.0      # of the white strip; emulated scans use the scene's
//! # [setup] = processing's Setup fields, for real hardware (setup.json of each scan)
//!
//! [arm]                        # or: kind = "grbl", path = "/dev/ttyUSB0"
//! kind = "emulator"
//! time_scale = 0.1             # emulated motion 10× faster than real time
//!
//! [camera]                     # or: kind = "gphoto2"
//! kind = "emulator"
//! scene = "gold"               # builtin scene name or path to a scene TOML
//! time_scale = 0.1
//!
//! [limits]                     # soft limits of θL, degrees
//! min_deg = -90.0
//! max_deg = 0.0
//!
//! [retry]                      # device faults: attempts and first backoff (doubles)
//! attempts = 4
//! backoff_ms = 200
//!
//! [emulator]
//! fault_injection = false      # test hook: POST /api/emulator/fault
//! ```

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_processing::geometry::Setup;
use serde::Deserialize;

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
    pub arm: ArmConfig,
    pub camera: CameraConfig,
    pub limits: Limits,
    pub retry: RetryConfig,
    pub emulator: EmulatorConfig,
    /// Reflectance of the white reference strip of the real setup (1 = perfect
    /// reflecting diffuser); emulated scans take the scene's.
    pub white_reflectance: f64,
    /// Geometry of the real setup (written to each scan's setup.json); emulated scans
    /// take the scene's geometry.
    pub setup: Option<Setup>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data_dir: PathBuf::from("gonio-data"),
            token: None,
            max_body_bytes: 64 * 1024,
            arm: ArmConfig::default(),
            camera: CameraConfig::default(),
            limits: Limits::default(),
            retry: RetryConfig::default(),
            emulator: EmulatorConfig::default(),
            white_reflectance: 1.0,
            setup: None,
        }
    }
}

/// The light arm: a GRBL controller on a serial port, or the emulator.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum ArmConfig {
    Grbl {
        /// Serial device, e.g. `/dev/ttyUSB0`.
        path: PathBuf,
    },
    Emulator {
        /// Real seconds per emulated second (1.0 = real time, 0.1 = 10× faster).
        #[serde(default = "default_time_scale")]
        time_scale: f64,
    },
}

impl Default for ArmConfig {
    fn default() -> Self {
        ArmConfig::Emulator {
            time_scale: default_time_scale(),
        }
    }
}

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
        /// Builtin scene name (`gold`, `red`, `blue-green`) or path to a scene TOML.
        #[serde(default = "default_scene")]
        scene: String,
        /// Real seconds per emulated second.
        #[serde(default = "default_time_scale")]
        time_scale: f64,
    },
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig::Emulator {
            scene: default_scene(),
            time_scale: default_time_scale(),
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
    fn default() -> Self {
        Self {
            min_deg: -90.0,
            max_deg: 0.0,
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

/// Emulator-only switches.
#[derive(Debug, Clone, Copy, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Enables `POST /api/emulator/fault`, which injects faults into the emulated
    /// devices. A test hook: leave off in the lab.
    pub fault_injection: bool,
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
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading config {}", path.display()))?;
        Self::from_toml_str(&text).with_context(|| format!("config {}", path.display()))
    }

    /// Parses and checks configuration text.
    pub fn from_toml_str(text: &str) -> anyhow::Result<Self> {
        let config: Config = toml::from_str(text)?;
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
            self.max_body_bytes >= 1024,
            "max_body_bytes must be at least 1024"
        );
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

    fn arm_time_scale(&self) -> Option<f64> {
        match self.arm {
            ArmConfig::Emulator { time_scale } => Some(time_scale),
            ArmConfig::Grbl { .. } => None,
        }
    }

    fn camera_time_scale(&self) -> Option<f64> {
        match self.camera {
            CameraConfig::Emulator { time_scale, .. } => Some(time_scale),
            CameraConfig::Gphoto2 { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_config_runs_on_emulators() {
        let config = Config::from_toml_str("").unwrap();
        assert!(matches!(config.arm, ArmConfig::Emulator { .. }));
        assert!(
            matches!(config.camera, CameraConfig::Emulator { ref scene, .. } if scene == "gold")
        );
        assert_eq!(config.bind.port(), 8080);
    }

    #[test]
    fn example_config_parses_to_the_defaults() {
        let example =
            Config::from_toml_str(include_str!("../../../assets/gonio.example.toml")).unwrap();
        let default = Config::default();
        assert_eq!(example.bind, default.bind);
        assert_eq!(example.data_dir, default.data_dir);
        assert_eq!(example.retry.attempts, default.retry.attempts);
        assert!(matches!(
            (example.arm, default.arm),
            (ArmConfig::Emulator { time_scale: a }, ArmConfig::Emulator { time_scale: b }) if a == b
        ));
    }

    #[test]
    fn grbl_arm_needs_a_path() {
        let err = Config::from_toml_str("[arm]\nkind = \"grbl\"\n").unwrap_err();
        assert!(format!("{err:#}").contains("path"), "{err:#}");
        let config =
            Config::from_toml_str("[arm]\nkind = \"grbl\"\npath = \"/dev/ttyUSB0\"\n").unwrap();
        assert!(matches!(config.arm, ArmConfig::Grbl { .. }));
    }

    #[test]
    fn unknown_keys_and_bad_limits_are_named() {
        let err = Config::from_toml_str("bogus = 1\n").unwrap_err();
        assert!(format!("{err:#}").contains("bogus"), "{err:#}");
        let err = Config::from_toml_str("[limits]\nmin_deg = 0\nmax_deg = -10\n").unwrap_err();
        assert!(format!("{err:#}").contains("min_deg"), "{err:#}");
    }
}
