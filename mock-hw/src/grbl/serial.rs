//! The firmware's serial input: real-time commands picked off the byte stream as they
//! arrive (serial.c), the 128-byte receive ring, and the main loop's line assembly
//! that strips spaces and comments and upper-cases letters (protocol.c).

use std::collections::VecDeque;

/// Serial receive ring size; it holds one byte less.
pub(crate) const RX_BUFFER_SIZE: usize = 128;
/// Longest line the main loop assembles (longer lines answer `error:11`).
const LINE_BUFFER_SIZE: usize = 80;

/// Real-time commands received and not yet executed.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Realtime {
    /// 0x18 (Ctrl-X).
    pub reset: bool,
    /// `?`.
    pub status: bool,
    /// `!`.
    pub hold: bool,
    /// `~`.
    pub resume: bool,
    /// 0x85.
    pub jog_cancel: bool,
}

/// A line the main loop has assembled.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Line {
    /// Upper-cased, without spaces, control characters or comments.
    pub text: Vec<u8>,
    /// Longer than the line buffer: the firmware answers `error:11`.
    pub overflow: bool,
}

#[derive(Debug, Default)]
pub(crate) struct SerialInput {
    pub realtime: Realtime,
    rx: VecDeque<u8>,
    line: Vec<u8>,
    overflow: bool,
    in_paren_comment: bool,
    in_semicolon_comment: bool,
}

impl SerialInput {
    /// One byte from the line, as the receive interrupt takes it.
    pub fn receive(&mut self, byte: u8) {
        match byte {
            0x18 => self.realtime.reset = true,
            b'?' => self.realtime.status = true,
            b'!' => self.realtime.hold = true,
            b'~' => self.realtime.resume = true,
            0x85 => self.realtime.jog_cancel = true,
            // Extended real-time commands (overrides, safety door) are not emulated; the
            // firmware drops any other byte above 0x7F too.
            0x80.. => {}
            _ => {
                // A full ring loses the byte, as the firmware's does.
                if self.rx.len() < RX_BUFFER_SIZE - 1 {
                    self.rx.push_back(byte);
                }
            }
        }
    }

    /// Free bytes in the receive ring (the `Bf` field).
    pub fn available(&self) -> usize {
        RX_BUFFER_SIZE - self.rx.len()
    }

    /// Everything received is dropped (a reset or boot).
    pub fn clear(&mut self) {
        *self = SerialInput::default();
    }

    /// Take bytes from the ring until a line ends (`\n` or `\r`); `None` when the ring
    /// runs out first (the partial line is kept).
    pub fn next_line(&mut self) -> Option<Line> {
        while let Some(c) = self.rx.pop_front() {
            if c == b'\n' || c == b'\r' {
                let line = Line {
                    text: std::mem::take(&mut self.line),
                    overflow: self.overflow,
                };
                self.overflow = false;
                self.in_paren_comment = false;
                self.in_semicolon_comment = false;
                return Some(line);
            }
            if self.overflow || self.in_paren_comment || self.in_semicolon_comment {
                if c == b')' {
                    self.in_paren_comment = false;
                }
            } else if c <= b' ' || c == b'/' {
                // Whitespace and control characters are dropped; block delete is ignored.
            } else if c == b'(' {
                self.in_paren_comment = true;
            } else if c == b';' {
                self.in_semicolon_comment = true;
            } else if self.line.len() >= LINE_BUFFER_SIZE - 1 {
                self.overflow = true;
            } else {
                self.line.push(c.to_ascii_uppercase());
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(input: &mut SerialInput, bytes: &[u8]) {
        for &b in bytes {
            input.receive(b);
        }
    }

    #[test]
    fn picks_off_realtime_bytes_and_assembles_lines() {
        let mut input = SerialInput::default();
        feed(&mut input, b"g0 x-1?(comment) ; rest\n$$");
        assert!(input.realtime.status);
        assert_eq!(
            input.next_line(),
            Some(Line {
                text: b"G0X-1".to_vec(),
                overflow: false
            })
        );
        assert_eq!(input.next_line(), None);
        feed(&mut input, b"\r");
        assert_eq!(input.next_line().unwrap().text, b"$$");
        feed(&mut input, format!("G0X{}\n", "1".repeat(90)).as_bytes());
        assert!(input.next_line().unwrap().overflow);
        // The ring keeps 127 bytes.
        feed(&mut input, &[b'G'; 200]);
        assert_eq!(input.available(), 1);
    }
}
