use super::*;

#[test]
fn the_table_predicts_a_brdf_of_the_half_angle_alone() {
    // β depends on signed θh only: every θL, interior or at an end of the θd range,
    // is predicted from the others to the accuracy of linear interpolation along θh.
    let beta = |h: f64| {
        let lobe = 50.0 * (-(h / 0.08).powi(2)).exp();
        [2.0 + lobe, 3.0 + 0.8 * lobe, 1.0 + 0.5 * lobe]
    };
    let mut samples = Vec::new();
    for theta_l in [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0] {
        // Every θL covers the lobe's θh (|θh| ≤ 17.5°): no extrapolation along θh.
        for k in 0..=320 {
            let theta_i = -40.0 + 0.25 * f64::from(k);
            let theta_r = theta_l - theta_i;
            let h = ((theta_i - theta_r) / 2.0f64).to_radians();
            samples.push(Sample::in_plane(theta_l, theta_i, theta_r, beta(h)));
        }
    }
    let held = table_held_out(&samples, None, &CameraModel::builtin());
    assert_eq!((held.folds.len(), held.failed.len()), (6, 0));
    for fold in held.folds {
        assert!(fold.all.err_p.iter().all(|&e| e < 1e-3), "{fold:?}");
        assert!(fold.lobe.is_some(), "{fold:?}");
    }
}

/// Samples of β(θh) per θL (θh in degrees), in-plane, no noise.
fn scan(beta: impl Fn(f64, f64) -> [f64; 3]) -> Vec<Sample> {
    let mut samples = Vec::new();
    for theta_l in [-20.0, -30.0, -40.0] {
        for k in 0..=160 {
            let theta_i = -40.0 + 0.5 * f64::from(k);
            let theta_r = theta_l - theta_i;
            samples.push(Sample::in_plane(
                theta_l,
                theta_i,
                theta_r,
                beta((theta_i - theta_r) / 2.0, theta_l),
            ));
        }
    }
    samples
}

#[test]
fn one_specular_colour_keeps_a_colourless_specular_and_changes_a_changing_one() {
    let peak_at = |h: f64| 40.0 / (1.0 + (h / 3.0).powi(2));
    // A white lobe whose brightness changes with θL over an orange diffuse: its lobe
    // is kept.
    let white = Table::new(
        &scan(|h, t| [8.0, 4.0, 1.5].map(|d| d + peak_at(h) * (1.0 - 0.01 * t))),
        0.0,
    )
    .unwrap();
    let kept = one_specular_colour(&white);
    for (a, b) in white.columns().iter().zip(kept.columns()) {
        let values: Vec<[f64; 3]> = a.points.iter().map(|p| [p[1], p[2], p[3]]).collect();
        let on = lobe(&values);
        assert!(on.iter().filter(|&&l| l).count() > 10);
        for ((p, q), _) in a.points.iter().zip(&b.points).zip(&on).filter(|(_, &l)| l) {
            assert!(
                (0..4).all(|c| (p[c] - q[c]).abs() < 1e-9 * p[c].abs().max(1.0)),
                "{p:?} {q:?}"
            );
        }
    }
    // A lobe red at one θL, green at another and blue at the third: each becomes the
    // one colour they share, far from its own.
    let changing = Table::new(
        &scan(|h, t| {
            let k = ((-t - 20.0) / 10.0).round() as usize;
            std::array::from_fn(|c| 2.0 + if c == k { peak_at(h) } else { 0.0 })
        }),
        0.0,
    )
    .unwrap();
    let one = one_specular_colour(&changing);
    let peak = |t: &Table, c: usize| {
        t.columns()[c]
            .points
            .iter()
            .max_by(|a, b| (a[1] + a[2] + a[3]).total_cmp(&(b[1] + b[2] + b[3])))
            .copied()
            .unwrap()
    };
    for c in 0..3 {
        let (own, shared) = (peak(&changing, c), peak(&one, c));
        let share = |p: [f64; 4]| p[1 + c] / (p[1] + p[2] + p[3]);
        assert!(
            share(own) > 0.9 && share(shared) < 0.5,
            "{own:?} {shared:?}"
        );
    }
}

#[test]
fn medians_skip_non_finite_values() {
    assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
    assert_eq!(median(&[4.0, 1.0, f64::NAN, 2.0, 3.0]), Some(2.5));
    assert_eq!(median(&[]), None);
}
