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

/// The temporaries left in `dir`.
fn partials(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".partial"))
        .collect()
}

/// The tiny fixture scene with a Cook–Torrance sample simulated into `dir`/scan (its
/// scene file `dir`/scene.toml); the scan's path.
fn simulated_scan(dir: &Path) -> std::path::PathBuf {
    let scan = dir.join("scan");
    let scene = dir.join("scene.toml");
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
    scan
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
    // A crop outside the sensor: with overflow checks rawler panics, catches it and
    // says so over two lines (joined into one); without them it decodes and the layout
    // check refuses the crop. One line either way.
    std::fs::write(&raw, seed("raw", "regression_crop_outside_sensor")).unwrap();
    let output = hdr(&out, &raw);
    let message = assert_clean_failure(&output, "huge.dng");
    assert!(
        message.contains("Caught a panic while decoding. Please file a bug")
            || message.contains("crop 8×6 at (6, 4) leaves the 8×6 sensor"),
        "{message}"
    );
}

/// A CRW (CIFF) heap whose directory lists `k` sub-heaps, each the heap itself, after
/// `padding` bytes of value data: rawler's reader follows them 10 levels deep, copying
/// the heap at each of k^10 entries, which takes hours. It starts "II" like a TIFF but
/// has no TIFF directory, so nothing refuses it before the decoder meets it.
fn ciff_bomb(k: u16, padding: usize) -> Vec<u8> {
    let mut heap = vec![0u8; padding];
    let heap_len = (padding + 2 + 10 * usize::from(k) + 4) as u32;
    heap.extend(k.to_le_bytes());
    for _ in 0..k {
        // A sub-heap entry (type 0x2800, data in the value area): its size, at offset 0.
        heap.extend(0x2801u16.to_le_bytes());
        heap.extend(heap_len.to_le_bytes());
        heap.extend(0u32.to_le_bytes());
    }
    heap.extend((padding as u32).to_le_bytes());
    let mut file = b"II".to_vec();
    file.extend(26u32.to_le_bytes());
    file.extend(b"HEAPCCDR");
    file.resize(26, 0);
    file.extend(heap);
    file
}

/// A decoder that would spin for hours is stopped by its time limit (10 s of processor
/// time for captures of a megapixel), with one line naming the file. Ignored by
/// default for its 10 s: `cargo test -p gonio-daemon --test cli -- --ignored hostile::`.
#[test]
#[ignore]
fn a_decoder_that_spins_is_stopped_by_its_time_limit() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("bomb.cr2");
    std::fs::write(&raw, ciff_bomb(4, 4 << 20)).unwrap();
    std::fs::write(
        dir.path().join("bomb.json"),
        r#"{"shutter_s":0.01,"iso":100,"theta_l":-20,"camera":"x","time":"t"}"#,
    )
    .unwrap();
    let out = dir.path().join("bomb.exr");
    let output = gonio(&[
        "hdr".as_ref(),
        "--max-frame-pixels".as_ref(),
        "1000000".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        raw.as_os_str(),
    ]);
    assert_clean_failure(
        &output,
        "bomb.cr2: cannot decode image: the decoder was killed by its processor time limit (10 s)",
    );
    assert!(!out.exists());
}

