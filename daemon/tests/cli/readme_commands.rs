//! The README's offline commands, taken from README.md itself (the indented block after
//! the `offline-commands` marker) and run as written by bash with the built `gonio`
//! first on PATH, in an empty directory: they cannot drift from what the README shows.

use std::path::Path;
use std::process::Command;

const MARKER: &str = "<!-- offline-commands:";

/// The indented command block that follows the marker line.
fn offline_commands(readme: &str) -> Vec<String> {
    let after = readme
        .split_once(MARKER)
        .expect("README.md has the offline-commands marker")
        .1;
    after
        .lines()
        .skip(1)
        .skip_while(|line| line.trim().is_empty())
        .take_while(|line| line.starts_with("    ") || line.trim().is_empty())
        .filter(|line| !line.trim().is_empty())
        .map(|line| line.trim().to_owned())
        .collect()
}

#[test]
fn readme_offline_commands_run_as_written() {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .expect("README.md");
    let commands = offline_commands(&readme);
    assert!(commands.len() >= 6, "{commands:?}");
    for sub in [
        "simulate",
        "hdr",
        "extract",
        "calibrate",
        "fit",
        "study",
        "tradeoff",
    ] {
        assert!(
            commands
                .iter()
                .any(|c| c.starts_with(&format!("gonio {sub} "))),
            "the README's block has no `gonio {sub}`: {commands:?}"
        );
    }

    let dir = tempfile::tempdir().unwrap();
    let bin_dir = Path::new(env!("CARGO_BIN_EXE_gonio")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin_dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let script = format!("set -euo pipefail\n{}\n", commands.join("\n"));
    let output = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(dir.path())
        .env("PATH", path)
        .output()
        .expect("bash runs");
    assert!(
        output.status.success(),
        "README commands failed:\n{script}\nstdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    for produced in [
        "scan/setup.json",
        "map.exr",
        "samples.csv",
        "fit.json",
        "fit-ward.json",
        "study/study.json",
        "tradeoff/tradeoff.csv",
    ] {
        assert!(dir.path().join(produced).is_file(), "{produced} missing");
    }
    // The temporary scan `tradeoff` rendered is gone and was never named.
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(!stdout.contains(".scan-"), "{stdout}");
    assert!(std::fs::read_dir(dir.path().join("tradeoff"))
        .unwrap()
        .flatten()
        .all(|e| !e.file_name().to_string_lossy().starts_with('.')));
}
