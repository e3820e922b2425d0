use gonio_processing::metrics::{
    delta_e_uv, delta_e_uv_point, err_p, loss, uv_prime, MetricsError,
};

#[test]
fn loss_is_the_sum_of_euclidean_distances() {
    let measured = [[3.0, 4.0, 0.0], [1.0, 1.0, 1.0]];
    let estimated = [[0.0, 0.0, 0.0], [1.0, 1.0, 3.0]];
    // 5 (a 3-4-5 triangle) + 2, not squared.
    assert_eq!(loss(&measured, &estimated).unwrap(), 7.0);
    assert!(matches!(
        loss(&measured, &estimated[..1]),
        Err(MetricsError::LengthMismatch {
            measured: 2,
            estimated: 1
        })
    ));
}

#[test]
fn err_p_per_channel() {
    let measured = [[10.0, 20.0, 5.0], [30.0, 20.0, 5.0]];
    let estimated = [[12.0, 20.0, 4.0], [27.0, 10.0, 7.0]];
    let e = err_p(&measured, &estimated).unwrap();
    assert!((e[0] - 5.0 / 40.0).abs() < 1e-15);
    assert!((e[1] - 10.0 / 40.0).abs() < 1e-15);
    assert!((e[2] - 3.0 / 10.0).abs() < 1e-15);
    let black_blue = [[1.0, 1.0, 0.0]];
    assert_eq!(
        err_p(&black_blue, &black_blue),
        Err(MetricsError::NoSignal { channel: 'B' })
    );
}

#[test]
fn uv_prime_of_known_whites() {
    // D65 white XYZ (95.047, 100, 108.883): u′ = 0.1978, v′ = 0.4683.
    let [u, v] = uv_prime([95.047, 100.0, 108.883]).unwrap();
    assert!(
        (u - 0.19784).abs() < 1e-4 && (v - 0.46834).abs() < 1e-4,
        "{u} {v}"
    );
    // Equal-energy white: u′ = 4/19, v′ = 9/19.
    let [u, v] = uv_prime([1.0, 1.0, 1.0]).unwrap();
    assert!((u - 4.0 / 19.0).abs() < 1e-15 && (v - 9.0 / 19.0).abs() < 1e-15);
    assert_eq!(uv_prime([0.0, 0.0, 0.0]), None);
}

#[test]
fn delta_e_uv_is_the_mean_relative_chromaticity_difference() {
    let white = [1.0, 1.0, 1.0];
    assert_eq!(delta_e_uv_point(white, [2.0, 2.0, 2.0]), Some(0.0));
    // X doubled: denominator 20, u′ = 8/20, v′ = 9/20.
    let d = delta_e_uv_point(white, [2.0, 1.0, 1.0]).unwrap();
    let expected =
        (8.0 / 20.0 - 4.0 / 19.0) / (4.0 / 19.0) + (9.0 / 19.0 - 9.0 / 20.0) / (9.0 / 19.0);
    assert!((d - expected).abs() < 1e-12);
    // The black point is left out of the mean.
    let mean = delta_e_uv(
        &[white, white, [0.0; 3]],
        &[white, [2.0, 1.0, 1.0], [0.0; 3]],
    )
    .unwrap();
    assert!((mean - expected / 2.0).abs() < 1e-12);
    assert_eq!(
        delta_e_uv(&[[0.0; 3]], &[[0.0; 3]]),
        Err(MetricsError::NoChromaticity)
    );
}
