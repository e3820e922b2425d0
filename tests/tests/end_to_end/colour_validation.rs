//! Multi-angle colour against the emulator's spectral truth (docs/ARCHITECTURE.md,
//! "Multi-angle colour"): accuracy, repeatability and discrimination of `gonio colour`
//! and `gonio compare` on emulated scans.
//!
//! Each scan is rendered (`gonio simulate --binning 8`), extracted with its uncertainty
//! columns and fitted with `--model auto` (its budget included); its colour per geometry
//! (ASTM E2539's six angles, D65/10°) is compared with the L*a*b* of the material's
//! spectral radiance factor at that geometry (`Material::beta_spectrum`, the renderer's
//! own spectral model: measured tables, thin film and Bragg flakes exactly, camera-RGB
//! models through the smooth spectrum whose camera RGB they are) through the CIE
//! observer directly. Materials: the example scenes and a seeded random family, half
//! smooth reflectance spectra with a Cook–Torrance lobe (rendered from their spectral
//! table), half goniochromatic lobes (a thin film or a Bragg band over a drawn diffuse
//! colour). Every scan's world departs from its stated setup by errors drawn from the
//! standard uncertainties its setup.json states, and has its own noise seed; the white's
//! reflectance error, the instrument's, is drawn once per material (its repeats are
//! scans made with the same white, as compare takes them).
//!
//! Figures: the share of L*, a*, b* coordinates inside their expanded interval (with its
//! 95 % Wilson interval, by coordinate and by origin, and its 95 % interval resampling
//! whole materials, whose coordinates share one transform error), the ΔE00 to the truth; the share
//! of angles at which two scans of one material (each its own mounting, disjoint pairs)
//! differ by less than compare's U; gold against red; gold against itself with Kd 1 %
//! higher. `colour_against_the_spectral_truth_fast` runs in CI; the full run
//! (`--ignored`, GONIO_BIN=target/release/gonio to use a built binary) is what
//! `scripts/results.sh --colour-validation` records: `GONIO_COLOUR_SCANS=N` random
//! materials (default 200), `GONIO_COLOUR_OUT=FILE` writes the figures as JSON,
//! `GONIO_COLOUR_CACHE=DIR` keeps (and reuses) each scan's fit and samples.

use std::path::{Path, PathBuf};

use gonio_mock_hw::render::brdf::{cook_torrance_lobe, Geom};
use gonio_mock_hw::scene::Scene;
use gonio_processing::color::delta_e::ciede2000;
use gonio_processing::color::geometry::ASTM_E2539;
use gonio_processing::color::lab::lab_from_xyz;
use gonio_processing::color::observer::{Conditions, Observer, BANDS};
use gonio_processing::color::transform::{smooth_spectra, ColourTransform, SplitMix64};
use gonio_processing::color::CameraModel;
use gonio_processing::fit::FitResult;
use gonio_processing::multi_angle::compare::{compare, Mounting, Tolerances, Verdict};
use gonio_processing::multi_angle::{
    colour, ColourReport, Measured, Origin, COVERAGE_FACTOR, EXTRAPOLATION,
};
use gonio_processing::samples::read_csv;
use gonio_tests::{gonio, temp_dir};
use serde_json::json;

const GOLD: &str = include_str!("../../../mock-hw/scenes/gold.toml");
const RED: &str = include_str!("../../../mock-hw/scenes/red.toml");
const BLUE_GREEN: &str = include_str!("../../../mock-hw/scenes/blue-green.toml");
const OPAL: &str = include_str!("../../../mock-hw/scenes/opal.toml");

/// The standard uncertainties every scan's setup.json states (as the budget's coverage
/// test: a calibrated setup and a certified white).
const STATED: [(&str, f64); 7] = [
    ("white_reflectance", 0.005),
    ("camera_offset_mm", 0.05),
    ("camera_distance_mm", 1.0),
    ("light_distance_mm", 2.0),
    ("cylinder_tilt_deg", 0.03),
    ("arm_zero_offset_deg", 0.05),
    ("arm_angle_deg", 0.01),
];

