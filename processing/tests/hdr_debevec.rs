//! Debevec–Malik on 8-bit non-linear brackets with noise and clipping, against OpenCV's
//! `CalibrateDebevec` + `MergeDebevec` (documented defaults: 70 samples, λ = 10, grid
//! sampling) on the very same frames.
//!
//! Error measure, the same for both: each channel's radiance is known only up to a
//! scale (both fix g(128) = 0 per channel), so each channel is scaled by the median of
//! truth / estimate over the evaluated values; the relative error is then
//! |scaled estimate − truth| / truth, pooled over the three channels, and summarised by
//! its median and 99th percentile. Evaluated: every value that some frame of the bracket
//! records, noise aside, between levels 4 and 251 (values black or clipped in every
//! frame cannot be measured by either method and are left out of both).
//!
//! OpenCV runs through `tests/opencv_debevec.py` (python3 with opencv-python-headless and
//! numpy, which scripts/test.sh installs). Where it cannot run, the comparison is skipped
//! with a message unless `GONIO_REQUIRE_OPENCV` is set (scripts/test.sh sets it); our own
//! thresholds are checked either way.

use std::path::{Path, PathBuf};
use std::process::Command;

use gonio_processing::capture::{Frame, Response, Sidecar};
use gonio_processing::hdr::{self, MergeMethod, MergeOptions};

mod common;
use common::Rng;

const W: usize = 160;
const H: usize = 120;

/// Camera: a filmic response (gamma 2.2 with a soft S), shot and read noise on the
/// normalised exposure x (1 = clipping), 8-bit quantisation.
struct Camera {
    /// Electrons at x = 1 (shot noise variance x / full_well).
    full_well: f64,
    /// Read noise standard deviation in units of x.
    read_noise: f64,
}

impl Camera {
    /// Level 0..255 (real-valued) of a noiseless exposure x.
    fn level(x: f64) -> f64 {
        let u = x.clamp(0.0, 1.0).powf(1.0 / 2.2);
        255.0 * (0.8 * u + 0.2 * u * u * (3.0 - 2.0 * u))
    }

    fn capture(&self, x: f64, rng: &mut Rng) -> u8 {
        let sigma = (x.max(0.0) / self.full_well + self.read_noise * self.read_noise).sqrt();
        Self::level(x + sigma * rng.normal()).round() as u8
    }
}

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

struct Bracket {
    shutters: Vec<f64>,
    /// Per frame, interleaved RGB levels.
    frames: Vec<Vec<u8>>,
    /// Which values some frame records between levels 4 and 251, noise aside.
    measurable: Vec<bool>,
}

fn capture(radiance: &[f64], shutters: &[f64], camera: &Camera, seed: u64) -> Bracket {
    let mut rng = Rng(seed);
    let frames = shutters
        .iter()
        .map(|&t| {
            radiance
                .iter()
                .map(|&e| camera.capture(e * t, &mut rng))
                .collect()
        })
        .collect();
    let measurable = radiance
        .iter()
        .map(|&e| {
            shutters
                .iter()
                .any(|&t| (4.0..=251.0).contains(&Camera::level(e * t)))
        })
        .collect();
    Bracket {
        shutters: shutters.to_vec(),
        frames,
        measurable,
    }
}

/// Our merge of the bracket: radiance and per-pixel mask.
fn gonio_merge(bracket: &Bracket) -> (Vec<f64>, Vec<u8>) {
    let frames: Vec<Frame> = bracket
        .shutters
        .iter()
        .zip(&bracket.frames)
        .map(|(&t, levels)| {
            let sidecar = Sidecar {
                shutter_s: t,
                iso: Some(100.0),
                theta_l: -30.0,
                camera: "8-bit test camera".into(),
                time: "2026-11-23T14:00:00Z".into(),
                black_level: None,
                white_level: None,
                response: Response::Nonlinear,
                significant_bits: None,
                aperture: None,
                width: None,
                height: None,
            };
            let data = levels.iter().map(|&z| u16::from(z)).collect();
            Frame::from_counts(PathBuf::from("bracket.tiff"), sidecar, W, H, data, 255.0).unwrap()
        })
        .collect();
    let options = MergeOptions {
        method: MergeMethod::DebevecMalik,
        ..MergeOptions::default()
    };
    let merged = hdr::merge(&frames, &options).unwrap();
    assert_eq!(merged.info.method, "debevec-malik");
    assert!(merged.rgb.iter().all(|v| v.is_finite() && *v >= 0.0));
    (
        merged.rgb.iter().map(|&v| f64::from(v)).collect(),
        merged.mask,
    )
}

