//! The house rule on file size: no source file of the workspace (Rust, the page's
//! HTML, CSS and JavaScript, the scripts) is over 800 lines. Vendored third-party
//! files (`vendor/` folders) are not ours to split and are left out.

use std::path::{Path, PathBuf};

/// The most lines a source file may have.
const MAX_LINES: usize = 800;

/// Endings of the files the rule covers.
const SOURCE_ENDINGS: [&str; 7] = ["rs", "js", "html", "css", "py", "sh", "toml"];

/// Folders that hold no source of ours: build output, environments, vendored code.
const SKIPPED: [&str; 6] = [
    "target",
    ".git",
    ".venv-test",
    ".venv-bench",
    "vendor",
    "node_modules",
];

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let entry = entry.unwrap();
        let path = entry.path();
        let name = entry.file_name();
        let kind = entry.file_type().unwrap();
        if kind.is_dir() {
            if !SKIPPED.iter().any(|s| name == *s) {
                sources(&path, out);
            }
        } else if kind.is_file()
            && path
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| SOURCE_ENDINGS.contains(&e))
        {
            out.push(path);
        }
    }
}

#[test]
fn no_source_file_is_over_800_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut files = Vec::new();
    sources(root, &mut files);
    assert!(
        files.iter().any(|f| f.ends_with("server/src/lib.rs")),
        "the walk must see the workspace's sources (found {})",
        files.len()
    );
    let mut over: Vec<String> = files
        .iter()
        .filter_map(|file| {
            let lines = std::fs::read_to_string(file).ok()?.lines().count();
            (lines > MAX_LINES).then(|| {
                format!(
                    "{} ({lines} lines)",
                    file.strip_prefix(root).unwrap().display()
                )
            })
        })
        .collect();
    over.sort();
    assert!(
        over.is_empty(),
        "source files over {MAX_LINES} lines: {}",
        over.join(", ")
    );
}
