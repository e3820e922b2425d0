//! The emulated camera behind the drivers' Camera trait: settings, captures with the
//! light at the world's arm angle, timing and every injected fault.

use std::time::{Duration, Instant};

use gonio_drivers::{Camera, DeviceError, Exposure};
use gonio_mock_hw::camera::{CameraFault, CaptureTiming, EmulatedCamera, SHUTTER_SPEEDS_S};
use gonio_mock_hw::render::render_frame;
use gonio_mock_hw::scene::Scene;
use gonio_mock_hw::world::World;

const SMALL: &str = include_str!("../scene_small.toml");
const CT: &str =
    "[sample]\nmodel = \"cook-torrance\"\nkd = [10.0, 8.0, 3.0]\nks = [2.0, 1.5, 0.5]\nm = [0.1]\n";

/// Fast timing: 1/100 of real time, 0.5 s download, 2 s deadline.
const TIMING: CaptureTiming = CaptureTiming {
    time_scale: 0.01,
    download_latency_s: 0.5,
    deadline_s: 2.0,
};

fn camera(world: &World) -> EmulatedCamera {
    let scene = Scene::from_toml_str(&format!("{SMALL}\n{CT}")).unwrap();
    EmulatedCamera::new(scene, world.clone(), TIMING)
}

fn read_tiff(path: &std::path::Path) -> (u32, u32, Vec<u16>) {
    let mut decoder = tiff::decoder::Decoder::new(std::fs::File::open(path).unwrap()).unwrap();
    let (w, h) = decoder.dimensions().unwrap();
    assert_eq!(decoder.colortype().unwrap(), tiff::ColorType::RGB(16));
    match decoder.read_image().unwrap() {
        tiff::decoder::DecodingResult::U16(data) => (w, h, data),
        _ => panic!("not 16-bit"),
    }
}

fn entries(dir: &std::path::Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn settings_snap_like_a_nikon() {
    let mut cam = camera(&World::new(-20.0));
    let info = cam.identify().unwrap();
    assert_eq!(info.model, "Test body");
    let speeds = cam.shutter_speeds().unwrap();
    assert!(speeds.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(speeds.first(), Some(&(1.0 / 8000.0)));
    assert_eq!(speeds.last(), Some(&30.0));
    assert!(speeds.contains(&0.01) && speeds.contains(&0.5));

    let got = cam
        .set_exposure(Exposure {
            shutter_s: 0.011,
            iso: Some(150),
        })
        .unwrap();
    assert_eq!(
        got,
        Exposure {
            shutter_s: 0.01,
            iso: Some(200)
        }
    );
    let got = cam
        .set_exposure(Exposure {
            shutter_s: 100.0,
            iso: None,
        })
        .unwrap();
    assert_eq!(
        got,
        Exposure {
            shutter_s: 30.0,
            iso: Some(200)
        }
    );
    let got = cam
        .set_exposure(Exposure {
            shutter_s: 0.26,
            iso: Some(100),
        })
        .unwrap();
    assert_eq!(got.shutter_s, 0.25);
    assert!(matches!(
        cam.set_exposure(Exposure {
            shutter_s: -1.0,
            iso: None
        }),
        Err(DeviceError::OutOfRange { .. })
    ));
    assert!(matches!(
        cam.set_exposure(Exposure {
            shutter_s: f64::NAN,
            iso: None
        }),
        Err(DeviceError::OutOfRange { .. })
    ));
    assert_eq!(SHUTTER_SPEEDS_S.len(), speeds.len());
    let levels = cam.file_levels();
    assert_eq!(
        (levels.black_level, levels.white_level, levels.nonlinear),
        (0, 65535, false)
    );
}

#[test]
fn capture_renders_at_the_arm_angle_and_takes_its_time() {
    let dir = tempfile::tempdir().unwrap();
    let world = World::new(-25.0);
    let mut cam = camera(&world);
    let exposure = cam
        .set_exposure(Exposure {
            shutter_s: 1.0 / 60.0,
            iso: Some(100),
        })
        .unwrap();
    let started = Instant::now();
    let capture = cam.capture_to(&dir.path().join("a.nef")).unwrap();
    let took = started.elapsed().as_secs_f64();
    assert!(
        took >= TIMING.capture_duration_s(exposure.shutter_s),
        "{took}"
    );
    assert_eq!(capture.path, dir.path().join("a.tiff"));
    assert_eq!(capture.exposure, exposure);
    let (w, h, data) = read_tiff(&capture.path);
    assert_eq!((w, h), (400, 120));
    let expected = render_frame(&cam.scene(), -25.0, exposure.shutter_s);
    assert_eq!(data, expected.stored());

    world.set_arm_deg(-40.0);
    let moved = cam.capture_to(&dir.path().join("b.tiff")).unwrap();
    let (_, _, data) = read_tiff(&moved.path);
    assert_eq!(
        data,
        render_frame(&cam.scene(), -40.0, exposure.shutter_s).stored()
    );
    assert_ne!(data, expected.stored());
    assert_eq!(
        entries(dir.path()),
        ["a.tiff", "b.tiff"],
        "no temporary files left"
    );
}

#[test]
fn busy_fails_the_next_captures_then_recovers() {
    let dir = tempfile::tempdir().unwrap();
    let mut cam = camera(&World::new(-30.0));
    cam.inject(CameraFault::Busy { captures: 2 });
    let injector = cam.fault_injector();
    assert_eq!(injector.pending(), 1);
    for _ in 0..2 {
        let err = cam.capture_to(&dir.path().join("x.tiff")).unwrap_err();
        assert!(matches!(err, DeviceError::Busy), "{err}");
        assert!(err.is_transient());
    }
    assert_eq!(injector.pending(), 0);
    assert!(cam.capture_to(&dir.path().join("x.tiff")).is_ok());
}

#[test]
fn unplugged_camera_fails_every_call_until_replugged() {
    let dir = tempfile::tempdir().unwrap();
    let mut cam = camera(&World::new(-30.0));
    let cable = cam.fault_injector();
    cable.unplug();
    let err = cam.identify().unwrap_err();
    assert!(matches!(err, DeviceError::Disconnected(_)), "{err}");
    assert!(cam.shutter_speeds().is_err());
    assert!(cam.capture_to(&dir.path().join("x.tiff")).is_err());
    assert!(entries(dir.path()).is_empty());
    cable.replug();
    assert!(cam.identify().is_ok());
    assert!(cam.capture_to(&dir.path().join("x.tiff")).is_ok());
    // Pulled while the frame downloads (0.3 s here): the frame is lost.
    let scene = Scene::from_toml_str(&format!("{SMALL}\n{CT}")).unwrap();
    let slow = CaptureTiming {
        time_scale: 1.0,
        download_latency_s: 0.3,
        deadline_s: 2.0,
    };
    let mut cam = EmulatedCamera::new(scene, World::new(-30.0), slow);
    let puller = cam.fault_injector();
    let pull = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(100));
        puller.unplug();
    });
    let err = cam.capture_to(&dir.path().join("y.tiff")).unwrap_err();
    pull.join().unwrap();
    assert!(matches!(err, DeviceError::Disconnected(_)), "{err}");
    assert_eq!(entries(dir.path()), ["x.tiff"]);
}

