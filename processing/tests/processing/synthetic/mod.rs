//! Synthetic scans shared by the fitting tests: samples of a known model on the
//! distant-source geometry with seeded Gaussian noise.

use gonio_processing::brdf::{Model, Params};
use gonio_processing::samples::Sample;

use crate::common::Rng;

/// Noise of a synthetic scan: σ = `relative`·β + `absolute` per channel, independent
/// between points and channels.
#[derive(Debug, Clone, Copy)]
pub struct Noise {
    pub relative: f64,
    pub absolute: f64,
}

/// Samples of the distant-source geometry (θi = θL − φ, θr = φ), φ every `step_deg`
/// degrees, both angles within ±85°, from `model` with the specular colour at 90°
/// `ks_90` (Cook–Torrance–Fresnel; ignored by the others), plus `noise` drawn from `rng`.
pub fn scan(
    model: Model,
    p: &Params,
    ks_90: &[f64; 3],
    theta_ls: &[f64],
    step_deg: f64,
    noise: Noise,
    rng: &mut Rng,
) -> Vec<Sample> {
    let steps = (85.0 / step_deg).floor() as i32;
    let mut out = Vec::new();
    for &theta_l in theta_ls {
        for k in -steps..=steps {
            let phi = f64::from(k) * step_deg;
            let (theta_i, theta_r) = (theta_l - phi, phi);
            if theta_i.abs() > 85.0 || theta_r.abs() > 85.0 {
                continue;
            }
            let clean = model.basis(theta_i, theta_r).evaluate_fresnel(p, ks_90);
            let rgb = clean.map(|b| b + (noise.relative * b + noise.absolute) * rng.normal());
            out.push(Sample::in_plane(theta_l, theta_i, theta_r, rgb));
        }
    }
    out
}
