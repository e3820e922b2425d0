//! θL combinations, box-plot statistics, Pareto fronts and the SVG figures of a study.

use gonio_processing::study::boxplot::BoxStats;
use gonio_processing::study::combinations::combinations;
use gonio_processing::study::figures::{box_plot_svg, xy_svg, BoxSeries, Mark, XyPlot, XySeries};

const SIX: [f64; 6] = [-20.0, -25.0, -30.0, -35.0, -40.0, -45.0];

#[test]
fn six_directions_give_63_distinct_combinations_binomially_sized() {
    let all = combinations(&SIX).unwrap();
    assert_eq!(all.len(), 63);
    for k in 1..=6 {
        let expected = [6, 15, 20, 15, 6, 1][k - 1];
        assert_eq!(
            all.iter().filter(|c| c.len() == k).count(),
            expected,
            "size {k}"
        );
    }
    let mut keys: Vec<String> = all.iter().map(|c| format!("{c:?}")).collect();
    keys.sort();
    keys.dedup();
    assert_eq!(keys.len(), 63, "combinations are distinct");
    assert!(
        all.iter().all(|c| c.windows(2).all(|w| w[0] > w[1])),
        "members keep input order"
    );
}

#[test]
fn box_stats_of_known_data_follow_type7_quartiles_and_tukey_whiskers() {
    // Sorted: 1..=9 and 30. Type-7 quartiles with n = 10: h = 9p.
    let values = [5.0, 1.0, 9.0, 2.0, 8.0, 3.0, 7.0, 4.0, 30.0, 6.0];
    let b = BoxStats::from_values(&values).unwrap();
    assert_eq!(b.count, 10);
    assert!((b.q1 - 3.25).abs() < 1e-12, "q1 {}", b.q1);
    assert!((b.median - 5.5).abs() < 1e-12);
    assert!((b.q3 - 7.75).abs() < 1e-12, "q3 {}", b.q3);
    // IQR 4.5: fences at -3.5 and 14.5.
    assert_eq!(b.whisker_low, 1.0);
    assert_eq!(b.whisker_high, 9.0);
    assert_eq!(b.outliers, vec![30.0]);
    assert_eq!((b.min, b.max), (1.0, 30.0));
}

#[test]
fn box_stats_ignore_non_finite_values_and_handle_tiny_groups() {
    assert!(BoxStats::from_values(&[]).is_none());
    assert!(BoxStats::from_values(&[f64::NAN, f64::INFINITY]).is_none());
    let one = BoxStats::from_values(&[f64::NAN, 0.4]).unwrap();
    assert_eq!(one.count, 1);
    assert_eq!((one.q1, one.median, one.q3), (0.4, 0.4, 0.4));
    assert_eq!((one.whisker_low, one.whisker_high), (0.4, 0.4));
    assert!(one.outliers.is_empty());
    let two = BoxStats::from_values(&[0.0, 10.0]).unwrap();
    assert_eq!((two.q1, two.median, two.q3), (2.5, 5.0, 7.5));
    assert_eq!((two.whisker_low, two.whisker_high), (0.0, 10.0));
}

#[test]
fn figures_are_written_as_svg_with_their_labels() {
    let dir = tempfile::tempdir().unwrap();
    let stats = |v: &[f64]| BoxStats::from_values(v).unwrap();
    let series = vec![
        BoxSeries {
            name: "Cook-Torrance".into(),
            groups: vec![(1, stats(&[0.1, 0.2, 0.3, 0.9])), (2, stats(&[0.1, 0.15]))],
        },
        BoxSeries {
            name: "Ward".into(),
            groups: vec![(1, stats(&[0.2, 0.4])), (2, stats(&[0.3]))],
        },
    ];
    let boxes = dir.path().join("box.svg");
    box_plot_svg(&boxes, "ΔErr_p (G)", "ΔErr_p", &series).unwrap();
    let text = std::fs::read_to_string(&boxes).unwrap();
    assert!(text.starts_with("<svg"), "an SVG document");
    assert!(text.contains("Cook-Torrance") && text.contains("Ward"));

    let plot = XyPlot {
        title: "Pareto".into(),
        x_label: "time (s)".into(),
        y_label: "error".into(),
        log_x: true,
        log_y: false,
        series: vec![
            XySeries {
                name: "settings".into(),
                mark: Mark::Points,
                segments: vec![vec![(1.0, 0.5), (10.0, 0.2), (0.0, 9.0), (100.0, f64::NAN)]],
            },
            XySeries {
                name: "front".into(),
                mark: Mark::Lines,
                segments: vec![vec![(1.0, 0.5), (10.0, 0.2)]],
            },
        ],
    };
    let xy = dir.path().join("xy.svg");
    xy_svg(&xy, &plot).unwrap();
    let text = std::fs::read_to_string(&xy).unwrap();
    assert!(text.contains("settings") && text.contains("front") && text.contains("time (s)"));
}

#[test]
fn figure_into_a_missing_directory_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("missing").join("fig.svg");
    let plot = XyPlot {
        title: "t".into(),
        x_label: "x".into(),
        y_label: "y".into(),
        log_x: false,
        log_y: false,
        series: vec![],
    };
    let err = xy_svg(&path, &plot).unwrap_err();
    assert!(err.to_string().contains("fig.svg"), "{err}");
}

#[test]
fn subsample_keeps_every_nth_sample_of_each_theta_l() {
    use gonio_processing::samples::Sample;
    use gonio_processing::study::subsample;
    let sample = |theta_l: f64, theta_r: f64| Sample {
        theta_l,
        theta_i: theta_l - theta_r,
        theta_r,
        rgb: [1.0, 1.0, 1.0],
        ..Sample::default()
    };
    // Interleaved θL: counting restarts per θL.
    let samples: Vec<Sample> = (0..10)
        .map(|k| sample(if k % 2 == 0 { -20.0 } else { -30.0 }, f64::from(k)))
        .collect();
    let kept: Vec<f64> = subsample(&samples, 2).iter().map(|s| s.theta_r).collect();
    assert_eq!(kept, vec![0.0, 1.0, 4.0, 5.0, 8.0, 9.0]);
    assert_eq!(subsample(&samples, 1), samples);
    assert_eq!(subsample(&samples, 100).len(), 2, "the first of each θL");
}
