//! Exact minimisation of the eq. 10 loss over Kd, Ks ≥ 0 at a fixed roughness.
//!
//! At fixed m both models are linear in (Kd_c, Ks_c), so eq. 10, Σ_p ‖y_p − ŷ_p‖₂, is a
//! convex function of the six coefficients. It is minimised by iteratively reweighted
//! least squares, a majorise–minimise scheme: with w_p = 1/‖r_p‖ of the current
//! residuals, Σ_p w_p‖r_p‖²/2 + const majorises the loss, and each majoriser splits into
//! one weighted two-variable non-negative least-squares problem per channel, solved in
//! closed form. The first pass (unit weights, or the weights of a previous solve) is the
//! ordinary NNLS start; the loss never rises by more than rounding and the best iterate is
//! kept. Residuals below a tiny floor δ get weight 1/δ.

use super::Data;

/// Stop reweighting once one pass lowers the loss by less than this fraction.
const RELATIVE_TOLERANCE: f64 = 1e-10;
/// Cap on reweighting passes per solve.
const MAX_PASSES: usize = 60;

/// Coefficients minimising eq. 10 at one roughness, with that loss.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LinearFit {
    pub kd: [f64; 3],
    pub ks: [f64; 3],
    pub loss: f64,
}

/// Minimises Σ w (y − kd·a − ks·s)² over kd, ks ≥ 0 from the weighted sums
/// saa = Σwa², sas = Σwas, sss = Σws², say = Σway, ssy = Σwsy.
fn nnls2(saa: f64, sas: f64, sss: f64, say: f64, ssy: f64) -> (f64, f64) {
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

/// Minimises eq. 10 over Kd, Ks ≥ 0 given each channel's specular basis values `spec[c][p]`.
/// `weights` carries the reweighting state between calls (resized to unit weights when its
/// length does not match); `residuals` is scratch space.
pub(crate) fn solve(
    data: &Data,
    spec: [&[f64]; 3],
    weights: &mut Vec<f64>,
    residuals: &mut Vec<f64>,
) -> LinearFit {
    let n = data.y.len();
    if weights.len() != n {
        weights.clear();
        weights.resize(n, 1.0);
    }
    residuals.resize(n, 0.0);
    let floor = data.residual_floor;
    let mut best = LinearFit {
        kd: [0.0; 3],
        ks: [0.0; 3],
        loss: f64::INFINITY,
    };
    let mut previous = f64::INFINITY;
    for _ in 0..MAX_PASSES {
        let mut kd = [0.0; 3];
        let mut ks = [0.0; 3];
        for c in 0..3 {
            let (mut saa, mut sas, mut sss, mut say, mut ssy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for p in 0..n {
                let w = weights[p];
                let a = data.diffuse[p];
                let s = spec[c][p];
                let y = data.y[p][c];
                let wa = w * a;
                let ws = w * s;
                saa += wa * a;
                sas += wa * s;
                sss += ws * s;
                say += wa * y;
                ssy += ws * y;
            }
            (kd[c], ks[c]) = nnls2(saa, sas, sss, say, ssy);
        }
        let mut loss = 0.0;
        for p in 0..n {
            let a = data.diffuse[p];
            let y = &data.y[p];
            let r: [f64; 3] =
                std::array::from_fn(|c| y[c] - kd[c] * a - ks[c] * spec[c][p]);
            let norm = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            residuals[p] = norm;
            loss += norm;
        }
        if loss < best.loss {
            best = LinearFit { kd, ks, loss };
        }
        if loss <= floor || (previous.is_finite() && previous - loss <= RELATIVE_TOLERANCE * previous) {
            break;
        }
        previous = loss;
        for (w, r) in weights.iter_mut().zip(residuals.iter()) {
            *w = 1.0 / r.max(floor);
        }
    }
    best
}
