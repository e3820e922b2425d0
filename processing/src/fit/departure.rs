//! The departure of the setup that best explains a fit's residuals, for the uncertainty
//! budget (docs/ARCHITECTURE.md, "Uncertainty budget").
//!
//! A setup that is not the one setup.json states leaves residuals of its own: the θL no
//! longer agree with each other, and no parameter of the model absorbs that. Counted as
//! misfit they would count the setup's error twice (once in its source's line, once in
//! the misfit line), and sensitivities taken at values the model cannot fit are not the
//! model's (a robust fit to values that disagree moves in jumps). So the budget first
//! finds the departure z of each source (in standard uncertainties; the arm's angle one
//! per θL) most probable given the residuals r and the stated uncertainties,
//!
//!   min over z, δ of  Σ_pc (r_pc − Σ_j c_pcj·z_j − Σ_k g_pck·δ_k)² / (s²·u_pc²)  +  Σ_j z_j²,
//!
//! with c_pcj the samples' change of β per +1 u of source j, g_pck the model's Jacobian
//! (the parameters take up what they can: a departure they absorb is not identifiable
//! from the residuals and the prior keeps it at 0, as the white's is), u_pc the noise the
//! samples state and s² ≥ 1 the scatter of what is left over the noise (re-estimated until
//! it settles, so that misfit the sources cannot explain pulls z towards 0). The budget's
//! noise, misfit and source lines are then taken at the values with that departure
//! removed, y − Σ_j c_j·z_j. The fitted values themselves are not corrected: that is
//! calibration, `gonio calibrate`'s job.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::data::Data;
use super::FitError;
use crate::brdf::Params;
use crate::samples::{Sample, THETA_L_TOLERANCE};
use crate::setup_uncertainty::Source;

/// Samples whose rows one task sums into the normal equations.
const NORMAL_BLOCK: usize = 1024;

/// Rounds of the scatter s² (it settles in 2–3).
const SCATTER_ROUNDS: usize = 5;

/// Step in ln m of the Jacobian's central difference.
const LN_M_STEP: f64 = 1e-3;

/// Singular values below this fraction of the largest are dropped in the solve.
const SOLVE_TOLERANCE: f64 = 1e-12;

/// A source's departure is taken as identified by the residuals only when they know it
/// at least this much better than the prior does: its posterior standard deviation at
/// most this many standard uncertainties (the prior's is 1).
pub const MAX_POSTERIOR_STD: f64 = 0.5;

/// … and when it is significant: |z| at least this many posterior standard deviations.
pub const MIN_SIGNIFICANCE: f64 = 2.0;

/// … and when the stated uncertainty makes it plausible: |z| at most this many standard
/// uncertainties (a normal error lies beyond 3.5 u once in 2 000). Residuals that call
/// for more are the model's misfit, not a setup error.
pub const MAX_PLAUSIBLE_Z: f64 = 3.5;

/// … and only where what the departure leaves of the residuals is at most this many times
/// the noise the samples state: residuals well above the noise are the model's misfit,
/// which the sources' columns would take up in part (a Ward fit of a Cook–Torrance lobe
/// would read as arm angles several u off).
pub const MAX_LEFT_SCATTER: f64 = 1.5;

/// Whether a source whose departure is `z` ± `std` (posterior mean and standard
/// deviation, in its standard uncertainties) is identified by the residuals.
fn identified(z: f64, std: f64) -> bool {
    std <= MAX_POSTERIOR_STD && z.abs() >= MIN_SIGNIFICANCE * std && z.abs() <= MAX_PLAUSIBLE_Z
}

/// How far a source is from being identified (larger: farther), to leave out the worst
/// first: the largest of its three criteria's ratios to their bounds.
fn unidentified(z: f64, std: f64) -> f64 {
    let significance = MIN_SIGNIFICANCE * std / z.abs().max(f64::MIN_POSITIVE);
    (std / MAX_POSTERIOR_STD)
        .max(significance)
        .max(z.abs() / MAX_PLAUSIBLE_Z)
}

/// One identified source's departure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Found {
    pub source: Source,
    /// The arm angle θL (degrees) for the arm's angle.
    pub theta_l: Option<f64>,
    /// Posterior mean, in standard uncertainties (of the residuals' sign: the world's
    /// departure is −z).
    pub z: f64,
    /// Posterior standard deviation, in standard uncertainties.
    pub std: f64,
}

/// The departure found: the sources the residuals identify (the arm's angle per θL),
/// and the values with their departure removed.
pub(crate) struct Departure {
    /// Every identified source; the others are left at 0.
    pub z: Vec<Found>,
    /// y − Σ_j c_j·z_j per point (0 where a value was dropped).
    pub corrected: Vec<[f64; 3]>,
}

