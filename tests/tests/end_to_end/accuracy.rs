//! Accuracy of extraction and fitting against the emulator's truth: the README's
//! simulate → extract → fit chain, with no flags, recovers the built-in `gold` scene's
//! Kd, Ks and m within 0.2 %; so does `red` (whose small Ks is noise-limited at this
//! image size, so it is rendered without noise here: what is measured is the bias). The
//! scenes are binned 4× (968×648 pixels, the same geometry and strip heights) so the
//! test takes seconds; the default 5 rows per strip are read. Evaluating the models at
//! in-plane angles instead of each pixel's 3D cosines leaves gold's Ks ~0.9 % low.

use std::path::{Path, PathBuf};

use gonio_mock_hw::scene::rgl::{RglBsdf, RglMaterial};
use gonio_mock_hw::scene::Scene;
use gonio_processing::brdf::{Cosines, Model, Params};
use gonio_processing::fit::{fit, FitOptions, FitResult};
use gonio_processing::samples::{read_csv, Sample};
use gonio_tests::{gonio, temp_dir};
use serde_json::Value;

fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The relative error of every Kd, Ks and m of `fit` against `truth.json`, by name.
fn errors(fit: &Value, truth: &Value) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for key in ["kd", "ks", "m"] {
        let fitted = fit[key].as_array().unwrap();
        for (c, want) in truth[key].as_array().unwrap().iter().enumerate() {
            let (got, want) = (fitted[c].as_f64().unwrap(), want.as_f64().unwrap());
            out.push((format!("{key}[{c}]"), got / want - 1.0));
        }
    }
    out
}

fn assert_within(fit: &Value, truth: &Value, limit: f64, what: &str) {
    for (name, error) in errors(fit, truth) {
        assert!(
            error.abs() < limit,
            "{what}: {name} off by {:.3} %",
            100.0 * error
        );
    }
}

/// Simulates `scene` (built-in name or file) binned 4× into `dir/scan`, then runs the
/// README's extract and fit; returns the fit, the truth and what extract printed.
fn readme_chain(dir: &Path, scene: &str) -> (Value, Value, String) {
    let scan = dir.join("scan");
    let (samples, fitted) = (dir.join("samples.csv"), dir.join("fit.json"));
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    gonio(&[
        "simulate",
        "--scene",
        scene,
        "--binning",
        "4",
        "--out",
        &s(&scan),
    ]);
    let extracted = gonio(&["extract", &s(&scan), "--out", &s(&samples)]);
    assert!(
        extracted.contains("white reference reflectance 0.99 (setup.json)"),
        "{extracted}"
    );
    gonio(&[
        "fit",
        &s(&samples),
        "--model",
        "cook-torrance",
        "--out",
        &s(&fitted),
    ]);
    (json(&fitted), json(&scan.join("truth.json")), extracted)
}

