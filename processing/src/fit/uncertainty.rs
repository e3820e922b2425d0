//! Standard uncertainty of fitted parameters: the sandwich covariance of the eq. 10
//! M-estimator (`docs/ARCHITECTURE.md`, "Parameter uncertainty").
//!
//! The fit minimises L(θ) = Σ_p ρ(r_p) with ρ(r) = ‖r‖ and r_p = y_p − ŷ_p(θ) the RGB
//! residual of point p. With J_p = ∂ŷ_p/∂θ (3 × P) and u_p = r_p/‖r_p‖, the estimator's
//! asymptotic covariance is A⁻¹ B A⁻¹ (Huber 1967) with
//! A = Σ_p J_pᵀ M_p J_p, M_p = (I − u_p u_pᵀ)/‖r_p‖ (the Gauss–Newton Hessian of L), and
//! B = N/(N − P) · Σ_p g_p g_pᵀ, g_p = J_pᵀ u_p (the spread of the per-point gradients,
//! with the small-sample factor of HC1). Both come from the residuals at the optimum, so
//! the noise level, its differences between channels and its growth with β need no model.
//! Points are taken as independent (pixel noise); correlated residuals (model misfit,
//! demosaicing) make the intervals too narrow. A dropped channel of a point (`Data::keep`)
//! has no residual and no row in J_p.
//!
//! The colour-shift test uses the HC3 form instead, B = Σ_p g_p g_pᵀ/(1 − h_p)² with the
//! leverage h_p = tr(M_p J_p A⁻¹ J_pᵀ) (MacKinnon and White 1985): the shift is decided by
//! the few points of the specular lobe at few θL, points of high leverage whose residuals
//! understate their noise, and with HC1 its χ² has a heavy tail (a shift that is not there
//! kept in 6–14 % of simulated sharp-lobe scans at the 1 % level, 1.5–2 % with HC3). The
//! intervals keep HC1: their coverage is right (see the tests), HC3's is above 99 %.
//!
//! Parameters: Kd, Ks (and Ks_90) per channel and ln m. Intervals are θ̂ ± 1.96·σ
//! for the colour coefficients (lower end clipped at 0, their feasible bound) and
//! m·exp(±1.96·σ_ln m) for the roughness (always positive; its standard uncertainty is
//! m·σ_ln m). When A is singular (a parameter has no effect on the loss, e.g. m when
//! Ks = 0) the uncertainty is not defined and none is reported.

use std::borrow::Cow;
use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::block_sums::{Block, Columns, Square, Totals, BLOCK, MAX_PARAMETERS};
use super::data::Data;
use super::options::FitOptions;
use crate::brdf::{Basis, Params, Roughness};
#[cfg(target_arch = "x86_64")]
use crate::simd::avx2_fma;

/// The two-sided 95 % quantile of the standard normal distribution.
pub const Z95: f64 = 1.959_963_984_540_054;

/// Leverages are capped here so that a point the fit passes through exactly (h = 1)
/// keeps a finite weight in HC3.
const MAX_LEVERAGE: f64 = 0.99;

/// Smallest eigenvalue of A's correlation form (A scaled to a unit diagonal) at which the
/// parameters still count as identifiable.
const MIN_RELATIVE_EIGENVALUE: f64 = 1e-12;

/// One value per fitted parameter, in the shapes of the fit JSON: `m` holds one value
/// (shared roughness) or three (per channel); `ks_90` only for Cook–Torrance–Fresnel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterSet<T> {
    pub kd: [T; 3],
    pub ks: [T; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ks_90: Option<[T; 3]>,
    pub m: Vec<T>,
}

impl<T> ParameterSet<T> {
    /// Every value in order: Kd, Ks, Ks_90 (when present) per channel, then m.
    pub fn flat(&self) -> Vec<&T> {
        self.kd
            .iter()
            .chain(&self.ks)
            .chain(self.ks_90.iter().flatten())
            .chain(&self.m)
            .collect()
    }
}

/// Correlations between fitted parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Correlation {
    /// Correlation of Ks_c with the roughness of channel c (the shared m, or m_c), per
    /// channel R, G, B.
    pub ks_m: [f64; 3],
}