/// The departure of the setup that best explains the residuals of the fit (`params`,
/// `ks_90`) to `data`, made from `samples` (which carry their uncertainty); `theta_l` the
/// scan's distinct arm angles. `fresnel`: the fit has a specular colour at 90° of its own;
/// `shared`: one roughness for all channels.
pub(crate) fn estimate(
    data: &Data,
    samples: &[Sample],
    params: &Params,
    ks_90: &[f64; 3],
    theta_l: &[f64],
    fresnel: bool,
    shared: bool,
) -> Result<Departure, FitError> {
    // The columns: every source but the white's, the camera's yaw and roll and the arm's
    // angle, then the arm's angle per θL. The white's error scales every value: Kd and Ks
    // take it up entirely, and its column, the measured values scaled, would only find
    // their noise. The yaw moves the picture as the camera's offset does and the roll
    // slants it as the cylinder's tilt does: the residuals cannot tell them from those,
    // which take up their departures (as columns they only spread the others', and let a
    // fluctuation of one θL's arm angle pass for a departure on an exact scan).
    let mut columns: Vec<(Source, Option<f64>)> = Source::ALL
        .iter()
        .filter(|&&s| {
            !matches!(
                s,
                Source::ArmAngle
                    | Source::WhiteReflectance
                    | Source::CameraYaw
                    | Source::CameraRoll
            )
        })
        .map(|&s| (s, None))
        .collect();
    columns.extend(theta_l.iter().map(|&t| (Source::ArmAngle, Some(t))));
    let change = |sample: &Sample, &(source, at): &(Source, Option<f64>)| -> [f64; 3] {
        let Some(u) = &sample.uncertainty else {
            return [0.0; 3];
        };
        match at {
            Some(t) if (sample.theta_l - t).abs() > THETA_L_TOLERANCE => [0.0; 3],
            _ => u.sources[source.index()],
        }
    };
    let (estimates, jacobian) = jacobian(data, params, ks_90, fresnel, shared);
    let (n_z, n_g) = (columns.len(), jacobian.len());
    let size = n_z + n_g;

    let keep = |p: usize, c: usize| data.keep.as_ref().is_none_or(|k| k[p][c] > 0.0);
    let mean = data.zero_loss / data.y.len().max(1) as f64;
    let floor = 1e-6 * mean + f64::MIN_POSITIVE;
    // Per value: the row [c_·j | g_·k], its residual and 1/u², summed into the normal
    // equations as they come, a block of samples at a time in parallel (the blocks' sums
    // added in order: the same sums on any number of threads).
    let block = |(k, block): (usize, &[Sample])| {
        let mut normal = Normal::new(size);
        let mut row = vec![0.0; size];
        let mut changes = vec![[0.0; 3]; n_z];
        for (i, sample) in block.iter().enumerate() {
            let p = k * NORMAL_BLOCK + i;
            let noise = sample.uncertainty.as_ref().map_or([0.0; 3], |u| u.noise);
            for (d, col) in changes.iter_mut().zip(&columns) {
                *d = change(sample, col);
            }
            for c in (0..3).filter(|&c| keep(p, c)) {
                for (v, d) in row.iter_mut().zip(
                    changes
                        .iter()
                        .map(|d| d[c])
                        .chain(jacobian.iter().map(|g| g[p][c])),
                ) {
                    *v = d;
                }
                let u = noise[c].max(floor);
                normal.add(&row, data.y[p][c] - estimates[p][c], 1.0 / (u * u));
            }
        }
        normal
    };
    let blocks: Vec<Normal> = samples
        .par_chunks(NORMAL_BLOCK)
        .enumerate()
        .map(block)
        .collect();
    let mut normal = Normal::new(size);
    for b in &blocks {
        normal.merge(b);
    }
    if normal.rows <= size {
        return Err(FitError::TooFewPoints {
            points: normal.rows,
            parameters: size,
        });
    }

    // Sources are left out, the least identified first, until every one kept is
    // identified ([`identified`]); the model's parameters always stay.
    let mut active: Vec<bool> = vec![true; n_z];
    let (z, std) = loop {
        let (z, std, scatter2) = solve_active(&normal, &active, n_z)?;
        let worst = (0..n_z)
            .filter(|&j| active[j] && !identified(z[j], std[j]))
            .max_by(|&a, &b| unidentified(z[a], std[a]).total_cmp(&unidentified(z[b], std[b])));
        match worst {
            Some(j) => active[j] = false,
            // Residuals the departure leaves well above the noise are the model's misfit
            // (or a setup error the sources' columns do not describe): none is identified.
            None if scatter2 > MAX_LEFT_SCATTER * MAX_LEFT_SCATTER => break (vec![0.0; n_z], std),
            None => break (z, std),
        }
    };
    let corrected = samples
        .iter()
        .enumerate()
        .map(|(p, sample)| {
            let mut y = data.y[p];
            for (col, zj) in columns.iter().zip(&z) {
                let d = change(sample, col);
                for c in (0..3).filter(|&c| keep(p, c)) {
                    y[c] -= zj * d[c];
                }
            }
            y
        })
        .collect();
    Ok(Departure {
        z: columns
            .iter()
            .zip(z.iter().zip(&std))
            .filter(|(_, (z, _))| **z != 0.0)
            .map(|(&(s, at), (&z, &std))| Found {
                source: s,
                theta_l: at,
                z,
                std,
            })
            .collect(),
        corrected,
    })
}

