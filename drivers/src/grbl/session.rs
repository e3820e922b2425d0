//! One conversation with the controller: at most one line in flight, every `ok` or
//! `error:N` paired with the line it answers (a late answer still pairs with its own
//! line), alarms and resets recognised as GRBL 1.1h sends them, and motion waited for
//! while status reports show it progressing.
//!
//! What GRBL does that shapes this:
//! - ALARM:1 (hard limit) and ALARM:2 (soft limit) lock the controller: it answers
//!   nothing, not even `?`, until a soft reset; then the line that was executing gets
//!   its `ok`, and the banner follows. The session sends the reset itself.
//! - Any other alarm resets the controller on its own: the executing line's `ok`, then
//!   the banner (`ALARM:8\r\nok\r\n\r\nGrbl 1.1h …`).
//! - A banner without an alarm is a reset (DTR, power, a soft reset at rest): the line in
//!   flight, if any, is gone.

use std::time::{Duration, Instant};

use super::codes::{alarm_meaning, error_meaning, homing_advice, is_homing_alarm};
use super::link::{Link, LINE_GRACE};
use super::protocol::{parse_line, Line, StatusReport};
use crate::{DeviceError, LiveAngle};

/// GRBL's soft-reset real-time byte (Ctrl-X).
pub const SOFT_RESET: u8 = 0x18;
/// GRBL's feed-hold real-time byte.
pub const FEED_HOLD: u8 = b'!';
/// GRBL's status-report real-time byte.
const STATUS_QUERY: u8 = b'?';
/// The longest answer GRBL sends (`error:38`): a garbled line longer than this is not
/// the answer to a line.
const MAX_ANSWER_LEN: usize = 8;

/// How long the answer to a line may take.
#[derive(Debug, Clone, Copy)]
pub enum Patience {
    /// A command that does not wait for motion.
    Reply(Duration),
    /// A line answered when motion ends (`G4 P0`): expected within `expected`; past
    /// that, it is alive while `?` (sent every `poll`) shows it progressing, for at
    /// most `stall` without progress and `cap` in all.
    Motion {
        expected: Duration,
        cap: Duration,
        poll: Duration,
        stall: Duration,
    },
}

/// What happened on the line besides answers, since it was last taken.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Seen {
    /// The controller greeted (it reset).
    pub reset: bool,
    /// The last `ALARM:N`.
    pub alarm: Option<u32>,
}

/// Where the status reports of a move publish the arm's angle as they arrive: the live
/// angle, the arm's axis, and the work offset to use while no report has given one.
#[derive(Debug, Clone)]
pub struct AngleWatch {
    pub angle: LiveAngle,
    pub axis: usize,
    pub known_wco: Option<[f64; 3]>,
}

/// The conversation state.
pub struct Session {
    link: Option<Link>,
    /// A line sent whose answer has not arrived: nothing else is sent until it does or
    /// the controller is reset.
    in_flight: Option<String>,
    /// The work coordinate offset of the last report that carried one (reset clears it).
    wco: Option<[f64; 3]>,
    seen: Seen,
    banner_timeout: Duration,
    /// Publishes the angle from the reports, while a move is watched.
    watch: Option<AngleWatch>,
}

impl Session {
    pub fn new(banner_timeout: Duration) -> Self {
        Session {
            link: None,
            in_flight: None,
            wco: None,
            seen: Seen::default(),
            banner_timeout,
            watch: None,
        }
    }

    /// Publishes the arm's angle from every status report until [`Session::unwatch`].
    pub fn watch(&mut self, watch: AngleWatch) {
        self.watch = Some(watch);
    }

    pub fn unwatch(&mut self) {
        self.watch = None;
    }

    pub fn connected(&self) -> bool {
        self.link.is_some()
    }

    pub fn attach(&mut self, link: Link) {
        self.link = Some(link);
        self.in_flight = None;
        self.wco = None;
    }

    /// Forget the line (the device went away).
    pub fn detach(&mut self) {
        self.link = None;
        self.in_flight = None;
        self.wco = None;
    }

    /// The line whose answer is still awaited, if any.
    pub fn in_flight(&self) -> Option<&str> {
        self.in_flight.as_deref()
    }

