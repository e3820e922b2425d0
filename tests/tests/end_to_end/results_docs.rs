//! The tables of docs/results/README.md and the README's Results summary say what the
//! committed outputs under docs/results say: `scripts/results_docs.py --check` rebuilds
//! every table from those outputs and fails on any difference. And the check can fail:
//! on a copy whose outputs say something else, it names the table that no longer agrees.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the tests crate sits in the repository")
        .to_path_buf()
}

fn check(root: &Path) -> Output {
    Command::new("python3")
        .arg(repository().join("scripts/results_docs.py"))
        .arg("--root")
        .arg(root)
        .arg("--check")
        .output()
        .expect("python3 runs (scripts/test.sh installs it)")
}

#[test]
fn committed_tables_match_the_committed_outputs() {
    let output = check(&repository());
    assert!(
        output.status.success(),
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
}

/// Copies the documents and the outputs the tables are built from into `to`.
fn copy_inputs(from: &Path, to: &Path) {
    let files = ["README.md", "docs/results/README.md"];
    let per_scene = [
        "study/study.json",
        "study/boxplots.csv",
        "tradeoff/tradeoff.json",
        "tradeoff/tradeoff.csv",
    ];
    let mut all: Vec<PathBuf> = files.iter().map(PathBuf::from).collect();
    for entry in std::fs::read_dir(from.join("docs/results")).expect("docs/results") {
        let scene = entry.expect("entry").path();
        let name = Path::new("docs/results").join(scene.file_name().expect("name"));
        if scene.join("study/study.json").is_file() {
            all.extend(per_scene.iter().map(|f| name.join(f)));
        }
        if scene.join("colour.json").is_file() {
            all.push(name.join("colour.json"));
        }
    }
    let real = from.join("docs/results/real-materials");
    if let Ok(entries) = std::fs::read_dir(&real) {
        for entry in entries {
            let path = entry.expect("entry").path();
            let name =
                Path::new("docs/results/real-materials").join(path.file_name().expect("name"));
            if path.join("held_out.json").is_file() {
                all.push(name.join("held_out.json"));
            }
            if path.join("colour.json").is_file() {
                all.push(name.join("colour.json"));
            }
            if path.is_file() {
                all.push(name);
            }
        }
    }
    for output in [
        "docs/results/uncertainty/coverage.json",
        "docs/results/uncertainty/coverage-defaults.json",
        "docs/results/uncertainty/coverage-lab.json",
        "docs/results/verdicts/verdicts.json",
        "docs/results/verdicts/command.txt",
        "docs/results/colour-validation/figures.json",
        "docs/results/colour-validation/command.txt",
    ] {
        if from.join(output).is_file() {
            all.push(PathBuf::from(output));
        }
    }
    for file in all {
        let target = to.join(&file);
        std::fs::create_dir_all(target.parent().expect("parent")).expect("create dir");
        std::fs::copy(from.join(&file), &target).expect("copy input");
    }
}

#[test]
fn a_table_that_no_longer_matches_its_outputs_is_named() {
    let dir = std::env::temp_dir().join(format!("gonio-results-docs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    copy_inputs(&repository(), &dir);
    assert!(check(&dir).status.success(), "the copy starts consistent");

    // The gold study took another time than the table says.
    let path = dir.join("docs/results/gold/study/study.json");
    let mut study: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).expect("study.json"))
            .expect("study.json is JSON");
    let seconds = study["seconds"].as_f64().expect("seconds");
    study["seconds"] = (seconds * 2.0 + 1.0).into();
    std::fs::write(&path, study.to_string()).expect("write study.json");
    let output = check(&dir);
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    std::fs::remove_dir_all(&dir).expect("remove the copy");
    assert!(!output.status.success(), "a stale table passed: {stdout}");
    assert!(
        stdout.contains("docs/results/README.md: study-time"),
        "the stale table is named: {stdout}"
    );
    assert!(
        !stdout.contains("README.md: summary"),
        "only the stale table is named: {stdout}"
    );
}
