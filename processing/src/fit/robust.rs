//! The robust method: the colour coefficients solved at each m (see `linear`) and a global
//! search over log m.

use std::cell::{Cell, RefCell};

use argmin::core::{CostFunction, Error as ArgminError, Executor};
use argmin::solver::brent::BrentOpt;

use super::data::{Data, Found};
use super::error::FitError;
use super::linear;
use super::nelder_mead;
use super::options::FitOptions;
use crate::brdf::{Params, Roughness};

/// Grid local minima within this fraction of the best grid value are refined too.
const REFINE_WITHIN: f64 = 0.05;
/// At most this many grid local minima are refined.
const MAX_REFINED: usize = 3;
/// Per-channel roughness: rounds of channel-by-channel search at most.
const MAX_ROUNDS: usize = 6;
/// Per-channel roughness: stop once a round lowers the loss by less than this fraction of
/// it plus [`ROUND_SIGNAL_TOLERANCE`] of the data's scale Σ‖y‖ (for near-exact fits).
const ROUND_TOLERANCE: f64 = 1e-7;
const ROUND_SIGNAL_TOLERANCE: f64 = 1e-9;
/// Brent tolerance on ln m: relative and absolute parts.
const BRENT_EPS: f64 = 1.5e-8;
const BRENT_ABS: f64 = 1e-6;

/// How finely a search along ln m converges: each solve's relative loss tolerance (see
/// `linear::solve`) and Brent's relative and absolute tolerances on ln m.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Precision {
    pub solve: f64,
    pub ln_m_relative: f64,
    pub ln_m_absolute: f64,
}

impl Precision {
    /// The fit's own: m to about 1e-6 of itself.
    pub(crate) const FINE: Precision = Precision {
        solve: linear::FINE_TOLERANCE,
        ln_m_relative: BRENT_EPS,
        ln_m_absolute: BRENT_ABS,
    };
}

/// Which roughness a one-dimensional search moves.
#[derive(Clone, Copy)]
enum Target {
    Shared,
    Channel(usize),
}

impl Target {
    fn apply(self, mut m: [f64; 3], value: f64) -> [f64; 3] {
        match self {
            Target::Shared => m = [value; 3],
            Target::Channel(c) => m[c] = value,
        }
        m
    }
}

/// The loss profile: eq. 10 minimised over Kd, Ks at a given m, with caches.
struct Profile<'a> {
    data: &'a Data,
    spec: [Vec<f64>; 3],
    /// The m each `spec` vector holds; NaN when not computed yet.
    spec_m: [f64; 3],
    workspace: linear::Workspace,
    evaluations: u64,
    /// The best solve so far: its parameters, specular colour at 90° and loss.
    best: Option<(Params, [f64; 3], f64)>,
}

impl<'a> Profile<'a> {
    fn new(data: &'a Data) -> Self {
        let n = data.y.len();
        Profile {
            data,
            spec: [vec![0.0; n], vec![0.0; n], vec![0.0; n]],
            spec_m: [f64::NAN; 3],
            workspace: linear::Workspace::default(),
            evaluations: 0,
            best: None,
        }
    }

    fn update_spec(&mut self, c: usize, m: f64) {
        if self.spec_m[c] != m {
            self.data.columns.specular(m, &mut self.spec[c]);
            self.spec_m[c] = m;
        }
    }

    /// Profile loss at roughness `m` (all channels use `m[0]` when `shared`), with the
    /// inner solve converged to `tolerance`, warm-started from the previous solve if `warm`.
    fn eval(&mut self, m: [f64; 3], shared: bool, tolerance: f64, warm: bool) -> f64 {
        let fit = if shared {
            self.update_spec(0, m[0]);
            let s = self.spec[0].as_slice();
            linear::solve(self.data, [s, s, s], tolerance, warm, &mut self.workspace)
        } else {
            for (c, &mc) in m.iter().enumerate() {
                self.update_spec(c, mc);
            }
            let [r, g, b] = &self.spec;
            linear::solve(self.data, [r, g, b], tolerance, warm, &mut self.workspace)
        };
        self.evaluations += 1;
        let better = match &self.best {
            Some((_, _, loss)) => fit.loss < *loss,
            None => true,
        };
        if better {
            self.best = Some((
                Params {
                    kd: fit.kd,
                    ks: fit.ks,
                    m,
                },
                fit.kg,
                fit.loss,
            ));
        }
        fit.loss
    }