/// The weighted normal equations of the rows (row, residual r, weight w) over every
/// column: Σ w·row·rowᵀ (upper triangle, row-major), Σ w·row·r and Σ w·r².
struct Normal {
    size: usize,
    matrix: Vec<f64>,
    rhs: Vec<f64>,
    squares: f64,
    rows: usize,
    /// The columns of the row being added whose entry is not 0 (kept from row to row).
    nonzero: Vec<usize>,
}

impl Normal {
    fn new(size: usize) -> Self {
        Normal {
            size,
            matrix: vec![0.0; size * size],
            rhs: vec![0.0; size],
            squares: 0.0,
            rows: 0,
            nonzero: Vec::with_capacity(size),
        }
    }

    /// Adds one row. A zero entry adds nothing to any sum (most of a row's are zero: the
    /// arm's angle of the other θL, the model's columns of the other channels), so only
    /// the products of nonzero entries are added, each sum's in the order of the rows.
    fn add(&mut self, row: &[f64], r: f64, w: f64) {
        self.nonzero.clear();
        self.nonzero
            .extend((0..row.len()).filter(|&a| row[a] != 0.0));
        for (k, &a) in self.nonzero.iter().enumerate() {
            let wa = w * row[a];
            self.rhs[a] += wa * r;
            let line = &mut self.matrix[a * self.size..(a + 1) * self.size];
            for &b in &self.nonzero[k..] {
                line[b] += wa * row[b];
            }
        }
        self.squares += w * r * r;
        self.rows += 1;
    }

    /// Adds the rows summed in `other` (of the same size).
    fn merge(&mut self, other: &Normal) {
        for (v, o) in self.matrix.iter_mut().zip(&other.matrix) {
            *v += o;
        }
        for (v, o) in self.rhs.iter_mut().zip(&other.rhs) {
            *v += o;
        }
        self.squares += other.squares;
        self.rows += other.rows;
    }

    /// Σ w·row_i·row_j.
    fn at(&self, i: usize, j: usize) -> f64 {
        self.matrix[i.min(j) * self.size + i.max(j)]
    }
}

/// The least-squares solution of the rows summed in `normal` over the model's columns
/// (those from `n_z` on) and the active sources' (each with its N(0, 1) prior), the
/// scatter s² of what is left over the noise re-estimated until it settles: every
/// source's posterior mean and standard deviation (0 and 1, the prior, for an inactive
/// one), and s².
fn solve_active(
    normal: &Normal,
    active: &[bool],
    n_z: usize,
) -> Result<(Vec<f64>, Vec<f64>, f64), FitError> {
    let kept: Vec<usize> = (0..normal.size)
        .filter(|&i| i >= n_z || active[i])
        .collect();
    let n = kept.len();
    let mut scatter2: f64 = 1.0;
    let mut found = (vec![0.0; n_z], vec![1.0; n_z]);
    for _ in 0..SCATTER_ROUNDS {
        let matrix = DMatrix::from_fn(n, n, |a, b| {
            let prior = if a == b && kept[a] < n_z { 1.0 } else { 0.0 };
            normal.at(kept[a], kept[b]) / scatter2 + prior
        });
        let rhs = DVector::from_fn(n, |a, _| normal.rhs[kept[a]] / scatter2);
        let (solution, variance) = solve(matrix, rhs)?;
        for (a, &i) in kept.iter().enumerate().filter(|(_, &i)| i < n_z) {
            found.0[i] = solution[a];
            found.1[i] = variance[a].max(0.0).sqrt();
        }
        // What is left, over the noise, per value (at least 1): Σ w (r − row·x)².
        let mut left = normal.squares;
        for (a, &i) in kept.iter().enumerate() {
            left -= 2.0 * solution[a] * normal.rhs[i];
            for (b, &j) in kept.iter().enumerate() {
                left += solution[a] * solution[b] * normal.at(i, j);
            }
        }
        let next = (left.max(0.0) / (normal.rows - n) as f64).max(1.0);
        let settled = (next - scatter2).abs() <= 1e-3 * scatter2;
        scatter2 = next;
        if settled {
            break;
        }
    }
    Ok((found.0, found.1, scatter2))
}

