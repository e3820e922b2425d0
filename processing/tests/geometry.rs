use gonio_processing::geometry::{column_angles, GeometryError, Setup};

fn setup(radius: f64, camera: f64, light: f64, focal: f64, width: u32) -> Setup {
    Setup {
        cylinder_radius_mm: radius,
        camera_distance_mm: camera,
        light_distance_mm: light,
        focal_length_mm: focal,
        pixel_pitch_um: 5.0,
        image_width: width,
        image_height: 100,
        principal_point_x: None,
        sample_row: 30,
        white_row: 70,
    }
}

#[test]
fn distant_limit_gives_theta_i_plus_theta_r_equal_theta_l() {
    // Camera and light 1e9 mm away; the focal length makes the cylinder span ~800 of
    // 1001 columns (half image 2.5 mm on the sensor, cylinder image half-width 2 mm).
    let distance = 1e9;
    let s = setup(50.0, distance, distance, 2.0 * distance / 50.0, 1001);
    for theta_l in [-20.0, -45.0, 10.0] {
        let angles = column_angles(&s, theta_l);
        assert_eq!(angles.len(), 1001);
        let hits: Vec<_> = angles.iter().flatten().collect();
        assert!(hits.len() > 790 && hits.len() < 810, "{} hits", hits.len());
        for a in hits {
            assert!((a.theta_i + a.theta_r - theta_l).abs() < 1e-5, "{a:?}");
            assert!((a.theta_r - a.phi).abs() < 1e-5, "{a:?}");
        }
    }
}

#[test]
fn columns_beyond_the_silhouette_miss() {
    let s = setup(50.0, 500.0, 800.0, 50.0, 4000);
    let angles = column_angles(&s, -30.0);
    assert!(angles[0].is_none() && angles[3999].is_none());
    assert!(angles[2000].is_some());
    // Visible points face the camera: |θr| < 90° everywhere.
    assert!(angles.iter().flatten().all(|a| a.theta_r.abs() < 90.0));
}

#[test]
fn mirror_symmetry_of_columns_and_light() {
    let s = setup(40.0, 600.0, 700.0, 60.0, 3001);
    let left = column_angles(&s, -35.0);
    let right = column_angles(&s, 35.0);
    for u in 0..3001 {
        match (left[u], right[3000 - u]) {
            (Some(a), Some(b)) => {
                assert!((a.phi + b.phi).abs() < 1e-9);
                assert!((a.theta_i + b.theta_i).abs() < 1e-9);
                assert!((a.theta_r + b.theta_r).abs() < 1e-9);
            }
            (None, None) => {}
            other => panic!("column {u}: asymmetric hit {other:?}"),
        }
    }
}

#[test]
fn hand_worked_centre_column() {
    // Odd width: column 1000 is the principal point, its ray hits P = (R, 0).
    let s = setup(50.0, 500.0, 200.0, 50.0, 2001);
    let a = column_angles(&s, -60.0)[1000].expect("centre column hits");
    assert!(a.phi.abs() < 1e-12 && a.theta_r.abs() < 1e-12);
    // Light at (100, −173.205): from P the direction (50, −173.205).
    let expected = (-(3f64.sqrt()) * 100.0).atan2(50.0).to_degrees();
    assert!((a.theta_i - expected).abs() < 1e-9, "{a:?} vs {expected}");
    assert!((a.theta_i - -73.897_886).abs() < 1e-5);
}

#[test]
fn hand_worked_oblique_column() {
    // A ray 15° off the optical axis toward +y, camera 100 mm, radius 50 mm.
    // Law of sines: the angle at P is 180° − asin(2 sin 15°), so φ = asin(2 sin 15°) − 15°
    // and the view makes asin(2 sin 15°) with the normal: θr = φ + 15°.
    let mut s = setup(50.0, 100.0, 300.0, 50.0, 10);
    s.pixel_pitch_um = 10.0;
    s.principal_point_x = Some(0.0);
    let u = 50.0 * 15f64.to_radians().tan() / 10e-3;
    let a = s.angles_at_column(u, 0.0).expect("ray hits");
    let at_p = (2.0 * 15f64.to_radians().sin()).asin().to_degrees();
    assert!((a.phi - (at_p - 15.0)).abs() < 1e-9, "{a:?}");
    assert!((a.theta_r - at_p).abs() < 1e-9, "{a:?}");
    assert!((a.phi - 16.173_95).abs() < 1e-4, "{a:?}");
    // Light on +x at 300 mm: P = 50(cos φ, sin φ); θi = angle of (300 − Px, −Py) from n.
    let phi = a.phi.to_radians();
    let (px, py) = (50.0 * phi.cos(), 50.0 * phi.sin());
    let expected = (-py).atan2(300.0 - px).to_degrees() - a.phi;
    assert!((a.theta_i - expected).abs() < 1e-9);
    assert!(
        a.theta_i < -a.phi,
        "a nearer light sees the point more obliquely"
    );
}

#[test]
fn invalid_setups_are_reported_and_give_no_columns() {
    let inside = setup(50.0, 40.0, 800.0, 50.0, 100);
    assert!(matches!(
        inside.validate(),
        Err(GeometryError::InsideCylinder { what: "camera", .. })
    ));
    assert!(column_angles(&inside, -20.0).iter().all(Option::is_none));
    let zero_focal = setup(50.0, 500.0, 800.0, 0.0, 100);
    assert!(matches!(
        zero_focal.validate(),
        Err(GeometryError::NotPositive {
            field: "focal_length_mm",
            ..
        })
    ));
    assert!(setup(50.0, 500.0, 800.0, 50.0, 100).validate().is_ok());
}
