//! Cook–Torrance and isotropic Ward reflection models in the paper's form (eq. 6–9, F = 1),
//! and the goniochromatic Cook–Torrance–Fresnel model (Cook–Torrance with a fitted colour
//! Fresnel term, `docs/ARCHITECTURE.md`, "Quantities and models"), as radiance factor β
//! per camera channel, at in-plane angles (θi, θr) in degrees or at the 3D cosines of a
//! surface point ([`Cosines`]).
//!
//! All models are linear in their coefficients: β_c = Kd_c·a + s(m_c)·F_c(w), with a
//! diffuse basis `a` (1 for the Cook–Torrance forms, 1/π for Ward), a specular lobe
//! s(m) = g · exp(−tan²α/m²) / m², where g depends on the angles only:
//! - Cook–Torrance (both forms): g = G / (π cos⁴α cos θi cos θr),
//!   G = min(1, 2(n·h)(n·v)/(v·h), 2(n·h)(n·l)/(v·h));
//! - Ward: g = 1 / (4π sqrt(cos θi cos θr));
//!
//! and the specular colour F_c(w) = Ks_c·(1 − w) + Ks_90_c·w: w = 0 for Cook–Torrance and
//! Ward (F_c = Ks_c); for Cook–Torrance–Fresnel w = min(1, 1 − l·v) = min(1, 2 sin²θd),
//! θd the incidence on the facet (cos θd = v·h), so the colour moves linearly in the
//! cosine of the angle γ = 2θd between light and camera from Ks at γ = 0 to Ks_90 at
//! γ = 90° (θd = 45°), and stays at Ks_90 beyond.
//!
//! Numerics: tan²α = (1 − c²)/c² with c = cos α clamped to [1e−12, 1]; the lobe is exactly 0
//! where tan²α/m² exceeds the exponent at which exp(−x) leaves the normal f64 range;
//! a direction at or past grazing (cos θ < 1e−9, or a non-finite angle) makes β exactly 0
//! (no light arrives, or the point is not seen); m is clamped to [1e−6, 1e6].
#![doc = include_str!("brdf.md")]

use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::color::WHITE_BETA_G;

/// Cosines below this count as at or past grazing.
const COS_GRAZING: f64 = 1e-9;
/// Smallest cos α used in tan²α.
const COS_ALPHA_MIN: f64 = 1e-12;
/// exp(−x) is below the smallest normal f64 for x above this: the lobe is 0 there.
pub(crate) const EXP_UNDERFLOW: f64 = 708.0;
/// Range to which the roughness m is clamped.
pub const M_MIN: f64 = 1e-6;
/// Upper end of the roughness clamp, see [`M_MIN`].
pub const M_MAX: f64 = 1e6;

/// A reflection model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Model {
    /// Cook–Torrance with Beckmann distribution, F = 1 (paper eq. 6, 8).
    CookTorrance,
    /// Isotropic Ward (paper eq. 7, 9).
    Ward,
    /// Cook–Torrance whose specular colour varies with the facet incidence θd:
    /// F_c = Ks_c·cos 2θd + Ks_90_c·(1 − cos 2θd) up to θd = 45°, Ks_90_c beyond
    /// (goniochromatic samples).
    CookTorranceFresnel,
}

/// Whether the three channels share one roughness m or have one each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Roughness {
    /// One m for R, G and B (paper eq. 6, 7).
    #[default]
    Shared,
    /// One m per channel (paper eq. 8, 9).
    PerChannel,
}

/// Model coefficients in the camera-RGB β domain; `m` per channel (all equal when shared).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Params {
    pub kd: [f64; 3],
    pub ks: [f64; 3],
    pub m: [f64; 3],
}

impl Params {
    /// Parameters with one roughness for all channels.
    pub fn shared(kd: [f64; 3], ks: [f64; 3], m: f64) -> Self {
        Params { kd, ks, m: [m; 3] }
    }
}

/// The four cosines a reflection model needs at one surface point: n·l (cos θi), n·v
/// (cos θr), n·h (cos α) and v·h, with l, v the unit directions to the light and the
/// camera and h = (l + v)/|l + v| the half vector. In the plane of the light they follow
/// from the signed in-plane angles ([`Cosines::in_plane`]); off that plane (the strip's
/// rows above and below it) from the true 3D directions ([`Cosines::from_directions`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Cosines {
    pub n_dot_l: f64,
    pub n_dot_v: f64,
    pub n_dot_h: f64,
    pub v_dot_h: f64,
}

