//! Faults a test (or a schedule in the emulator's configuration) can inject into the
//! emulated controller, and the corruption of replies.

use serde::Deserialize;

/// A fault injected with `GrblEmulator::inject`, or on a schedule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fault {
    /// USB unplugged: the pty master closes (the driver's reads and writes fail with a
    /// broken pipe / EIO), the device link disappears and the board loses power.
    /// `GrblEmulator::reconnect` (or [`Fault::Replug`]) plugs it back in.
    Unplug,
    /// Plug the board back in after [`Fault::Unplug`] (or replug it): a new pty behind
    /// the same device path, and the board boots again.
    Replug,
    /// The controller hangs: input is ignored and nothing is sent, while the arm keeps
    /// executing what it was doing. Undone by [`Fault::Responsive`], or by a power cycle
    /// ([`Fault::Unplug`] + reconnect) or [`Fault::ResetBanner`].
    Silent,
    /// Undo [`Fault::Silent`].
    Responsive,
    /// The next reply line arrives corrupted (line noise: bytes flipped, line ending kept).
    Garble,
    /// The next reply line is cut in half, without its line ending.
    Truncate,
    /// `ALARM:code` when the current or next move is half done (e.g. 1 = hard limit).
    /// Codes 1 and 2 lock the controller until a soft reset, like limit alarms do.
    AlarmDuringMotion(u8),
    /// An unexpected hardware reset (as when DTR toggles): the board reboots and greets
    /// with the banner; machine position and any queued motion are lost.
    ResetBanner,
}

/// Line-level faults applied to the controller's output.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct LineFaults {
    pub silent: bool,
    pub garble_next: bool,
    pub truncate_next: bool,
}

impl LineFaults {
    /// The bytes actually sent for one reply line, if any.
    pub fn apply(&mut self, mut line: Vec<u8>) -> Option<Vec<u8>> {
        if self.silent {
            return None;
        }
        let body_len = line.len() - trailing_line_ending(&line);
        if std::mem::take(&mut self.garble_next) {
            for byte in &mut line[..body_len] {
                *byte ^= 0xA5;
            }
        }
        if std::mem::take(&mut self.truncate_next) {
            line.truncate(body_len.div_ceil(2));
        }
        Some(line)
    }
}

fn trailing_line_ending(line: &[u8]) -> usize {
    line.iter()
        .rev()
        .take_while(|&&b| b == b'\r' || b == b'\n')
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn garble_and_truncate_touch_one_line() {
        let mut faults = LineFaults {
            garble_next: true,
            ..LineFaults::default()
        };
        assert_eq!(
            faults.apply(b"ok\r\n".to_vec()),
            Some(vec![0xCA, 0xCE, b'\r', b'\n'])
        );
        assert_eq!(faults.apply(b"ok\r\n".to_vec()), Some(b"ok\r\n".to_vec()));
        faults.truncate_next = true;
        assert_eq!(
            faults.apply(b"error:9\r\n".to_vec()),
            Some(b"erro".to_vec())
        );
        faults.silent = true;
        assert_eq!(faults.apply(b"ok\r\n".to_vec()), None);
    }
}
