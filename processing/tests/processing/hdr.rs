//! HDR merge: brackets of known radiance, hard cases, OpenEXR output.

use std::path::PathBuf;

use gonio_processing::capture::{Frame, Response, Sidecar};
use gonio_processing::hdr::{
    self, HdrError, MergeMethod, MergeOptions, NoiseModel, SATURATED, UNDEREXPOSED,
};

use crate::common;
use common::Rng;

const W: usize = 64;
const H: usize = 48;
const BLACK: f64 = 600.0;
const WHITE: f64 = 60_000.0;
const BRACKET: [f64; 7] = [
    1.0 / 100.0,
    1.0 / 50.0,
    1.0 / 25.0,
    1.0 / 13.0,
    1.0 / 8.0,
    1.0 / 4.0,
    1.0 / 2.0,
];

/// Known radiance (normalised signal per second at ISO 100) spanning 3.5 decades.
fn radiance(x: usize, y: usize, c: usize) -> f64 {
    let t = (x + W * y) as f64 / (W * H - 1) as f64;
    0.02 * 10f64.powf(3.5 * t) * [1.0, 0.8, 0.6][c]
}

/// Standard deviation of a single-frame radiance estimate under the default noise.
fn single_frame_sigma(radiance: f64, shutter_s: f64) -> f64 {
    let noise = NoiseModel::default();
    let s = radiance * shutter_s;
    (s / noise.full_well_electrons + noise.read_noise.powi(2)).sqrt() / shutter_s
}

fn sidecar(shutter_s: f64, response: Response) -> Sidecar {
    Sidecar {
        shutter_s,
        iso: Some(100.0),
        theta_l: -30.0,
        camera: "test".into(),
        time: "2026-11-23T14:00:00Z".into(),
        black_level: Some(BLACK),
        white_level: Some(WHITE),
        response,
        significant_bits: None,
        aperture: None,
        width: None,
        height: None,
    }
}

/// A linear raw frame of `radiance` with shot and read noise from `noise`.
fn linear_frame(
    shutter_s: f64,
    noise: &NoiseModel,
    rng: &mut Rng,
    scene: impl Fn(usize, usize, usize) -> f64,
) -> Frame {
    let mut data = Vec::with_capacity(W * H * 3);
    for y in 0..H {
        for x in 0..W {
            for c in 0..3 {
                let s = scene(x, y, c) * shutter_s;
                let sigma =
                    (s / noise.full_well_electrons + noise.read_noise * noise.read_noise).sqrt();
                let signal = s + sigma * rng.normal();
                let count = BLACK + signal * (WHITE - BLACK);
                data.push(count.round().clamp(0.0, 65_535.0) as u16);
            }
        }
    }
    counts_frame(W, H, shutter_s, data)
}

/// A linear 16-bit frame of w × h pixels of `data` at `shutter_s`.
fn counts_frame(w: usize, h: usize, shutter_s: f64, data: Vec<u16>) -> Frame {
    let path = PathBuf::from(format!("t{shutter_s}.tiff"));
    let sidecar = sidecar(shutter_s, Response::Linear);
    Frame::from_counts(path, sidecar, w, h, data, 65_535.0).unwrap()
}

fn bracket(shutters: &[f64], scene: impl Fn(usize, usize, usize) -> f64 + Copy) -> Vec<Frame> {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let noise = NoiseModel::default();
    shutters
        .iter()
        .map(|&t| linear_frame(t, &noise, &mut rng, scene))
        .collect()
}

