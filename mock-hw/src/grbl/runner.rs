//! The emulator thread: serves the pty with blocking I/O, resets the board whenever a
//! driver opens the port (DTR), drives the controller in machine time and applies
//! injected and scheduled faults.

use std::io;
use std::path::PathBuf;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError};
use std::time::{Duration, Instant};

use super::config::ScheduledFault;
use super::faults::{Fault, LineFaults};
use super::protocol::Controller;
use super::pty::{self, Pty, Received};
use super::transcript::Transcript;

/// Poll interval while something changes with time (motion, dwell, queued output).
const BUSY_POLL: Duration = Duration::from_millis(1);
/// Poll interval while idle; bounds the latency of injected faults.
const IDLE_POLL: Duration = Duration::from_millis(10);

/// Requests from the [`super::GrblEmulator`] handle, each acknowledged.
pub(crate) enum Command {
    Inject(Fault, SyncSender<()>),
    Reconnect(SyncSender<io::Result<()>>),
    Stop,
}

/// Machine time: real time since start divided by the time scale.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Clock {
    origin: Instant,
    time_scale: f64,
}

impl Clock {
    pub fn new(time_scale: f64) -> Self {
        Clock {
            origin: Instant::now(),
            time_scale,
        }
    }

    /// Machine seconds since start.
    pub fn now(&self) -> f64 {
        self.real_s() / self.time_scale
    }

    /// Real seconds since start.
    pub fn real_s(&self) -> f64 {
        self.origin.elapsed().as_secs_f64()
    }
}

pub(crate) struct Runner {
    pub controller: Controller,
    pub pty: Option<Pty>,
    /// A driver has the port open (DTR high).
    pub port_open: bool,
    pub link: PathBuf,
    pub clock: Clock,
    pub faults: LineFaults,
    /// Faults still to come, earliest first.
    pub schedule: Vec<ScheduledFault>,
    pub transcript: Transcript,
    pub commands: Receiver<Command>,
}

impl Runner {
    pub fn run(mut self) {
        let mut buf = [0u8; 512];
        loop {
            loop {
                match self.commands.try_recv() {
                    Ok(Command::Stop) | Err(TryRecvError::Disconnected) => return,
                    Ok(command) => self.handle(command),
                    Err(TryRecvError::Empty) => break,
                }
            }
            self.apply_schedule();
            let wait = if self.controller.busy() {
                BUSY_POLL
            } else {
                IDLE_POLL
            };
            let read = match &mut self.pty {
                Some(pty) => pty.read(&mut buf, wait).unwrap_or(Received::Closed),
                None => Received::Closed,
            };
            let received = match read {
                Received::Bytes(n) => {
                    if !self.port_open {
                        // Opening the port pulls DTR: the board resets, and what came
                        // with the open is lost in the boot loader.
                        self.port_open = true;
                        self.transcript.record("DTR");
                        self.controller.hard_reset(self.clock.now());
                        0
                    } else {
                        n
                    }
                }
                Received::Closed => {
                    self.port_open = false;
                    // A closed port answers at once: keep the loop from spinning.
                    std::thread::sleep(wait);
                    0
                }
            };
            let now = self.clock.now();
            if !self.faults.silent {
                // Each byte is a checkpoint, so a real-time command after a line acts
                // after that line, as on the serial line.
                for &byte in &buf[..received] {
                    self.controller.receive(byte);
                    self.controller.tick(now);
                }
            }
            self.controller.tick(now);
            self.send_output(now);
        }
    }

    fn send_output(&mut self, now: f64) {
        for line in self.controller.take_output(now) {
            let bytes = self.faults.apply(line);
            // With the port closed the bytes go nowhere, as from a real board.
            if let (Some(bytes), Some(pty), true) = (bytes, &mut self.pty, self.port_open) {
                pty.write(&bytes);
            }
        }
    }

    fn apply_schedule(&mut self) {
        let elapsed = self.clock.real_s();
        while self.schedule.first().is_some_and(|f| f.at_s <= elapsed) {
            let fault = self.schedule.remove(0).fault;
            self.inject(fault, self.clock.now());
        }
    }

    fn handle(&mut self, command: Command) {
        let now = self.clock.now();
        match command {
            Command::Inject(fault, ack) => {
                self.inject(fault, now);
                let _ = ack.send(());
            }
            Command::Reconnect(ack) => {
                let _ = ack.send(self.reconnect(now));
            }
            Command::Stop => {}
        }
    }

    fn inject(&mut self, fault: Fault, now: f64) {
        match fault {
            Fault::Unplug => self.unplug(now),
            // A failed replug leaves the board unplugged, which is what the caller sees.
            Fault::Replug => {
                let _ = self.reconnect(now);
            }
            Fault::Silent => self.faults.silent = true,
            Fault::Responsive => self.faults.silent = false,
            Fault::Garble => self.faults.garble_next = true,
            Fault::Truncate => self.faults.truncate_next = true,
            Fault::AlarmDuringMotion(code) => self.controller.arm_alarm(code),
            Fault::ResetBanner => {
                // A reset also ends a hang.
                self.faults.silent = false;
                self.controller.hard_reset(now);
            }
        }
    }

    fn unplug(&mut self, now: f64) {
        self.pty = None;
        self.port_open = false;
        // Losing power also ends a hang.
        self.faults.silent = false;
        pty::remove_link(&self.link);
        self.controller.power_off(now);
    }

    fn reconnect(&mut self, now: f64) -> io::Result<()> {
        if self.pty.is_some() {
            self.unplug(now);
        }
        self.pty = Some(Pty::open(&self.link)?);
        self.controller.power_on(now);
        Ok(())
    }
}
