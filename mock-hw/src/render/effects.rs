//! The optional camera effects. Each costs nothing unless the scene names it: the
//! renderer holds `Option`s of these and skips absent ones.

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

use crate::scene::{Noise, Response};

/// SplitMix64 finaliser: decorrelates seeds built from small integers.
pub(crate) fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Shot noise (Gaussian with the Poisson variance S/g, S the signal in counts and g
/// electrons per count at the shot's ISO) plus Gaussian read noise, one generator per
/// image row so rows render in parallel and deterministically.
pub(crate) struct NoiseModel {
    counts_per_electron: f64,
    read_var: f64,
    read_sd: f64,
}

impl NoiseModel {
    pub fn new(noise: &Noise, iso: u32) -> Self {
        let electrons_per_dn = noise.electrons_per_dn * 100.0 / f64::from(iso);
        Self {
            counts_per_electron: 1.0 / electrons_per_dn,
            read_var: noise.read_noise_dn * noise.read_noise_dn,
            read_sd: noise.read_noise_dn,
        }
    }

    /// Generator for one row of one frame.
    pub fn row_rng(frame_seed: u64, row: u32) -> Pcg64Mcg {
        Pcg64Mcg::seed_from_u64(mix(frame_seed ^ mix(u64::from(row))))
    }

    /// `signal` counts (above black) plus noise.
    #[inline]
    pub fn apply(&self, signal: f64, rng: &mut Pcg64Mcg) -> f64 {
        let z: f64 = rng.sample(StandardNormal);
        if signal <= 0.0 {
            return z * self.read_sd;
        }
        let var = signal * self.counts_per_electron + self.read_var;
        signal + z * var.sqrt()
    }
}

/// Natural vignetting gain (1 − s) + s·cos⁴θ, cos θ = f/√(f² + x² + y²) with x, y the
/// pixel's sensor offsets from the principal point (mm).
#[inline]
pub(crate) fn vignetting_gain(strength: f64, f_mm: f64, x_mm: f64, y_mm: f64) -> f64 {
    let f2 = f_mm * f_mm;
    let c2 = f2 / (f2 + x_mm * x_mm + y_mm * y_mm);
    (1.0 - strength) + strength * c2 * c2
}

/// The 8-bit non-linear response as a lookup from linear raw count to stored value.
pub(crate) fn response_table(response: &Response, black: u32, white: u32) -> Vec<u16> {
    let range = f64::from(white - black);
    (0..=white)
        .map(|v| {
            let y = (f64::from(v.saturating_sub(black)) / range).clamp(0.0, 1.0);
            let code = (255.0 * y.powf(1.0 / response.gamma)).round() as u16;
            code * 257
        })
        .collect()
}

/// `count` distinct pixel indices (row-major) in a `width`×`height` image, fixed by
/// `seed`: the camera's stuck pixels.
pub(crate) fn hot_pixel_positions(count: u32, width: u32, height: u32, seed: u64) -> Vec<usize> {
    let total = width as usize * height as usize;
    let count = (count as usize).min(total);
    let mut rng = Pcg64Mcg::seed_from_u64(mix(seed ^ 0x686F_7420_7069_7865));
    let mut seen = std::collections::HashSet::with_capacity(count);
    let mut positions = Vec::with_capacity(count);
    while positions.len() < count {
        let p = rng.random_range(0..total);
        if seen.insert(p) {
            positions.push(p);
        }
    }
    positions
}
