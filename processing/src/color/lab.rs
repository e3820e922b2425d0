//! CIE 1976 L*a*b* and its polar form L*C*h (CIE 015:2018 §8.2.1).

/// L*, a*, b* of `xyz` relative to the white point `white` (both with Y of the white
/// 100). Negative or tiny ratios take the linear segment of f(t), so a noisy black or a
/// negative value from a measurement gives a finite L*a*b*, never NaN.
pub fn lab_from_xyz(xyz: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    let f = |t: f64| {
        const D: f64 = 6.0 / 29.0;
        if t > D * D * D {
            t.cbrt()
        } else {
            t / (3.0 * D * D) + 4.0 / 29.0
        }
    };
    let ratio = |c: usize| {
        if white[c] > 0.0 {
            xyz[c] / white[c]
        } else {
            0.0
        }
    };
    let (fx, fy, fz) = (f(ratio(0)), f(ratio(1)), f(ratio(2)));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// Chroma C*ab = √(a*² + b*²).
pub fn chroma(lab: [f64; 3]) -> f64 {
    lab[1].hypot(lab[2])
}

/// Hue angle h_ab in degrees, [0, 360); 0 for a neutral (a* = b* = 0).
pub fn hue_deg(lab: [f64; 3]) -> f64 {
    let h = lab[2].atan2(lab[1]).to_degrees();
    if h < 0.0 {
        h + 360.0
    } else {
        h
    }
}
