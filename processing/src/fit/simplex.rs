//! MATLAB's `fminsearch`: the Nelder–Mead simplex method as Lagarias, Reeds, Wright and
//! Wright (1998) describe it, with bounds kept by clipping trial points onto them (as
//! scipy's Nelder–Mead does when given bounds), never by a penalty.
//!
//! - Initial simplex: x0 and, for each coordinate j, x0 with x_j · 1.05 (0.00025 where
//!   x_j = 0), each clipped onto the bounds.
//! - Each iteration replaces the worst vertex by the reflection (coefficient 1), the
//!   expansion (2) or a contraction outside or inside (0.5), or else shrinks every vertex
//!   halfway toward the best one (0.5). The vertices stay sorted by value, ties in their
//!   previous order.
//! - Before each iteration it stops when max_j |f_j − f_1| ≤ max(TolFun, 10·eps(f_1)) and
//!   max_j ‖v_j − v_1‖∞ ≤ max(TolX, 10·eps(max_i v_1,i)) (both absolute), or when MaxIter
//!   iterations or MaxFunEvals evaluations are reached. The initial simplex counts as one
//!   iteration and n + 1 evaluations.
//!
//! A NaN value counts as +∞, so the simplex moves away from it.

/// Stopping settings, with fminsearch's meaning and defaults (see [`Settings::fminsearch`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Settings {
    pub tol_x: f64,
    pub tol_fun: f64,
    pub max_iter: usize,
    pub max_fun_evals: usize,
}

impl Settings {
    /// fminsearch's defaults for `n` unknowns: TolX = TolFun = 1e-4,
    /// MaxIter = MaxFunEvals = 200·n.
    pub fn fminsearch(n: usize) -> Self {
        Settings {
            tol_x: 1e-4,
            tol_fun: 1e-4,
            max_iter: 200 * n,
            max_fun_evals: 200 * n,
        }
    }
}

/// Why the search ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Stop {
    /// Both tolerances were met (fminsearch's exit flag 1).
    Converged,
    /// MaxFunEvals reached (exit flag 0).
    MaxFunEvals,
    /// MaxIter reached (exit flag 0).
    MaxIter,
}

/// The best vertex found and what it took.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Minimum {
    pub x: Vec<f64>,
    pub value: f64,
    pub iterations: usize,
    pub evaluations: usize,
    pub stop: Stop,
}

/// Lagarias et al.'s coefficients: reflection ρ, expansion χ, contraction ψ, shrink σ.
const RHO: f64 = 1.0;
const CHI: f64 = 2.0;
const PSI: f64 = 0.5;
const SIGMA: f64 = 0.5;
/// Relative step of the initial simplex for a non-zero coordinate.
const USUAL_DELTA: f64 = 0.05;
/// Step of the initial simplex for a zero coordinate.
const ZERO_TERM_DELTA: f64 = 0.00025;

/// MATLAB's eps(x): the distance from |x| to the next larger double (NaN for ±∞, NaN).
fn eps(x: f64) -> f64 {
    let a = x.abs();
    if a.is_finite() {
        a.next_up() - a
    } else {
        f64::NAN
    }
}

