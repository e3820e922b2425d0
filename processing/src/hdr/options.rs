//! Options of the HDR merge: the method, the sensor noise model (in units of the
//! normalised signal), the linear method's usable signal range and Debevec–Malik's
//! smoothness and sampling; and their checks.

use super::error::HdrError;

/// Which merge to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MergeMethod {
    /// Linear for linear frames, Debevec–Malik for non-linear ones.
    #[default]
    Auto,
    Linear,
    DebevecMalik,
}

/// Sensor noise model for the linear merge, in units of the normalised signal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Electrons at clipping at ISO 100 (shot variance of signal s is s / full_well,
    /// scaled by ISO/100).
    pub full_well_electrons: f64,
    /// Read noise standard deviation as a fraction of the range black..white.
    pub read_noise: f64,
}

impl Default for NoiseModel {
    /// Typical of an APS-C DSLR at base ISO: 30 000 e⁻ full well, read noise 1/5000.
    fn default() -> Self {
        Self {
            full_well_electrons: 30_000.0,
            read_noise: 2e-4,
        }
    }
}

/// Options of [`merge`](super::merge).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MergeOptions {
    pub method: MergeMethod,
    pub noise: NoiseModel,
    /// Normalised signals below this are treated as black (linear method).
    pub min_signal: f64,
    /// Normalised signals above this are treated as clipped (linear method).
    pub max_signal: f64,
    /// Debevec–Malik smoothness weight λ, relative to the data's weight per level.
    pub smoothness: f64,
    /// Debevec–Malik: about this many pixel locations per channel are sampled evenly in
    /// rank, and as many evenly in brightness (fewer where the image has fewer usable).
    pub response_samples: usize,
}

impl Default for MergeOptions {
    fn default() -> Self {
        Self {
            method: MergeMethod::Auto,
            noise: NoiseModel::default(),
            min_signal: 0.002,
            max_signal: 0.98,
            smoothness: 50.0,
            response_samples: 1000,
        }
    }
}

pub(super) fn check_options(o: &MergeOptions) -> Result<(), HdrError> {
    let bad = |m: &str| Err(HdrError::Options(m.to_string()));
    let ordered =
        (0.0..1.0).contains(&o.min_signal) && o.max_signal > o.min_signal && o.max_signal <= 1.0;
    if !ordered {
        return bad("need 0 ≤ min_signal < max_signal ≤ 1");
    }
    if !(o.noise.full_well_electrons.is_finite() && o.noise.full_well_electrons > 0.0) {
        return bad("full_well_electrons must be positive");
    }
    if !(o.noise.read_noise.is_finite() && o.noise.read_noise > 0.0) {
        return bad("read_noise must be positive");
    }
    if !(o.smoothness.is_finite() && o.smoothness >= 0.0) || o.response_samples < 2 {
        return bad("smoothness must be ≥ 0 and response_samples ≥ 2");
    }
    Ok(())
}