#[test]
fn linear_bracket_merges_back_to_the_known_radiance_within_the_noise() {
    let frames = bracket(&BRACKET, radiance);
    let merged = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    assert_eq!(merged.info.method, "linear");
    assert_eq!(merged.count_flagged(SATURATED | UNDEREXPOSED), 0);
    let mut worst_z: f64 = 0.0;
    for y in 0..H {
        for x in 0..W {
            for (c, got) in merged.pixel(x, y).into_iter().enumerate() {
                let truth = radiance(x, y, c);
                // Noise of the best single frame bounds the merged noise from above.
                let t = BRACKET
                    .iter()
                    .copied()
                    .filter(|&t| truth * t <= 0.98)
                    .fold(0.0, f64::max);
                let sigma = single_frame_sigma(truth, t);
                worst_z = worst_z.max((f64::from(got) - truth).abs() / sigma);
            }
        }
    }
    // 9216 values: a correct merge stays within 4.5 σ of the best single frame.
    assert!(worst_z < 4.5, "worst deviation {worst_z} σ");
}

#[test]
fn frame_order_and_duplicated_exposures_do_not_matter() {
    let frames = bracket(&BRACKET, radiance);
    let forward = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    let mut shuffled = frames.clone();
    shuffled.reverse();
    shuffled.swap(1, 4);
    let backward = hdr::merge(&shuffled, &MergeOptions::default()).unwrap();
    for (a, b) in forward.rgb.iter().zip(&backward.rgb) {
        assert!((a - b).abs() <= 1e-5 * a.abs().max(1e-3), "{a} vs {b}");
    }
    // The same exposure three times (three noisy frames) merges to the truth with
    // the noise of one frame divided by √3.
    let thrice = bracket(&[0.1, 0.1, 0.1], |_, _, c| 2.0 + c as f64);
    let merged = hdr::merge(&thrice, &MergeOptions::default()).unwrap();
    let mut sum_sq = 0.0;
    for (i, v) in merged.rgb.iter().enumerate() {
        let truth = 2.0 + (i % 3) as f64;
        let z = (f64::from(*v) - truth) / (single_frame_sigma(truth, 0.1) / 3f64.sqrt());
        assert!(z.abs() < 5.0, "{v} vs {truth}");
        sum_sq += z * z;
    }
    let rms_z = (sum_sq / merged.rgb.len() as f64).sqrt();
    assert!((0.8..1.2).contains(&rms_z), "rms deviation {rms_z} σ");
}

#[test]
fn single_exposure_merges_linearly_and_is_refused_by_debevec_malik() {
    let frames = bracket(&[0.05], |_, _, _| 4.0);
    let merged = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    let sigma = single_frame_sigma(4.0, 0.05);
    for v in &merged.rgb {
        assert!((f64::from(*v) - 4.0).abs() < 5.0 * sigma, "{v}");
    }
    let dm = MergeOptions {
        method: MergeMethod::DebevecMalik,
        ..MergeOptions::default()
    };
    assert!(matches!(
        hdr::merge(&frames, &dm),
        Err(HdrError::SingleExposure)
    ));
    // Two frames of the same exposure are still a single exposure.
    let same = bracket(&[0.05, 0.05], |_, _, _| 4.0);
    assert!(matches!(
        hdr::merge(&same, &dm),
        Err(HdrError::SingleExposure)
    ));
}

#[test]
fn all_saturated_is_flagged_with_a_finite_lower_bound() {
    let frames = bracket(&[0.1, 0.5, 1.0], |_, _, _| 1.0e4);
    let merged = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    assert_eq!(merged.count_flagged(SATURATED), W * H);
    for v in &merged.rgb {
        assert!(v.is_finite());
        // Lower bound from the shortest exposure: 0.98 / 0.1.
        assert!((f64::from(*v) - 9.8).abs() < 1e-4, "{v}");
    }
    let dm = MergeOptions {
        method: MergeMethod::DebevecMalik,
        ..MergeOptions::default()
    };
    let merged = hdr::merge(&frames, &dm).unwrap();
    assert_eq!(merged.count_flagged(SATURATED), W * H);
    assert!(merged.rgb.iter().all(|v| v.is_finite() && *v > 0.0));
}