/// Minimises `f` from `x0` with every point clipped into [lower, upper] (per coordinate;
/// `x0`, `lower` and `upper` have the same length).
pub(crate) fn minimize(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    lower: &[f64],
    upper: &[f64],
    settings: &Settings,
) -> Minimum {
    let n = x0.len();
    debug_assert!(lower.len() == n && upper.len() == n);
    let clip = |x: &mut [f64]| {
        for ((v, &lo), &hi) in x.iter_mut().zip(lower).zip(upper) {
            *v = v.clamp(lo, hi);
        }
    };
    let mut evaluate = |x: &[f64]| {
        let v = f(x);
        if v.is_nan() {
            f64::INFINITY
        } else {
            v
        }
    };

    let mut start = x0.to_vec();
    clip(&mut start);
    let mut vertices = vec![start.clone()];
    for j in 0..n {
        let mut y = start.clone();
        y[j] = if y[j] != 0.0 {
            (1.0 + USUAL_DELTA) * y[j]
        } else {
            ZERO_TERM_DELTA
        };
        clip(&mut y);
        vertices.push(y);
    }
    let mut values: Vec<f64> = vertices.iter().map(|v| evaluate(v)).collect();
    sort(&mut vertices, &mut values);
    let mut iterations = 1;
    let mut evaluations = n + 1;

    // Trial point (1 + t)·x̄ − t·v_worst, clipped.
    let trial = |centroid: &[f64], worst: &[f64], t: f64| {
        let mut x: Vec<f64> = centroid
            .iter()
            .zip(worst)
            .map(|(c, w)| (1.0 + t) * c - t * w)
            .collect();
        clip(&mut x);
        x
    };
    while evaluations < settings.max_fun_evals && iterations < settings.max_iter {
        if converged(&vertices, &values, settings) {
            break;
        }
        let mut centroid = vec![0.0; n];
        for v in &vertices[..n] {
            for (c, x) in centroid.iter_mut().zip(v) {
                *c += x;
            }
        }
        centroid.iter_mut().for_each(|c| *c /= n as f64);
        let worst = vertices[n].clone();
        let reflected = trial(&centroid, &worst, RHO);
        let f_reflected = evaluate(&reflected);
        evaluations += 1;
        let mut replacement = None;
        if f_reflected < values[0] {
            let expanded = trial(&centroid, &worst, RHO * CHI);
            let f_expanded = evaluate(&expanded);
            evaluations += 1;
            replacement = Some(if f_expanded < f_reflected {
                (expanded, f_expanded)
            } else {
                (reflected, f_reflected)
            });
        } else if f_reflected < values[n - 1] {
            replacement = Some((reflected, f_reflected));
        } else if f_reflected < values[n] {
            let outside = trial(&centroid, &worst, PSI * RHO);
            let f_outside = evaluate(&outside);
            evaluations += 1;
            if f_outside <= f_reflected {
                replacement = Some((outside, f_outside));
            }
        } else {
            let inside = trial(&centroid, &worst, -PSI);
            let f_inside = evaluate(&inside);
            evaluations += 1;
            if f_inside < values[n] {
                replacement = Some((inside, f_inside));
            }
        }
        match replacement {
            Some((x, value)) => {
                vertices[n] = x;
                values[n] = value;
            }
            None => {
                let best = vertices[0].clone();
                for j in 1..=n {
                    for (v, b) in vertices[j].iter_mut().zip(&best) {
                        *v = b + SIGMA * (*v - b);
                    }
                    clip(&mut vertices[j]);
                    values[j] = evaluate(&vertices[j]);
                }
                evaluations += n;
            }
        }
        sort(&mut vertices, &mut values);
        iterations += 1;
    }
    let stop = if evaluations >= settings.max_fun_evals {
        Stop::MaxFunEvals
    } else if iterations >= settings.max_iter {
        Stop::MaxIter
    } else {
        Stop::Converged
    };
    Minimum {
        x: vertices.swap_remove(0),
        value: values[0],
        iterations,
        evaluations,
        stop,
    }
}

/// fminsearch's test: the values and the vertices are both within tolerance of the best.
fn converged(vertices: &[Vec<f64>], values: &[f64], settings: &Settings) -> bool {
    let best = &vertices[0];
    let value_spread = values[1..]
        .iter()
        .map(|v| (values[0] - v).abs())
        .fold(0.0, f64::max);
    let size = vertices[1..]
        .iter()
        .flat_map(|v| v.iter().zip(best).map(|(a, b)| (a - b).abs()))
        .fold(0.0, f64::max);
    let largest = best.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    value_spread <= settings.tol_fun.max(10.0 * eps(values[0]))
        && size <= settings.tol_x.max(10.0 * eps(largest))
}

