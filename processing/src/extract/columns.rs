//! One θL's samples from its merged strips: per column the strips' geometry and values
//! (five-row means, or the centre row on a sharp peak), the drops, and per channel
//! β_c = (L̄_sample,c / L̄_white,c) · (Ē_white / Ē_sample) · ρ_white · f_white(θi) · W_c,
//! f_white the white's reflectance factor at its pixels' angle of incidence
//! ([`crate::white_angular`]).

use rayon::prelude::*;

use super::drops::{DropCounts, DropReason};
use super::layout::{ColumnGeometry, StripLayout, StripPixels, STRIP_ROWS};
use super::options::ExtractOptions;
use super::sharp::{is_sharp, pooled_row_noise, Curvature};
use super::strip::{StripRows, StripValue};
use crate::geometry::Setup;
use crate::hdr::HdrImage;
use crate::samples::{Sample, SampleUncertainty};

/// One column before the samples are made: what its strip pixels see (`None` off the
/// cylinder or unlit), its strips' rows, and how each strip curves per channel.
struct Column {
    pixels: Option<StripPixels>,
    sample: StripRows,
    white: StripRows,
    curvature: [Option<Curvature>; 3],
    white_curvature: [Option<Curvature>; 3],
}

impl Column {
    /// The sample's geometry and the two strips' values: five-row means, or on a
    /// sharp peak the sample strip's centre row with that pixel's geometry.
    fn read(&self, sharp: bool) -> Option<(ColumnGeometry, StripValue, StripValue)> {
        let geometry = self.pixels.as_ref()?.column_geometry(sharp);
        let sample = if sharp {
            self.sample.centre()
        } else {
            self.sample.mean()
        };
        Some((geometry, sample, self.white.mean()))
    }
}

/// One θL's samples and what was made of its columns.
pub(super) struct ThetaSamples {
    pub(super) samples: Vec<Sample>,
    /// The image column of each sample.
    pub(super) columns: Vec<usize>,
    pub(super) dropped: DropCounts,
    /// Samples read from the centre row (sharp peaks).
    pub(super) centre_rows: usize,
    /// Per sample, the relative change of β for +1 standard uncertainty of the white's
    /// angular dependence: u_f / f at the white's angle of incidence.
    pub(super) white_angular: Vec<f64>,
    /// Per sample, the geometry it was given and whether it was read from the centre row.
    pub(super) geometry: Vec<ColumnGeometry>,
    pub(super) centre_row: Vec<bool>,
}

/// The samples of one θL's strips in `map` with `setup`.
pub(super) fn extract_theta(
    setup: &Setup,
    map: &HdrImage,
    layout: &StripLayout,
    theta_l: f64,
    options: &ExtractOptions,
    white_reflectance: f64,
) -> ThetaSamples {
    let view = setup.view(theta_l);
    let columns: Vec<Column> = (0..map.width)
        .into_par_iter()
        .map(|x| {
            let pixels = layout.strip_pixels(&view, x);
            let sample = StripRows::read(map, x, layout.sample_map_row);
            let white = StripRows::read(map, x, layout.white_map_row);
            let (curvature, white_curvature) = match &pixels {
                Some(p) => (
                    sample.curvatures(&p.sample.map(|g| g.irradiance)),
                    white.curvatures(&p.white.map(|l| l.irradiance)),
                ),
                None => ([None; 3], [None; 3]),
            };
            Column {
                pixels,
                sample,
                white,
                curvature,
                white_curvature,
            }
        })
        .collect();
    let noise = pooled_row_noise(&columns.iter().map(|c| c.curvature).collect::<Vec<_>>());
    let white_noise = pooled_row_noise(
        &columns
            .iter()
            .map(|c| c.white_curvature)
            .collect::<Vec<_>>(),
    );
    let sharp: Vec<bool> = columns
        .iter()
        .zip(&noise)
        .map(|(column, noise)| is_sharp(&column.curvature, noise))
        .collect();
    let columns: Vec<_> = columns
        .iter()
        .zip(&sharp)
        .zip(noise.iter().zip(&white_noise))
        .map(|((column, &sharp), (&noise, &white_noise))| {
            column.read(sharp).map(|read| {
                // One row's relative noise over the rows averaged, both strips.
                let rows = if sharp { 1.0 } else { STRIP_ROWS as f64 };
                let relative: [f64; 3] = std::array::from_fn(|c| {
                    (noise[c] * noise[c] / rows
                        + white_noise[c] * white_noise[c] / STRIP_ROWS as f64)
                        .sqrt()
                });
                (read, sharp, relative)
            })
        })
        .collect();
    // The brightest usable white of each channel, for the too-dark threshold.
    let mut brightest_white = [0.0f64; 3];
    for ((_, _, white), _, _) in columns.iter().flatten() {
        for (c, brightest) in brightest_white.iter_mut().enumerate() {
            if white.flags[c] == 0 {
                *brightest = brightest.max(white.rgb[c]);
            }
        }
    }
    let threshold = brightest_white.map(|w| options.min_white_fraction * w);
    let white_rgb = options.camera.white_rgb();
    let limit = options.grazing_limit_deg;

    let angular = setup.white_angular();
    let mut samples = Vec::new();
    let mut sample_columns = Vec::new();
    let mut white_angular = Vec::new();
    let mut geometry = Vec::new();
    let mut centre_row = Vec::new();
    let mut dropped = DropCounts::default();
    let mut centre_rows = 0;
    for (x, column) in columns.into_iter().enumerate() {
        let Some(((g, sample, white), sharp, relative_noise)) = column else {
            dropped.off_cylinder += 1;
            continue;
        };
        if g.theta_i.abs() > limit || g.theta_r.abs() > limit {
            dropped.grazing += 1;
            continue;
        }
        let mut point = Sample {
            theta_l,
            theta_i: g.theta_i,
            theta_r: g.theta_r,
            cosines: Some(g.cosines),
            ..Sample::default()
        };
        let mut noise = [0.0; 3];
        // The factor stays within [0.5, 1.5] for a valid falloff and in (0, 2] for a
        // valid table.
        let (factor, factor_change) = angular.at(g.white_cos_i);
        for c in 0..3 {
            match DropReason::of(&sample, &white, c, threshold[c]) {
                Some(reason) => {
                    dropped.count(reason, c);
                    point.dropped[c] = true;
                }
                None => {
                    point.rgb[c] = sample.rgb[c] / white.rgb[c]
                        * g.irradiance_ratio
                        * white_reflectance
                        * factor
                        * white_rgb[c];
                    noise[c] = point.rgb[c] * relative_noise[c];
                }
            }
        }
        if point.dropped.iter().all(|&d| d) {
            dropped.no_channel += 1;
        } else {
            centre_rows += usize::from(sharp);
            if options.uncertainty {
                point.uncertainty = Some(SampleUncertainty {
                    noise,
                    ..SampleUncertainty::default()
                });
            }
            samples.push(point);
            sample_columns.push(x);
            white_angular.push(if factor > 0.0 {
                factor_change / factor
            } else {
                0.0
            });
            geometry.push(g);
            centre_row.push(sharp);
        }
    }
    ThetaSamples {
        samples,
        columns: sample_columns,
        dropped,
        centre_rows,
        white_angular,
        geometry,
        centre_row,
    }
}
