//! A bounded walk over the image file directories (IFDs) of a TIFF-structured file
//! (TIFF, and the camera raw formats built on it: NEF, DNG, CR2, ARW, PEF, ORF, RW2),
//! to learn, before a decoder allocates for them, the largest image any of them claims
//! and the largest value any entry claims (a decoder reads an entry's `count` values
//! into a buffer of that size, so a count beyond the file is refused here).
//! Reads at most [`MAX_IFDS`] directories of at most [`MAX_ENTRIES`] entries each,
//! follows the next-IFD chain, SubIFDs, the Exif IFD and the TIFF structure embedded in
//! a Nikon maker note, and never loops; it reports an IFD reached twice, since a decoder
//! that follows the same pointers would go round that loop without end.

/// Most IFDs visited in one file.
const MAX_IFDS: usize = 256;
/// Most entries read from one IFD.
const MAX_ENTRIES: usize = 4096;

const IMAGE_WIDTH: u16 = 256;
const IMAGE_LENGTH: u16 = 257;
const SAMPLES_PER_PIXEL: u16 = 277;
const SUB_IFDS: u16 = 330;
const EXIF_IFD: u16 = 34665;
/// GPS and ICC-profile tags, which rawler's TIFF reader also follows as IFD pointers.
const GPS_IFD: u16 = 34853;
const ICC_PROFILE: u16 = 34675;
/// Panasonic RW2 sensor size tags (IFD0 of a file with magic 0x55).
const RW2_SENSOR_WIDTH: u16 = 2;
const RW2_SENSOR_HEIGHT: u16 = 3;
const RW2_MAGIC: u16 = 0x55;
const MAKER_NOTE: u16 = 37500;
/// A Nikon maker note: this prefix, then a whole TIFF structure whose offsets count from
/// its own header at [`NIKON_TIFF_AT`].
const NIKON_PREFIX: &[u8] = b"Nikon\0";
const NIKON_TIFF_AT: usize = 10;
/// Most maker notes walked inside one another.
const MAX_NESTING: usize = 2;

/// Bytes per value of a TIFF field type (1 for types a decoder would refuse anyway).
fn type_size(field_type: u16) -> u64 {
    match field_type {
        3 | 8 => 2,
        4 | 9 | 11 | 13 => 4,
        5 | 10 | 12 | 16..=18 => 8,
        _ => 1,
    }
}

/// The largest image an IFD of the file claims.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Claim {
    pub width: u64,
    pub height: u64,
    /// Samples per pixel (1 for a mosaic).
    pub samples: u64,
    /// The largest value any entry claims (count × bytes per value), and its tag.
    pub largest_entry: (u64, u16),
    /// The offset of the first IFD reached a second time, if any.
    pub revisited: Option<usize>,
    /// The largest SamplesPerPixel any entry states, in any IFD (a decoder sizes its
    /// per-sample levels by it, whatever image it belongs to).
    pub max_samples: u64,
}

impl Claim {
    /// Pixels × samples, saturating.
    pub fn values(&self) -> u64 {
        self.width
            .saturating_mul(self.height)
            .saturating_mul(self.samples.max(1))
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    little: bool,
}

impl Reader<'_> {
    fn u16(&self, at: usize) -> Option<u16> {
        let b: [u8; 2] = self.bytes.get(at..at.checked_add(2)?)?.try_into().ok()?;
        Some(if self.little {
            u16::from_le_bytes(b)
        } else {
            u16::from_be_bytes(b)
        })
    }

