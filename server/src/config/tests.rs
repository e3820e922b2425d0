use super::*;

#[test]
fn empty_config_runs_on_emulators() {
    let config = Config::from_toml_str("").unwrap();
    assert_eq!(config.arm.kind, ArmKind::Emulator);
    assert_eq!(config.arm.homing, HomingMode::Required);
    assert!(matches!(config.camera, CameraConfig::Emulator { ref scene, .. } if scene == "gold"));
    assert_eq!(config.bind.port(), 8080);
}

#[test]
fn a_camera_table_without_its_kind_is_the_emulator_s() {
    let config = Config::from_toml_str("[camera]\nscene = \"red\"\nsample = \"red\"\n").unwrap();
    assert!(matches!(config.camera, CameraConfig::Emulator { ref scene, .. } if scene == "red"));
    let err = Config::from_toml_str("[camera]\nscene = \"red\"\nsceen = 1\n").unwrap_err();
    assert!(format!("{err:#}").contains("sceen"), "{err:#}");
    let err = Config::from_toml_str("[camera]\nkind = \"nikon\"\n").unwrap_err();
    assert!(format!("{err:#}").contains("nikon"), "{err:#}");
}

#[test]
fn the_example_s_notify_section_parses_once_uncommented() {
    let example = include_str!("../../assets/gonio.example.toml");
    let notify: String = example
        .lines()
        .skip_while(|l| !l.starts_with("# [notify]"))
        .take_while(|l| l.starts_with('#'))
        .filter(|l| !l.starts_with("#   ") && !l.starts_with("#    "))
        .map(|l| l.trim_start_matches("# "))
        .collect::<Vec<_>>()
        .join("\n");
    let config = Config::from_toml_str(&notify).unwrap();
    let notify = config.notify.expect("[notify]");
    assert!(notify.command.contains("mail") && notify.command.contains("$GONIO_REASON"));
    assert_eq!(notify.timeout_s, 30.0);
    let err = Config::from_toml_str("[notify]\ncommand = \"true\"\ntimeout_s = 0\n").unwrap_err();
    assert!(err.to_string().contains("notify.timeout_s"), "{err}");
}

#[test]
fn example_config_parses_to_the_defaults() {
    let example = Config::from_toml_str(include_str!("../../assets/gonio.example.toml")).unwrap();
    let default = Config::default();
    assert_eq!(example.bind, default.bind);
    assert_eq!(example.data_dir, default.data_dir);
    assert_eq!(example.retry.attempts, default.retry.attempts);
    assert_eq!(example.arm.kind, default.arm.kind);
    assert_eq!(example.arm.time_scale, default.arm.time_scale);
    assert_eq!(example.arm.steps_per_deg, default.arm.steps_per_deg);
    assert_eq!(example.arm.max_travel_deg, default.arm.max_travel_deg);
    assert_eq!(example.arm.homing, default.arm.homing);
    assert_eq!(example.arm.axis, default.arm.axis);
    assert_eq!(example.arm.apply_settings, default.arm.apply_settings);
    assert_eq!(example.arm.reply_timeout_s, default.arm.reply_timeout_s);
    assert_eq!(example.limits.max_deg, default.limits.max_deg);
}

#[test]
fn grbl_arm_needs_a_path() {
    let err = Config::from_toml_str("[arm]\nkind = \"grbl\"\n").unwrap_err();
    assert!(format!("{err:#}").contains("path"), "{err:#}");
    let config = Config::from_toml_str(
        "[arm]\nkind = \"grbl\"\npath = \"/dev/ttyUSB0\"\nhoming = \"off\"\naxis = \"y\"\n",
    )
    .unwrap();
    assert_eq!(config.arm.kind, ArmKind::Grbl);
    assert_eq!(config.arm.homing, HomingMode::Off);
    assert_eq!(config.arm.axis(), ArmAxis::Y);
    for (text, named) in [
        ("[arm]\nhoming = \"sometimes\"\n", "homing"),
        ("[arm]\naxis = \"A\"\n", "arm.axis"),
        ("[arm]\nsteps_per_deg = 0\n", "arm.steps_per_deg"),
        ("[arm]\nreply_timeout_s = 0.05\n", "arm.reply_timeout_s"),
        ("[arm]\nreply_timeout_s = 61\n", "arm.reply_timeout_s"),
        ("[arm]\nreply_timeout_s = nan\n", "arm.reply_timeout_s"),
        ("[arm]\nreply_timeout_s = inf\n", "arm.reply_timeout_s"),
        (
            "[arm]\nkind = \"grbl\"\npath = \"/x\"\nboard = \"b.toml\"\n",
            "board",
        ),
    ] {
        let err = Config::from_toml_str(text).unwrap_err();
        assert!(format!("{err:#}").contains(named), "{text}: {err:#}");
    }
}

