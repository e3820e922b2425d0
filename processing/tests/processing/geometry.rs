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
        principal_point_y: None,
        white_reflectance: None,
        camera_offset_mm: 0.0,
        cylinder_tilt_deg: 0.0,
        arm_zero_offset_deg: 0.0,
        camera_yaw_deg: 0.0,
        camera_roll_deg: 0.0,
        white_falloff: None,
        white_angular: None,
        uncertainty: Default::default(),
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

/// The paper's setup with a D200-sized sensor, for the 3D checks.
fn d200() -> Setup {
    let mut s = setup(40.0, 700.0, 1000.0, 85.0, 3872);
    s.pixel_pitch_um = 6.1;
    s.image_height = 2592;
    s
}

fn norm(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / l)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The hit of pixel (u, v) by marching along its ray and bisecting on the distance from
/// the axis: independent of the closed form. Returns the point.
fn marched_hit(s: &Setup, u: f64, v: f64) -> Option<[f64; 3]> {
    let pitch = s.pixel_pitch_um * 1e-3;
    let camera = [s.camera_distance_mm, s.camera_offset_mm, 0.0];
    let d = norm([
        -s.focal_length_mm,
        (u - s.principal_point()) * pitch,
        -(v - s.principal_row()) * pitch,
    ]);
    let tilt = s.cylinder_tilt_deg.to_radians();
    let axis = [0.0, tilt.sin(), tilt.cos()];
    let at = |t: f64| std::array::from_fn::<f64, 3, _>(|k| camera[k] + t * d[k]);
    let inside = |t: f64| {
        let p = at(t);
        let h = dot(p, axis);
        let q: [f64; 3] = std::array::from_fn(|k| p[k] - h * axis[k]);
        dot(q, q) < s.cylinder_radius_mm * s.cylinder_radius_mm
    };
    let step = 0.01;
    let mut t = 0.0;
    while !inside(t + step) {
        t += step;
        if t > 2.0 * s.camera_distance_mm {
            return None;
        }
    }
    let (mut lo, mut hi) = (t, t + step);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if inside(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(at(0.5 * (lo + hi)))
}

#[test]
fn pixel_geometry_matches_a_marched_ray_with_every_misalignment() {
    let mut s = d200();
    s.camera_offset_mm = 3.0;
    s.cylinder_tilt_deg = 0.5;
    s.arm_zero_offset_deg = 0.3;
    s.validate().unwrap();
    let theta_l = -30.0;
    let tilt = s.cylinder_tilt_deg.to_radians();
    let axis = [0.0, tilt.sin(), tilt.cos()];
    let angle = (theta_l + s.arm_zero_offset_deg).to_radians();
    let light = [1000.0 * angle.cos(), 1000.0 * angle.sin(), 0.0];
    let camera = [700.0, 3.0, 0.0];
    let mut checked = 0;
    for (u, v) in [
        (1700.0, 1190.0),
        (2100.0, 1401.0),
        (1200.0, 300.0),
        (1935.5, 1295.5),
    ] {
        let g = s.pixel_geometry(u, v, theta_l).expect("on the cylinder");
        let p = marched_hit(&s, u, v).expect("marched hit");
        let h = dot(p, axis);
        let n = norm(std::array::from_fn(|k| p[k] - h * axis[k]));
        let l = norm(std::array::from_fn(|k| light[k] - p[k]));
        let c = norm(std::array::from_fn(|k| camera[k] - p[k]));
        let half = norm(std::array::from_fn(|k| l[k] + c[k]));
        assert!((g.height_mm - h).abs() < 1e-6, "{g:?} vs height {h}");
        assert!((g.cosines.n_dot_l - dot(n, l)).abs() < 1e-9, "{g:?}");
        assert!((g.cosines.n_dot_v - dot(n, c)).abs() < 1e-9, "{g:?}");
        assert!((g.cosines.n_dot_h - dot(n, half)).abs() < 1e-9, "{g:?}");
        assert!((g.cosines.v_dot_h - dot(c, half)).abs() < 1e-9, "{g:?}");
        let to_light: [f64; 3] = std::array::from_fn(|k| light[k] - p[k]);
        let d2 = dot(to_light, to_light);
        assert!(
            (g.irradiance - dot(n, to_light) / d2.powf(1.5)).abs() < 1e-15,
            "{g:?}"
        );
        checked += 1;
    }
    assert_eq!(checked, 4);
}

#[test]
fn rows_off_the_plane_keep_in_plane_angles_but_not_cosines() {
    // An upright cylinder: the in-plane projections do not depend on the row; the 3D
    // half vector tilts out of plane above and below it, so n·h drops there.
    let s = d200();
    let (u, theta_l) = (1700.0, -30.0);
    let centre = s.pixel_geometry(u, s.principal_row(), theta_l).unwrap();
    let above = s.pixel_geometry(u, 1190.0, theta_l).unwrap();
    let below = s
        .pixel_geometry(u, 2.0 * s.principal_row() - 1190.0, theta_l)
        .unwrap();
    assert!((above.theta_i - centre.theta_i).abs() < 1e-9);
    assert!((above.theta_r - centre.theta_r).abs() < 1e-9);
    assert!(above.height_mm > 4.0 && (above.height_mm + below.height_mm).abs() < 1e-9);
    // Mirror rows about the plane of the light see the same cosines.
    assert!((above.cosines.n_dot_h - below.cosines.n_dot_h).abs() < 1e-12);
    let in_plane = gonio_processing::brdf::Cosines::in_plane(centre.theta_i, centre.theta_r);
    assert!((centre.cosines.n_dot_h - in_plane.n_dot_h).abs() < 1e-12);
    assert!(above.cosines.n_dot_h < centre.cosines.n_dot_h - 1e-6);
}

#[test]
fn arm_zero_offset_is_a_light_angle_and_tilt_rotates_the_image() {
    let mut s = d200();
    s.arm_zero_offset_deg = 0.3;
    let shifted = s.pixel_geometry(1800.0, 1190.0, -30.0).unwrap();
    s.arm_zero_offset_deg = 0.0;
    assert_eq!(s.pixel_geometry(1800.0, 1190.0, -29.7).unwrap(), shifted);

    // With the camera on the x axis, tilting the cylinder about it rotates the whole
    // picture of the cylinder about the principal point: the rotated pixel sees the
    // same point at the same height and azimuth.
    let upright = d200();
    let mut tilted = d200();
    tilted.cylinder_tilt_deg = 2.0;
    let (cx, cy) = (upright.principal_point(), upright.principal_row());
    let tau = 2f64.to_radians();
    for (u, v) in [(1700.0, 1190.0), (2200.0, 1500.0), (1400.0, 1000.0)] {
        let (x, y_up) = (u - cx, cy - v);
        // Clockwise by τ in the image (top toward the right).
        let (xr, yr) = (
            x * tau.cos() + y_up * tau.sin(),
            -x * tau.sin() + y_up * tau.cos(),
        );
        let seen = |s: &Setup, u: f64, v: f64| {
            let g = s.pixel_geometry(u, v, -30.0).expect("on the cylinder");
            (g.height_mm, g.phi())
        };
        let a = seen(&upright, u, v);
        let b = seen(&tilted, cx + xr, cy - yr);
        assert!(
            (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9,
            "{a:?} vs {b:?}"
        );
    }
}

#[test]
fn camera_yaw_and_roll_turn_the_rays_about_the_camera_centre() {
    // Turning the camera leaves its centre where it is: a turned camera's pixel sees the
    // ray that the unturned camera sees at the pixel turned back. Yaw ψ (counter-clockwise
    // seen from above) turns a ray's bearing by ψ, so on the principal row pixel x sees
    // what the unturned one sees at x' = f·tan(atan(x/f) − ψ); roll ρ (the image's right
    // toward its up) puts image vector (x, y↑) at (x cos ρ − y sin ρ, x sin ρ + y cos ρ)
    // of the unrolled image.
    let nominal = Setup {
        camera_offset_mm: 1.0,
        ..d200()
    };
    let pitch = nominal.pixel_pitch_um * 1e-3;
    let f = nominal.focal_length_mm;
    let (cx, cy) = (nominal.principal_point(), nominal.principal_row());
    let yaw = 0.7f64;
    let yawed = Setup {
        camera_yaw_deg: yaw,
        ..nominal.clone()
    };
    let roll = -1.3f64;
    let rolled = Setup {
        camera_roll_deg: roll,
        ..nominal.clone()
    };
    let (sin_r, cos_r) = roll.to_radians().sin_cos();
    let mut compared = 0;
    for u in (0..3872).step_by(97).map(f64::from) {
        let x = (u - cx) * pitch;
        let turned = f * ((x / f).atan() - yaw.to_radians()).tan();
        let seen = yawed.pixel_geometry(u, cy, -30.0);
        let expected = nominal.pixel_geometry(cx + turned / pitch, cy, -30.0);
        for (v, y) in [(cy - 300.0, 300.0 * pitch), (cy + 150.0, -150.0 * pitch)] {
            let (xr, yr) = (x * cos_r - y * sin_r, x * sin_r + y * cos_r);
            let rolled_seen = rolled.pixel_geometry(u, v, -30.0);
            let rolled_expected = nominal.pixel_geometry(cx + xr / pitch, cy - yr / pitch, -30.0);
            assert_eq!(
                rolled_seen.is_some(),
                rolled_expected.is_some(),
                "roll at {u}"
            );
            if let (Some(a), Some(b)) = (rolled_seen, rolled_expected) {
                assert!(
                    (a.phi() - b.phi()).abs() < 1e-9 && (a.height_mm - b.height_mm).abs() < 1e-9
                );
                compared += 1;
            }
        }
        assert_eq!(seen.is_some(), expected.is_some(), "yaw at {u}");
        if let (Some(a), Some(b)) = (seen, expected) {
            assert!((a.phi() - b.phi()).abs() < 1e-9, "{a:?} {b:?}");
            assert!((a.theta_i - b.theta_i).abs() < 1e-9);
            assert!((a.cosines.n_dot_h - b.cosines.n_dot_h).abs() < 1e-12);
            compared += 1;
        }
    }
    assert!(compared > 40, "{compared} pixels compared");
    // A positive yaw moves the cylinder toward the image's right: the column seeing the
    // front of the cylinder (φ = 0) lies right of where the unturned camera sees it.
    let front = |s: &Setup| {
        (0..3872)
            .map(f64::from)
            .filter_map(|u| Some((u, s.pixel_geometry(u, cy, -30.0)?.phi().abs())))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap()
            .0
    };
    assert!(front(&yawed) > front(&nominal) + 100.0);
    for (field, bad) in [("camera_yaw_deg", 31.0), ("camera_roll_deg", f64::NAN)] {
        let mut s = nominal.clone();
        if field == "camera_yaw_deg" {
            s.camera_yaw_deg = bad;
        } else {
            s.camera_roll_deg = bad;
        }
        let err = s.validate().unwrap_err();
        assert!(err.to_string().contains(field), "{err}");
    }
}

#[test]
fn bad_white_angular_dependence_is_named() {
    let mut s = d200();
    s.white_falloff = Some(0.7);
    assert!(s
        .validate()
        .unwrap_err()
        .to_string()
        .contains("white_falloff"));
    let json = r#"{"theta_i_deg":[0,60],"factor":[1,0.97],"u":[0,0.01]}"#;
    s.white_falloff = None;
    s.white_angular = Some(serde_json::from_str(json).unwrap());
    assert!(s.validate().is_ok());
    assert_eq!(s.white_angular().at(0.5), (0.97, 0.01));
    s.white_falloff = Some(0.01);
    assert!(s
        .validate()
        .unwrap_err()
        .to_string()
        .contains("white_falloff"));
    s.white_falloff = None;
    s.white_angular = Some(
        serde_json::from_str(r#"{"theta_i_deg":[0,60],"factor":[1,-1],"u":[0,0.01]}"#).unwrap(),
    );
    assert!(s
        .validate()
        .unwrap_err()
        .to_string()
        .contains("white_angular.factor"));
}