    /// The last work coordinate offset reported since the last reset.
    pub fn wco(&self) -> Option<[f64; 3]> {
        self.wco
    }

    /// What was seen since the last call.
    pub fn take_seen(&mut self) -> Seen {
        std::mem::take(&mut self.seen)
    }

    fn link(&mut self) -> Result<&mut Link, DeviceError> {
        self.link
            .as_mut()
            .ok_or_else(|| DeviceError::Disconnected("arm controller not connected".into()))
    }

    /// The device path, for messages.
    pub fn path(&self) -> String {
        self.link
            .as_ref()
            .map_or_else(String::new, |l| l.path().display().to_string())
    }

    fn io<T>(&mut self, result: Result<T, DeviceError>) -> Result<T, DeviceError> {
        if matches!(result, Err(DeviceError::Disconnected(_))) {
            self.detach();
        }
        result
    }

    /// Send a real-time byte (`!`, `?`, Ctrl-X): never a line, never answered `ok`.
    pub fn realtime(&mut self, byte: u8) -> Result<(), DeviceError> {
        let result = self.link()?.write(&[byte]);
        self.io(result)
    }

    fn read_line(&mut self, deadline: Instant) -> Result<Option<Line>, DeviceError> {
        let result = self.link()?.read_line(deadline);
        let line = self.io(result)?.map(|text| parse_line(&text));
        if let Some(line) = &line {
            self.note(line);
        }
        Ok(line)
    }

    /// Record what a line says about the controller; answers pair with the line in
    /// flight, a banner ends it.
    fn note(&mut self, line: &Line) {
        match line {
            Line::Ok | Line::Error(_) => self.in_flight = None,
            Line::Banner(_) => {
                self.in_flight = None;
                self.wco = None;
                self.seen.reset = true;
            }
            Line::Alarm(code) => self.seen.alarm = Some(*code),
            Line::Status(report) => {
                if let Some(wco) = report.wco {
                    self.wco = Some(wco);
                }
                if let Some(watch) = &self.watch {
                    let known = self.wco.or(watch.known_wco);
                    if let Some(angle) = report.work(watch.axis, known) {
                        watch.angle.set(angle);
                    }
                }
            }
            Line::Feedback(_) | Line::Setting(..) | Line::Garbled(_) => {}
        }
    }

    /// Read what arrived unasked: late answers (paired), banners, alarms, noise.
    pub fn drain(&mut self) -> Result<(), DeviceError> {
        let now = Instant::now();
        while self.read_line(now)?.is_some() {}
        Ok(())
    }

