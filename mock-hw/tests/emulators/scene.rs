//! Scene files: built-ins, validation errors that name the key, truth and setup JSON,
//! and the camera-RGB domain.

use gonio_mock_hw::scene::{Sample, Scene, SceneError};

const SMALL: &str = include_str!("../scene_small.toml");
const CT: &str =
    "[sample]\nmodel = \"cook-torrance\"\nkd = [10.0, 8.0, 3.0]\nks = [2.0, 1.5, 0.5]\nm = [0.1]\n";

fn small(extra: &str) -> Result<Scene, SceneError> {
    Scene::from_toml_str(&format!("{SMALL}\n{extra}"))
}

fn error_text(toml: &str) -> String {
    match Scene::from_toml_str(toml) {
        Ok(_) => panic!("scene was accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn builtin_scenes_are_realistic() {
    for name in Scene::BUILTIN {
        let scene = Scene::builtin(name).expect(name);
        assert_eq!(scene.name(), name);
        assert_eq!(
            scene.theta_l_deg(),
            &[-20.0, -25.0, -30.0, -35.0, -40.0, -45.0]
        );
        let s = scene.setup();
        assert_eq!((s.image_width, s.image_height), (3872, 2592));
        assert_eq!(s.pixel_pitch_um, 6.1);
        assert!(scene.bracket_s().iter().all(|t| (0.01..=0.5).contains(t)));
    }
    assert!(Scene::builtin("silver").is_none());
    let gold = Scene::builtin("gold").unwrap();
    assert_eq!(gold.bracket_s().len(), 4);
    match gold.sample() {
        Sample::CookTorrance { kd, ks, m } => {
            assert!(m[0] >= 0.05 && m[0] <= 0.1);
            assert!(ks[0] > kd[0] && ks[0] > ks[2], "strong yellowish specular");
        }
        other => panic!("gold is {other:?}"),
    }
    assert!(matches!(
        Scene::builtin("red").unwrap().sample(),
        Sample::CookTorrance { m, .. } if (m[0] - 0.4).abs() < 0.1
    ));
    assert!(Scene::builtin("blue-green").unwrap().sample().is_spectral());
    assert!(matches!(
        Scene::builtin("opal").unwrap().sample(),
        Sample::BraggFlakes(_)
    ));
}

#[test]
fn white_is_100_in_green_and_spectra_round_trip() {
    let scene = small(CT).unwrap();
    let domain = scene.camera_domain();
    let white = domain.white_rgb();
    assert!((white[1] - 100.0).abs() < 1e-9);
    // Tungsten light through the D5100: red above blue.
    assert!(white[0] > white[2]);
    for rgb in [[10.0, 20.0, 30.0], [80.0, 5.0, 1.0], white] {
        let back = domain.rgb(&domain.spectrum_from_rgb(rgb));
        for c in 0..3 {
            assert!((back[c] - rgb[c]).abs() < 1e-9, "{back:?} vs {rgb:?}");
        }
    }
}

#[test]
fn unknown_keys_are_named() {
    let text = format!("{SMALL}\n{CT}").replace("cylinder_radius_mm", "cylinder_radus_mm");
    let err = error_text(&text);
    assert!(err.contains("cylinder_radus_mm"), "{err}");
    let text = format!("{SMALL}\n{CT}").replace("image_width = 400", "image_width = \"big\"");
    let err = error_text(&text);
    assert!(err.contains("image_width") && err.contains("line"), "{err}");
    let err = error_text(&format!("{SMALL}\n{CT}shininess = 3\n"));
    assert!(err.contains("shininess"), "{err}");
    let err = error_text(&format!("{SMALL}\n{CT}\n[effects.blur]\nradius = 2\n"));
    assert!(err.contains("blur"), "{err}");
    let err = error_text(&format!(
        "{SMALL}\n[sample]\nmodel = \"phong\"\nkd = [1.0, 1.0, 1.0]\n"
    ));
    assert!(err.contains("phong"), "{err}");
}

#[test]
fn bad_values_are_named() {
    let cases = [
        (
            "cylinder_radius_mm = 40.0",
            "cylinder_radius_mm = -1.0",
            "setup.cylinder_radius_mm",
        ),
        (
            "white_rows = [79, 99]",
            "white_rows = [30, 50]",
            "setup.white_rows",
        ),
        (
            "sample_rows = [20, 40]",
            "sample_rows = [20, 400]",
            "setup.sample_rows",
        ),
        ("bracket_s = [0.01]", "bracket_s = []", "scan.bracket_s"),
        (
            "theta_l_deg = [-30.0]",
            "theta_l_deg = [-130.0]",
            "scan.theta_l_deg",
        ),
        (
            "reflectance = 0.9",
            "reflectance = 0.0",
            "white.reflectance",
        ),
        (
            "white_level = 65535",
            "white_level = 70000",
            "camera.white_level",
        ),
        ("bit_depth = 16", "bit_depth = 4", "camera.bit_depth"),
        (
            "image_width = 400\nimage_height = 120",
            "image_width = 20000\nimage_height = 20000",
            "400000000 pixels, more than the 100000000 gonio decodes",
        ),
        (
            "intensity = 2000000.0",
            "intensity = nan",
            "light.intensity",
        ),
    ];
    for (from, to, key) in cases {
        let text = format!("{SMALL}\n{CT}").replace(from, to);
        let err = error_text(&text);
        assert!(err.contains(key), "{to}: {err}");
    }
    let err = error_text(&format!("{SMALL}\n{}", CT.replace("[0.1]", "[0.1, 0.2]")));
    assert!(err.contains("sample.m"), "{err}");
    let err = error_text(&format!(
        "{SMALL}\n{}",
        CT.replace("ks = [2.0", "ks = [-2.0")
    ));
    assert!(err.contains("sample.ks"), "{err}");
    let err = error_text(&format!(
        "{SMALL}\n{CT}\n[effects.noise]\nelectrons_per_dn = 0.0\nread_noise_dn = 1.0\n"
    ));
    assert!(err.contains("effects.noise.electrons_per_dn"), "{err}");
    for (line, key) in [
        (
            "cylinder_tilt_deg = 45.0",
            "effects.misalignment.cylinder_tilt_deg",
        ),
        (
            "camera_yaw_deg = nan",
            "effects.misalignment.camera_yaw_deg",
        ),
        (
            "camera_roll_deg = 12.0",
            "effects.misalignment.camera_roll_deg",
        ),
        ("white_falloff = 0.6", "effects.misalignment.white_falloff"),
        (
            "camera_offset_mm = 500.0",
            "effects.misalignment.camera_offset_mm",
        ),
        (
            "light_distance_error_mm = -990.0",
            "effects.misalignment.light_distance_error_mm",
        ),
        (
            "white_reflectance_error = -1.0",
            "effects.misalignment.white_reflectance_error",
        ),
        (
            // 0.9 × 2.5 renders a white above 2.
            "white_reflectance_error = 1.5",
            "effects.misalignment.white_reflectance_error",
        ),
        (
            "camera_distance_error_mm = -400.0",
            "effects.misalignment.camera_distance_error_mm",
        ),
        (
            "camera_distance_error_mm = inf",
            "effects.misalignment.camera_distance_error_mm",
        ),
        (
            // The scan has one light angle.
            "arm_angle_errors_deg = [0.1, 0.2]",
            "effects.misalignment.arm_angle_errors_deg",
        ),
        (
            "arm_angle_errors_deg = [11.0]",
            "effects.misalignment.arm_angle_errors_deg",
        ),
        ("camera_pitch_deg = 1.0", "camera_pitch_deg"),
    ] {
        let err = error_text(&format!("{SMALL}\n{CT}\n[effects.misalignment]\n{line}\n"));
        assert!(err.contains(key), "{line}: {err}");
    }
    let mut errors = small(&format!(
        "{CT}\n[effects.misalignment]\narm_angle_errors_deg = [0.1]\n"
    ))
    .unwrap();
    assert!(errors.set_theta_l_deg(vec![-20.0, -30.0]).is_err());
    assert!(errors.set_theta_l_deg(vec![-20.0]).is_ok());
    let err = error_text(
        &format!("{SMALL}\n{CT}").replace("\"nikon-d5100\"", "\"/nonexistent/sens.csv\""),
    );
    assert!(err.contains("/nonexistent/sens.csv"), "{err}");
    let err = error_text(&format!("{SMALL}\n{CT}").replace("name = \"small\"\n", ""));
    assert!(err.contains("name"), "{err}");
    let flakes = "[sample]\nmodel = \"bragg-flakes\"\nkd = [3.0, 4.0, 8.0]\nks = 0.5\nm = 0.12\n\
                  wavelength_nm = 600.0\neffective_index = 1.35\nband_width_nm = 30.0\n";
    assert!(small(flakes).is_ok());
    for (from, to, key) in [
        (
            "effective_index = 1.35",
            "effective_index = 0.9",
            "sample.effective_index",
        ),
        (
            "wavelength_nm = 600.0",
            "wavelength_nm = 60.0",
            "sample.wavelength_nm",
        ),
        (
            "band_width_nm = 30.0",
            "band_width_nm = 0.0",
            "sample.band_width_nm",
        ),
        ("m = 0.12", "m = 0.0", "sample.m"),
        ("ks = 0.5", "ks = 0.5\nshininess = 3", "shininess"),
    ] {
        let err = error_text(&format!("{SMALL}\n{}", flakes.replace(from, to)));
        assert!(err.contains(key), "{to}: {err}");
    }
}

#[test]
fn bad_tables_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let sens = dir.path().join("sens.csv");
    std::fs::write(&sens, "wavelength_nm,r,g,b\n390,0,0,0\n400,0,x,0\n").unwrap();
    let text = format!("{SMALL}\n{CT}").replace("\"nikon-d5100\"", &format!("{:?}", sens));
    let err = error_text(&text);
    assert!(err.contains("sens.csv") && err.contains("line 3"), "{err}");

    let table = dir.path().join("measured.csv");
    std::fs::write(&table, "theta_i,theta_r,390\n0,0,1\n").unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::write(
        &scene,
        format!("{SMALL}\n[sample]\nmodel = \"measured\"\npath = \"measured.csv\"\n"),
    )
    .unwrap();
    let err = Scene::load(&scene).unwrap_err().to_string();
    assert!(
        err.contains("measured.csv") && err.contains("line 2"),
        "{err}"
    );
    // An endless file is read only up to the cap, for the measured table and for a
    // spectral one alike.
    for (from, to) in [
        ("path = \"measured.csv\"", "path = \"/dev/zero\""),
        ("\"nikon-d5100\"", "\"/dev/zero\""),
    ] {
        let text = format!("{SMALL}\n[sample]\nmodel = \"measured\"\npath = \"measured.csv\"\n")
            .replace(from, to);
        std::fs::write(&scene, text).unwrap();
        let err = Scene::load(&scene).unwrap_err().to_string();
        assert!(
            err.contains("/dev/zero") && err.contains("not a regular file (a character device)"),
            "{err}"
        );
    }
}

#[test]
fn truth_and_setup_json() {
    let scene = small(CT).unwrap();
    let truth = scene.truth_json();
    assert_eq!(truth["scene"], "small");
    assert_eq!(truth["model"], "cook-torrance");
    assert_eq!(truth["roughness"], "shared");
    assert_eq!(truth["kd"], serde_json::json!([10.0, 8.0, 3.0]));
    assert_eq!(truth["ks"], serde_json::json!([2.0, 1.5, 0.5]));
    assert_eq!(truth["m"], serde_json::json!([0.1]));
    assert_eq!(truth["white_reflectance"], 0.9);
    let per_channel = small(&CT.replace("[0.1]", "[0.1, 0.2, 0.3]")).unwrap();
    assert_eq!(per_channel.truth_json()["roughness"], "per-channel");

    assert!(truth.get("misalignment").is_none());
    let misaligned = small(&format!(
        "{CT}\n[effects.misalignment]\ncamera_offset_mm = 3.0\narm_zero_offset_deg = 0.3\n"
    ))
    .unwrap();
    let stated = misaligned.truth_json()["misalignment"].clone();
    assert_eq!(stated["camera_offset_mm"], 3.0);
    assert_eq!(stated["arm_zero_offset_deg"], 0.3);
    assert_eq!(stated["cylinder_tilt_deg"], 0.0);
    assert_eq!(stated["white_reflectance_error"], 0.0);
    assert_eq!(stated["camera_distance_error_mm"], 0.0);
    assert_eq!(stated["arm_angle_errors_deg"], serde_json::json!([]));
    let errors = small(&format!(
        "{CT}\n[effects.misalignment]\nwhite_reflectance_error = 0.02\n\
         camera_distance_error_mm = -1.5\narm_angle_errors_deg = [0.05]\n"
    ))
    .unwrap();
    let stated = errors.truth_json()["misalignment"].clone();
    assert_eq!(stated["white_reflectance_error"], 0.02);
    assert_eq!(stated["camera_distance_error_mm"], -1.5);
    assert_eq!(stated["arm_angle_errors_deg"], serde_json::json!([0.05]));
    assert_eq!(errors.setup_json(), scene.setup_json());
    // setup.json states the nominal setup, whatever the misalignment.
    assert_eq!(misaligned.setup_json(), scene.setup_json());

    let setup = scene.setup_json();
    let keys: Vec<&str> = setup
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(
        keys,
        [
            "camera_distance_mm",
            "cylinder_radius_mm",
            "focal_length_mm",
            "image_height",
            "image_width",
            "light_distance_mm",
            "pixel_pitch_um",
            "principal_point_x",
            "principal_point_y",
            "sample_row",
            "white_falloff",
            "white_reflectance",
            "white_row"
        ]
    );
    assert_eq!(setup["white_reflectance"], 0.9);
    assert_eq!(setup["sample_row"], 30);
    assert_eq!(setup["white_row"], 89);
}

/// The small scene with `table` as its `[setup.uncertainty]`.
fn with_uncertainty(table: &str) -> String {
    format!("{SMALL}\n{CT}").replace(
        "\n[scan]",
        &format!("\n[setup.uncertainty]\n{table}\n\n[scan]"),
    )
}

#[test]
fn setup_uncertainty_is_stated_in_setup_json() {
    let scene = Scene::from_toml_str(&with_uncertainty(
        "white_reflectance = [0.01, 0.004, 0.006]\ncamera_offset_mm = 0.2\n\
         camera_distance_mm = 0.8\nlight_distance_mm = 3.0\ncylinder_tilt_deg = 0.05\n\
         arm_zero_offset_deg = 0.02\narm_angle_deg = 0.001",
    ))
    .unwrap();
    assert_eq!(
        scene.setup_json()["uncertainty"],
        serde_json::json!({
            "white_reflectance": [0.01, 0.004, 0.006], "camera_offset_mm": 0.2,
            "camera_distance_mm": 0.8, "light_distance_mm": 3.0, "cylinder_tilt_deg": 0.05,
            "arm_zero_offset_deg": 0.02, "arm_angle_deg": 0.001,
        })
    );
    // Only what the table names; binning keeps it.
    let one = Scene::from_toml_str(&with_uncertainty("white_reflectance = 0.003")).unwrap();
    let expected = serde_json::json!({ "white_reflectance": 0.003 });
    assert_eq!(one.setup_json()["uncertainty"], expected);
    assert_eq!(one.binned(2).unwrap().setup_json()["uncertainty"], expected);
    // No table, no block.
    assert!(small(CT).unwrap().setup_json().get("uncertainty").is_none());
    // The white's falloff: Lambertian unless `[white]` states one; stated as rendered.
    assert_eq!(small(CT).unwrap().setup_json()["white_falloff"], 0.0);
    let falloff = format!("{SMALL}\n{CT}").replace(
        "[white]\nreflectance = 0.9",
        "[white]\nreflectance = 0.9\nfalloff = 0.02",
    );
    let scene = Scene::from_toml_str(&falloff).unwrap();
    assert_eq!(scene.setup_json()["white_falloff"], 0.02);
    assert_eq!(scene.rendered_white_falloff(), 0.02);
    let bad = Scene::from_toml_str(&falloff.replace("falloff = 0.02", "falloff = nan"))
        .unwrap_err()
        .to_string();
    assert!(bad.contains("white.falloff"), "{bad}");
    for (line, key) in [
        (
            "camera_offset_mm = -0.1",
            "setup.uncertainty.camera_offset_mm",
        ),
        ("arm_angle_deg = nan", "setup.uncertainty.arm_angle_deg"),
        (
            "light_distance_mm = 101.0",
            "setup.uncertainty.light_distance_mm",
        ),
        (
            "white_reflectance = [0.01, -0.01, 0.01]",
            "setup.uncertainty.white_reflectance",
        ),
        (
            "camera_roll_deg = -0.1",
            "setup.uncertainty.camera_roll_deg",
        ),
        ("camera_pitch_deg = 0.1", "camera_pitch_deg"),
    ] {
        let err = error_text(&with_uncertainty(line));
        assert!(err.contains(key), "{line}: {err}");
    }
}

#[test]
fn binning_keeps_the_geometry() {
    let gold = Scene::builtin("gold").unwrap();
    let small = gold.binned(8).unwrap();
    let (a, b) = (gold.setup(), small.setup());
    assert_eq!((b.image_width, b.image_height), (484, 324));
    assert_eq!(b.pixel_pitch_um, 8.0 * a.pixel_pitch_um);
    assert_eq!(b.sample_rows, [137, 160]);
    // The sensor spans the same angle of view.
    let span = |s: &gonio_mock_hw::scene::SceneSetup| f64::from(s.image_width) * s.pixel_pitch_um;
    assert!((span(a) - span(b)).abs() <= 8.0 * a.pixel_pitch_um);
    assert_eq!(small.truth_json(), gold.truth_json());
    assert!(gold.binned(0).is_err());
    assert!(gold.binned(5000).is_err());
}
