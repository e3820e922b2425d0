//! An emulated GRBL 1.1h controller driving the light arm, served on a pseudo-terminal.
//!
//! A driver opens [`GrblEmulator::device_path`] with `serialport` at 115200 8N1 exactly
//! as it opens `/dev/ttyUSB0`. The path is a symlink that survives
//! [`Fault::Unplug`] + [`GrblEmulator::reconnect`] (like `/dev/serial/by-id/...`).
//!
//! Machine X is the arm angle in degrees. The homing switch sits at the positive end,
//! physically θ = 0: after `$H`, MPos X = −`$27` (0 with the default pull-off) and soft
//! limits allow X in [−`$130`, 0]. Until the arm is homed, MPos counts from wherever the
//! board powered up, so it differs from the physical angle, which is what the shared
//! [`World`] holds. Motion follows trapezoidal velocity profiles (blocks run stop to
//! stop) in machine time, which runs `1 / time_scale` times faster than real time.
//! When the steppers stop dead (soft reset while moving, a limit alarm, power loss) the
//! arm coasts on and slips steps, so MPos is off until the next `$H`.
//!
//! What the firmware does and this emulator does not: arcs and other G-codes outside
//! G0 G1 G4 G17 G20 G21 G53 G54 G90 G91 G94 M3 M4 M5 M8 M9 (`error:20`), check mode
//! (`$C`), sleep (`$SLP`), startup blocks (`$Nx=`), overrides and the safety door, and
//! junction blending between consecutive blocks. Jogging (`$J=`, jog cancel 0x85) is
//! emulated.

mod faults;
mod gcode;
mod motion;
mod protocol;
mod pty;
mod runner;
mod settings;

pub use faults::Fault;

use std::io;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Sender};
use std::thread::JoinHandle;

use crate::world::World;
use faults::LineFaults;
use protocol::Controller;
use runner::{Clock, Command, Runner};

/// Emulator settings. The arm axis (X) uses degrees as GRBL's machine unit.
#[derive(Debug, Clone, PartialEq)]
pub struct GrblConfig {
    /// Real seconds per machine second: 1.0 = real time, 0.01 = 100× faster.
    pub time_scale: f64,
    /// `$100`, steps per degree.
    pub steps_per_deg: f64,
    /// `$110`, degrees per minute.
    pub max_rate_deg_per_min: f64,
    /// `$120`, degrees per second².
    pub accel_deg_per_s2: f64,
    /// `$130`, degrees: soft limits allow X in [−max_travel, 0].
    pub max_travel_deg: f64,
    /// `$22`: boot locked in Alarm until `$H` or `$X`.
    pub homing_enabled: bool,
    /// `$20` (needs homing enabled, as in the firmware).
    pub soft_limits: bool,
    /// `$25`, homing seek rate, degrees per minute.
    pub homing_seek_deg_per_min: f64,
    /// `$24`, homing locate feed rate, degrees per minute.
    pub homing_feed_deg_per_min: f64,
    /// `$27`, pull-off after homing, degrees (MPos X after `$H` is minus this).
    pub homing_pulloff_deg: f64,
    /// Machine seconds from power-up or hardware reset to the banner.
    pub boot_delay_s: f64,
    /// Status reports also carry the stock 1.1h build's optional fields, as the firmware
    /// prints them: `Pn:X` while the arm presses the home switch, `WCO:` on every 10th
    /// report (30th while busy) and `Ov:` (with `A:`) one report later. When false,
    /// reports are `<State|MPos:x,y,z|FS:feed,spindle>` only.
    pub status_extras: bool,
}

impl Default for GrblConfig {
    fn default() -> Self {
        GrblConfig {
            time_scale: 1.0,
            steps_per_deg: 80.0,
            max_rate_deg_per_min: 1200.0,
            accel_deg_per_s2: 40.0,
            max_travel_deg: 180.0,
            homing_enabled: true,
            soft_limits: true,
            homing_seek_deg_per_min: 600.0,
            homing_feed_deg_per_min: 100.0,
            homing_pulloff_deg: 0.0,
            boot_delay_s: 0.5,
            status_extras: false,
        }
    }
}

/// Duration in real seconds of a move of `distance_deg` from rest to rest under a
/// trapezoidal velocity profile (triangular when the cruise rate is not reached).
/// Rates and accelerations below 1e-9 are taken as 1e-9.
pub fn move_duration_s(distance_deg: f64, max_rate_deg_per_min: f64, accel_deg_per_s2: f64) -> f64 {
    motion::Profile::new(
        distance_deg.abs(),
        0.0,
        max_rate_deg_per_min / 60.0,
        accel_deg_per_s2,
    )
    .duration()
}

/// A running emulated controller. Dropping it stops its thread and removes the device.
#[derive(Debug)]
pub struct GrblEmulator {
    link: PathBuf,
    commands: Sender<Command>,
    thread: Option<JoinHandle<()>>,
    // Declared last: the directory goes after the thread has stopped using it.
    _link_dir: tempfile::TempDir,
}

impl GrblEmulator {
    /// Power up a controller on a new pty. The arm starts at `world`'s angle, which the
    /// emulator updates continuously as the arm moves.
    pub fn start(config: GrblConfig, world: World) -> io::Result<GrblEmulator> {
        if !(config.time_scale.is_finite() && config.time_scale > 0.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("time_scale must be positive, got {}", config.time_scale),
            ));
        }
        let link_dir = tempfile::Builder::new().prefix("gonio-grbl-").tempdir()?;
        let link = link_dir.path().join("ttyGRBL");
        let pty = pty::Pty::open(&link)?;
        let clock = Clock::new(config.time_scale);
        let controller = Controller::new(&config, world, clock.now());
        let (commands, receiver) = mpsc::channel();
        let runner = Runner {
            controller,
            pty: Some(pty),
            link: link.clone(),
            clock,
            faults: LineFaults::default(),
            commands: receiver,
        };
        let thread = std::thread::Builder::new()
            .name("grbl-emulator".into())
            .spawn(move || runner.run())?;
        Ok(GrblEmulator {
            link,
            commands,
            thread: Some(thread),
            _link_dir: link_dir,
        })
    }

    /// The stable device path a driver opens (a symlink to the current pty slave).
    pub fn device_path(&self) -> &Path {
        &self.link
    }

    /// Inject a fault; it has taken effect when this returns.
    pub fn inject(&self, fault: Fault) {
        let (ack, done) = mpsc::sync_channel(1);
        if self.commands.send(Command::Inject(fault, ack)).is_ok() {
            // A stopped emulator has nothing left to fault.
            let _ = done.recv();
        }
    }

    /// Plug the controller back in (after [`Fault::Unplug`], or as a replug): a new pty
    /// behind the same [`Self::device_path`], and the board boots again.
    pub fn reconnect(&self) -> io::Result<()> {
        let (ack, done) = mpsc::sync_channel(1);
        self.commands
            .send(Command::Reconnect(ack))
            .map_err(|_| io::Error::other("GRBL emulator thread has stopped"))?;
        done.recv()
            .map_err(|_| io::Error::other("GRBL emulator thread has stopped"))?
    }
}

impl Drop for GrblEmulator {
    fn drop(&mut self) {
        let _ = self.commands.send(Command::Stop);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
