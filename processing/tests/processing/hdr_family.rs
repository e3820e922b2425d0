//! HDR merges judged on randomized families of brackets that this test generates from a
//! seed, not on hand-picked cases.
//!
//! - Debevec–Malik against OpenCV's `CalibrateDebevec` + `MergeDebevec` on the same 8-bit
//!   frames (error measure and OpenCV runner: `tests/bracket`): 2–6 decades of scene
//!   range topping out at 2–95 % of clipping in the shortest frame, 3–9 frames 1–2 EV
//!   apart, gamma 2.2, sRGB, filmic and soft-S responses, shot and read noise, values
//!   clipped or black in every frame, highlights unclipped in the shortest frame only and
//!   a sharp highlight; plus the regime of a 7-frame 1/2…1/100 s bracket of 4 decades and
//!   a sharp highlight.
//! - The linear merge against an oracle on linear 8-, 12- and 14-bit brackets of the same
//!   kind of scenes: the inverse-variance mean that knows the true variance of every
//!   reading and which frames truly hold the value within the merge's signal range.
//!
//! Each test prints its table (`-- --nocapture`). `GONIO_HDR_FAMILY_N` sets the number of
//! brackets per family (default 12, seconds; the seven-frame regime gets a quarter as
//! many scenes): `GONIO_HDR_FAMILY_N=200 cargo test -p gonio-processing --test processing hdr_family::
//! -- --nocapture --test-threads 1` gives the figures of a larger family (minutes).

use std::path::PathBuf;

use gonio_processing::capture::{Frame, Response, Sidecar};
use gonio_processing::hdr::{self, MergeMethod, MergeOptions, NoiseModel, UNDEREXPOSED};

use crate::bracket;
use crate::common;
use bracket::{Camera, Curve};
use common::Rng;

const W: usize = 128;
const H: usize = 96;

/// Brackets per family: `GONIO_HDR_FAMILY_N`, else 12.
fn family_size() -> usize {
    std::env::var("GONIO_HDR_FAMILY_N")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(12)
}

fn log_uniform(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo * (hi / lo).powf(rng.uniform())
}

/// What a scene holds, in units of the radiance that gives x = 1 in the shortest frame.
struct SceneSpec {
    /// The brightest value of the body: x in the shortest frame.
    top: f64,
    /// Decades between the brightest and darkest value of the body.
    decades: f64,
    /// The lowest x in the shortest frame of the highlights that only it leaves unclipped.
    highlight_from: f64,
}

/// A W×H scene: a body log-uniform over `decades` below x = `top` in the shortest frame,
/// each channel a random fraction 0.15–1 of the pixel's luminance; 6 % highlights (each
/// channel log-uniform in x from `highlight_from` to 0.95 in the shortest frame); 2 % of
/// pixels clipped in every frame and 1 % black in every frame; and a sharp highlight, a
/// disc of radius W/12 whose luminance rises log-linearly from the body's top at its rim
/// to 100× it at its centre.
fn scene(spec: &SceneSpec, rng: &mut Rng) -> Vec<f64> {
    let top = spec.top;
    let (cx, cy) = (
        W as f64 * (0.2 + 0.6 * rng.uniform()),
        H as f64 * (0.2 + 0.6 * rng.uniform()),
    );
    let radius = W as f64 / 12.0;
    let mut out = Vec::with_capacity(3 * W * H);
    for y in 0..H {
        for x in 0..W {
            let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt() / radius;
            let kind = rng.uniform();
            let chroma: [f64; 3] = std::array::from_fn(|_| 0.15 + 0.85 * rng.uniform());
            let pixel: [f64; 3] = if d < 1.0 {
                let peak = top * 100f64.powf(1.0 - d);
                chroma.map(|k| peak * (0.85 + 0.15 * k))
            } else if kind < 0.02 {
                [100.0; 3]
            } else if kind < 0.03 {
                [1e-9; 3]
            } else if kind < 0.09 {
                std::array::from_fn(|_| log_uniform(rng, spec.highlight_from, 0.95))
            } else {
                let luminance = top * 10f64.powf(-spec.decades * rng.uniform());
                chroma.map(|k| luminance * k)
            };
            out.extend(pixel);
        }
    }
    out
}