    fn best_m(&self) -> [f64; 3] {
        self.best.as_ref().map_or([f64::NAN; 3], |(p, _, _)| p.m)
    }

    fn best_loss(&self) -> f64 {
        self.best
            .as_ref()
            .map_or(f64::INFINITY, |(_, _, loss)| *loss)
    }
}

/// The profile along one roughness as a function of ln m, for Brent's method. Its first
/// evaluation starts cold, later ones warm from the previous (nearby) m.
struct LineProfile<'p, 'a> {
    profile: &'p RefCell<Profile<'a>>,
    base: [f64; 3],
    target: Target,
    warm: Cell<bool>,
    tolerance: f64,
}

impl CostFunction for LineProfile<'_, '_> {
    type Param = f64;
    type Output = f64;
    fn cost(&self, ln_m: &f64) -> Result<f64, ArgminError> {
        let m = self.target.apply(self.base, ln_m.exp());
        let shared = matches!(self.target, Target::Shared);
        let warm = self.warm.replace(true);
        Ok(self
            .profile
            .borrow_mut()
            .eval(m, shared, self.tolerance, warm))
    }
}

/// Minimises the profile along `target` on [lo, hi] in ln m with Brent's method.
fn brent(
    profile: &RefCell<Profile<'_>>,
    base: [f64; 3],
    target: Target,
    lo: f64,
    hi: f64,
) -> Result<(), FitError> {
    brent_from(profile, base, target, (lo, hi), false, Precision::FINE)
}

/// [`brent`], its first solve warm from the profile's last one when `warm`.
fn brent_from(
    profile: &RefCell<Profile<'_>>,
    base: [f64; 3],
    target: Target,
    (lo, hi): (f64, f64),
    warm: bool,
    precision: Precision,
) -> Result<(), FitError> {
    let line = LineProfile {
        profile,
        base,
        target,
        warm: Cell::new(warm),
        tolerance: precision.solve,
    };
    let solver =
        BrentOpt::new(lo, hi).set_tolerance(precision.ln_m_relative, precision.ln_m_absolute);
    Executor::new(line, solver)
        .configure(|state| state.max_iters(200))
        .run()
        .map_err(|e| FitError::Optimizer(e.to_string()))?;
    Ok(())
}

/// Grid over the whole ln m range along `target` (each grid solve warm-started from the
/// previous grid point's), then Brent around the best grid minima.
fn global_search(
    profile: &RefCell<Profile<'_>>,
    base: [f64; 3],
    target: Target,
    ln_range: (f64, f64),
    grid_points: usize,
) -> Result<(), FitError> {
    let (lo, hi) = ln_range;
    let step = (hi - lo) / (grid_points - 1) as f64;
    let grid: Vec<f64> = (0..grid_points).map(|k| lo + step * k as f64).collect();
    let shared = matches!(target, Target::Shared);
    let values: Vec<f64> = grid
        .iter()
        .enumerate()
        .map(|(k, x)| {
            profile.borrow_mut().eval(
                target.apply(base, x.exp()),
                shared,
                linear::COARSE_TOLERANCE,
                k > 0,
            )
        })
        .collect();
    let mut minima: Vec<usize> = (0..grid_points)
        .filter(|&k| {
            (k == 0 || values[k] <= values[k - 1])
                && (k + 1 == grid_points || values[k] <= values[k + 1])
        })
        .collect();
    minima.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let Some(&first) = minima.first() else {
        return Err(FitError::Optimizer(
            "the loss profile over m is not finite".into(),
        ));
    };
    let best = values[first];
    for &k in minima
        .iter()
        .take(MAX_REFINED)
        .filter(|&&k| values[k] <= best + REFINE_WITHIN * best.abs())
    {
        let a = grid[k.saturating_sub(1)];
        let b = grid[(k + 1).min(grid_points - 1)];
        brent(profile, base, target, a, b)?;
    }
    Ok(())
}

