//! Parameter uncertainty of fits: the 95 % intervals hold the truth 90–99 % of the time
//! over 200 noisy repeats of a small synthetic scan (two θL, a point per degree, noise
//! σ = 1 % of β + 0.05, so brighter points are noisier, as shot noise makes them), for
//! every model; the fit JSON carries the intervals in the design's shapes; the colour-shift
//! test of Cook–Torrance–Fresnel rejects a shift that is not there about as often as its
//! level says.

use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::fit::{chi2_3_survival, fit, FitOptions, FitResult};

use crate::common;
use crate::synthetic;
use common::Rng;
use synthetic::Noise;

const REPEATS: usize = 200;
const NOISE: Noise = Noise {
    relative: 0.01,
    absolute: 0.05,
};

/// Fits of `model` to `REPEATS` noisy scans of the truth (`ks_90` for Cook–Torrance–
/// Fresnel) at `theta_ls`.
fn repeats(
    model: Model,
    roughness: Roughness,
    truth: &Params,
    ks_90: &[f64; 3],
    theta_ls: &[f64],
) -> Vec<FitResult> {
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let mut options = FitOptions::new(model);
    options.roughness = roughness;
    (0..REPEATS)
        .map(|_| {
            let samples = synthetic::scan(model, truth, ks_90, theta_ls, 1.0, NOISE, &mut rng);
            fit(&samples, &options).unwrap()
        })
        .collect()
}

/// Fraction of the fits whose 95 % interval of each parameter holds the truth, named
/// `kd_r`, …, `m` (or `m_r`, …).
fn coverage(fits: &[FitResult], truth: &Params, ks_90: Option<&[f64; 3]>) -> Vec<(String, f64)> {
    let mut hits: Vec<(String, usize)> = Vec::new();
    let mut count = |name: String, inside: bool| match hits.iter_mut().find(|(n, _)| *n == name) {
        Some((_, k)) => *k += usize::from(inside),
        None => hits.push((name, usize::from(inside))),
    };
    let holds = |[lo, hi]: [f64; 2], value: f64| lo <= value && value <= hi;
    for f in fits {
        let ci = f.ci95.as_ref().expect("every noisy fit has intervals");
        for (c, channel) in ["r", "g", "b"].into_iter().enumerate() {
            count(format!("kd_{channel}"), holds(ci.kd[c], truth.kd[c]));
            count(format!("ks_{channel}"), holds(ci.ks[c], truth.ks[c]));
            if let Some(k90) = ks_90 {
                let interval = ci.ks_90.expect("Cook–Torrance–Fresnel has Ks_90")[c];
                count(format!("ks_90_{channel}"), holds(interval, k90[c]));
            }
        }
        for (c, interval) in ci.m.iter().enumerate() {
            count(format!("m_{c}"), holds(*interval, truth.m[c]));
        }
    }
    hits.into_iter()
        .map(|(name, k)| (name, k as f64 / fits.len() as f64))
        .collect()
}

fn assert_covered(model: Model, coverage: &[(String, f64)]) {
    for (name, fraction) in coverage {
        assert!(
            (0.90..=0.99).contains(fraction),
            "{model} {name}: the 95 % interval held the truth in {fraction} of {REPEATS} repeats"
        );
    }
}