/// A sidecar's values outside their physical range are refused naming the key (a
/// shutter of 1e-300 s once gave an EXR of +inf, ISO 1e308 an all-zero one, both exit
/// 0); a frame whose θL is not its directory's is refused naming the file.
#[test]
fn sidecars_out_of_physical_range_or_directory_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let image = capture_from_seed(dir.path(), "valid_rgb16_4x3");
    let sidecar = image.with_extension("json");
    let valid: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&sidecar).unwrap()).unwrap();
    let out = dir.path().join("map.exr");
    for (key, value) in [
        ("shutter_s", serde_json::json!(1e-300)),
        ("shutter_s", serde_json::json!(5e-7)),
        ("shutter_s", serde_json::json!(3601.0)),
        ("iso", serde_json::json!(1e308)),
        ("iso", serde_json::json!(12)),
        ("iso", serde_json::json!(409_601)),
        ("white_level", serde_json::json!(1e300)),
        ("black_level", serde_json::json!(-1)),
        ("aperture", serde_json::json!(1e300)),
        ("aperture", serde_json::json!(0.1)),
    ] {
        let mut bad = valid.clone();
        bad[key] = value.clone();
        std::fs::write(&sidecar, bad.to_string()).unwrap();
        let output = hdr(&out, &image);
        let stderr = assert_clean_failure(&output, &format!("sidecar field '{key}'"));
        assert!(
            stderr.contains("valid_rgb16_4x3.json"),
            "{key} {value}: {stderr}"
        );
        assert!(!out.exists(), "{key} {value}: an output was written");
    }
    // The frame in theta_l_-20.0/ says θL −45.
    let theta_dir = dir.path().join("theta_l_-20.0");
    std::fs::create_dir(&theta_dir).unwrap();
    let mut moved = valid.clone();
    moved["theta_l"] = serde_json::json!(-45.0);
    let frame = theta_dir.join("exp_00.tiff");
    std::fs::copy(&image, &frame).unwrap();
    std::fs::write(frame.with_extension("json"), moved.to_string()).unwrap();
    let stderr = assert_clean_failure(&hdr(&out, &frame), "theta_l_-20.0/exp_00.json");
    assert!(
        stderr.contains("'theta_l'") && stderr.contains("-45"),
        "{stderr}"
    );
    moved["theta_l"] = serde_json::json!(-20.04);
    std::fs::write(frame.with_extension("json"), moved.to_string()).unwrap();
    let output = hdr(&out, &frame);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// Runs `gonio ARGS`, which must end within 20 s (a device once kept it reading).
