//! Fitting Cook–Torrance–Fresnel (a specular colour that turns with the facet's
//! incidence) on synthetic data from known parameters: noise-free data give Kd, Ks and
//! Ks_90 within 1e-4 relative and a loss no dense scan of m beats; with 1 % noise the
//! colour shift stays significant. Also its dropped channels, its fallback to
//! Cook–Torrance (one θL, or a given tied fit) and the robust method as its only one.

use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::fit::{
    fit, fit_fresnel_given, solve_at_roughness, FitError, FitMethod, FitResult,
};
use gonio_processing::metrics;

use crate::common;
use crate::fitting;
use crate::synthetic;
use common::Rng;
use fitting::{
    assert_close, assert_recovers, clip_and_drop, options, synthetic, synthetic_fresnel,
    ALL_THETA_L,
};
use synthetic::Noise;

#[test]
fn dropped_channels_are_left_out_of_the_fresnel_fit() {
    // As for Cook–Torrance (fit.rs), for Cook–Torrance–Fresnel's three-coefficient solve
    // and colour-shift test.
    let (truth, ks_90) = fresnel_truth();
    let model = Model::CookTorranceFresnel;
    let o = options(model, Roughness::Shared, FitMethod::Robust);
    let clean = synthetic_fresnel(model, &truth, &ks_90, &ALL_THETA_L, 0.0);
    let (garbage, dropped, count) = clip_and_drop(&clean, 150.0);
    assert!(count > 20, "{count} values above the ceiling");
    let fitted = fit(&dropped, &o).unwrap();
    assert!(fitted.colour_shift.unwrap().fitted, "{fitted:?}");
    assert_recovers(&fitted, &truth, 1e-4, 0.0, true);
    for (&got, &want) in fitted.ks_90.unwrap().iter().zip(&ks_90) {
        assert_close("ks_90", got, want, 1e-4, 0.0);
    }
    assert!(fitted.err_p.iter().all(|e| e.is_finite()), "{fitted:?}");
    // Its uncertainty too: with 1 % noise, Ks stays known to a few per cent without the
    // peak values (their garbage, 1e9, would make it unbounded).
    let noisy = synthetic_fresnel(model, &truth, &ks_90, &ALL_THETA_L, 0.01);
    let (_, noisy_dropped, _) = clip_and_drop(&noisy, 150.0);
    let se = fit(&noisy_dropped, &o).unwrap().stderr.unwrap();
    for c in 0..3 {
        assert!(se.ks[c] > 0.0 && se.ks[c] < 0.05 * truth.ks[c], "{se:?}");
    }
    let clipped = fit(&garbage, &o).unwrap();
    assert!(
        (clipped.ks[1] - truth.ks[1]).abs() > 0.05 * truth.ks[1],
        "{clipped:?}"
    );
}

/// A blue-green-like goniochromatic truth: the specular colour turns from red-green at
/// γ = 0 to green-blue at γ = 90°.
fn fresnel_truth() -> (Params, [f64; 3]) {
    (
        Params::shared([4.0, 12.0, 14.0], [54.0, 72.0, 29.0], 0.12),
        [2.0, 60.0, 45.0],
    )
}

#[test]
fn fresnel_colour_shift_is_recovered_globally() {
    let (truth, ks_90) = fresnel_truth();
    let model = Model::CookTorranceFresnel;
    let samples = synthetic_fresnel(model, &truth, &ks_90, &ALL_THETA_L, 0.0);
    let r = fit(
        &samples,
        &options(model, Roughness::Shared, FitMethod::Robust),
    )
    .unwrap();
    assert_recovers(&r, &truth, 1e-4, 0.0, true);
    let fitted_90 = r.ks_90.unwrap();
    for c in 0..3 {
        assert_close("ks_90", fitted_90[c], ks_90[c], 1e-4, 0.0);
    }
    // Global in m: no roughness of a dense scan does better.
    let brute = (0..400)
        .map(|k| {
            let m = (1e-3f64.ln() + 2000f64.ln() * f64::from(k) / 399.0).exp();
            solve_at_roughness(&samples, model, [m; 3]).unwrap().loss
        })
        .fold(f64::INFINITY, f64::min);
    assert!(
        r.loss <= brute * (1.0 + 1e-9) + 1e-9,
        "{} > {brute}",
        r.loss
    );
}

