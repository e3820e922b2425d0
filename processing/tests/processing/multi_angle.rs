//! Multi-angle colour and compare on constructed fits (docs/ARCHITECTURE.md,
//! "Multi-angle colour").

use gonio_processing::brdf::{Model, Roughness};
use gonio_processing::color::delta_e::ciede2000;
use gonio_processing::color::geometry::{half_difference, incidence_and_view, ASTM_E2539};
use gonio_processing::color::observer::Conditions;
use gonio_processing::color::transform::ColourTransform;
use gonio_processing::color::CameraModel;
use gonio_processing::fit::{FitMethod, FitResult, FittedRoughness, ParameterSet};
use gonio_processing::multi_angle::compare::{compare, Mounting, Tolerances, Verdict};
use gonio_processing::multi_angle::{colour, ColourReport, Measured, Origin, EXTRAPOLATION};
use gonio_processing::samples::Sample;

fn fit(kd: [f64; 3], ks: [f64; 3], m: f64) -> FitResult {
    FitResult {
        model: Model::CookTorrance,
        roughness: Roughness::Shared,
        kd,
        ks,
        ks_90: None,
        m: FittedRoughness::Shared([m]),
        rho_d: None,
        loss: 1.0,
        err_p: [0.0; 3],
        method: FitMethod::Robust,
        evaluations: 1,
        seconds: 0.0,
        stderr: Some(ParameterSet {
            kd: kd.map(|v| 0.002 * v),
            ks: ks.map(|v| 0.005 * v),
            ks_90: None,
            m: vec![0.002 * m],
        }),
        ci95: None,
        correlation: None,
        colour_shift: None,
        global_minimum: None,
        selection: None,
        budget: None,
        table: None,
    }
}

fn report(f: &FitResult) -> ColourReport {
    let transform = ColourTransform::new(&CameraModel::builtin(), Conditions::D65Ten).unwrap();
    colour(f, None, &transform, &ASTM_E2539).unwrap()
}

#[test]
fn the_geometries_follow_the_aspecular_convention() {
    assert_eq!(incidence_and_view(15.0, 1.0), (45.0, 30.0));
    assert_eq!(incidence_and_view(110.0, 1.0), (45.0, -65.0));
    assert_eq!(incidence_and_view(-15.0, -1.0), (-45.0, -60.0));
    assert_eq!(half_difference(45.0, 1.0), (22.5, 22.5));
    assert_eq!(half_difference(110.0, -1.0), (-55.0, 10.0));
}

