//! Extraction of synthetic scans with a known Lambertian β.

use std::fs;
use std::path::Path;

use gonio_processing::capture::{self, CaptureError, Response, Sidecar};
use gonio_processing::color::CameraModel;
use gonio_processing::extract::{self, ExtractError, ExtractOptions, WhiteSource};
use gonio_processing::geometry::Setup;
use gonio_processing::samples::{self, Sample};
use gonio_processing::white_angular::WhiteTable;

const W: u32 = 64;
const H: u32 = 48;
const BRACKET: [f64; 3] = [0.01, 0.04, 0.16];
/// Camera-RGB β of the Lambertian sample.
const KD: [f64; 3] = [30.0, 50.0, 20.0];

fn setup() -> Setup {
    Setup {
        cylinder_radius_mm: 50.0,
        camera_distance_mm: 1000.0,
        light_distance_mm: 800.0,
        focal_length_mm: 50.0,
        pixel_pitch_um: 90.0,
        image_width: W,
        image_height: H,
        principal_point_x: None,
        sample_row: 14,
        white_row: 34,
        principal_point_y: None,
        white_reflectance: None,
        camera_offset_mm: 0.0,
        cylinder_tilt_deg: 0.0,
        arm_zero_offset_deg: 0.0,
        camera_yaw_deg: 0.0,
        camera_roll_deg: 0.0,
        // The synthetic white is Lambertian, and the setup says so.
        white_falloff: Some(0.0),
        white_angular: None,
        uncertainty: Default::default(),
    }
}

/// How one scan is made: the white's reflectance and radiance scale, per-θL brackets.
struct Scene {
    white_reflectance: f64,
    /// Radiance (normalised signal per second) of the white strip at θi = 0, per channel.
    white_level: [f64; 3],
    sample_scale: f64,
    /// Camera-RGB β of the Lambertian sample.
    kd: [f64; 3],
    /// setup.json's `white_reflectance`.
    recorded_white: Option<f64>,
    /// The white's falloff toward grazing as rendered: its radiance × (1 − a·(1 − cos θi)).
    white_falloff: f64,
    /// setup.json's `white_falloff` and `white_angular`.
    stated_falloff: Option<f64>,
    stated_table: Option<WhiteTable>,
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            white_reflectance: 1.0,
            white_level: [10.0, 12.0, 6.0],
            sample_scale: 1.0,
            kd: KD,
            recorded_white: None,
            white_falloff: 0.0,
            stated_falloff: Some(0.0),
            stated_table: None,
        }
    }
}

/// Writes setup.json and the TIFF captures of a Lambertian sample above a diffuse white.
fn write_scan(dir: &Path, theta_ls: &[f64], scene: &Scene) {
    let setup = Setup {
        white_reflectance: scene.recorded_white,
        white_falloff: scene.stated_falloff,
        white_angular: scene.stated_table.clone(),
        ..setup()
    };
    fs::write(
        dir.join("setup.json"),
        serde_json::to_string(&setup).unwrap(),
    )
    .unwrap();
    let white_rgb = CameraModel::builtin().white_rgb();
    let (black, white) = (512.0, 64_000.0);
    for &theta_l in theta_ls {
        let sub = dir.join(format!("theta_l_{theta_l:.1}"));
        fs::create_dir_all(&sub).unwrap();
        for (n, &t) in BRACKET.iter().enumerate() {
            let mut counts = Vec::with_capacity((W * H * 3) as usize);
            for y in 0..H {
                for x in 0..W {
                    // Irradiance cos θi/d² of the pixel's point, relative to 1 m.
                    let g = setup.pixel_geometry(f64::from(x), f64::from(y), theta_l);
                    let irradiance = g.map_or(0.0, |g| g.irradiance * 1e6);
                    let cos_i = g.map_or(1.0, |g| g.cosines.n_dot_l.clamp(0.0, 1.0));
                    let white_factor = 1.0 - scene.white_falloff * (1.0 - cos_i);
                    for (c, w) in white_rgb.iter().enumerate() {
                        // The white's radiance is ρ·PRD; the sample's is β/W_c times the PRD.
                        let prd = scene.white_level[c] * irradiance;
                        let radiance = if (24..44).contains(&y) {
                            prd * scene.white_reflectance * white_factor
                        } else {
                            prd * scene.kd[c] / w * scene.sample_scale
                        };
                        let signal = (radiance * t).min(1.0);
                        counts.push((black + signal * (white - black)).round() as u16);
                    }
                }
            }
            let sidecar = Sidecar {
                shutter_s: t,
                iso: Some(100.0),
                theta_l,
                camera: "synthetic".into(),
                time: "2026-11-23T15:00:00Z".into(),
                black_level: Some(black),
                white_level: Some(white),
                response: Response::Linear,
                significant_bits: None,
                aperture: None,
                width: Some(W),
                height: Some(H),
            };
            capture::write_tiff_capture(
                &sub.join(format!("exp_{n:02}.tiff")),
                W,
                H,
                &counts,
                &sidecar,
            )
            .unwrap();
        }
    }
}

