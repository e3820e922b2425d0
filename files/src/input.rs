//! Reading an input file a user or a client named, bounded: it must be a regular file
//! (a device such as `/dev/zero` or `/dev/urandom`, a FIFO or a socket is refused before
//! it is opened, and opening never blocks), of at most the size its reader allows, and
//! no more than that is ever read (a file growing meanwhile included).
#![doc = include_str!("input.md")]

use std::fs::{self, File, OpenOptions};
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// Largest configuration, sidecar, setup, fit or other JSON or TOML file read: far
/// beyond any real one (they take a few kilobytes), far below what memory holds.
pub const MAX_SMALL_FILE_BYTES: u64 = 16 << 20;

/// Opens `path` for reading as an input file of at most `max_bytes` (see the module).
/// Errors say what is wrong (`not a regular file (a character device)`,
/// `2000000 bytes, more than the 1048576 such a file may have`); a missing file keeps
/// `NotFound`.
pub fn open_input(path: &Path, max_bytes: u64) -> io::Result<File> {
    // Looked at first, so that a device is never opened: opening one may have effects
    // (a serial port resets its board).
    check_kind(&fs::metadata(path)?)?;
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)?;
    let meta = file.metadata()?;
    check_kind(&meta)?;
    if meta.len() > max_bytes {
        return Err(too_long(Some(meta.len()), max_bytes));
    }
    Ok(file)
}

/// The bytes of the input file `path`, of at most `max_bytes` ([`open_input`]).
pub fn read_input(path: &Path, max_bytes: u64) -> io::Result<Vec<u8>> {
    let file = open_input(path, max_bytes)?;
    let mut bytes = Vec::with_capacity(file.metadata()?.len() as usize);
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_long(None, max_bytes));
    }
    Ok(bytes)
}

/// The text of the input file `path`, of at most `max_bytes` ([`open_input`]); not
/// UTF-8 is an `InvalidData` error.
pub fn read_input_to_string(path: &Path, max_bytes: u64) -> io::Result<String> {
    String::from_utf8(read_input(path, max_bytes)?)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// The error of a file longer than `max_bytes`: `size` bytes, or growing past it.
fn too_long(size: Option<u64>, max_bytes: u64) -> io::Error {
    let message = match size {
        Some(size) => format!("{size} bytes, more than the {max_bytes} such a file may have"),
        None => format!("more than the {max_bytes} bytes such a file may have (it grew)"),
    };
    io::Error::new(io::ErrorKind::FileTooLarge, message)
}

/// Refuses anything but a regular file, naming what it is.
pub(crate) fn check_kind(meta: &fs::Metadata) -> io::Result<()> {
    let kind = meta.file_type();
    let what = if kind.is_file() {
        return Ok(());
    } else if kind.is_dir() {
        "a directory"
    } else if kind.is_char_device() {
        "a character device"
    } else if kind.is_block_device() {
        "a block device"
    } else if kind.is_fifo() {
        "a FIFO"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "not a file"
    };
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("not a regular file ({what})"),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_fifos_and_directories_are_refused_unopened() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        crate::mkfifo(&fifo);
        for (path, what) in [
            (Path::new("/dev/zero"), "a character device"),
            (Path::new("/dev/urandom"), "a character device"),
            (fifo.as_path(), "a FIFO"),
            (dir.path(), "a directory"),
        ] {
            let err = read_input(path, 1 << 20).unwrap_err();
            assert_eq!(
                err.kind(),
                io::ErrorKind::InvalidInput,
                "{}",
                path.display()
            );
            assert_eq!(err.to_string(), format!("not a regular file ({what})"));
        }
    }

    #[test]
    fn a_file_over_its_cap_is_refused_unread_and_one_within_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fit.json");
        fs::write(&path, b"0123456789").unwrap();
        assert_eq!(read_input(&path, 10).unwrap(), b"0123456789");
        assert_eq!(read_input_to_string(&path, 100).unwrap(), "0123456789");
        let err = read_input(&path, 9).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::FileTooLarge);
        assert_eq!(
            err.to_string(),
            "10 bytes, more than the 9 such a file may have"
        );
        let missing = read_input(&dir.path().join("missing"), 9).unwrap_err();
        assert_eq!(missing.kind(), io::ErrorKind::NotFound);
        fs::write(&path, [0xff, 0xfe]).unwrap();
        let err = read_input_to_string(&path, 9).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidData);
    }
}