fn validate(options: &FitOptions) -> Result<(f64, f64), FitError> {
    let o = &options.robust;
    if !(o.m_min > 0.0 && o.m_max > o.m_min && o.m_max.is_finite()) {
        return Err(FitError::InvalidOptions(format!(
            "roughness range [{}, {}] must satisfy 0 < m_min < m_max < ∞",
            o.m_min, o.m_max
        )));
    }
    if o.grid_points < 3 {
        return Err(FitError::InvalidOptions(format!(
            "grid_points = {} (at least 3 needed)",
            o.grid_points
        )));
    }
    Ok((o.m_min.ln(), o.m_max.ln()))
}

/// Brackets the profile's minimum along `target` from ln m = `x0` (each solve warm from
/// the last, converged to `tolerance`): `x0 ± step`, then downhill in steps doubling
/// each time until the profile rises again or the search range `range` ends. Returns an
/// interval of ln m holding the lowest value found with a higher one (or a range end)
/// on each side.
fn bracket(
    profile: &RefCell<Profile<'_>>,
    base: [f64; 3],
    target: Target,
    x0: f64,
    step: f64,
    range: (f64, f64),
    tolerance: f64,
) -> (f64, f64) {
    let shared = matches!(target, Target::Shared);
    let at = |x: f64| {
        profile
            .borrow_mut()
            .eval(target.apply(base, x.exp()), shared, tolerance, true)
    };
    let x0 = x0.clamp(range.0, range.1);
    let f0 = at(x0);
    let up = (x0 + step).min(range.1);
    let down = (x0 - step).max(range.0);
    let f_up = if up > x0 { at(up) } else { f64::INFINITY };
    let f_down = if down < x0 { at(down) } else { f64::INFINITY };
    if f0 <= f_up && f0 <= f_down {
        return (down, up);
    }
    let (sign, mut end) = if f_up < f_down {
        (1.0, up)
    } else {
        (-1.0, down)
    };
    let (mut behind, mut f_end, mut stride) = (x0, f_up.min(f_down), step);
    while end > range.0 && end < range.1 {
        stride *= 2.0;
        let next = (end + sign * stride).clamp(range.0, range.1);
        let f_next = at(next);
        if f_next >= f_end {
            return (behind.min(next), behind.max(next));
        }
        (behind, end, f_end) = (end, next, f_next);
    }
    (behind.min(end), behind.max(end))
}

/// The robust fit of data near those of a known fit `start` (its parameters and specular
/// colour at 90°): from `start`'s roughness, the minimum bracketed along ln m by steps of
/// `step` ([`bracket`]) within the search range, then Brent within the bracket (each
/// channel's in turn for per-channel roughness, in rounds as [`fit`]'s); the first solve
/// warm from `start`'s coefficients, no grid and no polish, converged to `precision`.
/// A local search: for data whose profile has one minimum within reach of `start`'s, as
/// data moved a little from `start`'s have.
pub(crate) fn fit_near(
    data: &Data,
    options: &FitOptions,
    start: &Params,
    start_kg: [f64; 3],
    step: f64,
    precision: Precision,
) -> Result<(Found, [f64; 3]), FitError> {
    let ln_range = validate(options)?;
    let profile = RefCell::new(Profile::new(data));
    profile
        .borrow_mut()
        .workspace
        .start_from(start.kd, start.ks, start_kg);
    let search = |base: [f64; 3], target: Target, c: usize| {
        let range = bracket(
            &profile,
            base,
            target,
            base[c].ln(),
            step,
            ln_range,
            precision.solve,
        );
        brent_from(&profile, base, target, range, true, precision)
    };
    match options.roughness {
        Roughness::Shared => search(start.m, Target::Shared, 0)?,
        Roughness::PerChannel => {
            for _ in 0..MAX_ROUNDS {
                let before = profile.borrow().best_loss();
                for c in 0..3 {
                    let base = profile
                        .borrow()
                        .best
                        .as_ref()
                        .map_or(start.m, |(p, _, _)| p.m);
                    search(base, Target::Channel(c), c)?;
                }
                let after = profile.borrow().best_loss();
                if before - after
                    <= ROUND_TOLERANCE * before + ROUND_SIGNAL_TOLERANCE * data.zero_loss
                {
                    break;
                }
            }
        }
    }
    let profile = profile.into_inner();
    let (params, ks_90, _) = profile
        .best
        .ok_or_else(|| FitError::Optimizer("no roughness was evaluated".into()))?;
    Ok((
        Found {
            params,
            evaluations: profile.evaluations,
        },
        ks_90,
    ))
}

