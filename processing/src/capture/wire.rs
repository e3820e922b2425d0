//! The protocol between a program and a child process that decodes captures for it
//! (a [`Decoder`](super::Decoder) of the program spawns the child, which runs
//! [`serve`] on its stdin and stdout).
//!
//! Binary, little-endian, every message a one-byte tag and fixed-size fields:
//! - parent: `D`, path length (u32), path bytes, largest pixel count (u64): decode;
//! - child: `S`, width, height (u64): the image's size (after superpixels for raw);
//! - parent: `B`, band count (u32), then start and end rows (u64 each) per band: the
//!   rows to send; or `X`: none, stop (the child then waits for the next request);
//! - child: `F`, width, height, stored width, stored height (u64), black level, white
//!   level, largest count (f64), value count (u64), then the counts (u16 each): the
//!   selected rows, RGB interleaved;
//! - child: `E`, kind (u8), reason length (u32), reason (UTF-8): the file cannot be
//!   decoded, for that reason.
//!
//! The parent checks every size before it allocates anything for it: a path or reason
//! of at most [`MAX_TEXT`] bytes, a size within the largest pixel count, counts for
//! exactly the rows it asked for.

use std::io::{self, Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use super::decoded::check_bands;
use super::{checked_len, decode_here, max_pixels, set_max_pixels};
use super::{CaptureError, Decoded};

/// Longest path or reason sent, bytes.
pub const MAX_TEXT: usize = 64 << 10;

const DECODE: u8 = b'D';
const SIZE: u8 = b'S';
const BANDS: u8 = b'B';
const STOP: u8 = b'X';
const FRAME: u8 = b'F';
const ERROR: u8 = b'E';

/// Counts converted to bytes at a time where memory is not little-endian already.
const CHUNK_VALUES: usize = 32 << 10;

/// The bytes of `values` in memory (their little-endian encoding on a little-endian
/// machine), without a copy.
fn as_bytes(values: &[u16]) -> &[u8] {
    // SAFETY: the view covers exactly the memory of `values`, u8 has no alignment
    // needs, and the borrow keeps `values` alive and unchanged.
    unsafe { std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), 2 * values.len()) }
}

/// As [`as_bytes`], to fill `values` from bytes: any two bytes are a valid u16.
fn as_bytes_mut(values: &mut [u16]) -> &mut [u8] {
    // SAFETY: as in `as_bytes`; every bit pattern is a u16, and the borrow is unique.
    unsafe { std::slice::from_raw_parts_mut(values.as_mut_ptr().cast::<u8>(), 2 * values.len()) }
}

fn invalid(what: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, what)
}

fn read_u8(r: &mut impl Read) -> io::Result<u8> {
    let mut b = [0; 1];
    r.read_exact(&mut b)?;
    Ok(b[0])
}

fn read_u32(r: &mut impl Read) -> io::Result<u32> {
    let mut b = [0; 4];
    r.read_exact(&mut b)?;
    Ok(u32::from_le_bytes(b))
}

fn read_u64(r: &mut impl Read) -> io::Result<u64> {
    let mut b = [0; 8];
    r.read_exact(&mut b)?;
    Ok(u64::from_le_bytes(b))
}

fn read_f64(r: &mut impl Read) -> io::Result<f64> {
    read_u64(r).map(f64::from_bits)
}

/// A u64 that must fit a `usize` no larger than `max`.
fn read_size(r: &mut impl Read, what: &str, max: u64) -> io::Result<usize> {
    let v = read_u64(r)?;
    if v > max {
        return Err(invalid(format!("{what} {v} is more than {max}")));
    }
    usize::try_from(v).map_err(|_| invalid(format!("{what} {v} does not fit in memory")))
}

/// A length-prefixed text of at most [`MAX_TEXT`] bytes.
fn read_text(r: &mut impl Read) -> io::Result<Vec<u8>> {
    let len = read_u32(r)? as usize;
    if len > MAX_TEXT {
        return Err(invalid(format!("a text of {len} bytes")));
    }
    let mut text = vec![0; len];
    r.read_exact(&mut text)?;
    Ok(text)
}

fn put_text(out: &mut Vec<u8>, text: &[u8]) {
    let text = &text[..text.len().min(MAX_TEXT)];
    out.extend((text.len() as u32).to_le_bytes());
    out.extend(text);
}

fn path_bytes(path: &Path) -> &[u8] {
    use std::os::unix::ffi::OsStrExt;
    path.as_os_str().as_bytes()
}

