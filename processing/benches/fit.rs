//! Fit speed on 1,000 points: robust and Nelder–Mead, Cook–Torrance and Ward, and the
//! robust fits with shared m without their uncertainty (target: the uncertainty costs at
//! most 10 % of a Cook–Torrance fit).
//!
//!     cargo bench -p gonio-processing --bench fit

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::fit::{fit, FitMethod, FitOptions};
use gonio_processing::samples::Sample;

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
            group.bench_function(name, |b| {
                b.iter(|| fit(black_box(&data), &options).expect("fit"))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_fits);
criterion_main!(benches);