/// The Wald test of Cook–Torrance–Fresnel's colour shift, Ks_90 = Ks in every
/// channel, with the sandwich covariance: χ² = dᵀ Σ_d⁻¹ d, d = Ks_90 − Ks, 3
/// degrees of freedom.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ColourShift {
    /// Whether Ks_90 was fitted (the shift was significant) or tied to Ks.
    pub fitted: bool,
    /// The test statistic and its p-value; absent when no test was possible (one θL).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chi2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p_value: Option<f64>,
}

/// The HC1 sandwich covariance of the parameters of one fit, θ laid out as in [`Layout`].
pub(crate) struct Covariance {
    layout: Layout,
    hc1: DMatrix<f64>,
}

/// The uncertainty of one fit.
pub(crate) struct Spread {
    pub stderr: ParameterSet<f64>,
    pub ci95: ParameterSet<[f64; 2]>,
    pub correlation: Correlation,
}

/// Positions of the parameters in θ: Kd, Ks, Ks_90 (when `fresnel`) per channel, then
/// ln m (one when `shared`, else per channel).
pub(crate) struct Layout {
    pub fresnel: bool,
    pub shared: bool,
}

impl Layout {
    /// The layout of a fit to `data` (Ks_90 its own where `data` has shift weights).
    pub(crate) fn of(data: &Data, options: &FitOptions) -> Self {
        Layout {
            fresnel: data.shift_weight.is_some(),
            shared: options.roughness == Roughness::Shared,
        }
    }
    pub(crate) fn kd(&self, c: usize) -> usize {
        c
    }
    pub(crate) fn ks(&self, c: usize) -> usize {
        3 + c
    }
    pub(crate) fn kg(&self, c: usize) -> Option<usize> {
        self.fresnel.then_some(6 + c)
    }
    pub(crate) fn ln_m(&self, c: usize) -> usize {
        let base = if self.fresnel { 9 } else { 6 };
        if self.shared {
            base
        } else {
            base + c
        }
    }
    pub(crate) fn len(&self) -> usize {
        self.ln_m(2) + 1
    }
    /// The columns a row of channel `c` of a point's Jacobian can be nonzero at,
    /// ascending: Kd, Ks, Ks_90 (with its own) and ln m; and how many there are.
    fn columns(&self, c: usize) -> Columns {
        match self.kg(c) {
            Some(kg) => ([self.kd(c), self.ks(c), kg, self.ln_m(c)], 4),
            None => ([self.kd(c), self.ks(c), self.ln_m(c), 0], 3),
        }
    }
}

/// The standard uncertainties and intervals at (`params`, `ks_90`); `None` when they
/// are not defined (singular A, too few points, non-finite values).
pub(crate) fn estimate(
    data: &Data,
    options: &FitOptions,
    params: &Params,
    ks_90: &[f64; 3],
) -> Option<Spread> {
    let covariance = covariance(data, options, params, ks_90)?;
    let mut spread = spread(&covariance.layout, params, ks_90, &covariance.hc1)?;
    if options.model.has_fresnel_colour() && !covariance.layout.fresnel {
        // Ks_90 tied to Ks: the same parameter.
        spread.stderr.ks_90 = Some(spread.stderr.ks);
        spread.ci95.ks_90 = Some(spread.ci95.ks);
    }
    Some(spread)
}

/// The Wald statistic of Ks_90 = Ks (χ², 3 degrees of freedom) with the HC3 covariance
/// at (`params`, `ks_90`); `None` when the fit has no specular colour at 90°, too few
/// points, or A or the difference's covariance is singular.
pub(crate) fn shift_statistic(
    data: &Data,
    options: &FitOptions,
    params: &Params,
    ks_90: &[f64; 3],
) -> Option<f64> {
    let residuals = Residuals::new(data, options, params, ks_90)?;
    let layout = &residuals.layout;
    let inverse = inverse_if_identifiable(&residuals.sums(false).hessian)?;
    let hc3 = &inverse * residuals.hc3_spread(&inverse) * &inverse;
    let d = DVector::from_iterator(3, (0..3).map(|c| ks_90[c] - params.ks[c]));
    let mut sigma = DMatrix::<f64>::zeros(3, 3);
    for i in 0..3 {
        for j in 0..3 {
            let (gi, gj) = (layout.kg(i)?, layout.kg(j)?);
            let (si, sj) = (layout.ks(i), layout.ks(j));
            let v = &hc3;
            sigma[(i, j)] = v[(gi, gj)] - v[(gi, sj)] - v[(si, gj)] + v[(si, sj)];
        }
    }
    let chi2 = (d.transpose() * inverse_if_identifiable(&sigma)? * &d)[(0, 0)];
    chi2.is_finite().then_some(chi2.max(0.0))
}

