//! Where the strips lie in a capture (full resolution or 2×2-superpixel raw) and in the
//! merged map, and the geometry their pixels see: the point on the cylinder, its normal,
//! the light and the camera ([`Setup::pixel_geometry`]). Angles in degrees.

use std::ops::Range;

use super::error::ExtractError;
use crate::brdf::Cosines;
use crate::geometry::{Lighting, PixelGeometry, Setup, SetupView};

/// Rows averaged around each strip's centre row (paper §2.2).
pub const STRIP_ROWS: usize = 5;

/// Sensor pixels per pixel of a `width`×`height` capture of `setup`'s sensor: 1 for
/// full resolution, 2 for 2×2-superpixel raw; other sizes are refused.
pub(crate) fn capture_scale(
    setup: &Setup,
    width: usize,
    height: usize,
    theta_l: f64,
) -> Result<usize, ExtractError> {
    let (sw, sh) = (setup.image_width as usize, setup.image_height as usize);
    if (width, height) == (sw, sh) {
        Ok(1)
    } else if (width, height) == (sw / 2, sh / 2) {
        Ok(2)
    } else {
        Err(ExtractError::SizeMismatch {
            theta_l,
            width,
            height,
            setup_width: setup.image_width,
            setup_height: setup.image_height,
        })
    }
}

/// Where the strips lie in a capture of a given size, and in the merged map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct StripLayout {
    /// Sensor pixels per capture pixel: 1, or 2 for superpixel raw.
    scale: usize,
    /// Centre rows of the strips in the capture.
    pub(super) sample_row: usize,
    pub(super) white_row: usize,
    /// Centre rows of the strips in the merged map (the capture's, or those of a map
    /// holding only [`StripLayout::bands`]).
    pub(super) sample_map_row: usize,
    pub(super) white_map_row: usize,
}

impl StripLayout {
    pub(super) fn new(
        setup: &Setup,
        width: usize,
        height: usize,
        theta_l: f64,
    ) -> Result<Self, ExtractError> {
        let scale = capture_scale(setup, width, height, theta_l)?;
        let row = |which: &'static str, sensor_row: u32| {
            let row = sensor_row as usize / scale;
            if row < STRIP_ROWS / 2 || row + STRIP_ROWS / 2 >= height {
                Err(ExtractError::RowOutside { which, row, height })
            } else {
                Ok(row)
            }
        };
        let (sample_row, white_row) = (
            row("sample", setup.sample_row)?,
            row("white", setup.white_row)?,
        );
        if sample_row.abs_diff(white_row) < STRIP_ROWS {
            return Err(ExtractError::StripsOverlap {
                sample: sample_row,
                white: white_row,
                rows: STRIP_ROWS,
            });
        }
        Ok(Self {
            scale,
            sample_row,
            white_row,
            sample_map_row: sample_row,
            white_map_row: white_row,
        })
    }

    /// The capture row ranges of the two strips (sample, then white).
    pub(super) fn bands(&self) -> Vec<Range<usize>> {
        let half = STRIP_ROWS / 2;
        [self.sample_row, self.white_row]
            .map(|centre| centre - half..centre + half + 1)
            .to_vec()
    }

    /// The same strips in a frame holding only [`StripLayout::bands`].
    pub(super) fn strips_only(self) -> Self {
        let half = STRIP_ROWS / 2;
        Self {
            sample_map_row: half,
            white_map_row: STRIP_ROWS + half,
            ..self
        }
    }

    /// Sensor coordinate of the centre of capture pixel `i` (a superpixel spans two).
    fn sensor(&self, i: usize) -> f64 {
        (self.scale * i) as f64 + (self.scale as f64 - 1.0) / 2.0
    }

    /// The values `pixel` gives the strip rows around capture row `centre` at sensor
    /// column `u`, top to bottom; `None` if any row's is.
    fn rows<T: Copy>(
        &self,
        u: f64,
        centre: usize,
        pixel: impl Fn(f64, f64) -> Option<T>,
    ) -> Option<[T; STRIP_ROWS]> {
        let first = centre - STRIP_ROWS / 2;
        let rows: [Option<T>; STRIP_ROWS] =
            std::array::from_fn(|i| pixel(u, self.sensor(first + i)));
        let mut all = [rows[0]?; STRIP_ROWS];
        for (to, row) in all.iter_mut().zip(rows) {
            *to = row?;
        }
        Some(all)
    }

    /// What column `x`'s strip pixels see through `view`: `None` if any of them misses
    /// the cylinder or is unlit.
    pub(super) fn strip_pixels(&self, view: &SetupView, x: usize) -> Option<StripPixels> {
        let u = self.sensor(x);
        Some(StripPixels {
            sample: self.rows(u, self.sample_row, |u, v| {
                view.pixel_geometry(u, v)
                    .filter(|g| g.irradiance > 0.0 && g.theta_i.abs() < 90.0)
            })?,
            white: self.rows(u, self.white_row, |u, v| view.lighting(u, v))?,
        })
    }

    /// Column `x`'s [`ColumnGeometry`] both ways a column is read, seen through `view`:
    /// `[mean of the sample rows, centre row alone]`; `None` as [`Self::strip_pixels`].
    pub(super) fn column_geometry(
        &self,
        view: &SetupView,
        x: usize,
    ) -> Option<[ColumnGeometry; 2]> {
        let pixels = self.strip_pixels(view, x)?;
        Some([false, true].map(|centre| pixels.column_geometry(centre)))
    }
}

