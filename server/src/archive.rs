//! A whole scan as one POSIX tar archive (pax), written entry by entry so that
//! `GET /api/scans/{id}/archive` streams it without holding it in memory. Any name a
//! directory may hold is kept byte for byte: one of at most 100 bytes in the ustar
//! header, a longer one in a pax extended header (`path`, with `hdrcharset=BINARY`
//! when it is not UTF-8); a file of 8 GiB or more has its size there too.

use std::io::{self, Read, Write};

/// Bytes of a tar block; headers and file data are padded to it.
const BLOCK: usize = 512;
/// Longest name the ustar header's `name` field holds.
const NAME_LEN: usize = 100;
/// Sizes from this on do not fit the header's 11 octal digits.
const OCTAL_SIZE_LIMIT: u64 = 1 << 33;

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

    /// Adds a regular file `name` (relative, `/`-separated, any bytes but NUL) with the
    /// bytes of `data`, `size` of them, last modified at `mtime` (Unix seconds).
    pub fn append(
        &mut self,
        name: &[u8],
        size: u64,
        mtime: u64,
        data: &mut impl Read,
    ) -> io::Result<()> {
        let mut records = Vec::new();
        if name.len() > NAME_LEN {
            if std::str::from_utf8(name).is_err() {
                records.extend(pax_record(b"hdrcharset", b"BINARY"));
            }
            records.extend(pax_record(b"path", name));
        }
        if size >= OCTAL_SIZE_LIMIT {
            records.extend(pax_record(b"size", size.to_string().as_bytes()));
        }
        let short = &name[..name.len().min(NAME_LEN)];
        if !records.is_empty() {
            self.out
                .write_all(&header(short, records.len() as u64, mtime, b'x'))?;
            self.write_padded(&records)?;
        }
        let octal_size = if size < OCTAL_SIZE_LIMIT { size } else { 0 };
        self.out
            .write_all(&header(short, octal_size, mtime, b'0'))?;
        let copied = io::copy(&mut data.take(size), &mut self.out)?;
        if copied != size {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                format!(
                    "{}: {copied} of {size} bytes read (the file shrank)",
                    String::from_utf8_lossy(name)
                ),
            ));
        }
        self.pad(size)
    }

    /// Writes `bytes` and pads them to a whole block.
    fn write_padded(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.out.write_all(bytes)?;
        self.pad(bytes.len() as u64)
    }

    /// Pads `written` bytes of data to a whole block.
    fn pad(&mut self, written: u64) -> io::Result<()> {
        let pad = (BLOCK - (written % BLOCK as u64) as usize) % BLOCK;
        self.out.write_all(&[0; BLOCK][..pad])
    }

    /// Writes the two zero blocks that end an archive and returns the writer.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.write_all(&[0; 2 * BLOCK])?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// One pax record, `"<length> <key>=<value>\n"`, its length counting its own digits.
fn pax_record(key: &[u8], value: &[u8]) -> Vec<u8> {
    let rest = key.len() + value.len() + 3;
    let mut length = rest + 1;
    while length != rest + length.to_string().len() {
        length = rest + length.to_string().len();
    }
    let mut record = length.to_string().into_bytes();
    record.push(b' ');
    record.extend_from_slice(key);
    record.push(b'=');
    record.extend_from_slice(value);
    record.push(b'\n');
    record
}