#[test]
fn readme_chain_recovers_gold_within_0_2_percent() {
    let dir = temp_dir("accuracy-gold");
    let (fitted, truth, extracted) = readme_chain(&dir, "gold");
    assert_within(&fitted, &truth, 2e-3, "gold");
    // Noise alone rarely makes a column look like a sharp peak: at most 1 % of the
    // samples are read from one row.
    let written: usize = extracted
        .split_whitespace()
        .nth(1)
        .and_then(|n| n.parse().ok())
        .unwrap();
    let centre_rows: usize = extracted
        .lines()
        .find(|l| l.contains("samples on a peak too sharp to average"))
        .map_or(0, |l| l.split_whitespace().next().unwrap().parse().unwrap());
    assert!(100 * centre_rows <= written, "{extracted}");

    // The same samples with the models at in-plane angles (no 3D cosines): the strips'
    // rows lie above and below the light's plane, where the specular peak is lower.
    let in_plane: Vec<Sample> = read_csv(&dir.join("samples.csv"))
        .unwrap()
        .into_iter()
        .map(|s| Sample { cosines: None, ..s })
        .collect();
    let flat: FitResult = fit(&in_plane, &FitOptions::new(Model::CookTorrance)).unwrap();
    let flat = serde_json::to_value(&flat).unwrap();
    let ks_error = errors(&flat, &truth)
        .into_iter()
        .filter(|(name, _)| name.starts_with("ks"))
        .map(|(_, e)| e)
        .fold(f64::INFINITY, f64::min);
    assert!(
        ks_error < -5e-3,
        "in-plane Ks should be biased low, worst {ks_error}"
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A scene file's text without its `[effects.noise]` table.
fn without_noise(scene: &str) -> String {
    let start = scene.find("[effects.noise]").unwrap();
    let end = start + scene[start..].find("read_noise_dn").unwrap();
    let end = end + scene[end..].find('\n').unwrap();
    let quiet = format!("{}{}", &scene[..start], &scene[end..]);
    assert!(!quiet.contains("electrons_per_dn"));
    quiet
}

#[test]
fn red_without_noise_is_within_0_2_percent() {
    let dir = temp_dir("accuracy-red");
    let quiet = without_noise(include_str!("../../../mock-hw/scenes/red.toml"));
    let scene = dir.join("red.toml");
    std::fs::write(&scene, quiet).unwrap();
    let (fitted, truth, _) = readme_chain(&dir, scene.to_str().unwrap());
    assert_within(&fitted, &truth, 2e-3, "red");
    std::fs::remove_dir_all(dir).ok();
}

/// p95 and largest relative difference between the samples' β and the material's,
/// `beta` at each sample's cosines, over the values above 2 % of their channel's largest.
fn sample_errors(samples: &[Sample], beta: impl Fn(&Cosines) -> [f64; 3]) -> (f64, f64) {
    let mut largest = [0.0f64; 3];
    for s in samples {
        for (c, top) in largest.iter_mut().enumerate() {
            *top = top.max(s.channel(c).unwrap_or(0.0));
        }
    }
    let mut errors = Vec::new();
    for s in samples {
        let want = beta(&s.cosines());
        for c in 0..3 {
            if let Some(got) = s.channel(c).filter(|&v| v > 0.02 * largest[c]) {
                errors.push((got / want[c] - 1.0).abs());
            }
        }
    }
    errors.sort_by(f64::total_cmp);
    let p95 = errors[(errors.len() as f64 * 0.95) as usize];
    (p95, *errors.last().unwrap())
}

/// Gold's scene without noise, with `sample` as its `[sample]` table, one θL (−30°) and a
/// bracket down to 1/100,000 s so a sharp peak is not clipped.
fn sharp_scene(sample: &str) -> String {
    let gold = include_str!("../../../mock-hw/scenes/gold.toml");
    let table =
        "model = \"cook-torrance\"\nkd = [9.0, 6.5, 2.0]\nks = [25.0, 20.0, 7.0]\nm = [0.07]\n";
    let bracket = "bracket_s = [0.5, 0.125, 0.033333333333333333, 0.01]";
    let theta_l = "theta_l_deg = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0]";
    assert!(gold.contains(table) && gold.contains(bracket) && gold.contains(theta_l));
    without_noise(gold)
        .replace(table, sample)
        .replace(
            bracket,
            "bracket_s = [0.5, 0.05, 0.005, 0.0005, 0.00005, 0.00001]",
        )
        .replace(theta_l, "theta_l_deg = [-30.0]")
}

/// Simulates `scene` (a file's text) binned `binning`× and extracts it; returns the
/// samples.
fn sharp_samples(dir: &Path, scene: &str, binning: u32) -> Vec<Sample> {
    let (file, scan, samples) = (dir.join("scene.toml"), dir.join("scan"), dir.join("s.csv"));
    std::fs::write(&file, scene).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    let binning = binning.to_string();
    gonio(&[
        "simulate",
        "--scene",
        &s(&file),
        "--binning",
        &binning,
        "--out",
        &s(&scan),
    ]);
    let extracted = gonio(&["extract", &s(&scan), "--out", &s(&samples)]);
    assert!(
        extracted.contains("samples on a peak too sharp to average"),
        "{extracted}"
    );
    read_csv(&samples).unwrap()
}

/// A specular peak a fraction of a degree wide (m = 0.004 with gold's colours and
/// camera binned 4×): each sample's β is the material's β at the sample's cosines within
/// 0.5 % (p95 of the values above 2 % of the channel's maximum). The mean of the strip's
/// five rows would leave the peak's samples 4.5 % low, since β is far from linear over
/// them.
#[test]
fn samples_on_a_sub_degree_peak_are_the_materials_beta() {
    let dir = temp_dir("accuracy-sharp");
    let (kd, ks, m) = ([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.004);
    let table = format!("model = \"cook-torrance\"\nkd = {kd:?}\nks = {ks:?}\nm = [{m}]\n");
    let samples = sharp_samples(&dir, &sharp_scene(&table), 4);
    let params = Params::shared(kd, ks, m);
    let (p95, max) = sample_errors(&samples, |c| Model::CookTorrance.evaluate_at(&params, c));
    eprintln!(
        "sub-degree peak: p95 {:.3} %, max {:.3} % over {} samples",
        100.0 * p95,
        100.0 * max,
        samples.len()
    );
    assert!(p95 <= 5e-3, "p95 {:.3} %", 100.0 * p95);
    std::fs::remove_dir_all(dir).ok();
}

/// The same on the real colour-changing films (`cc_*.bsdf`) of `GONIO_RGL_DIR`, whose
/// specular peaks are under a degree wide, rendered at full size and binned 2×.
#[test]
fn real_films_sharp_peaks_when_gonio_rgl_dir_is_set() {
    let Some(rgl) = std::env::var_os("GONIO_RGL_DIR") else {
        println!("skipped: set GONIO_RGL_DIR to a directory of RGL-EPFL .bsdf files");
        return;
    };
    let mut films: Vec<PathBuf> = std::fs::read_dir(&rgl)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with("cc_") && name.ends_with(".bsdf")
        })
        .collect();
    films.sort();
    assert!(!films.is_empty(), "no cc_*.bsdf file in {rgl:?}");
    for film in films {
        let name = film.file_stem().unwrap().to_string_lossy().into_owned();
        let table = format!("model = \"rgl\"\nbsdf = {:?}\n", film.to_str().unwrap());
        let text = sharp_scene(&table);
        let scene = Scene::from_toml_str(&text).unwrap();
        let material =
            RglMaterial::new(RglBsdf::read(&film).unwrap(), scene.camera_domain()).unwrap();
        for binning in [1, 2] {
            let dir = temp_dir("accuracy-film");
            let samples = sharp_samples(&dir, &text, binning);
            let (p95, max) = sample_errors(&samples, |c| {
                let l_dot_v = 2.0 * c.v_dot_h * c.v_dot_h - 1.0;
                material.beta(c.n_dot_l, c.n_dot_v, l_dot_v)
            });
            println!(
                "{name}, binned {binning}×: p95 {:.3} %, max {:.3} % over {} samples",
                100.0 * p95,
                100.0 * max,
                samples.len()
            );
            assert!(p95 <= 5e-3, "{name}: p95 {:.3} %", 100.0 * p95);
            std::fs::remove_dir_all(dir).ok();
        }
    }
}
