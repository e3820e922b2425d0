//! The uncertainty budget (`fit::budget`) on synthetic scans whose sensitivities are known:
//! the white reference's line is the exact scale it must be, the law of propagation
//! agrees with the Monte Carlo where both apply, the noise and misfit lines split the
//! residuals' scatter as documented, and a setup's departure is found in the residuals
//! rather than counted as misfit.

use gonio_processing::brdf::{Model, Params};
use gonio_processing::fit::agreement::{compare, Holds};
use gonio_processing::fit::budget::{budget, monte_carlo, Draw};
use gonio_processing::fit::{fit, FitOptions, FitResult};
use gonio_processing::samples::{Sample, SampleUncertainty};
use gonio_processing::setup_uncertainty::Source;

/// A deterministic normal stream for the test's noise.
struct Noise(u64);

impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

const TRUTH_KD: [f64; 3] = [9.0, 6.5, 2.0];
const TRUTH_KS: [f64; 3] = [25.0, 20.0, 7.0];
const TRUTH_M: f64 = 0.12;
const U_WHITE: f64 = 0.005;
const U_ARM_DEG: f64 = 0.1;
const U_ANGLE_DEG: f64 = 0.02;
const NOISE: f64 = 0.01;

fn beta(theta_i: f64, theta_r: f64) -> [f64; 3] {
    let truth = Params::shared(TRUTH_KD, TRUTH_KS, TRUTH_M);
    Model::CookTorrance.evaluate(&truth, theta_i, theta_r)
}

/// Four θL of 120 in-plane points with 1 % noise, each carrying its noise and the
/// sensitivities of a white reference (the exact scale), an arm zero and an arm angle
/// (β at θi shifted by u, central difference) and a camera offset (a tilt of the θr
/// labels by 0.2 %).
fn scan(seed: u64) -> Vec<Sample> {
    let mut noise = Noise(seed);
    let mut out = Vec::new();
    for theta_l in [-20.0, -30.0, -40.0, -50.0] {
        for k in 0..120 {
            let theta_r = theta_l / 2.0 - 40.0 + 80.0 * f64::from(k) / 119.0;
            let theta_i = theta_l - theta_r;
            let clean = beta(theta_i, theta_r);
            let shifted = |d: f64| {
                let (p, m) = (beta(theta_i + d, theta_r), beta(theta_i - d, theta_r));
                std::array::from_fn(|c| (p[c] - m[c]) / 2.0)
            };
            let offset = {
                let d = 0.002 * theta_r;
                let (p, m) = (beta(theta_i, theta_r + d), beta(theta_i, theta_r - d));
                std::array::from_fn(|c| (p[c] - m[c]) / 2.0)
            };
            let mut sources = [[0.0; 3]; Source::COUNT];
            sources[0] = clean.map(|b| b * U_WHITE);
            sources[1] = offset;
            sources[5] = shifted(U_ARM_DEG);
            sources[6] = shifted(U_ANGLE_DEG);
            let rgb = clean.map(|b| b * (1.0 + NOISE * noise.normal()));
            let mut sample = Sample::in_plane(theta_l, theta_i, theta_r, rgb);
            sample.uncertainty = Some(SampleUncertainty {
                noise: rgb.map(|b| b * NOISE),
                sources,
            });
            out.push(sample);
        }
    }
    out
}

fn line(b: &gonio_processing::fit::budget::ParameterBudget, source: &str) -> f64 {
    b.contributions
        .iter()
        .find(|c| c.source == source)
        .unwrap_or_else(|| panic!("no {source} line"))
        .u
}

fn cook_torrance(samples: &[Sample]) -> FitResult {
    fit(samples, &FitOptions::new(Model::CookTorrance)).unwrap()
}

#[test]
fn the_white_reference_scales_the_colours_and_leaves_the_roughness() {
    let samples = scan(7);
    let result = cook_torrance(&samples);
    let b = budget(&samples, &result).unwrap();
    for c in 0..3 {
        let kd = &b.parameters.kd[c];
        let ks = &b.parameters.ks[c];
        let ratio = line(kd, "white_reflectance") / (result.kd[c] * U_WHITE);
        // Exact but for the refits' own precision (ln m to 1e-6).
        assert!((ratio - 1.0).abs() < 1e-2, "Kd {c}: {ratio}");
        let ratio = line(ks, "white_reflectance") / (result.ks[c] * U_WHITE);
        assert!((ratio - 1.0).abs() < 1e-2, "Ks {c}: {ratio}");
    }
    let m = line(&b.parameters.m[0], "white_reflectance");
    assert!(m < 1e-5 * result.m.per_channel()[0], "m: {m}");
    // Sources the samples do not move contribute nothing.
    for source in ["camera_distance", "light_distance", "cylinder_tilt"] {
        assert_eq!(line(&b.parameters.kd[1], source), 0.0);
    }
}

#[test]
fn the_combined_uncertainty_adds_the_lines_in_quadrature() {
    let samples = scan(11);
    let result = cook_torrance(&samples);
    let b = budget(&samples, &result).unwrap();
    for (name, p) in b.named() {
        let sum: f64 = p
            .contributions
            .iter()
            .map(|c| c.u * c.u)
            .sum::<f64>()
            .sqrt();
        assert!((p.combined / sum - 1.0).abs() < 1e-9, "{name}");
        assert!(
            (p.expanded - 2.0 * p.combined).abs() < 1e-12 * p.expanded,
            "{name}"
        );
        assert!(p.interval[0] < p.value && p.value < p.interval[1], "{name}");
        // Noise and misfit split the fit's own (HC1) standard uncertainty.
        assert!(line(p, "noise") > 0.0, "{name}");
    }
    // Noise as stated: the residuals scatter as the noise the samples carry, so the
    // misfit line is small against the noise line.
    assert!(
        (0.8..1.25).contains(&b.residual_to_noise),
        "{}",
        b.residual_to_noise
    );
    // The split is of the HC1 of the values with the setup's departure removed: on a
    // scan whose setup is as stated, that of the fit itself within a few per cent.
    let kd = &b.parameters.kd[0];
    let hc1 = result.stderr.as_ref().unwrap().kd[0];
    let split = (line(kd, "noise").powi(2) + line(kd, "misfit").powi(2)).sqrt();
    assert!((split / hc1 - 1.0).abs() < 0.05, "{split} against {hc1}");
}