fn assert_beta_is_kd(s: &Sample) {
    for (beta, kd) in s.rgb.iter().zip(KD) {
        assert!((beta - kd).abs() < 0.01 * kd, "{s:?}");
    }
}

#[test]
fn synthetic_lambertian_scan_gives_the_known_beta() {
    let dir = tempfile::tempdir().unwrap();
    let theta_ls = [-45.0, -20.0];
    write_scan(dir.path(), &theta_ls, &Scene::default());
    let hdr_dir = dir.path().join("hdr");
    let options = ExtractOptions {
        hdr_dir: Some(hdr_dir.clone()),
        ..ExtractOptions::default()
    };
    let progress = std::cell::RefCell::new(Vec::new());
    let extraction = extract::extract_scan_with_progress(dir.path(), &options, |done, total| {
        progress.borrow_mut().push((done, total))
    })
    .unwrap();
    assert_eq!(*progress.borrow(), vec![(0, 2), (1, 2), (2, 2)]);
    // Merging only the strip rows (no maps written) gives the same samples.
    let strips_only = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert_eq!(strips_only.samples, extraction.samples);
    // One θL alone gives exactly that θL's rows (the daemon extracts θL by θL).
    let one = ExtractOptions {
        theta_l: Some(-20.0),
        ..ExtractOptions::default()
    };
    let alone = extract::extract_scan(dir.path(), &one).unwrap();
    let rows: Vec<&Sample> = extraction
        .samples
        .iter()
        .filter(|s| s.theta_l == -20.0)
        .collect();
    assert_eq!(alone.samples.iter().collect::<Vec<_>>(), rows);
    assert!(!rows.is_empty() && rows.len() < extraction.samples.len());
    assert_eq!(extraction.per_theta.len(), 2);
    assert_eq!(extraction.per_theta[0].theta_l, -45.0);
    assert!(
        hdr_dir.join("theta_l_-45.0.exr").is_file() && hdr_dir.join("theta_l_-20.0.exr").is_file()
    );
    let setup = setup();
    for summary in &extraction.per_theta {
        assert_eq!(summary.frames, 3);
        assert_eq!(summary.samples + summary.dropped.total(), W as usize);
        assert!(summary.samples > 25, "{summary:?}");
        // Every column past the limit or off the cylinder is dropped as such.
        let (mut off, mut grazing) = (0, 0);
        for x in 0..W {
            match setup.angles_at_column(f64::from(x), summary.theta_l) {
                Some(a) if a.theta_i.abs() < 90.0 => {
                    grazing += usize::from(a.theta_i.abs() > 80.0 || a.theta_r.abs() > 80.0)
                }
                _ => off += 1,
            }
        }
        assert_eq!(
            (summary.dropped.off_cylinder, summary.dropped.grazing),
            (off, grazing),
            "{summary:?}"
        );
        assert_eq!(summary.dropped.no_channel, 0, "{summary:?}");
        for c in 0..3 {
            assert_eq!(summary.dropped.values(c), 0, "{summary:?}");
        }
    }
    for s in &extraction.samples {
        assert!(s.theta_i.abs() <= 80.0 && s.theta_r.abs() <= 80.0);
        // Lit points of one θL lie near θi + θr = θL (finite distances bend it a little).
        assert!((s.theta_i + s.theta_r - s.theta_l).abs() < 6.0, "{s:?}");
        assert_beta_is_kd(s);
    }
}

