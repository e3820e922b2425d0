use gonio_processing::samples::{read_csv, read_csv_from, write_csv, Sample, SamplesError};

fn samples() -> Vec<Sample> {
    vec![
        Sample {
            theta_l: -20.0,
            theta_i: -30.125,
            theta_r: 10.1,
            rgb: [1.0 / 3.0, 50.0, 1e-7],
            ..Sample::default()
        },
        Sample {
            theta_l: -45.0,
            theta_i: 0.0,
            theta_r: -44.9,
            rgb: [0.0, 99.5, 12.25],
            ..Sample::default()
        },
    ]
}

#[test]
fn write_then_read_round_trips_exactly() {
    let dir = std::env::temp_dir().join(format!("gonio-samples-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("samples.csv");
    write_csv(&path, &samples()).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.starts_with("theta_l,theta_i,theta_r,r,g,b\n"));
    assert_eq!(read_csv(&path).unwrap(), samples());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn extra_columns_are_ignored() {
    let text = "theta_l,theta_i,theta_r,r,g,b,weight,valid\n-20,-25,5,1,2,3,0.5,true\n";
    let read = read_csv_from(text.as_bytes()).unwrap();
    assert_eq!(read.len(), 1);
    assert_eq!(read[0].rgb, [1.0, 2.0, 3.0]);
    assert_eq!(read[0].theta_i, -25.0);
}

#[test]
fn wrong_header_is_rejected() {
    let err = read_csv_from("theta_i,theta_l,theta_r,r,g,b\n".as_bytes()).unwrap_err();
    assert!(matches!(err, SamplesError::Header { .. }), "{err}");
}

#[test]
fn malformed_rows_name_their_line() {
    let text = "theta_l,theta_i,theta_r,r,g,b\n-20,-25,5,1,2,3\n-20,-26,x,1,2,3\n";
    let err = read_csv_from(text.as_bytes()).unwrap_err();
    let message = err.to_string();
    assert!(
        message.contains("line 3") && message.contains("theta_r"),
        "{message}"
    );

    let short = "theta_l,theta_i,theta_r,r,g,b\n-20,-25,5,1,2,3\n-20,-25,5,1,2,3\n-20,1\n";
    let message = read_csv_from(short.as_bytes()).unwrap_err().to_string();
    assert!(message.contains("line 4"), "{message}");
}

#[test]
fn angles_and_cosines_out_of_their_range_are_refused() {
    let header = "theta_l,theta_i,theta_r,r,g,b";
    let cosines = "theta_l,theta_i,theta_r,r,g,b,n_dot_l,n_dot_v,n_dot_h,v_dot_h";
    for (text, needle) in [
        (
            format!("{header}\n-20,-25,5,1,2,3\n-20,120,5,1,2,3\n"),
            "line 3, column `theta_i`",
        ),
        (
            format!("{header}\n-20,-25,-95,1,2,3\n"),
            "line 2, column `theta_r`",
        ),
        (
            format!("{header}\n-200,-25,5,1,2,3\n"),
            "line 2, column `theta_l`",
        ),
        // With cosine columns the angles are still checked, and the cosines too.
        (
            format!("{cosines}\n-20,120,5,1,2,3,0.9,0.9,1,0.9\n"),
            "column `theta_i`",
        ),
        (
            format!("{cosines}\n-20,-25,5,1,2,3,5,0.9,1,0.9\n"),
            "column `n_dot_l`: 5 is not a cosine",
        ),
        (
            format!("{cosines}\n-20,-25,5,1,2,3,0.9,0.9,1,-1.5\n"),
            "column `v_dot_h`",
        ),
    ] {
        let message = read_csv_from(text.as_bytes()).unwrap_err().to_string();
        assert!(message.contains(needle), "{needle}: {message}");
    }
    // The ends of the ranges are values, and a negative cosine within [−1, 1] is read
    // (a fit then calls that direction grazing).
    let ends = format!("{cosines}\n-180,-90,90,1,2,3,-1,1,1,0\n");
    assert_eq!(read_csv_from(ends.as_bytes()).unwrap().len(), 1);
}

#[test]
fn windows_line_ends_count_as_lines() {
    // A spreadsheet's export: every line ends in \r\n.
    let text = "theta_l,theta_i,theta_r,r,g,b\r\n-20,-25,5,1,2,3\r\n-20,-25,5,1,2,3\r\n-20,-26,x,1,2,3\r\n";
    let message = read_csv_from(text.as_bytes()).unwrap_err().to_string();
    assert!(
        message.contains("line 4,") && message.contains("theta_r"),
        "{message}"
    );
    let good = "theta_l,theta_i,theta_r,r,g,b\r\n-20,-25,5,1,2,3\r\n";
    assert_eq!(read_csv_from(good.as_bytes()).unwrap().len(), 1);
}

#[test]
fn non_finite_values_are_rejected() {
    let text = "theta_l,theta_i,theta_r,r,g,b\n-20,-25,5,NaN,2,3\n";
    let message = read_csv_from(text.as_bytes()).unwrap_err().to_string();
    assert!(
        message.contains("line 2") && message.contains("`r`"),
        "{message}"
    );
    let text = "theta_l,theta_i,theta_r,r,g,b\n-20,-25,5,1,inf,3\n";
    assert!(read_csv_from(text.as_bytes()).is_err());
}

#[test]
fn missing_file_names_the_path() {
    let message = read_csv(std::path::Path::new("/nonexistent/gonio.csv"))
        .unwrap_err()
        .to_string();
    assert!(message.contains("/nonexistent/gonio.csv"), "{message}");
}

#[test]
fn non_finite_field_names_the_first_bad_column() {
    let good = Sample {
        theta_l: -20.0,
        theta_i: 10.0,
        theta_r: -10.0,
        rgb: [1.0, 2.0, 3.0],
        ..Sample::default()
    };
    assert_eq!(good.non_finite_field(), None);
    let bad = Sample {
        theta_r: f64::INFINITY,
        rgb: [1.0, f64::NAN, 3.0],
        ..good
    };
    assert_eq!(bad.non_finite_field(), Some("theta_r"));
    let bad_g = Sample {
        rgb: [1.0, f64::NAN, 3.0],
        ..good
    };
    assert_eq!(bad_g.non_finite_field(), Some("g"));
}

#[test]
fn cosine_columns_round_trip_and_reach_the_models() {
    use gonio_processing::brdf::{Cosines, Model, Params};
    // A point above the plane of the light: its true cosines differ from the in-plane ones.
    let cosines = Cosines::from_directions([1.0, 0.0, 0.0], [0.8, 0.5, 0.2], [1.0, -0.4, 0.2]);
    let mut with = samples();
    with[0].cosines = Some(cosines);
    let mut text = Vec::new();
    gonio_processing::samples::write_csv_to(&mut text, &with).unwrap();
    let text = String::from_utf8(text).unwrap();
    assert!(
        text.starts_with("theta_l,theta_i,theta_r,r,g,b,n_dot_l,n_dot_v,n_dot_h,v_dot_h\n"),
        "{text}"
    );
    let read = read_csv_from(text.as_bytes()).unwrap();
    assert_eq!(read[0].cosines, Some(cosines));
    // The sample without 3D cosines was written with its in-plane ones.
    assert_eq!(read[1].cosines(), samples()[1].cosines());

    let p = Params::shared([1.0, 2.0, 3.0], [4.0, 5.0, 6.0], 0.2);
    let at = Model::CookTorrance.evaluate_at(&p, &read[0].cosines());
    let in_plane = Model::CookTorrance.evaluate(&p, read[0].theta_i, read[0].theta_r);
    assert_ne!(at, in_plane);

    let three = "theta_l,theta_i,theta_r,r,g,b,n_dot_l,n_dot_v,n_dot_h\n";
    let err = read_csv_from(three.as_bytes()).unwrap_err();
    assert!(err.to_string().contains("v_dot_h"), "{err}");
}

#[test]
fn empty_beta_fields_are_dropped_values_and_empty_angles_are_errors() {
    let text = "theta_l,theta_i,theta_r,r,g,b\n-20,-25,5,1,,3\n-20,-24,4,,,7\n";
    let read = read_csv_from(text.as_bytes()).unwrap();
    assert_eq!(read[0].dropped, [false, true, false]);
    assert_eq!(
        (read[0].channel(0), read[0].channel(1), read[0].channel(2)),
        (Some(1.0), None, Some(3.0))
    );
    assert_eq!(read[1].dropped, [true, true, false]);
    // Written back the same way.
    let mut out = Vec::new();
    gonio_processing::samples::write_csv_to(&mut out, &read).unwrap();
    assert_eq!(String::from_utf8(out).unwrap(), text);
    let bad = "theta_l,theta_i,theta_r,r,g,b\n-20,,5,1,2,3\n";
    let message = read_csv_from(bad.as_bytes()).unwrap_err().to_string();
    assert!(message.contains("theta_i"), "{message}");
}

#[test]
fn uncertainty_columns_of_an_earlier_extraction_read_with_no_change_for_later_sources() {
    // An earlier extraction wrote the noise and seven sources; the camera's yaw and roll
    // and the white's falloff came later and read as no change. A file lacking an
    // earlier column is refused.
    let earlier = [
        "noise",
        "white_reflectance",
        "camera_offset",
        "camera_distance",
        "light_distance",
        "cylinder_tilt",
        "arm_zero",
        "arm_angle",
    ];
    let columns: Vec<String> = earlier
        .iter()
        .flat_map(|n| ["r", "g", "b"].map(|c| format!("u_{n}_{c}")))
        .collect();
    let values: Vec<String> = (1..=columns.len()).map(|k| format!("{k}")).collect();
    let text = format!(
        "theta_l,theta_i,theta_r,r,g,b,{}\n-20,-25,5,1,2,3,{}\n",
        columns.join(","),
        values.join(",")
    );
    let read = read_csv_from(text.as_bytes()).unwrap();
    let u = read[0].uncertainty.unwrap();
    assert_eq!(u.noise, [1.0, 2.0, 3.0]);
    assert_eq!(u.sources[6], [22.0, 23.0, 24.0]);
    assert!(u.sources[7..].iter().all(|s| *s == [0.0; 3]));
    let without_tilt = text.replace("u_cylinder_tilt_g", "u_tilt_g");
    let err = read_csv_from(without_tilt.as_bytes()).unwrap_err();
    assert!(err.to_string().contains("u_cylinder_tilt_g"), "{err}");
}