    fn u32(&self, at: usize) -> Option<u32> {
        let b: [u8; 4] = self.bytes.get(at..at.checked_add(4)?)?.try_into().ok()?;
        Some(if self.little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    /// Where the values of the entry at `entry` are: in its 4-byte field when they fit,
    /// else at the offset that field holds.
    fn values_at(&self, entry: usize) -> Option<usize> {
        let count = u64::from(self.u32(entry + 4)?);
        if count.saturating_mul(type_size(self.u16(entry + 2)?)) <= 4 {
            Some(entry + 8)
        } else {
            self.u32(entry + 8).map(|o| o as usize)
        }
    }

    /// The first value of an integer entry at `entry`, wherever it is stored, as a
    /// decoder reads it: signed values widened from their two's complement, so a
    /// negative size counts as a huge one.
    fn scalar(&self, entry: usize) -> Option<u64> {
        let at = self.values_at(entry)?;
        let u64_at = |at: usize| -> Option<u64> {
            let (lo, hi) = (self.u32(at)?, self.u32(at + 4)?);
            let (lo, hi) = if self.little { (lo, hi) } else { (hi, lo) };
            Some(u64::from(lo) | (u64::from(hi) << 32))
        };
        match self.u16(entry + 2)? {
            1 => self.bytes.get(at).map(|&b| u64::from(b)),
            6 => self.bytes.get(at).map(|&b| i64::from(b as i8) as u64),
            3 => self.u16(at).map(u64::from),
            8 => self.u16(at).map(|v| i64::from(v as i16) as u64),
            4 | 13 => self.u32(at).map(u64::from),
            9 => self.u32(at).map(|v| i64::from(v as i32) as u64),
            16..=18 => u64_at(at),
            // Rationals and floats as rawler converts them: through f32 (f64 for a
            // DOUBLE), saturating, so n/0 reads as the largest size.
            5 => Some((self.u32(at)? as f32 / self.u32(at + 4)? as f32) as u64),
            10 => Some((self.u32(at)? as i32 as f32 / self.u32(at + 4)? as i32 as f32) as u64),
            11 => Some(f32::from_bits(self.u32(at)?) as u64),
            12 => Some(f64::from_bits(u64_at(at)?) as u64),
            _ => None,
        }
    }

    /// Where rawler looks for an IFD when a pointer entry has another type than LONG,
    /// reading its values as bytes (inline when at most 4): at the values of an
    /// UNDEFINED entry, at the value of the first byte of one of an unknown type (0, or
    /// above 12, the IFD type 13 included).
    fn odd_pointer(&self, entry: usize) -> Option<usize> {
        let field_type = self.u16(entry + 2)?;
        if !(field_type == 0 || field_type == 7 || field_type > 12) {
            return None;
        }
        let at = if self.u32(entry + 4)? <= 4 {
            entry + 8
        } else {
            self.u32(entry + 8)? as usize
        };
        if field_type == 7 {
            Some(at)
        } else {
            self.bytes.get(at).map(|&b| usize::from(b))
        }
    }

    /// The offsets an IFD-pointer entry (LONG or IFD type) at `entry` lists.
    fn offsets(&self, entry: usize) -> Vec<usize> {
        let count = self.u32(entry + 4).unwrap_or(0) as usize;
        let count = count.min(MAX_IFDS);
        if count <= 1 {
            return self
                .u32(entry + 8)
                .map(|o| o as usize)
                .into_iter()
                .collect();
        }
        let Some(base) = self.u32(entry + 8) else {
            return Vec::new();
        };
        (0..count)
            .filter_map(|k| self.u32(base as usize + 4 * k).map(|o| o as usize))
            .collect()
    }
}

/// The largest image claimed by any IFD, or `None` when `bytes` do not start like a
/// TIFF-structured file (BigTIFF included in that: its directories are not walked).
pub fn largest_claim(bytes: &[u8]) -> Option<Claim> {
    walk(bytes, 0)
}

fn walk(bytes: &[u8], nesting: usize) -> Option<Claim> {
    let little = match bytes.get(..2)? {
        b"II" => true,
        b"MM" => false,
        _ => return None,
    };
    let r = Reader { bytes, little };
    let magic = r.u16(2)?;
    if magic == 43 {
        return None;
    }
    let mut queue = vec![r.u32(4)? as usize];
    let mut visited = Vec::new();
    let mut largest = Claim::default();
    let mut largest_entry = (0, 0);
    let mut revisited = None;
    let mut max_samples = 0;
    while let Some(offset) = queue.pop() {
        if visited.contains(&offset) {
            revisited.get_or_insert(offset);
            continue;
        }
        if visited.len() >= MAX_IFDS {
            continue;
        }
        visited.push(offset);
        let Some(count) = r.u16(offset) else {
            continue;
        };
        let mut claim = Claim {
            samples: 1,
            ..Claim::default()
        };
        for k in 0..usize::from(count).min(MAX_ENTRIES) {
            let entry = offset + 2 + 12 * k;
            let Some(tag) = r.u16(entry) else {
                break;
            };
            let values = u64::from(r.u32(entry + 4).unwrap_or(0));
            let size = values.saturating_mul(type_size(r.u16(entry + 2).unwrap_or(0)));
            if size > largest_entry.0 {
                largest_entry = (size, tag);
            }
            match tag {
                // A size given twice counts with its larger value; one whose value
                // cannot be read counts as nothing.
                IMAGE_WIDTH => claim.width = claim.width.max(r.scalar(entry).unwrap_or(0)),
                IMAGE_LENGTH => claim.height = claim.height.max(r.scalar(entry).unwrap_or(0)),
                RW2_SENSOR_WIDTH if magic == RW2_MAGIC => {
                    claim.width = claim.width.max(r.scalar(entry).unwrap_or(0))
                }
                RW2_SENSOR_HEIGHT if magic == RW2_MAGIC => {
                    claim.height = claim.height.max(r.scalar(entry).unwrap_or(0))
                }
                SAMPLES_PER_PIXEL => {
                    // An unknown type counts as its raw 4-byte field, the largest reading.
                    let samples = r
                        .scalar(entry)
                        .unwrap_or_else(|| u64::from(r.u32(entry + 8).unwrap_or(1)));
                    claim.samples = claim.samples.max(samples);
                    max_samples = max_samples.max(samples);
                }
                SUB_IFDS | EXIF_IFD | GPS_IFD | ICC_PROFILE => {
                    queue.extend(r.offsets(entry));
                    queue.extend(r.odd_pointer(entry));
                }
                MAKER_NOTE if nesting < MAX_NESTING => {
                    let note = r
                        .u32(entry + 8)
                        .map_or(&[][..], |at| bytes.get(at as usize..).unwrap_or_default());
                    let inner = note
                        .starts_with(NIKON_PREFIX)
                        .then(|| note.get(NIKON_TIFF_AT..))
                        .flatten()
                        .and_then(|tiff| walk(tiff, nesting + 1));
                    if let Some(inner) = inner {
                        if inner.largest_entry.0 > largest_entry.0 {
                            largest_entry = inner.largest_entry;
                        }
                        revisited = revisited.or(inner.revisited);
                        max_samples = max_samples.max(inner.max_samples);
                        if inner.values() > largest.values() {
                            largest = inner;
                        }
                    }
                }
                _ => {}
            }
        }
        if claim.values() > largest.values() {
            largest = claim;
        }
        // A next-IFD pointer of 0 ends the chain; a sub-IFD pointer of 0 is followed,
        // as a decoder follows it.
        if let Some(next) = r
            .u32(offset + 2 + 12 * usize::from(count))
            .filter(|&n| n != 0)
        {
            queue.push(next as usize);
        }
    }
    Some(Claim {
        largest_entry,
        revisited,
        max_samples,
        ..largest
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian TIFF whose IFD0 points to a SubIFD claiming `w`×`h`, and whose
    /// next-IFD pointer loops back to IFD0.
    fn nested(w: u32, h: u32) -> Vec<u8> {
        let mut b = b"II*\0\x08\0\0\0".to_vec();
        // IFD0 at 8: 2 entries (width 10, SubIFDs -> 38), next -> 8 (a loop).
        b.extend(2u16.to_le_bytes());
        b.extend([0, 1, 3, 0, 1, 0, 0, 0, 10, 0, 0, 0]);
        b.extend([0x4a, 1, 4, 0, 1, 0, 0, 0, 38, 0, 0, 0]);
        b.extend(8u32.to_le_bytes());
        assert_eq!(b.len(), 38);
        b.extend(2u16.to_le_bytes());
        b.extend([0, 1, 4, 0, 1, 0, 0, 0]);
        b.extend(w.to_le_bytes());
        b.extend([1, 1, 4, 0, 1, 0, 0, 0]);
        b.extend(h.to_le_bytes());
        b.extend(0u32.to_le_bytes());
        b
    }

    /// A little-endian TIFF whose only IFD, at 8, holds `entries` (next IFD 0), followed
    /// by `tail` (at offset 14 + 12 × entries).
    fn little_tiff(entries: &[[u8; 12]], tail: &[u8]) -> Vec<u8> {
        let mut b = b"II*\0\x08\0\0\0".to_vec();
        b.extend((entries.len() as u16).to_le_bytes());
        for entry in entries {
            b.extend(entry);
        }
        b.extend([0, 0, 0, 0]);
        b.extend(tail);
        b
    }

    #[test]
    fn finds_the_largest_claim_in_sub_ifds_and_survives_loops() {
        let claim = largest_claim(&nested(70_000, 60_000)).unwrap();
        assert_eq!(
            (claim.width, claim.height, claim.samples),
            (70_000, 60_000, 1)
        );
        assert_eq!(claim.largest_entry, (4, 330));
        assert_eq!(claim.revisited, Some(8));
        assert_eq!(largest_claim(b"not a tiff"), None);
        // Truncated anywhere: still an answer, never a panic.
        let full = nested(5, 5);
        for cut in 0..full.len() {
            let _ = largest_claim(&full[..cut]);
        }
    }

    /// A value count beyond the file, in IFD0 or in a Nikon maker note's own TIFF.
    #[test]
    fn finds_the_largest_entry_in_ifds_and_nikon_maker_notes() {
        // IFD0 at 8: one Make (ASCII) entry with 0xFFFF_F81A values, next -> 0.
        let mut plain = b"MM\0*\0\0\0\x08\0\x01".to_vec();
        plain.extend([0x01, 0x0f, 0, 2, 0xff, 0xff, 0xf8, 0x1a, 0, 0, 0, 26]);
        plain.extend([0, 0, 0, 0]);
        assert_eq!(
            largest_claim(&plain).unwrap().largest_entry,
            (0xFFFF_F81A, 0x010f)
        );
        // IFD0 holds a maker note (UNDEFINED, 30 bytes at 26); inside, after "Nikon\0"
        // and 4 bytes, a TIFF whose IFD claims 2^30 RATIONALs under tag 0x0097.
        let mut nested = b"II*\0\x08\0\0\0\x01\0".to_vec();
        nested.extend([0x7c, 0x92, 7, 0, 30, 0, 0, 0, 26, 0, 0, 0]);
        nested.extend([0, 0, 0, 0]);
        assert_eq!(nested.len(), 26);
        nested.extend(b"Nikon\0\x02\x10\0\0");
        nested.extend(b"II*\0\x08\0\0\0\x01\0");
        nested.extend([0x97, 0, 5, 0, 0, 0, 0, 0x40, 0, 0, 0, 0]);
        nested.extend([0, 0, 0, 0]);
        assert_eq!(
            largest_claim(&nested).unwrap().largest_entry,
            (8 << 30, 0x0097)
        );
    }

    /// Every SamplesPerPixel entry counts, a repeated one and one of an unknown type too.
    #[test]
    fn the_largest_samples_per_pixel_of_any_entry_is_kept() {
        // IFD0 at 8 with 3 entries: SamplesPerPixel as SHORT 3, as LONG 4 294 901 766,
        // and as an unknown type 99 whose field holds 70 000.
        let b = little_tiff(
            &[
                [0x15, 1, 3, 0, 1, 0, 0, 0, 3, 0, 0, 0],
                [0x15, 1, 4, 0, 1, 0, 0, 0, 6, 0, 0xff, 0xff],
                [0x15, 1, 99, 0, 1, 0, 0, 0, 0x70, 0x11, 1, 0],
            ],
            &[],
        );
        assert_eq!(largest_claim(&b).unwrap().max_samples, 0xFFFF_0006);
        assert_eq!(largest_claim(&nested(5, 5)).unwrap().max_samples, 0);
    }

    /// Sub-IFD pointers of other types are followed where rawler follows them, and
    /// sizes given as rationals or floats are read as it converts them.
    #[test]
    fn odd_pointers_and_sizes_are_read_as_rawler_reads_them() {
        // IFD0 at 8 with 2 entries: SubIFDs of type 99 (its first byte, 0, is where
        // rawler reads an IFD: the header, 18 761 entries, cut at 4096), SamplesPerPixel
        // as the SRATIONAL 3/0 at offset 38.
        let b = little_tiff(
            &[
                [0x4a, 1, 99, 0, 1, 0, 0, 0, 0, 1, 1, 0],
                [0x15, 1, 10, 0, 1, 0, 0, 0, 38, 0, 0, 0],
            ],
            &[3, 0, 0, 0, 0, 0, 0, 0],
        );
        let claim = largest_claim(&b).unwrap();
        assert_eq!(claim.max_samples, u64::MAX);
        // The header read as an entry: tag 0x2a, type 8 (SSHORT), count 0x0002_0000.
        assert_eq!(claim.largest_entry, (2 * 0x0002_0000, 0x2a));
        // An UNDEFINED pointer leads to its own value field: an IFD of 0 entries.
        let u = little_tiff(&[[0x4a, 1, 7, 0, 4, 0, 0, 0, 0, 0, 0, 0]], &[]);
        let reader = Reader {
            bytes: &u,
            little: true,
        };
        assert_eq!(reader.odd_pointer(10), Some(18));
        // A FLOAT width of 1e30 saturates (height 1).
        let mut width = [0, 1, 11, 0, 1, 0, 0, 0, 0, 0, 0, 0];
        width[8..].copy_from_slice(&1e30f32.to_bits().to_le_bytes());
        let f = little_tiff(&[width, [1, 1, 3, 0, 1, 0, 0, 0, 1, 0, 0, 0]], &[]);
        assert_eq!(largest_claim(&f).unwrap().width, u64::MAX);
        // A GPS IFD pointer (LONG, to 26) is followed like a SubIFDs one.
        let mut gps_ifd = vec![1, 0, 0x97, 0, 5, 0, 0, 0, 0, 0x40, 0, 0, 0, 0];
        gps_ifd.extend([0, 0, 0, 0]);
        let g = little_tiff(&[[0x25, 0x88, 4, 0, 1, 0, 0, 0, 26, 0, 0, 0]], &gps_ifd);
        assert_eq!(largest_claim(&g).unwrap().largest_entry, (8 << 30, 0x0097));
    }

    /// A size stored out of line (count above one) is read where the decoder reads it.
    #[test]
    fn sizes_stored_out_of_line_are_read_at_their_offset() {
        // IFD0 at 8 with 2 entries: width as 2 LONGs at offset 38 (70 000, 1), height 1.
        let mut b = b"II*\0\x08\0\0\0\x02\0".to_vec();
        b.extend([0, 1, 4, 0, 2, 0, 0, 0, 38, 0, 0, 0]);
        b.extend([1, 1, 8, 0, 1, 0, 0, 0, 0xff, 0xff, 0, 0]);
        b.extend([0, 0, 0, 0]);
        assert_eq!(b.len(), 38);
        b.extend(70_000u32.to_le_bytes());
        b.extend(1u32.to_le_bytes());
        let claim = largest_claim(&b).unwrap();
        assert_eq!(claim.width, 70_000);
        // A height of −1 (SSHORT) is as large as a decoder taking it unsigned would make it.
        assert_eq!(claim.height, u64::MAX);
    }
}
