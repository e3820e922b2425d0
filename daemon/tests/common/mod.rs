//! Helpers shared by the CLI tests: run the built `gonio` binary.

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