#[test]
fn a_fit_gives_every_angle_from_its_model_with_a_flop_index() {
    let gold = report(&fit([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07));
    assert_eq!(gold.angles.len(), 6);
    for a in &gold.angles {
        assert_eq!(a.origin, Origin::Model);
        for c in [a.l, a.a, a.b, a.c, a.h] {
            assert!(c.value.is_finite() && c.expanded > 0.0, "{a:?}");
        }
    }
    // Near the specular a gold is light and yellow; far from it dark.
    let l = |as_: f64| {
        gold.angles
            .iter()
            .find(|a| a.aspecular == as_)
            .unwrap()
            .l
            .value
    };
    assert!(l(15.0) > l(45.0) && l(45.0) >= l(110.0));
    let fi = gold.flop_index.unwrap();
    assert!(fi.value > 0.0 && fi.expanded > 0.0);
}

/// Samples of `f` on six columns θL = 20°…45° (θd = θL/2), θh from −30° to 30°, each
/// channel scaled by `drift(sin²θd)`.
fn measured_samples(f: &FitResult, drift: impl Fn(f64) -> [f64; 3]) -> Vec<Sample> {
    let mut out = Vec::new();
    for k in 0..6 {
        let theta_l = 20.0 + 5.0 * f64::from(k);
        let d = theta_l / 2.0;
        let scale = drift(d.to_radians().sin().powi(2));
        for h in -30..=30 {
            let (ti, tr) = (d + f64::from(h), d - f64::from(h));
            let beta = f.predict(ti, tr);
            out.push(Sample::in_plane(
                theta_l,
                ti,
                tr,
                std::array::from_fn(|c| beta[c] * scale[c]),
            ));
        }
    }
    out
}

/// The L* standard uncertainty of an angle's extrapolation lines.
fn extrapolation_l(report: &ColourReport, aspecular: f64) -> f64 {
    let angle = report
        .angles
        .iter()
        .find(|a| a.aspecular == aspecular)
        .unwrap();
    angle
        .lines
        .iter()
        .filter(|l| l.source.starts_with(EXTRAPOLATION))
        .map(|l| l.lab[0].powi(2))
        .sum::<f64>()
        .sqrt()
}

#[test]
fn a_model_value_beyond_the_data_carries_the_colour_drift_the_data_show() {
    let transform = ColourTransform::new(&CameraModel::builtin(), Conditions::D65Ten).unwrap();
    let gold = fit([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07);
    let report_of = |samples: &[Sample]| {
        let measured = Measured::of(&gold, samples).unwrap();
        colour(&gold, Some(&measured), &transform, &ASTM_E2539).unwrap()
    };
    // The model's own colour: what drifts is the mix of its diffuse and lobe colours
    // along θd at a fixed θh, a small term however far the geometry.
    let steady = report_of(&measured_samples(&gold, |_| [1.0; 3]));
    // Red giving way to green over the measured columns, as a film's or flakes' lobe.
    let drifting = report_of(&measured_samples(&gold, |s| {
        [1.0 - 2.0 * s, 1.0 + 2.0 * s, 1.0]
    }));
    for report in [&steady, &drifting] {
        let origin = |a: f64| {
            report
                .angles
                .iter()
                .find(|c| c.aspecular == a)
                .unwrap()
                .origin
        };
        assert_eq!(origin(45.0), Origin::Data);
        assert_eq!(origin(-15.0), Origin::Model);
        // A value from the data has no such line.
        assert_eq!(extrapolation_l(report, 45.0), 0.0);
    }
    let (still, moving) = (
        extrapolation_l(&steady, -15.0),
        extrapolation_l(&drifting, -15.0),
    );
    eprintln!("extrapolation's L* u at −15°: steady {still:.4}, drifting {moving:.4}");
    assert!(still < 0.5, "steady {still}");
    assert!(moving > 2.0, "drifting {moving}");
    // Farther from the data, more of it: 15° lies nearer the measured θd than −15°.
    assert!(extrapolation_l(&drifting, 15.0) < moving);
    let at = |r: &ColourReport| {
        r.angles
            .iter()
            .find(|a| a.aspecular == -15.0)
            .unwrap()
            .l
            .expanded
    };
    assert!(at(&drifting) > at(&steady) + 4.0);
}

#[test]
fn a_model_value_brighter_than_the_data_support_is_flagged_beyond_the_data() {
    let transform = ColourTransform::new(&CameraModel::builtin(), Conditions::D65Ten).unwrap();
    let measured_lobe = fit([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.2);
    let samples = measured_samples(&measured_lobe, |_| [1.0; 3]);
    let flagged = |model: &FitResult| {
        let measured = Measured::of(model, &samples).unwrap();
        let report = colour(model, Some(&measured), &transform, &ASTM_E2539).unwrap();
        report
            .angles
            .iter()
            .filter(|a| a.beyond_data)
            .map(|a| a.aspecular)
            .collect::<Vec<_>>()
    };
    // The lobe the data were measured from, carried beyond them: within its bound.
    assert_eq!(flagged(&measured_lobe), Vec::<f64>::new());
    // A model whose lobe is ten times what was measured, beyond the data at −15°.
    let claimed = fit([9.0, 6.5, 2.0], [250.0, 200.0, 70.0], 0.2);
    let beyond = flagged(&claimed);
    assert!(beyond.contains(&-15.0), "{beyond:?}");
    // Values from the data are never flagged.
    assert!(!beyond.contains(&45.0), "{beyond:?}");
}

#[test]
fn compare_fails_gold_against_red_and_passes_a_sample_against_itself() {
    let gold = report(&fit([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07));
    let red = report(&fit([20.0, 3.0, 2.5], [10.0, 10.0, 10.0], 0.15));
    let c = compare(&gold, &red, &Tolerances::default(), Mounting::Same).unwrap();
    assert_eq!(c.overall, Verdict::Fail);
    let same = compare(&gold, &gold, &Tolerances::default(), Mounting::Same).unwrap();
    for a in &same.angles {
        assert_eq!(a.delta_e00.value, 0.0);
        // Shared lines (the transform) cancel in a colour against itself; the
        // independent ones of both scans remain.
        assert_eq!(a.delta_l.u_shared, 0.0);
        assert!(a.delta_e00.u_independent > 0.0);
    }
    // A diffuse 1 % lighter: the ΔE00 found is the ΔE00 of the two colours.
    let lighter = report(&fit([9.09, 6.565, 2.02], [25.0, 20.0, 7.0], 0.07));
    let c = compare(&gold, &lighter, &Tolerances::default(), Mounting::Same).unwrap();
    for (a, (s, b)) in c.angles.iter().zip(gold.angles.iter().zip(&lighter.angles)) {
        assert!((a.delta_e00.value - ciede2000(s.lab(), b.lab())).abs() < 1e-12);
        assert!(a.delta_l.value > 0.0);
    }
}

#[test]
fn tolerances_name_angles_and_refuse_nonsense() {
    let t: Tolerances = serde_json::from_str(r#"{"delta_e00":{"default":1.0,"15":2.0}}"#).unwrap();
    t.check().unwrap();
    assert_eq!(t.delta_e00_at(15.0), 2.0);
    assert_eq!(t.delta_e00_at(45.0), 1.0);
    for bad in [
        r#"{"delta_e00":{"fifteen":2.0}}"#,
        r#"{"delta_e00":{"15":-1.0}}"#,
        r#"{"flop_index":0.0}"#,
    ] {
        let t: Tolerances = serde_json::from_str(bad).unwrap();
        assert!(t.check().is_err(), "{bad}");
    }
    assert_eq!(Verdict::judge(0.5, 0.3, 1.0), Verdict::Pass);
    assert_eq!(Verdict::judge(0.9, 0.3, 1.0), Verdict::Undecided);
    assert_eq!(Verdict::judge(1.5, 0.3, 1.0), Verdict::Fail);
}

#[test]
fn the_geometry_s_errors_cancel_only_within_one_mounting_the_white_s_always() {
    let standard = report(&fit([9.0, 6.5, 2.0], [25.0, 20.0, 7.0], 0.07));
    let bare = compare(&standard, &standard, &Tolerances::default(), Mounting::Same).unwrap();
    // Both scans moved alike by a camera offset (1 in L*) and a white (0.5 in L*).
    let mut moved = standard.clone();
    for a in &mut moved.angles {
        for (source, l) in [("camera_offset:ks_g", 1.0), ("white_reflectance:kd_g", 0.5)] {
            a.lines.push(gonio_processing::multi_angle::Line {
                source: source.into(),
                shared: true,
                lab: [l, 0.0, 0.0],
            });
        }
    }
    let u = |c: &gonio_processing::multi_angle::compare::Comparison, k: usize| {
        c.angles[k].delta_l.expanded
    };
    let same = compare(&moved, &moved, &Tolerances::default(), Mounting::Same).unwrap();
    let separate = compare(&moved, &moved, &Tolerances::default(), Mounting::Separate).unwrap();
    for k in 0..moved.angles.len() {
        // One mounting: both lines cancel exactly.
        assert!((u(&same, k) - u(&bare, k)).abs() < 1e-9, "{k}");
        // Each its own: the offset's line is each scan's own (u² grows by 1 + 1, U = 2u);
        // the white's still cancels.
        let grown = u(&separate, k).powi(2) - u(&bare, k).powi(2);
        assert!((grown - 8.0).abs() < 1e-6, "{k}: {grown}");
    }
}