#[test]
fn one_theta_l_alone_is_its_rows_of_the_whole_scan_with_a_misaligned_setup() {
    // The 3D geometry of a misaligned setup (given as another setup file) and its
    // white reflectance apply to one θL alone exactly as to the whole scan.
    let dir = tempfile::tempdir().unwrap();
    write_scan(dir.path(), &[-45.0, -30.0, -20.0], &Scene::default());
    let misaligned = Setup {
        camera_offset_mm: 2.0,
        cylinder_tilt_deg: 0.4,
        arm_zero_offset_deg: 0.3,
        white_reflectance: Some(0.9),
        ..setup()
    };
    let setup_path = dir.path().join("calibrated.json");
    fs::write(&setup_path, serde_json::to_string(&misaligned).unwrap()).unwrap();
    let all_options = ExtractOptions {
        setup: Some(setup_path),
        ..ExtractOptions::default()
    };
    let all = extract::extract_scan(dir.path(), &all_options).unwrap();
    assert_eq!(all.white_source, WhiteSource::Setup);
    let mut pieced = Vec::new();
    for theta_l in [-45.0, -30.0, -20.0] {
        let one = ExtractOptions {
            theta_l: Some(theta_l),
            ..all_options.clone()
        };
        let alone = extract::extract_scan(dir.path(), &one).unwrap();
        assert_eq!(alone.per_theta.len(), 1);
        assert!(!alone.samples.is_empty(), "θL {theta_l}");
        pieced.extend(alone.samples);
    }
    assert_eq!(pieced, all.samples);
    // A θL the scan does not have is a clear error, not an empty result.
    let missing = ExtractOptions {
        theta_l: Some(-60.0),
        ..all_options
    };
    assert!(matches!(
        extract::extract_scan(dir.path(), &missing),
        Err(ExtractError::NoCaptures { .. })
    ));
}

#[test]
fn white_reflectance_scales_beta_and_is_validated() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Scene {
        white_reflectance: 0.8,
        ..Scene::default()
    };
    write_scan(dir.path(), &[-30.0], &scene);
    let options = ExtractOptions {
        white_reflectance: Some(0.8),
        ..ExtractOptions::default()
    };
    let extraction = extract::extract_scan(dir.path(), &options).unwrap();
    assert!(!extraction.samples.is_empty());
    for s in &extraction.samples {
        assert_beta_is_kd(s);
    }
    for bad in [0.0, -1.0, f64::NAN] {
        let options = ExtractOptions {
            white_reflectance: Some(bad),
            ..ExtractOptions::default()
        };
        assert!(matches!(
            extract::extract_scan(dir.path(), &options),
            Err(ExtractError::Options(_))
        ));
    }
}

#[test]
fn dark_white_reference_drops_columns_instead_of_dividing_by_zero() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Scene {
        white_level: [0.0; 3],
        ..Scene::default()
    };
    write_scan(dir.path(), &[-30.0], &scene);
    let extraction = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert!(extraction.samples.is_empty());
    let d = extraction.dropped;
    assert!(d.dark_white.iter().all(|&n| n > 25), "{d:?}");
    assert!(d.no_channel > 25, "{d:?}");
    assert_eq!(d.total(), W as usize);
}

