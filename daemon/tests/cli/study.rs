//! `gonio study` and `gonio tradeoff` end to end: the built binary on small inputs.

use std::path::{Path, PathBuf};
use std::process::Output;

use gonio_processing::brdf::{Model, Params};
use gonio_processing::color::CameraModel;
use gonio_processing::samples::{write_csv, Sample};

use crate::common;
use common::{gonio, text};

/// A neutral Cook–Torrance material (coefficients ∝ the white's camera RGB), so a flat
/// spectral reference reproduces it.
fn material() -> Params {
    let w = CameraModel::builtin().white_rgb();
    Params::shared(w.map(|c| 0.2 * c), w.map(|c| 0.05 * c), 0.25)
}

/// Writes distant-geometry samples at two θL and a 2.5° reference grid of `p`.
fn write_inputs(dir: &Path, p: &Params) {
    let mut samples = Vec::new();
    for theta_l in [-20.0, -40.0] {
        for k in 0..=50 {
            let theta_r = -50.0 + 2.0 * f64::from(k);
            let theta_i = theta_l - theta_r;
            if theta_i.abs() < 70.0 {
                let rgb = Model::CookTorrance.evaluate(p, theta_i, theta_r);
                samples.push(Sample {
                    theta_l,
                    theta_i,
                    theta_r,
                    rgb,
                    ..Sample::default()
                });
            }
        }
    }
    write_csv(&dir.join("samples.csv"), &samples).unwrap();
    let white_g = CameraModel::builtin().white_rgb()[1];
    let wavelengths: Vec<String> = (39..=73).map(|w| (10 * w).to_string()).collect();
    let mut csv = format!("theta_i,theta_r,{}\n", wavelengths.join(","));
    for i in -32..=32 {
        for r in -32..=32 {
            let (ti, tr) = (2.5 * f64::from(i), 2.5 * f64::from(r));
            let f = Model::CookTorrance.evaluate(p, ti, tr)[1] / white_g;
            csv.push_str(&format!(
                "{ti},{tr},{}\n",
                vec![f.to_string(); 35].join(",")
            ));
        }
    }
    std::fs::write(dir.join("reference.csv"), csv).unwrap();
}

/// `gonio study` on the inputs of [`write_inputs`] in `dir`, writing to `out`.
fn study(dir: &Path, out: &Path, extra: &[&str]) -> Output {
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let (samples, reference) = (p("samples.csv"), p("reference.csv"));
    let mut args = vec![
        "study",
        &samples,
        "--reference",
        &reference,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    gonio(&args)
}

#[test]
fn study_writes_tables_and_figures_with_near_zero_error_for_the_true_model() {
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path(), &material());
    let out = dir.path().join("study");
    let result = study(dir.path(), &out, &[]);
    assert!(result.status.success(), "{}", text(&result.stderr));
    let stdout = text(&result.stdout);
    assert!(
        stdout.contains("2 θL, 3 combinations × 3 variants = 9 fits"),
        "{stdout}"
    );
    for name in [
        "combinations.csv",
        "boxplots.csv",
        "local_minima.csv",
        "study.json",
    ] {
        assert!(out.join(name).is_file(), "{name}");
    }
    for name in [
        "fig6_g_channel",
        "fig7_err_p_g",
        "fig8_uv_chart",
        "fig9_delta_e_uv",
        "fig10_uv_held_out",
        "fig11_held_out_delta_e_uv",
        "fig12_held_out_err_p_r",
    ] {
        let svg = std::fs::read_to_string(out.join(format!("{name}.svg"))).unwrap();
        assert!(svg.starts_with("<svg"), "{name}");
    }
    // The generating model's ΔErr_p (G) is near zero for every combination, and so is
    // Cook–Torrance–Fresnel's, which holds it.
    let table = std::fs::read_to_string(out.join("combinations.csv")).unwrap();
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let g = header.iter().position(|h| *h == "err_p_g").unwrap();
    for model in ["cook-torrance,", "cook-torrance-fresnel,"] {
        let err: Vec<f64> = table
            .lines()
            .skip(1)
            .filter(|l| l.starts_with(model))
            .map(|l| l.split(',').nth(g).unwrap().parse().unwrap())
            .collect();
        assert_eq!(err.len(), 3, "{model}");
        assert!(err.iter().all(|&e| e < 5e-3), "{model} {err:?}");
    }
}

