//! The supervisor against scripted workers, and the worker loop against a fake camera.

use super::*;

/// A worker script for `sh`: announces a camera, answers identify and capture; the
/// first capture ever (marked by a file in `$STATE`) hangs.
const HANGING_ONCE: &str = r#"
echo '{"ready":{"model":"Scripted","port":"usb:001,002"}}'
while read -r line; do
  case "$line" in
    *identify*) echo '{"info":{"model":"Scripted","port":"usb:001,002"}}' ;;
    *set_exposure*) echo '{"exposure":{"shutter_s":0.01,"iso":null}}' ;;
    *capture_to*)
      if [ ! -e "$STATE/hung" ]; then touch "$STATE/hung"; exec sleep 60; fi
      echo '{"capture":{"path":"/tmp/x.jpg","exposure":{"shutter_s":0.01,"iso":null}}}' ;;
    *) echo '{"error":{"kind":"busy"}}' ;;
  esac
done
"#;

fn spec(script: &str, state: &Path) -> WorkerSpec {
    WorkerSpec {
        program: "sh".into(),
        args: vec!["-c".into(), script.into()],
        env: vec![("STATE".into(), state.display().to_string())],
    }
}

fn quick() -> SupervisorConfig {
    SupervisorConfig {
        start_timeout: Duration::from_secs(5),
        call_timeout: Duration::from_secs(5),
        capture_timeout: Duration::from_millis(300),
    }
}

#[test]
fn hung_capture_times_out_and_the_next_one_works() {
    let state = tempfile::tempdir().unwrap();
    let mut camera = SupervisedCamera::start(spec(HANGING_ONCE, state.path()), quick()).unwrap();
    assert_eq!(camera.identify().unwrap().model, "Scripted");
    camera
        .set_exposure(Exposure {
            shutter_s: 0.01,
            iso: None,
        })
        .unwrap();
    let started = std::time::Instant::now();
    assert!(matches!(
        camera.capture_to(Path::new("/tmp/x")),
        Err(DeviceError::Timeout { .. })
    ));
    assert!(started.elapsed() < Duration::from_secs(5));
    assert_eq!(camera.restarts(), 0);
    let capture = camera.capture_to(Path::new("/tmp/x")).unwrap();
    assert_eq!(capture.path, Path::new("/tmp/x.jpg"));
    assert_eq!(camera.restarts(), 1);
}

/// A worker script whose camera is unplugged while `$STATE/unplugged` exists: it is
/// not found at start then, and a running worker that has seen it gone keeps failing
/// with I/O errors (as a libgphoto2 session does after the cable is pulled).
const UNPLUGGABLE: &str = r#"
if [ -e "$STATE/unplugged" ]; then
  echo '{"error":{"kind":"not_found","message":"no camera detected"}}'; exit 0
fi
echo '{"ready":{"model":"Scripted","port":"usb:001,002"}}'
lost=""
while read -r line; do
  if [ -e "$STATE/unplugged" ]; then lost=1; fi
  if [ -n "$lost" ]; then echo '{"error":{"kind":"io","message":"USB transfer failed"}}'; continue; fi
  case "$line" in
    *identify*) echo '{"info":{"model":"Scripted","port":"usb:001,002"}}' ;;
    *set_exposure*) echo '{"exposure":{"shutter_s":0.01,"iso":null}}' ;;
    *capture_to*) echo '{"capture":{"path":"/tmp/x.jpg","exposure":{"shutter_s":0.01,"iso":null}}}' ;;
  esac
done
"#;

#[test]
fn an_unplugged_camera_restarts_the_worker_and_comes_back() {
    let state = tempfile::tempdir().unwrap();
    let unplugged = state.path().join("unplugged");
    // Started lazily: the first call starts the worker.
    let mut camera = SupervisedCamera::new(spec(UNPLUGGABLE, state.path()), quick());
    assert_eq!(camera.identify().unwrap().model, "Scripted");
    assert_eq!(camera.restarts(), 0);
    std::fs::write(&unplugged, b"").unwrap();
    assert!(matches!(
        camera.capture_to(Path::new("/tmp/x")),
        Err(DeviceError::Io(_))
    ));
    // The worker was dropped: the next one looks for the camera and does not find it.
    let Err(DeviceError::NotFound(message)) = camera.identify() else {
        panic!("a missing camera must be reported as not found")
    };
    assert_eq!(message, "no camera detected");
    std::fs::remove_file(&unplugged).unwrap();
    assert_eq!(camera.identify().unwrap().model, "Scripted");
    assert_eq!(camera.restarts(), 1);
    assert!(camera.capture_to(Path::new("/tmp/x")).is_ok());
}