/// P(X > x) for X ~ χ² with 3 degrees of freedom: erfc(√(x/2)) + √(2x/π)·e^(−x/2).
pub fn chi2_3_survival(x: f64) -> f64 {
    if x.is_nan() || x <= 0.0 {
        return 1.0;
    }
    let p = erfc((x / 2.0).sqrt()) + (2.0 * x / std::f64::consts::PI).sqrt() * (-x / 2.0).exp();
    p.clamp(0.0, 1.0)
}

/// The complementary error function (Numerical Recipes' Chebyshev fit, relative error
/// below 1.2e-7), for x ≥ 0.
fn erfc(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.5 * x);
    let poly = -x * x - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    t * poly.exp()
}

/// The HC1 sandwich covariance of the parameters at (`params`, `ks_90`); `None` when it
/// is not defined (singular A, too few points).
pub(crate) fn covariance(
    data: &Data,
    options: &FitOptions,
    params: &Params,
    ks_90: &[f64; 3],
) -> Option<Covariance> {
    let residuals = Residuals::new(data, options, params, ks_90)?;
    let (n, p) = (data.y.len(), residuals.layout.len());
    let Sums {
        hessian, spread, ..
    } = residuals.sums(true);
    let inverse = inverse_if_identifiable(&hessian)?;
    let hc1 = &inverse * spread * (n as f64 / (n - p) as f64) * &inverse;
    Some(Covariance {
        hc1,
        layout: residuals.layout,
    })
}

/// The Gauss–Newton system of the loss at (`params`, `ks_90`), θ laid out as in
/// [`Layout::of`]: A (its Hessian without the model's second derivatives) and Σ_p g_p,
/// the loss's gradient with its sign reversed; `None` when there are no more points than
/// parameters.
pub(crate) fn gauss_newton(
    data: &Data,
    options: &FitOptions,
    params: &Params,
    ks_90: &[f64; 3],
) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let Sums {
        hessian, descent, ..
    } = Residuals::new(data, options, params, ks_90)?.sums(false);
    Some((hessian, descent))
}

/// One point's part of the sandwich, on the stack: its Jacobian J_p, each channel's
/// row at that channel's columns ([`Layout::columns`]; a zero row for a dropped
/// channel), its curvature M_p and its gradient g_p.
struct PointTerm {
    rows: [[f64; 4]; 3],
    curvature: [[f64; 3]; 3],
    gradient: [f64; MAX_PARAMETERS],
}

/// A, Σ_p g_p g_pᵀ (B without its small-sample factor) and Σ_p g_p (the loss's
/// gradient with its sign reversed).
struct Sums {
    hessian: DMatrix<f64>,
    spread: DMatrix<f64>,
    descent: DVector<f64>,
}

/// The residuals of a fit at its parameters, read by the passes over the points; held
/// as columns (per channel, one value per point) for the passes' loops.
struct Residuals<'a> {
    data: &'a Data,
    layout: Layout,
    params: Params,
    ks_90: [f64; 3],
    /// The lobe at each channel's roughness: one for a shared m, else one per channel.
    lobes: Vec<Lobe>,
    /// The weight w of the specular colour at 90° per point ([`Basis::shift_weight`]),
    /// all 0 where the colour is constant (Ks_90 = Ks).
    weight: Cow<'a, [f64]>,
    /// r_pc = y_pc − ŷ_pc (0 in a dropped channel) per channel and point.
    residuals: [Vec<f64>; 3],
    /// ‖r_p‖ per point, at least `floor`.
    norms: Vec<f64>,
}

