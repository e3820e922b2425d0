//! Reflection models in vector form (half vector, n·h, v·h from 3D directions),
//! independent of processing's angle-form code. β is the radiance factor in the
//! camera-RGB domain (a perfect white gives β_G = 100).

use crate::scene::material::{table_at, Material};
use crate::scene::spectral::{CameraDomain, Spectrum};

/// Cosines below this are clamped, so grazing geometry stays finite.
const MIN_COS: f64 = 1e-4;

/// The local geometry at one surface point. `cos_i` = n·l, `cos_r` = n·v, `l_dot_v` =
/// l·v with unit vectors; `theta_i_deg`/`theta_r_deg` the signed in-plane angles
/// (specular at θr = θi) of the directions projected on the horizontal plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geom {
    pub cos_i: f64,
    pub cos_r: f64,
    /// n·h with h the unit half vector.
    pub n_h: f64,
    /// v·h (= l·h).
    pub v_h: f64,
    pub l_dot_v: f64,
    pub theta_i_deg: f64,
    pub theta_r_deg: f64,
}

impl Geom {
    /// From the cosines of unit vectors n·l, n·v, l·v (h = (l + v)/|l + v|).
    pub fn new(cos_i: f64, cos_r: f64, l_dot_v: f64, theta_i_deg: f64, theta_r_deg: f64) -> Self {
        let h_len = (2.0 + 2.0 * l_dot_v).max(1e-12).sqrt();
        Self {
            cos_i,
            cos_r,
            n_h: ((cos_i + cos_r) / h_len).clamp(0.0, 1.0),
            v_h: ((1.0 + l_dot_v) / h_len).clamp(MIN_COS, 1.0),
            l_dot_v,
            theta_i_deg,
            theta_r_deg,
        }
    }

    /// In-plane geometry of a distant light and viewer at signed angles (degrees).
    pub fn in_plane(theta_i_deg: f64, theta_r_deg: f64) -> Self {
        let (ti, tr) = (theta_i_deg.to_radians(), theta_r_deg.to_radians());
        // n = (1, 0), l = (cos θi, sin θi), v = (cos θr, −sin θr).
        let l_dot_v = ti.cos() * tr.cos() - ti.sin() * tr.sin();
        Self::new(ti.cos(), tr.cos(), l_dot_v, theta_i_deg, theta_r_deg)
    }
}

/// Beckmann distribution D = exp(−tan²α/m²)/(m² cos⁴α), cos α = n·h, tan²α from the
/// cosine.
fn beckmann(n_h: f64, m: f64) -> f64 {
    let c = n_h.max(MIN_COS);
    let c2 = c * c;
    let tan2 = (1.0 - c2) / c2;
    (-tan2 / (m * m)).exp() / (m * m * c2 * c2)
}

/// Geometric attenuation G = min(1, 2(n·h)(n·v)/(v·h), 2(n·h)(n·l)/(v·h)).
fn masking(g: &Geom) -> f64 {
    let k = 2.0 * g.n_h / g.v_h;
    (k * g.cos_r).min(k * g.cos_i).min(1.0)
}

/// The Cook–Torrance specular factor D·G/(π (n·l)(n·v)) with F = 1.
pub fn cook_torrance_lobe(g: &Geom, m: f64) -> f64 {
    beckmann(g.n_h, m) * masking(g)
        / (std::f64::consts::PI * g.cos_i.max(MIN_COS) * g.cos_r.max(MIN_COS))
}

/// The isotropic Ward lobe exp(−tan²α/m²)/(4π m² √(cosθi cosθr)).
fn ward_lobe(g: &Geom, m: f64) -> f64 {
    let c = g.n_h.max(MIN_COS);
    let tan2 = (1.0 - c * c) / (c * c);
    (-tan2 / (m * m)).exp()
        / (4.0 * std::f64::consts::PI * m * m * (g.cos_i * g.cos_r).max(MIN_COS).sqrt())
}

/// Retro-reflection lobe exp(−tan²(γ/2)/w²), cos γ = l·v, `w2` = w²; tan²(γ/2) from the
/// cosine as (1 − c)/(1 + c).
pub fn retro_lobe(l_dot_v: f64, w2: f64) -> f64 {
    let c = l_dot_v.clamp(-1.0 + 1e-9, 1.0);
    (-((1.0 - c) / (1.0 + c)) / w2).exp()
}

/// A material's β at a surface point (its preparation: `scene::material`).
impl Material {
    /// β per camera channel at `g`.
    pub fn beta(&self, g: &Geom) -> [f64; 3] {
        match self {
            Material::Lambertian { kd } => *kd,
            Material::CookTorrance { kd, ks, m } => {
                std::array::from_fn(|c| ks[c] * cook_torrance_lobe(g, m[c]) + kd[c])
            }
            Material::Ward { kd, ks, m } => {
                std::array::from_fn(|c| kd[c] / std::f64::consts::PI + ks[c] * ward_lobe(g, m[c]))
            }
            Material::SpectralLobe { kd, m, table, .. } => {
                let lobe = cook_torrance_lobe(g, *m);
                let colour = table_at(table, g.v_h);
                std::array::from_fn(|c| lobe * colour[c] + kd[c])
            }
            Material::Measured(table) => table.rgb_at(g.theta_i_deg, g.theta_r_deg),
            Material::Rgl(bsdf) => bsdf.beta(g.cos_i, g.cos_r, g.l_dot_v),
        }
    }

    /// Spectral radiance factor at `g`: exact for spectral samples; for camera-RGB
    /// models the smooth spectrum of [`CameraDomain::spectrum_from_rgb`], whose
    /// camera RGB equals [`Material::beta`].
    pub fn beta_spectrum(&self, g: &Geom, domain: &CameraDomain) -> Spectrum {
        match self {
            Material::SpectralLobe {
                kd_spectrum,
                ks,
                m,
                reflector,
                ..
            } => {
                let lobe = ks * cook_torrance_lobe(g, *m);
                let reflectance = reflector.spectrum(g.v_h);
                std::array::from_fn(|i| lobe * reflectance[i] + kd_spectrum[i])
            }
            Material::Measured(table) => table.spectrum_at(g.theta_i_deg, g.theta_r_deg),
            Material::Rgl(bsdf) => bsdf.beta_spectrum(g.cos_i, g.cos_r, g.l_dot_v),
            _ => domain.spectrum_from_rgb(self.beta(g)),
        }
    }
}
