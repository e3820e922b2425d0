use std::f64::consts::PI;

use gonio_processing::brdf::{Model, Params, Roughness};
use proptest::prelude::*;

/// Independent vector-form evaluation: n = +z, l and v in the x–z plane, h = (l + v)/|l + v|;
/// `kg` is Cook–Torrance–Fresnel's specular colour at 90°.
fn vector_form(model: Model, p: &Params, kg: &[f64; 3], theta_i: f64, theta_r: f64) -> [f64; 3] {
    let (ti, tr) = (theta_i.to_radians(), theta_r.to_radians());
    // Specular direction at θr = θi: l and v on opposite sides of the normal.
    let l = [ti.sin(), ti.cos()];
    let v = [-tr.sin(), tr.cos()];
    let h_len = ((l[0] + v[0]).powi(2) + (l[1] + v[1]).powi(2)).sqrt();
    let h = [(l[0] + v[0]) / h_len, (l[1] + v[1]) / h_len];
    let (nl, nv, nh) = (l[1], v[1], h[1]);
    let vh = v[0] * h[0] + v[1] * h[1];
    let tan2 = (1.0 - nh * nh) / (nh * nh);
    std::array::from_fn(|c| {
        let m2 = p.m[c] * p.m[c];
        match model {
            Model::CookTorrance => {
                let d = (-tan2 / m2).exp() / (m2 * nh.powi(4));
                let g = 1f64.min(2.0 * nh * nv / vh).min(2.0 * nh * nl / vh);
                p.ks[c] * d * g / (PI * nl * nv) + p.kd[c]
            }
            Model::Ward => {
                p.kd[c] / PI + p.ks[c] * (-tan2 / m2).exp() / (4.0 * PI * m2 * (nl * nv).sqrt())
            }
            Model::CookTorranceFresnel => {
                let d = (-tan2 / m2).exp() / (m2 * nh.powi(4));
                let g = 1f64.min(2.0 * nh * nv / vh).min(2.0 * nh * nl / vh);
                // 1 − l·v = 2 sin²θd, clamped at θd = 45°.
                let w = (2.0 * (1.0 - vh * vh)).min(1.0);
                let f = p.ks[c] * (1.0 - w) + kg[c] * w;
                f * d * g / (PI * nl * nv) + p.kd[c]
            }
        }
    })
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300)
}

