//! Fit speed on 1,000 points: robust and Nelder–Mead, Cook–Torrance and Ward, and the
//! robust fits with shared m without their uncertainty (target: the uncertainty costs at
//! most 10 % of a Cook–Torrance fit), and the model choice (`fit_auto` over
//! `AUTO_CANDIDATES`, the fit of `gonio fit --model auto` without its budget; target: at
//! most twice the robust Cook–Torrance fit). A Nelder–Mead fit includes its check against
//! the robust fit.
//!
//!     cargo bench -p gonio-processing --bench fit
//!     GONIO_BENCH_SAMPLES=samples.csv cargo bench -p gonio-processing --bench fit
//!
//! With a samples file that has uncertainty columns (`gonio extract` writes them), also
//! the uncertainty budget of its robust fits and the convergence of its Monte Carlo.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::color::CameraModel;
use gonio_processing::fit::budget::{budget, monte_carlo, Draw};
use gonio_processing::fit::{
    fit, fit_auto, loss_reached, FitMethod, FitOptions, FitResult, AUTO_CANDIDATES,
};
use gonio_processing::samples::{read_csv, Sample};

/// 1,000 distant-geometry points over four θL (θi = θL − φ, θr = φ, 250 per θL) with 1 %
/// deterministic multiplicative noise.
fn samples(model: Model) -> Vec<Sample> {
    let truth = Params::shared([8.0, 6.0, 3.0], [4.0, 3.5, 2.0], 0.12);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut out = Vec::with_capacity(1000);
    for theta_l in [-20.0, -30.0, -40.0, -45.0] {
        for k in 0..250 {
            let phi = theta_l / 2.0 - 60.0 + 120.0 * f64::from(k) / 249.0;
            let (theta_i, theta_r) = (theta_l - phi, phi);
            let rgb = model.evaluate(&truth, theta_i, theta_r).map(|b| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let u = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                b * (1.0 + 0.02 * u)
            });
            out.push(Sample {
                theta_l,
                theta_i,
                theta_r,
                rgb,
                ..Sample::default()
            });
        }
    }
    out
}

fn bench_fits(c: &mut Criterion) {
    let mut group = c.benchmark_group("fit_1000");
    let mut fits = serde_json::Map::new();
    for model in [Model::CookTorrance, Model::Ward] {
        let data = samples(model);
        for (method, roughness, uncertainty) in [
            (FitMethod::Robust, Roughness::Shared, true),
            (FitMethod::Robust, Roughness::Shared, false),
            (FitMethod::Robust, Roughness::PerChannel, true),
            (FitMethod::NelderMead, Roughness::Shared, true),
        ] {
            let mut options = FitOptions::new(model);
            options.method = method;
            options.roughness = roughness;
            options.uncertainty = uncertainty;
            let suffix = if uncertainty { "" } else { "/no-uncertainty" };
            let name = format!("{model}/{method}/{roughness}{suffix}");
            let result = fit(&data, &options).expect("fit");
            fits.insert(format!("fit_1000/{name}"), work(&result, data.len()));
            group.bench_function(name, |b| {
                b.iter(|| fit(black_box(&data), &options).expect("fit"))
            });
        }
    }
    let camera = CameraModel::builtin();
    let data = samples(Model::CookTorrance);
    let auto = fit_auto(&data, &AUTO_CANDIDATES, &camera).expect("fit");
    fits.insert("fit_1000/auto".into(), work(&auto, data.len()));
    group.bench_function("auto", |b| {
        b.iter(|| fit_auto(black_box(&data), &AUTO_CANDIDATES, &camera).expect("fit"))
    });
    group.finish();
    println!(
        "{}",
        serde_json::json!({ "bench": "fit_1000_work", "fits": fits })
    );
}

/// One fit's work for the floor column of README's cost table: its loss evaluations
/// (each one pass of the model over every point), its points and its model; a model
/// choice's also the evaluations × points of the fits that judged the candidates.
fn work(result: &FitResult, points: usize) -> serde_json::Value {
    let judging = result.selection.as_ref().map_or(0, |s| s.point_evaluations);
    passes(result.evaluations, points, result.model, judging)
}

/// `evaluations` passes of `model`'s loss over `points` points, and `point_evaluations`
/// more points of it, as scripts/bench_table.py reads a work.
fn passes(
    evaluations: u64,
    points: usize,
    model: Model,
    point_evaluations: u64,
) -> serde_json::Value {
    serde_json::json!({
        "evaluations": evaluations,
        "points": points,
        "model": model.to_string(),
        "point_evaluations": point_evaluations,
    })
}