/// A bracket's design: `frames` frames `ev` stops apart from `shortest` seconds up, and
/// the scene it is made for.
struct Design {
    frames: usize,
    ev: f64,
    shortest: f64,
    /// The body's brightest value: x in the shortest frame.
    top: f64,
    decades: f64,
}

impl Design {
    fn random(rng: &mut Rng) -> Self {
        Self {
            frames: 3 + (7.0 * rng.uniform()) as usize,
            ev: 1.0 + rng.uniform(),
            shortest: 1.0 / log_uniform(rng, 30.0, 1000.0),
            top: log_uniform(rng, 0.02, 0.95),
            decades: 2.0 + 4.0 * rng.uniform(),
        }
    }

    fn shutters(&self) -> Vec<f64> {
        (0..self.frames)
            .map(|k| self.shortest * 2f64.powf(self.ev * k as f64))
            .collect()
    }

    /// The scene in radiance units (x = radiance × shutter).
    fn scene(&self, rng: &mut Rng) -> Vec<f64> {
        let spec = SceneSpec {
            top: self.top,
            decades: self.decades,
            // Clipped in the second shortest frame (x ≥ 1.05 there).
            highlight_from: (1.05 / 2f64.powf(self.ev)).max(0.3),
        };
        scene(&spec, rng)
            .into_iter()
            .map(|x| x / self.shortest)
            .collect()
    }
}

/// Where a value lies in its bracket, noise aside: how many frames leave it unclipped and
/// the highest level it reaches below clipping.
const REGIMES: [&str; 5] = [
    "unclipped in the shortest frame only",
    "unclipped in the shortest two frames only",
    "darkest: best level below 16",
    "dark: best level 16 to 63",
    "the rest",
];

fn regime(radiance: f64, shutters: &[f64], curve: Curve) -> usize {
    let levels = shutters.iter().map(|&t| curve.level(radiance * t));
    let unclipped: Vec<f64> = levels.filter(|&z| z < 254.5).collect();
    let best = unclipped.iter().copied().fold(0.0, f64::max);
    match unclipped.len() {
        0 | 1 => 0,
        2 => 1,
        _ if best < 16.0 => 2,
        _ if best < 64.0 => 3,
        _ => 4,
    }
}

/// The pooled errors of one method over a family, each with its value's regime.
#[derive(Default)]
struct Tally {
    errors: Vec<f64>,
    regimes: Vec<usize>,
}

impl Tally {
    /// Adds a bracket's errors; its median and p99.
    fn add(&mut self, errors: &[f64], regimes: &[usize]) -> (f64, f64) {
        self.errors.extend_from_slice(errors);
        self.regimes.extend_from_slice(regimes);
        bracket::median_p99(errors)
    }

    /// Median and p99 of the values of regime `r` (NaN for none).
    fn regime(&self, r: usize) -> (f64, f64) {
        let errors: Vec<f64> = self
            .errors
            .iter()
            .zip(&self.regimes)
            .filter(|&(_, &k)| k == r)
            .map(|(&e, _)| e)
            .collect();
        if errors.is_empty() {
            (f64::NAN, f64::NAN)
        } else {
            bracket::median_p99(&errors)
        }
    }
}

/// One Debevec–Malik bracket of a family: its table label, its truth and its capture.
struct Run {
    label: String,
    truth: Vec<f64>,
    captured: bracket::Bracket,
    /// The regime of each evaluated value, in the order of `bracket::evaluated`.
    regimes: Vec<usize>,
}

impl Run {
    fn new(label: String, truth: Vec<f64>, shutters: &[f64], camera: &Camera, seed: u64) -> Self {
        let captured = bracket::capture(&truth, W, H, shutters, camera, seed);
        let regimes = bracket::evaluated(&captured.measurable)
            .into_iter()
            .map(|i| regime(truth[i], shutters, camera.curve))
            .collect();
        Self {
            label,
            truth,
            captured,
            regimes,
        }
    }
}

