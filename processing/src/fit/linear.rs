//! Minimisation of the eq. 10 loss over Kd, Ks (and Ks_90) ≥ 0 at a fixed roughness.
//!
//! At fixed m every model is linear in its coefficients (Kd_c, Ks_c, and Ks_90_c for
//! Cook–Torrance–Fresnel), so eq. 10, Σ_p ‖y_p − ŷ_p‖₂, is a convex function of them. It is
//! minimised by iteratively reweighted least squares, a majorise–minimise scheme: with
//! w_p = 1/‖r_p‖ of the current residuals, Σ_p w_p‖r_p‖²/2 + const majorises the loss, and
//! each majoriser splits into one weighted non-negative least-squares problem per channel
//! in two or three variables, solved exactly (closed form, or every active set of three).
//! The first pass (unit weights) is the ordinary NNLS solution. Weights are capped through
//! a smoothing ε that shrinks to the requested tolerance, so the result is within that
//! relative tolerance of the exact minimum; the best iterate is kept.

use super::data::Data;

/// Relative loss decrease at which a solve counts as converged.
pub(crate) const FINE_TOLERANCE: f64 = 1e-9;
/// Looser convergence for scanning a grid, where only the ranking of values matters.
pub(crate) const COARSE_TOLERANCE: f64 = 1e-3;
/// Cap on reweighting passes per solve.
const MAX_PASSES: usize = 60;
/// Smoothing of the weights, as a fraction of the mean residual: first value and per-pass
/// factor. It ends at the solve's tolerance, which bounds the loss error the smoothing
/// leaves (a fraction ε of the mean residual per point).
const EPSILON_START: f64 = 0.1;
const EPSILON_SHRINK: f64 = 0.1;
/// First smoothing of a warm solve.
const WARM_EPSILON_START: f64 = 1e-4;
/// Largest extrapolation factor tried along a pass's step.
const MAX_EXTRAPOLATION: f64 = 64.0;

/// Coefficients minimising eq. 10 at one roughness, with that loss. `kg` is the grazing
/// specular colour Ks_90; equal to `ks` for the models without one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LinearFit {
    pub kd: [f64; 3],
    pub ks: [f64; 3],
    pub kg: [f64; 3],
    pub loss: f64,
}

/// Minimises Σ w (y − kd·a − ks·s)² over kd, ks ≥ 0 from the weighted sums
/// saa = Σwa², sas = Σwas, sss = Σws², say = Σway, ssy = Σwsy.
pub(crate) fn nnls2(saa: f64, sas: f64, sss: f64, say: f64, ssy: f64) -> (f64, f64) {
    let det = saa * sss - sas * sas;
    if det > 1e-12 * saa * sss {
        let kd = (sss * say - sas * ssy) / det;
        let ks = (saa * ssy - sas * say) / det;
        if kd >= 0.0 && ks >= 0.0 {
            return (kd, ks);
        }
    }
    // The optimum lies on one of the two boundary rays: the best of their clamped minima.
    let kd = if saa > 0.0 { (say / saa).max(0.0) } else { 0.0 };
    let ks = if sss > 0.0 { (ssy / sss).max(0.0) } else { 0.0 };
    let gain_kd = kd * (2.0 * say - kd * saa);
    let gain_ks = ks * (2.0 * ssy - ks * sss);
    if gain_kd >= gain_ks {
        (kd, 0.0)
    } else {
        (0.0, ks)
    }
}

/// Minimises Σ w (y − Σ_k z_k·b_k)² over z ≥ 0 for three bases, from the weighted Gram
/// matrix `g` (g_jk = Σ w b_j b_k) and `r` (r_k = Σ w b_k y): the convex problem's optimum
/// is the best feasible unconstrained optimum over the seven non-empty active sets (and 0).
/// An active set whose Gram block is singular (relative pivot below 1e-12) is skipped.
fn nnls3(g: &[[f64; 3]; 3], r: &[f64; 3]) -> [f64; 3] {
    let mut best = ([0.0; 3], 0.0);
    for set in 1u8..8 {
        let mut members = [0; 3];
        let mut len = 0;
        for k in 0..3 {
            if set & (1 << k) != 0 {
                members[len] = k;
                len += 1;
            }
        }
        let index = &members[..len];
        let Some(z) = solve_block(g, r, index) else {
            continue;
        };
        if z.iter().any(|&v| v < 0.0) {
            continue;
        }
        // The objective ½zᵀGz − rᵀz at the block's optimum is −½ rᵀz.
        let value = -0.5 * index.iter().map(|&k| r[k] * z[k]).sum::<f64>();
        if value < best.1 {
            best = (z, value);
        }
    }
    best.0
}

