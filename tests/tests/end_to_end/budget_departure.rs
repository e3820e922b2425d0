//! The budget's departure names only what the residuals identify (docs/ARCHITECTURE.md,
//! "Uncertainty budget"): a model that misses the data is misfit, never a setup error.
//! On the README's own scan (gold, an exact setup, sensor binned 4×4), a Ward fit of its
//! Cook–Torrance lobe leaves residuals well above the noise: no source may be reported
//! beyond 2 standard uncertainties from the stated setup, and the misfit line carries
//! what the residuals show; the Cook–Torrance fit, which describes the data, reports no
//! departure at all and its residuals are at the noise.

use gonio_processing::brdf::Model;
use gonio_processing::fit::budget::budget;
use gonio_processing::fit::{fit, FitOptions};
use gonio_processing::samples::read_csv;
use gonio_tests::{gonio, temp_dir};

#[test]
fn a_ward_fit_of_an_exact_cook_torrance_scan_reports_misfit_not_a_departure() {
    let dir = temp_dir("budget-departure");
    let s = |p: &std::path::Path| p.to_str().unwrap().to_owned();
    let scan = dir.join("scan");
    gonio(&[
        "simulate",
        "--scene",
        "gold",
        "--binning",
        "4",
        "--out",
        &s(&scan),
    ]);
    let csv = dir.join("samples.csv");
    gonio(&["extract", &s(&scan), "--out", &s(&csv)]);
    let samples = read_csv(&csv).unwrap();
    std::fs::remove_dir_all(&dir).ok();

    let ward = fit(&samples, &FitOptions::new(Model::Ward)).unwrap();
    let b = budget(&samples, &ward).unwrap();
    assert!(b.residual_to_noise > 2.0, "{}", b.residual_to_noise);
    for d in &b.departure {
        assert!(d.z.abs() <= 2.0, "{} {:?}: {} u", d.source, d.theta_l, d.z);
    }
    for (name, p) in b.named() {
        let line = |source: &str| {
            p.contributions
                .iter()
                .find(|c| c.source == source)
                .unwrap()
                .u
        };
        assert!(line("misfit") > line("noise"), "{name}: {p:?}");
    }

    let cook_torrance = fit(&samples, &FitOptions::new(Model::CookTorrance)).unwrap();
    let b = budget(&samples, &cook_torrance).unwrap();
    assert!(b.residual_to_noise < 1.25, "{}", b.residual_to_noise);
    assert!(b.departure.is_empty(), "{:?}", b.departure);
}