impl Cosines {
    /// In-plane cosines at signed (θi, θr) in degrees (specular at θr = θi):
    /// n·h = cos((θi − θr)/2), v·h = cos((θi + θr)/2).
    pub fn in_plane(theta_i_deg: f64, theta_r_deg: f64) -> Self {
        let theta_i = theta_i_deg.to_radians();
        let theta_r = theta_r_deg.to_radians();
        Cosines {
            n_dot_l: theta_i.cos(),
            n_dot_v: theta_r.cos(),
            n_dot_h: ((theta_i - theta_r) / 2.0).cos(),
            v_dot_h: ((theta_i + theta_r) / 2.0).cos(),
        }
    }

    /// Cosines from the unit normal `n` and the (not necessarily unit) vectors from the
    /// surface point to the light and to the camera. A zero vector, or light and camera in
    /// exactly opposite directions, gives cosines that mark the point as grazing (0).
    pub fn from_directions(n: [f64; 3], to_light: [f64; 3], to_camera: [f64; 3]) -> Self {
        let unit = |v: [f64; 3]| {
            let len = dot(v, v).sqrt();
            if len > 0.0 && len.is_finite() {
                v.map(|x| x / len)
            } else {
                [0.0; 3]
            }
        };
        let l = unit(to_light);
        let v = unit(to_camera);
        let h = unit([l[0] + v[0], l[1] + v[1], l[2] + v[2]]);
        Cosines {
            n_dot_l: dot(n, l),
            n_dot_v: dot(n, v),
            n_dot_h: dot(n, h),
            v_dot_h: dot(v, h),
        }
    }

    /// The cosines in CSV column order (`n_dot_l,n_dot_v,n_dot_h,v_dot_h`).
    pub fn to_array(self) -> [f64; 4] {
        [self.n_dot_l, self.n_dot_v, self.n_dot_h, self.v_dot_h]
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The model at one (θi, θr), as the basis of its linear form
/// β_c = Kd_c·diffuse + specular(m_c)·(Ks_c·(1 − w) + Ks_90_c·w), w = [`Basis::shift_weight`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Basis {
    /// Diffuse basis a: 1 (Cook–Torrance forms) or 1/π (Ward); 0 at or past grazing.
    pub diffuse: f64,
    /// tan²α of the half vector.
    tan2_alpha: f64,
    /// Angular factor g of the lobe; 0 at or past grazing.
    gain: f64,
    /// Weight w ∈ [0, 1] of the specular colour at 90°, see [`Basis::shift_weight`].
    shift_weight: f64,
}

/// Parameters prepared for evaluating a model at many points: each channel's roughness
/// clamped and turned into 1/m² once, and the specular colour's change Ks_90 − Ks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prepared {
    kd: [f64; 3],
    ks: [f64; 3],
    /// Ks_90 − Ks per channel.
    shift: [f64; 3],
    /// 1/m² per channel, m clamped as [`Basis::specular_and_slope`] clamps it.
    inv_m2: [f64; 3],
    /// Whether the three channels have the same m (one lobe evaluation per point).
    shared: bool,
    /// Whether m is shared and Ks_90 = Ks (as in the loss of Cook–Torrance and Ward).
    plain: bool,
}

impl Prepared {
    /// Whether one lobe with one specular colour serves every channel (m shared,
    /// Ks_90 = Ks, Ks finite): the model of Cook–Torrance's and Ward's loss.
    pub(crate) fn is_plain(&self) -> bool {
        self.plain
    }

    /// `params` with the specular colour at 90° `ks_90`.
    pub fn new(params: &Params, ks_90: &[f64; 3]) -> Self {
        let [m0, m1, m2] = params.m;
        let shift = std::array::from_fn(|c| ks_90[c] - params.ks[c]);
        let shared = m1 == m0 && m2 == m0;
        Prepared {
            kd: params.kd,
            ks: params.ks,
            shift,
            inv_m2: params.m.map(inverse_square),
            shared,
            // Ks + w·0 is Ks exactly for a finite Ks.
            plain: shared && shift == [0.0; 3] && params.ks.iter().all(|k| k.is_finite()),
        }
    }
}

/// 1/m² of the roughness m clamped to [[`M_MIN`], [`M_MAX`]] (NaN taken as [`M_MAX`]).
#[inline]
pub(crate) fn inverse_square(m: f64) -> f64 {
    let m = if m.is_nan() {
        M_MAX
    } else {
        m.clamp(M_MIN, M_MAX)
    };
    1.0 / (m * m)
}

