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

/// Pixels (width × height) a capture may have unless the reader is told otherwise (100
/// megapixels; a 16-bit RGB frame of that size takes 600 MB): what gonio's readers
/// decode by default, and so what the emulator renders at most.
pub const DEFAULT_MAX_FRAME_PIXELS: u64 = 100_000_000;

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

/// A reader of text whose line ends are all `\n`: `\r\n` and a lone `\r` each become
/// one `\n`. A CSV reader counts a Windows file's lines as a Unix file's through it (the
/// `csv` crate's positions fall one line short after a `\r\n`).
pub struct UnixLineEnds<R> {
    inner: R,
    /// The last byte read was a `\r` (already given as `\n`): a `\n` next is dropped.
    after_cr: bool,
}

impl<R: Read> UnixLineEnds<R> {
    pub fn new(inner: R) -> Self {
        UnixLineEnds {
            inner,
            after_cr: false,
        }
    }
}

impl<R: Read> Read for UnixLineEnds<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            let n = self.inner.read(buf)?;
            if n == 0 {
                return Ok(0);
            }
            let mut kept = 0;
            for i in 0..n {
                let byte = buf[i];
                let dropped = byte == b'\n' && self.after_cr;
                self.after_cr = byte == b'\r';
                if !dropped {
                    buf[kept] = if byte == b'\r' { b'\n' } else { byte };
                    kept += 1;
                }
            }
            // A read that was one dropped `\n` is not the end: read on.
            if kept > 0 {
                return Ok(kept);
            }
        }
    }
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

    #[test]
    fn windows_and_old_mac_line_ends_read_as_unix_ones() {
        // Read a byte at a time too, so that a `\r\n` split between reads is seen.
        let text = b"a,b\r\n1,2\r\n\r\n3\r4\n";
        for chunk in [1, 3, 64] {
            let mut reader = UnixLineEnds::new(ChunkedReader { text, at: 0, chunk });
            let mut out = Vec::new();
            reader.read_to_end(&mut out).unwrap();
            assert_eq!(out, b"a,b\n1,2\n\n3\n4\n", "chunks of {chunk}");
        }
    }

    /// Gives `text` at most `chunk` bytes a read.
    struct ChunkedReader {
        text: &'static [u8],
        at: usize,
        chunk: usize,
    }

    impl Read for ChunkedReader {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            let n = self.chunk.min(buf.len()).min(self.text.len() - self.at);
            buf[..n].copy_from_slice(&self.text[self.at..self.at + n]);
            self.at += n;
            Ok(n)
        }
    }
}