#[test]
fn all_black_is_flagged_as_zero() {
    let frames = bracket(&[0.01, 0.02], |_, _, _| 0.0);
    for method in [MergeMethod::Linear, MergeMethod::DebevecMalik] {
        let options = MergeOptions {
            method,
            ..MergeOptions::default()
        };
        let merged = hdr::merge(&frames, &options).unwrap();
        assert_eq!(merged.count_flagged(UNDEREXPOSED), W * H, "{method:?}");
        assert!(merged.rgb.iter().all(|&v| v == 0.0), "{method:?}");
    }
}

#[test]
fn brackets_that_do_not_belong_together_are_refused() {
    let mut frames = bracket(&[0.01, 0.02], radiance);
    frames[1].sidecar.theta_l = -35.0;
    assert!(matches!(
        hdr::merge(&frames, &MergeOptions::default()),
        Err(HdrError::ThetaMismatch { .. })
    ));
    let mut frames = bracket(&[0.01, 0.02], radiance);
    frames[1].sidecar.response = Response::Nonlinear;
    assert!(matches!(
        hdr::merge(&frames, &MergeOptions::default()),
        Err(HdrError::MixedResponse { .. })
    ));
    let mut frames = bracket(&[0.01, 0.02], radiance);
    frames[1].width = W / 2;
    assert!(matches!(
        hdr::merge(&frames, &MergeOptions::default()),
        Err(HdrError::SizeMismatch { .. })
    ));
    assert!(matches!(
        hdr::merge(&[], &MergeOptions::default()),
        Err(HdrError::NoFrames)
    ));
}

/// Noise-free 8-bit frames of `scene` through a gamma 2.2 response (x = 20·radiance·t).
fn gamma_frames(shutters: &[f64], scene: impl Fn(usize, usize, usize) -> f64) -> Vec<Frame> {
    shutters
        .iter()
        .map(|&t| {
            let data = (0..H)
                .flat_map(|y| (0..W).flat_map(move |x| (0..3).map(move |c| (x, y, c))))
                .map(|(x, y, c)| {
                    let exposure = (scene(x, y, c) * t * 20.0).min(1.0);
                    (255.0 * exposure.powf(1.0 / 2.2)).round() as u16
                })
                .collect();
            let mut side = sidecar(t, Response::Nonlinear);
            side.black_level = None;
            side.white_level = None;
            Frame::from_counts(PathBuf::from("nl.tiff"), side, W, H, data, 255.0).unwrap()
        })
        .collect()
}

/// 8-bit frames through a gamma-like response: the recovered radiance must be
/// proportional to the truth (Debevec–Malik fixes only the scale).
#[test]
fn debevec_malik_recovers_radiance_up_to_scale() {
    let scene = |x: usize, y: usize, c: usize| {
        0.01 * 10f64.powf(2.5 * (x + W * y) as f64 / (W * H - 1) as f64) * [1.0, 0.7, 0.5][c]
    };
    let frames = gamma_frames(&[1.0 / 64.0, 1.0 / 16.0, 1.0 / 4.0, 1.0], scene);
    let merged = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    assert_eq!(merged.info.method, "debevec-malik");
    for c in 0..3 {
        let logs: Vec<f64> = (0..W * H)
            .map(|p| (f64::from(merged.rgb[3 * p + c]) / scene(p % W, p / W, c)).ln())
            .collect();
        let mean = logs.iter().sum::<f64>() / logs.len() as f64;
        let spread = logs.iter().map(|l| (l - mean).abs()).fold(0.0, f64::max);
        assert!(spread < 0.03, "channel {c}: ln ratio varies by {spread}");
    }
}

