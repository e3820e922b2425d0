//! Every offline command reports a missing input in one line that names the file and
//! its cause once (an error that quotes its cause does not also chain it); options that
//! do not apply, and a folder that is no scan, are refused.

use std::process::Command;

const NOT_FOUND: &str = "No such file or directory";

/// Runs `gonio args` in `dir`, expects failure, returns stderr.
fn failing(dir: &std::path::Path, args: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("gonio runs");
    assert!(!output.status.success(), "{args:?} succeeded");
    String::from_utf8_lossy(&output.stderr).into_owned()
}

fn assert_once(stderr: &str, needle: &str) {
    assert_eq!(
        stderr.matches(needle).count(),
        1,
        "`{needle}` should appear once in: {stderr}"
    );
}

#[test]
fn missing_inputs_are_named_once_with_their_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("header.csv"),
        "theta_l,theta_i,theta_r,r,g,b\n",
    )
    .unwrap();
    let cases: &[(&[&str], &str)] = &[
        (
            &["simulate", "--scene", "silver", "--out", "scan"],
            "silver",
        ),
        (&["tradeoff", "--scene", "silver", "--out", "t"], "silver"),
        (
            &["fit", "missing.csv", "--model", "ward", "--out", "f.json"],
            "missing.csv",
        ),
        (
            &["study", "missing.csv", "--reference", "r.csv", "--out", "s"],
            "missing.csv",
        ),
        (
            &[
                "study",
                "header.csv",
                "--reference",
                "ref.csv",
                "--out",
                "s",
            ],
            "ref.csv",
        ),
        (&["extract", "nowhere", "--out", "s.csv"], "nowhere"),
        (
            &[
                "tradeoff", "--scene", "gold", "--scan", "nowhere", "--out", "t",
            ],
            "nowhere",
        ),
    ];
    for (args, path) in cases {
        let stderr = failing(dir.path(), args);
        assert!(stderr.starts_with("error: "), "{args:?}: {stderr}");
        assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        assert_once(&stderr, NOT_FOUND);
        assert_once(&stderr, path);
    }
    let stderr = failing(dir.path(), &["report", "nowhere", "--out", "r.html"]);
    assert!(
        stderr.contains("nowhere: no such scan directory"),
        "{stderr}"
    );
    // A name that is no scene: the built-in scenes listed, the file's absence said once.
    let stderr = failing(dir.path(), &["simulate", "--scene", "silver", "--out", "x"]);
    assert!(
        stderr.contains("`silver` is neither a built-in scene (gold, red, blue-green, opal)")
            && stderr.contains(&format!("nor a scene file: {NOT_FOUND}")),
        "{stderr}"
    );
}

#[test]
fn options_that_do_not_apply_and_folders_that_are_no_scan_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("samples.csv"),
        "theta_l,theta_i,theta_r,r,g,b\n-20,10,30,1,1,1\n",
    )
    .unwrap();
    let stderr = failing(
        dir.path(),
        &[
            "fit",
            "samples.csv",
            "--model",
            "ward",
            "--method",
            "nelder-mead",
            "--polish",
            "--out",
            "f.json",
        ],
    );
    assert!(
        stderr.starts_with("error: --polish") && stderr.contains("does not apply"),
        "{stderr}"
    );
    let stderr = failing(
        dir.path(),
        &[
            "export", "f.json", "--format", "mitsuba", "--step", "2", "--out", "f.xml",
        ],
    );
    assert!(stderr.contains("do not apply"), "{stderr}");
    let stderr = failing(
        dir.path(),
        &[
            "study",
            "samples.csv",
            "--held-out",
            "--reference",
            "r.csv",
            "--out",
            "x",
        ],
    );
    assert!(stderr.contains("cannot be used with"), "{stderr}");
    // A folder of results that is no scan (no setup.json, no plan.json).
    let stderr = failing(dir.path(), &["report", ".", "--out", "r.html"]);
    assert!(stderr.contains("not a scan directory"), "{stderr}");
    assert!(!dir.path().join("r.html").exists());
}