/// One channel's row of a point's Jacobian at [`Layout::columns`]: ∂β/∂(Kd, Ks, Ks_90
/// when `fresnel`, ln m) at diffuse basis `a`, specular basis and slope `lobe` = (s,
/// ∂s/∂ln m), weight `x` of the specular colour at 90° and `colour` = (Ks, Ks_90).
#[inline(always)]
fn jacobian_row(fresnel: bool, a: f64, lobe: [f64; 2], x: f64, colour: [f64; 2]) -> [f64; 4] {
    let ([s, slope], [ks, kg]) = (lobe, colour);
    let colour = ks + x * (kg - ks);
    if fresnel {
        [a, s * (1.0 - x), s * x, colour * slope]
    } else {
        [a, s, colour * slope, 0.0]
    }
}

/// The residuals r_pc = y_pc − β_pc per channel (0 where dropped) and their norms ‖r_p‖
/// per point, at the lobes `lobes` (one, or one per channel) and the weights `weight` of
/// the specular colour at 90°.
fn residual_columns(
    data: &Data,
    weight: &[f64],
    lobes: &[Lobe],
    params: &Params,
    ks_90: &[f64; 3],
) -> ([Vec<f64>; 3], Vec<f64>) {
    let n = data.y.len();
    // β_c = Kd_c·a + s_c·(Ks_c + w·(Ks_90,c − Ks_c)); dropped values (y = 0, estimate
    // 0) leave no residual.
    let (w, a, y) = (weight, &data.diffuse[..n], &data.y[..n]);
    let residuals: [Vec<f64>; 3] = std::array::from_fn(|c| {
        let s = &lobes[c.min(lobes.len() - 1)].s[..n];
        let (kd, ks, shift) = (params.kd[c], params.ks[c], ks_90[c] - params.ks[c]);
        let points = y.iter().zip(a).zip(&w[..n]).zip(s);
        let estimate = |a: f64, w: f64, s: f64| kd * a + (ks + w * shift) * s;
        match &data.keep {
            Some(keep) => points
                .zip(keep.iter())
                .map(|((((y, &a), &w), &s), k)| y[c] - estimate(a, w, s) * k[c])
                .collect(),
            None => points
                .map(|(((y, &a), &w), &s)| y[c] - estimate(a, w, s))
                .collect(),
        }
    });
    let [r0, r1, r2] = &residuals;
    let norms: Vec<f64> = r0
        .iter()
        .zip(r1)
        .zip(r2)
        .map(|((r0, r1), r2)| (r0 * r0 + r1 * r1 + r2 * r2).sqrt())
        .collect();
    (residuals, norms)
}

/// The specular basis s and its slope ∂s/∂ln m at every point, at one roughness.
struct Lobe {
    s: Vec<f64>,
    slope: Vec<f64>,
}

impl Lobe {
    fn at(data: &Data, m: f64) -> Self {
        let n = data.y.len();
        let (mut s, mut slope) = (vec![0.0; n], vec![0.0; n]);
        data.columns.specular_and_slope(m, &mut s, &mut slope);
        Lobe { s, slope }
    }
}