#[test]
fn matches_vector_form_on_a_grid() {
    let params = Params {
        kd: [3.0, 10.0, 0.5],
        ks: [20.0, 40.0, 5.0],
        m: [0.05, 0.2, 0.6],
    };
    let kg = [2.0, 60.0, 9.0];
    for model in Model::ALL {
        for ti in (-85..=85).step_by(5) {
            for tr in (-85..=85).step_by(5) {
                let (ti, tr) = (f64::from(ti) + 0.3, f64::from(tr) - 0.2);
                let got = model.basis(ti, tr).evaluate_fresnel(&params, &kg);
                let want = vector_form(model, &params, &kg, ti, tr);
                for c in 0..3 {
                    assert!(
                        close(got[c], want[c], 1e-9),
                        "{model} {ti} {tr}: {got:?} vs {want:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn specular_peak_hand_values() {
    // At θi = θr = θ: α = 0, D = 1/m², G = 1.
    let p = Params::shared([0.0; 3], [1.0; 3], 0.1);
    let theta = 30f64;
    let c = theta.to_radians().cos();
    let ct = Model::CookTorrance.evaluate(&p, theta, theta)[0];
    assert!(close(ct, 1.0 / (PI * 0.01 * c * c), 1e-12));
    let ward = Model::Ward.evaluate(&p, theta, theta)[0];
    assert!(close(ward, 1.0 / (4.0 * PI * 0.01 * c), 1e-12));
    // Diffuse only: CT gives Kd, Ward Kd/π.
    let d = Params::shared([7.0, 8.0, 9.0], [0.0; 3], 0.3);
    assert_eq!(
        Model::CookTorrance.evaluate(&d, -10.0, 40.0),
        [7.0, 8.0, 9.0]
    );
    assert!(close(
        Model::Ward.evaluate(&d, -10.0, 40.0)[2],
        9.0 / PI,
        1e-15
    ));
}

#[test]
fn fresnel_colour_is_linear_in_the_cosine_between_light_and_camera() {
    // At the specular peak θi = θr = θ the light and camera are γ = 2θ apart and
    // F = Ks·cos γ + Ks_90·(1 − cos γ) up to γ = 90°, Ks_90 beyond; F multiplies the
    // Cook–Torrance lobe.
    let p = Params::shared([1.0, 2.0, 3.0], [10.0, 20.0, 30.0], 0.2);
    let kg = [40.0, 0.0, 30.0];
    for theta in [0.0f64, 10.0, 25.0, 45.0, 60.0] {
        let w = (1.0 - (2.0 * theta).to_radians().cos()).min(1.0);
        let ct = Model::CookTorrance.evaluate(&p, theta, theta);
        let got = Model::CookTorranceFresnel
            .basis(theta, theta)
            .evaluate_fresnel(&p, &kg);
        for ch in 0..3 {
            let f = p.ks[ch] * (1.0 - w) + kg[ch] * w;
            let want = p.kd[ch] + (ct[ch] - p.kd[ch]) * f / p.ks[ch];
            assert!(close(got[ch], want, 1e-12), "θ {theta}: {got:?} vs {want}");
        }
    }
    // A colour at 90° equal to Ks is Cook–Torrance itself.
    assert_eq!(
        Model::CookTorranceFresnel.evaluate(&p, -10.0, 35.0),
        Model::CookTorrance.evaluate(&p, -10.0, 35.0)
    );
}

#[test]
fn lobe_is_exactly_zero_where_exp_underflows() {
    let p = Params::shared([0.0; 3], [1.0; 3], 1e-3);
    for model in Model::ALL {
        assert_eq!(model.evaluate(&p, 30.0, -30.0), [0.0; 3]);
        assert_eq!(model.evaluate(&p, 89.99, -89.99), [0.0; 3]);
    }
}

#[test]
fn grazing_and_beyond_is_masked_to_zero() {
    let p = Params::shared([5.0; 3], [10.0; 3], 0.3);
    for model in Model::ALL {
        for (ti, tr) in [
            (90.0, 10.0),
            (10.0, -90.0),
            (95.0, 0.0),
            (f64::NAN, 0.0),
            (-120.0, 30.0),
        ] {
            assert_eq!(model.evaluate(&p, ti, tr), [0.0; 3], "{model} {ti} {tr}");
        }
    }
}

#[test]
fn names_round_trip() {
    for model in Model::ALL {
        assert_eq!(model.name().parse::<Model>().unwrap(), model);
        assert_eq!(
            serde_json::to_string(&model).unwrap(),
            format!("\"{model}\"")
        );
    }
    for r in [Roughness::Shared, Roughness::PerChannel] {
        assert_eq!(r.name().parse::<Roughness>().unwrap(), r);
        assert_eq!(serde_json::to_string(&r).unwrap(), format!("\"{r}\""));
    }
    assert!("phong".parse::<Model>().is_err());
}

proptest! {
    #[test]
    fn finite_and_non_negative(
        ti in -89.99f64..=89.99,
        tr in -89.99f64..=89.99,
        m in prop::array::uniform3(1e-3f64..=2.0),
        kd in prop::array::uniform3(0.0f64..=100.0),
        ks in prop::array::uniform3(0.0f64..=100.0),
        kg in prop::array::uniform3(0.0f64..=100.0),
    ) {
        let p = Params { kd, ks, m };
        for model in Model::ALL {
            let beta = model.basis(ti, tr).evaluate_fresnel(&p, &kg);
            for b in beta {
                prop_assert!(b.is_finite() && b >= 0.0, "{model} {ti} {tr} {m:?}: {beta:?}");
            }
            let basis = model.basis(ti, tr);
            for mc in m {
                let s = basis.specular(mc);
                prop_assert!(s.is_finite() && s >= 0.0);
            }
        }
    }

    #[test]
    fn finite_at_extreme_grazing(
        ti in prop::sample::select(vec![-89.99f64, 89.99, -89.9999999, 89.9999999]),
        tr in prop::sample::select(vec![-89.99f64, 89.99, -89.9999999, 89.9999999, 0.0]),
        m in 1e-3f64..=2.0,
    ) {
        let p = Params::shared([1.0; 3], [100.0; 3], m);
        for model in Model::ALL {
            for b in model.evaluate(&p, ti, tr) {
                prop_assert!(b.is_finite() && b >= 0.0);
            }
        }
    }
}

#[test]
fn cosines_from_in_plane_directions_match_the_angle_form() {
    use gonio_processing::brdf::Cosines;
    // Normal along +x; the light at signed θi (counter-clockwise), the camera at −θr.
    for (ti, tr) in [(30.0, 30.0), (-10.0, 40.0), (60.0, -20.0), (5.0, 80.0)] {
        let (ti_r, tr_r) = (f64::to_radians(ti), f64::to_radians(tr));
        let from_dirs = Cosines::from_directions(
            [1.0, 0.0, 0.0],
            [ti_r.cos(), ti_r.sin(), 0.0],
            [tr_r.cos(), -tr_r.sin(), 0.0],
        );
        let angles = Cosines::in_plane(ti, tr);
        for (a, b) in from_dirs.to_array().into_iter().zip(angles.to_array()) {
            assert!(
                (a - b).abs() < 1e-12,
                "({ti}, {tr}): {from_dirs:?} vs {angles:?}"
            );
        }
    }
}
