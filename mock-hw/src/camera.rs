//! A camera emulator behind the drivers' [`Camera`] trait: renders the scene of the
//! sample mounted on the cylinder with the light where the shared world's arm is, takes
//! as long as a real body (exposure plus download, scalable), and fails on demand the
//! ways a tethered DSLR fails.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use gonio_drivers::{Camera, CameraInfo, Capture, DeviceError, Exposure};
use gonio_files::output::write_atomically;

use crate::render::{self, FileLevels, Shot};
use crate::scene::Scene;
use crate::world::World;

/// Nikon shutter speeds in ⅓-stop steps, 1/8000 s to 30 s, seconds, ascending.
pub const SHUTTER_SPEEDS_S: [f64; 55] = [
    1.0 / 8000.0,
    1.0 / 6400.0,
    1.0 / 5000.0,
    1.0 / 4000.0,
    1.0 / 3200.0,
    1.0 / 2500.0,
    1.0 / 2000.0,
    1.0 / 1600.0,
    1.0 / 1250.0,
    1.0 / 1000.0,
    1.0 / 800.0,
    1.0 / 640.0,
    1.0 / 500.0,
    1.0 / 400.0,
    1.0 / 320.0,
    1.0 / 250.0,
    1.0 / 200.0,
    1.0 / 160.0,
    1.0 / 125.0,
    1.0 / 100.0,
    1.0 / 80.0,
    1.0 / 60.0,
    1.0 / 50.0,
    1.0 / 40.0,
    1.0 / 30.0,
    1.0 / 25.0,
    1.0 / 20.0,
    1.0 / 15.0,
    1.0 / 13.0,
    1.0 / 10.0,
    1.0 / 8.0,
    1.0 / 6.0,
    1.0 / 5.0,
    1.0 / 4.0,
    1.0 / 3.0,
    1.0 / 2.5,
    1.0 / 2.0,
    1.0 / 1.6,
    1.0 / 1.3,
    1.0,
    1.3,
    1.6,
    2.0,
    2.5,
    3.0,
    4.0,
    5.0,
    6.0,
    8.0,
    10.0,
    13.0,
    15.0,
    20.0,
    25.0,
    30.0,
];

/// ISO settings of the emulated body.
pub const ISO_VALUES: [u32; 5] = [100, 200, 400, 800, 1600];

/// How long captures take. Durations are real-time seconds, multiplied by `time_scale`
/// when the emulator waits (1.0 real time, 0.01 a hundred times faster).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureTiming {
    pub time_scale: f64,
    /// Time from the shutter closing until the file is on the host.
    pub download_latency_s: f64,
    /// How long past the exposure the driver waits for a capture before giving up.
    pub deadline_s: f64,
}

impl Default for CaptureTiming {
    fn default() -> Self {
        Self {
            time_scale: 1.0,
            download_latency_s: 1.5,
            deadline_s: 20.0,
        }
    }
}

impl CaptureTiming {
    /// Wall-clock seconds a successful capture at `shutter_s` takes.
    pub fn capture_duration_s(&self, shutter_s: f64) -> f64 {
        (shutter_s + self.download_latency_s) * self.time_scale
    }

    /// Wall-clock seconds before a capture that never completes is given up.
    pub fn deadline_wall_s(&self, shutter_s: f64) -> f64 {
        (shutter_s + self.deadline_s) * self.time_scale
    }
}

/// A fault the next capture(s) meet, in injection order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraFault {
    /// The next `captures` captures fail at once with [`DeviceError::Busy`].
    Busy { captures: u32 },
    /// The next capture fails with an I/O error (USB transfer); no file is written.
    Io,
    /// The next capture never completes: [`DeviceError::Timeout`] after the deadline.
    Timeout,
    /// The next capture exposes, but its file never reaches the host:
    /// [`DeviceError::Timeout`] after the deadline, no file written.
    FileNeverArrives,
    /// The next capture aborts the process that drives the camera, as a camera
    /// library with a memory fault would.
    Abort,
}

/// Injects faults into a camera from any thread (cheap to clone).
#[derive(Debug, Clone, Default)]
pub struct FaultInjector {
    queue: Arc<Mutex<VecDeque<CameraFault>>>,
    unplugged: Arc<AtomicBool>,
}

impl FaultInjector {
    /// Pulls the camera's USB cable: every call fails with
    /// [`DeviceError::Disconnected`] until [`FaultInjector::replug`], and a capture
    /// under way loses its file.
    pub fn unplug(&self) {
        self.unplugged.store(true, Ordering::Release);
    }

    /// Plugs the cable back in.
    pub fn replug(&self) {
        self.unplugged.store(false, Ordering::Release);
    }

    /// Fails while the cable is out.
    fn check_plugged(&self) -> Result<(), DeviceError> {
        if self.unplugged.load(Ordering::Acquire) {
            return Err(DeviceError::Disconnected("camera unplugged".into()));
        }
        Ok(())
    }

