//! `gonio hdr` as a whole process against the merge alone, on the same bracket: the
//! builtin `gold` scene's frames at θL −20° (full size), rendered by `gonio simulate`.
//! The command decodes its frames in parallel; its target is a whole-process time
//! within 1.5× of the merge alone. Decoding and writing the EXR are timed alone too.
//!
//!     cargo bench -p gonio-daemon --bench hdr_command [-- --runs N]
//!
//! The last line is the result as JSON (`{"bench": "hdr_command", ...}`), which
//! scripts/bench.sh keeps.

mod common;
mod stats;

use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use gonio_processing::capture::{is_capture_path, Frame};
use gonio_processing::hdr::{merge, MergeOptions};

/// `f`'s value and the seconds it took.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let started = Instant::now();
    let value = f();
    (value, started.elapsed().as_secs_f64())
}

fn main() {
    let runs = common::runs(5);
    let gonio = env!("CARGO_BIN_EXE_gonio");
    let dir = tempfile::tempdir().expect("temp dir");
    let simulate = [
        "simulate",
        "--scene",
        "gold",
        "--theta-l",
        "-20",
        "--out",
        "scan",
    ];
    common::run(gonio, &simulate, dir.path());
    let mut frames: Vec<PathBuf> = std::fs::read_dir(dir.path().join("scan/theta_l_-20.0"))
        .expect("frames")
        .map(|e| e.expect("entry").path())
        .filter(|p| is_capture_path(p))
        .collect();
    frames.sort();
    let out = dir.path().join("map.exr");
    let command = || {
        let output = Command::new(gonio)
            .arg("hdr")
            .arg("--out")
            .arg(&out)
            .args(&frames)
            .output()
            .expect("running gonio hdr");
        assert!(output.status.success(), "{output:?}");
    };
    // Warm the page cache.
    command();
    let mut whole = Vec::new();
    let mut decode = Vec::new();
    let mut merged = Vec::new();
    let mut write = Vec::new();
    for _ in 0..runs {
        whole.push(timed(command).1);
        let (decoded, took) = timed(|| Frame::read_all(&frames).expect("decoding"));
        decode.push(took);
        let (map, took) = timed(|| merge(&decoded, &MergeOptions::default()).expect("merging"));
        merged.push(took);
        drop(decoded);
        write.push(timed(|| map.write_exr(&out).expect("writing")).1);
    }
    // What the process must move at least: the files read, the frames decoded, the map.
    let file_bytes: u64 = frames
        .iter()
        .map(|p| std::fs::metadata(p).map_or(0, |m| m.len()))
        .sum();
    let decoded = Frame::read_all(&frames).expect("decoding");
    let decoded_bytes: usize = decoded.iter().map(|f| 2 * f.data.len()).sum();
    let (width, height) = (decoded[0].width, decoded[0].height);
    drop(decoded);
    let (whole_spread, merge_spread) = (stats::spread(&whole), stats::spread(&merged));
    let (whole, merge_s) = (stats::median(&whole), stats::median(&merged));
    println!(
        "gonio hdr, {} frames of the gold scene at θL −20°, median of {runs}:",
        frames.len()
    );
    println!("  whole process {whole:.3} s");
    println!("  decode alone  {:.3} s (parallel)", stats::median(&decode));
    println!("  merge alone   {merge_s:.3} s");
    println!("  EXR write     {:.3} s", stats::median(&write));
    println!("  whole / merge {:.2} (target ≤ 1.5)", whole / merge_s);
    // The line scripts/bench.sh keeps for the README's table.
    println!(
        "{}",
        serde_json::json!({
            "bench": "hdr_command",
            "whole_s": whole,
            "merge_s": merge_s,
            "spread": whole_spread.max(merge_spread),
            "file_bytes": file_bytes,
            "decoded_bytes": decoded_bytes,
            "map_pixels": width * height,
        })
    );
}