/// Error kinds as they cross the pipe.
fn error_kind(error: &CaptureError) -> (u8, String) {
    match error {
        CaptureError::Image { reason, .. } => (0, reason.clone()),
        CaptureError::Layout { reason, .. } => (1, reason.clone()),
        CaptureError::TooLarge { reason, .. } => (2, reason.clone()),
        CaptureError::UnsupportedFormat { .. } => (3, String::new()),
        other => (0, other.to_string()),
    }
}

fn error_of_kind(kind: u8, path: &Path, reason: String) -> CaptureError {
    let path = path.to_path_buf();
    match kind {
        1 => CaptureError::Layout { path, reason },
        2 => CaptureError::TooLarge { path, reason },
        3 => CaptureError::UnsupportedFormat { path },
        _ => CaptureError::Image { path, reason },
    }
}

/// The parent's side of one decode: asks the child on `to`/`from` to decode `path`,
/// answers its size with the rows `select` returns, and reads those rows back.
/// `Ok(Err(…))` is the child's error about the file, `Ok(Ok(None))` a stop `select`
/// asked for; `Err` is a broken exchange (the child died or said something
/// malformed), after which the child is of no further use.
pub fn request(
    to: &mut impl Write,
    from: &mut impl Read,
    path: &Path,
    select: &mut dyn FnMut(usize, usize) -> Option<Vec<Range<usize>>>,
) -> io::Result<Result<Option<Decoded>, CaptureError>> {
    let max = max_pixels();
    let mut message = vec![DECODE];
    let bytes = path_bytes(path);
    if bytes.len() > MAX_TEXT {
        return Ok(Err(super::image_error(path, "path too long")));
    }
    put_text(&mut message, bytes);
    message.extend(max.to_le_bytes());
    to.write_all(&message)?;
    to.flush()?;
    // The width and rows asked for, once the child has told the size.
    let mut asked: Option<(usize, usize)> = None;
    loop {
        match read_u8(from)? {
            SIZE if asked.is_none() => {
                let width = read_size(from, "width", max)?;
                let height = read_size(from, "height", max)?;
                if (width as u64).saturating_mul(height as u64) > max {
                    return Err(invalid(format!("a {width}×{height} image")));
                }
                let Some(bands) = select(width, height) else {
                    to.write_all(&[STOP])?;
                    to.flush()?;
                    return Ok(Ok(None));
                };
                if let Err(e) = check_bands(path, &bands, height) {
                    to.write_all(&[STOP])?;
                    to.flush()?;
                    return Ok(Err(e));
                }
                let mut message = vec![BANDS];
                message.extend((bands.len() as u32).to_le_bytes());
                for band in &bands {
                    message.extend((band.start as u64).to_le_bytes());
                    message.extend((band.end as u64).to_le_bytes());
                }
                to.write_all(&message)?;
                to.flush()?;
                asked = Some((width, bands.iter().map(|b| b.len()).sum()));
            }
            FRAME => {
                let Some((width, rows)) = asked else {
                    return Err(invalid("counts before the size".into()));
                };
                return read_frame(from, max, width, rows).map(|d| Ok(Some(d)));
            }
            ERROR => {
                let kind = read_u8(from)?;
                let reason = String::from_utf8_lossy(&read_text(from)?).into_owned();
                return Ok(Err(error_of_kind(kind, path, reason)));
            }
            tag => return Err(invalid(format!("unexpected message {tag:#04x}"))),
        }
    }
}

/// Reads an `F` message's body: counts for exactly `width` × `rows` pixels.
fn read_frame(from: &mut impl Read, max: u64, width: usize, rows: usize) -> io::Result<Decoded> {
    let got_width = read_size(from, "width", max)?;
    let got_rows = read_size(from, "height", max)?;
    let stored_w = read_size(from, "stored width", max)?;
    let stored_h = read_size(from, "stored height", max)?;
    if (got_width, got_rows) != (width, rows) {
        return Err(invalid(format!(
            "{got_width}×{got_rows} counts for {width}×{rows} asked"
        )));
    }
    if (stored_w as u64).saturating_mul(stored_h as u64) > max {
        return Err(invalid(format!("a stored {stored_w}×{stored_h} image")));
    }
    let (black_level, white_level, max_count) = (read_f64(from)?, read_f64(from)?, read_f64(from)?);
    let values = read_u64(from)?;
    let expected = 3u64
        .saturating_mul(width as u64)
        .saturating_mul(rows as u64);
    if values != expected {
        return Err(invalid(format!("{values} counts for {expected}")));
    }
    let mut data = vec![0u16; expected as usize];
    from.read_exact(as_bytes_mut(&mut data))?;
    for v in &mut data {
        *v = u16::from_le(*v);
    }
    Ok(Decoded {
        width,
        height: rows,
        stored: (stored_w, stored_h),
        data,
        black_level,
        white_level,
        max_count,
    })
}