#[test]
fn io_error_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let mut cam = camera(&World::new(-30.0));
    cam.fault_injector().inject(CameraFault::Io);
    let err = cam.capture_to(&dir.path().join("x.tiff")).unwrap_err();
    assert!(matches!(err, DeviceError::Io(_)), "{err}");
    assert!(entries(dir.path()).is_empty());
    assert!(cam.capture_to(&dir.path().join("x.tiff")).is_ok());
}

#[test]
fn timeout_and_missing_file_fail_after_the_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let mut cam = camera(&World::new(-30.0));
    let shutter = cam
        .set_exposure(Exposure {
            shutter_s: 0.5,
            iso: None,
        })
        .unwrap()
        .shutter_s;
    let deadline = Duration::from_secs_f64(TIMING.deadline_wall_s(shutter));
    for (fault, what) in [
        (CameraFault::Timeout, "capture"),
        (CameraFault::FileNeverArrives, "file"),
    ] {
        cam.inject(fault);
        let started = Instant::now();
        let err = cam.capture_to(&dir.path().join("x.tiff")).unwrap_err();
        let took = started.elapsed();
        match &err {
            DeviceError::Timeout { what: w, seconds } => {
                assert!(w.contains(what), "{err}");
                assert!(*seconds >= deadline.as_secs_f64());
            }
            other => panic!("{other}"),
        }
        assert!(
            took >= deadline && took < deadline + Duration::from_secs(2),
            "{took:?}"
        );
        assert!(entries(dir.path()).is_empty());
    }
    assert!(cam.capture_to(&dir.path().join("x.tiff")).is_ok());
}

#[test]
fn a_capture_renders_the_sample_mounted_when_it_starts() {
    let dir = tempfile::tempdir().unwrap();
    let world = World::new(-30.0);
    let mut cam = camera(&world);
    let exposure = cam
        .set_exposure(Exposure {
            shutter_s: 1.0 / 60.0,
            iso: Some(100),
        })
        .unwrap();
    let mount = cam.sample_mount();
    let first = cam.capture_to(&dir.path().join("first.tiff")).unwrap();
    let (_, _, mounted_first) = read_tiff(&first.path);
    let other = Scene::from_toml_str(&format!(
        "{SMALL}\n[sample]\nmodel = \"cook-torrance\"\nkd = [2.0, 3.0, 12.0]\nks = [0.5, 1.0, 4.0]\nm = [0.3]\n"
    ))
    .unwrap();
    mount.mount(other.clone());
    let second = cam.capture_to(&dir.path().join("second.tiff")).unwrap();
    let (_, _, mounted_second) = read_tiff(&second.path);
    assert_eq!(
        mounted_second,
        render_frame(&other, -30.0, exposure.shutter_s).stored()
    );
    assert_ne!(mounted_first, mounted_second);
    assert_eq!(cam.scene().truth_json(), other.truth_json());
}
