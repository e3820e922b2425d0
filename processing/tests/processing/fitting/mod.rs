//! Scaffolding shared by the fitting tests (fit.rs, fit_fresnel.rs): synthetic scans of
//! the distant-source geometry, fit options, tolerance checks and clipped peaks.

use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::fit::{FitMethod, FitOptions, FitResult};
use gonio_processing::samples::Sample;

use crate::common::Rng;
use crate::synthetic::{self, Noise};

pub const ALL_THETA_L: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];

/// Samples of the distant-source geometry, φ every 0.5°, both angles within ±85°, with
/// multiplicative Gaussian noise of relative size `noise` (the same draws every call).
pub fn synthetic(model: Model, p: &Params, theta_ls: &[f64], noise: f64) -> Vec<Sample> {
    synthetic_fresnel(model, p, &p.ks, theta_ls, noise)
}

/// [`synthetic`] with the specular colour at 90° `ks_90` (Cook–Torrance–Fresnel).
pub fn synthetic_fresnel(
    model: Model,
    p: &Params,
    ks_90: &[f64; 3],
    theta_ls: &[f64],
    noise: f64,
) -> Vec<Sample> {
    let noise = Noise {
        relative: noise,
        absolute: 0.0,
    };
    synthetic::scan(
        model,
        p,
        ks_90,
        theta_ls,
        0.5,
        noise,
        &mut Rng(0x9e37_79b9_7f4a_7c15),
    )
}

pub fn options(model: Model, roughness: Roughness, method: FitMethod) -> FitOptions {
    let mut o = FitOptions::new(model);
    o.roughness = roughness;
    o.method = method;
    o
}

pub fn assert_close(name: &str, got: f64, want: f64, rel: f64, abs: f64) {
    assert!(
        (got - want).abs() <= rel * want.abs() + abs,
        "{name}: got {got}, want {want} (rel {rel}, abs {abs})"
    );
}

pub fn assert_recovers(r: &FitResult, truth: &Params, rel: f64, abs: f64, check_m: bool) {
    for c in 0..3 {
        assert_close("kd", r.kd[c], truth.kd[c], rel, abs);
        assert_close("ks", r.ks[c], truth.ks[c], rel, abs);
        if check_m {
            assert_close("m", r.params().m[c], truth.m[c], rel, 0.0);
        }
    }
}

/// Clipped peaks: each value of `clean` above `ceiling` as a clipped reading (the ceiling)
/// and as a dropped one (garbage in its place, marked dropped), with their count.
pub fn clip_and_drop(clean: &[Sample], ceiling: f64) -> (Vec<Sample>, Vec<Sample>, usize) {
    let mut clipped = clean.to_vec();
    let mut dropped = clean.to_vec();
    let mut count = 0;
    for (g, d) in clipped.iter_mut().zip(dropped.iter_mut()) {
        for c in 0..3 {
            if g.rgb[c] > ceiling {
                g.rgb[c] = ceiling;
                d.rgb[c] = 1e9;
                d.dropped[c] = true;
                count += 1;
            }
        }
    }
    (clipped, dropped, count)
}
