//! `gonio fit --model auto` against `gonio fit --model cook-torrance` as whole processes
//! (reading the samples, the fit, its uncertainty budget, writing the JSON), on the
//! samples of the full-size `gold` scan and of the same scan binned 4 × 4. The scans are
//! rendered by `gonio simulate` and extracted once; the two commands then run in turn
//! `--runs` times (default 7), so a load that comes and goes weighs on both alike, each
//! run timing five processes in a row.
//! Prints each median wall time and their ratio (target ≤ 2), then the result as JSON
//! (`{"bench": "fit_auto_command", ...}`), which scripts/bench.sh keeps, with each
//! process's work from the fit JSON it writes: its passes over the points (the fit's
//! loss evaluations and its budget's refits', each × the points, plus the model choice's
//! `point_evaluations`).
//!
//!     cargo bench -p gonio-daemon --bench fit_auto_command [-- --runs N]

mod common;
mod stats;

use std::path::Path;
use std::time::Instant;

/// Processes timed together as one run: a process of a few tens of milliseconds alone
/// varies by as much as it takes with the scheduler's whims, a batch far less.
const BATCH: usize = 5;

/// The median wall seconds of `gonio fit --model auto` and of `--model cook-torrance` on
/// `samples` (a run: [`BATCH`] processes in a row, its time per process), the two run in
/// turn `runs` times, and the larger of their spreads.
fn compare(gonio: &str, samples: &str, runs: usize, dir: &Path) -> (f64, f64, f64) {
    let mut times = [Vec::new(), Vec::new()];
    for _ in 0..runs {
        for (model, times) in ["auto", "cook-torrance"].iter().zip(&mut times) {
            let fit = ["fit", samples, "--model", model, "--out", "fit.json"];
            let started = Instant::now();
            for _ in 0..BATCH {
                common::run(gonio, &fit, dir);
            }
            times.push(started.elapsed().as_secs_f64() / BATCH as f64);
        }
    }
    let spread = stats::spread(&times[0]).max(stats::spread(&times[1]));
    (stats::median(&times[0]), stats::median(&times[1]), spread)
}

/// The loss evaluations × points of `gonio fit --model MODEL` on `samples` (of `points`
/// points), read from the fit JSON it writes.
fn point_evaluations(gonio: &str, samples: &str, model: &str, points: u64, dir: &Path) -> u64 {
    let out = format!("work-{model}.json");
    common::run(
        gonio,
        &["fit", samples, "--model", model, "--out", &out],
        dir,
    );
    let text = std::fs::read_to_string(dir.join(&out)).expect("the fit JSON");
    let fit: serde_json::Value = serde_json::from_str(&text).expect("fit JSON");
    let count = |v: &serde_json::Value| v.as_u64().unwrap_or(0);
    (count(&fit["evaluations"]) + count(&fit["budget"]["evaluations"])) * points
        + count(&fit["selection"]["point_evaluations"])
}

fn main() {
    let runs = common::runs(7);
    let gonio = env!("CARGO_BIN_EXE_gonio");
    let dir = tempfile::tempdir().expect("temp dir");
    let mut rows = serde_json::Map::new();
    for (name, binning) in [("full", "1"), ("binning_4", "4")] {
        let scan = format!("scan_{name}");
        let samples = format!("{name}.csv");
        let simulate = [
            "simulate",
            "--scene",
            "gold",
            "--binning",
            binning,
            "--out",
            &scan,
        ];
        common::run(gonio, &simulate, dir.path());
        common::run(gonio, &["extract", &scan, "--out", &samples], dir.path());
        let (auto, cook_torrance, spread) = compare(gonio, &samples, runs, dir.path());
        let ratio = auto / cook_torrance;
        let csv = std::fs::read_to_string(dir.path().join(&samples)).expect("samples");
        let points = csv.lines().skip(1).filter(|l| !l.trim().is_empty()).count() as u64;
        let work = |model| point_evaluations(gonio, &samples, model, points, dir.path());
        println!(
            "gonio fit, gold scan ({name}), median of {runs}: --model auto {auto:.3} s, \
             --model cook-torrance {cook_torrance:.3} s, ratio {ratio:.2} (target ≤ 2)"
        );
        rows.insert(
            name.to_string(),
            serde_json::json!({
                "auto_s": auto,
                "cook_torrance_s": cook_torrance,
                "ratio": ratio,
                "spread": spread,
                "points": points,
                "auto_point_evaluations": work("auto"),
                "cook_torrance_point_evaluations": work("cook-torrance"),
            }),
        );
    }
    rows.insert("bench".into(), "fit_auto_command".into());
    println!("{}", serde_json::Value::Object(rows));
}
