//! An emulated GRBL 1.1h controller driving the light arm, served on a pseudo-terminal,
//! answering byte for byte as the firmware does (gnea/grbl 1.1h.20190830, stock build).
//!
//! A driver opens [`GrblEmulator::device_path`] with `serialport` at 115200 8N1 exactly
//! as it opens `/dev/ttyUSB0`. The path is a symlink that survives
//! [`Fault::Unplug`] + [`GrblEmulator::reconnect`] (like `/dev/serial/by-id/...`).
//! Opening the port resets the board as DTR resets an Arduino-based controller: the
//! banner arrives on every open, and the machine position restarts at zero.
//!
//! The arm is one axis (X unless [`GrblConfig::arm_axis`] says otherwise), in degrees.
//! Its homing switch sits at the positive end, physically θ = 0: after `$H` its MPos is
//! −`$27` and soft limits allow [−`$130`, 0]. Until it is homed, MPos counts from
//! wherever the board powered up, so it differs from the physical angle, which is what
//! the shared [`World`] holds. The other two axes carry nothing; their switches sit
//! [`GrblConfig::idle_axis_switch`] above where they power up. Motion follows
//! trapezoidal velocity profiles (blocks run stop to stop) in machine time, which runs
//! `1 / time_scale` times faster than real time. When the steppers stop dead (reset
//! while moving, a limit alarm, power loss) the arm coasts on and slips steps, so MPos
//! is off until the next `$H`.
//!
//! The modules form a line, each using only those before it: `faults`, `config`,
//! `report` (what the firmware prints), `settings`, `gcode`, `motion`, `homing`,
//! `serial` (input), `transcript`, `protocol` (the state machine), `pty`, `runner`
//! (the thread).
//!
//! What the firmware does and this emulator does not: arcs, probing and G-codes outside
//! G0 G1 G4 G10 G17 G20 G21 G53 G54–G59 G90 G91 G92 G92.1 G94 M3 M4 M5 M8 M9
//! (`error:20`), check mode (`$C`), sleep (`$SLP`), startup blocks (`$Nx=`), overrides,
//! the safety door and the control pins, and junction blending between consecutive
//! blocks; a homing phase moves every axis of its cycle in one block rather than
//! stopping each at its switch. Jogging (`$J=`, jog cancel 0x85) is emulated.
#![doc = include_str!("grbl.md")]

mod config;
mod faults;
mod gcode;
mod homing;
mod motion;
mod protocol;
mod pty;
mod report;
mod runner;
mod serial;
mod settings;
mod transcript;

pub use config::{Axis, AxisSet, ConfigError, GrblConfig, ScheduledFault};
pub use faults::Fault;

use std::io;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Sender};
use std::thread::JoinHandle;

use crate::world::World;
use faults::LineFaults;
use protocol::Controller;
use runner::{Clock, Command, Runner};
use transcript::Transcript;

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

/// The factory max travel (`$13N`, the axis' units) of `axis` on a board set up as
/// `config` says: soft limits and the homed positions lie on [−travel, 0].
pub fn axis_travel(config: &GrblConfig, axis: Axis) -> f64 {
    settings::Settings::from_config(config).axes[axis.index()].max_travel
}

/// A running emulated controller. Dropping it stops its thread and removes the device.
#[derive(Debug)]
pub struct GrblEmulator {
    link: PathBuf,
    commands: Sender<Command>,
    transcript: Transcript,
    thread: Option<JoinHandle<()>>,
    // Declared last: the directory goes after the thread has stopped using it.
    link_dir: Option<tempfile::TempDir>,
}

impl GrblEmulator {
    /// Power up a controller on a new pty, linked from a new temporary directory. The
    /// arm starts at `world`'s angle, which the emulator updates continuously as the
    /// arm moves.
    pub fn start(config: GrblConfig, world: World) -> io::Result<GrblEmulator> {
        let link_dir = tempfile::Builder::new().prefix("gonio-grbl-").tempdir()?;
        let link = link_dir.path().join("ttyGRBL");
        Self::spawn(config, world, link, Some(link_dir))
    }

    /// Like [`GrblEmulator::start`], with the device link at `link` (its directory must
    /// exist; an existing symlink there is replaced, any other file is left alone and
    /// refused). The link is removed when the emulator is dropped.
    pub fn start_at(config: GrblConfig, world: World, link: &Path) -> io::Result<GrblEmulator> {
        Self::spawn(config, world, link.to_owned(), None)
    }

    fn spawn(
        config: GrblConfig,
        world: World,
        link: PathBuf,
        link_dir: Option<tempfile::TempDir>,
    ) -> io::Result<GrblEmulator> {
        let problems = config.problems();
        if !problems.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                problems.join("; "),
            ));
        }
        let pty = pty::Pty::open(&link)?;
        let clock = Clock::new(config.time_scale);
        let transcript = Transcript::default();
        let controller = Controller::new(&config, world, transcript.clone(), clock.now());
        let (commands, receiver) = mpsc::channel();
        let mut schedule = config.faults.clone();
        schedule.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        let runner = Runner {
            controller,
            pty: Some(pty),
            port_open: false,
            link: link.clone(),
            clock,
            faults: LineFaults::default(),
            schedule,
            transcript: transcript.clone(),
            commands: receiver,
        };
        let thread = std::thread::Builder::new()
            .name("grbl-emulator".into())
            .spawn(move || runner.run())?;
        Ok(GrblEmulator {
            link,
            commands,
            transcript,
            thread: Some(thread),
            link_dir,
        })
    }

    /// The stable device path a driver opens (a symlink to the current pty slave).
    pub fn device_path(&self) -> &Path {
        &self.link
    }

    /// What the firmware was asked so far, oldest first: each line its main loop
    /// executed (upper-cased, spaces and comments stripped), `^X` for a soft reset,
    /// `DTR` for the reset of opening the port.
    pub fn transcript(&self) -> Vec<String> {
        self.transcript.entries()
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
        if self.link_dir.is_none() {
            // A link the caller placed: the device is gone.
            pty::remove_link(&self.link);
        }
    }
}