#[test]
fn a_carousel_names_its_axis_and_slots() {
    let config =
        Config::from_toml_str("[carousel]\naxis = \"y\"\nslots = { gold = -10.0, red = -100.0 }\n")
            .unwrap();
    let carousel = config.carousel.unwrap();
    assert_eq!(carousel.axis(), ArmAxis::Y);
    assert_eq!(carousel.slot("red"), Some(-100.0));
    assert_eq!(carousel.slot("teal"), None);
    assert!(carousel.check_travel(100.0).is_ok());
    let err = carousel.check_travel(90.0).unwrap_err().to_string();
    assert!(err.contains("carousel.slots.red = -100"), "{err}");
    for (text, named) in [
        (
            "[carousel]\naxis = \"X\"\nslots = { a = -1.0 }\n",
            "arm's axis",
        ),
        (
            "[carousel]\naxis = \"Q\"\nslots = { a = -1.0 }\n",
            "carousel.axis",
        ),
        ("[carousel]\naxis = \"Y\"\nslots = {}\n", "carousel.slots"),
        (
            "[carousel]\naxis = \"Y\"\nslots = { a = 5.0 }\n",
            "carousel.slots.a",
        ),
        (
            "[arm]\nhoming = \"off\"\n[carousel]\naxis = \"Y\"\nslots = { a = -1.0 }\n",
            "homing",
        ),
        (
            "[carousel]\naxis = \"Y\"\nslots = { \"../a\" = -1.0 }\n",
            "\"../a\" is not a sample name",
        ),
        (
            "[carousel]\naxis = \"Y\"\nslots = { \"a b\" = -1.0 }\n",
            "\"a b\" is not a sample name",
        ),
    ] {
        let err = Config::from_toml_str(text).unwrap_err();
        assert!(format!("{err:#}").contains(named), "{text}: {err:#}");
    }
}

#[test]
fn setup_uncertainty_is_read_checked_and_named() {
    let setup = "[setup]\ncylinder_radius_mm = 40.0\ncamera_distance_mm = 700.0\n\
        light_distance_mm = 1000.0\nfocal_length_mm = 85.0\npixel_pitch_um = 6.1\n\
        image_width = 3872\nimage_height = 2592\nsample_row = 1100\nwhite_row = 1491\n";
    let config = Config::from_toml_str(&format!(
        "{setup}[setup.uncertainty]\nwhite_reflectance = 0.004\ncamera_offset_mm = 0.3\n"
    ))
    .unwrap();
    let uncertainty = config.setup().unwrap().uncertainty;
    assert_eq!(uncertainty.camera_offset_mm, Some(0.3));
    assert_eq!(
        uncertainty.white_reflectance.map(|w| w.per_channel()),
        Some([0.004; 3])
    );
    assert_eq!(uncertainty.arm_angle_deg, None);
    assert!(Config::from_toml_str(setup)
        .unwrap()
        .setup()
        .unwrap()
        .uncertainty
        .is_empty());
    for (table, named) in [
        ("cylinder_tilt_deg = -0.1", "uncertainty.cylinder_tilt_deg"),
        ("arm_angle_deg = 1000.0", "uncertainty.arm_angle_deg"),
        ("yaw_deg = 0.1", "yaw_deg"),
    ] {
        let err =
            Config::from_toml_str(&format!("{setup}[setup.uncertainty]\n{table}\n")).unwrap_err();
        assert!(format!("{err:#}").contains(named), "{table}: {err:#}");
    }
}

#[test]
fn unknown_keys_and_bad_limits_are_named() {
    let err = Config::from_toml_str("bogus = 1\n").unwrap_err();
    assert!(format!("{err:#}").contains("bogus"), "{err:#}");
    let err = Config::from_toml_str("[limits]\nmin_deg = 0\nmax_deg = -10\n").unwrap_err();
    assert!(format!("{err:#}").contains("min_deg"), "{err:#}");
}