impl<'a> Residuals<'a> {
    /// `None` when there are no more points than parameters.
    fn new(
        data: &'a Data,
        options: &FitOptions,
        params: &Params,
        ks_90: &[f64; 3],
    ) -> Option<Self> {
        let layout = Layout::of(data, options);
        let n = data.y.len();
        if n <= layout.len() {
            return None;
        }
        // A shared roughness needs one lobe evaluation for all channels.
        let lobes: Vec<Lobe> = if params.m.iter().all(|&m| m == params.m[0]) {
            vec![Lobe::at(data, params.m[0])]
        } else {
            params.m.iter().map(|&m| Lobe::at(data, m)).collect()
        };
        let weight = match &data.shift_weight {
            Some(w) => Cow::Borrowed(&w[..]),
            None if *ks_90 == params.ks => Cow::Owned(vec![0.0; n]),
            None => Cow::Owned(data.bases.iter().map(Basis::shift_weight).collect()),
        };
        let (residuals, mut norms) = residual_columns(data, &weight, &lobes, params, ks_90);
        // The median of values ≥ 0 is at most twice their mean, so the floor is below
        // 4e-6 of the mean over the data's: where the smallest norm is above that (and
        // none is NaN), it floors nothing and the median is not needed.
        let (least, sum) = norms
            .iter()
            .fold((f64::INFINITY, 0.0), |(lo, sum), &v| (lo.min(v), sum + v));
        if !(sum.is_finite() && least > 4e-6 * sum / n as f64 + data.residual_floor) {
            let mut order = norms.clone();
            let median = *order.select_nth_unstable_by(n / 2, f64::total_cmp).1;
            let floor = 1e-6 * median + data.residual_floor;
            for norm in &mut norms {
                *norm = norm.max(floor);
            }
        }
        Some(Residuals {
            data,
            layout,
            params: *params,
            ks_90: *ks_90,
            lobes,
            weight,
            residuals,
            norms,
        })
    }

    /// Channel `c`'s row of point `point`'s Jacobian at [`Layout::columns`], as if the
    /// channel counted.
    #[inline(always)]
    fn row(&self, c: usize, point: usize) -> [f64; 4] {
        let lobe = &self.lobes[c.min(self.lobes.len() - 1)];
        jacobian_row(
            self.layout.fresnel,
            self.data.diffuse[point],
            [lobe.s[point], lobe.slope[point]],
            self.weight[point],
            [self.params.ks[c], self.ks_90[c]],
        )
    }

    /// Channel `c`'s rows of the Jacobians of `points` (at most [`BLOCK`]) into `rows`,
    /// side by side: `rows[a][k]` is column a of point `points.start + k` (zero where
    /// the channel was dropped).
    #[inline(always)]
    fn fill_rows(&self, rows: &mut [[f64; BLOCK]; 4], c: usize, points: Range<usize>) {
        let lobe = &self.lobes[c.min(self.lobes.len() - 1)];
        let (s, slope) = (&lobe.s[points.clone()], &lobe.slope[points.clone()]);
        let (w, a) = (
            &self.weight[points.clone()],
            &self.data.diffuse[points.clone()],
        );
        let (ks, kg) = (self.params.ks[c], self.ks_90[c]);
        let [r0, r1, r2, r3] = rows;
        let columns = r0
            .iter_mut()
            .zip(r1.iter_mut())
            .zip(r2.iter_mut().zip(r3.iter_mut()));
        let terms = a.iter().zip(s).zip(w.iter().zip(slope));
        for (((r0, r1), (r2, r3)), ((&a, &s), (&x, &slope))) in columns.zip(terms) {
            [*r0, *r1, *r2, *r3] = jacobian_row(self.layout.fresnel, a, [s, slope], x, [ks, kg]);
        }
        // A dropped channel's row and residual are zero.
        if let Some(keep) = &self.data.keep {
            for (k, keep) in keep[points].iter().enumerate() {
                for row in rows.iter_mut() {
                    row[k] *= keep[c];
                }
            }
        }
    }

    /// Point `point`'s Jacobian J_p as [`Layout::columns`] lays it out: per channel its
    /// values at that channel's columns (a dropped channel's row is zero).
    fn rows(&self, point: usize) -> [[f64; 4]; 3] {
        let keep = self
            .data
            .keep
            .as_ref()
            .map_or([true; 3], |keep| keep[point].map(|k| k > 0.0));
        std::array::from_fn(|c| {
            if keep[c] {
                self.row(c, point)
            } else {
                [0.0; 4]
            }
        })
    }

    /// u_p = r_p/‖r_p‖ of point `point` (of length ≤ 1 after the floor).
    fn direction(&self, point: usize) -> [f64; 3] {
        let norm = self.norms[point];
        std::array::from_fn(|c| self.residuals[c][point] / norm)
    }

    /// Every channel's [`Layout::columns`].
    fn columns(&self) -> [Columns; 3] {
        std::array::from_fn(|c| self.layout.columns(c))
    }