#[test]
fn study_rejects_bad_input_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path(), &material());
    let p = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let out = p("out");

    // A malformed samples row: the error names the file.
    std::fs::write(
        dir.path().join("bad.csv"),
        "theta_l,theta_i,theta_r,r,g,b\n-20,10,-30,1,2,3\n-20,oops,-30,1,2,3\n",
    )
    .unwrap();
    let result = gonio(&[
        "study",
        &p("bad.csv"),
        "--reference",
        &p("reference.csv"),
        "--out",
        &out,
    ]);
    assert!(!result.status.success());
    let stderr = text(&result.stderr);
    assert!(stderr.contains("bad.csv"), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "one-line error: {stderr}");

    // A missing reference.
    let result = gonio(&[
        "study",
        &p("samples.csv"),
        "--reference",
        &p("none.csv"),
        "--out",
        &out,
    ]);
    assert!(!result.status.success());
    assert!(text(&result.stderr).contains("none.csv"));

    // Unknown model, zero stride.
    let result = gonio(&[
        "study",
        &p("samples.csv"),
        "--reference",
        &p("reference.csv"),
        "--out",
        &out,
        "--models",
        "phong",
    ]);
    assert!(!result.status.success());
    assert!(text(&result.stderr).contains("phong"));
    let result = gonio(&[
        "study",
        &p("samples.csv"),
        "--reference",
        &p("reference.csv"),
        "--out",
        &out,
        "--stride",
        "0",
    ]);
    assert!(!result.status.success());
    assert!(
        !Path::new(&out).join("combinations.csv").exists(),
        "nothing written on bad input"
    );
}

#[test]
fn tradeoff_rejects_unknown_scenes_and_bad_settings() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t");
    let result = gonio(&[
        "tradeoff",
        "--scene",
        "no-such-scene",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!result.status.success());
    assert!(
        text(&result.stderr).contains("no-such-scene"),
        "{}",
        text(&result.stderr)
    );
    let result = gonio(&[
        "tradeoff",
        "--scene",
        "gold",
        "--out",
        out.to_str().unwrap(),
        "--strides",
        "4,0",
    ]);
    assert!(!result.status.success());
    assert!(text(&result.stderr).contains("--strides"));
}

/// The tiny fixture scene with a noise-free Cook–Torrance sample.
fn tiny_scene() -> String {
    include_str!("../fixtures/tiny_scene.toml").to_owned()
        + r#"
[sample]
model = "cook-torrance"
kd = [9.0, 6.5, 2.0]
ks = [25.0, 20.0, 7.0]
m = [0.2]

[effects]
seed = 5
"#
}

/// `gonio tradeoff` of the tiny scene (written in `dir`) into `dir/tradeoff`, robust fits
/// only, with the pixel-column `strides` and `extra` arguments.
fn tiny_tradeoff(dir: &Path, strides: &str, extra: &[&str]) -> (Output, PathBuf) {
    let scene = dir.join("tiny.toml");
    std::fs::write(&scene, tiny_scene()).unwrap();
    let out = dir.join("tradeoff");
    let mut args = vec![
        "tradeoff",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--strides",
        strides,
        "--methods",
        "robust",
    ];
    args.extend_from_slice(extra);
    (gonio(&args), out)
}

/// `tradeoff.csv` in `out`: its rows and the index of each column by name.
fn tradeoff_rows(out: &Path) -> (Vec<Vec<String>>, impl Fn(&str) -> usize) {
    let table = std::fs::read_to_string(out.join("tradeoff.csv")).unwrap();
    let header: Vec<String> = table
        .lines()
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = table
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (rows, move |name: &str| {
        header.iter().position(|h| h == name).unwrap()
    })
}

#[test]
fn tradeoff_on_a_tiny_scene_costs_every_setting_and_recommends_one() {
    let dir = tempfile::tempdir().unwrap();
    let (result, out) = tiny_tradeoff(dir.path(), "1,2", &[]);
    assert!(result.status.success(), "{}", text(&result.stderr));
    for name in ["tradeoff.csv", "pareto.svg", "tradeoff.json"] {
        assert!(out.join(name).is_file(), "{name}");
    }
    let (rows, col) = tradeoff_rows(&out);
    assert_eq!(
        rows.len(),
        2 * 2 * 2,
        "θL counts × bracket lengths × strides"
    );
    let num = |row: &Vec<String>, name: &str| row[col(name)].parse::<f64>().unwrap();
    for row in &rows {
        assert_eq!(row[col("status")], "ok", "{row:?}");
        let parts = num(row, "acquisition_s") + num(row, "processing_s");
        assert!((num(row, "total_s") - parts).abs() < 2e-3, "{row:?}");
    }
    // Two θL cost more acquisition time than one; two exposures more than one.
    let acquisition = |n: f64, b: f64| {
        let row = rows
            .iter()
            .find(|r| num(r, "n_theta_l") == n && num(r, "bracket") == b)
            .unwrap();
        num(row, "acquisition_s")
    };
    assert!(acquisition(2.0, 1.0) > acquisition(1.0, 1.0));
    assert!(acquisition(1.0, 2.0) > acquisition(1.0, 1.0));
    // The full scan recovers the scene: small ΔErr_p and roughness error.
    let full = rows
        .iter()
        .find(|r| num(r, "n_theta_l") == 2.0 && num(r, "bracket") == 2.0 && num(r, "stride") == 1.0)
        .unwrap();
    assert!(num(full, "err_p_g") < 0.05, "{full:?}");
    assert!(num(full, "m_rel_err") < 0.1, "{full:?}");
    assert_eq!(
        rows.iter()
            .filter(|r| r[col("recommended")] == "true")
            .count(),
        1
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("tradeoff.json")).unwrap()).unwrap();
    assert_eq!(summary["scene"], "tiny");
    assert!(summary["recommended"]["total_s"].as_f64().unwrap() > 0.0);
}