/// The robust fit: the parameters found and the specular colour at 90°.
pub(crate) fn fit(data: &Data, options: &FitOptions) -> Result<(Found, [f64; 3]), FitError> {
    let ln_range = validate(options)?;
    let grid_points = options.robust.grid_points;
    let profile = RefCell::new(Profile::new(data));
    global_search(&profile, [1.0; 3], Target::Shared, ln_range, grid_points)?;
    if options.roughness == Roughness::PerChannel {
        let step = (ln_range.1 - ln_range.0) / (grid_points - 1) as f64;
        for round in 0..MAX_ROUNDS {
            let before = profile.borrow().best_loss();
            for c in 0..3 {
                let base = profile.borrow().best_m();
                let target = Target::Channel(c);
                if round == 0 {
                    global_search(&profile, base, target, ln_range, grid_points)?;
                } else {
                    let x = base[c].ln();
                    let lo = (x - 2.0 * step).max(ln_range.0);
                    let hi = (x + 2.0 * step).min(ln_range.1);
                    brent(&profile, base, target, lo, hi)?;
                }
            }
            let after = profile.borrow().best_loss();
            if before - after <= ROUND_TOLERANCE * before + ROUND_SIGNAL_TOLERANCE * data.zero_loss
            {
                break;
            }
        }
    }
    let profile = profile.into_inner();
    let (params, ks_90, loss) = profile
        .best
        .ok_or_else(|| FitError::Optimizer("no roughness was evaluated".into()))?;
    let mut found = Found {
        params,
        evaluations: profile.evaluations,
    };
    if options.robust.polish {
        let polished = nelder_mead::polish(data, options, &params)?;
        found.evaluations += polished.evaluations;
        if data.loss(&polished.params) < loss {
            found.params = polished.params;
            return Ok((found, polished.params.ks));
        }
    }
    Ok((found, ks_90))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Model;
    use crate::samples::Sample;

    /// Two θL of Cook–Torrance values with roughness `m` and 2 % deterministic noise.
    fn data(m: f64) -> Data {
        let truth = Params::shared([8.0, 6.0, 3.0], [4.0, 3.5, 2.0], m);
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut samples = Vec::new();
        for theta_l in [-20.0, -40.0] {
            for k in 0..120 {
                let phi = theta_l / 2.0 - 50.0 + 100.0 * f64::from(k) / 119.0;
                let beta = Model::CookTorrance
                    .evaluate(&truth, theta_l - phi, phi)
                    .map(|b| {
                        state = state
                            .wrapping_mul(6_364_136_223_846_793_005)
                            .wrapping_add(1_442_695_040_888_963_407);
                        b * (1.0 + 0.04 * ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5))
                    });
                samples.push(Sample::in_plane(theta_l, theta_l - phi, phi, beta));
            }
        }
        Data::new(&samples, Model::CookTorrance, 7).unwrap()
    }

    /// A start whose roughness is a factor 2 off each way (ln m 0.69, many bracketing
    /// steps): the bracket walks to the minimum and Brent finds the full search's.
    #[test]
    fn a_fit_near_a_distant_start_finds_the_full_search_minimum() {
        let data = data(0.2);
        let options = FitOptions::new(Model::CookTorrance);
        let (full, _) = fit(&data, &options).unwrap();
        for factor in [0.5, 2.0] {
            let start = Params::shared([7.0, 5.0, 2.5], [3.0, 3.0, 1.5], 0.2 * factor);
            let (near, _) =
                fit_near(&data, &options, &start, start.ks, 0.02, Precision::FINE).unwrap();
            let m = (near.params.m[0], full.params.m[0]);
            assert!((m.0 / m.1 - 1.0).abs() < 1e-5, "factor {factor}: m {m:?}");
            let loss = (data.loss(&near.params), data.loss(&full.params));
            assert!(
                loss.0 <= loss.1 * (1.0 + 1e-9),
                "factor {factor}: loss {loss:?}"
            );
            assert!(
                near.evaluations < full.evaluations,
                "factor {factor}: {} evaluations, the full search {}",
                near.evaluations,
                full.evaluations
            );
        }
    }
}
