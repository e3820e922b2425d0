//! A goniospectrophotometer-style reference of a scene's sample: spectral radiance
//! factor at in-plane θi, θr from −80° to 80° in 5° steps, 390–730 nm in 10 nm steps.
//!
//! Distant light and detector (the instrument's geometry). The full 33 × 33 grid is
//! written, including the near-retro combinations θr ≈ −θi that a real instrument
//! cannot reach (its detector would block the source), so readers get a complete grid
//! for interpolation. The retro-reflection effect, when the scene names it, is part of
//! the sample and appears here.

use std::fmt::Write as _;

use super::brdf::{retro_lobe, Geom};
use crate::scene::spectral::{wavelength_nm, BANDS};
use crate::scene::Scene;

/// Angles of the grid, degrees.
pub fn grid_deg() -> impl Iterator<Item = f64> + Clone {
    (-16..=16).map(|k| 5.0 * f64::from(k))
}

/// The reference CSV text: header `theta_i,theta_r,390,…,730`, one row per (θi, θr).
pub fn reference_csv(scene: &Scene) -> String {
    let domain = scene.camera_domain();
    let retro = scene.effects().retro_reflection.as_ref().map(|r| {
        (
            domain.spectrum_from_rgb(r.kr),
            r.width_deg.to_radians().tan().powi(2),
        )
    });
    let mut out = String::from("theta_i,theta_r");
    for i in 0..BANDS {
        write!(out, ",{}", wavelength_nm(i)).expect("writing to a String");
    }
    out.push('\n');
    for theta_i in grid_deg() {
        for theta_r in grid_deg() {
            let g = Geom::in_plane(theta_i, theta_r);
            let mut beta = scene.material().beta_spectrum(&g, domain);
            if let Some((kr, w2)) = &retro {
                let lobe = retro_lobe(g.l_dot_v, *w2);
                for (b, k) in beta.iter_mut().zip(kr) {
                    *b += k * lobe;
                }
            }
            write!(out, "{theta_i},{theta_r}").expect("writing to a String");
            for b in beta {
                write!(out, ",{b:.6e}").expect("writing to a String");
            }
            out.push('\n');
        }
    }
    out
}
