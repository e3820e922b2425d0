//! `gonio simulate` on a tiny scene: the scan directory layout, sidecars, truth,
//! reference, seeding and errors.

use std::path::Path;
use std::process::Command;

/// The tiny fixture scene with a noisy Cook–Torrance sample.
fn tiny_scene() -> String {
    include_str!("../fixtures/tiny_scene.toml").to_owned()
        + r#"
[sample]
model = "cook-torrance"
kd = [9.0, 6.5, 2.0]
ks = [25.0, 20.0, 7.0]
m = [0.07]

[effects]
seed = 5

[effects.noise]
electrons_per_dn = 9.0
read_noise_dn = 1.2
"#
}

fn gonio(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .arg("simulate")
        .args(args)
        .output()
        .unwrap()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn simulate_writes_a_complete_scan() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("tiny.toml");
    std::fs::write(&scene, tiny_scene()).unwrap();
    let out = dir.path().join("scan");
    let result = gonio(&[
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );

    let setup: gonio_processing::geometry::Setup =
        serde_json::from_value(json(&out.join("setup.json"))).unwrap();
    assert_eq!((setup.image_width, setup.image_height), (400, 120));
    assert_eq!((setup.sample_row, setup.white_row), (30, 89));

    let truth = json(&out.join("truth.json"));
    assert_eq!(truth["scene"], "tiny");
    assert_eq!(truth["model"], "cook-torrance");
    assert_eq!(truth["ks"], serde_json::json!([25.0, 20.0, 7.0]));
    assert_eq!(truth["white_reflectance"], 0.99);

    let reference = std::fs::read_to_string(out.join("reference.csv")).unwrap();
    assert!(reference.starts_with("theta_i,theta_r,390,400,"));
    assert_eq!(reference.lines().count(), 1 + 33 * 33);

    for theta_l in ["-20.0", "-35.0"] {
        for (index, shutter) in [(0, 0.5), (1, 0.01)] {
            let stem = out.join(format!("theta_l_{theta_l}/exp_{index:02}"));
            let sidecar = json(&stem.with_extension("json"));
            assert_eq!(sidecar["shutter_s"], shutter);
            assert_eq!(sidecar["iso"], 100);
            assert_eq!(sidecar["theta_l"], theta_l.parse::<f64>().unwrap());
            assert_eq!(sidecar["camera"], "Tiny body");
            // The 12-bit counts are stored in the top 12 bits; levels in stored units.
            assert_eq!(sidecar["black_level"], 0);
            assert_eq!(sidecar["white_level"], 4095 * 16);
            assert_eq!(sidecar["significant_bits"], 12);
            assert!(sidecar.get("response").is_none());
            assert!(sidecar["time"].as_str().unwrap().contains('T'));
            let image = image::open(stem.with_extension("tiff")).unwrap();
            assert_eq!((image.width(), image.height()), (400, 120));
            let rgb = image.to_rgb16();
            // Between the strips: dark, only read noise.
            assert!(rgb.get_pixel(200, 60).0.iter().all(|v| *v <= 10 * 16));
            assert!(rgb.pixels().all(|p| p.0.iter().all(|v| v % 16 == 0)));
        }
    }
    // Longer exposures collect more light on the white strip.
    let long = image::open(out.join("theta_l_-20.0/exp_00.tiff"))
        .unwrap()
        .to_rgb16();
    let short = image::open(out.join("theta_l_-20.0/exp_01.tiff"))
        .unwrap()
        .to_rgb16();
    assert!(long.get_pixel(200, 89).0[1] > 10 * short.get_pixel(200, 89).0[1]);
    let leftovers: Vec<_> = std::fs::read_dir(out.join("theta_l_-20.0"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn theta_l_and_seed_override_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("tiny.toml");
    std::fs::write(&scene, tiny_scene()).unwrap();
    let run = |name: &str, seed: &str| {
        let out = dir.path().join(name);
        let args = [
            "--scene",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--theta-l",
            "-45,-30.5",
            "--seed",
            seed,
        ];
        let result = gonio(&args);
        assert!(
            result.status.success(),
            "{}",
            String::from_utf8_lossy(&result.stderr)
        );
        out
    };
    let a = run("a", "11");
    let mut dirs: Vec<_> = std::fs::read_dir(&a)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("theta_l_"))
        .collect();
    dirs.sort();
    assert_eq!(dirs, ["theta_l_-30.5", "theta_l_-45.0"]);
    let b = run("b", "11");
    let c = run("c", "12");
    let bytes = |d: &Path| std::fs::read(d.join("theta_l_-45.0/exp_00.tiff")).unwrap();
    assert_eq!(bytes(&a), bytes(&b));
    assert_ne!(bytes(&a), bytes(&c));
}

#[test]
fn bad_scenes_fail_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bad.toml");
    std::fs::write(
        &scene,
        tiny_scene().replace("focal_length_mm = 85.0", "focal_length_mm = -85.0"),
    )
    .unwrap();
    let out = dir.path().join("scan");
    let result = gonio(&[
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(stderr.contains("setup.focal_length_mm"), "{stderr}");
    assert!(!out.exists());

    let result = gonio(&["--scene", "silver", "--out", out.to_str().unwrap()]);
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.contains("silver") && stderr.contains("gold, red, blue-green"),
        "{stderr}"
    );

    // Two θL in one directory (named to 0.1°) would overwrite each other's captures.
    let result = gonio(&[
        "--scene",
        "gold",
        "--binning",
        "8",
        "--theta-l=-30,-30.02",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(stderr.contains("-30.02 is listed twice"), "{stderr}");
    // A binning too coarse for the scene's strips names the binning, not a scene key
    // the user never wrote.
    let result = gonio(&[
        "--scene",
        "gold",
        "--binning",
        "32",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        stderr.contains("32 is too coarse for this scene"),
        "{stderr}"
    );
    assert!(!out.exists());
}

#[test]
fn builtin_scene_with_binning() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("red");
    let result = gonio(&[
        "--scene",
        "red",
        "--out",
        out.to_str().unwrap(),
        "--binning",
        "8",
        "--theta-l",
        "-20",
    ]);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert_eq!(json(&out.join("truth.json"))["scene"], "red");
    let setup = json(&out.join("setup.json"));
    assert_eq!(
        (
            setup["image_width"].as_u64(),
            setup["image_height"].as_u64()
        ),
        (Some(484), Some(324))
    );
    let image = image::open(out.join("theta_l_-20.0/exp_00.tiff")).unwrap();
    assert_eq!((image.width(), image.height()), (484, 324));
    let sidecar = json(&out.join("theta_l_-20.0/exp_00.json"));
    assert!((sidecar["shutter_s"].as_f64().unwrap() - 1.0 / 15.0).abs() < 1e-12);
}
