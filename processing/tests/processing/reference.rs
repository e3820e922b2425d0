//! Goniospectrophotometer reference: CSV, eq. 5, spline interpolation.

use std::fmt::Write;

use gonio_processing::color::CameraModel;
use gonio_processing::reference::{Reference, ReferenceError};

/// A smooth spectral radiance factor over the grid: a flat part that depends on angle
/// and a red part that grows toward the specular direction θr = θi.
fn factor(theta_i: f64, theta_r: f64, wavelength: f64) -> f64 {
    let d = (theta_i - theta_r).to_radians();
    let red = if wavelength >= 600.0 { 0.4 } else { 0.0 };
    0.3 + 0.1 * theta_i.to_radians().cos() + (0.2 + red) * (-d * d / 0.3).exp()
}

fn csv(skip: Option<(f64, f64)>) -> String {
    let wavelengths: Vec<f64> = (0..35).map(|i| 390.0 + 10.0 * i as f64).collect();
    let mut text = String::from("theta_i,theta_r");
    for w in &wavelengths {
        write!(text, ",{w}").unwrap();
    }
    text.push('\n');
    for ti in (-60..=60).step_by(10) {
        for tr in (-80..=80).step_by(5) {
            let (ti, tr) = (f64::from(ti), f64::from(tr));
            if skip == Some((ti, tr)) {
                continue;
            }
            write!(text, "{ti},{tr}").unwrap();
            for &w in &wavelengths {
                write!(text, ",{:.6}", factor(ti, tr, w)).unwrap();
            }
            text.push('\n');
        }
    }
    text
}

fn truth(camera: &CameraModel, theta_i: f64, theta_r: f64) -> [f64; 3] {
    let spectrum: Vec<f64> = camera
        .wavelengths_nm()
        .iter()
        .map(|&w| factor(theta_i, theta_r, w))
        .collect();
    camera.camera_rgb(&spectrum).unwrap()
}

#[test]
fn nodes_are_eq5_camera_rgb_and_between_nodes_splines_follow_the_surface() {
    let camera = CameraModel::builtin();
    let reference = Reference::from_reader(csv(None).as_bytes(), "ref", &camera).unwrap();
    assert_eq!(reference.points().len(), 13 * 33);
    let p = reference.points()[40];
    let expected = truth(&camera, p.theta_i, p.theta_r);
    let at_node = reference.interpolate(p.theta_i, p.theta_r).unwrap();
    for ((node, want), interpolated) in p.rgb.iter().zip(expected).zip(at_node) {
        assert!((node - want).abs() < 1e-3, "{p:?}");
        assert!((interpolated - node).abs() < 1e-9);
    }
    for (ti, tr) in [(-32.5, -17.0), (12.3, 14.1), (0.0, -78.0), (47.0, 61.2)] {
        let got = reference.interpolate(ti, tr).unwrap();
        let want = truth(&camera, ti, tr);
        for c in 0..3 {
            assert!(
                (got[c] - want[c]).abs() < 0.01 * want[c],
                "({ti},{tr}) c{c}: {got:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn outside_the_grid_there_is_no_value_and_missing_nodes_are_bridged() {
    let camera = CameraModel::builtin();
    let reference =
        Reference::from_reader(csv(Some((10.0, 15.0))).as_bytes(), "ref", &camera).unwrap();
    assert_eq!(reference.interpolate(65.0, 0.0), None);
    assert_eq!(reference.interpolate(0.0, 85.0), None);
    assert_eq!(reference.interpolate(f64::NAN, 0.0), None);
    let got = reference.interpolate(10.0, 15.0).unwrap();
    let want = truth(&camera, 10.0, 15.0);
    for c in 0..3 {
        assert!(
            (got[c] - want[c]).abs() < 0.02 * want[c],
            "{got:?} vs {want:?}"
        );
    }
}

#[test]
fn bad_reference_files_name_the_problem() {
    let camera = CameraModel::builtin();
    let read = |text: &str| {
        Reference::from_reader(text.as_bytes(), "ref.csv", &camera)
            .unwrap_err()
            .to_string()
    };
    let good = csv(None);
    let header = good.lines().next().unwrap();
    assert!(read("angle_i,angle_r,400\n").contains("theta_i,theta_r"));
    assert!(read(&header.replace(",550,", ",x,")).contains("'x'"));
    assert!(read(&header.replace(",550,", ",555,")).contains("550 nm"));
    let row = good.lines().nth(1).unwrap();
    let mut fields: Vec<&str> = row.split(',').collect();
    fields[3] = "zero"; // the 400 nm column
    let bad_number = format!("{header}\n{row}\n{}\n", fields.join(","));
    let message = read(&bad_number);
    assert!(
        message.contains("line 3") && message.contains("zero"),
        "{message}"
    );
    assert!(read(&format!("{header}\n{row}\n{row}\n")).contains("duplicate node"));
    assert!(read(&format!("{header}\n1,2,3\n")).contains("fields"));
    assert!(read(&format!("{header}\n")).contains("no rows"));
    let missing = Reference::read_csv(std::path::Path::new("/nonexistent/ref.csv")).unwrap_err();
    assert!(matches!(missing, ReferenceError::Io { .. }));
}