#[test]
fn fresnel_inner_solve_is_optimal_in_every_coefficient() {
    // Convex at fixed m: no single coefficient moved either way (within ≥ 0) lowers eq. 10.
    let (truth, ks_90) = fresnel_truth();
    let model = Model::CookTorranceFresnel;
    let samples = synthetic_fresnel(model, &truth, &ks_90, &[-20.0, -35.0], 0.02);
    let solved = solve_at_roughness(&samples, model, [0.1; 3]).unwrap();
    let loss = |p: &Params, k90: &[f64; 3]| {
        let measured: Vec<[f64; 3]> = samples.iter().map(|s| s.rgb).collect();
        let estimated: Vec<[f64; 3]> = samples
            .iter()
            .map(|s| model.basis(s.theta_i, s.theta_r).evaluate_fresnel(p, k90))
            .collect();
        metrics::loss(&measured, &estimated).unwrap()
    };
    let base = loss(&solved.params, &solved.ks_90);
    assert!((base - solved.loss).abs() <= 1e-9 * base);
    for k in 0..9 {
        for step in [1e-3, -1e-3] {
            let (mut p, mut k90) = (solved.params, solved.ks_90);
            let value = match k / 3 {
                0 => &mut p.kd[k % 3],
                1 => &mut p.ks[k % 3],
                _ => &mut k90[k % 3],
            };
            *value = (*value + step * value.abs().max(1.0)).max(0.0);
            assert!(
                loss(&p, &k90) >= base * (1.0 - 1e-7),
                "coefficient {k} moved by {step}: {} < {base}",
                loss(&p, &k90)
            );
        }
    }
}

#[test]
fn fresnel_with_noise_keeps_a_significant_shift() {
    let (truth, ks_90) = fresnel_truth();
    let model = Model::CookTorranceFresnel;
    let samples = synthetic_fresnel(model, &truth, &ks_90, &[-20.0, -30.0, -45.0], 0.01);
    let r = fit(
        &samples,
        &options(model, Roughness::Shared, FitMethod::Robust),
    )
    .unwrap();
    let shift = r.colour_shift.unwrap();
    assert!(shift.fitted && shift.p_value.unwrap() < 1e-6, "{shift:?}");
    assert_close("m", r.params().m[0], 0.12, 0.02, 0.0);
    let fitted_90 = r.ks_90.unwrap();
    for c in 0..3 {
        assert_close("kd", r.kd[c], truth.kd[c], 0.05, 0.0);
        assert_close("ks", r.ks[c], truth.ks[c], 0.05, 0.0);
        // Ks_90 is extrapolated from γ ≤ 45°: a looser bound.
        assert_close("ks_90", fitted_90[c], ks_90[c], 0.1, 1.0);
    }
}

#[test]
fn fresnel_from_one_theta_l_is_cook_torrance() {
    // One θL sees one facet incidence: the colour shift is tied, the fit is Cook–Torrance's.
    let (truth, ks_90) = fresnel_truth();
    let samples = synthetic_fresnel(Model::CookTorranceFresnel, &truth, &ks_90, &[-30.0], 0.01);
    let fresnel = fit(
        &samples,
        &options(
            Model::CookTorranceFresnel,
            Roughness::Shared,
            FitMethod::Robust,
        ),
    )
    .unwrap();
    let ct = fit(
        &samples,
        &options(Model::CookTorrance, Roughness::Shared, FitMethod::Robust),
    )
    .unwrap();
    let shift = fresnel.colour_shift.unwrap();
    assert!(!shift.fitted && shift.chi2.is_none(), "{shift:?}");
    assert_eq!(fresnel.ks_90, Some(fresnel.ks));
    assert_close("loss", fresnel.loss, ct.loss, 1e-9, 0.0);
    assert_eq!(fresnel.params(), ct.params());
    // Its Ks_90 is Ks: the same uncertainty.
    let se = fresnel.stderr.unwrap();
    assert_eq!(se.ks_90, Some(se.ks));
}