#[test]
fn saturated_strips_are_dropped_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    // Sample 400× brighter than its β: clipped even in the shortest exposure where lit.
    let scene = Scene {
        sample_scale: 400.0,
        ..Scene::default()
    };
    write_scan(dir.path(), &[-30.0], &scene);
    let extraction = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert!(
        extraction.dropped.saturated.iter().all(|&n| n > 20),
        "{:?}",
        extraction.dropped
    );
    for s in &extraction.samples {
        assert!(s.rgb.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn grazing_limit_is_configurable() {
    let dir = tempfile::tempdir().unwrap();
    write_scan(dir.path(), &[-30.0], &Scene::default());
    let options = ExtractOptions {
        grazing_limit_deg: 40.0,
        ..ExtractOptions::default()
    };
    let extraction = extract::extract_scan(dir.path(), &options).unwrap();
    let all = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert!(extraction.samples.len() < all.samples.len());
    assert!(extraction
        .samples
        .iter()
        .all(|s| s.theta_i.abs() <= 40.0 && s.theta_r.abs() <= 40.0));
}

#[test]
fn scan_directory_problems_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let err = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap_err();
    assert!(
        matches!(err, ExtractError::Setup { .. }) && err.to_string().contains("setup.json"),
        "{err}"
    );

    fs::write(
        dir.path().join("setup.json"),
        r#"{"cylinder_radius_mm": 50}"#,
    )
    .unwrap();
    let err = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap_err();
    assert!(err.to_string().contains("camera_distance_mm"), "{err}");

    let mut bad = setup();
    bad.camera_distance_mm = 10.0;
    fs::write(
        dir.path().join("setup.json"),
        serde_json::to_string(&bad).unwrap(),
    )
    .unwrap();
    assert!(matches!(
        extract::extract_scan(dir.path(), &ExtractOptions::default()),
        Err(ExtractError::Geometry { .. })
    ));

    fs::write(
        dir.path().join("setup.json"),
        serde_json::to_string(&setup()).unwrap(),
    )
    .unwrap();
    // An image without a sidecar is skipped, and then there is nothing to extract.
    fs::write(dir.path().join("stray.tiff"), b"x").unwrap();
    assert!(matches!(
        extract::extract_scan(dir.path(), &ExtractOptions::default()),
        Err(ExtractError::NoCaptures { .. })
    ));

    write_scan(dir.path(), &[-30.0], &Scene::default());
    let extraction = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert_eq!(
        extraction.skipped_without_sidecar,
        vec![dir.path().join("stray.tiff")]
    );

    // A sidecar that contradicts its image stops the extraction and names the file.
    let side = dir.path().join("theta_l_-30.0/exp_01.json");
    let text = fs::read_to_string(&side)
        .unwrap()
        .replace("\"width\": 64", "\"width\": 640");
    fs::write(&side, text).unwrap();
    match extract::extract_scan(dir.path(), &ExtractOptions::default()) {
        Err(ExtractError::Capture(CaptureError::InvalidSidecar { path, field, .. })) => {
            assert_eq!((path, field), (side, "width"));
        }
        other => panic!("expected InvalidSidecar, got {other:?}"),
    }
}

#[test]
fn captures_of_another_size_than_the_setup_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    write_scan(dir.path(), &[-30.0], &Scene::default());
    let mut other = setup();
    other.image_width = 100;
    fs::write(
        dir.path().join("setup.json"),
        serde_json::to_string(&other).unwrap(),
    )
    .unwrap();
    assert!(matches!(
        extract::extract_scan(dir.path(), &ExtractOptions::default()),
        Err(ExtractError::SizeMismatch { .. })
    ));
    let mut rows = setup();
    rows.white_row = 47;
    fs::write(
        dir.path().join("setup.json"),
        serde_json::to_string(&rows).unwrap(),
    )
    .unwrap();
    assert!(matches!(
        extract::extract_scan(dir.path(), &ExtractOptions::default()),
        Err(ExtractError::RowOutside { which: "white", .. })
    ));
    // The white strip on the sample's rows: the sample would be measured against itself.
    let mut overlapping = setup();
    overlapping.white_row = overlapping.sample_row + 2;
    fs::write(
        dir.path().join("setup.json"),
        serde_json::to_string(&overlapping).unwrap(),
    )
    .unwrap();
    let err = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap_err();
    assert!(
        matches!(err, ExtractError::StripsOverlap { rows: 5, .. })
            && err.to_string().contains("overlap"),
        "{err}"
    );
}

