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
            for (s, b) in self.spec[c].iter_mut().zip(&self.data.bases) {
                *s = b.specular(m);
            }
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

/// The robust fit of data near those of a known fit `start` (its parameters and specular
/// colour at 90°): Brent over ln m within ±`span` of `start`'s roughness (each channel's in
/// turn for per-channel roughness, in rounds as [`fit`]'s), the first solve warm from
/// `start`'s coefficients, no grid and no polish, converged to `precision`. `None` when a roughness found lies at an
/// end of its bracket that is not an end of the search range: the fit may lie beyond, and
/// the caller searches the whole range with [`fit`].
pub(crate) fn fit_near(
    data: &Data,
    options: &FitOptions,
    start: &Params,
    start_kg: [f64; 3],
    span: f64,
    precision: Precision,
) -> Result<Option<(Found, [f64; 3])>, FitError> {
    let ln_range = validate(options)?;
    let profile = RefCell::new(Profile::new(data));
    profile
        .borrow_mut()
        .workspace
        .start_from(start.kd, start.ks, start_kg);
    let bracket = |x: f64| ((x - span).max(ln_range.0), (x + span).min(ln_range.1));
    // Whether ln m = `x` found in `bracket` lies at one of its inner ends: within a
    // hundredth of the span and four times Brent's tolerance, where Brent stops when the
    // minimum lies beyond the end.
    let at_inner_end = |x: f64, (lo, hi): (f64, f64)| {
        let margin =
            0.01 * span + 4.0 * (precision.ln_m_absolute + precision.ln_m_relative * x.abs());
        (x - lo < margin && lo > ln_range.0) || (hi - x < margin && hi < ln_range.1)
    };
    let m0 = start.m;
    match options.roughness {
        Roughness::Shared => {
            let range = bracket(m0[0].ln());
            brent_from(&profile, m0, Target::Shared, range, true, precision)?;
            if at_inner_end(profile.borrow().best_m()[0].ln(), range) {
                return Ok(None);
            }
        }
        Roughness::PerChannel => {
            for _ in 0..MAX_ROUNDS {
                let before = profile.borrow().best_loss();
                for c in 0..3 {
                    let base = profile.borrow().best.as_ref().map_or(m0, |(p, _, _)| p.m);
                    let range = bracket(base[c].ln());
                    brent_from(&profile, base, Target::Channel(c), range, true, precision)?;
                    if at_inner_end(profile.borrow().best_m()[c].ln(), range) {
                        return Ok(None);
                    }
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
    Ok(Some((
        Found {
            params,
            evaluations: profile.evaluations,
        },
        ks_90,
    )))
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