/// Why a decode in the child ended without counts to send.
enum Ended {
    File(CaptureError),
    /// The parent asked for no rows.
    Stopped,
    Pipe(io::Error),
}

impl From<CaptureError> for Ended {
    fn from(e: CaptureError) -> Self {
        Ended::File(e)
    }
}

/// The child's side: answers decode requests read from `input` on `output` until
/// `input` ends. `before(path)` runs before each decode (to set a time limit, say).
pub fn serve(
    mut input: impl Read,
    mut output: impl Write,
    mut before: impl FnMut(&Path),
) -> io::Result<()> {
    loop {
        let mut tag = [0; 1];
        if input.read(&mut tag)? == 0 {
            return Ok(());
        }
        if tag[0] != DECODE {
            return Err(invalid(format!("unexpected request {:#04x}", tag[0])));
        }
        let path = {
            use std::os::unix::ffi::OsStringExt;
            PathBuf::from(std::ffi::OsString::from_vec(read_text(&mut input)?))
        };
        set_max_pixels(read_u64(&mut input)?);
        before(&path);
        let decoded = checked_len(&path).map_err(Ended::File).and_then(|len| {
            decode_here(&path, len, |width, height| {
                ask_rows(&mut input, &mut output, width, height)
            })
        });
        match decoded {
            Ok(decoded) => send_frame(&mut output, &decoded)?,
            Err(Ended::File(e)) => {
                let (kind, reason) = error_kind(&e);
                let mut message = vec![ERROR, kind];
                put_text(&mut message, reason.as_bytes());
                output.write_all(&message)?;
            }
            Err(Ended::Stopped) => {}
            Err(Ended::Pipe(e)) => return Err(e),
        }
        output.flush()?;
    }
}

/// Tells the parent the image's size and reads the rows it wants.
fn ask_rows(
    input: &mut impl Read,
    output: &mut impl Write,
    width: usize,
    height: usize,
) -> Result<Vec<Range<usize>>, Ended> {
    let mut message = vec![SIZE];
    message.extend((width as u64).to_le_bytes());
    message.extend((height as u64).to_le_bytes());
    let answer = (|| {
        output.write_all(&message)?;
        output.flush()?;
        match read_u8(input)? {
            STOP => Ok(None),
            BANDS => {
                let count = read_u32(input)? as usize;
                let mut bands = Vec::with_capacity(count.min(1024));
                for _ in 0..count {
                    let start = read_size(input, "row", height as u64)?;
                    let end = read_size(input, "row", height as u64)?;
                    bands.push(start..end);
                }
                Ok(Some(bands))
            }
            tag => Err(invalid(format!("unexpected answer {tag:#04x}"))),
        }
    })();
    match answer {
        Ok(Some(bands)) => Ok(bands),
        Ok(None) => Err(Ended::Stopped),
        Err(e) => Err(Ended::Pipe(e)),
    }
}

