//! `gonio fit` end to end: the built binary on CSV files.

use std::path::Path;
use std::process::{Command, Output};

use gonio_processing::brdf::{Model, Params};
use gonio_processing::samples::{write_csv, Sample};

/// Distant-geometry samples (θi = θL − φ, θr = φ) of Cook–Torrance with `p`.
fn cook_torrance_samples(p: &Params, theta_ls: &[f64]) -> Vec<Sample> {
    let mut out = Vec::new();
    for &theta_l in theta_ls {
        for k in -160..=160 {
            let phi = f64::from(k) * 0.5;
            let (theta_i, theta_r) = (theta_l - phi, phi);
            if theta_i.abs() <= 80.0 {
                out.push(Sample {
                    theta_l,
                    theta_i,
                    theta_r,
                    rgb: Model::CookTorrance.evaluate(p, theta_i, theta_r),
                    ..Sample::default()
                });
            }
        }
    }
    out
}

fn gonio_fit(csv: &Path, extra: &[&str], out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .arg("fit")
        .arg(csv)
        .args(["--model", "cook-torrance"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .expect("gonio runs")
}

/// Asserts a failed run with a one-line error containing all of `needles`.
fn assert_one_line_error(output: &Output, needles: &[&str]) {
    assert!(!output.status.success(), "expected failure");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "not one line: {stderr}"
    );
    assert!(stderr.starts_with("error: "), "{stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "`{needle}` missing from: {stderr}");
    }
}

#[test]
fn recovers_known_cook_torrance_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let truth = Params::shared([5.0, 4.0, 3.0], [2.0, 2.5, 1.0], 0.12);
    let csv = dir.path().join("samples.csv");
    let samples = cook_torrance_samples(&truth, &[-20.0, -25.0, -30.0, -35.0, -40.0, -45.0]);
    write_csv(&csv, &samples).unwrap();
    // Eq. 10 loss of the all-zero model: the scale a near-exact fit's loss is measured on.
    let scale: f64 = samples
        .iter()
        .map(|s| s.rgb.iter().map(|v| v * v).sum::<f64>().sqrt())
        .sum();
    let out = dir.path().join("fit.json");
    let output = gonio_fit(&csv, &[], &out);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(json["model"], "cook-torrance");
    assert_eq!(json["roughness"], "shared");
    assert_eq!(json["method"], "robust");
    let close = |got: &serde_json::Value, want: f64| {
        let got = got.as_f64().unwrap();
        assert!((got - want).abs() <= 1e-4 * want, "{got} vs {want}");
    };
    for c in 0..3 {
        close(&json["kd"][c], truth.kd[c]);
        close(&json["ks"][c], truth.ks[c]);
    }
    assert_eq!(json["m"].as_array().unwrap().len(), 1);
    close(&json["m"][0], 0.12);
    let loss = json["loss"].as_f64().unwrap();
    assert!(loss < 1e-6 * scale, "loss {loss} of {scale}");
    assert!(json["evaluations"].as_u64().unwrap() > 0);

    // A subset of θL, written with the leading minus right after the flag.
    let subset = dir.path().join("fit-subset.json");
    let output = gonio_fit(
        &csv,
        &["--theta-l", "-20,-25", "--roughness", "per-channel"],
        &subset,
    );
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&subset).unwrap()).unwrap();
    assert_eq!(json["m"].as_array().unwrap().len(), 3);
    close(&json["m"][2], 0.12);
}

#[test]
fn bad_input_fails_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fit.json");
    let write = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path
    };
    let header = "theta_l,theta_i,theta_r,r,g,b\n";

    let malformed = write(
        "malformed.csv",
        &format!("{header}-20,-25,5,1,2,3\n-20,-26,6,1,oops,3\n"),
    );
    assert_one_line_error(&gonio_fit(&malformed, &[], &out), &["line 3", "`g`"]);

    let nan = write("nan.csv", &format!("{header}-20,-25,5,1,2,NaN\n"));
    assert_one_line_error(&gonio_fit(&nan, &[], &out), &["line 2", "not finite"]);

    let rows: String = (0..5)
        .map(|k| format!("-20,{},{},1,2,3\n", -20 - k, k))
        .collect();
    let few = write("few.csv", &format!("{header}{rows}"));
    assert_one_line_error(
        &gonio_fit(&few, &[], &out),
        &["5 sample points", "7 parameters"],
    );

    let truth = Params::shared([5.0, 4.0, 3.0], [2.0, 2.5, 1.0], 0.12);
    let good = dir.path().join("good.csv");
    write_csv(&good, &cook_torrance_samples(&truth, &[-20.0, -30.0])).unwrap();
    assert_one_line_error(
        &gonio_fit(&good, &["--theta-l", "-20,-50"], &out),
        &["θL -50", "present: -20, -30"],
    );
    assert!(!out.exists(), "no fit JSON is written on failure");
}

/// A reader that closes stdout early (`gonio fit … | head -1`) ends the command
/// quietly: exit 141 (as a shell reports SIGPIPE) or 0, nothing on stderr (it once
/// said "internal error (a bug; please report): failed printing to stdout: Broken
/// pipe"), and the fit written before the summary is whole.
#[test]
fn a_closed_stdout_ends_fit_quietly() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let truth = Params::shared([5.0, 4.0, 3.0], [2.0, 2.5, 1.0], 0.12);
    let csv = dir.path().join("samples.csv");
    write_csv(&csv, &cook_torrance_samples(&truth, &[-20.0, -30.0])).unwrap();
    let out = dir.path().join("fit.json");
    let mut child = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .arg("fit")
        .arg(&csv)
        .args(["--model", "cook-torrance", "--out"])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gonio runs");
    // The reader goes away before gonio prints anything.
    drop(child.stdout.take());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        matches!(output.status.code(), Some(0 | 141)),
        "{:?}: {stderr}",
        output.status
    );
    assert_eq!(stderr, "");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(json["model"], "cook-torrance");
}
