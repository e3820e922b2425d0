//! Camera-RGB colorimetry (eq. 4, 5, 12) with the built-in tables.

use gonio_processing::color::{self, CameraModel, ColorError, SpectralTable};

#[test]
fn perfect_white_has_g_100_and_spectra_scale_linearly() {
    let camera = CameraModel::builtin();
    let n = camera.wavelengths_nm().len();
    assert_eq!(n, 31);
    assert_eq!(camera.wavelengths_nm()[0], 400.0);
    assert_eq!(camera.wavelengths_nm()[n - 1], 700.0);
    let white = camera.camera_rgb(&vec![1.0; n]).unwrap();
    assert!((white[1] - 100.0).abs() < 1e-9);
    assert_eq!(white, camera.white_rgb());
    // Tungsten light is red-heavy: R above B for a flat spectrum.
    assert!(white[0] > white[2] && white[2] > 0.0, "{white:?}");
    let grey = camera.camera_rgb(&vec![0.3; n]).unwrap();
    for c in 0..3 {
        assert!((grey[c] - 0.3 * white[c]).abs() < 1e-9);
    }
    assert!(matches!(
        camera.camera_rgb(&[1.0; 5]),
        Err(ColorError::SpectrumLength {
            expected: 31,
            found: 5
        })
    ));
}

#[test]
fn a_red_spectrum_is_red_in_camera_rgb() {
    let camera = CameraModel::builtin();
    let red: Vec<f64> = camera
        .wavelengths_nm()
        .iter()
        .map(|&w| if w >= 600.0 { 0.9 } else { 0.05 })
        .collect();
    let rgb = camera.camera_rgb(&red).unwrap();
    let white = camera.white_rgb();
    assert!(
        rgb[0] / white[0] > 0.6 && rgb[2] / white[2] < 0.2,
        "{rgb:?}"
    );
}

#[test]
fn fitted_matrix_reproduces_the_chromaticity_of_illuminant_a() {
    let camera = CameraModel::builtin();
    // Perfect white under illuminant A: CIE 1976 u'v' = (0.2560, 0.5243).
    let uv = camera.uv_prime(camera.white_rgb()).unwrap();
    assert!(
        (uv[0] - 0.2560).abs() < 0.005 && (uv[1] - 0.5243).abs() < 0.005,
        "{uv:?}"
    );
    // And Y of the perfect white is close to G = 100 (both normalised to the illuminant).
    let xyz = camera.xyz(camera.white_rgb());
    assert!((xyz[1] - 100.0).abs() < 5.0, "{xyz:?}");
    let m = camera.rgb_to_xyz_matrix();
    let direct: Vec<f64> = (0..3)
        .map(|r| (0..3).map(|c| m[r][c] * camera.white_rgb()[c]).sum())
        .collect();
    assert!(direct.iter().zip(xyz).all(|(a, b)| (a - b).abs() < 1e-9));
}

#[test]
fn uv_prime_is_guarded_against_black() {
    assert_eq!(color::uv_prime_from_xyz([0.0, 0.0, 0.0]), None);
    assert_eq!(color::uv_prime_from_xyz([-1.0, 0.0, 0.0]), None);
    assert_eq!(color::uv_prime_from_xyz([f64::NAN, 1.0, 1.0]), None);
    // Equal-energy white E: u'v' = (4/19, 9/19).
    let uv = color::uv_prime_from_xyz([1.0, 1.0, 1.0]).unwrap();
    assert!((uv[0] - 4.0 / 19.0).abs() < 1e-12 && (uv[1] - 9.0 / 19.0).abs() < 1e-12);
    assert_eq!(CameraModel::builtin().uv_prime([0.0; 3]), None);
}

#[test]
fn bad_tables_name_the_line() {
    let err = SpectralTable::<3>::parse_csv("t", "nm,a,b,c\n400,1,2,3\n410,1,x,3\n").unwrap_err();
    assert!(err.to_string().contains("line 3"), "{err}");
    let err = SpectralTable::<1>::parse_csv("t", "nm,a\n400,1\n400,2\n").unwrap_err();
    assert!(err.to_string().contains("ascend"), "{err}");
    let err = SpectralTable::<1>::parse_csv("t", "nm,a\n400,1,2\n").unwrap_err();
    assert!(err.to_string().contains("fields"), "{err}");
    // A table that stops short of 700 nm cannot feed eq. 4.
    let short = "nm,r,g,b\n400,1,1,1\n410,1,1,1\n";
    let err = CameraModel::from_csv(short, "nm,p\n400,1\n", "nm,x,y,z\n400,1,1,1\n").unwrap_err();
    assert!(matches!(err, ColorError::MissingWavelength { .. }), "{err}");
}
