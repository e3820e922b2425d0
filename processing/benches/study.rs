//! Benchmark of the θL-combination study: 3 samples × 63 combinations × the 3 models
//! (Cook–Torrance, Ward, Cook–Torrance–Fresnel) with the robust fitter and their
//! uncertainty, on synthetic data at the geometry of the example scenes
//! (full-resolution columns, six θL, 1 % noise), fitting every column or every 4th.
//! The full-size `gonio study` with the Nelder–Mead comparison is timed as a whole
//! process by `cargo bench -p gonio-daemon --bench study_command`.
//!
//! Run: `cargo bench -p gonio-processing --bench study`

mod common;

use common::{d200_setup, THETA_L};
use criterion::{criterion_group, criterion_main, Criterion};
use gonio_processing::brdf::{Model, Params};
use gonio_processing::color::CameraModel;
use gonio_processing::geometry::column_angles;
use gonio_processing::reference::Reference;
use gonio_processing::samples::Sample;
use gonio_processing::study::combinations::combinations;
use gonio_processing::study::{run_study, StudyOptions};

/// Samples of Cook–Torrance `params` at every column within 80° of the normal, with
/// deterministic 1 % multiplicative noise.
fn samples(params: &Params) -> Vec<Sample> {
    let setup = d200_setup();
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut noise = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        1.0 + 0.02 * ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5)
    };
    let mut out = Vec::new();
    for theta_l in THETA_L {
        for a in column_angles(&setup, theta_l).into_iter().flatten() {
            if a.theta_i.abs() < 80.0 && a.theta_r.abs() < 80.0 {
                let rgb = Model::CookTorrance
                    .evaluate(params, a.theta_i, a.theta_r)
                    .map(|v| v * noise());
                out.push(Sample {
                    theta_l,
                    theta_i: a.theta_i,
                    theta_r: a.theta_r,
                    rgb,
                    ..Sample::default()
                });
            }
        }
    }
    out
}

/// A goniospectrophotometer-like reference on a 5° grid: a flat spectrum with the
/// material's G value.
fn reference(params: &Params, camera: &CameraModel) -> Reference {
    let mut csv = String::from("theta_i,theta_r");
    for w in (390..=730).step_by(10) {
        csv.push_str(&format!(",{w}"));
    }
    csv.push('\n');
    for i in -16..=16 {
        for r in -16..=16 {
            let (ti, tr) = (5.0 * f64::from(i), 5.0 * f64::from(r));
            let f = Model::CookTorrance.evaluate(params, ti, tr)[1] / camera.white_rgb()[1];
            csv.push_str(&format!("{ti},{tr}{}\n", format!(",{f}").repeat(35)));
        }
    }
    Reference::from_reader(csv.as_bytes(), "bench", camera).expect("valid reference")
}

/// The fits' work of one run of the studies, for the floor column of README's cost
/// table: Σ over every fit of its loss evaluations × its points (`Scores::point_evaluations`).
fn study_work(
    inputs: &[(Vec<Sample>, Reference)],
    camera: &CameraModel,
    options: &StudyOptions,
) -> f64 {
    let mut point_evaluations = 0;
    for (samples, reference) in inputs {
        let report = run_study(samples, reference, camera, options).expect("study runs");
        point_evaluations += (report.results.iter())
            .filter_map(|c| c.outcome.as_ref().ok())
            .map(|scores| scores.point_evaluations)
            .sum::<u64>();
    }
    point_evaluations as f64
}

fn study(c: &mut Criterion) {
    let camera = CameraModel::builtin();
    let materials = [
        // Gold-like: smooth, specular.
        Params::shared([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07),
        // Red-like: mostly diffuse, rough.
        Params::shared([40.0, 8.0, 6.0], [2.0, 2.0, 2.0], 0.35),
        // Blue-green-like: one roughness per channel.
        Params {
            kd: [4.0, 12.0, 14.0],
            ks: [3.0, 8.0, 6.0],
            m: [0.2, 0.12, 0.1],
        },
    ];
    let inputs: Vec<(Vec<Sample>, Reference)> = materials
        .iter()
        .map(|p| (samples(p), reference(p, &camera)))
        .collect();
    let mut work = serde_json::Map::new();
    let mut group = c.benchmark_group("study");
    group.sample_size(10);
    // Every column (stride 1), and every 4th column of each θL (stride 4, ~340 per θL).
    for stride in [1, 4] {
        let options = StudyOptions {
            compare_nelder_mead: false,
            stride,
            ..StudyOptions::default()
        };
        let name = format!(
            "3_samples_x_63_combinations_x_{}_models_robust_stride_{stride}",
            options.variants.len()
        );
        work.insert(name.clone(), study_work(&inputs, &camera, &options).into());
        group.bench_function(name, |b| {
            b.iter(|| {
                for (samples, reference) in &inputs {
                    run_study(samples, reference, &camera, &options).expect("study runs");
                }
            })
        });
    }
    group.finish();
    println!(
        "{}",
        serde_json::json!({ "bench": "study_work", "studies": work })
    );
    c.bench_function("combinations_of_6", |b| b.iter(|| combinations(&THETA_L)));
}

criterion_group!(benches, study);
criterion_main!(benches);
