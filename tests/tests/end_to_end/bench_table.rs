//! README's cost table as `scripts/bench_table.py` writes it from a run's results: each
//! row against its floor (what this machine allows), and no table from an unsteady run.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use gonio_tests::temp_dir;

const README: &str = "# gonio\n\n<!-- bench: costs -->\nold table\n<!-- /bench: costs -->\n";

/// The floors and the whole-process results of a run, one JSON object a line; `steal`
/// the share of the CPU time the host took over the run.
fn results(scan_spread: f64, steal: f64) -> String {
    [
        &format!(r#"{{"bench": "steal", "share": {steal}}}"#),
        r#"{"bench": "conditions", "date": "2026-12-04", "cpu": "test", "cores": 2, "load": "0.1"}"#,
        r#"{"bench": "floors", "cores": 2, "read_bytes_per_s": 4e9, "copy_bytes_per_s": 5e9,
            "point_s": {"cook-torrance": 5e-9, "ward": 4e-9, "cook-torrance-fresnel": 6e-9}}"#,
        r#"{"bench": "fit_1000_work", "fits": {"fit_1000/cook-torrance/robust/shared":
            {"evaluations": 200, "points": 1000, "model": "cook-torrance"},
            "fit_1000/auto": {"evaluations": 30, "points": 1000, "model": "cook-torrance",
            "point_evaluations": 170000}}}"#,
        &format!(
            r#"{{"bench": "scan", "ratio": 1.2, "wall_s": 12.0, "hardware_s": 10.0, "spread": {scan_spread}}}"#
        ),
        &format!(
            r#"{{"bench": "fit_auto_command",
                "full": {{"auto_s": 1.4, "cook_torrance_s": 1.0, "ratio": 1.4, "spread": {scan_spread},
                    "points": 8000, "auto_point_evaluations": 20000000}},
                "binning_4": {{"auto_s": 0.5, "cook_torrance_s": 0.25, "ratio": 2.0, "spread": 0.05,
                    "points": 2000, "auto_point_evaluations": 4000000}}}}"#
        ),
        r#"{"bench": "hdr_command", "whole_s": 1.0, "merge_s": 0.5, "spread": 0.1,
            "file_bytes": 1000000000, "decoded_bytes": 2000000000, "map_pixels": 100000000}"#,
        r#"{"bench": "fit_samples", "samples": 8000, "robust_loss": 1.0, "fits": {
            "fit_samples/cook-torrance/robust/shared/budget":
            {"evaluations": 300, "points": 8000, "model": "cook-torrance"},
            "fit_samples/auto": {"evaluations": 40, "points": 8000, "model": "cook-torrance",
            "point_evaluations": 1600000}}}"#,
        r#"{"bench": "budget_monte_carlo", "ks_g_combined": 1.0, "m_combined": 0.01, "runs": [
            {"draws": 250, "seconds": 0.3, "ks_g_std": 0.9, "m_std": 0.008,
             "evaluations": 1500, "points": 8000}]}"#,
        r#"{"bench": "scan_time_scale_1", "ratio": 1.01, "wall_s": 101.0, "hardware_s": 100.0,
            "spread": 0.0}"#,
        r#"{"bench": "study_command", "wall_s": 3.0, "cpu_s": 5.5, "spread": 0.05,
            "point_evaluations": 120000000}"#,
        r#"{"bench": "peers_hdr", "frames": 7, "runs": 3, "opencv_version": "5.1.0",
            "gonio": {"seconds": 1.52, "peak_bytes": 100000000},
            "opencv": {"seconds": 4.0, "peak_bytes": 200000000},
            "file_bytes": 1000000000, "decoded_bytes": 1500000000, "map_pixels": 100000000}"#,
    ]
    .map(|line| line.replace('\n', " "))
    .join("\n")
}