#[test]
fn white_reflectance_comes_from_setup_json_and_the_option_overrides_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Scene {
        white_reflectance: 0.8,
        recorded_white: Some(0.8),
        ..Scene::default()
    };
    write_scan(dir.path(), &[-30.0], &scene);
    let extraction = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert_eq!(
        (extraction.white_reflectance, extraction.white_source),
        (0.8, WhiteSource::Setup)
    );
    assert!(extraction.samples.len() > 25);
    extraction.samples.iter().for_each(assert_beta_is_kd);
    // The option overrides setup.json: β scales with it.
    let options = ExtractOptions {
        white_reflectance: Some(0.4),
        ..ExtractOptions::default()
    };
    let halved = extract::extract_scan(dir.path(), &options).unwrap();
    assert_eq!(halved.white_source, WhiteSource::Option);
    for (h, s) in halved.samples.iter().zip(&extraction.samples) {
        for c in 0..3 {
            assert!((h.rgb[c] - 0.5 * s.rgb[c]).abs() < 1e-9 * s.rgb[c]);
        }
    }
    // A setup.json without it: a perfect diffuser is assumed, and said so.
    write_scan(dir.path(), &[-30.0], &Scene::default());
    let assumed = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    assert_eq!(
        (assumed.white_reflectance, assumed.white_source),
        (1.0, WhiteSource::Assumed)
    );
}

#[test]
fn a_channel_below_the_noise_floor_is_dropped_not_written_as_zero() {
    let dir = tempfile::tempdir().unwrap();
    // Blue far below the noise floor in every exposure; red and green well exposed.
    let scene = Scene {
        kd: [30.0, 50.0, 1e-4],
        ..Scene::default()
    };
    write_scan(dir.path(), &[-30.0], &scene);
    let extraction = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
    let d = extraction.dropped;
    assert!(extraction.samples.len() > 25, "{d:?}");
    assert_eq!(d.underexposed[2], extraction.samples.len(), "{d:?}");
    assert_eq!(
        (d.underexposed[0], d.underexposed[1], d.no_channel),
        (0, 0, 0)
    );
    for s in &extraction.samples {
        assert_eq!(s.dropped, [false, false, true], "{s:?}");
        assert_eq!(s.channel(2), None);
        for c in 0..2 {
            assert!((s.rgb[c] - scene.kd[c]).abs() < 0.01 * scene.kd[c], "{s:?}");
        }
    }
    // Written as an empty field, read back as dropped.
    let mut text = Vec::new();
    samples::write_csv_to(&mut text, &extraction.samples).unwrap();
    let text = String::from_utf8(text).unwrap();
    let row = text.lines().nth(1).unwrap();
    let fields: Vec<&str> = row.split(',').collect();
    assert_eq!(fields[5], "", "{row}");
    // Read back as extracted: the extraction states its uncertainties to the 6
    // significant digits the file holds.
    assert_eq!(
        samples::read_csv_from(text.as_bytes()).unwrap(),
        extraction.samples
    );
}

#[test]
fn the_white_falloff_or_table_setup_json_states_is_divided_out() {
    // A white 4 % darker at grazing: β comes out as the sample's kd when setup.json
    // states that falloff or a certificate's table of it, and low toward grazing when it
    // states a Lambertian white.
    let falloff = 0.04;
    let theta: Vec<f64> = (0..=9).map(|k| 10.0 * f64::from(k)).collect();
    let table = WhiteTable {
        factor: theta
            .iter()
            .map(|t: &f64| 1.0 - falloff * (1.0 - t.to_radians().cos()))
            .collect(),
        u: vec![0.01; theta.len()],
        theta_i_deg: theta,
    };
    for (stated_falloff, stated_table, holds) in [
        (Some(falloff), None, true),
        (None, Some(table), true),
        (Some(0.0), None, false),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let scene = Scene {
            white_falloff: falloff,
            stated_falloff,
            stated_table,
            ..Scene::default()
        };
        write_scan(dir.path(), &[-30.0], &scene);
        let extraction = extract::extract_scan(dir.path(), &ExtractOptions::default()).unwrap();
        assert!(extraction.samples.len() > 25);
        let worst = extraction
            .samples
            .iter()
            .flat_map(|s| (0..3).map(move |c| (s.rgb[c] - KD[c]).abs() / KD[c]))
            .fold(0.0f64, f64::max);
        if holds {
            // Linear interpolation of the table between 10° rows: within 0.1 %.
            for s in &extraction.samples {
                assert_beta_is_kd(s);
            }
            let u = extraction.samples[0].uncertainty.unwrap().sources;
            assert!(u.iter().all(|c| c.iter().all(|v| v.is_finite())));
        } else {
            assert!(worst > 0.015, "a Lambertian white stated: worst {worst}");
        }
    }
}
