//! Each sample's sensitivity to the setup's uncertain inputs: the white reflectance
//! scales β, its angular dependence scales it by u_f/f at the white's angle of incidence;
//! a geometric source is moved by ± one standard uncertainty and the strips extracted
//! again (slopes per radian of signed θh).

use rayon::prelude::*;

use super::columns::{extract_theta, ThetaSamples};
use super::layout::StripLayout;
use super::options::ExtractOptions;
use super::sharp::NOISE_NEIGHBOURS;
use crate::geometry::Setup;
use crate::hdr::HdrImage;
use crate::samples::{Sample, SampleUncertainty};
use crate::setup_uncertainty::Source;

/// One θL's merged strips, as [`extract_theta`] reads them.
pub(super) struct Strips<'a> {
    pub(super) map: &'a HdrImage,
    pub(super) layout: &'a StripLayout,
    pub(super) theta_l: f64,
}

/// `setup` with `source` moved by `delta` (its unit); the white is not part of the
/// geometry and is returned unchanged.
fn perturbed(setup: &Setup, source: Source, delta: f64) -> Setup {
    let mut s = setup.clone();
    match source {
        Source::WhiteReflectance | Source::WhiteFalloff => {}
        Source::CameraOffset => s.camera_offset_mm += delta,
        Source::CameraDistance => s.camera_distance_mm += delta,
        Source::LightDistance => s.light_distance_mm += delta,
        Source::CylinderTilt => s.cylinder_tilt_deg += delta,
        Source::ArmZero | Source::ArmAngle => s.arm_zero_offset_deg += delta,
        Source::CameraYaw => s.camera_yaw_deg += delta,
        Source::CameraRoll => s.camera_roll_deg += delta,
    }
    s
}

/// Samples each side of a point in the local line whose slope is β's derivative along
/// signed θh ([`slopes`]).
const SLOPE_NEIGHBOURS: usize = 3;

/// Per sample and channel, dβ/dθh (per radian of signed θh) along its θL: the slope of
/// the least-squares line through it and its [`SLOPE_NEIGHBOURS`] neighbours each side
/// (fewer at the ends), which averages the noise that a difference of two neighbours
/// would carry into the sensitivities. 0 where a channel is dropped or the points do not
/// spread in θh.
fn slopes(samples: &[Sample], half_angles: &[f64]) -> Vec<[f64; 3]> {
    (0..samples.len())
        .map(|i| {
            let near =
                i.saturating_sub(SLOPE_NEIGHBOURS)..(i + SLOPE_NEIGHBOURS + 1).min(samples.len());
            std::array::from_fn(|c| {
                let points: Vec<(f64, f64)> = near
                    .clone()
                    .filter_map(|k| Some((half_angles[k], samples[k].channel(c)?)))
                    .collect();
                let n = points.len() as f64;
                if samples[i].dropped[c] || n < 2.0 {
                    return 0.0;
                }
                let mean_h = points.iter().map(|p| p.0).sum::<f64>() / n;
                let mean_b = points.iter().map(|p| p.1).sum::<f64>() / n;
                let sxx: f64 = points.iter().map(|p| (p.0 - mean_h).powi(2)).sum();
                let sxy: f64 = points.iter().map(|p| (p.0 - mean_h) * (p.1 - mean_b)).sum();
                if sxx > 0.0 {
                    sxy / sxx
                } else {
                    0.0
                }
            })
        })
        .collect()
}

/// Fills each sample's [`SampleUncertainty::sources`]: how β at the sample's stated
/// geometry changes when each uncertain input moves by one standard uncertainty.
/// The white reflectance scales β. A geometric source changes where each pixel's value is
/// placed, and a little the value itself (the strips' irradiance ratio): the strips are
/// extracted again with the setup moved by ±u, and a column whose value v goes to v′ and
/// whose signed θh moves by Δ changes β at its stated θh by (v′ − v) − Δ·dβ/dθh ([`slopes`]
/// of the stated samples); half the difference of the two signs is taken (central
/// difference). The change of θd at a fixed θh (a fraction of the source's own size) is
/// left out. A column the moved extraction drops gets no change.
pub(super) fn add_sensitivities(
    setup: &Setup,
    strips: &Strips,
    options: &ExtractOptions,
    white_reflectance: f64,
    (samples, columns, white_angular): (&mut [Sample], &[usize], &[f64]),
) {
    let inputs = setup.inputs();
    let half_angles: Vec<f64> = samples.iter().map(|s| s.half_difference().0).collect();
    let slope = slopes(samples, &half_angles);
    let stated: &[Sample] = samples;
    // The moved extractions need the stated samples' columns only, with the neighbours
    // their rows' noise is pooled over.
    let only = match (columns.first(), columns.last()) {
        (Some(&first), Some(&last)) => {
            Some(first.saturating_sub(NOISE_NEIGHBOURS)..last + NOISE_NEIGHBOURS + 1)
        }
        _ => return,
    };
    let changes: Vec<(usize, Vec<[f64; 3]>)> = inputs
        .par_iter()
        .enumerate()
        .filter(|(_, input)| {
            !matches!(
                input.source,
                Source::WhiteReflectance | Source::WhiteFalloff
            ) && input.u[0] > 0.0
        })
        .map(|(j, input)| {
            let [plus, minus] = [1.0, -1.0].map(|sign| {
                let moved = perturbed(setup, input.source, sign * input.u[0]);
                let ThetaSamples {
                    samples: moved_samples,
                    columns: moved_columns,
                    ..
                } = extract_theta(
                    &moved,
                    strips.map,
                    strips.layout,
                    strips.theta_l,
                    options,
                    white_reflectance,
                    only.clone(),
                );
                stated
                    .iter()
                    .zip(columns)
                    .enumerate()
                    .map(|(i, (s, x))| {
                        let Ok(k) = moved_columns.binary_search(x) else {
                            return [0.0; 3];
                        };
                        let m = &moved_samples[k];
                        let shift = m.half_difference().0 - half_angles[i];
                        std::array::from_fn(|c| match (s.channel(c), m.channel(c)) {
                            (Some(v), Some(moved)) => (moved - v) - shift * slope[i][c],
                            _ => 0.0,
                        })
                    })
                    .collect::<Vec<[f64; 3]>>()
            });
            let change = plus
                .iter()
                .zip(&minus)
                .map(|(p, m)| std::array::from_fn(|c| (p[c] - m[c]) / 2.0))
                .collect();
            (j, change)
        })
        .collect();
    // Source::ALL begins with the white reference.
    let white = inputs[0].u;
    let falloff = Source::ALL
        .iter()
        .position(|&s| s == Source::WhiteFalloff)
        .unwrap_or(0);
    for (i, sample) in samples.iter_mut().enumerate() {
        let rgb = sample.rgb;
        let dropped = sample.dropped;
        let u = sample
            .uncertainty
            .get_or_insert_with(SampleUncertainty::default);
        u.sources[0] = std::array::from_fn(|c| rgb[c] * white[c]);
        u.sources[falloff] = rgb.map(|v| v * white_angular[i]);
        for (j, change) in &changes {
            u.sources[*j] = change[i];
        }
        for c in (0..3).filter(|&c| dropped[c]) {
            for source in &mut u.sources {
                source[c] = 0.0;
            }
        }
    }
}