#[test]
fn worker_errors_come_back_typed() {
    let state = tempfile::tempdir().unwrap();
    let mut camera = SupervisedCamera::start(spec(HANGING_ONCE, state.path()), quick()).unwrap();
    assert!(matches!(camera.shutter_speeds(), Err(DeviceError::Busy)));
}

#[test]
fn start_failures_are_reported() {
    let state = tempfile::tempdir().unwrap();
    let no_camera = r#"echo '{"error":{"kind":"not_found","message":"no camera detected"}}'"#;
    let Err(DeviceError::NotFound(message)) =
        SupervisedCamera::start(spec(no_camera, state.path()), quick())
    else {
        panic!("missing camera not reported")
    };
    assert_eq!(message, "no camera detected");
    let dies = "exit 3";
    assert!(matches!(
        SupervisedCamera::start(spec(dies, state.path()), quick()),
        Err(DeviceError::Disconnected(_))
    ));
    let garbage = "echo hello; sleep 5";
    assert!(matches!(
        SupervisedCamera::start(spec(garbage, state.path()), quick()),
        Err(DeviceError::Protocol(_))
    ));
    let missing = WorkerSpec {
        program: state.path().join("no-such-worker"),
        args: vec![],
        env: vec![],
    };
    assert!(matches!(
        SupervisedCamera::start(missing, quick()),
        Err(DeviceError::NotFound(_))
    ));
}

/// An in-memory camera for the worker loop.
struct Fake {
    shutter_s: f64,
}

impl Camera for Fake {
    fn identify(&mut self) -> Result<CameraInfo, DeviceError> {
        Ok(CameraInfo {
            model: "Fake".into(),
            port: "usb:".into(),
        })
    }
    fn shutter_speeds(&mut self) -> Result<Vec<f64>, DeviceError> {
        Ok(vec![0.01, 0.1])
    }
    fn set_exposure(&mut self, exposure: Exposure) -> Result<Exposure, DeviceError> {
        self.shutter_s = exposure.shutter_s;
        Ok(exposure)
    }
    fn capture_to(&mut self, _path: &Path) -> Result<Capture, DeviceError> {
        Err(DeviceError::Timeout {
            what: "capture".into(),
            seconds: 1.5,
        })
    }
}

#[test]
fn worker_loop_answers_each_request() {
    let input = [
        r#"{"op":"identify"}"#,
        r#"{"op":"set_exposure","exposure":{"shutter_s":0.1,"iso":200}}"#,
        "not json",
        r#"{"op":"capture_to","path":"/x/y"}"#,
        r#"{"op":"shutter_speeds"}"#,
    ]
    .join("\n");
    let mut output = Vec::new();
    serve_worker(
        || Ok(Fake { shutter_s: 0.0 }),
        input.as_bytes(),
        &mut output,
    )
    .unwrap();
    let replies: Vec<WorkerReply> = String::from_utf8(output)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let info = CameraInfo {
        model: "Fake".into(),
        port: "usb:".into(),
    };
    assert_eq!(replies.len(), 6);
    assert_eq!(replies[0], WorkerReply::Ready(info.clone()));
    assert_eq!(replies[1], WorkerReply::Info(info));
    assert_eq!(
        replies[2],
        WorkerReply::Exposure(Exposure {
            shutter_s: 0.1,
            iso: Some(200)
        })
    );
    assert!(matches!(
        &replies[3],
        WorkerReply::Error(WireError::Protocol { .. })
    ));
    assert_eq!(
        replies[4],
        WorkerReply::Error(WireError::Timeout {
            what: "capture".into(),
            seconds: 1.5
        })
    );
    assert_eq!(replies[5], WorkerReply::ShutterSpeeds(vec![0.01, 0.1]));
}

#[test]
fn worker_that_cannot_open_says_why() {
    let mut output = Vec::new();
    serve_worker::<Fake>(
        || Err(DeviceError::NotFound("no camera".into())),
        &b""[..],
        &mut output,
    )
    .unwrap();
    let reply: WorkerReply = serde_json::from_slice(output.trim_ascii()).unwrap();
    assert_eq!(
        reply,
        WorkerReply::Error(WireError::NotFound {
            message: "no camera".into()
        })
    );
}

#[test]
fn errors_survive_the_wire() {
    let errors = [
        DeviceError::Busy,
        DeviceError::Reset,
        DeviceError::Rejected {
            code: 2,
            meaning: "bad".into(),
        },
        DeviceError::OutOfRange {
            what: "shutter".into(),
            value: 99.0,
            min: 0.001,
            max: 30.0,
        },
        DeviceError::Io(io::Error::other("usb")),
    ];
    for error in errors {
        let wire = WireError::from(&error);
        let back: WireError = serde_json::from_str(&serde_json::to_string(&wire).unwrap()).unwrap();
        assert_eq!(DeviceError::from(back).to_string(), error.to_string());
    }
}