#[test]
fn fresnel_is_fitted_by_the_robust_method_only() {
    let (truth, ks_90) = fresnel_truth();
    let model = Model::CookTorranceFresnel;
    let samples = synthetic_fresnel(model, &truth, &ks_90, &[-20.0, -40.0], 0.0);
    let nm = options(model, Roughness::Shared, FitMethod::NelderMead);
    assert!(matches!(
        fit(&samples, &nm),
        Err(FitError::InvalidOptions(_))
    ));
    let mut polish = options(model, Roughness::Shared, FitMethod::Robust);
    polish.robust.polish = true;
    assert!(matches!(
        fit(&samples, &polish),
        Err(FitError::InvalidOptions(_))
    ));
}

/// Cook–Torrance–Fresnel given the Cook–Torrance fit it falls back to is the fit it makes
/// alone, field for field but its time: on Cook–Torrance scans (shift tied, the given fit
/// taken) and on goniochromatic ones (shift kept, the given fit unused), with shared and
/// per-channel roughness and random parameters and noise.
#[test]
fn fresnel_given_its_tied_fit_is_the_fit_alone() {
    let mut rng = Rng(0x51_7cc1_b727_220a);
    let mut taken = 0;
    for case in 0..6 {
        let roughness = [Roughness::Shared, Roughness::PerChannel][case % 2];
        let truth = Params::shared(
            std::array::from_fn(|_| 2.0 + 20.0 * rng.uniform()),
            std::array::from_fn(|_| 5.0 + 40.0 * rng.uniform()),
            0.05 + 0.3 * rng.uniform(),
        );
        // Half the scans without a colour shift, half with one.
        let ks_90 = if case < 3 {
            truth.ks
        } else {
            std::array::from_fn(|c| truth.ks[c] * (0.3 + 1.4 * rng.uniform()))
        };
        let samples = synthetic::scan(
            Model::CookTorranceFresnel,
            &truth,
            &ks_90,
            &[-20.0, -35.0, -45.0],
            1.0,
            Noise {
                relative: 0.005 + 0.02 * rng.uniform(),
                absolute: 0.0,
            },
            &mut rng,
        );
        let fresnel = options(Model::CookTorranceFresnel, roughness, FitMethod::Robust);
        let ct = fit(
            &samples,
            &options(Model::CookTorrance, roughness, FitMethod::Robust),
        )
        .unwrap();
        let alone = fit(&samples, &fresnel).unwrap();
        let given = fit_fresnel_given(&samples, &fresnel, &ct).unwrap();
        taken += usize::from(!alone.colour_shift.unwrap().fitted);
        assert_eq!(
            FitResult {
                seconds: 0.0,
                ..given
            },
            FitResult {
                seconds: 0.0,
                ..alone
            },
            "case {case}"
        );
    }
    assert!(
        (1..6).contains(&taken),
        "the given fit was taken in {taken} of 6"
    );
    // Only a robust Cook–Torrance fit of the same roughness is the tied form.
    let samples = synthetic(
        Model::CookTorrance,
        &fresnel_truth().0,
        &[-20.0, -40.0],
        0.01,
    );
    let fresnel = options(
        Model::CookTorranceFresnel,
        Roughness::Shared,
        FitMethod::Robust,
    );
    for other in [
        options(Model::Ward, Roughness::Shared, FitMethod::Robust),
        options(
            Model::CookTorrance,
            Roughness::PerChannel,
            FitMethod::Robust,
        ),
        options(
            Model::CookTorrance,
            Roughness::Shared,
            FitMethod::NelderMead,
        ),
    ] {
        let other = fit(&samples, &other).unwrap();
        assert!(matches!(
            fit_fresnel_given(&samples, &fresnel, &other),
            Err(FitError::InvalidOptions(_))
        ));
    }
}