/// A criterion result directory holding one benchmark's median and its interval.
fn criterion(dir: &Path, full_id: &str, median_ns: f64, width: f64) {
    let new = dir.join(full_id.replace('/', "_")).join("new");
    std::fs::create_dir_all(&new).unwrap();
    std::fs::write(
        new.join("benchmark.json"),
        serde_json::json!({ "full_id": full_id }).to_string(),
    )
    .unwrap();
    let half = median_ns * width / 2.0;
    let estimates = serde_json::json!({"median": {
        "point_estimate": median_ns,
        "confidence_interval": {"lower_bound": median_ns - half, "upper_bound": median_ns + half},
    }});
    std::fs::write(new.join("estimates.json"), estimates.to_string()).unwrap();
}

/// Writes the table from `results(spread, steal)` into a README of its own in `dir`:
/// the script's output and the README after it.
fn run(dir: &Path, spread: f64, steal: f64) -> (Output, String) {
    let (results_file, readme) = (dir.join("results.jsonl"), dir.join("README.md"));
    std::fs::write(&results_file, results(spread, steal)).unwrap();
    std::fs::write(&readme, README).unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scripts/bench_table.py");
    let output = Command::new("python3")
        .arg(script)
        .arg(&results_file)
        .arg("--criterion")
        .arg(dir.join("criterion"))
        .arg("--readme")
        .arg(&readme)
        .output()
        .expect("python3 runs");
    (output, std::fs::read_to_string(&readme).unwrap())
}

/// The cells of the row whose first cell starts with `what`.
fn row<'a>(table: &'a str, what: &str) -> Vec<&'a str> {
    let line = table
        .lines()
        .find(|l| l.starts_with(&format!("| {what}")))
        .unwrap_or_else(|| panic!("no row `{what}` in\n{table}"));
    line.trim_matches('|').split(" | ").map(str::trim).collect()
}

