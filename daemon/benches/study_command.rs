//! `gonio study` as a whole process on the full-size `gold` scan, as docs/results runs
//! it: the 63 θL combinations × 3 models with their uncertainty, and the Nelder–Mead
//! comparison of the paper's two models, every column fitted. The scan is rendered by
//! `gonio simulate` and extracted once; the study runs `--runs` times (default 3).
//! Prints the median wall time (target ≤ 4 s on the 2-core machine, idle) and the
//! median CPU time of the process (user + system, which a loaded machine disturbs less),
//! then the result as JSON (`{"bench": "study_command", ...}`), which scripts/bench.sh
//! keeps, with the study's work from its `study.json` (`point_evaluations`: its fits'
//! loss evaluations × their points).
//!
//!     cargo bench -p gonio-daemon --bench study_command [-- --runs N]

mod common;
mod stats;

use std::time::Instant;

/// User + system CPU seconds of the children waited for so far.
fn children_cpu_s() -> f64 {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct it is given.
    let usage = unsafe {
        libc::getrusage(libc::RUSAGE_CHILDREN, usage.as_mut_ptr());
        usage.assume_init()
    };
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    seconds(usage.ru_utime) + seconds(usage.ru_stime)
}

fn main() {
    let runs = common::runs(3);
    let gonio = env!("CARGO_BIN_EXE_gonio");
    let dir = tempfile::tempdir().expect("temp dir");
    common::run(
        gonio,
        &["simulate", "--scene", "gold", "--out", "scan"],
        dir.path(),
    );
    common::run(
        gonio,
        &["extract", "scan", "--out", "samples.csv"],
        dir.path(),
    );
    let study = [
        "study",
        "samples.csv",
        "--reference",
        "scan/reference.csv",
        "--out",
        "study",
    ];
    let mut wall = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..runs {
        let before = children_cpu_s();
        let started = Instant::now();
        common::run(gonio, &study, dir.path());
        wall.push(started.elapsed().as_secs_f64());
        cpu.push(children_cpu_s() - before);
    }
    let spread = stats::spread(&wall);
    let (wall_s, cpu_s) = (stats::median(&wall), stats::median(&cpu));
    let summary = std::fs::read_to_string(dir.path().join("study/study.json")).expect("study.json");
    let summary: serde_json::Value = serde_json::from_str(&summary).expect("study.json is JSON");
    println!("gonio study, full-size gold scan, 3 models, Nelder–Mead compared, median of {runs}:");
    println!("  wall {wall_s:.2} s (target ≤ 4 s), CPU {cpu_s:.2} s");
    println!(
        "{}",
        serde_json::json!({
            "bench": "study_command",
            "wall_s": wall_s,
            "cpu_s": cpu_s,
            "spread": spread,
            "point_evaluations": summary["point_evaluations"],
        })
    );
}