/// Merges every bracket with gonio and (in one process) OpenCV, prints a row per bracket
/// and the pooled figures, overall and by regime, and checks that ours are no worse than
/// OpenCV's, overall and in every regime (median and p99). No tolerance: both are pooled
/// over the same values.
fn judge(name: &str, runs: &[Run]) {
    let dir = tempfile::tempdir().unwrap();
    let brackets: Vec<&bracket::Bracket> = runs.iter().map(|run| &run.captured).collect();
    let opencv_runs = bracket::opencv_or_skip(&brackets, dir.path());
    let (mut gonio, mut opencv) = (Tally::default(), Tally::default());
    eprintln!(
        "bracket                                         gonio median / p99    OpenCV median / p99"
    );
    for (k, run) in runs.iter().enumerate() {
        let errors_of = |radiance: &[f64]| {
            bracket::relative_errors(radiance, &run.truth, &run.captured.measurable)
        };
        let (radiance, _) = bracket::gonio_merge(&run.captured);
        let (median, p99) = gonio.add(&errors_of(&radiance), &run.regimes);
        match &opencv_runs {
            Some(cv) => {
                let (cv_median, cv_p99) = opencv.add(&errors_of(&cv[k]), &run.regimes);
                eprintln!(
                    "{} {median:>8.4} {p99:>8.4} {cv_median:>8.4} {cv_p99:>8.4}",
                    run.label
                );
            }
            None => eprintln!("{} {median:>8.4} {p99:>8.4}", run.label),
        }
    }
    let (median, p99) = bracket::median_p99(&gonio.errors);
    eprintln!("{name}: gonio median {median:.4}, p99 {p99:.4}");
    if opencv_runs.is_none() {
        return;
    }
    let (cv_median, cv_p99) = bracket::median_p99(&opencv.errors);
    eprintln!("{name}: OpenCV median {cv_median:.4}, p99 {cv_p99:.4}");
    let mut worse = Vec::new();
    for (r, label) in REGIMES.iter().enumerate() {
        let n = gonio.regimes.iter().filter(|&&k| k == r).count();
        let ((m, p), (cm, cp)) = (gonio.regime(r), opencv.regime(r));
        eprintln!("  {label:<42} {n:>7} values  gonio {m:.4} / {p:.4}  OpenCV {cm:.4} / {cp:.4}");
        if n > 0 && !(m <= cm && p <= cp) {
            worse.push(format!("{label}: gonio {m} / {p}, OpenCV {cm} / {cp}"));
        }
    }
    assert!(
        median <= cv_median && p99 <= cv_p99,
        "{name}: gonio median {median}, p99 {p99}; OpenCV {cv_median}, {cv_p99}"
    );
    // Every regime too, the highlights that only the shortest one or two frames leave
    // unclipped among them: no worse than OpenCV's on the same values.
    assert!(
        worse.is_empty(),
        "{name}: worse than OpenCV in {}",
        worse.join("; ")
    );
}

#[test]
fn debevec_malik_matches_opencv_on_a_random_family() {
    let mut rng = Rng(0x5eed_0fb7_ac4e_7500);
    let runs: Vec<Run> = (0..family_size())
        .map(|k| {
            let design = Design::random(&mut rng);
            let curve = [Curve::Gamma, Curve::Srgb, Curve::Filmic, Curve::SoftS][k % 4];
            let camera = Camera {
                curve,
                full_well: log_uniform(&mut rng, 2000.0, 40_000.0),
                read_noise: log_uniform(&mut rng, 2e-4, 2e-3),
            };
            let truth = design.scene(&mut rng);
            let label = format!(
                "{k:>3} {} fr {:.2} EV {:.1} dec top {:.2} {:<9} fw {:>5.0} rn {:.1e}",
                design.frames,
                design.ev,
                design.decades,
                design.top,
                curve.name(),
                camera.full_well,
                camera.read_noise
            );
            Run::new(label, truth, &design.shutters(), &camera, 1000 + k as u64)
        })
        .collect();
    judge("family", &runs);
}