/// Sorts vertices by value, ties kept in their current order (MATLAB's stable `sort`).
fn sort(vertices: &mut Vec<Vec<f64>>, values: &mut Vec<f64>) {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    *vertices = order.iter().map(|&i| vertices[i].clone()).collect();
    *values = order.iter().map(|&i| values[i]).collect();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rosenbrock(x: &[f64]) -> f64 {
        100.0 * (x[1] - x[0] * x[0]).powi(2) + (1.0 - x[0]).powi(2)
    }

    /// MATLAB's documentation example: `fminsearch(@(x)100*(x(2)-x(1)^2)^2+(1-x(1))^2,
    /// [-1.2,1])` with `Display iter` ends at iteration 85 after 159 function evaluations
    /// with f = 8.17766e-10 and x = (1.0000, 1.0000); its last three steps are "contract
    /// inside" (155 evaluations, 1.12293e-09), "contract outside" (157, 1.10755e-09) and
    /// "contract inside" (159, 8.17766e-10). An identical path reproduces all of it.
    #[test]
    fn rosenbrock_follows_the_documented_fminsearch_path() {
        let unbounded = [f64::NEG_INFINITY; 2];
        let free = [f64::INFINITY; 2];
        let settings = Settings::fminsearch(2);
        let mut trace = Vec::new();
        let found = minimize(
            |x| {
                let v = rosenbrock(x);
                trace.push(v);
                v
            },
            &[-1.2, 1.0],
            &unbounded,
            &free,
            &settings,
        );
        assert_eq!(found.stop, Stop::Converged);
        assert_eq!(found.evaluations, 159);
        assert_eq!(found.iterations, 85);
        assert_eq!(trace.len(), 159);
        assert!((found.value - 8.17766e-10).abs() < 5e-15, "{}", found.value);
        for (x, want) in found.x.iter().zip([1.0, 1.0]) {
            assert!((x - want).abs() < 1e-4, "{:?}", found.x);
        }
    }

    #[test]
    fn caps_and_clipping_hold() {
        // MaxFunEvals is checked before each iteration, as in fminsearch: it may be
        // passed by at most the n + 1 evaluations of one shrink.
        let capped = |settings: Settings| {
            let free = [f64::NEG_INFINITY, f64::INFINITY];
            minimize(
                rosenbrock,
                &[-1.2, 1.0],
                &[free[0]; 2],
                &[free[1]; 2],
                &settings,
            )
        };
        let found = capped(Settings {
            max_fun_evals: 40,
            ..Settings::fminsearch(2)
        });
        assert_eq!(found.stop, Stop::MaxFunEvals);
        assert!((40..=42).contains(&found.evaluations));
        let found = capped(Settings {
            max_iter: 10,
            ..Settings::fminsearch(2)
        });
        assert_eq!((found.stop, found.iterations), (Stop::MaxIter, 10));
        // The unconstrained minimum (1, 1) lies outside x ≤ 0.5: the search ends on the
        // bound, at the constrained minimum (0.5, 0.25), and never evaluates outside.
        let mut outside = 0;
        let found = minimize(
            |x| {
                outside += usize::from(x[0] > 0.5);
                rosenbrock(x)
            },
            &[-1.2, 1.0],
            &[f64::NEG_INFINITY; 2],
            &[0.5, f64::INFINITY],
            &Settings::fminsearch(2),
        );
        assert_eq!(outside, 0);
        assert!((found.x[0] - 0.5).abs() < 1e-3 && (found.x[1] - 0.25).abs() < 1e-3);
        // NaN counts as +∞: the simplex turns back from where f is undefined.
        let mut undefined = 0;
        let found = minimize(
            |x| {
                if x[1] > 1.1 {
                    undefined += 1;
                    f64::NAN
                } else {
                    rosenbrock(x)
                }
            },
            &[-1.2, 1.0],
            &[f64::NEG_INFINITY; 2],
            &[f64::INFINITY; 2],
            &Settings::fminsearch(2),
        );
        assert!(undefined > 0);
        assert!(found.value.is_finite() && found.value < 1e-6, "{found:?}");
    }
}
