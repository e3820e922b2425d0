//! Export of fits: the Mitsuba 3 parameters evaluated with the formulas of Mitsuba 3's
//! documentation reproduce the fitted reflectance of the G channel, and the table holds
//! the fit's predictions.
//!
//! Mitsuba 3 (documentation of `diffuse`, `roughconductor`, `blendbsdf` and
//! `MicrofacetDistribution`): diffuse f = ρ/π; rough conductor
//! f = F·S·D(h)·G(l, v)/(4 cos θi cos θr) with the Beckmann D(h) = exp(−tan²θh/α²)/(π α²
//! cos⁴θh), Smith's separable G = G1(l)·G1(v) with the rational G1 of Walter et al. 2007
//! (a = 1/(α tan θ): 1 for a ≥ 1.6, else (3.535a + 2.181a²)/(1 + 2.276a + 2.577a²)), and
//! F = 1 for `material = "none"`; blend f = (1 − w)·f₀ + w·f₁.

use std::f64::consts::PI;

use gonio_processing::brdf::{Model, Roughness};
use gonio_processing::color::CameraModel;
use gonio_processing::export::{mitsuba_bsdf, mitsuba_xml, table, table_csv, ExportError};
use gonio_processing::fit::{FitMethod, FitResult, FittedRoughness};

fn fit_of(model: Model, kd: [f64; 3], ks: [f64; 3], m: f64) -> FitResult {
    FitResult {
        model,
        roughness: Roughness::Shared,
        kd,
        ks,
        ks_90: None,
        m: FittedRoughness::Shared([m]),
        rho_d: Some(model.diffuse_albedo(kd)),
        loss: 0.0,
        err_p: [0.0; 3],
        method: FitMethod::Robust,
        evaluations: 1,
        seconds: 0.0,
        stderr: None,
        ci95: None,
        correlation: None,
        colour_shift: None,
        global_minimum: None,
        selection: None,
        budget: None,
        table: None,
    }
}

/// In-plane unit directions of signed θ (degrees) in the x–z plane, normal +z; the
/// light at θi, the camera at −θr (specular at θr = θi).
fn directions(theta_i: f64, theta_r: f64) -> ([f64; 3], [f64; 3]) {
    let (ti, tr) = (theta_i.to_radians(), theta_r.to_radians());
    ([ti.sin(), 0.0, ti.cos()], [-tr.sin(), 0.0, tr.cos()])
}

