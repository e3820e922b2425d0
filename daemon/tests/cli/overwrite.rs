//! No offline command writes its result over a file it reads: an `--out` naming one of
//! its inputs (by any name), or a scan's own files (setup, plan, truth, reference, the
//! captures and their sidecars), is refused before anything is done, and the file is left
//! as it was.

use crate::common;

use std::fs;
use std::path::Path;

use common::{gonio, gonio_ok, small_scan, text};

/// `gonio args` fails naming what it would have replaced, and `kept` is unchanged.
fn refused(args: &[&str], kept: &Path) {
    let before = fs::read(kept).unwrap();
    let out = gonio(args);
    let stderr = text(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert!(
        stderr.contains("would replace") && stderr.trim_end().lines().count() == 1,
        "{args:?}: {stderr}"
    );
    assert_eq!(fs::read(kept).unwrap(), before, "{args:?} changed {kept:?}");
}

#[test]
fn an_output_over_an_input_is_refused_and_the_input_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let scan = path(
        small_scan(dir.path())
            .file_name()
            .unwrap()
            .to_str()
            .unwrap(),
    );
    let theta = format!("{scan}/theta_l_-20.0");
    let (frame, sidecar) = (
        format!("{theta}/exp_00.tiff"),
        format!("{theta}/exp_00.json"),
    );
    let setup = format!("{scan}/setup.json");
    let samples = format!("{scan}/samples.csv");

    // A scan's files, through the scan directory.
    refused(&["extract", &scan, "--out", &setup], Path::new(&setup));
    refused(&["extract", &scan, "--out", &sidecar], Path::new(&sidecar));
    refused(&["calibrate", &scan, "--out", &setup], Path::new(&setup));
    // Writing the samples into the scan directory is what the daemon does: allowed.
    gonio_ok(&["extract", &scan, "--out", &samples]);

    // A frame or its sidecar given as an input.
    let frames: Vec<String> = (0..4).map(|i| format!("{theta}/exp_0{i}.tiff")).collect();
    let mut hdr = vec!["hdr", "--out", &frame];
    hdr.extend(frames.iter().map(String::as_str));
    refused(&hdr, Path::new(&frame));
    hdr[2] = &sidecar;
    refused(&hdr, Path::new(&sidecar));

    // The same file by another name: `./` and a hard link.
    let fit = path("fit.json");
    gonio_ok(&["fit", &samples, "--model", "ward", "--out", &fit]);
    let linked = path("linked.csv");
    fs::hard_link(&samples, &linked).unwrap();
    refused(
        &["fit", &linked, "--model", "ward", "--out", &samples],
        Path::new(&samples),
    );
    let dotted = format!("{scan}/./samples.csv");
    refused(
        &["fit", &samples, "--model", "ward", "--out", &dotted],
        Path::new(&samples),
    );
    refused(
        &["export", &fit, "--format", "mitsuba", "--out", &fit],
        Path::new(&fit),
    );

    // A scan's results that `report` reads.
    fs::copy(&fit, format!("{scan}/fit-ward.json")).unwrap();
    refused(&["report", &scan, "--out", &samples], Path::new(&samples));
    gonio_ok(&["report", &scan, "--out", &path("report.html")]);
}