    pub fn inject(&self, fault: CameraFault) {
        self.queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push_back(fault);
    }

    /// Faults not yet consumed.
    pub fn pending(&self) -> usize {
        self.queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .len()
    }

    /// The fault the next capture meets, if any.
    fn take(&self) -> Option<CameraFault> {
        let mut queue = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
        match queue.front_mut() {
            Some(CameraFault::Busy { captures }) if *captures > 1 => {
                *captures -= 1;
                Some(CameraFault::Busy { captures: 1 })
            }
            Some(CameraFault::Busy { captures: 0 }) => {
                queue.pop_front();
                drop(queue);
                self.take()
            }
            _ => queue.pop_front(),
        }
    }
}

/// The sample on the emulated cylinder, as the scene the camera renders: state of the
/// emulated instrument, changed from any thread (an operator swapping the cylinder).
/// With a [`Carousel`], the sample before the camera is the one whose slot the
/// carousel's axis is at, none between slots. A capture renders the scene before the
/// camera when it starts. Cheap to clone.
#[derive(Debug, Clone)]
pub struct SampleMount {
    scene: Arc<Mutex<Arc<Scene>>>,
    carousel: Option<Arc<Carousel>>,
}

/// A sample carousel on an axis of the emulated board: each slot is a physical position
/// of the axis (its units, 0 at its homing switch: the machine position once homed)
/// that brings a sample before the camera.
#[derive(Debug)]
pub struct Carousel {
    axis: usize,
    slots: Vec<(f64, Arc<Scene>)>,
    /// What the camera sees between slots.
    empty: Arc<Scene>,
    world: World,
}

/// How far (the axis' units) the carousel may sit from a slot and still hold its
/// sample before the camera.
pub const SLOT_TOLERANCE: f64 = 0.05;

impl Carousel {
    /// A carousel on axis `axis` (0 = X) of the board that moves `world`, holding each
    /// scene of `slots` at its position; `empty` is seen between slots.
    pub fn new(axis: usize, slots: Vec<(f64, Scene)>, empty: Scene, world: World) -> Self {
        Self {
            axis,
            slots: slots.into_iter().map(|(p, s)| (p, Arc::new(s))).collect(),
            empty: Arc::new(empty),
            world,
        }
    }

    /// The scene before the camera now.
    fn scene(&self) -> Arc<Scene> {
        let at = self.world.axis(self.axis);
        self.slots
            .iter()
            .find(|(slot, _)| (slot - at).abs() <= SLOT_TOLERANCE)
            .map_or_else(|| self.empty.clone(), |(_, scene)| scene.clone())
    }
}

impl SampleMount {
    fn new(scene: Scene) -> Self {
        Self {
            scene: Arc::new(Mutex::new(Arc::new(scene))),
            carousel: None,
        }
    }

    /// Mounts the sample `scene` shows, in place of the one mounted (with a carousel,
    /// the carousel's position decides instead).
    pub fn mount(&self, scene: Scene) {
        *self.scene.lock().unwrap_or_else(PoisonError::into_inner) = Arc::new(scene);
    }

    /// Whether a carousel decides which sample is before the camera.
    pub fn has_carousel(&self) -> bool {
        self.carousel.is_some()
    }

    /// The scene of the sample before the camera now.
    pub fn scene(&self) -> Arc<Scene> {
        if let Some(carousel) = &self.carousel {
            return carousel.scene();
        }
        self.scene
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }
}

/// The emulated camera. Captures render the mounted sample's scene with the light at
/// the world's arm angle and are stored as 16-bit RGB TIFF (extension `tiff`).
pub struct EmulatedCamera {
    mount: SampleMount,
    world: World,
    timing: CaptureTiming,
    faults: FaultInjector,
    exposure: Exposure,
    frames: u64,
}

impl EmulatedCamera {
    /// A camera at the scene's ISO and 1/60 s, with the sample of `scene` mounted.
    pub fn new(scene: Scene, world: World, timing: CaptureTiming) -> Self {
        let iso = scene.camera().iso;
        Self {
            mount: SampleMount::new(scene),
            world,
            timing,
            faults: FaultInjector::default(),
            exposure: Exposure {
                shutter_s: 1.0 / 60.0,
                iso: Some(iso),
            },
            frames: 0,
        }
    }

    /// The scene of the sample mounted now.
    pub fn scene(&self) -> Arc<Scene> {
        self.mount.scene()
    }

    /// The camera before `carousel`: it sees the sample of the slot the carousel is at.
    pub fn with_carousel(mut self, carousel: Carousel) -> Self {
        self.mount.carousel = Some(Arc::new(carousel));
        self
    }

    /// A handle that changes the mounted sample while the camera is owned elsewhere.
    pub fn sample_mount(&self) -> SampleMount {
        self.mount.clone()
    }

