//! 8-bit non-linear brackets of known radiance for the Debevec–Malik tests, our merge and
//! OpenCV's of them, and the error measure both are judged by.
//!
//! Error measure, the same for every method: each channel's radiance is known only up to
//! a scale (Debevec–Malik fixes g(128) = 0 per channel), so each channel is scaled by the
//! median of truth / estimate over the evaluated values; the relative error is then
//! |scaled estimate − truth| / truth, pooled over the three channels. Evaluated: every
//! value that some frame of the bracket records, noise aside, between levels 4 and 251
//! (values black or clipped in every frame cannot be measured by any method and are left
//! out of all).
//!
//! OpenCV (`CalibrateDebevec` + `MergeDebevec` with its documented defaults: 70 samples,
//! λ = 10, grid sampling) runs through `tests/opencv_debevec.py` under `GONIO_PYTHON`
//! (else python3), with opencv-python-headless and numpy (scripts/test.sh installs them
//! in .venv-test and sets it). Where it cannot
//! run, [`opencv_or_skip`] says why and the comparison is skipped, unless
//! `GONIO_REQUIRE_OPENCV` is set (scripts/test.sh sets it).

use std::path::{Path, PathBuf};
use std::process::Command;

use gonio_processing::capture::{Frame, Response, Sidecar};
use gonio_processing::hdr::{self, MergeMethod, MergeOptions};

use crate::common::Rng;

/// A camera's response from normalised exposure x (1 = clipping) to level 0..255.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Curve {
    /// Pure gamma 2.2.
    Gamma,
    /// The sRGB transfer function (linear toe below 0.0031308).
    Srgb,
    /// Gamma 2.2 blended with a soft S: 0.8u + 0.2·smoothstep(u), u = x^(1/2.2).
    SoftS,
    /// A filmic S-curve: ACES's tone curve (Narkowicz's fit) of 7.24·x, which reaches
    /// white at x = 1, then sRGB-encoded; a flat toe and a long shoulder.
    Filmic,
}

impl Curve {
    pub fn name(self) -> &'static str {
        match self {
            Curve::Gamma => "gamma 2.2",
            Curve::Srgb => "sRGB",
            Curve::SoftS => "soft S",
            Curve::Filmic => "filmic",
        }
    }

    /// Level 0..255 (real-valued) of a noiseless exposure x.
    pub fn level(self, x: f64) -> f64 {
        let x = x.clamp(0.0, 1.0);
        let srgb = |v: f64| {
            if v <= 0.003_130_8 {
                12.92 * v
            } else {
                1.055 * v.powf(1.0 / 2.4) - 0.055
            }
        };
        let v = match self {
            Curve::Gamma => x.powf(1.0 / 2.2),
            Curve::Srgb => srgb(x),
            Curve::SoftS => {
                let u = x.powf(1.0 / 2.2);
                0.8 * u + 0.2 * u * u * (3.0 - 2.0 * u)
            }
            Curve::Filmic => {
                let a = 7.24 * x;
                let tone = a * (2.51 * a + 0.03) / (a * (2.43 * a + 0.59) + 0.14);
                srgb(tone.min(1.0))
            }
        };
        255.0 * v
    }
}

/// An 8-bit camera: shot and read noise on the normalised exposure x, then its curve.
#[derive(Debug, Clone, Copy)]
pub struct Camera {
    pub curve: Curve,
    /// Electrons at x = 1 (shot noise variance x / full_well).
    pub full_well: f64,
    /// Read noise standard deviation in units of x.
    pub read_noise: f64,
}

impl Camera {
    pub fn capture(&self, x: f64, rng: &mut Rng) -> u8 {
        let sigma = (x.max(0.0) / self.full_well + self.read_noise * self.read_noise).sqrt();
        self.curve.level(x + sigma * rng.normal()).round() as u8
    }
}

/// A captured bracket and what of it can be evaluated.
pub struct Bracket {
    pub width: usize,
    pub height: usize,
    pub shutters: Vec<f64>,
    /// Per frame, interleaved RGB levels.
    pub frames: Vec<Vec<u8>>,
    /// Which values some frame records between levels 4 and 251, noise aside.
    pub measurable: Vec<bool>,
}

/// The bracket of `radiance` (interleaved RGB of `width` × `height` pixels) that `camera`
/// takes at `shutters`.
pub fn capture(
    radiance: &[f64],
    width: usize,
    height: usize,
    shutters: &[f64],
    camera: &Camera,
    seed: u64,
) -> Bracket {
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
                .any(|&t| (4.0..=251.0).contains(&camera.curve.level(e * t)))
        })
        .collect();
    Bracket {
        width,
        height,
        shutters: shutters.to_vec(),
        frames,
        measurable,
    }
}