fn normal(rng: &mut SplitMix64) -> f64 {
    let (a, b) = (rng.uniform().max(1e-300), rng.uniform());
    (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
}

/// `base` with its `[sample]` table replaced by `sample`.
fn with_sample(base: &str, sample: &str) -> String {
    let start = base.find("[sample]").unwrap();
    let end = start + base[start..].find("\n\n").unwrap();
    format!("{}{sample}{}", &base[..start], &base[end..])
}

/// `text` with its noise seed `seed`, and the world's departures from the stated setup
/// drawn from `seed`, but for the white's reflectance: drawn from `instrument`, as the
/// white is the instrument's and the same in every scan made with it.
fn scene_text(text: &str, seed: u64, instrument: u64) -> String {
    let white = normal(&mut SplitMix64::new(0xC010_0000 + instrument));
    let mut rng = SplitMix64::new(0xC010_0000 + seed);
    let text = text.replace("[effects]\nseed = 1", &format!("[effects]\nseed = {seed}"));
    let u = |key: &str| STATED.iter().find(|(k, _)| *k == key).unwrap().1;
    let angles: Vec<String> = (0..6)
        .map(|_| (normal(&mut rng) * u("arm_angle_deg")).to_string())
        .collect();
    let misalignment = format!(
        "[effects.misalignment]\nwhite_reflectance_error = {}\ncamera_offset_mm = {}\n\
         camera_distance_error_mm = {}\nlight_distance_error_mm = {}\ncylinder_tilt_deg = {}\n\
         arm_zero_offset_deg = {}\narm_angle_errors_deg = [{}]\n",
        {
            normal(&mut rng);
            white * u("white_reflectance")
        },
        normal(&mut rng) * u("camera_offset_mm"),
        normal(&mut rng) * u("camera_distance_mm"),
        normal(&mut rng) * u("light_distance_mm"),
        normal(&mut rng) * u("cylinder_tilt_deg"),
        normal(&mut rng) * u("arm_zero_offset_deg"),
        angles.join(", "),
    );
    let stated: Vec<String> = STATED.iter().map(|(k, v)| format!("{k} = {v}")).collect();
    format!(
        "{text}\n{misalignment}\n[setup.uncertainty]\n{}\n",
        stated.join("\n")
    )
}

/// A goniochromatic lobe of the seeded family: a thin film or a Bragg band of drawn
/// thickness or wavelength over a drawn diffuse colour, drawn roughness and strength.
fn effect_sample(seed: u64) -> String {
    let mut rng = SplitMix64::new(0x5EC7_0000 + seed);
    let mut between = |lo: f64, hi: f64| lo + (hi - lo) * rng.uniform();
    let kd = [between(2.0, 40.0), between(2.0, 40.0), between(2.0, 40.0)];
    let (ks, m) = (between(0.5, 4.0), between(0.08, 0.3));
    let head = format!(
        "kd = [{}, {}, {}]\nks = {ks}\nm = {m}\n",
        kd[0], kd[1], kd[2]
    );
    if between(0.0, 1.0) < 0.5 {
        format!(
            "[sample]\nmodel = \"thin-film\"\n{head}film_thickness_nm = {}\nfilm_index = 2.5\nmedium_index = 1.5\nsubstrate_index = 1.58",
            between(100.0, 400.0)
        )
    } else {
        format!(
            "[sample]\nmodel = \"bragg-flakes\"\n{head}wavelength_nm = {}\neffective_index = 1.35\nband_width_nm = {}",
            between(450.0, 650.0),
            between(20.0, 60.0)
        )
    }
}

/// Angles of a smooth lobe's measured table: −85°…85° at 1° in θi and θr.
const TABLE_DEG: std::ops::RangeInclusive<i32> = -85..=85;

/// A smooth reflectance spectrum with a lobe, of the seeded family: the diffuse
/// reflectance a·ρ(λ) and the lobe's ks·F(λ)·D·G/(π (n·l)(n·v)) (Beckmann, slope
/// roughness m), ρ a smooth spectrum of the colour transform's family drawn with its own
/// seed (`smooth_spectra`), F neutral or another such spectrum (a coloured, metal-like
/// lobe), a ~ U(0.1, 0.6), ks ~ U(0.05, 0.4), m ~ U(0.08, 0.3). Written as a measured
/// spectral table (`name`-table.csv in `dir`, the emulator's `measured` sample), so the
/// scan renders the spectrum itself and not a camera-RGB stand-in.
fn smooth_lobe_sample(dir: &Path, name: &str, seed: u64) -> String {
    let mut rng = SplitMix64::new(0x5700_0000 + seed);
    let mut between = |lo: f64, hi: f64| lo + (hi - lo) * rng.uniform();
    let (a, ks, m) = (between(0.1, 0.6), between(0.05, 0.4), between(0.08, 0.3));
    let coloured_lobe = between(0.0, 1.0) < 0.5;
    let spectra = smooth_spectra(0x5700_0000 + seed, 2);
    let lobe_colour = if coloured_lobe {
        spectra[1]
    } else {
        [1.0; BANDS]
    };
    let mut csv = String::from("theta_i,theta_r");
    for i in 0..BANDS {
        csv += &format!(",{}", 390 + 10 * i);
    }
    csv.push('\n');
    for ti in TABLE_DEG {
        for tr in TABLE_DEG {
            let g = Geom::in_plane(f64::from(ti), f64::from(tr));
            let lobe = ks * cook_torrance_lobe(&g, m);
            csv += &format!("{ti},{tr}");
            for (rho, f) in spectra[0].iter().zip(&lobe_colour) {
                csv += &format!(",{:.6e}", a * rho + lobe * f);
            }
            csv.push('\n');
        }
    }
    let table = format!("{name}-table.csv");
    std::fs::write(dir.join(&table), csv).unwrap();
    format!("[sample]\nmodel = \"measured\"\npath = \"{table}\"")
}

/// Material `k` of the random family: a smooth spectrum with a lobe (even k) or a
/// goniochromatic lobe (odd k).
fn random_sample(dir: &Path, name: &str, k: u64) -> String {
    if k.is_multiple_of(2) {
        smooth_lobe_sample(dir, name, k)
    } else {
        effect_sample(k)
    }
}

/// A scan of scene text: rendered, extracted, fitted with `--model auto`; its colour.
struct Scan {
    scene: Scene,
    report: ColourReport,
}

/// Scans `text` as `name` in `dir`. The scan's fit and samples are kept there, and
/// reused when `dir` already holds them for the same scene text (`GONIO_COLOUR_CACHE`).
fn scan(dir: &Path, name: &str, text: &str, transform: &ColourTransform) -> Scan {
    let path = dir.join(format!("{name}.toml"));
    let out: PathBuf = dir.join(name);
    let csv = out.join("samples.csv");
    let fit_path = out.join("fit-auto.json");
    let cached = std::fs::read_to_string(&path).is_ok_and(|t| t == text) && fit_path.is_file();
    if !cached {
        std::fs::write(&path, text).unwrap();
        std::fs::remove_dir_all(&out).ok();
        let s = |p: &Path| p.to_str().unwrap().to_owned();
        gonio(&[
            "simulate",
            "--scene",
            &s(&path),
            "--binning",
            "8",
            "--out",
            &s(&out),
        ]);
        gonio(&["extract", &s(&out), "--out", &s(&csv)]);
        gonio(&["fit", &s(&csv), "--model", "auto", "--out", &s(&fit_path)]);
        // Only the fit and its samples are read again.
        for entry in std::fs::read_dir(&out).unwrap() {
            let entry = entry.unwrap().path();
            if entry != csv && entry != fit_path {
                if entry.is_dir() {
                    std::fs::remove_dir_all(&entry).ok();
                } else {
                    std::fs::remove_file(&entry).ok();
                }
            }
        }
    }
    let fit: FitResult =
        serde_json::from_str(&std::fs::read_to_string(&fit_path).unwrap()).unwrap();
    let samples = read_csv(&csv).unwrap();
    let measured = Measured::of(&fit, &samples).unwrap();
    let report = colour(&fit, Some(&measured), transform, &ASTM_E2539).unwrap();
    Scan {
        scene: Scene::load(&path).unwrap(),
        report,
    }
}

/// L*a*b* of the scene's material at each of the report's geometries, from its spectral
/// radiance factor with the observer.
fn truth(scan: &Scan, observer: &Observer) -> Vec<[f64; 3]> {
    scan.report
        .angles
        .iter()
        .map(|a| {
            let g = Geom::in_plane(a.theta_i, a.theta_r);
            let f = scan
                .scene
                .material()
                .beta_spectrum(&g, scan.scene.camera_domain());
            lab_from_xyz(observer.xyz(&f).unwrap(), observer.white())
        })
        .collect()
}

/// A count of hits among trials.
#[derive(Default, Clone, Copy)]
struct Count {
    hits: usize,
    trials: usize,
}

impl Count {
    fn add(&mut self, hit: bool) {
        self.hits += usize::from(hit);
        self.trials += 1;
    }

    fn share(&self) -> f64 {
        self.hits as f64 / self.trials.max(1) as f64
    }

    /// The Wilson score interval of the share at 95 % (z = 1.96): what the counts say of
    /// the share were the trials independent (trials within one scan are not quite, so
    /// the interval is if anything too narrow).
    fn interval(&self) -> [f64; 2] {
        let (n, p, z) = (self.trials.max(1) as f64, self.share(), 1.96_f64);
        let centre = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
        let half = z / (1.0 + z * z / n) * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt();
        [(centre - half).max(0.0), (centre + half).min(1.0)]
    }

    fn json(&self) -> serde_json::Value {
        json!({"within": self.hits, "of": self.trials, "share": self.share(), "interval_95": self.interval()})
    }
}

/// Hits of the expanded intervals of L*, a*, b* over the truth, and the ΔE00 to it.
#[derive(Default)]
struct Accuracy {
    all: Count,
    /// By coordinate: L*, a*, b*.
    by_coordinate: [Count; 3],
    /// By origin: data, model.
    by_origin: [Count; 2],
    /// By kind of material ([`KINDS`]).
    by_kind: [Count; 3],
    delta_e: Vec<f64>,
    delta_e_model: Vec<f64>,
    /// Every coordinate judged, with what its U is made of.
    judged: Vec<Judged>,
    /// Geometries flagged beyond the data, and of those the ones whose truth is darker
    /// than the value (L* overstated).
    beyond_data: Count,
    beyond_data_overstated: Count,
}

/// Classes of a coordinate's lines: the colour transform's, the colour drift carried
/// beyond the data, and the rest (the budget's or the samples' own: setup, noise, misfit).
const TERMS: [&str; 3] = ["transform", "extrapolation", "budget"];

/// The class of a line's source ([`TERMS`]).
fn term(source: &str) -> usize {
    if source.starts_with("transform:") {
        0
    } else if source.starts_with(EXTRAPOLATION) {
        1
    } else {
        2
    }
}

/// One coordinate against its truth: its material (an index over the run's materials,
/// the same for every scan of it), coordinate (L*, a*, b*), origin, whether the truth
/// lies inside U, the error and the variance of each class of its lines ([`TERMS`]).
struct Judged {
    material: usize,
    coordinate: usize,
    origin: usize,
    hit: bool,
    error: f64,
    variance: [f64; 3],
}

impl Judged {
    /// Its material's kind ([`kind`]).
    fn kind(&self) -> usize {
        kind(self.material)
    }

    /// Inside k·u with the classes `keep` (by [`TERMS`] index) counted.
    fn inside(&self, keep: [bool; 3]) -> bool {
        let v: f64 = (0..3).filter(|&t| keep[t]).map(|t| self.variance[t]).sum();
        self.error <= COVERAGE_FACTOR * v.sqrt()
    }

    /// The class with the largest share of the variance.
    fn dominant(&self) -> usize {
        (0..3)
            .max_by(|&a, &b| self.variance[a].total_cmp(&self.variance[b]))
            .unwrap_or(2)
    }
}

impl Accuracy {
    fn add(&mut self, scan: &Scan, observer: &Observer, label: &str, material: usize) {
        let kind = kind(material);
        for (a, t) in scan.report.angles.iter().zip(truth(scan, observer)) {
            let de = ciede2000(a.lab(), t);
            self.delta_e.push(de);
            let origin = usize::from(a.origin == Origin::Model);
            if a.origin == Origin::Model {
                self.beyond_data.add(a.beyond_data);
                if a.beyond_data {
                    self.beyond_data_overstated.add(t[0] < a.l.value);
                }
            }
            if a.origin == Origin::Model {
                self.delta_e_model.push(de);
            }
            let mut line = format!("{label} as {:>4} {:?}:", a.aspecular, a.origin);
            for (k, (c, truth)) in [a.l, a.a, a.b].iter().zip(t).enumerate() {
                let hit = (c.value - truth).abs() <= c.expanded;
                let mut variance = [0.0; 3];
                for line in &a.lines {
                    variance[term(&line.source)] += line.lab[k] * line.lab[k];
                }
                self.judged.push(Judged {
                    material,
                    coordinate: k,
                    origin,
                    hit,
                    error: (c.value - truth).abs(),
                    variance,
                });
                self.all.add(hit);
                self.by_coordinate[k].add(hit);
                self.by_origin[origin].add(hit);
                self.by_kind[kind].add(hit);
                line += &format!(
                    " {:.2}±{:.2} (truth {truth:.2}{})",
                    c.value,
                    c.expanded,
                    if hit { "" } else { " OUT" }
                );
            }
            let flag = if a.beyond_data {
                " beyond the data"
            } else {
                ""
            };
            eprintln!("{line} ΔE00 {de:.2}{flag}");
        }
    }
}

impl Accuracy {
    /// The 95 % interval of the coverage of the coordinates `keep` chooses, resampling whole
    /// materials (2,000 seeded draws): a material's coordinates share its spectrum's
    /// transform error and its white, so the Wilson interval over coordinates is too narrow.
    fn by_material(&self, keep: &dyn Fn(&Judged) -> bool) -> serde_json::Value {
        let mut per: std::collections::BTreeMap<usize, (usize, usize)> = Default::default();
        for j in self.judged.iter().filter(|j| keep(j)) {
            let e = per.entry(j.material).or_default();
            e.0 += usize::from(j.hit);
            e.1 += 1;
        }
        let groups: Vec<(usize, usize)> = per.into_values().collect();
        let mut rng = SplitMix64::new(0xC0FE_0001);
        let shares: Vec<f64> = (0..2000)
            .map(|_| {
                let (mut hits, mut trials) = (0, 0);
                for _ in 0..groups.len() {
                    let (h, n) = groups[(rng.next_u64() % groups.len() as u64) as usize];
                    hits += h;
                    trials += n;
                }
                hits as f64 / trials.max(1) as f64
            })
            .collect();
        json!({
            "materials": groups.len(),
            "interval_95": [percentile(&shares, 0.025), percentile(&shares, 0.975)],
        })
    }

    /// The coverage broken down: per kind of material, by coordinate, by origin and by
    /// the class of lines that dominates U; with each class of lines left out in turn
    /// (how much of the coverage each class buys); and the median of |error|/U (about
    /// 0.34 for a normal error whose U is k = 2 of its standard deviation).
    fn breakdown(&self) -> serde_json::Value {
        let group = |keep: &dyn Fn(&Judged) -> bool| {
            let chosen: Vec<&Judged> = self.judged.iter().filter(|j| keep(j)).collect();
            let count = |classes: [bool; 3]| {
                let mut c = Count::default();
                for j in &chosen {
                    c.add(j.inside(classes));
                }
                c.json()
            };
            let ratios: Vec<f64> = chosen
                .iter()
                .map(|j| {
                    let u = j.variance.iter().sum::<f64>().sqrt();
                    j.error / (COVERAGE_FACTOR * u).max(1e-300)
                })
                .collect();
            json!({
                "count": count([true; 3]),
                "median_error_over_u": percentile(&ratios, 0.5),
                "without": TERMS.iter().enumerate().map(|(t, name)| {
                    let mut keep = [true; 3];
                    keep[t] = false;
                    json!({"term": name, "count": count(keep)})
                }).collect::<Vec<_>>(),
            })
        };
        let mut out = Vec::new();
        for (k, kind) in KINDS.iter().enumerate() {
            let of_kind = |j: &Judged| j.kind() == k;
            let by_coordinate: Vec<_> = ["L", "a", "b"]
                .iter()
                .enumerate()
                .map(|(c, name)| {
                    json!({"coordinate": name, "group": group(&|j: &Judged| of_kind(j) && j.coordinate == c)})
                })
                .collect();
            let by_origin: Vec<_> = ["data", "model"]
                .iter()
                .enumerate()
                .map(|(o, name)| {
                    json!({"origin": name, "group": group(&|j: &Judged| of_kind(j) && j.origin == o)})
                })
                .collect();
            out.push(json!({
                "kind": kind,
                "all": group(&of_kind),
                "by_coordinate": by_coordinate,
                "by_origin": by_origin,
                "by_dominant_term": TERMS.iter().enumerate().map(|(t, name)| {
                    json!({"term": name, "group": group(&|j: &Judged| of_kind(j) && j.dominant() == t)})
                }).collect::<Vec<_>>(),
            }));
        }
        json!(out)
    }
}

fn percentile(values: &[f64], q: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((q * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1)]
}

fn distribution(values: &[f64]) -> serde_json::Value {
    json!({
        "geometries": values.len(),
        "median": percentile(values, 0.5),
        "p75": percentile(values, 0.75),
        "p95": percentile(values, 0.95),
        "max": percentile(values, 1.0),
    })
}

/// What a run scans: the random materials, the materials scanned again and how often.
struct Plan {
    randoms: u64,
    /// Example scenes (by name) and random materials (by index) scanned again.
    repeated_examples: &'static [&'static str],
    repeated_randoms: u64,
    /// Scans of each repeated material besides its first: disjoint pairs of scans
    /// (first and second, third and fourth, …) are compared.
    repeats: u64,
}

