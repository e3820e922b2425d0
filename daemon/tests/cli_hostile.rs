//! The offline commands on hostile input: crafted captures, absurd values and setups,
//! outputs that cannot be written. Each exits non-zero with a one-line error naming what
//! is wrong: never a panic (exit 101), an abort, a printed backtrace, or a removed path.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn gonio(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .output()
        .expect("gonio runs")
}

fn seed(target: &str, name: &str) -> Vec<u8> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target)
        .join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Writes a TIFF+sidecar seed of the fuzz corpus as `dir/name.tiff` + `dir/name.json`.
fn capture_from_seed(dir: &Path, name: &str) -> PathBuf {
    let bytes = seed("tiff_sidecar", name);
    let len = usize::from(u16::from_le_bytes([bytes[0], bytes[1]]));
    let image = dir.join(format!("{name}.tiff"));
    std::fs::write(dir.join(format!("{name}.json")), &bytes[2..2 + len]).unwrap();
    std::fs::write(&image, &bytes[2 + len..]).unwrap();
    image
}

/// `gonio hdr --out OUT INPUT`.
fn hdr(out: &Path, input: &Path) -> Output {
    gonio(&[
        "hdr".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        input.as_os_str(),
    ])
}

/// A failure: exit 1, one line on stderr starting `error:`, no panic text.
fn assert_clean_failure(output: &Output, needle: &str) -> String {
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.starts_with("error: "), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(stderr.contains(needle), "wanted {needle:?} in {stderr}");
    stderr
}

#[test]
fn hdr_refuses_crafted_captures_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    for (name, needle) in [
        ("regression_huge_width_u32max", "max_frame_pixels"),
        ("regression_huge_100k_square", "max_frame_pixels"),
        ("regression_huge_compressed_claim", "max_frame_pixels"),
        ("strip_too_short", "frame.tiff"),
        (
            "strip_offset_outside_file",
            "strip_offset_outside_file.tiff",
        ),
        ("rows_per_strip_zero", "rows_per_strip_zero.tiff"),
    ] {
        let image = capture_from_seed(dir.path(), name);
        let out = dir.path().join(format!("{name}.exr"));
        let output = hdr(&out, &image);
        let needle = if needle == "frame.tiff" { name } else { needle };
        assert_clean_failure(&output, needle);
        assert!(!out.exists(), "{name}: no output on failure");
    }
    // A raw file whose directory claims 200000×150000 pixels: refused before decoding.
    let raw = dir.path().join("huge.dng");
    std::fs::write(&raw, seed("raw", "regression_huge_subifd_dims")).unwrap();
    std::fs::write(
        dir.path().join("huge.json"),
        r#"{"shutter_s":0.01,"iso":100,"theta_l":-20,"camera":"x","time":"t"}"#,
    )
    .unwrap();
    let out = dir.path().join("raw.exr");
    let output = hdr(&out, &raw);
    assert_clean_failure(&output, "max_frame_pixels");
    // Raw data the decoder cannot read: rawler's own caught panics print nothing.
    std::fs::write(&raw, seed("raw", "truncated_dng")).unwrap();
    let output = hdr(&out, &raw);
    assert_clean_failure(&output, "huge.dng");
}

/// `--out` through a link to a path whose writes fail (a stand-in for `/dev/full`, which
/// the EXR writer once deleted): the error is reported and the link is still there.
#[test]
fn a_failed_output_never_removes_a_path_it_did_not_create() {
    let dir = tempfile::tempdir().unwrap();
    let image = capture_from_seed(dir.path(), "valid_rgb16_4x3");
    let full = Path::new("/dev/full");
    let link = dir.path().join("out.exr");
    if full.exists() {
        std::os::unix::fs::symlink(full, &link).unwrap();
        let output = hdr(&link, &image);
        assert_clean_failure(&output, "out.exr");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert!(full.exists());
    }
    // A directory as the output: refused, left alone.
    let target = dir.path().join("a-directory");
    std::fs::create_dir(&target).unwrap();
    std::fs::write(target.join("keep"), b"x").unwrap();
    let output = hdr(&target, &image);
    assert_clean_failure(&output, "directory");
    assert!(target.join("keep").is_file());
    // A regular file is replaced whole, with no temporary left beside it.
    let good = dir.path().join("good.exr");
    std::fs::write(&good, b"old").unwrap();
    let output = hdr(&good, &image);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert_ne!(std::fs::read(&good).unwrap(), b"old");
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".partial"))
        .collect();
    assert!(names.is_empty(), "{names:?}");
}

#[test]
fn fit_refuses_a_beta_whose_square_overflows_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("samples.csv");
    std::fs::write(&csv, seed("samples_csv", "regression_beta_1e308")).unwrap();
    let out = dir.path().join("fit.json");
    let output = gonio(&[
        "fit".as_ref(),
        csv.as_os_str(),
        "--model".as_ref(),
        "cook-torrance".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert_clean_failure(&output, "line 2");
    assert!(!out.exists());
}

/// A setup whose camera sees no column of the cylinder: no samples, so a non-zero exit
/// naming the reason (it once exited 0 with an empty CSV).
#[test]
fn extract_with_no_samples_exits_non_zero_naming_the_dominant_reason() {
    let dir = tempfile::tempdir().unwrap();
    let scan = dir.path().join("scan");
    let scene = dir.path().join("scene.toml");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/tiny_scene.toml");
    let text = std::fs::read_to_string(fixture).unwrap()
        + "\n[sample]\nmodel = \"cook-torrance\"\nkd = [9.0, 6.5, 2.0]\nks = [25.0, 20.0, 7.0]\nm = [0.07]\n";
    std::fs::write(&scene, text).unwrap();
    let output = gonio(&[
        "simulate".as_ref(),
        "--scene".as_ref(),
        scene.as_os_str(),
        "--out".as_ref(),
        scan.as_os_str(),
    ]);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // The same captures with the camera 10 km away: the cylinder is not in the picture.
    let setup_path = scan.join("setup.json");
    let mut setup: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&setup_path).unwrap()).unwrap();
    setup["camera_distance_mm"] = serde_json::json!(1e7);
    std::fs::write(&setup_path, setup.to_string()).unwrap();
    let out = dir.path().join("samples.csv");
    let output = gonio(&[
        "extract".as_ref(),
        scan.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert_clean_failure(&output, "no samples");
    assert!(!out.exists());
}