/// Our Debevec–Malik merge of the bracket: radiance and per-pixel mask.
pub fn gonio_merge(bracket: &Bracket) -> (Vec<f64>, Vec<u8>) {
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
            let path = PathBuf::from("bracket.tiff");
            Frame::from_counts(path, sidecar, bracket.width, bracket.height, data, 255.0).unwrap()
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

/// OpenCV's merges of the brackets, in one process (with `dir` for its files), or why it
/// could not run.
pub fn opencv_merge(brackets: &[&Bracket], dir: &Path) -> Result<Vec<Vec<f64>>, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/opencv_debevec.py");
    let mut args = vec![script.display().to_string()];
    let mut outputs = Vec::new();
    for (k, bracket) in brackets.iter().enumerate() {
        if k > 0 {
            args.push("--".into());
        }
        let out = dir.join(format!("opencv{k}.f32"));
        args.extend([
            bracket.width.to_string(),
            bracket.height.to_string(),
            out.display().to_string(),
        ]);
        for (j, (levels, t)) in bracket.frames.iter().zip(&bracket.shutters).enumerate() {
            let path = dir.join(format!("bracket{k}_frame{j}.u8"));
            std::fs::write(&path, levels).unwrap();
            args.push(format!("{}:{t}", path.display()));
        }
        outputs.push(out);
    }
    // The tests' own interpreter (scripts/test.sh: .venv-test), else python3 on PATH.
    let python = std::env::var("GONIO_PYTHON").unwrap_or_else(|_| "python3".into());
    let run = Command::new(&python)
        .args(&args)
        .output()
        .map_err(|e| format!("{python}: {e}"))?;
    if !run.status.success() {
        return Err(String::from_utf8_lossy(&run.stderr).trim().to_string());
    }
    brackets
        .iter()
        .zip(&outputs)
        .map(|(bracket, out)| {
            let bytes = std::fs::read(out).map_err(|e| e.to_string())?;
            assert_eq!(
                bytes.len(),
                4 * 3 * bracket.width * bracket.height,
                "OpenCV output size"
            );
            Ok(bytes
                .chunks_exact(4)
                .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])))
                .collect())
        })
        .collect()
}

/// OpenCV's merges, or `None` after saying why it could not run; panics instead when
/// `GONIO_REQUIRE_OPENCV` is set.
pub fn opencv_or_skip(brackets: &[&Bracket], dir: &Path) -> Option<Vec<Vec<f64>>> {
    match opencv_merge(brackets, dir) {
        Ok(radiance) => Some(radiance),
        Err(why) if std::env::var_os("GONIO_REQUIRE_OPENCV").is_none() => {
            eprintln!("OpenCV comparison skipped: {why}");
            None
        }
        Err(why) => panic!("OpenCV could not run: {why}"),
    }
}

/// The indices of the evaluated values, channel by channel: the order of
/// [`relative_errors`].
pub fn evaluated(measurable: &[bool]) -> Vec<usize> {
    (0..3)
        .flat_map(|c| (c..measurable.len()).step_by(3))
        .filter(|&i| measurable[i])
        .collect()
}

/// The relative error of every evaluated value after the per-channel median scale (see
/// the module comment), in the order of [`evaluated`]; a value with no finite estimate
/// counts as an infinite error.
pub fn relative_errors(estimate: &[f64], truth: &[f64], measurable: &[bool]) -> Vec<f64> {
    let values = evaluated(measurable);
    let mut scale = [f64::NAN; 3];
    for (c, scale) in scale.iter_mut().enumerate() {
        let mut ratios: Vec<f64> = values
            .iter()
            .filter(|&&i| i % 3 == c && estimate[i] > 0.0 && estimate[i].is_finite())
            .map(|&i| truth[i] / estimate[i])
            .collect();
        ratios.sort_by(f64::total_cmp);
        if let Some(&median) = ratios.get(ratios.len() / 2) {
            *scale = median;
        }
    }
    values
        .iter()
        .map(|&i| {
            let e = (estimate[i] * scale[i % 3] - truth[i]).abs() / truth[i];
            if e.is_finite() {
                e
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

/// Median and 99th percentile of `errors`.
pub fn median_p99(errors: &[f64]) -> (f64, f64) {
    let mut sorted = errors.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99))
}