/// The solution of G_SS z_S = r_S on the indices S (others 0) by Gaussian elimination
/// with partial pivoting; `None` when the block is singular.
fn solve_block(g: &[[f64; 3]; 3], r: &[f64; 3], index: &[usize]) -> Option<[f64; 3]> {
    let n = index.len();
    let mut a = [[0.0; 4]; 3];
    for (i, &gi) in index.iter().enumerate() {
        for (j, &gj) in index.iter().enumerate() {
            a[i][j] = g[gi][gj];
        }
        a[i][n] = r[gi];
    }
    let scale = index.iter().map(|&k| g[k][k]).fold(0.0, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for col in 0..n {
        let pivot = (col..n).max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))?;
        if a[pivot][col].abs() <= 1e-12 * scale {
            return None;
        }
        a.swap(col, pivot);
        let pivot_row = a[col];
        for row in a.iter_mut().take(n).skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (v, p) in row[col..=n].iter_mut().zip(&pivot_row[col..=n]) {
                *v -= f * p;
            }
        }
    }
    let mut z = [0.0; 3];
    for i in (0..n).rev() {
        let tail: f64 = (i + 1..n).map(|k| a[i][k] * z[index[k]]).sum();
        z[index[i]] = (a[i][n] - tail) / a[i][i];
    }
    z.iter().all(|v| v.is_finite()).then_some(z)
}

/// Scratch buffers of [`solve`], reused across calls.
#[derive(Debug, Default)]
pub(crate) struct Workspace {
    /// Residual norms of the current iterate, of the pass's candidate and of a trial.
    current: Vec<f64>,
    candidate: Vec<f64>,
    trial: Vec<f64>,
    /// The last solution, the start of a warm solve.
    last: Option<LinearFit>,
}

impl Workspace {
    /// Makes (kd, ks, kg) the start of the next warm solve: a known fit near the one sought.
    pub(crate) fn start_from(&mut self, kd: [f64; 3], ks: [f64; 3], kg: [f64; 3]) {
        self.last = Some(LinearFit {
            kd,
            ks,
            kg,
            loss: f64::INFINITY,
        });
    }
}

/// Eq. 10 loss of (kd, ks, kg), writing each point's residual norm to `residuals`.
fn loss_of(
    data: &Data,
    spec: [&[f64]; 3],
    [kd, ks, kg]: [&[f64; 3]; 3],
    residuals: &mut [f64],
) -> f64 {
    if let Some(x) = &data.shift_weight {
        return fresnel_loss_of(data, spec, x, [kd, ks, kg], residuals);
    }
    let n = data.y.len();
    // Equal-length slices let the loop run without bounds checks.
    let (y, a, out) = (&data.y[..n], &data.diffuse[..n], &mut residuals[..n]);
    let (s0, s1, s2) = (&spec[0][..n], &spec[1][..n], &spec[2][..n]);
    let mut loss = 0.0;
    if let Some(keep) = &data.keep {
        // Dropped values (y = 0, keep = 0) leave no residual.
        let keep = &keep[..n];
        for p in 0..n {
            let r0 = y[p][0] - keep[p][0] * (kd[0] * a[p] + ks[0] * s0[p]);
            let r1 = y[p][1] - keep[p][1] * (kd[1] * a[p] + ks[1] * s1[p]);
            let r2 = y[p][2] - keep[p][2] * (kd[2] * a[p] + ks[2] * s2[p]);
            let norm = (r0 * r0 + r1 * r1 + r2 * r2).sqrt();
            out[p] = norm;
            loss += norm;
        }
        return loss;
    }
    for p in 0..n {
        let r0 = y[p][0] - kd[0] * a[p] - ks[0] * s0[p];
        let r1 = y[p][1] - kd[1] * a[p] - ks[1] * s1[p];
        let r2 = y[p][2] - kd[2] * a[p] - ks[2] * s2[p];
        let norm = (r0 * r0 + r1 * r1 + r2 * r2).sqrt();
        out[p] = norm;
        loss += norm;
    }
    loss
}

/// [`loss_of`] for the models with a specular colour at 90°, Ks·(1 − w) + kg·w, with the
/// points' shift weights w in `x`.
fn fresnel_loss_of(
    data: &Data,
    spec: [&[f64]; 3],
    x: &[f64],
    [kd, ks, kg]: [&[f64; 3]; 3],
    residuals: &mut [f64],
) -> f64 {
    let n = data.y.len();
    let (y, a, x, out) = (
        &data.y[..n],
        &data.diffuse[..n],
        &x[..n],
        &mut residuals[..n],
    );
    let s = [&spec[0][..n], &spec[1][..n], &spec[2][..n]];
    let shift: [f64; 3] = std::array::from_fn(|c| kg[c] - ks[c]);
    let keep = data.keep.as_ref().map(|keep| &keep[..n]);
    let mut loss = 0.0;
    for p in 0..n {
        // Dropped values (y = 0, keep = 0) leave no residual.
        let keep = keep.map_or([1.0; 3], |keep| keep[p]);
        let mut r = [0.0; 3];
        for (c, rc) in r.iter_mut().enumerate() {
            *rc = y[p][c] - keep[c] * (kd[c] * a[p] + (ks[c] + x[p] * shift[c]) * s[c][p]);
        }
        let norm = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        out[p] = norm;
        loss += norm;
    }
    loss
}