#[test]
fn every_row_stands_against_its_floor() {
    let dir = temp_dir("bench-table-floors");
    // 2 ms for 200 evaluations × 1,000 points × 5 ns over 2 cores = 0.5 ms: 4× its floor.
    criterion(
        &dir.join("criterion"),
        "fit_1000/cook-torrance/robust/shared",
        2e6,
        0.02,
    );
    for (id, median_ns) in [
        ("fit_samples/cook-torrance/robust/shared/budget", 24e6),
        ("fit_samples/cook-torrance/robust/shared", 4e6),
        ("fit_samples/auto", 9.6e6),
        ("fit_1000/auto", 5e6),
    ] {
        criterion(&dir.join("criterion"), id, median_ns, 0.02);
    }
    let (output, readme) = run(&dir, 0.05, 0.012);
    assert!(output.status.success(), "{output:?}");
    assert!(
        readme.contains("| what | median | floor | ÷ floor | target | command |"),
        "{readme}"
    );
    assert!(
        readme.contains("the host took 1.2% of the CPU time (steal)"),
        "{readme}"
    );
    let fit = row(&readme, "robust Cook–Torrance fit, 1,000 points");
    assert_eq!(fit[1..4], ["2 ms", "500 µs", "4"], "{fit:?}");
    // The scan's floor is its hardware time.
    let scan = row(&readme, "6-θL `gold` scan through `gonio serve`");
    assert_eq!(scan[2..4], ["10.00 s", "1.2"], "{scan:?}");
    // And at the hardware's own speeds.
    let real = row(&readme, "same scan at the hardware's own speeds");
    assert_eq!(
        real[1..4],
        ["1.010 (101.00 s / 100.00 s)", "100.00 s", "1.01"],
        "{real:?}"
    );
    // `gonio hdr`: 1 GB read + 2 GB decoded + 1.3 GB of map at 5 GB/s = 0.86 s.
    let hdr = row(&readme, "`gonio hdr`, 4 Deflate TIFFs");
    assert_eq!(hdr[2..4], ["860 ms", "1.16"], "{hdr:?}");
    // A budget's floor: its refits' 300 passes × 8,000 points × 5 ns over 2 cores = 6 ms,
    // against the propagation's 24 ms.
    let budget = row(
        &readme,
        "uncertainty budget of the full-size `gold` scan, Cook–Torrance:",
    );
    assert_eq!(budget[2..4], ["6 ms", "4"], "{budget:?}");
    // The Monte Carlo's: 1,500 passes × 8,000 points × 5 ns over 2 cores = 30 ms, against
    // 300 ms.
    let mc = row(&readme, "Monte Carlo of the Cook–Torrance budget");
    assert_eq!(mc[2..4], ["30 ms", "10"], "{mc:?}");
    // `gonio hdr` beside OpenCV: 1 GB read + 1.5 GB decoded + 1.3 GB of map at 5 GB/s =
    // 0.76 s, against 1.52 s.
    let peers = row(&readme, "`gonio hdr` / OpenCV 5.1.0");
    assert_eq!(peers[2..4], ["760 ms", "2"], "{peers:?}");
    // `gonio study`'s: 1.2e8 passes × the three models' mean 5 ns over 2 cores = 300 ms.
    let study = row(&readme, "`gonio study` of the full-size `gold` scan");
    assert_eq!(study[2..4], ["300 ms", "10"], "{study:?}");
    // A model choice's floor counts the fits that judged the candidates: (40 × 8,000 +
    // 1.6e6) × 5 ns over 2 cores = 4.8 ms; (30 × 1,000 + 170,000) × 5 ns / 2 = 500 µs.
    let choice = row(&readme, "fit --model auto / one Cook–Torrance fit");
    assert_eq!(choice[2..4], ["4.8 ms / 500 µs", "2 / 10"], "{choice:?}");
    // Auto against one fit, both scans in one row.
    let auto = row(
        &readme,
        "`gonio fit --model auto` / `--model cook-torrance`",
    );
    assert_eq!(
        auto[1], "1.40 (1.40 s / 1.00 s) / 2.00 (500 ms / 250 ms)",
        "{auto:?}"
    );
    // Its floor, the auto process's passes over the points: 2e7 × 5 ns / 2 = 50 ms;
    // 4e6 × 5 ns / 2 = 10 ms.
    assert_eq!(auto[2..4], ["50 ms / 10 ms", "28 / 50"], "{auto:?}");
    // A row this run did not measure says so rather than keeping an old number.
    let ward = row(&readme, "robust Ward fit");
    assert_eq!(
        ward[1..4],
        ["not measured in this run", "not measured in this run", "—"]
    );
    assert!(
        readme.contains("Floor: what this machine allows"),
        "{readme}"
    );
}

/// The script's complaint about a run whose criterion fit median has an interval of
/// `width` of it, whose whole-process runs spread `spread` and during which the host
/// took `steal` of the CPU time; it must refuse and leave the README as it was.
fn refused(name: &str, width: f64, spread: f64, steal: f64) -> String {
    let dir = temp_dir(name);
    criterion(
        &dir.join("criterion"),
        "fit_1000/cook-torrance/robust/shared",
        2e6,
        width,
    );
    let (output, readme) = run(&dir, spread, steal);
    assert!(!output.status.success(), "{output:?}");
    assert_eq!(readme, README);
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn an_unsteady_run_writes_no_table() {
    let stderr = refused("bench-table-unsteady", 0.02, 0.4, 0.0);
    assert!(stderr.contains("`scan`: runs spread 40%"), "{stderr}");
    // A benchmark of several parts: each part's spread counts.
    assert!(
        stderr.contains("`fit_auto_command/full`: runs spread 40%"),
        "{stderr}"
    );
    // A criterion median whose interval is too wide for the table it is used in.
    let stderr = refused("bench-table-wide", 0.3, 0.05, 0.0);
    assert!(
        stderr.contains("95 % interval 30% of its median"),
        "{stderr}"
    );
    // Steady runs on a host that took a third of the CPU time: slower code, it would read.
    let stderr = refused("bench-table-steal", 0.02, 0.05, 0.33);
    assert!(
        stderr.contains("the host took 33% of the CPU time over the run"),
        "{stderr}"
    );
}
