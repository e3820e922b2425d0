//! Reading captures: TIFF + sidecar, levels, and every kind of bad input.

use std::fs;
use std::path::Path;

use gonio_processing::capture::{self, CaptureError, Frame, Response, Sidecar};

fn sidecar() -> Sidecar {
    Sidecar {
        shutter_s: 0.01,
        iso: Some(200.0),
        theta_l: -20.0,
        camera: "test".into(),
        time: "2026-11-23T14:00:00Z".into(),
        black_level: None,
        white_level: None,
        response: Response::Linear,
        significant_bits: None,
        aperture: None,
        width: None,
        height: None,
    }
}

fn counts(width: u32, height: u32) -> Vec<u16> {
    (0..width * height * 3)
        .map(|i| (i * 997 % 65_536) as u16)
        .collect()
}

#[test]
fn tiff_and_sidecar_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("exp_00.tiff");
    let data = counts(8, 5);
    capture::write_tiff_capture(&path, 8, 5, &data, &sidecar()).unwrap();
    let frame = Frame::read(&path).unwrap();
    assert_eq!((frame.width, frame.height), (8, 5));
    assert_eq!(frame.data, data);
    assert_eq!(frame.sidecar, sidecar());
    assert_eq!((frame.black_level, frame.white_level), (0.0, 65_535.0));
    assert!((frame.sidecar.exposure() - 0.02).abs() < 1e-15);
    let expected = f64::from(data[3 * (2 * 8 + 3) + 1]) / 65_535.0;
    assert!((frame.signal(3, 2, 1) - expected).abs() < 1e-12);
}

#[test]
fn sidecar_levels_override_file_levels() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.tif");
    let mut side = sidecar();
    side.black_level = Some(1024.0);
    side.white_level = Some(60_000.0);
    capture::write_tiff_capture(&path, 2, 2, &[30_512; 12], &side).unwrap();
    let frame = Frame::read(&path).unwrap();
    assert_eq!((frame.black_level, frame.white_level), (1024.0, 60_000.0));
    assert!((frame.signal(1, 1, 2) - 0.5).abs() < 1e-12);
}

#[test]
fn missing_sidecar_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.tiff");
    capture::write_tiff_capture(&path, 2, 2, &[0; 12], &sidecar()).unwrap();
    fs::remove_file(dir.path().join("a.json")).unwrap();
    match Frame::read(&path) {
        Err(CaptureError::MissingSidecar { sidecar, .. }) => {
            assert_eq!(sidecar, dir.path().join("a.json"))
        }
        other => panic!("expected MissingSidecar, got {other:?}"),
    }
}

fn read_with_sidecar_json(dir: &Path, json: &str) -> Result<Frame, CaptureError> {
    let path = dir.join("b.tiff");
    capture::write_tiff_capture(&path, 4, 3, &[100; 36], &sidecar()).unwrap();
    fs::write(dir.join("b.json"), json).unwrap();
    Frame::read(&path)
}

#[test]
fn malformed_sidecar_names_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let err = read_with_sidecar_json(
        dir.path(),
        r#"{"iso":100,"theta_l":-20,"camera":"c","time":"t"}"#,
    )
    .unwrap_err();
    assert!(matches!(err, CaptureError::SidecarJson { .. }));
    assert!(err.to_string().contains("shutter_s"), "{err}");
    let err = read_with_sidecar_json(dir.path(), "{not json").unwrap_err();
    assert!(matches!(err, CaptureError::SidecarJson { .. }), "{err}");
}

#[test]
fn contradicting_or_nonsense_sidecar_values_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let base = r#""camera":"c","time":"2026-11-23T14:00:00Z""#;
    let cases = [
        (
            format!(r#"{{"shutter_s":-0.01,"iso":100,"theta_l":-20,{base}}}"#),
            "shutter_s",
        ),
        (
            format!(r#"{{"shutter_s":0,"iso":100,"theta_l":-20,{base}}}"#),
            "shutter_s",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":0,"theta_l":-20,{base}}}"#),
            "iso",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":400,{base}}}"#),
            "theta_l",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"width":5,{base}}}"#),
            "width",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"height":4,{base}}}"#),
            "height",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"white_level":70000,{base}}}"#),
            "white_level",
        ),
        (
            format!(
                r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"black_level":5000,"white_level":4000,{base}}}"#
            ),
            "black_level",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"white_level":0,{base}}}"#),
            "white_level",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"black_level":-3,{base}}}"#),
            "black_level",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"aperture":0.2,{base}}}"#),
            "aperture",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"aperture":1e300,{base}}}"#),
            "aperture",
        ),
        (
            format!(r#"{{"shutter_s":0.1,"iso":100,"theta_l":-20,"aperture":-8,{base}}}"#),
            "aperture",
        ),
    ];
    for (json, field) in cases {
        match read_with_sidecar_json(dir.path(), &json) {
            Err(CaptureError::InvalidSidecar { field: f, .. }) => assert_eq!(f, field, "{json}"),
            other => panic!("{json}: expected InvalidSidecar({field}), got {other:?}"),
        }
    }
    // Matching dimensions, a null ISO, an aperture and a nonlinear response are accepted.
    let ok = format!(
        r#"{{"shutter_s":0.1,"iso":null,"theta_l":-20,"width":4,"height":3,"aperture":5.6,"response":"nonlinear",{base}}}"#
    );
    let frame = read_with_sidecar_json(dir.path(), &ok).unwrap();
    assert_eq!(frame.sidecar.response, Response::Nonlinear);
    assert_eq!(frame.sidecar.aperture, Some(5.6));
    assert_eq!(frame.sidecar.exposure(), 0.1);
}

