//! The gphoto2 driver against libgphoto2's virtual camera (the `vusb` port driver of
//! libgphoto2 ≥ 2.5.31, a virtual "Nikon DSC D750"; `scripts/test.sh` sets it up).
//! The virtual camera's capture returns the first `*.jpg` in `VCAMERADIR`.
//! Skipped, with a message, when `VCAMERADIR` is unset.
#![cfg(feature = "gphoto2")]

use std::fs;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gonio_drivers::gphoto2_camera::{GphotoCamera, GphotoConfig};
use gonio_drivers::supervised_camera::{SupervisedCamera, SupervisorConfig, WorkerSpec};
use gonio_drivers::{Camera, DeviceError, Exposure};

/// The folder the virtual camera serves, or `None` (with a note) to skip.
fn vcamera_dir() -> Option<PathBuf> {
    match std::env::var_os("VCAMERADIR") {
        Some(dir) => Some(PathBuf::from(dir)),
        None => {
            eprintln!("VCAMERADIR is unset: skipping the virtual-camera test (scripts/test.sh sets it up)");
            None
        }
    }
}

fn only_jpeg(dir: &Path) -> Vec<u8> {
    let jpegs: Vec<PathBuf> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("jpg")))
        .collect();
    assert_eq!(
        jpegs.len(),
        1,
        "VCAMERADIR must hold exactly one .jpg: {jpegs:?}"
    );
    fs::read(&jpegs[0]).unwrap()
}

#[test]
fn detects_sets_shutter_and_captures_atomically() {
    let Some(dir) = vcamera_dir() else { return };
    let jpeg = only_jpeg(&dir);
    let mut camera = GphotoCamera::open(GphotoConfig::default()).unwrap();
    let info = camera.identify().unwrap();
    assert_eq!(info.model, "Nikon DSC D750");
    assert!(info.port.starts_with("usb:"), "{info:?}");

    let speeds = camera.shutter_speeds().unwrap();
    assert!(speeds.windows(2).all(|w| w[0] < w[1]), "{speeds:?}");
    assert_eq!(speeds.first().copied(), Some(0.0001));
    assert_eq!(speeds.last().copied(), Some(1.0));
    for &wanted in &speeds {
        let set = camera
            .set_exposure(Exposure {
                shutter_s: wanted,
                iso: Some(100),
            })
            .unwrap();
        assert_eq!(set.shutter_s, wanted);
        // The virtual body has no ISO setting.
        assert_eq!(set.iso, None);
    }
    // Between choices: the nearest in stops is read back.
    let set = camera
        .set_exposure(Exposure {
            shutter_s: 0.03,
            iso: None,
        })
        .unwrap();
    assert_eq!(set.shutter_s, 0.02);
    assert!(matches!(
        camera.set_exposure(Exposure {
            shutter_s: -1.0,
            iso: None
        }),
        Err(DeviceError::OutOfRange { .. })
    ));

    let out = tempfile::tempdir().unwrap();
    let capture = camera.capture_to(&out.path().join("exp_00.tiff")).unwrap();
    assert_eq!(capture.path, out.path().join("exp_00.jpg"));
    assert_eq!(capture.exposure.shutter_s, 0.02);
    assert_eq!(fs::read(&capture.path).unwrap(), jpeg);
    let names: Vec<_> = fs::read_dir(out.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["exp_00.jpg"], "temporary files left behind");
}

#[test]
fn missing_camera_is_a_clear_error() {
    if vcamera_dir().is_none() {
        return;
    }
    let config = GphotoConfig {
        model: Some("Nikon DSC D850".into()),
        ..GphotoConfig::default()
    };
    let Err(DeviceError::NotFound(message)) = GphotoCamera::open(config) else {
        panic!("a camera that is not there was opened")
    };
    assert!(
        message.contains("D850") && message.contains("Nikon DSC D750"),
        "{message}"
    );
}

/// A hung capture inside libgphoto2 (the virtual camera blocks reading a FIFO named
/// `*.jpg`) is killed by the watchdog; the next capture works in a fresh worker.
#[test]
fn watchdog_recovers_from_a_hung_capture() {
    let Some(dir) = vcamera_dir() else { return };
    let jpeg = only_jpeg(&dir);
    let served = tempfile::tempdir().unwrap();
    let fifo = served.path().join("frame.jpg");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let spec = WorkerSpec {
        program: env!("CARGO_BIN_EXE_gonio-camera-worker").into(),
        args: vec!["--model".into(), "Nikon DSC D750".into()],
        env: vec![("VCAMERADIR".into(), served.path().display().to_string())],
    };
    let config = SupervisorConfig {
        capture_timeout: Duration::from_secs(3),
        ..SupervisorConfig::default()
    };
    let mut camera = SupervisedCamera::start(spec, config).unwrap();
    assert_eq!(camera.identify().unwrap().model, "Nikon DSC D750");
    let set = camera
        .set_exposure(Exposure {
            shutter_s: 0.1,
            iso: None,
        })
        .unwrap();
    assert_eq!(set.shutter_s, 0.1);

    let out = tempfile::tempdir().unwrap();
    let started = Instant::now();
    let hung = camera.capture_to(&out.path().join("exp_00"));
    assert!(matches!(hung, Err(DeviceError::Timeout { .. })), "{hung:?}");
    assert!(started.elapsed() < Duration::from_secs(10));
    assert_eq!(fs::read_dir(out.path()).unwrap().count(), 0);

    fs::remove_file(&fifo).unwrap();
    fs::write(served.path().join("frame.jpg"), &jpeg).unwrap();
    let capture = camera.capture_to(&out.path().join("exp_00")).unwrap();
    assert_eq!(camera.restarts(), 1);
    assert_eq!(
        capture.exposure.shutter_s, 0.1,
        "exposure not re-applied after restart"
    );
    assert_eq!(fs::read(&capture.path).unwrap(), jpeg);
}