/// Kinds of material: the example scenes (gold and red camera-RGB models, blue-green a
/// film, opal flakes; their diffuse spectra three-Gaussian), smooth spectra with a lobe
/// (the transform's family), films and flakes over a three-Gaussian diffuse spectrum.
const KINDS: [&str; 3] = ["examples", "smooth spectra with a lobe", "films and flakes"];

/// The kind of material `k` (examples first, then the random family).
fn kind(k: usize) -> usize {
    match k.checked_sub(EXAMPLES.len()) {
        None => 0,
        Some(r) if r.is_multiple_of(2) => 1,
        Some(_) => 2,
    }
}

/// The example scenes.
const EXAMPLES: [(&str, &str); 4] = [
    ("gold", GOLD),
    ("red", RED),
    ("blue-green", BLUE_GREEN),
    ("opal", OPAL),
];

/// Everything a run measures, as JSON, and whether the targets hold by the test of
/// `strict` (point estimates) or not (the 95 % intervals reach the target).
fn validate(plan: &Plan, strict: bool) {
    let scratch = temp_dir("colour-validation");
    let dir = match std::env::var_os("GONIO_COLOUR_CACHE") {
        Some(d) => {
            std::fs::create_dir_all(&d).unwrap();
            PathBuf::from(d)
        }
        None => scratch.to_path_buf(),
    };
    let transform = ColourTransform::new(&CameraModel::builtin(), Conditions::D65Ten).unwrap();
    let observer = Observer::new(Conditions::D65Ten);

    // Accuracy over every scan; the materials and their first scans.
    let mut accuracy = Accuracy::default();
    let mut materials: Vec<(String, String)> = EXAMPLES
        .iter()
        .map(|(name, text)| (name.to_string(), text.to_string()))
        .collect();
    for k in 0..plan.randoms {
        let name = format!("random-{k}");
        let sample = random_sample(&dir, &name, k);
        materials.push((name, with_sample(GOLD, &sample)));
    }
    let mut first = Vec::new();
    for (k, (name, base)) in materials.iter().enumerate() {
        let s = scan(
            &dir,
            name,
            &scene_text(base, 11 + k as u64, 11 + k as u64),
            &transform,
        );
        accuracy.add(&s, &observer, name, k);
        first.push(s);
    }

    // Repeatability: disjoint pairs of scans of one material, each its own mounting.
    let mut repeat = Count::default();
    let mut repeat_by_angle = [Count::default(); 6];
    let mut repeat_de = Vec::new();
    let repeated: Vec<usize> = (0..materials.len())
        .filter(|&k| {
            let name = &materials[k].0;
            plan.repeated_examples.contains(&name.as_str())
                || (k >= EXAMPLES.len() && ((k - EXAMPLES.len()) as u64) < plan.repeated_randoms)
        })
        .collect();
    for &k in &repeated {
        let (name, base) = &materials[k];
        let mut again = Vec::new();
        for r in 1..=plan.repeats {
            let label = format!("{name}-again-{r}");
            let seed = 1000 + 100 * k as u64 + r;
            let s = scan(
                &dir,
                &label,
                &scene_text(base, seed, 11 + k as u64),
                &transform,
            );
            accuracy.add(&s, &observer, &label, k);
            again.push(s);
        }
        let scans: Vec<&Scan> = std::iter::once(&first[k]).chain(&again).collect();
        for pair in scans.chunks_exact(2) {
            let c = compare(
                &pair[0].report,
                &pair[1].report,
                &Tolerances::default(),
                Mounting::Separate,
            )
            .unwrap();
            for (i, a) in c.angles.iter().enumerate() {
                let hit = a.delta_e00.value <= a.delta_e00.expanded;
                repeat.add(hit);
                repeat_by_angle[i].add(hit);
                repeat_de.push(a.delta_e00.value);
                if !hit {
                    eprintln!(
                        "{name} repeated: as {} ΔE00 {:.3} beyond its U {:.3}",
                        a.aspecular, a.delta_e00.value, a.delta_e00.expanded
                    );
                }
            }
        }
    }

    // Discrimination: gold against red fails; gold with Kd 1 % higher differs by the
    // ΔE00 the spectral truth says, one mounting (the same setup errors).
    let (gold, red) = (&first[0], &first[1]);
    let c = compare(
        &gold.report,
        &red.report,
        &Tolerances::default(),
        Mounting::Separate,
    )
    .unwrap();
    let lighter = GOLD.replace("kd = [9.0, 6.5, 2.0]", "kd = [9.09, 6.565, 2.02]");
    let moved = scan(&dir, "gold-kd", &scene_text(&lighter, 11, 11), &transform);
    let c_kd = compare(
        &gold.report,
        &moved.report,
        &Tolerances::default(),
        Mounting::Same,
    )
    .unwrap();
    let (truth_a, truth_b) = (truth(gold, &observer), truth(&moved, &observer));
    let mut kd = Count::default();
    for ((a, ta), tb) in c_kd.angles.iter().zip(&truth_a).zip(&truth_b) {
        let expected = ciede2000(*ta, *tb);
        let hit = (a.delta_e00.value - expected).abs() <= a.delta_e00.expanded;
        kd.add(hit);
        eprintln!(
            "Kd +1 %: as {:>4} ΔE00 {:.3} ± {:.3}, truth {expected:.3}{}",
            a.aspecular,
            a.delta_e00.value,
            a.delta_e00.expanded,
            if hit { "" } else { " OUT" }
        );
    }

    let [l, a, b] = accuracy.by_coordinate;
    eprintln!(
        "accuracy: {} of {} coordinates within U ({:.1} %, 95 % interval {:.3?}); L* {}/{}, a* {}/{}, b* {}/{}; from the data {}/{}, the model {}/{}; ΔE00 median {:.2}, p95 {:.2}",
        accuracy.all.hits,
        accuracy.all.trials,
        100.0 * accuracy.all.share(),
        accuracy.all.interval(),
        l.hits, l.trials, a.hits, a.trials, b.hits, b.trials,
        accuracy.by_origin[0].hits, accuracy.by_origin[0].trials,
        accuracy.by_origin[1].hits, accuracy.by_origin[1].trials,
        percentile(&accuracy.delta_e, 0.5),
        percentile(&accuracy.delta_e, 0.95),
    );
    eprintln!(
        "repeatability: ΔE00 within compare's U at {} of {} angle pairs (95 % interval {:.3?}) over {} materials; largest ΔE00 {:.3}",
        repeat.hits,
        repeat.trials,
        repeat.interval(),
        repeated.len(),
        percentile(&repeat_de, 1.0)
    );
    eprintln!("gold against red: {}", c.overall.name());
    if let Ok(path) = std::env::var("GONIO_COLOUR_OUT") {
        let figures = json!({
            "scans": accuracy.delta_e.len() / ASTM_E2539.len(),
            "materials": materials.len(),
            "random_materials": plan.randoms,
            "coverage": accuracy.all.json(),
            "coverage_by_coordinate": {"L": l.json(), "a": a.json(), "b": b.json()},
            "coverage_by_origin": {"data": accuracy.by_origin[0].json(), "model": accuracy.by_origin[1].json()},
            "coverage_by_material": {
                "all": accuracy.by_material(&|_| true),
                "by_kind": KINDS.iter().enumerate().map(|(k, name)| json!({"kind": name, "interval": accuracy.by_material(&|j: &Judged| j.kind() == k)})).collect::<Vec<_>>(),
            },
            "coverage_by_kind": KINDS.iter().zip(&accuracy.by_kind).map(|(k, c)| json!({"kind": k, "count": c.json()})).collect::<Vec<_>>(),
            "coverage_breakdown": accuracy.breakdown(),
            "beyond_data": {"of_model_values": accuracy.beyond_data.json(), "truth_darker": accuracy.beyond_data_overstated.json()},
            "delta_e00": distribution(&accuracy.delta_e),
            "delta_e00_model": distribution(&accuracy.delta_e_model),
            "repeatability": {
                "materials": repeated.len(),
                "all": repeat.json(),
                "by_angle": ASTM_E2539.iter().zip(&repeat_by_angle).map(|(a, c)| json!({"aspecular": a, "count": c.json()})).collect::<Vec<_>>(),
                "largest_delta_e00": percentile(&repeat_de, 1.0),
            },
            "gold_against_red": c.overall.name(),
            "kd_plus_1_percent": kd.json(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&figures).unwrap()).unwrap();
    }
    if std::env::var_os("GONIO_COLOUR_CACHE").is_none() {
        std::fs::remove_dir_all(&dir).ok();
    }

    assert_eq!(c.overall, Verdict::Fail, "gold against red");
    let meets = |count: &Count, lo: f64, hi: f64| {
        if strict {
            (lo..=hi).contains(&count.share())
        } else {
            let [a, b] = count.interval();
            a <= hi && b >= lo
        }
    };
    assert!(
        meets(&accuracy.all, 0.92, 0.98),
        "coverage {} of {} (95 % interval {:?})",
        accuracy.all.hits,
        accuracy.all.trials,
        accuracy.all.interval()
    );
    assert!(
        meets(&repeat, 0.95, 1.0),
        "repeatability {} of {} (95 % interval {:?})",
        repeat.hits,
        repeat.trials,
        repeat.interval()
    );
    assert!(
        meets(&kd, 0.95, 1.0),
        "Kd +1 %: {} of {}",
        kd.hits,
        kd.trials
    );
}

/// The CI run (nine scans, under two minutes on two cores): the example scenes, a smooth
/// lobe and a goniochromatic one, gold and the smooth lobe scanned again, gold with Kd
/// 1 % higher; the targets asserted as
/// reachable by their 95 % intervals over these counts (coverage's interval meets
/// 92–98 %, repeatability's and Kd's reach 95 %). At this size (eight scans, 144
/// coordinates) the Wilson interval of even 144/144 reaches below 98 %, so the test
/// catches an interval too narrow (coverage below about 87 %), not one too wide: the
/// full run judges that side.
#[test]
fn colour_against_the_spectral_truth_fast() {
    validate(
        &Plan {
            randoms: 2,
            repeated_examples: &["gold"],
            repeated_randoms: 1,
            repeats: 1,
        },
        false,
    );
}

/// The full validation (about 4 min on two cores with the release binary;
/// `scripts/results.sh --colour-validation` writes its figures): the example scenes,
/// `GONIO_COLOUR_SCANS` (default 200) random materials, every example and the first four
/// random materials scanned three times more; the targets asserted on the point
/// estimates.
#[test]
#[ignore = "228 scans, minutes; scripts/results.sh --colour-validation runs it and records which targets are met"]
fn colour_against_the_spectral_truth_full() {
    let randoms = std::env::var("GONIO_COLOUR_SCANS")
        .ok()
        .map(|v| v.parse().expect("GONIO_COLOUR_SCANS is a number"))
        .unwrap_or(200);
    validate(
        &Plan {
            randoms,
            repeated_examples: &["gold", "red", "blue-green", "opal"],
            repeated_randoms: 4,
            repeats: 3,
        },
        true,
    );
}
