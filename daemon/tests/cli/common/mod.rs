//! Helpers shared by the CLI tests: run the built `gonio` binary. Each test file uses
//! the ones it needs.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the built `gonio` with `args` and returns its status and output.
pub fn gonio(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .output()
        .unwrap()
}

/// Captured output as text (lossy UTF-8).
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Runs the built `gonio` with `args`; fails the test with its standard error if it
/// fails, else returns its standard output.
pub fn gonio_ok(args: &[&str]) -> String {
    let out = gonio(args);
    assert!(
        out.status.success(),
        "gonio {args:?}: {}",
        text(&out.stderr)
    );
    text(&out.stdout)
}

/// A small emulated scan of `gold` (binning 8, three θL) in `dir/scan`.
pub fn small_scan(dir: &Path) -> PathBuf {
    let scan = dir.join("scan");
    gonio_ok(&[
        "simulate",
        "--scene",
        "gold",
        "--binning",
        "8",
        "--theta-l",
        "-20,-30,-40",
        "--out",
        scan.to_str().unwrap(),
    ]);
    scan
}
