//! A study on synthetic data: samples and reference generated from one known
//! Cook–Torrance material, so the generating model must score near-zero errors.

use gonio_processing::brdf::{Model, Params, Roughness};
use gonio_processing::color::CameraModel;
use gonio_processing::reference::Reference;
use gonio_processing::samples::Sample;
use gonio_processing::study::{run_study, write_outputs, StudyError, StudyOptions, Variant};

/// A neutral (grey) material: coefficients proportional to the white's camera RGB, so
/// a flat spectral radiance factor reproduces its β exactly.
fn truth(camera: &CameraModel) -> Params {
    let w = camera.white_rgb();
    Params::shared(w.map(|c| 0.25 * c), w.map(|c| 0.04 * c), 0.3)
}

fn samples(params: &Params, theta_l: &[f64]) -> Vec<Sample> {
    let mut out = Vec::new();
    for &tl in theta_l {
        for step in 0..=60 {
            // Distant-source geometry: θi + θr = θL.
            let theta_r = -60.0 + 2.0 * f64::from(step);
            let theta_i = tl - theta_r;
            if theta_i.abs() < 75.0 {
                let rgb = Model::CookTorrance.evaluate(params, theta_i, theta_r);
                out.push(Sample {
                    theta_l: tl,
                    theta_i,
                    theta_r,
                    rgb,
                    ..Sample::default()
                });
            }
        }
    }
    out
}

/// Reference CSV on a 2.5° grid: flat spectrum β_G / 100 at every wavelength.
fn reference(params: &Params, camera: &CameraModel) -> Reference {
    let wavelengths: Vec<String> = (39..=73).map(|w| (10 * w).to_string()).collect();
    let mut csv = format!("theta_i,theta_r,{}\n", wavelengths.join(","));
    for i in -32..=32 {
        for r in -32..=32 {
            let (ti, tr) = (2.5 * f64::from(i), 2.5 * f64::from(r));
            let g = Model::CookTorrance.evaluate(params, ti, tr)[1] / camera.white_rgb()[1];
            let row = vec![format!("{g}"); wavelengths.len()].join(",");
            csv.push_str(&format!("{ti},{tr},{row}\n"));
        }
    }
    Reference::from_reader(csv.as_bytes(), "synthetic", camera).unwrap()
}

#[test]
fn generating_model_scores_near_zero_on_every_combination() {
    let camera = CameraModel::builtin();
    let params = truth(&camera);
    let theta_l = [-20.0, -30.0, -40.0];
    let samples = samples(&params, &theta_l);
    let reference = reference(&params, &camera);
    let report = run_study(&samples, &reference, &camera, &StudyOptions::default()).unwrap();

    assert_eq!(report.theta_l, theta_l.to_vec());
    assert_eq!(report.results.len(), 7 * 3, "7 combinations × 3 models");
    assert_eq!(
        report.points.len(),
        samples.len(),
        "the reference covers every sample"
    );
    let ct = Variant {
        model: Model::CookTorrance,
        roughness: Roughness::Shared,
    };
    for r in report.results.iter().filter(|r| r.variant == ct) {
        let s = r.outcome.as_ref().unwrap();
        for c in 0..3 {
            assert!(s.err_p[c] < 5e-3, "{:?}: ΔErr_p {:?}", r.theta_l, s.err_p);
        }
        assert!(
            s.delta_e_uv.unwrap() < 1e-3,
            "{:?}: ΔE {:?}",
            r.theta_l,
            s.delta_e_uv
        );
        let m = s.fit.params().m[0];
        assert!((m - 0.3).abs() < 0.01, "{:?}: m {m}", r.theta_l);
        assert!(s.nelder_mead_loss.is_some(), "Nelder–Mead was compared");
        // Held out: the other θL's points, none when every θL was fitted.
        match &s.held_out {
            Some(h) => {
                let other = samples
                    .iter()
                    .filter(|p| !r.theta_l.contains(&p.theta_l))
                    .count();
                assert_eq!(h.points, other, "{:?}", r.theta_l);
                assert!(h.err_p.iter().all(|&e| e < 5e-3), "{:?}: {h:?}", r.theta_l);
            }
            None => assert_eq!(r.theta_l.len(), 3),
        }
    }
    // Cook–Torrance–Fresnel on (noise-free) Cook–Torrance data: no colour shift, so it is
    // Cook–Torrance; Nelder–Mead is not its method.
    for r in report
        .results
        .iter()
        .filter(|r| r.variant.model == Model::CookTorranceFresnel)
    {
        let s = r.outcome.as_ref().unwrap();
        let shift = s.fit.colour_shift.unwrap();
        assert!(!shift.fitted, "{:?}: {shift:?}", r.theta_l);
        assert_eq!(s.fit.ks_90, Some(s.fit.ks));
        assert!(s.err_p.iter().all(|&e| e < 5e-3), "{:?}", r.theta_l);
        assert!(s.nelder_mead_loss.is_none());
    }
    let summary = report.summary();
    assert_eq!(summary.len(), 3 * 3, "3 variants × sizes 1..=3");
    let sizes: Vec<(usize, usize)> = summary.iter().map(|g| (g.size, g.fitted)).collect();
    assert_eq!(&sizes[..3], &[(1, 3), (2, 3), (3, 1)]);
    // Ward is not the generating model: it must do worse than Cook–Torrance.
    let median_g = |i: usize| summary[i].err_p[1].as_ref().unwrap().median;
    assert!(
        median_g(0) < median_g(3),
        "CT {} vs Ward {}",
        median_g(0),
        median_g(3)
    );

    let dir = tempfile::tempdir().unwrap();
    let written = write_outputs(&report, dir.path(), "synthetic").unwrap();
    for name in [
        "combinations.csv",
        "boxplots.csv",
        "local_minima.csv",
        "study.json",
        "fig6_g_channel.svg",
        "fig7_err_p_g.svg",
        "fig8_uv_chart.svg",
        "fig9_delta_e_uv.svg",
    ] {
        assert!(written.contains(&dir.path().join(name)), "{name} written");
    }
    let table = std::fs::read_to_string(dir.path().join("combinations.csv")).unwrap();
    assert_eq!(table.lines().count(), 1 + 21);
    assert!(table
        .lines()
        .nth(1)
        .unwrap()
        .starts_with("cook-torrance,shared,1,-20,ok,"));
}

#[test]
fn bad_inputs_are_typed_errors() {
    let camera = CameraModel::builtin();
    let params = truth(&camera);
    let reference = reference(&params, &camera);
    let options = StudyOptions::default();
    assert!(matches!(
        run_study(&[], &reference, &camera, &options),
        Err(StudyError::NoSamples)
    ));
    let mut bad = samples(&params, &[-30.0]);
    bad[3].rgb[1] = f64::NAN;
    let err = run_study(&bad, &reference, &camera, &options).unwrap_err();
    assert!(
        matches!(
            err,
            StudyError::NonFinite {
                index: 3,
                field: "g"
            }
        ),
        "{err}"
    );
    // Angles the reference does not cover.
    let outside: Vec<Sample> = samples(&params, &[-30.0])
        .into_iter()
        .map(|s| Sample { theta_i: 85.0, ..s })
        .collect();
    assert!(matches!(
        run_study(&outside, &reference, &camera, &options),
        Err(StudyError::NoOverlap { .. })
    ));
}