fn gonio_within(args: &[&std::ffi::OsStr]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("gonio runs");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while child.try_wait().unwrap().is_none() {
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            panic!("gonio {args:?} still runs after 20 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

fn mkfifo(path: &Path) {
    let made = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(made.success(), "mkfifo {}", path.display());
}

/// Devices and FIFOs named as input files are refused at once, unread: `/dev/zero` was
/// once read until memory ran out, `/dev/urandom` never answered, a FIFO blocked.
#[test]
fn devices_and_fifos_as_inputs_are_refused_unread() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe");
    mkfifo(&fifo);
    let scan = dir.path().join("scan");
    std::fs::create_dir(&scan).unwrap();
    let out = dir.path().join("out.csv");
    // A capture whose sidecar is the device, and one that is the device.
    let image = capture_from_seed(dir.path(), "valid_rgb16_4x3");
    let sidecar = image.with_extension("json");
    let frame = dir.path().join("frame.tiff");
    std::fs::write(
        frame.with_extension("json"),
        std::fs::read(&sidecar).unwrap(),
    )
    .unwrap();
    for device in [Path::new("/dev/zero"), Path::new("/dev/urandom"), &fifo] {
        let what = if device == fifo {
            "a FIFO"
        } else {
            "a character device"
        };
        let needle = format!("not a regular file ({what})");
        let d = device.as_os_str();
        std::fs::remove_file(&sidecar).unwrap();
        std::os::unix::fs::symlink(device, &sidecar).unwrap();
        let _ = std::fs::remove_file(&frame);
        std::os::unix::fs::symlink(device, &frame).unwrap();
        let runs: [&[&std::ffi::OsStr]; 8] = [
            &[
                "export".as_ref(),
                d,
                "--format".as_ref(),
                "mitsuba".as_ref(),
                "--out".as_ref(),
                out.as_os_str(),
            ],
            &[
                "calibrate".as_ref(),
                scan.as_os_str(),
                "--setup".as_ref(),
                d,
                "--out".as_ref(),
                out.as_os_str(),
            ],
            &[
                "fit".as_ref(),
                d,
                "--model".as_ref(),
                "ward".as_ref(),
                "--out".as_ref(),
                out.as_os_str(),
            ],
            &[
                "extract".as_ref(),
                scan.as_os_str(),
                "--setup".as_ref(),
                d,
                "--out".as_ref(),
                out.as_os_str(),
            ],
            &[
                "simulate".as_ref(),
                "--scene".as_ref(),
                d,
                "--out".as_ref(),
                scan.as_os_str(),
            ],
            &[
                "serve".as_ref(),
                "--config".as_ref(),
                d,
                "--data".as_ref(),
                scan.as_os_str(),
            ],
            &[
                "hdr".as_ref(),
                "--out".as_ref(),
                out.as_os_str(),
                image.as_os_str(),
            ],
            &[
                "hdr".as_ref(),
                "--out".as_ref(),
                out.as_os_str(),
                frame.as_os_str(),
            ],
        ];
        for args in runs {
            let output = gonio_within(args);
            assert_clean_failure(&output, &needle);
            assert!(!out.exists(), "{args:?} wrote an output");
        }
    }
}

/// `--out` naming a device or a FIFO is written in place: `export` and `calibrate` once
/// replaced a device (`/dev/null` as root) with a regular file. As root the device is
/// a node of the test's own with /dev/null's numbers; a FIFO always.
#[test]
fn devices_and_fifos_as_outputs_stay_what_they_are() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    // A fit to export and a scan to calibrate, both small.
    let scan = simulated_scan(dir.path());
    let fit = dir.path().join("fit.json");
    let samples = dir.path().join("samples.csv");
    for args in [
        vec![
            "extract".as_ref(),
            scan.as_os_str(),
            "--out".as_ref(),
            samples.as_os_str(),
        ],
        vec![
            "fit".as_ref(),
            samples.as_os_str(),
            "--model".as_ref(),
            "ward".as_ref(),
            "--out".as_ref(),
            fit.as_os_str(),
        ],
    ] {
        let output = gonio(&args);
        assert!(
            output.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    let null = dir.path().join("null");
    let c_path = std::ffi::CString::new(null.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    let device =
        unsafe { libc::mknod(c_path.as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) } == 0;
    if !device {
        eprintln!("no device node (creating one needs root): the outputs are a FIFO only");
    }
    let fifo = dir.path().join("fifo");
    mkfifo(&fifo);
    let targets = if device {
        vec![null.clone(), fifo.clone()]
    } else {
        vec![fifo.clone()]
    };
    for target in targets {
        let runs: [Vec<&std::ffi::OsStr>; 2] = [
            vec![
                "export".as_ref(),
                fit.as_os_str(),
                "--format".as_ref(),
                "mitsuba".as_ref(),
                "--out".as_ref(),
                target.as_os_str(),
            ],
            vec![
                "calibrate".as_ref(),
                scan.as_os_str(),
                "--out".as_ref(),
                target.as_os_str(),
            ],
        ];
        for args in runs {
            // The FIFO's reading end, open (non-blocking) before the writer comes.
            let reader = (target == fifo).then(|| {
                use std::os::unix::fs::OpenOptionsExt;
                std::fs::OpenOptions::new()
                    .read(true)
                    .custom_flags(libc::O_NONBLOCK)
                    .open(&fifo)
                    .unwrap()
            });
            let output = gonio_within(&args);
            assert!(
                output.status.success(),
                "{args:?}: {}",
                String::from_utf8_lossy(&output.stderr)
            );
            if let Some(mut reader) = reader {
                let mut got = Vec::new();
                let _ = std::io::Read::read_to_end(&mut reader, &mut got);
                assert!(!got.is_empty(), "{args:?}: nothing came through the FIFO");
            }
            let kind = std::fs::symlink_metadata(&target).unwrap().file_type();
            assert!(
                kind.is_char_device() || kind.is_fifo(),
                "{args:?} replaced {}",
                target.display()
            );
        }
    }
    assert_eq!(partials(dir.path()), Vec::<String>::new());
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
    assert_eq!(partials(dir.path()), Vec::<String>::new());
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
    let scan = simulated_scan(dir.path());
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

/// A θL folder of a scan that is a symbolic link (to `/etc`, to another scan) is
/// refused by extract and calibrate with one line naming it, as the daemon's files
/// route refuses links; neither follows it.
#[test]
fn extract_and_calibrate_refuse_a_symlinked_theta_l_folder() {
    let dir = tempfile::tempdir().unwrap();
    let scan = simulated_scan(dir.path());
    let folder = std::fs::read_dir(&scan)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .find(|name| name.starts_with("theta_l_"))
        .expect("a θL folder");
    // The captures stay where the link points: following it would find them.
    let elsewhere = dir.path().join("elsewhere");
    std::fs::rename(scan.join(&folder), &elsewhere).unwrap();
    std::os::unix::fs::symlink(&elsewhere, scan.join(&folder)).unwrap();
    let out = dir.path().join("out");
    for command in ["extract", "calibrate"] {
        let output = gonio(&[
            command.as_ref(),
            scan.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        let stderr = assert_clean_failure(&output, "symbolic link");
        assert!(stderr.contains(&folder), "{command}: {stderr}");
        assert!(!out.exists(), "{command}");
    }
}
