//! Reading a strip at one column of a merged map: its rows' radiance and flags, their
//! mean or centre row, and how each channel curves over the rows.

use super::layout::STRIP_ROWS;
use super::sharp::Curvature;
use crate::hdr::HdrImage;

/// One strip's rows at one column: each row's radiance and flags.
#[derive(Debug, Clone, Copy)]
pub(super) struct StripRows {
    rgb: [[f64; 3]; STRIP_ROWS],
    flags: [[u8; 3]; STRIP_ROWS],
}

impl StripRows {
    pub(super) fn read(map: &HdrImage, x: usize, centre: usize) -> Self {
        let mut rows = StripRows {
            rgb: [[0.0; 3]; STRIP_ROWS],
            flags: [[0; 3]; STRIP_ROWS],
        };
        for (i, y) in (centre - STRIP_ROWS / 2..=centre + STRIP_ROWS / 2).enumerate() {
            rows.rgb[i] = map.pixel(x, y).map(f64::from);
            for c in 0..3 {
                rows.flags[i][c] = map.channel_flags(x, y, c);
            }
        }
        rows
    }

    /// How each channel curves over the rows, per unit of their pixels' `irradiance`.
    pub(super) fn curvatures(&self, irradiance: &[f64; STRIP_ROWS]) -> [Option<Curvature>; 3] {
        std::array::from_fn(|c| {
            self.reflected(c, irradiance)
                .and_then(|v| Curvature::of(&v))
        })
    }

    /// The rows' mean, each channel's flags OR-ed over the rows.
    pub(super) fn mean(&self) -> StripValue {
        let mut value = StripValue::default();
        for (rgb, flags) in self.rgb.iter().zip(&self.flags) {
            for c in 0..3 {
                value.rgb[c] += rgb[c] / STRIP_ROWS as f64;
                value.flags[c] |= flags[c];
            }
        }
        value
    }

    /// The centre row alone.
    pub(super) fn centre(&self) -> StripValue {
        StripValue {
            rgb: self.rgb[STRIP_ROWS / 2],
            flags: self.flags[STRIP_ROWS / 2],
        }
    }

    /// Channel `c` over the rows as radiance per unit irradiance (the rows' own
    /// `irradiance`), `None` if a row is flagged or unlit.
    fn reflected(&self, c: usize, irradiance: &[f64; STRIP_ROWS]) -> Option<[f64; STRIP_ROWS]> {
        let mut v = [0.0; STRIP_ROWS];
        for i in 0..STRIP_ROWS {
            if self.flags[i][c] != 0 || irradiance[i] <= 0.0 {
                return None;
            }
            v[i] = self.rgb[i][c] / irradiance[i];
        }
        Some(v)
    }
}

/// A strip's radiance at one column (the mean of its rows, or one row) with each
/// channel's flags.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StripValue {
    pub(super) rgb: [f64; 3],
    pub(super) flags: [u8; 3],
}