/// The weights of a reweighted pass, computed as the pass reads them (no pass of their
/// own): all 1 (the first pass of a cold solve), or 1/max(‖r_p‖, cap) of the residual
/// norms `norms` of the current iterate.
#[derive(Clone, Copy)]
enum Weights<'a> {
    Unit,
    Capped { norms: &'a [f64], cap: f64 },
}

/// One reweighted pass: the weighted NNLS solution of each channel, as (kd, ks, kg).
fn weighted_nnls(data: &Data, spec: [&[f64]; 3], weights: Weights) -> [[f64; 3]; 3] {
    let n = data.y.len();
    match weights {
        Weights::Unit => weighted_nnls_with(data, spec, |_| 1.0),
        Weights::Capped { norms, cap } => {
            let norms = &norms[..n];
            weighted_nnls_with(data, spec, |p| 1.0 / norms[p].max(cap))
        }
    }
}

/// [`weighted_nnls`] with point p's weight `w(p)`.
#[inline(always)]
fn weighted_nnls_with(data: &Data, spec: [&[f64]; 3], w: impl Fn(usize) -> f64) -> [[f64; 3]; 3] {
    if let Some(x) = &data.shift_weight {
        return fresnel_weighted_nnls(data, spec, x, w);
    }
    let n = data.y.len();
    let (y, a) = (&data.y[..n], &data.diffuse[..n]);
    let s = [&spec[0][..n], &spec[1][..n], &spec[2][..n]];
    let mut saa = [0.0; 3];
    let (mut sas, mut sss, mut say, mut ssy) = ([0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3]);
    if let Some(keep) = &data.keep {
        // Each channel's sums over its measured values only (y is 0 where dropped).
        let keep = &keep[..n];
        for p in 0..n {
            let wp = w(p);
            for c in 0..3 {
                let wk = wp * keep[p][c];
                let sc = s[c][p];
                saa[c] += wk * a[p] * a[p];
                sas[c] += wk * a[p] * sc;
                sss[c] += wk * sc * sc;
                say[c] += wp * a[p] * y[p][c];
                ssy[c] += wp * sc * y[p][c];
            }
        }
    } else if std::ptr::eq(s[0], s[1]) && std::ptr::eq(s[0], s[2]) {
        // One specular basis for all channels: its sums are shared too.
        let s = s[0];
        for p in 0..n {
            let wp = w(p);
            let wa = wp * a[p];
            let ws = wp * s[p];
            saa[0] += wa * a[p];
            sas[0] += wa * s[p];
            sss[0] += ws * s[p];
            for c in 0..3 {
                say[c] += wa * y[p][c];
                ssy[c] += ws * y[p][c];
            }
        }
        saa = [saa[0]; 3];
        sas = [sas[0]; 3];
        sss = [sss[0]; 3];
    } else {
        for p in 0..n {
            let wp = w(p);
            let wa = wp * a[p];
            saa[0] += wa * a[p];
            for c in 0..3 {
                let sc = s[c][p];
                let ws = wp * sc;
                sas[c] += wa * sc;
                sss[c] += ws * sc;
                say[c] += wa * y[p][c];
                ssy[c] += ws * y[p][c];
            }
        }
        saa = [saa[0]; 3];
    }
    let mut kd = [0.0; 3];
    let mut ks = [0.0; 3];
    for c in 0..3 {
        (kd[c], ks[c]) = nnls2(saa[c], sas[c], sss[c], say[c], ssy[c]);
    }
    [kd, ks, ks]
}

/// [`weighted_nnls`] with the bases a, s·(1 − w), s·w of Kd, Ks, Ks_90, with the points'
/// shift weights w in `x`.
#[inline(always)]
fn fresnel_weighted_nnls(
    data: &Data,
    spec: [&[f64]; 3],
    x: &[f64],
    w: impl Fn(usize) -> f64,
) -> [[f64; 3]; 3] {
    let n = data.y.len();
    let (y, a, x) = (&data.y[..n], &data.diffuse[..n], &x[..n]);
    let mut gram = [[[0.0; 3]; 3]; 3];
    let mut rhs = [[0.0; 3]; 3];
    for c in 0..3 {
        let s = &spec[c][..n];
        let (g, r) = (&mut gram[c], &mut rhs[c]);
        for p in 0..n {
            // Each channel's sums over its measured values only.
            let wk = w(p) * data.keep.as_ref().map_or(1.0, |keep| keep[p][c]);
            let b = [a[p], s[p] * (1.0 - x[p]), s[p] * x[p]];
            for j in 0..3 {
                let wb = wk * b[j];
                r[j] += wb * y[p][c];
                for k in j..3 {
                    g[j][k] += wb * b[k];
                }
            }
        }
        let upper = *g;
        *g = std::array::from_fn(|j| std::array::from_fn(|k| upper[j.min(k)][j.max(k)]));
    }
    let z: [[f64; 3]; 3] = std::array::from_fn(|c| nnls3(&gram[c], &rhs[c]));
    std::array::from_fn(|k| std::array::from_fn(|c| z[c][k]))
}

