//! The pseudo-terminal the emulated controller serves, and the stable device path (a
//! symlink, like `/dev/serial/by-id/...`) that points at its current slave.

use std::io::{self, Read, Write};
use std::path::Path;
use std::time::Duration;

use serialport::{DataBits, FlowControl, Parity, SerialPort, StopBits, TTYPort};

/// The firmware's serial speed, baud.
pub(crate) const BAUD_RATE: u32 = 115_200;

/// How long a write may wait for the driver to drain the line before the bytes are
/// dropped (as on a real serial line nobody listens to).
const WRITE_TIMEOUT: Duration = Duration::from_millis(20);

/// One plugged-in connection: the master end the emulator drives, and the slave kept
/// open so that the line stays up while no driver has it open.
#[derive(Debug)]
pub(crate) struct Pty {
    master: TTYPort,
    _slave: TTYPort,
}

impl Pty {
    /// A new pty in raw mode at 115200 8N1, with `link` pointing at its slave.
    pub fn open(link: &Path) -> io::Result<Pty> {
        let (master, mut slave) = TTYPort::pair()?;
        slave.set_baud_rate(BAUD_RATE)?;
        slave.set_data_bits(DataBits::Eight)?;
        slave.set_parity(Parity::None)?;
        slave.set_stop_bits(StopBits::One)?;
        slave.set_flow_control(FlowControl::None)?;
        let name = slave
            .name()
            .ok_or_else(|| io::Error::other("pseudo-terminal slave has no name"))?;
        point_link(link, Path::new(&name))?;
        Ok(Pty {
            master,
            _slave: slave,
        })
    }

    /// Read what the driver sent, waiting at most `timeout`. Returns 0 bytes on timeout.
    pub fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.master.set_timeout(timeout)?;
        match self.master.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(0),
            other => other,
        }
    }

    /// Send bytes to the driver; what the line cannot take in time is dropped.
    pub fn write(&mut self, bytes: &[u8]) {
        if self.master.set_timeout(WRITE_TIMEOUT).is_err() {
            return;
        }
        // A full line or a closed driver loses the bytes, as a real serial port would.
        let _ = self.master.write_all(bytes);
    }
}

/// Point `link` at `target`, replacing any previous link atomically.
fn point_link(link: &Path, target: &Path) -> io::Result<()> {
    let mut tmp = link.as_os_str().to_owned();
    tmp.push(".new");
    let tmp = Path::new(&tmp);
    let _ = std::fs::remove_file(tmp);
    std::os::unix::fs::symlink(target, tmp)?;
    std::fs::rename(tmp, link)
}

/// Remove the device link (the device is unplugged).
pub(crate) fn remove_link(link: &Path) {
    // Already gone is fine: the device is absent either way.
    let _ = std::fs::remove_file(link);
}