/// Brackets that constrain the response little or not at all still merge to finite,
/// non-negative values: exposures 12 stops apart (no pixel usable in both frames, so
/// the response is taken as linear), one flat grey (a single level per frame), and a
/// 2-frame bracket of a scene half clipped.
#[test]
fn debevec_malik_copes_with_brackets_that_barely_constrain_it() {
    let dm = MergeOptions {
        method: MergeMethod::DebevecMalik,
        ..MergeOptions::default()
    };
    let ramp = |x: usize, y: usize, c: usize| {
        1e-3 * 10f64.powf(4.0 * (x + W * y) as f64 / (W * H - 1) as f64) * [1.0, 0.7, 0.5][c]
    };
    for (shutters, scene) in [
        (
            vec![1.0 / 4096.0, 1.0],
            &ramp as &dyn Fn(usize, usize, usize) -> f64,
        ),
        (vec![0.01, 0.02, 0.04], &|_, _, _| 0.5),
        (vec![0.5, 1.0], &|x, _, _| {
            if x < W / 2 {
                0.02
            } else {
                100.0
            }
        }),
    ] {
        let merged = hdr::merge(&gamma_frames(&shutters, scene), &dm).unwrap();
        assert!(
            merged.rgb.iter().all(|v| v.is_finite() && *v >= 0.0),
            "{shutters:?}"
        );
    }
}

#[test]
fn exr_holds_the_radiance_and_exposure_metadata() {
    use exr::meta::attribute::{AttributeValue, Text};
    let frames = bracket(&[0.02, 0.08], radiance);
    let merged = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.exr");
    merged.write_exr(&path).unwrap();
    let image = exr::prelude::read_first_rgba_layer_from_file(
        &path,
        |size, _| vec![[0f32; 3]; size.width() * size.height()],
        |pixels, position, (r, g, b, _): (f32, f32, f32, f32)| {
            pixels[position.y() * W + position.x()] = [r, g, b]
        },
    )
    .unwrap();
    let pixels = &image.layer_data.channel_data.pixels;
    assert_eq!(pixels.len(), W * H);
    for (p, rgb) in pixels.iter().enumerate() {
        assert_eq!(*rgb, merged.pixel(p % W, p / W));
    }
    let attributes = &image.layer_data.attributes;
    assert_eq!(attributes.exposure, Some(1.0));
    assert_eq!(
        attributes.other.get(&Text::from("gonio.thetaL")),
        Some(&AttributeValue::F64(-30.0))
    );
    assert_eq!(
        attributes.other.get(&Text::from("gonio.shutterS")),
        Some(&AttributeValue::Text(Text::from("0.02,0.08")))
    );
    let missing_dir = dir.path().join("no/such/dir/map.exr");
    assert!(matches!(
        merged.write_exr(&missing_dir),
        Err(HdrError::Exr { .. })
    ));
}

#[test]
fn frames_near_the_black_threshold_do_not_bias_the_linear_merge() {
    // A flat field whose short frame reads just around the black threshold: choosing
    // frames by their own noisy reading keeps that frame when noise lifts it and drops
    // it when noise lowers it, 1.0–1.4 % high here; choosing them by the predicted
    // signal is within 0.1 % (the mean's standard error is 0.03 %).
    let (w, h) = (256, 256);
    let noise = NoiseModel {
        full_well_electrons: 30_000.0,
        read_noise: 5e-4,
    };
    let options = MergeOptions::default();
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    for radiance in [0.012, 0.02] {
        let frames: Vec<Frame> = [0.5, 0.125]
            .iter()
            .map(|&shutter_s| {
                let data = (0..w * h * 3)
                    .map(|_| {
                        let s = radiance * shutter_s;
                        let sigma =
                            (s / noise.full_well_electrons + noise.read_noise.powi(2)).sqrt();
                        let count = BLACK + (s + sigma * rng.normal()) * (WHITE - BLACK);
                        count.round().clamp(0.0, 65_535.0) as u16
                    })
                    .collect();
                counts_frame(w, h, shutter_s, data)
            })
            .collect();
        let merged = hdr::merge(&frames, &options).unwrap();
        let kept: Vec<f64> = merged
            .rgb
            .iter()
            .zip(0..)
            .filter(|&(_, i)| merged.mask[i / 3] & (SATURATED | UNDEREXPOSED) == 0)
            .map(|(v, _)| f64::from(*v))
            .collect();
        assert!(kept.len() > w * h * 3 * 99 / 100, "{}", kept.len());
        let mean = kept.iter().sum::<f64>() / kept.len() as f64;
        let bias = mean / radiance - 1.0;
        assert!(bias.abs() < 1e-3, "radiance {radiance}: bias {bias}");
    }
}

