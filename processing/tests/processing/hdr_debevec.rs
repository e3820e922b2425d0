//! Debevec–Malik on 8-bit non-linear brackets with noise and clipping, against OpenCV's
//! `CalibrateDebevec` + `MergeDebevec` on the very same frames, with the error measure of
//! `tests/bracket` (per-channel median scale, median and 99th percentile of the relative
//! error over the values some frame records). Our own thresholds are checked whether or
//! not OpenCV can run.

use gonio_processing::hdr;

use crate::bracket;
use crate::common;
use bracket::{Camera, Curve};
use common::Rng;

const W: usize = 160;
const H: usize = 120;

/// A scene of W×H pixels matched to a bracket, as auto-bracketing makes it: each channel
/// a random fraction 0.15–1 of a luminance that is log-uniform between the values that
/// give x = 0.01 in the longest exposure (for the darkest chroma) and x = 0.8 in the
/// shortest; plus 2 % of pixels clipped in every frame and 2 % black in every frame.
fn scene(shutters: &[f64], seed: u64) -> Vec<f64> {
    let longest = shutters.iter().copied().fold(0.0, f64::max);
    let shortest = shutters.iter().copied().fold(f64::INFINITY, f64::min);
    let (lo, hi) = (0.01 / 0.15 / longest, 0.8 / shortest);
    let mut rng = Rng(seed);
    (0..W * H)
        .flat_map(|_| {
            let kind = rng.uniform();
            let luminance = if kind < 0.02 {
                100.0 / shortest
            } else if kind < 0.04 {
                1e-7 / longest
            } else {
                lo * (hi / lo).powf(rng.uniform())
            };
            let chroma: [f64; 3] = std::array::from_fn(|_| 0.15 + 0.85 * rng.uniform());
            chroma.map(|k| luminance * k)
        })
        .collect()
}

struct Case {
    name: &'static str,
    shutters: Vec<f64>,
    camera: Camera,
    /// Our own bounds on the median and 99th-percentile relative error.
    max_median: f64,
    max_p99: f64,
}

/// Two brackets (5 frames 2 stops apart, 7 frames 1 stop apart) with two cameras: the
/// emulator's noise at base ISO (≈ 37 000 e⁻ full well, read noise 3·10⁻⁴ of the range)
/// and a noisy one (2 000 e⁻, 10⁻³); each case with another of the four responses.
fn cases() -> Vec<Case> {
    let quiet = |curve| Camera {
        curve,
        full_well: 37_000.0,
        read_noise: 3e-4,
    };
    let noisy = |curve| Camera {
        curve,
        full_well: 2000.0,
        read_noise: 1e-3,
    };
    let two_stops: Vec<f64> = (0..5).map(|k| 4f64.powi(k - 4)).collect();
    let one_stop: Vec<f64> = (0..7).map(|k| 2f64.powi(k - 6)).collect();
    vec![
        Case {
            name: "5 frames 2 stops apart, base ISO",
            shutters: two_stops.clone(),
            camera: quiet(Curve::SoftS),
            max_median: 0.008,
            max_p99: 0.06,
        },
        Case {
            name: "7 frames 1 stop apart, base ISO",
            shutters: one_stop.clone(),
            camera: quiet(Curve::Gamma),
            max_median: 0.006,
            max_p99: 0.05,
        },
        Case {
            name: "5 frames 2 stops apart, noisy",
            shutters: two_stops,
            camera: noisy(Curve::Srgb),
            max_median: 0.03,
            max_p99: 0.21,
        },
        Case {
            name: "7 frames 1 stop apart, noisy",
            shutters: one_stop,
            camera: noisy(Curve::Filmic),
            max_median: 0.036,
            max_p99: 0.2,
        },
    ]
}

#[test]
fn debevec_malik_is_at_least_as_good_as_opencv() {
    let dir = tempfile::tempdir().unwrap();
    let cases = cases();
    let mut runs = Vec::new();
    for (k, case) in cases.iter().enumerate() {
        let truth = scene(&case.shutters, 17 + k as u64);
        let bracket = bracket::capture(&truth, W, H, &case.shutters, &case.camera, 91 + k as u64);
        let (radiance, mask) = bracket::gonio_merge(&bracket);
        // Pixels clipped in every frame are flagged, not guessed.
        let shortest = case.shutters.iter().copied().fold(f64::INFINITY, f64::min);
        for (p, flags) in mask.iter().enumerate() {
            if (0..3).all(|c| case.camera.curve.level(truth[3 * p + c] * shortest) >= 255.0) {
                assert!(flags & hdr::SATURATED != 0, "{}: pixel {p}", case.name);
            }
        }
        let errors = bracket::relative_errors(&radiance, &truth, &bracket.measurable);
        let (median, p99) = bracket::median_p99(&errors);
        eprintln!(
            "{} ({}): gonio median {median:.4}, p99 {p99:.4}",
            case.name,
            case.camera.curve.name()
        );
        assert!(
            median <= case.max_median && p99 <= case.max_p99,
            "{}: median {median}, p99 {p99}",
            case.name
        );
        runs.push((truth, bracket, median, p99));
    }
    let brackets: Vec<&bracket::Bracket> = runs.iter().map(|run| &run.1).collect();
    let Some(opencv) = bracket::opencv_or_skip(&brackets, dir.path()) else {
        return;
    };
    for ((case, (truth, bracket, median, p99)), opencv) in cases.iter().zip(&runs).zip(opencv) {
        let errors = bracket::relative_errors(&opencv, truth, &bracket.measurable);
        let (cv_median, cv_p99) = bracket::median_p99(&errors);
        eprintln!(
            "{}: OpenCV median {cv_median:.4}, p99 {cv_p99:.4}",
            case.name
        );
        assert!(
            median <= &cv_median && p99 <= &cv_p99,
            "{}: gonio median {median}, p99 {p99}; OpenCV {cv_median}, {cv_p99}",
            case.name
        );
    }
}