/// 7 frames 1/2…1/100 s of 4 decades and a sharp highlight through gamma 2.2, noisy:
/// values unclipped in the shortest one or two frames only, and a darkest decade seen
/// in the longest frames only.
#[test]
fn debevec_malik_matches_opencv_on_a_seven_frame_bracket_with_a_sharp_highlight() {
    let shutters = [
        1.0 / 100.0,
        1.0 / 60.0,
        1.0 / 30.0,
        1.0 / 15.0,
        1.0 / 8.0,
        1.0 / 4.0,
        1.0 / 2.0,
    ];
    let camera = Camera {
        curve: Curve::Gamma,
        full_well: 8000.0,
        read_noise: 1e-3,
    };
    let spec = SceneSpec {
        top: 0.95,
        decades: 4.0,
        highlight_from: 0.3,
    };
    let runs: Vec<Run> = (0..family_size().div_ceil(4))
        .map(|k| {
            let mut rng = Rng(0x0a11_5e70 + k as u64);
            let truth = scene(&spec, &mut rng)
                .into_iter()
                .map(|x| x * 100.0)
                .collect();
            let label = format!("{k:>3} 7 fr 1/2…1/100 s, 4 dec, gamma 2.2      ");
            Run::new(label, truth, &shutters, &camera, 2000 + k as u64)
        })
        .collect();
    judge("seven-frame regime", &runs);
}

/// A linear sensor of `bits` bits: black level, white level, noise.
struct Sensor {
    bits: u32,
    black: f64,
    white: f64,
    noise: NoiseModel,
}

impl Sensor {
    fn random(rng: &mut Rng, k: usize) -> Self {
        let bits = [8, 12, 14][k % 3];
        let max = f64::from((1u32 << bits) - 1);
        Self {
            bits,
            black: max / 64.0,
            white: max,
            noise: NoiseModel {
                full_well_electrons: log_uniform(rng, 2000.0, 40_000.0),
                read_noise: log_uniform(rng, 1e-4, 2e-3),
            },
        }
    }

    fn variance(&self, signal: f64) -> f64 {
        let quantum = 1.0 / (self.white - self.black);
        signal.max(0.0) / self.noise.full_well_electrons
            + self.noise.read_noise.powi(2)
            + quantum * quantum / 12.0
    }

    fn frame(&self, radiance: &[f64], shutter_s: f64, rng: &mut Rng) -> Frame {
        let data = radiance
            .iter()
            .map(|&e| {
                let s = e * shutter_s;
                let sigma =
                    (s / self.noise.full_well_electrons + self.noise.read_noise.powi(2)).sqrt();
                let count = self.black + (s + sigma * rng.normal()) * (self.white - self.black);
                count.round().clamp(0.0, self.white) as u16
            })
            .collect();
        let sidecar = Sidecar {
            shutter_s,
            iso: Some(100.0),
            theta_l: -30.0,
            camera: format!("{}-bit linear test camera", self.bits),
            time: "2026-11-23T14:00:00Z".into(),
            black_level: Some(self.black),
            white_level: Some(self.white),
            response: Response::Linear,
            significant_bits: None,
            aperture: None,
            width: None,
            height: None,
        };
        Frame::from_counts(PathBuf::from("raw.tiff"), sidecar, W, H, data, self.white).unwrap()
    }
}

/// The oracle's estimate of value `i`: the mean of signal/exposure over the frames whose
/// true signal lies within [min_signal, max_signal] and whose reading is not clipped,
/// weighted by exposure² over the true variance; `None` when no frame qualifies.
fn oracle(
    frames: &[Frame],
    sensor: &Sensor,
    options: &MergeOptions,
    truth: f64,
    i: usize,
) -> Option<f64> {
    let (mut sum, mut weights) = (0.0, 0.0);
    for f in frames {
        let h = f.sidecar.exposure();
        let s_true = truth * h;
        let s = (f64::from(f.data[i]) - sensor.black) / (sensor.white - sensor.black);
        if (options.min_signal..=options.max_signal).contains(&s_true) && s <= options.max_signal {
            let w = h * h / sensor.variance(s_true);
            sum += w * s / h;
            weights += w;
        }
    }
    (weights > 0.0).then(|| sum / weights)
}

/// How much worse than the oracle the linear merge may be on the values it measures,
/// pooled over a family: the oracle weighs each reading by its true variance and keeps a
/// frame by its true signal, the merge by a noisy estimate of both.
const ORACLE_TOLERANCE: f64 = 1.05;

/// The largest share of the values the oracle measures that the merge may declare black
/// (see the test).
const MAX_BLACK_SHARE: f64 = 0.02;