    pub fn timing(&self) -> CaptureTiming {
        self.timing
    }

    /// Black and white level and response of the files this camera writes (for the
    /// capture sidecar) with the sample mounted now.
    pub fn file_levels(&self) -> FileLevels {
        render::file_levels(&self.scene())
    }

    /// Queues a fault for the coming captures.
    pub fn inject(&self, fault: CameraFault) {
        self.faults.inject(fault);
    }

    /// A handle that injects faults while the camera is owned elsewhere.
    pub fn fault_injector(&self) -> FaultInjector {
        self.faults.clone()
    }

    fn timeout(&self, what: &str, started: Instant) -> DeviceError {
        let deadline = wall(self.timing.deadline_wall_s(self.exposure.shutter_s));
        std::thread::sleep(deadline.saturating_sub(started.elapsed()));
        DeviceError::Timeout {
            what: what.to_string(),
            seconds: started.elapsed().as_secs_f64(),
        }
    }
}

/// A wait of `seconds`; negative, NaN or unrepresentable values (a bad `time_scale`)
/// wait not at all.
fn wall(seconds: f64) -> Duration {
    Duration::try_from_secs_f64(seconds.max(0.0)).unwrap_or(Duration::ZERO)
}

/// The allowed value nearest to `value` on a log scale.
fn nearest_log(allowed: impl Iterator<Item = f64>, value: f64) -> f64 {
    allowed
        .min_by(|a, b| {
            let da = (a.ln() - value.ln()).abs();
            let db = (b.ln() - value.ln()).abs();
            da.total_cmp(&db)
        })
        .unwrap_or(value)
}

impl Camera for EmulatedCamera {
    fn identify(&mut self) -> Result<CameraInfo, DeviceError> {
        self.faults.check_plugged()?;
        Ok(CameraInfo {
            model: self.scene().camera().model.clone(),
            port: "emulated".to_string(),
        })
    }

    fn shutter_speeds(&mut self) -> Result<Vec<f64>, DeviceError> {
        self.faults.check_plugged()?;
        Ok(SHUTTER_SPEEDS_S.to_vec())
    }

    fn set_exposure(&mut self, exposure: Exposure) -> Result<Exposure, DeviceError> {
        self.faults.check_plugged()?;
        let (lo, hi) = (
            SHUTTER_SPEEDS_S[0],
            SHUTTER_SPEEDS_S[SHUTTER_SPEEDS_S.len() - 1],
        );
        if !(exposure.shutter_s.is_finite() && exposure.shutter_s > 0.0) {
            return Err(DeviceError::OutOfRange {
                what: "shutter time (s)".into(),
                value: exposure.shutter_s,
                min: lo,
                max: hi,
            });
        }
        let shutter_s = nearest_log(SHUTTER_SPEEDS_S.iter().copied(), exposure.shutter_s);
        let iso = match exposure.iso {
            Some(0) => {
                return Err(DeviceError::OutOfRange {
                    what: "ISO".into(),
                    value: 0.0,
                    min: f64::from(ISO_VALUES[0]),
                    max: f64::from(ISO_VALUES[ISO_VALUES.len() - 1]),
                })
            }
            Some(iso) => {
                let snapped = nearest_log(ISO_VALUES.iter().map(|&v| f64::from(v)), f64::from(iso));
                Some(snapped as u32)
            }
            None => self.exposure.iso,
        };
        self.exposure = Exposure { shutter_s, iso };
        Ok(self.exposure)
    }

    fn capture_to(&mut self, path: &Path) -> Result<Capture, DeviceError> {
        let started = Instant::now();
        self.faults.check_plugged()?;
        match self.faults.take() {
            Some(CameraFault::Busy { .. }) => return Err(DeviceError::Busy),
            Some(CameraFault::Timeout) => return Err(self.timeout("capture to complete", started)),
            Some(CameraFault::Io) => {
                return Err(DeviceError::Io(std::io::Error::other(
                    "USB transfer from the camera failed",
                )))
            }
            Some(CameraFault::FileNeverArrives) => {
                return Err(self.timeout("the image file from the camera", started))
            }
            Some(CameraFault::Abort) => std::process::abort(),
            None => {}
        }
        let scene = self.scene();
        let shot = Shot {
            theta_l_deg: self.world.arm_deg(),
            shutter_s: self.exposure.shutter_s,
            iso: self.exposure.iso.unwrap_or(scene.camera().iso),
            frame_index: self.frames,
        };
        self.frames += 1;
        let frame = render::render(&scene, &shot);
        let path = path.with_extension("tiff");
        let bytes = frame.encode_tiff()?;
        let duration = wall(self.timing.capture_duration_s(shot.shutter_s));
        std::thread::sleep(duration.saturating_sub(started.elapsed()));
        self.faults.check_plugged()?;
        write_atomically(&path, &bytes)?;
        Ok(Capture {
            path,
            exposure: self.exposure,
        })
    }
}
