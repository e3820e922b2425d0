//! What the whole-process benchmarks share: their command line, and running `gonio`.

use std::path::Path;
use std::process::{Command, Stdio};

/// `--runs N` from the bench's arguments (`default` without it); `--bench`, which cargo
/// passes to every bench target, is ignored, anything else refused.
pub fn runs(default: usize) -> usize {
    let mut runs = default;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--runs" => runs = args.next().and_then(|n| n.parse().ok()).expect("--runs N"),
            "--bench" => {}
            other => panic!("unknown argument {other}"),
        }
    }
    runs
}

/// Runs `gonio args` in `dir` and asserts that it succeeded.
pub fn run(gonio: &str, args: &[&str], dir: &Path) {
    let output = Command::new(gonio)
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .output()
        .expect("running gonio");
    assert!(output.status.success(), "gonio {args:?}: {output:?}");
}