    /// J_p, M_p and g_p of point `point`, each row of J_p at its channel's `columns`
    /// ([`Residuals::columns`]).
    fn term(&self, point: usize, columns: &[Columns; 3]) -> PointTerm {
        let rows = self.rows(point);
        let norm = self.norms[point];
        let u = self.direction(point);
        // (I − u uᵀ)/‖r‖.
        let curvature = std::array::from_fn(|c| {
            std::array::from_fn(|d| (if c == d { 1.0 } else { 0.0 } - u[c] * u[d]) / norm)
        });
        // g_p = J_pᵀ u_p.
        let mut gradient = [0.0; MAX_PARAMETERS];
        for ((row, (at, width)), u) in rows.iter().zip(columns).zip(u) {
            for (&i, v) in at[..*width].iter().zip(row) {
                gradient[i] += v * u;
            }
        }
        PointTerm {
            rows,
            curvature,
            gradient,
        }
    }

    /// A = Σ_p J_pᵀ M_p J_p, Σ_p g_p g_pᵀ (when `spread`, else 0) and Σ_p g_p, in one
    /// pass. J_pᵀ M_p J_p = (J_pᵀ J_p − g_p g_pᵀ)/‖r_p‖, each row of J_p nonzero only at
    /// its channel's columns ([`Layout::columns`]), which are all the pass visits.
    /// Compiled for AVX2 and FMA too, and that copy chosen where the processor has them.
    fn sums(&self, with_spread: bool) -> Sums {
        #[cfg(target_arch = "x86_64")]
        if avx2_fma() {
            // SAFETY: the processor has AVX2 and FMA, checked just above.
            return unsafe { self.sums_avx2(with_spread) };
        }
        self.sums_portable(with_spread)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn sums_avx2(&self, with_spread: bool) -> Sums {
        self.sums_portable(with_spread)
    }

    #[inline(always)]
    fn sums_portable(&self, with_spread: bool) -> Sums {
        let p = self.layout.len();
        let columns = self.columns();
        let mut totals = Totals::zero();
        let mut block = Block::zeroed();
        let n = self.norms.len();
        let mut u = [0.0; BLOCK];
        for start in (0..n).step_by(BLOCK) {
            let points = start..n.min(start + BLOCK);
            block.start(points.len(), p);
            for (k, point) in points.clone().enumerate() {
                block.inverse[k] = 1.0 / self.norms[point];
            }
            for (c, (columns, width)) in columns.iter().enumerate() {
                let residuals = &self.residuals[c][points.clone()];
                for ((u, r), point) in u.iter_mut().zip(residuals).zip(points.clone()) {
                    *u = r / self.norms[point];
                }
                self.fill_rows(&mut block.rows[c], c, points.clone());
                for (a, &column) in columns[..*width].iter().enumerate() {
                    // g_p = J_pᵀ u_p.
                    let (rows, gradient) = (&block.rows[c][a], &mut block.gradient[column]);
                    for ((g, row), u) in gradient.iter_mut().zip(rows).zip(&u) {
                        *g += row * u;
                    }
                }
            }
            totals.add(&block, &columns, p, with_spread);
        }
        Sums {
            hessian: symmetric(&totals.hessian, p),
            spread: symmetric(&totals.spread, p),
            descent: DVector::from_column_slice(&totals.descent[..p]),
        }
    }

    /// The HC3 spread Σ_p g_p g_pᵀ/(1 − h_p)², h_p = tr(M_p J_p A⁻¹ J_pᵀ) the leverage
    /// (capped at [`MAX_LEVERAGE`]), with `inverse` = A⁻¹.
    fn hc3_spread(&self, inverse: &DMatrix<f64>) -> DMatrix<f64> {
        let p = self.layout.len();
        let inverse = square(inverse);
        let columns = self.columns();
        let mut spread: Square = [[0.0; MAX_PARAMETERS]; MAX_PARAMETERS];
        for point in 0..self.norms.len() {
            let term = self.term(point, &columns);
            let leverage = term.leverage(&inverse, &columns).clamp(0.0, MAX_LEVERAGE);
            let scale = 1.0 / ((1.0 - leverage) * (1.0 - leverage));
            for (i, row) in spread.iter_mut().enumerate().take(p) {
                let gi = scale * term.gradient[i];
                for (v, gj) in row.iter_mut().zip(&term.gradient).take(p).skip(i) {
                    *v += gi * gj;
                }
            }
        }
        symmetric(&spread, p)
    }
}

impl PointTerm {
    /// tr(M_p J_p A⁻¹ J_pᵀ) = Σ_cd M_cd Q_cd, Q_cd = J_c A⁻¹ J_dᵀ, with `inverse` = A⁻¹,
    /// each row of J_p taken at its channel's `columns` only; M and Q are symmetric, so
    /// each pair c < d is found once and counted twice.
    fn leverage(&self, inverse: &Square, columns: &[Columns; 3]) -> f64 {
        let mut trace = 0.0;
        let channels = || columns.iter().zip(&self.rows).enumerate();
        for (c, ((at_c, width_c), row_c)) in channels() {
            for (d, ((at_d, width_d), row_d)) in channels().skip(c) {
                let mut q = 0.0;
                for (&i, jc) in at_c[..*width_c].iter().zip(row_c) {
                    let k: f64 = at_d[..*width_d]
                        .iter()
                        .zip(row_d)
                        .map(|(&j, jd)| inverse[i][j] * jd)
                        .sum();
                    q += jc * k;
                }
                let twice = if c == d { 1.0 } else { 2.0 };
                trace += twice * self.curvature[c][d] * q;
            }
        }
        trace
    }
}

/// The P × P matrix `m` (P ≤ [`MAX_PARAMETERS`]) as a square array, zero beyond P.
fn square(m: &DMatrix<f64>) -> Square {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            if i < m.nrows() && j < m.ncols() {
                m[(i, j)]
            } else {
                0.0
            }
        })
    })
}

