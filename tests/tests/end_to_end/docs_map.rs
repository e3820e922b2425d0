//! docs/ARCHITECTURE.md stays a map: at most 500 lines, every relative link in it names a
//! file that exists, and every detail file it links under a crate's `src/` is a module's
//! documentation (included by `include_str!` from a source file beside it), so that
//! `cargo doc` renders it.

use std::fs;
use std::path::{Component, Path, PathBuf};

const MAP: &str = "docs/ARCHITECTURE.md";
const MAX_LINES: usize = 500;

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the tests crate sits in the repository")
        .to_path_buf()
}

/// The targets of the Markdown links `[text](target)` in `text` that are relative paths:
/// no scheme, not an anchor alone; a `#fragment` is cut off.
fn relative_links(text: &str) -> Vec<String> {
    let mut links = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("](") {
        rest = &rest[at + 2..];
        let Some(end) = rest.find(')') else { break };
        let target = rest[..end].trim();
        rest = &rest[end..];
        let path = target.split('#').next().unwrap_or_default();
        if path.is_empty() || path.contains("://") || path.starts_with("mailto:") {
            continue;
        }
        links.push(path.to_string());
    }
    links
}

/// `path` with `.` and `..` components folded away (no file system access).
fn normalise(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// The map's text.
fn map_text() -> String {
    fs::read_to_string(repository().join(MAP)).expect("the map is readable")
}

/// The links of `text` (a file in `dir`) that name no existing file or directory.
fn broken_links(text: &str, dir: &Path) -> Vec<String> {
    relative_links(text)
        .into_iter()
        .filter(|link| !dir.join(link).exists())
        .collect()
}

/// Every `.rs` file below `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in fs::read_dir(dir).expect("a crate's source directory is readable") {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The files `source` includes with `include_str!("…")`, resolved against its directory.
fn included_files(source: &Path) -> Vec<PathBuf> {
    let text = fs::read_to_string(source).expect("a source file is readable");
    let dir = source.parent().expect("a source file has a directory");
    text.split("include_str!(\"")
        .skip(1)
        .filter_map(|tail| tail.split('"').next())
        .map(|name| normalise(&dir.join(name)))
        .collect()
}

#[test]
fn the_map_is_at_most_500_lines() {
    let lines = map_text().lines().count();
    assert!(
        lines <= MAX_LINES,
        "{MAP} has {lines} lines; at most {MAX_LINES}: move detail into the Markdown file \
         beside its code and link it"
    );
}

#[test]
fn every_relative_link_of_the_map_resolves() {
    let root = repository();
    let text = map_text();
    assert!(
        relative_links(&text).len() >= 20,
        "the map links its detail files"
    );
    let broken = broken_links(&text, &root.join("docs"));
    assert!(
        broken.is_empty(),
        "{MAP} links to missing files: {broken:?}"
    );
}

#[test]
fn every_detail_file_the_map_links_is_a_modules_documentation() {
    let root = repository();
    let text = map_text();
    let mut missing = Vec::new();
    for link in relative_links(&text) {
        let target = normalise(&root.join("docs").join(&link));
        let Ok(inside) = target.strip_prefix(&root) else {
            continue;
        };
        let mut parts = inside.components();
        let (Some(krate), Some(src)) = (parts.next(), parts.next()) else {
            continue;
        };
        if src.as_os_str() != "src" || target.extension().is_none_or(|e| e != "md") {
            continue;
        }
        let mut sources = Vec::new();
        rust_files(&root.join(krate.as_os_str()).join("src"), &mut sources);
        if !sources
            .iter()
            .any(|source| included_files(source).contains(&target))
        {
            missing.push(link);
        }
    }
    assert!(
        missing.is_empty(),
        "detail files no module includes as its documentation: {missing:?}"
    );
}

#[test]
fn the_link_check_finds_a_broken_link() {
    let root = repository();
    let text = "See [the HDR merge](../processing/src/hdr.md#limits), \
                [nowhere](../processing/src/no_such_topic.md), \
                [a site](https://example.org/x.md) and [a section](#crates).";
    assert_eq!(
        relative_links(text),
        [
            "../processing/src/hdr.md",
            "../processing/src/no_such_topic.md"
        ]
    );
    assert_eq!(
        broken_links(text, &root.join("docs")),
        ["../processing/src/no_such_topic.md"]
    );
}
