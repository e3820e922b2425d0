//! A display colour for a CIELAB value: the sRGB swatch of IEC 61966-2-1 (D65 white),
//! for showing a measured colour on a screen or page — not a measurement. Lab relative to
//! another white (D50) is first adapted to D65 by the linear Bradford transform (CIE
//! 160:2004's chromatic adaptation, as ICC profiles use it).

/// The D65 white of sRGB, XYZ with Y = 100 (IEC 61966-2-1: x = 0.3127, y = 0.3290).
pub const SRGB_WHITE: [f64; 3] = [95.047, 100.0, 108.883];

/// XYZ (Y = 1) → linear sRGB (IEC 61966-2-1).
const XYZ_TO_LINEAR_SRGB: [[f64; 3]; 3] = [
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
];

/// Bradford cone response matrix and its inverse.
const BRADFORD: [[f64; 3]; 3] = [
    [0.8951, 0.2664, -0.1614],
    [-0.7502, 1.7135, 0.0367],
    [0.0389, -0.0685, 1.0296],
];
const BRADFORD_INVERSE: [[f64; 3]; 3] = [
    [0.986_993, -0.147_054, 0.159_963],
    [0.432_305, 0.518_360, 0.049_291],
    [-0.008_529, 0.040_043, 0.968_487],
];

/// How far outside [0, 1] a linear channel may be and still count as in gamut: the
/// rounding of an 8-bit swatch.
const GAMUT_TOLERANCE: f64 = 0.5 / 255.0;

/// A swatch: 8-bit sRGB, and whether the colour had to be clipped into the sRGB gamut
/// (then the swatch only suggests it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Swatch {
    pub rgb: [u8; 3],
    pub in_gamut: bool,
}

impl Swatch {
    /// `#rrggbb`.
    pub fn hex(&self) -> String {
        format!("#{:02x}{:02x}{:02x}", self.rgb[0], self.rgb[1], self.rgb[2])
    }
}

fn apply(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

/// XYZ of `lab` relative to `white` (Y of the white 100): the inverse of
/// [`lab_from_xyz`](super::lab::lab_from_xyz) (CIE 015:2018 §8.2.1).
pub fn xyz_from_lab(lab: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    const D: f64 = 6.0 / 29.0;
    let f_inverse = |f: f64| {
        if f > D {
            f * f * f
        } else {
            3.0 * D * D * (f - 4.0 / 29.0)
        }
    };
    let fy = (lab[0] + 16.0) / 116.0;
    let fx = fy + lab[1] / 500.0;
    let fz = fy - lab[2] / 200.0;
    [
        white[0] * f_inverse(fx),
        white[1] * f_inverse(fy),
        white[2] * f_inverse(fz),
    ]
}

/// `xyz` seen under `from` white, adapted to `to` white (linear Bradford).
fn adapt(xyz: [f64; 3], from: [f64; 3], to: [f64; 3]) -> [f64; 3] {
    let (source, target) = (apply(&BRADFORD, from), apply(&BRADFORD, to));
    let cone = apply(&BRADFORD, xyz);
    let scaled: [f64; 3] = std::array::from_fn(|c| {
        if source[c] != 0.0 {
            cone[c] * target[c] / source[c]
        } else {
            cone[c]
        }
    });
    apply(&BRADFORD_INVERSE, scaled)
}

/// The sRGB transfer function (gamma encoding) of a linear value in [0, 1].
fn encode(linear: f64) -> f64 {
    if linear <= 0.003_130_8 {
        12.92 * linear
    } else {
        1.055 * linear.powf(1.0 / 2.4) - 0.055
    }
}

/// The swatch of `lab`, given relative to `white` (Y = 100); channels outside the gamut
/// are clipped and the swatch says so. Non-finite input gives black, out of gamut.
pub fn swatch(lab: [f64; 3], white: [f64; 3]) -> Swatch {
    let xyz = adapt(xyz_from_lab(lab, white), white, SRGB_WHITE);
    let linear = apply(&XYZ_TO_LINEAR_SRGB, xyz.map(|v| v / 100.0));
    let finite = linear.iter().all(|v| v.is_finite());
    let in_gamut = finite
        && linear
            .iter()
            .all(|&v| (-GAMUT_TOLERANCE..=1.0 + GAMUT_TOLERANCE).contains(&v));
    let rgb = linear.map(|v| {
        let v = if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        };
        (encode(v) * 255.0).round() as u8
    });
    Swatch { rgb, in_gamut }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::color::lab::lab_from_xyz;

    /// The Lab (relative to `white`) of 8-bit sRGB `rgb`: the inverse of [`swatch`] inside
    /// the gamut.
    fn lab_of_srgb(rgb: [u8; 3], white: [f64; 3]) -> [f64; 3] {
        let decode = |c: u8| {
            let v = f64::from(c) / 255.0;
            if v <= 0.040_45 {
                v / 12.92
            } else {
                ((v + 0.055) / 1.055).powf(2.4)
            }
        };
        let linear = rgb.map(decode);
        // Linear sRGB → XYZ (IEC 61966-2-1), Y = 100.
        const LINEAR_SRGB_TO_XYZ: [[f64; 3]; 3] = [
            [0.4124, 0.3576, 0.1805],
            [0.2126, 0.7152, 0.0722],
            [0.0193, 0.1192, 0.9505],
        ];
        let xyz = apply(&LINEAR_SRGB_TO_XYZ, linear).map(|v| v * 100.0);
        lab_from_xyz(adapt(xyz, SRGB_WHITE, white), white)
    }

    /// D50 (ICC PCS white), Y = 100.
    const D50: [f64; 3] = [96.422, 100.0, 82.521];

    #[test]
    fn white_black_and_grey_are_neutral() {
        assert_eq!(swatch([100.0, 0.0, 0.0], SRGB_WHITE).rgb, [255, 255, 255]);
        assert_eq!(swatch([0.0, 0.0, 0.0], SRGB_WHITE).rgb, [0, 0, 0]);
        let grey = swatch([50.0, 0.0, 0.0], SRGB_WHITE);
        assert!(grey.in_gamut);
        // L* = 50 is Y = 18.42 %, sRGB 119.
        assert_eq!(grey.rgb, [119, 119, 119]);
        // A neutral relative to D50 stays neutral once adapted.
        let d50_grey = swatch([50.0, 0.0, 0.0], D50);
        assert!(
            d50_grey.rgb.iter().all(|&c| c.abs_diff(119) <= 1),
            "{d50_grey:?}"
        );
    }

    #[test]
    fn primaries_round_trip_and_saturated_colours_are_flagged() {
        for rgb in [[255, 0, 0], [0, 255, 0], [0, 0, 255], [200, 120, 40]] {
            for white in [SRGB_WHITE, D50] {
                let lab = lab_of_srgb(rgb, white);
                let back = swatch(lab, white);
                assert!(
                    back.rgb.iter().zip(rgb).all(|(a, b)| a.abs_diff(b) <= 1),
                    "{rgb:?} → {lab:?} → {back:?}"
                );
            }
        }
        // A green more saturated than sRGB's primary: outside the gamut, clipped.
        let beyond = swatch([60.0, -120.0, 60.0], SRGB_WHITE);
        assert!(!beyond.in_gamut);
        assert_eq!(swatch([f64::NAN, 0.0, 0.0], SRGB_WHITE).rgb, [0, 0, 0]);
        assert!(!swatch([f64::NAN, 0.0, 0.0], SRGB_WHITE).in_gamut);
        assert_eq!(swatch([100.0, 0.0, 0.0], SRGB_WHITE).hex(), "#ffffff");
    }
}