/// A ustar header block of type `kind` (`0` a regular file, `x` a pax extended header)
/// for `name` (at most [`NAME_LEN`] bytes).
fn header(name: &[u8], size: u64, mtime: u64, kind: u8) -> [u8; BLOCK] {
    let mut block = [0u8; BLOCK];
    block[..name.len()].copy_from_slice(name);
    octal(&mut block[100..108], 0o644);
    octal(&mut block[108..116], 0);
    octal(&mut block[116..124], 0);
    octal(&mut block[124..136], size);
    octal(&mut block[136..148], mtime);
    block[156] = kind;
    block[257..263].copy_from_slice(b"ustar\0");
    block[263..265].copy_from_slice(b"00");
    // The checksum is computed with its own field as spaces.
    block[148..156].fill(b' ');
    let sum: u64 = block.iter().map(|&b| u64::from(b)).sum();
    octal(&mut block[148..155], sum);
    block
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

    /// The entries of a pax archive: (name, data), read back by the format's rules.
    fn entries(archive: &[u8]) -> Vec<(Vec<u8>, Vec<u8>)> {
        let field = |field: &[u8]| {
            let end = field.iter().position(|&b| b == 0).unwrap_or(field.len());
            field[..end].to_vec()
        };
        let number = |bytes: &[u8]| {
            u64::from_str_radix(String::from_utf8(field(bytes)).unwrap().trim(), 8).unwrap()
        };
        let mut out = Vec::new();
        let mut at = 0;
        let mut long_name = None;
        while archive[at..at + BLOCK].iter().any(|&b| b != 0) {
            let block = &archive[at..at + BLOCK];
            let mut stored = block.to_vec();
            stored[148..156].fill(b' ');
            let sum: u64 = stored.iter().map(|&b| u64::from(b)).sum();
            assert_eq!(number(&block[148..155]), sum);
            let size = number(&block[124..135]) as usize;
            let data = archive[at + BLOCK..at + BLOCK + size].to_vec();
            at += BLOCK + size.div_ceil(BLOCK) * BLOCK;
            if block[156] == b'x' {
                let mut rest = data.as_slice();
                while !rest.is_empty() {
                    let space = rest.iter().position(|&b| b == b' ').unwrap();
                    let length: usize = std::str::from_utf8(&rest[..space])
                        .unwrap()
                        .parse()
                        .unwrap();
                    let record = &rest[space + 1..length - 1];
                    let equals = record.iter().position(|&b| b == b'=').unwrap();
                    if &record[..equals] == b"path" {
                        long_name = Some(record[equals + 1..].to_vec());
                    }
                    rest = &rest[length..];
                }
                continue;
            }
            assert_eq!(block[156], b'0');
            let name = long_name.take().unwrap_or_else(|| field(&block[..100]));
            out.push((name, data));
        }
        assert!(archive[at..].iter().all(|&b| b == 0) && archive.len() - at >= 2 * BLOCK);
        out
    }

    #[test]
    fn entries_read_back_with_any_name_and_sizes_off_the_block() {
        let files: Vec<(Vec<u8>, Vec<u8>)> = vec![
            (
                b"3-gold/samples.csv".to_vec(),
                b"theta_i,theta_r\n1,2\n".to_vec(),
            ),
            (b"3-gold/empty".to_vec(), Vec::new()),
            (
                format!("{}/{}", "d".repeat(120), "f".repeat(255)).into_bytes(),
                vec![7u8; 1500],
            ),
            (b"3-gold/quote\"new\nline\xff".to_vec(), b"odd".to_vec()),
            ([&b"3-gold/"[..], &[0xfe; 200]].concat(), b"binary".to_vec()),
            // A record whose length gains a digit with its own length (99 → 100).
            ("x".repeat(92).into_bytes(), b"edge".to_vec()),
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
    fn pax_records_count_their_own_length() {
        for value in [0, 1, 80, 85, 86, 95, 96, 990, 995] {
            let record = pax_record(b"path", &vec![b'a'; value]);
            let space = record.iter().position(|&b| b == b' ').unwrap();
            let length: usize = std::str::from_utf8(&record[..space])
                .unwrap()
                .parse()
                .unwrap();
            assert_eq!(length, record.len(), "value of {value} bytes");
        }
    }

    #[test]
    fn sizes_beyond_the_octal_field_go_to_a_pax_record() {
        // The headers are written before the data, which runs short at once.
        let size = OCTAL_SIZE_LIMIT + 3;
        let mut head = Vec::new();
        let mut tar = TarWriter::new(&mut head);
        let err = tar.append(b"big", size, 0, &mut io::empty()).unwrap_err();
        assert!(
            err.to_string().contains(&format!("0 of {size} bytes")),
            "{err}"
        );
        assert_eq!(head.len(), 3 * BLOCK);
        assert_eq!(head[156], b'x');
        let record = pax_record(b"size", size.to_string().as_bytes());
        assert_eq!(&head[BLOCK..BLOCK + record.len()], record.as_slice());
        assert_eq!(head[2 * BLOCK + 156], b'0');
        assert_eq!(&head[2 * BLOCK..2 * BLOCK + 3], b"big");
    }

    #[test]
    fn files_that_shrink_are_errors() {
        let mut tar = TarWriter::new(Vec::new());
        let err = tar.append(b"a", 10, 0, &mut &b"abc"[..]).unwrap_err();
        assert!(err.to_string().contains("3 of 10 bytes"), "{err}");
    }

    #[test]
    fn file_name_parts_keep_only_safe_characters() {
        assert_eq!(file_name_part("gold"), "gold");
        assert_eq!(file_name_part("blue green/../x\"y"), "blue_green_.._x_y");
        assert_eq!(file_name_part("..hidden"), "hidden");
    }
}