/// The P × P symmetric matrix whose upper triangle `upper` holds.
fn symmetric(upper: &Square, p: usize) -> DMatrix<f64> {
    DMatrix::from_fn(p, p, |i, j| upper[i.min(j)][i.max(j)])
}

/// A⁻¹ of the symmetric positive semi-definite A, or `None` when A is singular in its
/// correlation form (some parameter has no effect, or two have the same effect).
fn inverse_if_identifiable(a: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let d: Vec<f64> = a.diagonal().iter().map(|&v| v.sqrt()).collect();
    if d.iter().any(|&v| !(v > 0.0 && v.is_finite())) {
        return None;
    }
    let scaled = DMatrix::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)] / (d[i] * d[j]));
    let eigen = scaled.symmetric_eigen();
    if eigen
        .eigenvalues
        .iter()
        .any(|&l| l.is_nan() || l <= MIN_RELATIVE_EIGENVALUE)
    {
        return None;
    }
    let inverse_scaled = &eigen.eigenvectors
        * DMatrix::from_diagonal(&eigen.eigenvalues.map(|l| 1.0 / l))
        * eigen.eigenvectors.transpose();
    Some(DMatrix::from_fn(a.nrows(), a.ncols(), |i, j| {
        inverse_scaled[(i, j)] / (d[i] * d[j])
    }))
}