/// The model's β at (`params`, `ks_90`) at every point ([`Data::estimates`]), and its
/// Jacobian there: per parameter (Kd, Ks, Ks_90 when `fresnel`, ln m shared or per
/// channel), the change of every point's β.
fn jacobian(
    data: &Data,
    params: &Params,
    ks_90: &[f64; 3],
    fresnel: bool,
    shared: bool,
) -> (Vec<[f64; 3]>, Vec<Vec<[f64; 3]>>) {
    // Each column as the difference of two evaluations at every point, (upper, lower
    // or the fit's own when `None`, step): found in parallel.
    type Point = (Params, [f64; 3]);
    let mut differences: Vec<(Point, Option<Point>, f64)> = Vec::new();
    for c in 0..3 {
        // Kd and Ks enter linearly: a unit step is exact.
        let mut p = *params;
        p.kd[c] += 1.0;
        differences.push(((p, *ks_90), None, 1.0));
        let mut p = *params;
        p.ks[c] += 1.0;
        let mut k = *ks_90;
        if !fresnel {
            k[c] += 1.0;
        }
        differences.push(((p, k), None, 1.0));
        if fresnel {
            let mut k = *ks_90;
            k[c] += 1.0;
            differences.push(((*params, k), None, 1.0));
        }
    }
    let channels: Vec<Vec<usize>> = if shared {
        vec![vec![0, 1, 2]]
    } else {
        (0..3).map(|c| vec![c]).collect()
    };
    for set in channels {
        let (mut up, mut down) = (*params, *params);
        for &c in &set {
            up.m[c] *= LN_M_STEP.exp();
            down.m[c] *= (-LN_M_STEP).exp();
        }
        differences.push(((up, *ks_90), Some((down, *ks_90)), 2.0 * LN_M_STEP));
    }
    let base_estimates = data.estimates(params, ks_90);
    let columns = differences
        .par_iter()
        .map(|((p, k), lower, scale)| {
            let upper = data.estimates(p, k);
            let lower = lower.map(|(p, k)| data.estimates(&p, &k));
            let lower = lower.as_deref().unwrap_or(&base_estimates);
            upper
                .iter()
                .zip(lower)
                .map(|(a, b)| std::array::from_fn(|c| (a[c] - b[c]) / scale))
                .collect()
        })
        .collect();
    (base_estimates, columns)
}

/// x of `normal`·x = `rhs` and the diagonal of `normal`'s inverse (the posterior
/// variances), scaled to a unit diagonal and solved by SVD (directions the data do not
/// determine are left at 0).
fn solve(normal: DMatrix<f64>, rhs: DVector<f64>) -> Result<(DVector<f64>, Vec<f64>), FitError> {
    let n = normal.nrows();
    let scale: Vec<f64> = (0..n)
        .map(|i| {
            let d = normal[(i, i)];
            if d > 0.0 && d.is_finite() {
                1.0 / d.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let scaled = DMatrix::from_fn(n, n, |i, j| normal[(i, j)] * scale[i] * scale[j]);
    let b = DVector::from_fn(n, |i, _| rhs[i] * scale[i]);
    let svd = scaled.svd(true, true);
    let largest = svd.singular_values.max();
    let y = svd
        .solve(&b, SOLVE_TOLERANCE * largest)
        .map_err(|e| FitError::Optimizer(format!("setup departure: {e}")))?;
    let inverse = svd
        .pseudo_inverse(SOLVE_TOLERANCE * largest)
        .map_err(|e| FitError::Optimizer(format!("setup departure: {e}")))?;
    let x = DVector::from_fn(n, |i, _| y[i] * scale[i]);
    let variance: Vec<f64> = (0..n)
        .map(|i| inverse[(i, i)] * scale[i] * scale[i])
        .collect();
    if x.iter().chain(&variance).all(|v| v.is_finite()) {
        Ok((x, variance))
    } else {
        Err(FitError::Overflow("setup departure"))
    }
}
