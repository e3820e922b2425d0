//! A parameter's refits with one source's values moved by ± k standard uncertainties
//! (the uncertainty budget's sensitivities, `budget.md`): its line, bend and excursions.

/// The coverage factor of the expanded uncertainty (≈ 95 % for a normal distribution).
pub const COVERAGE_FACTOR: f64 = 2.0;

/// Sensitivities are secants over ±this many standard uncertainties, the range the
/// expanded interval covers: a robust fit does not follow the setup linearly (on a broad
/// Ward lobe its m moves with about the cube of the camera's offset: a central difference
/// over ±1 u gives a fifth of the change at 2 u).
pub(super) const SECANT_SPAN: f64 = COVERAGE_FACTOR;

/// A parameter is taken as linear in a source when its refits at ±k u have their midpoint
/// within this fraction of their span from the unmoved fit (the second-order term is then
/// a tenth of the first at the interval's ends), or of k·u_c; otherwise the refits' ends
/// bound its interval where they reach farther (`IntervalFrom::RefitEnds` of the budget).
pub(super) const LINEAR_TOLERANCE: f64 = 0.1;

/// One parameter's fits with a source's values moved by ±[`SECANT_SPAN`] standard
/// uncertainties and unmoved.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Secant {
    pub base: f64,
    pub plus: f64,
    pub minus: f64,
}

impl Secant {
    /// The line: √(c₁² + ½·c₂²) with c₁ the secant's slope and c₂ the second difference,
    /// both per standard uncertainty (JCGM 100 §5.1.2, its note: the second-order term).
    pub(super) fn line(&self) -> f64 {
        let h = SECANT_SPAN;
        let slope = (self.plus - self.minus) / (2.0 * h);
        let curvature = (self.plus - 2.0 * self.base + self.minus) / (h * h);
        (slope * slope + 0.5 * curvature * curvature).sqrt()
    }

    /// How far the refits' midpoint lies from the unmoved fit: 0 where the parameter
    /// follows the source linearly over ±[`SECANT_SPAN`] u.
    pub(super) fn bend(&self) -> f64 {
        (0.5 * (self.plus + self.minus) - self.base).abs()
    }

    /// The bend's bound for a linear source: [`LINEAR_TOLERANCE`] of the refits' span.
    pub(super) fn bend_bound(&self) -> f64 {
        LINEAR_TOLERANCE * (self.plus - self.minus).abs()
    }

    /// How far the parameter goes above and below the unmoved fit within ±k u (each ≥ 0).
    pub(super) fn excursions(&self) -> [f64; 2] {
        let up = (self.plus - self.base).max(self.minus - self.base).max(0.0);
        let down = (self.base - self.plus).max(self.base - self.minus).max(0.0);
        [up, down]
    }
}
