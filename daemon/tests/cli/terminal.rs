//! How the offline commands behave towards a person: progress bars on a terminal and
//! none in a pipe, and a word (plus cleaning up) when interrupted.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const GONIO: &str = env!("CARGO_BIN_EXE_gonio");

/// The tiny fixture scene (400×120 pixels, two θL × two exposures).
fn tiny_scene(dir: &Path) -> String {
    let path = dir.join("tiny.toml");
    let sample = "[sample]\nmodel = \"cook-torrance\"\nkd = [9.0, 6.5, 2.0]\nks = [25.0, 20.0, 7.0]\nm = [0.07]\n";
    std::fs::write(
        &path,
        include_str!("../fixtures/tiny_scene.toml").to_owned() + sample,
    )
    .unwrap();
    path.to_str().unwrap().to_owned()
}

#[test]
fn no_progress_output_when_stderr_is_not_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("scan");
    let output = Command::new(GONIO)
        .args(["simulate", "--scene", &scene, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(output.status.success());
    assert!(
        output.stderr.is_empty(),
        "stderr: {:?}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8(output.stdout).unwrap();
    assert!(
        !stdout.contains('\u{1b}') && !stdout.contains('\r'),
        "{stdout:?}"
    );
    assert!(stdout.contains("4 captures"), "{stdout}");
}

#[test]
fn progress_bar_on_a_terminal() {
    // `script` (util-linux, in every Debian) runs the command on a pseudo-terminal.
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("scan");
    let command = format!(
        "{GONIO} simulate --scene {scene} --out {} 2>&1",
        out.display()
    );
    let output = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .stdin(Stdio::null())
        .output()
        .expect("`script` (util-linux) is installed");
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{text}");
    // The bar is drawn (then cleared) with its unit and count.
    assert!(text.contains("/4 captures"), "{text:?}");
}

fn wait_for(what: &str, deadline: Duration, mut ready: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ready() {
        assert!(start.elapsed() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn sigint_says_what_stopped_and_removes_temporary_directories() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tradeoff");
    // A full-size scene: rendering its scan takes seconds, time to interrupt it.
    let child = Command::new(GONIO)
        .args(["tradeoff", "--scene", "gold", "--out"])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let scan_dir_exists = || {
        std::fs::read_dir(&out).is_ok_and(|entries| {
            entries
                .flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with(".scan-"))
        })
    };
    wait_for(
        "the rendered scan",
        Duration::from_secs(60),
        scan_dir_exists,
    );
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(
        stderr.contains("gonio tradeoff: interrupted by Ctrl-C (SIGINT)"),
        "{stderr}"
    );
    assert!(!scan_dir_exists(), "the temporary scan is left behind");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(!stdout.contains(".scan-") && !stderr.contains(".scan-"));
}
