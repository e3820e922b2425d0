//! Diffuse albedo ρd: Cook–Torrance's Kd and Ward's Kd are π apart for the same
//! surface (β_d = Kd vs Kd/π); ρd puts both on one scale, in the fit and its JSON.

use gonio_processing::brdf::Model;
use gonio_processing::fit::{fit, FitOptions};
use gonio_processing::samples::Sample;

/// A Lambertian surface of radiance factor `beta` (camera RGB), seen at three θL.
fn lambertian(beta: [f64; 3]) -> Vec<Sample> {
    let mut out = Vec::new();
    for theta_l in [-20.0, -35.0, -50.0] {
        for k in -60..=60 {
            let phi = f64::from(k);
            let (theta_i, theta_r) = (theta_l - phi, phi);
            if theta_i.abs() < 80.0 {
                out.push(Sample {
                    theta_l,
                    theta_i,
                    theta_r,
                    rgb: beta,
                    ..Sample::default()
                });
            }
        }
    }
    out
}

#[test]
fn both_models_report_the_same_albedo_for_the_same_surface() {
    let beta = [9.0, 6.5, 2.0];
    let samples = lambertian(beta);
    let ct = fit(&samples, &FitOptions::new(Model::CookTorrance)).unwrap();
    let ward = fit(&samples, &FitOptions::new(Model::Ward)).unwrap();
    let ct_rho = ct.rho_d.unwrap();
    let ward_rho = ward.rho_d.unwrap();
    for c in 0..3 {
        // The raw coefficients differ by π ...
        assert!((ct.kd[c] - beta[c]).abs() < 1e-6 * beta[c], "{:?}", ct.kd);
        let ratio = ward.kd[c] / ct.kd[c];
        assert!((ratio - std::f64::consts::PI).abs() < 1e-6, "{ratio}");
        // ... the albedo is one number: β_d over a perfect white's 100.
        assert!((ct_rho[c] - beta[c] / 100.0).abs() < 1e-8, "{ct_rho:?}");
        assert!((ward_rho[c] - ct_rho[c]).abs() < 1e-8, "{ward_rho:?}");
    }
    let json = serde_json::to_value(&ward).unwrap();
    let written: Vec<f64> = json["rho_d"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(written, ward_rho.to_vec());
    assert_eq!(json["kd"][1], serde_json::json!(ward.kd[1]));
}

#[test]
fn fit_files_without_albedo_still_read() {
    let samples = lambertian([5.0, 5.0, 5.0]);
    let ct = fit(&samples, &FitOptions::new(Model::CookTorrance)).unwrap();
    let mut json = serde_json::to_value(&ct).unwrap();
    json.as_object_mut().unwrap().remove("rho_d");
    let old: gonio_processing::fit::FitResult = serde_json::from_value(json).unwrap();
    assert_eq!(old.rho_d, None);
    assert_eq!(old.kd, ct.kd);
}