#[test]
fn a_setup_departure_is_found_and_not_counted_as_misfit() {
    // The world's camera offset 1.5 u from the stated one: every value moved by −1.5 times
    // its offset column.
    let departure = 1.5;
    let stated = scan(19);
    let mut samples = stated.clone();
    for s in &mut samples {
        let u = s.uncertainty.as_ref().unwrap();
        let change = u.sources[1];
        s.rgb = std::array::from_fn(|c| s.rgb[c] - departure * change[c]);
    }
    let b = budget(&samples, &cook_torrance(&samples)).unwrap();
    let found = b
        .departure
        .iter()
        .find(|d| d.source == "camera_offset")
        .unwrap()
        .z;
    // Here a stretch of the θr labels (the offset) is much like θi shifted per θL (arm zero
    // and angles): the most probable departure shares it among them, the offset with its
    // sign.
    assert!(found > 0.3, "camera offset {found} u: {:?}", b.departure);
    // Every source reported is one the residuals identify: known to within half its
    // standard uncertainty, and significant.
    for d in &b.departure {
        let std = d.std.unwrap();
        assert!(std <= 0.5 && d.z.abs() >= 2.0 * std, "{d:?}");
    }
    // The white's departure cannot be seen in the residuals and is not sought.
    assert!(b.departure.iter().all(|d| d.source != "white_reflectance"));
    // What is left is the noise: the misfit line stays small, and the lines are those of
    // the scan whose setup is as stated.
    assert!(b.residual_to_noise < 1.25, "{}", b.residual_to_noise);
    let reference = budget(&stated, &cook_torrance(&stated)).unwrap();
    for ((name, p), (_, r)) in b.named().into_iter().zip(reference.named()) {
        let ratio = p.combined / r.combined;
        assert!((0.8..1.25).contains(&ratio), "{name}: {ratio}");
    }
}

#[test]
fn a_model_that_misses_the_data_gets_a_misfit_line() {
    // Ward fitted to Cook–Torrance data: the residuals exceed the stated noise.
    let samples = scan(13);
    let result = fit(&samples, &FitOptions::new(Model::Ward)).unwrap();
    let b = budget(&samples, &result).unwrap();
    assert!(b.residual_to_noise > 1.5, "{}", b.residual_to_noise);
    let ks = &b.parameters.ks[1];
    assert!(line(ks, "misfit") > line(ks, "noise"), "{ks:?}");
    // Misfit is misfit, not a setup error: no source is reported beyond 2 u.
    for d in &b.departure {
        assert!(d.z.abs() <= 2.0, "{d:?}");
    }
}

#[test]
fn the_law_of_propagation_agrees_with_the_monte_carlo() {
    let samples = scan(17);
    let result = cook_torrance(&samples);
    let b = budget(&samples, &result).unwrap();
    // Two refits a source, each at least one pass over the points.
    assert!(
        b.evaluations >= 2 * Source::COUNT as u64,
        "{}",
        b.evaluations
    );
    let mc = monte_carlo(&samples, &result, 400, Draw::Sources, 99).unwrap();
    for ((name, p), d) in b.named().into_iter().zip(mc.parameters.flat()) {
        let sources: f64 = p
            .contributions
            .iter()
            .filter(|c| c.source != "noise" && c.source != "misfit")
            .map(|c| c.u * c.u)
            .sum::<f64>()
            .sqrt();
        // 400 draws estimate a standard deviation within ±3.5 % (1σ).
        assert!(
            (d.std / sources - 1.0).abs() < 0.15,
            "{name}: Monte Carlo {} against {sources} by the law of propagation",
            d.std
        );
    }
}

#[test]
fn the_monte_carlo_and_the_budget_intervals_agree_where_both_apply() {
    // A scan whose setup is as stated, linear in every source over ±2 u: each end of the
    // Monte Carlo's 95 % interval within a tenth of the budget interval's width.
    let samples = scan(23);
    let result = cook_torrance(&samples);
    let mut b = budget(&samples, &result).unwrap();
    let mc = monte_carlo(&samples, &result, 400, Draw::All, 5).unwrap();
    assert_eq!(mc.draws, 400);
    assert!(mc.agreement.is_empty());
    // Each draw's refit passes over the points at least once.
    assert!(mc.evaluations >= 400, "{}", mc.evaluations);
    let agreement = compare(&b, &mc);
    assert_eq!(agreement.len(), b.named().len());
    for a in &agreement {
        assert_eq!(a.holds, Holds::Both, "{a:?}");
        assert!(a.end_offset <= 0.1, "{a:?}");
    }
    // Where they do not agree the comparison says which holds and why: here the budget's
    // interval of Kd_r made three times as wide.
    let kd = &mut b.parameters.kd[0];
    let half = kd.interval[1] - kd.value;
    kd.interval = [kd.value - 3.0 * half, kd.value + 3.0 * half];
    let a = &compare(&b, &mc)[0];
    assert_eq!(a.parameter, "kd_r");
    assert_ne!(a.holds, Holds::Both, "{a:?}");
    assert!(!a.reason.is_empty());
}
