//! A whole scan as one POSIX tar archive (ustar), written entry by entry so that
//! `GET /api/scans/{id}/archive` streams it without holding it in memory.

use std::io::{self, Read, Write};
use std::path::Path;

/// Bytes of a tar block; headers and file data are padded to it.
const BLOCK: usize = 512;
/// Longest name a ustar header holds in `name` (100 bytes) and `prefix` (155 bytes).
const NAME_LEN: usize = 100;
const PREFIX_LEN: usize = 155;

/// A file name safe in a download's name and an archive's directory: letters, digits,
/// `.`, `-` and `_` kept, anything else `_`.
pub fn file_name_part(text: &str) -> String {
    let cleaned: String = text
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_') {
                c
            } else {
                '_'
            }
        })
        .collect();
    cleaned.trim_start_matches('.').to_owned()
}

/// Writes tar entries to `out`.
pub struct TarWriter<W: Write> {
    out: W,
}

impl<W: Write> TarWriter<W> {
    pub fn new(out: W) -> Self {
        Self { out }
    }

    /// Adds a regular file `name` (relative, `/`-separated) with the bytes of `data`,
    /// `size` of them, last modified at `mtime` (Unix seconds).
    pub fn append(
        &mut self,
        name: &str,
        size: u64,
        mtime: u64,
        data: &mut impl Read,
    ) -> io::Result<()> {
        self.out.write_all(&header(name, size, mtime)?)?;
        let copied = io::copy(&mut data.take(size), &mut self.out)?;
        if copied != size {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!("{name}: {copied} of {size} bytes read (the file shrank)"),
            ));
        }
        let pad = (BLOCK - (size as usize % BLOCK)) % BLOCK;
        self.out.write_all(&[0; BLOCK][..pad])
    }

    /// Adds the file at `path` as `name`.
    pub fn append_file(&mut self, name: &str, path: &Path) -> io::Result<()> {
        let mut file = std::fs::File::open(path)?;
        let meta = file.metadata()?;
        let mtime = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_secs());
        self.append(name, meta.len(), mtime, &mut file)
    }

    /// Writes the two zero blocks that end an archive and returns the writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.write_all(&[0; 2 * BLOCK])?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// A ustar header block for a regular file.
fn header(name: &str, size: u64, mtime: u64) -> io::Result<[u8; BLOCK]> {
    let too_long = || {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{name}: too long for a tar header"),
        )
    };
    let (prefix, rest) = if name.len() <= NAME_LEN {
        ("", name)
    } else {
        // Split at a `/` so that the prefix and the name each fit.
        let cut = name
            .char_indices()
            .find(|&(i, c)| c == '/' && i <= PREFIX_LEN && name.len() - i - 1 <= NAME_LEN)
            .map(|(i, _)| i)
            .ok_or_else(too_long)?;
        (&name[..cut], &name[cut + 1..])
    };
    let mut block = [0u8; BLOCK];
    block[..rest.len()].copy_from_slice(rest.as_bytes());
    octal(&mut block[100..108], 0o644);
    octal(&mut block[108..116], 0);
    octal(&mut block[116..124], 0);
    octal(&mut block[124..136], size);
    octal(&mut block[136..148], mtime);
    block[156] = b'0';
    block[257..263].copy_from_slice(b"ustar\0");
    block[263..265].copy_from_slice(b"00");
    block[345..345 + prefix.len()].copy_from_slice(prefix.as_bytes());
    // The checksum is computed with its own field as spaces.
    block[148..156].fill(b' ');
    let sum: u64 = block.iter().map(|&b| u64::from(b)).sum();
    octal(&mut block[148..155], sum);
    Ok(block)
}

/// `value` as zero-padded octal digits filling `field` but its last byte (a NUL).
fn octal(field: &mut [u8], value: u64) {
    let digits = field.len() - 1;
    let text = format!("{value:0digits$o}");
    field[..digits].copy_from_slice(&text.as_bytes()[text.len() - digits..]);
    field[digits] = 0;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The entries of a ustar archive: (name, data), read back by the format's rules.
    fn entries(archive: &[u8]) -> Vec<(String, Vec<u8>)> {
        let text = |field: &[u8]| {
            let end = field.iter().position(|&b| b == 0).unwrap_or(field.len());
            String::from_utf8(field[..end].to_vec()).unwrap()
        };
        let mut out = Vec::new();
        let mut at = 0;
        while archive[at..at + BLOCK].iter().any(|&b| b != 0) {
            let block = &archive[at..at + BLOCK];
            let mut stored = block.to_vec();
            stored[148..156].fill(b' ');
            let sum: u64 = stored.iter().map(|&b| u64::from(b)).sum();
            assert_eq!(
                u64::from_str_radix(text(&block[148..155]).trim(), 8),
                Ok(sum)
            );
            let size = u64::from_str_radix(&text(&block[124..135]), 8).unwrap() as usize;
            let (prefix, name) = (text(&block[345..500]), text(&block[..100]));
            let name = if prefix.is_empty() {
                name
            } else {
                format!("{prefix}/{name}")
            };
            out.push((name, archive[at + BLOCK..at + BLOCK + size].to_vec()));
            at += BLOCK + size.div_ceil(BLOCK) * BLOCK;
        }
        assert!(archive[at..].iter().all(|&b| b == 0) && archive.len() - at >= 2 * BLOCK);
        out
    }

    #[test]
    fn entries_read_back_with_long_names_and_sizes_off_the_block() {
        let long = format!("{}/{}", "d".repeat(120), "f".repeat(90));
        let files: Vec<(String, Vec<u8>)> = vec![
            (
                "3-gold/samples.csv".into(),
                b"theta_i,theta_r\n1,2\n".to_vec(),
            ),
            ("3-gold/empty".into(), Vec::new()),
            (long, vec![7u8; 1500]),
        ];
        let mut tar = TarWriter::new(Vec::new());
        for (name, data) in &files {
            tar.append(name, data.len() as u64, 1, &mut data.as_slice())
                .unwrap();
        }
        let archive = tar.finish().unwrap();
        assert_eq!(archive.len() % BLOCK, 0);
        assert_eq!(entries(&archive), files);
    }

    #[test]
    fn names_that_fit_no_header_and_files_that_shrink_are_errors() {
        let mut tar = TarWriter::new(Vec::new());
        let err = tar
            .append(&"x".repeat(300), 0, 0, &mut io::empty())
            .unwrap_err();
        assert!(err.to_string().contains("too long"), "{err}");
        let err = tar.append("a", 10, 0, &mut &b"abc"[..]).unwrap_err();
        assert!(err.to_string().contains("3 of 10 bytes"), "{err}");
    }

    #[test]
    fn file_name_parts_keep_only_safe_characters() {
        assert_eq!(file_name_part("gold"), "gold");
        assert_eq!(file_name_part("blue green/../x\"y"), "blue_green_.._x_y");
        assert_eq!(file_name_part("..hidden"), "hidden");
    }
}