    /// Wait up to `timeout` for the banner, then until the line has been quiet for a
    /// moment (a reset can leave a second banner in flight). Returns whether it came.
    pub fn await_banner(&mut self, timeout: Duration) -> Result<bool, DeviceError> {
        let deadline = Instant::now() + timeout;
        while let Some(line) = self.read_line(deadline)? {
            if matches!(line, Line::Banner(_)) {
                while self.read_line(Instant::now() + LINE_GRACE)?.is_some() {}
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// After `ALARM:code`: reset a locked controller, collect the executing line's
    /// answer and the banner; the typed error to return.
    fn on_alarm(&mut self, code: u32) -> Result<DeviceError, DeviceError> {
        if code == 1 || code == 2 {
            // Locked: GRBL answers nothing, not even `?`, until reset.
            self.realtime(SOFT_RESET)?;
        }
        self.await_banner(self.banner_timeout)?;
        Ok(if is_homing_alarm(code) {
            DeviceError::HomingFailed {
                code,
                meaning: alarm_meaning(code).into(),
                advice: homing_advice(code).into(),
            }
        } else {
            DeviceError::Alarm {
                code,
                meaning: alarm_meaning(code).into(),
            }
        })
    }

    /// Send `line` and wait for its answer; returns the lines before the `ok`.
    /// On a timeout the line stays in flight: resynchronise before anything else.
    pub fn command(&mut self, line: &str, patience: Patience) -> Result<Vec<Line>, DeviceError> {
        self.drain()?;
        if let Some(waiting) = &self.in_flight {
            return Err(DeviceError::Protocol(format!(
                "{line:?} not sent: {waiting:?} is still unanswered"
            )));
        }
        let write = self.link()?.write(format!("{line}\n").as_bytes());
        self.io(write)?;
        self.in_flight = Some(line.to_owned());
        let started = Instant::now();
        let (expected_at, cap_at, poll, stall) = match patience {
            Patience::Reply(t) => (started + t, started + t, None, Duration::ZERO),
            Patience::Motion {
                expected,
                cap,
                poll,
                stall,
            } => (
                started + expected,
                started + cap.max(expected),
                Some(poll),
                stall,
            ),
        };
        let mut next_poll = poll.map(|p| started + p);
        let mut last_position: Option<[f64; 3]> = None;
        let mut last_progress = started;
        let mut lines = Vec::new();
        // A short garbled line that may be the answer, and until when a proper answer
        // may still come instead.
        let mut garbled: Option<(String, Instant)> = None;
        loop {
            let now = Instant::now();
            if let (Some(p), Some(at)) = (poll, next_poll) {
                if now >= at {
                    self.realtime(STATUS_QUERY)?;
                    next_poll = Some(now + p);
                }
            }
            // Late motion is given time while it progresses, up to the cap.
            let check_at = if now < expected_at {
                expected_at
            } else {
                (last_progress + stall).min(cap_at)
            };
            let wake = [Some(check_at), next_poll, garbled.as_ref().map(|g| g.1)]
                .into_iter()
                .flatten()
                .min()
                .unwrap_or(check_at);
            let Some(received) = self.read_line(wake)? else {
                let now = Instant::now();
                if let Some((text, until)) = &garbled {
                    if now >= *until {
                        // No proper answer came: the garbled line was it.
                        self.in_flight = None;
                        return Err(DeviceError::Protocol(format!(
                            "garbled reply to {line:?}: {text:?}"
                        )));
                    }
                }
                let stalled = poll.is_none() || now >= cap_at || now >= last_progress + stall;
                if now >= expected_at && stalled {
                    return Err(DeviceError::Timeout {
                        what: format!("reply to {line:?} from {}", self.path()),
                        seconds: (now - started).as_secs_f64(),
                    });
                }
                continue;
            };
            match received {
                Line::Ok => return Ok(lines),
                Line::Error(code) => {
                    return Err(DeviceError::Rejected {
                        code,
                        meaning: error_meaning(code).into(),
                    })
                }
                Line::Alarm(code) => return Err(self.on_alarm(code)?),
                Line::Banner(_) => return Err(DeviceError::Reset),
                Line::Garbled(text) if text.len() <= MAX_ANSWER_LEN => {
                    // Perhaps the answer: a proper one may still follow.
                    garbled = Some((text, Instant::now() + LINE_GRACE));
                }
                Line::Status(report) => {
                    let position = report.mpos.or(report.wpos);
                    let feeding = report.feed.is_some_and(|f| f > 0.0);
                    if feeding || (position.is_some() && position != last_position) {
                        last_progress = Instant::now();
                    }
                    last_position = position;
                }
                other => lines.push(other),
            }
        }
    }

    /// `?`: the next status report, within `timeout`. An alarm met meanwhile is
    /// returned as its error, a reset as [`DeviceError::Reset`].
    pub fn status(&mut self, timeout: Duration) -> Result<StatusReport, DeviceError> {
        self.drain()?;
        self.realtime(STATUS_QUERY)?;
        let mut deadline = Instant::now() + timeout;
        let mut garbled = None;
        loop {
            let Some(line) = self.read_line(deadline)? else {
                return Err(match garbled {
                    Some(text) => DeviceError::Protocol(format!("garbled status report: {text:?}")),
                    None => DeviceError::Timeout {
                        what: format!("status report from {}", self.path()),
                        seconds: timeout.as_secs_f64(),
                    },
                });
            };
            match line {
                Line::Status(report) => return Ok(report),
                Line::Alarm(code) => return Err(self.on_alarm(code)?),
                Line::Banner(_) => return Err(DeviceError::Reset),
                Line::Garbled(text) => {
                    garbled = Some(text);
                    deadline = deadline.min(Instant::now() + LINE_GRACE);
                }
                _ => {}
            }
        }
    }
}