/// Minimises eq. 10 over Kd, Ks ≥ 0 given each channel's specular basis values `spec[c][p]`.
/// Converged when a pass at the final smoothing lowers the loss by less than `tolerance`
/// (relative).
///
/// Weights are 1/max(‖r_p‖, ε) with ε a fraction of the mean residual that shrinks by
/// [`EPSILON_SHRINK`] per pass from [`EPSILON_START`] to `tolerance` (continuation):
/// capped weights keep the early passes from locking onto points that happen to have tiny
/// residuals, which makes plain reweighting crawl. Each pass also extrapolates along its
/// step (×2, ×4, … while the loss keeps falling, clamped to Kd, Ks ≥ 0), which shortens
/// the slow linear tail of reweighting.
///
/// A `warm` solve starts from the previous solution in `ws` (weights from its residuals at
/// the new basis, smoothing from [`WARM_EPSILON_START`]): for a small change of m.
pub(crate) fn solve(
    data: &Data,
    spec: [&[f64]; 3],
    tolerance: f64,
    warm: bool,
    ws: &mut Workspace,
) -> LinearFit {
    let n = data.y.len();
    for buffer in [&mut ws.current, &mut ws.candidate, &mut ws.trial] {
        buffer.resize(n, 0.0);
    }
    let floor = data.residual_floor;
    let mut epsilon = EPSILON_START;
    let mut current: Option<LinearFit> = None;
    // The next pass's weights: 1/max(‖r_p‖, cap) of the current iterate's residuals.
    let mut cap: Option<f64> = None;
    if let (true, Some(last)) = (warm, ws.last) {
        let loss = loss_of(data, spec, [&last.kd, &last.ks, &last.kg], &mut ws.current);
        cap = Some((WARM_EPSILON_START * loss / n as f64).max(floor));
        current = Some(LinearFit { loss, ..last });
        epsilon = (WARM_EPSILON_START * EPSILON_SHRINK).max(tolerance);
    }
    for _ in 0..MAX_PASSES {
        let weights = match cap {
            Some(cap) => Weights::Capped {
                norms: &ws.current,
                cap,
            },
            None => Weights::Unit,
        };
        let [kd, ks, kg] = weighted_nnls(data, spec, weights);
        let mut next = LinearFit {
            kd,
            ks,
            kg,
            loss: loss_of(data, spec, [&kd, &ks, &kg], &mut ws.candidate),
        };
        if let Some(cur) = &current {
            let mut t = 2.0;
            while t <= MAX_EXTRAPOLATION {
                let step = |from: &[f64; 3], to: &[f64; 3]| -> [f64; 3] {
                    std::array::from_fn(|c| (from[c] + t * (to[c] - from[c])).max(0.0))
                };
                let (kd, ks, kg) = (step(&cur.kd, &kd), step(&cur.ks, &ks), step(&cur.kg, &kg));
                let loss = loss_of(data, spec, [&kd, &ks, &kg], &mut ws.trial);
                if loss >= next.loss {
                    break;
                }
                next = LinearFit { kd, ks, kg, loss };
                std::mem::swap(&mut ws.candidate, &mut ws.trial);
                t *= 2.0;
            }
        }
        let previous = current.map_or(f64::INFINITY, |c| c.loss);
        if next.loss < previous {
            current = Some(next);
            std::mem::swap(&mut ws.current, &mut ws.candidate);
        }
        let final_smoothing = epsilon <= tolerance;
        if next.loss <= floor || (final_smoothing && previous - next.loss <= tolerance * previous) {
            break;
        }
        let mean = current.map_or(next.loss, |c| c.loss) / n as f64;
        cap = Some((epsilon * mean).max(floor));
        epsilon = (epsilon * EPSILON_SHRINK).max(tolerance);
    }
    let fit = current.unwrap_or_else(|| LinearFit {
        kd: [0.0; 3],
        ks: [0.0; 3],
        kg: [0.0; 3],
        loss: data
            .y
            .iter()
            .map(|y| (y[0] * y[0] + y[1] * y[1] + y[2] * y[2]).sqrt())
            .sum(),
    });
    ws.last = Some(fit);
    fit
}