impl Basis {
    /// Specular basis s(m) = g·exp(−tan²α/m²)/m², finite and ≥ 0.
    #[inline]
    pub fn specular(&self, m: f64) -> f64 {
        self.lobe(inverse_square(m)).0
    }

    /// s(m) and its derivative with respect to ln m, ∂s/∂ln m = 2·s·(tan²α/m² − 1), both
    /// finite (m clamped to [[`M_MIN`], [`M_MAX`]], NaN taken as [`M_MAX`]).
    #[inline]
    pub fn specular_and_slope(&self, m: f64) -> (f64, f64) {
        let (s, x) = self.lobe(inverse_square(m));
        if s == 0.0 {
            (0.0, 0.0)
        } else {
            (s, 2.0 * s * (x - 1.0))
        }
    }

    /// The lobe's terms at this point: tan²α of the half vector and the angular factor g
    /// (s = g·exp(−tan²α/m²)/m²), for evaluating it over many points at once.
    pub(crate) fn lobe_terms(&self) -> (f64, f64) {
        (self.tan2_alpha, self.gain)
    }

    /// s and x = tan²α/m² at 1/m² = `inv_m2`; s is 0 at or past grazing and where
    /// exp(−x) would leave the normal range.
    #[inline]
    fn lobe(&self, inv_m2: f64) -> (f64, f64) {
        let x = self.tan2_alpha * inv_m2;
        if self.gain == 0.0 || x > EXP_UNDERFLOW {
            (0.0, x)
        } else {
            (self.gain * (-x).exp() * inv_m2, x)
        }
    }

    /// Weight w ∈ [0, 1] of the specular colour at 90° in F_c = Ks_c·(1 − w) + Ks_90_c·w:
    /// min(1, 1 − l·v) = min(1, 2(1 − (v·h)²)) for Cook–Torrance–Fresnel, 0 for the
    /// models whose specular colour is constant.
    #[inline]
    pub fn shift_weight(&self) -> f64 {
        self.shift_weight
    }

    /// β per channel for the given parameters, with a constant specular colour
    /// (Ks_90 = Ks: Cook–Torrance–Fresnel then equals Cook–Torrance).
    pub fn evaluate(&self, params: &Params) -> [f64; 3] {
        self.evaluate_fresnel(params, &params.ks)
    }

    /// β per channel with the specular colour Ks·(1 − w) + `ks_90`·w.
    pub fn evaluate_fresnel(&self, params: &Params, ks_90: &[f64; 3]) -> [f64; 3] {
        self.evaluate_prepared(&Prepared::new(params, ks_90))
    }

    /// β per channel of parameters prepared once for many points.
    #[inline]
    pub fn evaluate_prepared(&self, p: &Prepared) -> [f64; 3] {
        if p.plain {
            // One lobe, and a specular colour Ks + w·0 = Ks.
            let s = self.lobe(p.inv_m2[0]).0;
            return std::array::from_fn(|c| p.kd[c] * self.diffuse + p.ks[c] * s);
        }
        let s0 = self.lobe(p.inv_m2[0]).0;
        // A shared roughness needs one lobe evaluation for all channels.
        let s = if p.shared {
            [s0; 3]
        } else {
            [s0, self.lobe(p.inv_m2[1]).0, self.lobe(p.inv_m2[2]).0]
        };
        let w = self.shift_weight;
        std::array::from_fn(|c| {
            let colour = p.ks[c] + w * p.shift[c];
            p.kd[c] * self.diffuse + colour * s[c]
        })
    }
}

