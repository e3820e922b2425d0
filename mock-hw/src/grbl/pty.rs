//! The pseudo-terminal the emulated controller serves, and the stable device path (a
//! symlink, like `/dev/serial/by-id/...`) that points at its current slave. Whether a
//! driver has the slave open is what an Arduino-based board sees as DTR: opening the
//! port resets the board.

use std::io::{self, Read, Write};
use std::path::Path;
use std::time::Duration;

use serialport::{DataBits, FlowControl, Parity, SerialPort, StopBits, TTYPort};

/// The firmware's serial speed, baud.
pub(crate) const BAUD_RATE: u32 = 115_200;

/// How long a write may wait for the driver to drain the line before the bytes are
/// dropped (as on a real serial line nobody listens to).
const WRITE_TIMEOUT: Duration = Duration::from_millis(20);

/// One plugged-in connection: the master end the emulator drives. The emulator does
/// not keep the slave open, so it sees when a driver opens and closes it.
#[derive(Debug)]
pub(crate) struct Pty {
    master: TTYPort,
}

/// What a read from the line found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Received {
    /// This many bytes (0 when nothing came in time).
    Bytes(usize),
    /// Nobody has the port open (DTR low).
    Closed,
}

impl Pty {
    /// A new pty in raw mode at 115200 8N1, with `link` pointing at its slave.
    pub fn open(link: &Path) -> io::Result<Pty> {
        let (inheritable, mut slave) = TTYPort::pair()?;
        // `pair` opens both ends without close-on-exec: a process this one starts (a
        // decode worker, another test's daemon) would hold the master open past an
        // unplug, and the driver would see no hangup. The master kept is a close-on-exec
        // duplicate; the originals close here (only a child started in the microseconds
        // between would keep them).
        let master = inheritable.try_clone_native()?;
        drop(inheritable);
        slave.set_baud_rate(BAUD_RATE)?;
        slave.set_data_bits(DataBits::Eight)?;
        slave.set_parity(Parity::None)?;
        slave.set_stop_bits(StopBits::One)?;
        slave.set_flow_control(FlowControl::None)?;
        let name = slave
            .name()
            .ok_or_else(|| io::Error::other("pseudo-terminal slave has no name"))?;
        point_link(link, Path::new(&name))?;
        // The settings stay with the pty; the slave closes here (DTR low).
        drop(slave);
        Ok(Pty { master })
    }

    /// Read what the driver sent, waiting at most `timeout` while the port is open
    /// (a closed port answers at once).
    pub fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<Received> {
        self.master.set_timeout(timeout)?;
        match self.master.read(buf) {
            Ok(n) => Ok(Received::Bytes(n)),
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(Received::Bytes(0)),
            // While no slave is open the master hangs up (poll reports POLLHUP, reads
            // fail with EIO).
            Err(_) => Ok(Received::Closed),
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

/// Point `link` at `target`, replacing a previous link atomically (a fresh temporary
/// link renamed over it); anything at `link` other than a link is refused, never
/// replaced.
fn point_link(link: &Path, target: &Path) -> io::Result<()> {
    if let Ok(meta) = std::fs::symlink_metadata(link) {
        if !meta.file_type().is_symlink() {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!("{} exists and is not a symlink", link.display()),
            ));
        }
    }
    let (temp, ()) =
        gonio_files::output::create_beside(link, |temp| std::os::unix::fs::symlink(target, temp))?;
    std::fs::rename(&temp, link).inspect_err(|_| {
        let _ = std::fs::remove_file(&temp);
    })
}

/// Remove the device link (the device is unplugged); anything else at its path is not
/// ours and stays.
pub(crate) fn remove_link(link: &Path) {
    // Already gone is fine: the device is absent either way.
    if std::fs::symlink_metadata(link).is_ok_and(|meta| meta.file_type().is_symlink()) {
        let _ = std::fs::remove_file(link);
    }
}
