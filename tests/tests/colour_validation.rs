//! Multi-angle colour against the emulator's spectral truth (docs/ARCHITECTURE.md,
//! "Multi-angle colour"): accuracy, repeatability and discrimination of `gonio colour`
//! and `gonio compare` on emulated scans.
//!
//! Each scan is rendered (`gonio simulate --binning 8`), extracted with its uncertainty
//! columns and fitted with `--model auto` (its budget included); its colour per geometry
//! (ASTM E2539's six angles, D65/10°) is compared with the L*a*b* of the material's
//! spectral radiance factor at that geometry (`Material::beta_spectrum`, the renderer's
//! own spectral model: thin film and Bragg flakes exactly, camera-RGB models through the
//! smooth spectrum whose camera RGB they are) through the CIE observer directly.
//! Materials: the example scenes and a seeded family of spectral lobes (a thin film or a
//! Bragg band of drawn thickness or wavelength, over a drawn diffuse colour, drawn
//! roughness and strength). Every scan's world departs from its stated setup by errors
//! drawn from the standard uncertainties its setup.json states, and has its own noise seed.
//!
//! Run with `--ignored` (GONIO_BIN=target/debug/gonio to use a built binary): the
//! example scenes and one random material; `GONIO_COLOUR_SCANS=N` runs N random
//! materials and `GONIO_COLOUR_OUT=FILE` writes the figures as JSON.

use std::path::{Path, PathBuf};

use gonio_mock_hw::render::brdf::Geom;
use gonio_mock_hw::scene::Scene;
use gonio_processing::color::delta_e::ciede2000;
use gonio_processing::color::geometry::ASTM_E2539;
use gonio_processing::color::lab::lab_from_xyz;
use gonio_processing::color::observer::{Conditions, Observer};
use gonio_processing::color::transform::{ColourTransform, SplitMix64};
use gonio_processing::color::CameraModel;
use gonio_processing::fit::table::Table;
use gonio_processing::fit::FitResult;
use gonio_processing::multi_angle::compare::{compare, Mounting, Tolerances, Verdict};
use gonio_processing::multi_angle::{colour, ColourReport, Measured};
use gonio_processing::samples::read_csv;
use gonio_tests::{gonio, temp_dir};
use serde_json::json;

const GOLD: &str = include_str!("../../mock-hw/scenes/gold.toml");
const RED: &str = include_str!("../../mock-hw/scenes/red.toml");
const BLUE_GREEN: &str = include_str!("../../mock-hw/scenes/blue-green.toml");
const OPAL: &str = include_str!("../../mock-hw/scenes/opal.toml");

/// Random materials of the CI run.
const FAST_SCANS: usize = 1;

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

