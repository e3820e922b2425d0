use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::fit::{fit, FitMethod, FitOptions};
use gonio_processing::samples::Sample;

fn synthetic(model: Model, p: &Params, theta_ls: &[f64], step: f64) -> Vec<Sample> {
    let mut out = Vec::new();
    let mut seed = 1u64;
    for &theta_l in theta_ls {
        let mut phi = -85.0;
        while phi <= 85.0 {
            let (theta_i, theta_r) = (theta_l - phi, phi);
            phi += step;
            if theta_i.abs() > 85.0 {
                continue;
            }
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5;
            let rgb = model
                .evaluate(p, theta_i, theta_r)
                .map(|b| b * (1.0 + 0.04 * u));
            out.push(Sample {
                theta_l,
                theta_i,
                theta_r,
                rgb,
            });
        }
    }
    out
}

#[test]
fn scratch() {
    let truth = Params::shared([10.0, 12.0, 8.0], [5.0, 6.0, 4.0], 0.1);
    for model in [Model::CookTorrance, Model::Ward] {
        let s = synthetic(model, &truth, &[-20.0, -30.0, -40.0], 0.3);
        for (rough, method) in [
            (Roughness::Shared, FitMethod::Robust),
            (Roughness::PerChannel, FitMethod::Robust),
            (Roughness::Shared, FitMethod::NelderMead),
        ] {
            let mut o = FitOptions::new(model);
            o.roughness = rough;
            o.method = method;
            let r = fit(&s, &o).unwrap();
            println!("{} pts {model} {rough} {method}: loss {:.6} evals {} {:.2} ms kd {:?} ks {:?} m {:?}", s.len(), r.loss, r.evaluations, r.seconds*1e3, r.kd, r.ks, r.m);
        }
    }
}