fn smith_g1(cos: f64, alpha: f64) -> f64 {
    let tan = (1.0 - cos * cos).sqrt() / cos;
    let a = 1.0 / (alpha * tan);
    if a >= 1.6 {
        1.0
    } else {
        (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    }
}

/// Mitsuba 3's BSDF value (without the cosine factor) for the written parameters, one
/// channel, with its Smith G.
fn mitsuba_f(diffuse: f64, specular: f64, alpha: f64, theta_i: f64, theta_r: f64) -> (f64, f64) {
    let (l, v) = directions(theta_i, theta_r);
    let h = [l[0] + v[0], 0.0, l[2] + v[2]];
    let len = (h[0] * h[0] + h[2] * h[2]).sqrt();
    let cos_h = h[2] / len;
    let tan2 = (1.0 - cos_h * cos_h) / (cos_h * cos_h);
    let d = (-tan2 / (alpha * alpha)).exp() / (PI * alpha * alpha * cos_h.powi(4));
    let g = smith_g1(l[2], alpha) * smith_g1(v[2], alpha);
    let f_diffuse = diffuse / PI;
    let f_conductor = specular * d * g / (4.0 * l[2] * v[2]);
    (0.5 * f_diffuse + 0.5 * f_conductor, g)
}

/// The paper's Cook–Torrance masking G at the same directions.
fn v_cavity_g(theta_i: f64, theta_r: f64) -> f64 {
    let (l, v) = directions(theta_i, theta_r);
    let h = [l[0] + v[0], 0.0, l[2] + v[2]];
    let len = (h[0] * h[0] + h[2] * h[2]).sqrt();
    let (n_h, v_h) = (h[2] / len, (v[0] * h[0] + v[2] * h[2]) / len);
    1f64.min(2.0 * n_h * v[2] / v_h).min(2.0 * n_h * l[2] / v_h)
}

#[test]
fn mitsuba_parameters_reproduce_cook_torrance_in_g() {
    let white = CameraModel::builtin().white_rgb();
    assert!((white[1] - 100.0).abs() < 1e-9);
    let fit = fit_of(
        Model::CookTorrance,
        [9.0, 6.5, 2.0],
        [25.0, 20.0, 7.0],
        0.07,
    );
    let b = mitsuba_bsdf(&fit, white).unwrap();
    assert_eq!(b.alpha, 0.07);
    let (mut compared, mut total) = (0, 0);
    for ti in (-80..=80).step_by(4) {
        for tr in (-80..=80).step_by(4) {
            let (ti, tr) = (f64::from(ti) + 0.5, f64::from(tr) - 0.3);
            let (f, g_smith) = mitsuba_f(b.diffuse[1], b.specular[1], b.alpha, ti, tr);
            let ours = fit.predict(ti, tr)[1] / (PI * 100.0);
            total += 1;
            if g_smith == 1.0 && v_cavity_g(ti, tr) == 1.0 {
                assert!(
                    (f - ours).abs() <= 1e-9 * ours,
                    "({ti}, {tr}): {f} vs {ours}"
                );
                compared += 1;
            } else {
                // Only the masking differs: Smith's against the V-cavity's.
                let ratio = g_smith / v_cavity_g(ti, tr);
                let diffuse = fit.kd[1] / (PI * 100.0);
                let expected = diffuse + (ours - diffuse) * ratio;
                assert!(
                    (f - expected).abs() <= 1e-9 * ours.max(1e-12),
                    "({ti}, {tr})"
                );
            }
        }
    }
    assert!(
        2 * compared > total,
        "{compared} of {total} directions where both G are 1"
    );
    // R and B are relative to the white's R and B.
    let (f, _) = mitsuba_f(b.diffuse[0], b.specular[0], b.alpha, 20.0, 20.0);
    let ours = fit.predict(20.0, 20.0)[0] / (PI * white[0]);
    assert!((f - ours).abs() <= 1e-9 * ours);
}

#[test]
fn ward_maps_exactly_at_normal_incidence_and_within_one_over_cos_at_the_peak() {
    let white = CameraModel::builtin().white_rgb();
    let fit = fit_of(Model::Ward, [28.0, 20.0, 6.0], [25.0, 20.0, 7.0], 0.1);
    let b = mitsuba_bsdf(&fit, white).unwrap();
    for theta in [0.0f64, 20.0, 45.0] {
        let (f, _) = mitsuba_f(b.diffuse[1], b.specular[1], b.alpha, theta, theta);
        let ours = fit.predict(theta, theta)[1] / (PI * 100.0);
        let diffuse = fit.kd[1] / (PI * PI * 100.0);
        let ratio = (f - diffuse) / (ours - diffuse);
        let expected = 1.0 / theta.to_radians().cos();
        assert!(
            (ratio - expected).abs() < 1e-9,
            "θ {theta}: {ratio} vs {expected}"
        );
    }
    // Far from the lobe only the diffuse part is left: Ward's Kd/π as a radiance factor.
    let (f, _) = mitsuba_f(b.diffuse[1], b.specular[1], b.alpha, 60.0, -40.0);
    assert!((f - fit.kd[1] / (PI * PI * 100.0)).abs() < 1e-12);
}

#[test]
fn mitsuba_xml_names_its_values_and_refuses_the_fresnel_model() {
    let white = CameraModel::builtin().white_rgb();
    let fit = fit_of(
        Model::CookTorrance,
        [9.0, 6.5, 2.0],
        [25.0, 20.0, 7.0],
        0.07,
    );
    let xml = mitsuba_xml(&fit, white).unwrap();
    let b = mitsuba_bsdf(&fit, white).unwrap();
    assert!(xml.contains("<scene version=\"3.0.0\">"));
    assert!(xml.contains("<bsdf type=\"blendbsdf\" id=\"gonio-fit\">"));
    assert!(xml.contains("<string name=\"distribution\" value=\"beckmann\"/>"));
    assert!(xml.contains("<string name=\"material\" value=\"none\"/>"));
    assert!(xml.contains(&format!("{:.9}", b.specular[1])));
    assert!(xml.contains("value=\"0.070000000\""));
    let mut fresnel = fit.clone();
    fresnel.model = Model::CookTorranceFresnel;
    fresnel.ks_90 = Some([1.0, 2.0, 3.0]);
    assert!(matches!(
        mitsuba_xml(&fresnel, white),
        Err(ExportError::NoMitsubaForm { .. })
    ));
    assert!(matches!(
        mitsuba_bsdf(&fit, [100.0, 0.0, 50.0]),
        Err(ExportError::BadWhite(_))
    ));
}

#[test]
fn table_holds_the_predictions_on_the_grid() {
    let white = CameraModel::builtin().white_rgb();
    let mut fit = fit_of(
        Model::CookTorranceFresnel,
        [4.0, 12.0, 14.0],
        [54.0, 72.0, 29.0],
        0.12,
    );
    fit.ks_90 = Some([2.0, 60.0, 45.0]);
    let rows = table(&fit, white, 5.0, 80.0).unwrap();
    assert_eq!(rows.len(), 33 * 33);
    assert_eq!((rows[0].theta_i, rows[0].theta_r), (-80.0, -80.0));
    assert_eq!((rows[34].theta_i, rows[34].theta_r), (-75.0, -75.0));
    for r in &rows {
        assert_eq!(r.beta, fit.predict(r.theta_i, r.theta_r));
        for ((&brdf, &beta), &w) in r.brdf.iter().zip(&r.beta).zip(&white) {
            assert!((brdf - beta / (PI * w)).abs() <= 1e-15 * brdf.max(1.0));
        }
    }
    let csv = table_csv(&rows);
    assert!(csv.starts_with("theta_i,theta_r,beta_r,beta_g,beta_b,brdf_r,brdf_g,brdf_b\n"));
    assert_eq!(csv.lines().count(), 1 + rows.len());
    for (step, max) in [(0.0, 80.0), (1.0, 90.0), (f64::NAN, 80.0), (0.01, 80.0)] {
        assert!(
            matches!(table(&fit, white, step, max), Err(ExportError::BadGrid(_))),
            "{step} {max}"
        );
    }
}