/// The linear merge declares a value black (flagged underexposed, 0) when no frame reads
/// it at `min_signal` or more; a value whose true signal is just above that in its
/// longest frame is read below it about half of the time, and the oracle, which knows
/// the truth, measures it anyway. So the comparison is split: the errors on the values
/// the merge measures, against the oracle's on the same values; and the share of the
/// oracle's values the merge declares black. Also printed: the errors over all of the
/// oracle's values, a value declared black counting as error 1.
#[test]
fn linear_merge_matches_an_oracle_on_a_random_family() {
    let mut rng = Rng(0x11ea_4f00_d5ee_d500);
    let (mut gonio_all, mut oracle_all, mut gonio_measured, mut oracle_measured) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    eprintln!(
        "bracket                                  gonio median / p99   oracle median / p99   black"
    );
    for k in 0..family_size() {
        let design = Design::random(&mut rng);
        let sensor = Sensor::random(&mut rng, k);
        let truth = design.scene(&mut rng);
        let shutters = design.shutters();
        let frames: Vec<Frame> = shutters
            .iter()
            .map(|&t| sensor.frame(&truth, t, &mut rng))
            .collect();
        let options = MergeOptions {
            method: MergeMethod::Linear,
            noise: sensor.noise,
            ..MergeOptions::default()
        };
        let merged = hdr::merge(&frames, &options).unwrap();
        assert!(merged.rgb.iter().all(|v| v.is_finite() && *v >= 0.0));
        let (mut gonio, mut best, mut black) = (Vec::new(), Vec::new(), 0);
        for (i, &e) in truth.iter().enumerate() {
            let Some(o) = oracle(&frames, &sensor, &options, e, i) else {
                continue;
            };
            let error = (f64::from(merged.rgb[i]) - e).abs() / e;
            let oracle_error = (o - e).abs() / e;
            gonio_all.push(error);
            oracle_all.push(oracle_error);
            let (x, y) = (i / 3 % W, i / 3 / W);
            if merged.channel_flags(x, y, i % 3) & UNDEREXPOSED != 0 {
                black += 1;
            } else {
                gonio.push(error);
                best.push(oracle_error);
            }
        }
        let (median, p99) = bracket::median_p99(&gonio);
        let (o_median, o_p99) = bracket::median_p99(&best);
        let share = black as f64 / (black + gonio.len()) as f64;
        eprintln!(
            "{k:>3} {:>2}-bit {} fr {:.2} EV {:.1} dec fw {:>5.0} rn {:.1e} {median:>8.4} {p99:>8.4} {o_median:>8.4} {o_p99:>8.4} {:>6.2} %",
            sensor.bits,
            design.frames,
            design.ev,
            design.decades,
            sensor.noise.full_well_electrons,
            sensor.noise.read_noise,
            100.0 * share
        );
        gonio_measured.extend(gonio);
        oracle_measured.extend(best);
    }
    let (median, p99) = bracket::median_p99(&gonio_measured);
    let (o_median, o_p99) = bracket::median_p99(&oracle_measured);
    let share = 1.0 - gonio_measured.len() as f64 / gonio_all.len() as f64;
    let (all_median, all_p99) = bracket::median_p99(&gonio_all);
    let (o_all_median, o_all_p99) = bracket::median_p99(&oracle_all);
    eprintln!("linear family, values merged: gonio median {median:.4}, p99 {p99:.4}");
    eprintln!("linear family, values merged: oracle median {o_median:.4}, p99 {o_p99:.4}");
    eprintln!(
        "linear family: {:.2} % of the oracle's values declared black",
        100.0 * share
    );
    eprintln!(
        "linear family, all (black = error 1): gonio median {all_median:.4}, p99 {all_p99:.4}; \
         oracle median {o_all_median:.4}, p99 {o_all_p99:.4}"
    );
    assert!(
        median <= ORACLE_TOLERANCE * o_median && p99 <= ORACLE_TOLERANCE * o_p99,
        "gonio median {median}, p99 {p99}; oracle {o_median}, {o_p99}"
    );
    assert!(
        share <= MAX_BLACK_SHARE,
        "{share} of the values declared black"
    );
}