impl Model {
    /// Name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Model::CookTorrance => "cook-torrance",
            Model::Ward => "ward",
            Model::CookTorranceFresnel => "cook-torrance-fresnel",
        }
    }

    /// The diffuse term's weight a in β_d = Kd·a: 1 for Cook–Torrance (eq. 6), 1/π for
    /// Ward (eq. 7). The papers' two models put Kd on scales π apart.
    pub fn diffuse_weight(self) -> f64 {
        match self {
            Model::CookTorrance | Model::CookTorranceFresnel => 1.0,
            Model::Ward => 1.0 / PI,
        }
    }

    /// The diffuse albedo ρd per channel of a fit with diffuse coefficients `kd`: the
    /// diffuse radiance factor β_d = Kd·a over a perfect white's β_G = 100, so that both
    /// models report it on one scale (docs/ARCHITECTURE.md, "Quantities and models").
    pub fn diffuse_albedo(self, kd: [f64; 3]) -> [f64; 3] {
        kd.map(|k| k * self.diffuse_weight() / WHITE_BETA_G)
    }

    /// Every model, in the order figures and tables list them.
    pub const ALL: [Model; 3] = [Model::CookTorrance, Model::Ward, Model::CookTorranceFresnel];

    /// Whether the model has a specular colour at 90° (Ks_90) besides Ks.
    pub fn has_fresnel_colour(self) -> bool {
        self == Model::CookTorranceFresnel
    }

    /// The linear basis of the model at in-plane (θi, θr) in degrees.
    pub fn basis(self, theta_i_deg: f64, theta_r_deg: f64) -> Basis {
        self.basis_at(&Cosines::in_plane(theta_i_deg, theta_r_deg))
    }

    /// The linear basis of the model at one surface point, from its 3D cosines.
    pub fn basis_at(self, cosines: &Cosines) -> Basis {
        let Cosines {
            n_dot_l: cos_i,
            n_dot_v: cos_r,
            n_dot_h,
            v_dot_h,
        } = *cosines;
        // `!(x >= y)` also masks NaN.
        if !(cos_i >= COS_GRAZING && cos_r >= COS_GRAZING) {
            return Basis {
                diffuse: 0.0,
                tan2_alpha: 0.0,
                gain: 0.0,
                shift_weight: 0.0,
            };
        }
        let cos_alpha = if n_dot_h.is_nan() {
            COS_ALPHA_MIN
        } else {
            n_dot_h.clamp(COS_ALPHA_MIN, 1.0)
        };
        let cos_alpha2 = cos_alpha * cos_alpha;
        let tan2_alpha = ((1.0 - cos_alpha2) / cos_alpha2).max(0.0);
        // v·h > 0 for directions before grazing.
        let v_dot_h = if v_dot_h.is_nan() {
            COS_GRAZING
        } else {
            v_dot_h.max(COS_GRAZING)
        };
        match self {
            Model::CookTorrance | Model::CookTorranceFresnel => {
                let masking = 2.0 * cos_alpha * cos_r / v_dot_h;
                let shadowing = 2.0 * cos_alpha * cos_i / v_dot_h;
                let g = 1f64.min(masking).min(shadowing);
                Basis {
                    diffuse: self.diffuse_weight(),
                    tan2_alpha,
                    gain: g / (PI * cos_alpha2 * cos_alpha2 * cos_i * cos_r),
                    shift_weight: if self.has_fresnel_colour() {
                        (2.0 * (1.0 - v_dot_h * v_dot_h)).clamp(0.0, 1.0)
                    } else {
                        0.0
                    },
                }
            }
            Model::Ward => Basis {
                diffuse: self.diffuse_weight(),
                tan2_alpha,
                gain: 1.0 / (4.0 * PI * (cos_i * cos_r).sqrt()),
                shift_weight: 0.0,
            },
        }
    }

    /// β per channel (R, G, B) at in-plane (θi, θr) in degrees.
    pub fn evaluate(&self, params: &Params, theta_i_deg: f64, theta_r_deg: f64) -> [f64; 3] {
        self.basis(theta_i_deg, theta_r_deg).evaluate(params)
    }

    /// β per channel (R, G, B) at one surface point given by its 3D cosines.
    pub fn evaluate_at(&self, params: &Params, cosines: &Cosines) -> [f64; 3] {
        self.basis_at(cosines).evaluate(params)
    }
}

impl Roughness {
    /// Name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Roughness::Shared => "shared",
            Roughness::PerChannel => "per-channel",
        }
    }

    /// How many roughness values the model has: 1 or 3.
    pub fn count(self) -> usize {
        match self {
            Roughness::Shared => 1,
            Roughness::PerChannel => 3,
        }
    }
}

/// An unknown model or roughness name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} `{name}` (expected {expected})")]
pub struct UnknownName {
    pub what: &'static str,
    pub name: String,
    pub expected: &'static str,
}

impl FromStr for Model {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "cook-torrance" => Ok(Model::CookTorrance),
            "ward" => Ok(Model::Ward),
            "cook-torrance-fresnel" => Ok(Model::CookTorranceFresnel),
            _ => Err(UnknownName {
                what: "model",
                name: s.to_owned(),
                expected: "cook-torrance, ward or cook-torrance-fresnel",
            }),
        }
    }
}

impl FromStr for Roughness {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "shared" => Ok(Roughness::Shared),
            "per-channel" => Ok(Roughness::PerChannel),
            _ => Err(UnknownName {
                what: "roughness",
                name: s.to_owned(),
                expected: "shared or per-channel",
            }),
        }
    }
}

impl fmt::Display for Model {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl fmt::Display for Roughness {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
