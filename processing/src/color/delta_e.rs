//! Colour differences: the CIELAB components ΔL*, ΔC*ab, ΔH*ab (CIE 015:2018 §8.2.1),
//! CIEDE2000 (CIE 142-2001, as Sharma, Wu and Dalal 2005, *The CIEDE2000 color-difference
//! formula: implementation notes, supplementary test data, and mathematical
//! observations*, Color Res. Appl. 30:21, write it, kL = kC = kH = 1) and the flop index
//! of effect colours.

use super::lab::{chroma, hue_deg};

/// ΔL*, ΔC*ab and ΔH*ab of `batch` against `standard` (batch − standard). ΔH*ab =
/// 2√(C₁C₂)·sin(Δh/2), Δh the hue difference in (−180°, 180°]: signed, and
/// ΔL*² + ΔC*² + ΔH*² = ΔE*ab².
pub fn cielab_components(standard: [f64; 3], batch: [f64; 3]) -> [f64; 3] {
    let (c1, c2) = (chroma(standard), chroma(batch));
    let dh = wrap_180(hue_deg(batch) - hue_deg(standard));
    [
        batch[0] - standard[0],
        c2 - c1,
        2.0 * (c1 * c2).sqrt() * (dh.to_radians() / 2.0).sin(),
    ]
}

/// A hue difference brought into (−180°, 180°].
fn wrap_180(d: f64) -> f64 {
    if d > 180.0 {
        d - 360.0
    } else if d <= -180.0 {
        d + 360.0
    } else {
        d
    }
}

/// CIEDE2000 ΔE00 between two L*a*b* (symmetric in its arguments).
pub fn ciede2000(lab1: [f64; 3], lab2: [f64; 3]) -> f64 {
    let pow7_25 = 25f64.powi(7);
    let c_bar = (chroma(lab1) + chroma(lab2)) / 2.0;
    let c_bar7 = c_bar.powi(7);
    let g = 0.5 * (1.0 - (c_bar7 / (c_bar7 + pow7_25)).sqrt());
    let prime = |lab: [f64; 3]| {
        let a = (1.0 + g) * lab[1];
        let c = a.hypot(lab[2]);
        let h = if c == 0.0 {
            0.0
        } else {
            hue_deg([lab[0], a, lab[2]])
        };
        (c, h)
    };
    let ((c1, h1), (c2, h2)) = (prime(lab1), prime(lab2));
    let d_l = lab2[0] - lab1[0];
    let d_c = c2 - c1;
    let product = c1 * c2;
    let d_h_angle = if product == 0.0 {
        0.0
    } else {
        let d = h2 - h1;
        if d > 180.0 {
            d - 360.0
        } else if d < -180.0 {
            d + 360.0
        } else {
            d
        }
    };
    let d_h = 2.0 * product.sqrt() * (d_h_angle.to_radians() / 2.0).sin();
    let l_bar = (lab1[0] + lab2[0]) / 2.0;
    let c_bar_p = (c1 + c2) / 2.0;
    let h_bar = if product == 0.0 {
        h1 + h2
    } else if (h1 - h2).abs() <= 180.0 {
        (h1 + h2) / 2.0
    } else if h1 + h2 < 360.0 {
        (h1 + h2 + 360.0) / 2.0
    } else {
        (h1 + h2 - 360.0) / 2.0
    };
    let cos_deg = |x: f64| x.to_radians().cos();
    let t = 1.0 - 0.17 * cos_deg(h_bar - 30.0)
        + 0.24 * cos_deg(2.0 * h_bar)
        + 0.32 * cos_deg(3.0 * h_bar + 6.0)
        - 0.20 * cos_deg(4.0 * h_bar - 63.0);
    let d_theta = 30.0 * (-((h_bar - 275.0) / 25.0).powi(2)).exp();
    let c_bar_p7 = c_bar_p.powi(7);
    let r_c = 2.0 * (c_bar_p7 / (c_bar_p7 + pow7_25)).sqrt();
    let l50 = (l_bar - 50.0).powi(2);
    let s_l = 1.0 + 0.015 * l50 / (20.0 + l50).sqrt();
    let s_c = 1.0 + 0.045 * c_bar_p;
    let s_h = 1.0 + 0.015 * c_bar_p * t;
    let r_t = -(2.0 * d_theta).to_radians().sin() * r_c;
    let (l, c, h) = (d_l / s_l, d_c / s_c, d_h / s_h);
    (l * l + c * c + h * h + r_t * c * h).max(0.0).sqrt()
}

/// The flop index of an effect colour from its L* at the aspecular angles 15°, 45° and
/// 110° (45° illumination): FI = 2.69·(L*15 − L*110)^1.11 / (L*45)^0.86, the DuPont
/// definition X-Rite's multi-angle instruments (MA68, MA98, MA-T) report (X-Rite, *MA98
/// Multi-Angle Spectrophotometer: Operation Manual*, "Flop index"). A solid colour has
/// FI ≈ 0, a bright aluminium 15–17. L*15 < L*110 gives a negative index (the power
/// taken of the magnitude); `None` when L*45 is not positive.
pub fn flop_index(l15: f64, l45: f64, l110: f64) -> Option<f64> {
    if !(l45 > 0.0 && l15.is_finite() && l110.is_finite()) {
        return None;
    }
    let d = l15 - l110;
    Some(2.69 * d.signum() * d.abs().powf(1.11) / l45.powf(0.86))
}