#[test]
fn unreadable_or_unsupported_images_give_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let side = serde_json::to_string(&sidecar()).unwrap();
    for (name, bytes, raw) in [
        ("garbage.tiff", b"not an image at all".as_slice(), false),
        ("garbage.nef", b"not a raw file either".as_slice(), true),
        ("empty.tif", b"".as_slice(), false),
    ] {
        let path = dir.path().join(name);
        fs::write(&path, bytes).unwrap();
        fs::write(path.with_extension("json"), &side).unwrap();
        let err = Frame::read(&path).unwrap_err();
        let expected = if raw && !cfg!(feature = "raw") {
            matches!(err, CaptureError::UnsupportedFormat { .. })
        } else {
            matches!(err, CaptureError::Image { .. })
        };
        assert!(expected, "{name}: {err:?}");
    }
    let absent = dir.path().join("absent.tiff");
    fs::write(absent.with_extension("json"), &side).unwrap();
    let err = Frame::read(&absent).unwrap_err();
    assert!(
        matches!(err, CaptureError::Image { .. }) && err.to_string().contains("no such file"),
        "{err}"
    );
    let path = dir.path().join("picture.png");
    fs::write(&path, b"png").unwrap();
    fs::write(path.with_extension("json"), &side).unwrap();
    assert!(matches!(
        Frame::read(&path),
        Err(CaptureError::UnsupportedFormat { .. })
    ));
}

#[test]
fn grey_tiff_is_a_layout_error_and_8_bit_rgb_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let side = serde_json::to_string(&sidecar()).unwrap();
    let grey = dir.path().join("grey.tiff");
    image::GrayImage::from_raw(2, 2, vec![1, 2, 3, 4])
        .unwrap()
        .save(&grey)
        .unwrap();
    fs::write(grey.with_extension("json"), &side).unwrap();
    assert!(matches!(
        Frame::read(&grey),
        Err(CaptureError::Layout { .. })
    ));

    let rgb8 = dir.path().join("rgb8.tiff");
    image::RgbImage::from_raw(2, 1, vec![0, 128, 255, 1, 2, 3])
        .unwrap()
        .save(&rgb8)
        .unwrap();
    fs::write(rgb8.with_extension("json"), &side).unwrap();
    let frame = Frame::read(&rgb8).unwrap();
    assert_eq!(frame.white_level, 255.0);
    assert_eq!(frame.data, vec![0, 128, 255, 1, 2, 3]);
    assert_eq!(frame.signal(0, 0, 2), 1.0);
}

#[test]
fn capture_paths_are_recognised_case_insensitively() {
    assert!(capture::is_capture_path(Path::new("x/exp_00.TIFF")));
    assert!(capture::is_capture_path(Path::new("x/DSC_0001.NEF")));
    assert!(!capture::is_capture_path(Path::new("x/exp_00.json")));
    assert_eq!(
        capture::sidecar_path(Path::new("x/a.nef")),
        Path::new("x/a.json")
    );
}

#[test]
fn selected_rows_match_the_full_read_for_striped_and_other_tiffs() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (7u32, 40u32);
    let data = counts(w, h);
    let striped = dir.path().join("striped.tiff");
    capture::write_tiff_capture(&striped, w, h, &data, &sidecar()).unwrap();
    // An 8-bit TIFF takes the decode-everything path.
    let rgb8 = dir.path().join("rgb8.tiff");
    let bytes: Vec<u8> = data.iter().map(|&v| (v >> 8) as u8).collect();
    image::RgbImage::from_raw(w, h, bytes)
        .unwrap()
        .save(&rgb8)
        .unwrap();
    fs::write(
        rgb8.with_extension("json"),
        serde_json::to_string(&sidecar()).unwrap(),
    )
    .unwrap();
    for path in [&striped, &rgb8] {
        let full = Frame::read(path).unwrap();
        let seen = std::cell::Cell::new((0, 0));
        let part = Frame::read_rows(path, |width, height| {
            seen.set((width, height));
            Ok::<_, CaptureError>(vec![31..36, 2..4])
        })
        .unwrap();
        assert_eq!(seen.get(), (w as usize, h as usize));
        assert_eq!((part.width, part.height), (w as usize, 7));
        let row =
            |f: &Frame, y: usize| f.data[3 * w as usize * y..3 * w as usize * (y + 1)].to_vec();
        for (k, y) in [31, 32, 33, 34, 35, 2, 3].into_iter().enumerate() {
            assert_eq!(row(&part, k), row(&full, y), "{path:?} row {y}");
        }
        let err =
            Frame::read_rows(path, |_, _| Ok::<_, CaptureError>(vec![2..4, 38..41])).unwrap_err();
        assert!(matches!(err, CaptureError::Layout { .. }), "{err}");
    }
}

#[test]
fn sidecar_writes_whole_iso_as_integer() {
    let json = serde_json::to_value(sidecar()).unwrap();
    assert_eq!(json["iso"], serde_json::json!(200));
    assert!(json["iso"].is_u64());
    let fractional = Sidecar {
        iso: Some(320.5),
        ..sidecar()
    };
    assert_eq!(serde_json::to_value(fractional).unwrap()["iso"], 320.5);
    let none = Sidecar {
        iso: None,
        ..sidecar()
    };
    assert!(serde_json::to_value(none).unwrap()["iso"].is_null());
}