/// `base` with its sample replaced (when given), its noise seed `seed`, and the world's
/// departures from the stated setup drawn from `seed`.
fn scene_text(base: &str, sample: Option<&str>, seed: u64) -> String {
    let mut rng = SplitMix64::new(0xC010_0000 + seed);
    let mut text = base.to_string();
    if let Some(sample) = sample {
        let start = text.find("[sample]").unwrap();
        let end = start + text[start..].find("\n\n").unwrap();
        text = format!("{}{sample}{}", &text[..start], &text[end..]);
    }
    let text = text.replace("[effects]\nseed = 1", &format!("[effects]\nseed = {seed}"));
    let u = |key: &str| STATED.iter().find(|(k, _)| *k == key).unwrap().1;
    let angles: Vec<String> = (0..6)
        .map(|_| (normal(&mut rng) * u("arm_angle_deg")).to_string())
        .collect();
    let misalignment = format!(
        "[effects.misalignment]\nwhite_reflectance_error = {}\ncamera_offset_mm = {}\n\
         camera_distance_error_mm = {}\nlight_distance_error_mm = {}\ncylinder_tilt_deg = {}\n\
         arm_zero_offset_deg = {}\narm_angle_errors_deg = [{}]\n",
        normal(&mut rng) * u("white_reflectance"),
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

/// A spectral lobe of the seeded family.
fn random_sample(seed: u64) -> String {
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

/// A scan of scene text: rendered, extracted, fitted with `--model auto`; its colour.
struct Scan {
    scene: Scene,
    report: ColourReport,
}

fn scan(dir: &Path, name: &str, text: &str, transform: &ColourTransform) -> Scan {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    let out: PathBuf = dir.join(name);
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
    let csv = out.join("samples.csv");
    gonio(&["extract", &s(&out), "--out", &s(&csv)]);
    let fit_path = out.join("fit-auto.json");
    gonio(&["fit", &s(&csv), "--model", "auto", "--out", &s(&fit_path)]);
    let fit: FitResult =
        serde_json::from_str(&std::fs::read_to_string(&fit_path).unwrap()).unwrap();
    let samples = read_csv(&csv).unwrap();
    let table = fit
        .table
        .clone()
        .unwrap_or_else(|| Table::new(&samples, 0.0).unwrap());
    let measured = Measured {
        table,
        samples: &samples,
    };
    let report = colour(&fit, Some(&measured), transform, &ASTM_E2539).unwrap();
    std::fs::remove_dir_all(&out).ok();
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

/// Hits of the expanded intervals of L*, a*, b* over the truth, and the ΔE00 to it.
#[derive(Default)]
struct Accuracy {
    hits: usize,
    count: usize,
    hits_data: usize,
    count_data: usize,
    delta_e: Vec<f64>,
}

impl Accuracy {
    fn add(&mut self, scan: &Scan, observer: &Observer, label: &str) {
        for (a, t) in scan.report.angles.iter().zip(truth(scan, observer)) {
            let de = ciede2000(a.lab(), t);
            self.delta_e.push(de);
            let mut line = format!("{label} as {:>4} {:?}:", a.aspecular, a.origin);
            for (c, truth) in [a.l, a.a, a.b].iter().zip(t) {
                let hit = (c.value - truth).abs() <= c.expanded;
                self.hits += usize::from(hit);
                self.count += 1;
                if a.origin == gonio_processing::multi_angle::Origin::Data {
                    self.hits_data += usize::from(hit);
                    self.count_data += 1;
                }
                line += &format!(
                    " {:.2}±{:.2} (truth {truth:.2}{})",
                    c.value,
                    c.expanded,
                    if hit { "" } else { " OUT" }
                );
            }
            eprintln!("{line} ΔE00 {de:.2}");
        }
    }
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((q * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1)]
}

#[test]
#[ignore = "about 5 min (a dozen scans with fits chosen by --model auto); its repeatability target does not hold yet (run with --ignored)"]
fn colour_per_geometry_against_the_spectral_truth_repeats_and_discriminates() {
    let randoms: usize = std::env::var("GONIO_COLOUR_SCANS")
        .ok()
        .map(|v| v.parse().expect("GONIO_COLOUR_SCANS is a number"))
        .unwrap_or(FAST_SCANS);
    let dir = temp_dir("colour-validation");
    let transform = ColourTransform::new(&CameraModel::builtin(), Conditions::D65Ten).unwrap();
    let observer = Observer::new(Conditions::D65Ten);

    // Accuracy: the example scenes and `randoms` materials of the family.
    let mut accuracy = Accuracy::default();
    let gold = scan(&dir, "gold", &scene_text(GOLD, None, 11), &transform);
    accuracy.add(&gold, &observer, "gold");
    let examples = [("red", RED), ("blue-green", BLUE_GREEN), ("opal", OPAL)];
    let mut red = None;
    for (name, text) in examples {
        let s = scan(&dir, name, &scene_text(text, None, 12), &transform);
        accuracy.add(&s, &observer, name);
        if name == "red" {
            red = Some(s);
        }
    }
    for k in 0..randoms {
        let name = format!("random-{k}");
        let s = scan(
            &dir,
            &name,
            &scene_text(GOLD, Some(&random_sample(k as u64)), 100 + k as u64),
            &transform,
        );
        accuracy.add(&s, &observer, &name);
    }
    let mut sorted = accuracy.delta_e.clone();
    sorted.sort_by(f64::total_cmp);
    let coverage = accuracy.hits as f64 / accuracy.count as f64;
    eprintln!(
        "accuracy: {} of {} coordinates within U ({:.1} %), from the data {} of {}; ΔE00 to the truth median {:.2}, p95 {:.2}, max {:.2} over {} geometries",
        accuracy.hits,
        accuracy.count,
        100.0 * coverage,
        accuracy.hits_data,
        accuracy.count_data,
        percentile(&sorted, 0.5),
        percentile(&sorted, 0.95),
        sorted[sorted.len() - 1],
        sorted.len()
    );

    // Repeatability: gold again with other noise seeds and setup errors.
    let (mut within, mut pairs) = (0, 0);
    let mut repeat_de = Vec::new();
    for seed in 21..23 {
        let again = scan(
            &dir,
            &format!("gold-{seed}"),
            &scene_text(GOLD, None, seed),
            &transform,
        );
        let c = compare(
            &gold.report,
            &again.report,
            &Tolerances::default(),
            Mounting::Separate,
        )
        .unwrap();
        for a in &c.angles {
            within += usize::from(a.delta_e00.value <= a.delta_e00.expanded);
            pairs += 1;
            repeat_de.push(a.delta_e00.value);
        }
    }
    eprintln!(
        "repeatability: ΔE00 between repeats within its U at {within} of {pairs} angles; largest ΔE00 {:.3}",
        repeat_de.iter().cloned().fold(0.0, f64::max)
    );

    // Discrimination: gold against red fails; gold with Kd 1 % higher differs by the
    // ΔE00 the spectral truth says.
    let red = red.unwrap();
    let c = compare(
        &gold.report,
        &red.report,
        &Tolerances::default(),
        Mounting::Separate,
    )
    .unwrap();
    eprintln!("gold against red: {}", c.overall.name());
    let lighter = GOLD.replace("kd = [9.0, 6.5, 2.0]", "kd = [9.09, 6.565, 2.02]");
    let moved = scan(&dir, "gold-kd", &scene_text(&lighter, None, 11), &transform);
    // One mounting: the same setup errors (seed 11) for both.
    let c_kd = compare(
        &gold.report,
        &moved.report,
        &Tolerances::default(),
        Mounting::Same,
    )
    .unwrap();
    let (truth_a, truth_b) = (truth(&gold, &observer), truth(&moved, &observer));
    let mut kd_within = 0;
    for ((a, ta), tb) in c_kd.angles.iter().zip(&truth_a).zip(&truth_b) {
        let expected = ciede2000(*ta, *tb);
        let hit = (a.delta_e00.value - expected).abs() <= a.delta_e00.expanded;
        kd_within += usize::from(hit);
        eprintln!(
            "Kd +1 %: as {:>4} ΔE00 {:.3} ± {:.3}, truth {expected:.3}{}",
            a.aspecular,
            a.delta_e00.value,
            a.delta_e00.expanded,
            if hit { "" } else { " OUT" }
        );
    }

    if let Ok(path) = std::env::var("GONIO_COLOUR_OUT") {
        let figures = json!({
            "coordinates": accuracy.count,
            "within": accuracy.hits,
            "coverage": coverage,
            "data_coordinates": accuracy.count_data,
            "data_within": accuracy.hits_data,
            "delta_e00": {"median": percentile(&sorted, 0.5), "p95": percentile(&sorted, 0.95), "max": sorted[sorted.len() - 1], "geometries": sorted.len()},
            "random_materials": randoms,
            "repeatability": {"pairs": pairs, "within": within},
            "gold_against_red": c.overall.name(),
            "kd_plus_1_percent": {"angles": c_kd.angles.len(), "within": kd_within},
        });
        std::fs::write(path, serde_json::to_string_pretty(&figures).unwrap()).unwrap();
    }
    std::fs::remove_dir_all(&dir).ok();

    assert_eq!(c.overall, Verdict::Fail, "gold against red");
    assert!(
        within * 100 >= 95 * pairs,
        "repeatability {within} of {pairs}"
    );
    assert!(
        kd_within * 100 >= 95 * c_kd.angles.len(),
        "Kd +1 %: {kd_within} of {}",
        c_kd.angles.len()
    );
    assert!(
        (0.92..=0.98).contains(&coverage) || accuracy.count < 200,
        "coverage {coverage} over {} coordinates",
        accuracy.count
    );
    assert!(coverage >= 0.8, "coverage {coverage}");
}