/// With `GONIO_BENCH_SAMPLES=samples.csv`: the robust Cook–Torrance fit of that file (with
/// its uncertainty), the model choice (`fit_auto`) and Nelder–Mead's minimisation alone (`fit::loss_reached`, as scipy's
/// `minimize` that scripts/bench_peers.py times on the same file); prints the samples'
/// size and the robust loss as the JSON line scripts/bench.sh keeps.
fn bench_samples_file(c: &mut Criterion) {
    let Ok(path) = std::env::var("GONIO_BENCH_SAMPLES") else {
        return;
    };
    let data = read_csv(std::path::Path::new(&path)).expect("GONIO_BENCH_SAMPLES is a samples CSV");
    let robust = FitOptions::new(Model::CookTorrance);
    let nelder_mead = FitOptions {
        method: FitMethod::NelderMead,
        ..robust.clone()
    };
    let robust_fit = fit(&data, &robust).expect("robust fit");
    let nelder_mead_fit = fit(&data, &nelder_mead).expect("Nelder–Mead fit");
    let camera = CameraModel::builtin();
    let auto = fit_auto(&data, &AUTO_CANDIDATES, &camera).expect("fit");
    let mut fits = serde_json::json!({
        "fit_samples/cook-torrance/robust/shared": work(&robust_fit, data.len()),
        "fit_samples/cook-torrance/nelder-mead/shared": work(&nelder_mead_fit, data.len()),
        "fit_samples/auto": work(&auto, data.len()),
    });
    // The budgets' work: their refits' passes over the points.
    if data.iter().all(|s| s.uncertainty.is_some()) {
        for model in [Model::CookTorrance, Model::CookTorranceFresnel] {
            let result = fit(&data, &FitOptions::new(model)).expect("fit");
            let budget = budget(&data, &result).expect("budget");
            fits[format!("fit_samples/{model}/robust/shared/budget")] =
                passes(budget.evaluations, data.len(), model, 0);
        }
    }
    println!(
        "{}",
        serde_json::json!({
            "bench": "fit_samples",
            "samples": data.len(),
            "robust_loss": robust_fit.loss,
            "fits": fits,
        })
    );
    let mut group = c.benchmark_group("fit_samples");
    group.sample_size(10);
    group.bench_function("cook-torrance/robust/shared", |b| {
        b.iter(|| fit(black_box(&data), &robust).expect("fit"))
    });
    group.bench_function("cook-torrance/nelder-mead/shared", |b| {
        b.iter(|| loss_reached(black_box(&data), &nelder_mead).expect("fit").0)
    });
    group.bench_function("auto", |b| {
        b.iter(|| fit_auto(black_box(&data), &AUTO_CANDIDATES, &camera).expect("fit"))
    });
    if data.iter().all(|s| s.uncertainty.is_some()) {
        // The uncertainty budget of the robust fits (law of propagation: two refits per
        // source and per θL for the arm's angle).
        for model in [Model::CookTorrance, Model::CookTorranceFresnel] {
            let result = fit(&data, &FitOptions::new(model)).expect("fit");
            group.bench_function(format!("{model}/robust/shared/budget"), |b| {
                b.iter(|| budget(black_box(&data), &result).expect("budget"))
            });
        }
    }
    group.finish();
    monte_carlo_convergence(&data);
}

/// The Monte Carlo (JCGM 101) of the Cook–Torrance fit's budget with 250, 500 and 1,000
/// draws: its time, and how its standard deviation of Ks_G and m settles against the law of
/// propagation's combined uncertainty, and m's interval; one JSON line for scripts/bench.sh.
fn monte_carlo_convergence(data: &[Sample]) {
    if data.iter().any(|s| s.uncertainty.is_none()) {
        return;
    }
    let result = fit(data, &FitOptions::new(Model::CookTorrance)).expect("fit");
    let lpu = budget(data, &result).expect("budget");
    let mut runs = Vec::new();
    for draws in [250, 500, 1000] {
        let start = std::time::Instant::now();
        let mc = monte_carlo(data, &result, draws, Draw::All, 7).expect("Monte Carlo");
        runs.push(serde_json::json!({
            "draws": draws,
            "seconds": start.elapsed().as_secs_f64(),
            "ks_g_std": mc.parameters.ks[1].std,
            "m_std": mc.parameters.m[0].std,
            "m_interval": mc.parameters.m[0].interval,
            "evaluations": mc.evaluations,
            "points": data.len(),
        }));
    }
    println!(
        "{}",
        serde_json::json!({
            "bench": "budget_monte_carlo",
            "ks_g_combined": lpu.parameters.ks[1].combined,
            "m_combined": lpu.parameters.m[0].combined,
            "runs": runs,
        })
    );
}

criterion_group!(benches, bench_fits, bench_samples_file);
criterion_main!(benches);