/// A noise-free linear frame of `scene` (w × h) at `shutter_s`.
fn clean_frame(
    w: usize,
    h: usize,
    shutter_s: f64,
    scene: impl Fn(usize, usize, usize) -> f64,
) -> Frame {
    let data = (0..w * h * 3)
        .map(|i| {
            let count = BLACK + scene(i / 3 % w, i / 3 / w, i % 3) * shutter_s * (WHITE - BLACK);
            count.round().clamp(0.0, 65_535.0) as u16
        })
        .collect();
    counts_frame(w, h, shutter_s, data)
}

#[test]
fn the_darkest_usable_count_is_merged_and_the_count_below_it_is_not() {
    let options = MergeOptions::default();
    let signal = |count: u16| (f64::from(count) - BLACK) / (WHITE - BLACK);
    let usable = (0..=u16::MAX)
        .find(|&c| signal(c) >= options.min_signal)
        .unwrap();
    // Pixel 0 reads the smallest usable count in the long frame, pixel 1 one count
    // less; the short frame is black.
    let counts = |first: u16, second: u16| [[first; 3], [second; 3]].concat();
    let frames: Vec<Frame> = [(0.5, counts(usable, usable - 1)), (0.05, counts(0, 0))]
        .into_iter()
        .map(|(shutter_s, data)| counts_frame(2, 1, shutter_s, data))
        .collect();
    let merged = hdr::merge(&frames, &options).unwrap();
    let expected = signal(usable) / frames[0].sidecar.exposure();
    assert!(expected > 0.0);
    for value in merged.pixel(0, 0) {
        assert!(
            (f64::from(value) / expected - 1.0).abs() < 1e-6,
            "{value} {expected}"
        );
    }
    assert_eq!(merged.mask[0], 0);
    assert_eq!(merged.pixel(1, 0), [0.0; 3]);
    assert_eq!(
        merged.mask[1],
        (0..3).fold(0, |m, c| m | hdr::channel_mask(UNDEREXPOSED, c))
    );
}

#[test]
fn a_mostly_black_map_reads_back_exactly_from_its_exr() {
    // 150×140 pixels: whole 64×64 tiles that are black, tiles with light, edge tiles.
    let (w, h) = (150, 140);
    let scene = |x: usize, y: usize, c: usize| {
        if (70..90).contains(&x) && (10..130).contains(&y) {
            0.05 * (1 + x + y + c) as f64
        } else {
            0.0
        }
    };
    let frames = [0.5, 0.05].map(|t| clean_frame(w, h, t, scene));
    let merged = hdr::merge(&frames, &MergeOptions::default()).unwrap();
    assert!(merged.pixel(0, 0) == [0.0; 3] && merged.pixel(80, 80)[0] > 0.0);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.exr");
    merged.write_exr(&path).unwrap();
    assert_eq!(
        hdr::read_exr_rgb(&path).unwrap(),
        (w, h, merged.rgb.clone())
    );
    let image = exr::prelude::read_first_rgba_layer_from_file(
        &path,
        |size, _| vec![[0f32; 3]; size.width() * size.height()],
        move |pixels, position, (r, g, b, _): (f32, f32, f32, f32)| {
            pixels[position.y() * w + position.x()] = [r, g, b]
        },
    )
    .unwrap();
    let pixels = &image.layer_data.channel_data.pixels;
    assert!((0..w * h).all(|p| pixels[p] == merged.pixel(p % w, p / w)));
}