#[test]
fn intervals_hold_the_truth_at_their_level() {
    let gold = Params::shared([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07);
    let fits = repeats(
        Model::CookTorrance,
        Roughness::Shared,
        &gold,
        &gold.ks,
        &[-20.0, -35.0],
    );
    assert_covered(Model::CookTorrance, &coverage(&fits, &gold, None));
    let ward = Params::shared([20.0, 16.0, 6.0], [25.0, 20.0, 7.0], 0.15);
    let fits = repeats(
        Model::Ward,
        Roughness::Shared,
        &ward,
        &ward.ks,
        &[-20.0, -35.0],
    );
    assert_covered(Model::Ward, &coverage(&fits, &ward, None));

    let bg = Params::shared([4.0, 12.0, 14.0], [54.0, 72.0, 29.0], 0.12);
    let ks_90 = [2.0, 60.0, 45.0];
    let fits = repeats(
        Model::CookTorranceFresnel,
        Roughness::Shared,
        &bg,
        &ks_90,
        &[-20.0, -45.0],
    );
    assert!(fits.iter().all(|f| f.colour_shift.unwrap().fitted));
    assert_covered(
        Model::CookTorranceFresnel,
        &coverage(&fits, &bg, Some(&ks_90)),
    );
}

#[test]
fn colour_shift_test_has_its_level_on_data_without_a_shift() {
    let gold = Params::shared([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07);
    let fits = repeats(
        Model::CookTorranceFresnel,
        Roughness::Shared,
        &gold,
        &gold.ks,
        &[-20.0, -35.0],
    );
    let kept = fits
        .iter()
        .filter(|f| f.colour_shift.unwrap().fitted)
        .count();
    // At the 1 % level: expect 2 of 200; more than 8 would be a badly sized test.
    assert!(
        kept <= 8,
        "shift kept in {kept} of {REPEATS} fits without a shift"
    );
    assert!(fits.iter().all(|f| f.colour_shift.unwrap().chi2.is_some()));
}

#[test]
fn chi2_survival_matches_table_values() {
    // χ² with 3 degrees of freedom: the 95th and 99th percentiles.
    assert!((chi2_3_survival(7.814_728) - 0.05).abs() < 1e-6);
    assert!((chi2_3_survival(11.344_867) - 0.01).abs() < 1e-6);
    assert_eq!(chi2_3_survival(0.0), 1.0);
    assert!(chi2_3_survival(1e4) < 1e-100);
}

#[test]
fn fit_json_carries_stderr_ci95_and_the_ks_m_correlation() {
    let gold = Params::shared([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07);
    let mut rng = Rng(7);
    let samples = synthetic::scan(
        Model::CookTorrance,
        &gold,
        &gold.ks,
        &[-20.0, -35.0],
        1.0,
        NOISE,
        &mut rng,
    );
    for (model, roughness, m_len) in [
        (Model::CookTorrance, Roughness::Shared, 1),
        (Model::Ward, Roughness::PerChannel, 3),
        (Model::CookTorranceFresnel, Roughness::Shared, 1),
    ] {
        let mut options = FitOptions::new(model);
        options.roughness = roughness;
        let r = fit(&samples, &options).unwrap();
        let json = serde_json::to_value(&r).unwrap();
        for key in ["stderr", "ci95"] {
            let set = &json[key];
            for name in ["kd", "ks"] {
                assert_eq!(
                    set[name].as_array().unwrap().len(),
                    3,
                    "{model} {key}.{name}"
                );
            }
            assert_eq!(set["m"].as_array().unwrap().len(), m_len, "{model} {key}.m");
            assert_eq!(
                set.get("ks_90").is_some(),
                model == Model::CookTorranceFresnel,
                "{model} {key}"
            );
        }
        let ci = r.ci95.as_ref().unwrap();
        let se = r.stderr.as_ref().unwrap();
        for c in 0..3 {
            let [lo, hi] = ci.ks[c];
            assert!(lo <= r.ks[c] && r.ks[c] <= hi && se.ks[c] > 0.0, "{model}");
            assert!(lo >= 0.0, "intervals stay in Ks ≥ 0");
        }
        let m = r.params().m[0];
        assert!(ci.m[0][0] < m && m < ci.m[0][1] && ci.m[0][0] > 0.0);
        let correlation = r.correlation.unwrap().ks_m;
        assert!(correlation.iter().all(|k| (-1.0..=1.0).contains(k)));
        if model == Model::CookTorrance {
            // The generating model: a wider lobe needs a larger Ks for the same peak, so
            // the errors of Ks and m rise together.
            assert!(correlation[1] > 0.5, "{model}: {correlation:?}");
        }
        let back: FitResult = serde_json::from_value(json).unwrap();
        assert_eq!(back, r);
    }
}