#[test]
fn tradeoff_ranks_by_the_expanded_uncertainty_of_the_parameters_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let run = |rank_by: &str| tiny_tradeoff(dir.path(), "1,4", &["--rank-by", rank_by]);
    let (result, out) = run("ks_g,m");
    assert!(result.status.success(), "{}", text(&result.stderr));
    let (rows, col) = tradeoff_rows(&out);
    let num = |row: &Vec<String>, name: &str| row[col(name)].parse::<f64>().unwrap();
    // Every setting has its relative expanded uncertainty; fewer columns, fewer θL or
    // fewer exposures never make it smaller than the full scan's by much.
    let full = rows
        .iter()
        .find(|r| num(r, "n_theta_l") == 2.0 && num(r, "bracket") == 2.0 && num(r, "stride") == 1.0)
        .unwrap();
    for row in &rows {
        let u = num(row, "rel_expanded");
        assert!(u > 0.0 && u.is_finite(), "{row:?}");
    }
    let one_theta = rows
        .iter()
        .find(|r| num(r, "n_theta_l") == 1.0 && num(r, "bracket") == 2.0 && num(r, "stride") == 1.0)
        .unwrap();
    assert!(
        num(one_theta, "rel_expanded") >= 0.9 * num(full, "rel_expanded"),
        "{one_theta:?} {full:?}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("tradeoff.json")).unwrap()).unwrap();
    assert_eq!(
        summary["ranked_by"]["rel_expanded"],
        serde_json::json!(["ks_g", "m"])
    );
    let best = summary["best_rel_expanded"].as_f64().unwrap();
    let recommended = summary["recommended"]["rel_expanded"].as_f64().unwrap();
    assert!(
        best <= recommended && recommended <= best + (0.1 * best).max(0.002),
        "{summary}"
    );
    assert!(summary["recommended"]["fit"]["budget"].is_object());
    // A parameter the fit does not have is named, with the ones it has.
    let (result, _) = run("ks_90_g");
    assert!(!result.status.success());
    let stderr = text(&result.stderr);
    assert!(
        stderr.contains("ks_90_g") && stderr.contains("kd_r"),
        "{stderr}"
    );
}

/// The study's results are written in a temporary directory and renamed into place:
/// nothing temporary is left, a stale result is replaced whole, and a result whose name
/// is taken by a directory fails the study naming it, removing nothing it did not create.
#[test]
fn study_outputs_are_renamed_into_place_and_nothing_else_is_removed() {
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path(), &material());
    let out = dir.path().join("study");
    std::fs::create_dir_all(out.join("fig9_delta_e_uv.svg")).unwrap();
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let study = || study(dir.path(), &out, &["--no-nelder-mead"]);
    let leftovers = || -> Vec<String> {
        std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|name| name.starts_with('.'))
            .collect()
    };
    let result = study();
    assert!(!result.status.success());
    let stderr = text(&result.stderr);
    assert!(
        stderr.contains("fig9_delta_e_uv.svg") && stderr.contains("directory"),
        "{stderr}"
    );
    assert!(out.join("fig9_delta_e_uv.svg").is_dir());
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    assert_eq!(leftovers(), Vec::<String>::new());

    std::fs::remove_dir(out.join("fig9_delta_e_uv.svg")).unwrap();
    std::fs::write(out.join("combinations.csv"), "stale").unwrap();
    let result = study();
    assert!(result.status.success(), "{}", text(&result.stderr));
    let table = std::fs::read_to_string(out.join("combinations.csv")).unwrap();
    // The header and a row per combination (3) and variant (3), not the stale text.
    assert!(
        !table.contains("stale") && table.lines().count() == 1 + 3 * 3,
        "{table}"
    );
    assert!(std::fs::read_to_string(out.join("fig9_delta_e_uv.svg"))
        .unwrap()
        .starts_with("<svg"));
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    assert_eq!(leftovers(), Vec::<String>::new());
}
