//! A minimal serial client that talks to the emulator as a driver would: it opens the
//! device path with `serialport` at 115200 8N1 and checks replies byte for byte.

#![allow(dead_code)]

use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use gonio_mock_hw::grbl::{GrblConfig, GrblEmulator};
use gonio_mock_hw::world::World;
use serialport::SerialPort;

/// How long any expected reply may take in real time.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

/// The arm board 100× faster than real time, reports without the optional fields.
pub fn fast_config() -> GrblConfig {
    GrblConfig {
        time_scale: 0.01,
        status_extras: false,
        ..GrblConfig::arm_board()
    }
}

pub fn start(config: GrblConfig, arm_deg: f64) -> (GrblEmulator, World) {
    let world = World::new(arm_deg);
    let emulator = GrblEmulator::start(config, world.clone()).unwrap();
    (emulator, world)
}

pub struct Client {
    port: Box<dyn SerialPort>,
    pending: Vec<u8>,
}

impl Client {
    pub fn open(path: &Path) -> Client {
        let port = serialport::new(path.to_str().unwrap(), 115_200)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .timeout(Duration::from_millis(20))
            .open()
            .unwrap();
        Client {
            port,
            pending: Vec::new(),
        }
    }

    pub fn send(&mut self, bytes: &[u8]) {
        self.port.write_all(bytes).unwrap();
        self.port.flush().unwrap();
    }

    /// Read until `n` bytes are buffered or `timeout` passes.
    fn fill(&mut self, n: usize, timeout: Duration) {
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 256];
        while self.pending.len() < n && Instant::now() < deadline {
            match self.port.read(&mut buf) {
                Ok(k) => self.pending.extend_from_slice(&buf[..k]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) => panic!("serial read failed: {e}"),
            }
        }
    }

    /// The next bytes must be exactly `expected`.
    pub fn expect_bytes(&mut self, expected: &[u8]) {
        self.fill(expected.len(), REPLY_TIMEOUT);
        let got: Vec<u8> = self
            .pending
            .drain(..expected.len().min(self.pending.len()))
            .collect();
        assert_eq!(
            String::from_utf8_lossy(&got),
            String::from_utf8_lossy(expected),
            "raw: {got:?}"
        );
        assert_eq!(got, expected);
    }

    pub fn expect(&mut self, expected: &str) {
        self.expect_bytes(expected.as_bytes());
    }

    /// Send `command` and expect exactly `reply`.
    pub fn exchange(&mut self, command: &str, reply: &str) {
        self.send(command.as_bytes());
        self.expect(reply);
    }

    /// The next line, with its `\r\n` stripped.
    pub fn read_line(&mut self) -> String {
        let deadline = Instant::now() + REPLY_TIMEOUT;
        loop {
            if let Some(end) = self.pending.windows(2).position(|w| w == b"\r\n") {
                let line: Vec<u8> = self.pending.drain(..end + 2).collect();
                return String::from_utf8(line[..end].to_vec()).unwrap();
            }
            assert!(
                Instant::now() < deadline,
                "no complete line: {:?}",
                self.pending
            );
            let n = self.pending.len() + 1;
            self.fill(n, Duration::from_millis(50));
        }
    }

    /// Send `?` and return the status report line.
    pub fn status(&mut self) -> String {
        self.send(b"?");
        let line = self.read_line();
        assert!(line.starts_with('<') && line.ends_with('>'), "{line}");
        line
    }

    /// Poll `?` until the state is `state` (`Hold` matches `Hold:0` and `Hold:1`).
    pub fn wait_for_state(&mut self, state: &str) -> String {
        let deadline = Instant::now() + REPLY_TIMEOUT;
        loop {
            let report = self.status();
            let current = report[1..].split('|').next().unwrap_or_default();
            if current == state || current.split(':').next() == Some(state) {
                return report;
            }
            assert!(Instant::now() < deadline, "never reached {state}: {report}");
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Nothing arrives for `duration`.
    pub fn expect_silence(&mut self, duration: Duration) {
        self.fill(1, duration);
        assert!(
            self.pending.is_empty(),
            "unexpected {:?}",
            String::from_utf8_lossy(&self.pending)
        );
    }

    pub fn port(&mut self) -> &mut dyn SerialPort {
        self.port.as_mut()
    }
}

/// MPos X of a status report.
pub fn mpos_x(report: &str) -> f64 {
    let start = report.find("MPos:").unwrap() + 5;
    let end = report[start..].find(',').unwrap() + start;
    report[start..end].parse().unwrap()
}

pub const BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n";
pub const LOCKED_BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n";