/// Standard uncertainties, intervals and the Ks–m correlation from the covariance of θ.
fn spread(
    layout: &Layout,
    params: &Params,
    ks_90: &[f64; 3],
    covariance: &DMatrix<f64>,
) -> Option<Spread> {
    let sigma = |i: usize| covariance[(i, i)].max(0.0).sqrt();
    let colour = |value: f64, i: usize| {
        let half = Z95 * sigma(i);
        [(value - half).max(0.0), value + half]
    };
    let m_count = if layout.shared { 1 } else { 3 };
    let stderr = ParameterSet {
        kd: std::array::from_fn(|c| sigma(layout.kd(c))),
        ks: std::array::from_fn(|c| sigma(layout.ks(c))),
        ks_90: layout
            .fresnel
            .then(|| std::array::from_fn(|c| sigma(layout.kg(c).unwrap_or_default()))),
        m: (0..m_count)
            .map(|c| params.m[c] * sigma(layout.ln_m(c)))
            .collect(),
    };
    let ci95 = ParameterSet {
        kd: std::array::from_fn(|c| colour(params.kd[c], layout.kd(c))),
        ks: std::array::from_fn(|c| colour(params.ks[c], layout.ks(c))),
        ks_90: layout
            .fresnel
            .then(|| std::array::from_fn(|c| colour(ks_90[c], layout.kg(c).unwrap_or_default()))),
        m: (0..m_count)
            .map(|c| {
                let half = Z95 * sigma(layout.ln_m(c));
                [params.m[c] * (-half).exp(), params.m[c] * half.exp()]
            })
            .collect(),
    };
    let correlation = Correlation {
        ks_m: std::array::from_fn(|c| {
            let (i, j) = (layout.ks(c), layout.ln_m(c));
            let scale = sigma(i) * sigma(j);
            if scale > 0.0 {
                (covariance[(i, j)] / scale).clamp(-1.0, 1.0)
            } else {
                0.0
            }
        }),
    };
    let finite = stderr
        .kd
        .iter()
        .chain(&stderr.ks)
        .chain(stderr.ks_90.iter().flatten())
        .chain(&stderr.m)
        .chain(ci95.m.iter().flatten())
        .chain(&correlation.ks_m)
        .all(|v| v.is_finite());
    finite.then_some(Spread {
        stderr,
        ci95,
        correlation,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::brdf::Model;
    use crate::samples::Sample;

    /// A small two-θL scan of `model` with 2 % deterministic multiplicative noise, a
    /// colour shift in the truth, and one dropped value.
    pub(crate) fn samples(model: Model) -> Vec<Sample> {
        let truth = Params::shared([8.0, 6.0, 3.0], [4.0, 3.5, 2.0], 0.15);
        let ks_90 = [2.0, 4.5, 3.0];
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut out = Vec::new();
        for theta_l in [-20.0, -45.0] {
            for k in 0..60 {
                let phi = theta_l / 2.0 - 50.0 + 100.0 * f64::from(k) / 59.0;
                let mut sample = Sample::in_plane(theta_l, theta_l - phi, phi, [0.0; 3]);
                let beta = model
                    .basis_at(&sample.cosines())
                    .evaluate_fresnel(&truth, &ks_90);
                sample.rgb = beta.map(|b| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    b * (1.0 + 0.04 * ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5))
                });
                out.push(sample);
            }
        }
        out[7].dropped[1] = true;
        out[7].rgb[1] = 0.0;
        out
    }

    /// Σ_p h_p = tr(A⁻¹ Σ_p J_pᵀ M_p J_p) = P: the leverages and A come from the same
    /// per-point terms, for every layout of θ.
    #[test]
    fn leverages_sum_to_the_number_of_parameters() {
        for (model, roughness, expected) in [
            (Model::CookTorrance, Roughness::Shared, 7),
            (Model::Ward, Roughness::PerChannel, 9),
            (Model::CookTorranceFresnel, Roughness::Shared, 10),
            (Model::CookTorranceFresnel, Roughness::PerChannel, 12),
        ] {
            let samples = samples(model);
            let data = Data::new(&samples, model, expected).unwrap();
            let mut options = FitOptions::new(model);
            options.roughness = roughness;
            let params = Params::shared([7.5, 6.2, 3.1], [4.2, 3.3, 2.1], 0.16);
            let ks_90 = [2.2, 4.4, 2.9];
            let residuals = Residuals::new(&data, &options, &params, &ks_90).unwrap();
            assert_eq!(residuals.layout.len(), expected, "{model} {roughness}");
            let inverse = square(&inverse_if_identifiable(&residuals.sums(false).hessian).unwrap());
            let columns = residuals.columns();
            let total: f64 = (0..samples.len())
                .map(|p| residuals.term(p, &columns).leverage(&inverse, &columns))
                .sum();
            assert!(
                (total - expected as f64).abs() < 1e-8,
                "{model} {roughness}: Σ h = {total}, expected {expected}"
            );
        }
    }
}