/// OpenCV's merge of the same frames, or why it could not run.
fn opencv_merge(bracket: &Bracket, dir: &Path) -> Result<Vec<f64>, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/opencv_debevec.py");
    let mut args = vec![script.display().to_string(), W.to_string(), H.to_string()];
    let out = dir.join("opencv.f32");
    args.push(out.display().to_string());
    for (j, (levels, t)) in bracket.frames.iter().zip(&bracket.shutters).enumerate() {
        let path = dir.join(format!("frame{j}.u8"));
        std::fs::write(&path, levels).unwrap();
        args.push(format!("{}:{t}", path.display()));
    }
    let run = Command::new("python3")
        .args(&args)
        .output()
        .map_err(|e| format!("python3: {e}"))?;
    if !run.status.success() {
        return Err(String::from_utf8_lossy(&run.stderr).trim().to_string());
    }
    eprintln!("OpenCV {}", String::from_utf8_lossy(&run.stdout).trim());
    let bytes = std::fs::read(&out).map_err(|e| e.to_string())?;
    assert_eq!(bytes.len(), 4 * 3 * W * H, "OpenCV output size");
    Ok(bytes
        .chunks_exact(4)
        .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])))
        .collect())
}

/// Median and 99th percentile of the relative error after the per-channel median scale.
fn relative_errors(estimate: &[f64], truth: &[f64], measurable: &[bool]) -> (f64, f64) {
    let mut errors = Vec::new();
    for c in 0..3 {
        let values: Vec<(f64, f64)> = (c..truth.len())
            .step_by(3)
            .filter(|&i| measurable[i])
            .map(|i| (estimate[i], truth[i]))
            .collect();
        let mut ratios: Vec<f64> = values
            .iter()
            .filter(|(e, _)| *e > 0.0 && e.is_finite())
            .map(|(e, t)| t / e)
            .collect();
        ratios.sort_by(f64::total_cmp);
        let scale = ratios[ratios.len() / 2];
        errors.extend(values.iter().map(|(e, t)| {
            let e = (e * scale - t).abs() / t;
            if e.is_finite() {
                e
            } else {
                f64::INFINITY
            }
        }));
    }
    errors.sort_by(f64::total_cmp);
    let at = |q: f64| errors[((errors.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99))
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
/// and a noisy one (2 000 e⁻, 10⁻³).
fn cases() -> Vec<Case> {
    let quiet = || Camera {
        full_well: 37_000.0,
        read_noise: 3e-4,
    };
    let noisy = || Camera {
        full_well: 2000.0,
        read_noise: 1e-3,
    };
    let two_stops: Vec<f64> = (0..5).map(|k| 4f64.powi(k - 4)).collect();
    let one_stop: Vec<f64> = (0..7).map(|k| 2f64.powi(k - 6)).collect();
    vec![
        Case {
            name: "5 frames 2 stops apart, base ISO",
            shutters: two_stops.clone(),
            camera: quiet(),
            max_median: 0.008,
            max_p99: 0.06,
        },
        Case {
            name: "7 frames 1 stop apart, base ISO",
            shutters: one_stop.clone(),
            camera: quiet(),
            max_median: 0.006,
            max_p99: 0.05,
        },
        Case {
            name: "5 frames 2 stops apart, noisy",
            shutters: two_stops,
            camera: noisy(),
            max_median: 0.03,
            max_p99: 0.21,
        },
        Case {
            name: "7 frames 1 stop apart, noisy",
            shutters: one_stop,
            camera: noisy(),
            max_median: 0.024,
            max_p99: 0.2,
        },
    ]
}

#[test]
fn debevec_malik_is_at_least_as_good_as_opencv() {
    let dir = tempfile::tempdir().unwrap();
    let require = std::env::var_os("GONIO_REQUIRE_OPENCV").is_some();
    for (k, case) in cases().iter().enumerate() {
        let truth = scene(&case.shutters, 17 + k as u64);
        let bracket = capture(&truth, &case.shutters, &case.camera, 91 + k as u64);
        let (radiance, mask) = gonio_merge(&bracket);
        // Pixels clipped in every frame are flagged, not guessed.
        let shortest = case.shutters.iter().copied().fold(f64::INFINITY, f64::min);
        for (p, flags) in mask.iter().enumerate() {
            if (0..3).all(|c| Camera::level(truth[3 * p + c] * shortest) >= 255.0) {
                assert!(flags & hdr::SATURATED != 0, "{}: pixel {p}", case.name);
            }
        }
        let (median, p99) = relative_errors(&radiance, &truth, &bracket.measurable);
        eprintln!("{}: gonio median {median:.4}, p99 {p99:.4}", case.name);
        assert!(
            median <= case.max_median && p99 <= case.max_p99,
            "{}: median {median}, p99 {p99}",
            case.name
        );
        match opencv_merge(&bracket, dir.path()) {
            Ok(opencv) => {
                let (cv_median, cv_p99) = relative_errors(&opencv, &truth, &bracket.measurable);
                eprintln!(
                    "{}: OpenCV median {cv_median:.4}, p99 {cv_p99:.4}",
                    case.name
                );
                assert!(
                    median <= cv_median && p99 <= cv_p99,
                    "{}: gonio median {median}, p99 {p99}; OpenCV {cv_median}, {cv_p99}",
                    case.name
                );
            }
            Err(why) if !require => eprintln!("OpenCV comparison skipped: {why}"),
            Err(why) => panic!("OpenCV could not run: {why}"),
        }
    }
}