fn send_frame(output: &mut impl Write, d: &Decoded) -> io::Result<()> {
    let mut message = vec![FRAME];
    for v in [d.width, d.height, d.stored.0, d.stored.1] {
        message.extend((v as u64).to_le_bytes());
    }
    for v in [d.black_level, d.white_level, d.max_count] {
        message.extend(v.to_bits().to_le_bytes());
    }
    message.extend((d.data.len() as u64).to_le_bytes());
    output.write_all(&message)?;
    if cfg!(target_endian = "little") {
        return output.write_all(as_bytes(&d.data));
    }
    let mut bytes = Vec::with_capacity(2 * CHUNK_VALUES);
    for chunk in d.data.chunks(CHUNK_VALUES) {
        bytes.clear();
        bytes.extend(chunk.iter().flat_map(|v| v.to_le_bytes()));
        output.write_all(&bytes)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decoded(width: usize, height: usize) -> Decoded {
        Decoded {
            width,
            height,
            stored: (width, height),
            data: (0..3 * width * height).map(|v| v as u16).collect(),
            black_level: 2.0,
            white_level: 4000.0,
            max_count: 65535.0,
        }
    }

    /// A child's reply to one request, as bytes: its size, then `rest`.
    fn reply(width: u64, height: u64, rest: &[u8]) -> Vec<u8> {
        let mut b = vec![SIZE];
        b.extend(width.to_le_bytes());
        b.extend(height.to_le_bytes());
        b.extend(rest);
        b
    }

    fn frame_message(d: &Decoded) -> Vec<u8> {
        let mut b = Vec::new();
        send_frame(&mut b, d).unwrap();
        b
    }

    fn run(
        from: &[u8],
        select: &mut dyn FnMut(usize, usize) -> Option<Vec<Range<usize>>>,
    ) -> (Vec<u8>, io::Result<Result<Option<Decoded>, CaptureError>>) {
        let mut to = Vec::new();
        let result = request(&mut to, &mut &from[..], Path::new("/x/f.tiff"), select);
        (to, result)
    }

    #[test]
    fn a_frame_crosses_with_the_rows_asked_for() {
        let sent = decoded(4, 2);
        let (to, got) = run(&reply(4, 5, &frame_message(&sent)), &mut |_, _| {
            Some(vec![1..2, 3..4])
        });
        assert_eq!(got.unwrap().unwrap(), Some(sent));
        // The request, then the bands.
        assert_eq!(to[0], DECODE);
        let bands = &to[to.len() - 37..];
        assert_eq!(bands[0], BANDS);
        assert_eq!(u32::from_le_bytes(bands[1..5].try_into().unwrap()), 2);
        assert_eq!(u64::from_le_bytes(bands[29..37].try_into().unwrap()), 4);
    }

    #[test]
    fn sizes_are_checked_before_anything_is_allocated() {
        let mut all = |_: usize, h: usize| Some(std::iter::once(0..h).collect::<Vec<_>>());
        // More pixels than allowed.
        let huge = max_pixels() + 1;
        assert!(run(&reply(huge, 1, &[]), &mut all).1.is_err());
        // Counts for other rows than asked.
        let (_, got) = run(&reply(4, 2, &frame_message(&decoded(4, 3))), &mut all);
        assert_eq!(got.unwrap_err().kind(), io::ErrorKind::InvalidData);
        // A count that is not 3 × width × height.
        let mut bad = frame_message(&decoded(4, 2));
        bad[57..65].copy_from_slice(&u64::MAX.to_le_bytes());
        let (_, got) = run(&reply(4, 2, &bad), &mut all);
        assert!(got.unwrap_err().to_string().contains("counts for 24"));
        // Counts before a size, a reason beyond the cap, an unknown tag, a cut reply.
        assert!(run(&frame_message(&decoded(1, 1)), &mut all).1.is_err());
        let mut long = vec![ERROR, 0];
        long.extend(u32::MAX.to_le_bytes());
        assert!(run(&long, &mut all).1.is_err());
        assert!(run(b"?", &mut all).1.is_err());
        let whole = reply(4, 2, &frame_message(&decoded(4, 2)));
        for cut in 0..whole.len() {
            assert!(run(&whole[..cut], &mut all).1.is_err(), "cut at {cut}");
        }
    }

    #[test]
    fn errors_and_stops_cross_as_they_are() {
        let mut message = vec![ERROR, 1];
        put_text(&mut message, b"strip 3 is too short");
        let (_, got) = run(&message, &mut |_, _| None);
        let error = got.unwrap().unwrap_err();
        assert!(matches!(error, CaptureError::Layout { .. }));
        assert_eq!(
            error.to_string(),
            "/x/f.tiff: unsupported image layout: strip 3 is too short"
        );
        // A selector that declines: the child is told to stop.
        let (to, got) = run(&reply(4, 2, &[]), &mut |_, _| None);
        assert_eq!(got.unwrap().unwrap(), None);
        assert_eq!(to.last(), Some(&STOP));
        // Rows outside the image are refused here, not sent.
        let (to, got) = run(&reply(4, 2, &[]), &mut |_, _| {
            Some(std::iter::once(1..9).collect::<Vec<_>>())
        });
        assert!(matches!(got.unwrap(), Err(CaptureError::Layout { .. })));
        assert_eq!(to.last(), Some(&STOP));
    }

    /// Both sides together: a child answering two requests for a missing file, then
    /// its input ending.
    #[test]
    fn the_child_answers_each_request_and_ends_with_its_input() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("none.tiff");
        let mut input = Vec::new();
        for _ in 0..2 {
            input.push(DECODE);
            put_text(&mut input, path_bytes(&missing));
            input.extend(max_pixels().to_le_bytes());
        }
        let mut output = Vec::new();
        let mut seen = Vec::new();
        serve(&input[..], &mut output, |p| seen.push(p.to_path_buf())).unwrap();
        assert_eq!(seen, vec![missing.clone(), missing.clone()]);
        let mut from = &output[..];
        for _ in 0..2 {
            let got = request(&mut Vec::new(), &mut from, &missing, &mut |_, h| {
                Some(std::iter::once(0..h).collect::<Vec<_>>())
            });
            let error = got.unwrap().unwrap_err().to_string();
            assert!(error.ends_with("no such file"), "{error}");
        }
        assert!(from.is_empty());
    }
}