/// What one column's strip pixels see, rows top to bottom: the sample's whole geometry,
/// the white's lighting.
#[derive(Debug, Clone, Copy)]
pub(super) struct StripPixels {
    pub(super) sample: [PixelGeometry; STRIP_ROWS],
    pub(super) white: [Lighting; STRIP_ROWS],
}

impl StripPixels {
    /// The column's [`ColumnGeometry`], its sample read as the mean of the rows or, with
    /// `centre`, the centre row alone.
    pub(super) fn column_geometry(&self, centre: bool) -> ColumnGeometry {
        let sample = if centre {
            std::slice::from_ref(&self.sample[STRIP_ROWS / 2])
        } else {
            &self.sample[..]
        };
        ColumnGeometry::new(sample, &self.white)
    }
}

/// The mean of `field` over `of` (never empty: a strip's rows, or its centre row).
fn mean<T>(of: &[T], field: impl Fn(&T) -> f64) -> f64 {
    of.iter().map(field).sum::<f64>() / of.len() as f64
}

/// The geometry of a column's sample (the mean of its strip pixels', or the centre
/// pixel's), the irradiance ratio Ē_white / E_sample of its two strips and the white's
/// angle of incidence.
#[derive(Debug, Clone, Copy)]
pub(super) struct ColumnGeometry {
    pub(super) theta_i: f64,
    pub(super) theta_r: f64,
    pub(super) cosines: Cosines,
    pub(super) irradiance_ratio: f64,
    /// Mean cosine of the angle of incidence on the white strip's pixels.
    pub(super) white_cos_i: f64,
}

impl ColumnGeometry {
    fn new(sample: &[PixelGeometry], white: &[Lighting]) -> Self {
        Self {
            theta_i: mean(sample, |g| g.theta_i),
            theta_r: mean(sample, |g| g.theta_r),
            cosines: Cosines {
                n_dot_l: mean(sample, |g| g.cosines.n_dot_l),
                n_dot_v: mean(sample, |g| g.cosines.n_dot_v),
                n_dot_h: mean(sample, |g| g.cosines.n_dot_h),
                v_dot_h: mean(sample, |g| g.cosines.v_dot_h),
            },
            irradiance_ratio: mean(white, |l| l.irradiance) / mean(sample, |g| g.irradiance),
            white_cos_i: mean(white, |l| l.n_dot_l),
        }
    }

    /// The fields as one array: θi, θr, n·l, n·v, n·h, v·h, irradiance ratio, white cos θi.
    pub(super) fn to_array(self) -> [f64; 8] {
        let c = self.cosines;
        [
            self.theta_i,
            self.theta_r,
            c.n_dot_l,
            c.n_dot_v,
            c.n_dot_h,
            c.v_dot_h,
            self.irradiance_ratio,
            self.white_cos_i,
        ]
    }

    /// The inverse of [`Self::to_array`].
    pub(super) fn from_array(a: [f64; 8]) -> Self {
        Self {
            theta_i: a[0],
            theta_r: a[1],
            cosines: Cosines {
                n_dot_l: a[2],
                n_dot_v: a[3],
                n_dot_h: a[4],
                v_dot_h: a[5],
            },
            irradiance_ratio: a[6],
            white_cos_i: a[7],
        }
    }
}
