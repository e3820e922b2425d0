//! Opening the devices the configuration names: the real GRBL arm and gphoto2 camera,
//! or the emulators (a GRBL emulator on a pseudo-terminal, driven through the real
//! GRBL driver, and a camera rendering a scene).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use gonio_drivers::grbl::{ArmAxis, GrblArm, GrblArmConfig, Homing};
use gonio_drivers::supervised_camera::{SupervisedCamera, SupervisorConfig, WorkerSpec};
use gonio_drivers::{Arm, Camera, DeviceError};
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_mock_hw::camera::{CameraFault, CaptureTiming, Carousel, EmulatedCamera, FaultInjector};
use gonio_mock_hw::grbl::{Axis, AxisSet, Fault, GrblConfig, GrblEmulator};
use gonio_mock_hw::scene::Scene;
use gonio_mock_hw::world::World;
use gonio_processing::capture::Response;
use gonio_processing::geometry::Setup;
use serde_json::Value;

use super::config::{ArmConfig, ArmKind, CameraConfig, CarouselConfig, Config, HomingMode, Limits};
use super::mount::{scene_of, EmulatedSamples, Mount};
use super::sync::lock;
use super::timing::Timing;

/// What every capture sidecar says besides the exposure (`None`: the camera's own).
#[derive(Debug, Clone, Copy, Default)]
pub struct SidecarDefaults {
    pub black_level: Option<f64>,
    pub white_level: Option<f64>,
    pub response: Response,
    pub significant_bits: Option<u32>,
}

/// Opens (and reopens, after a disconnect) the arm.
pub struct ArmOpener {
    path: PathBuf,
    config: GrblArmConfig,
}

impl ArmOpener {
    pub fn open(&self) -> Result<Box<dyn Arm>, DeviceError> {
        Ok(Box::new(GrblArm::open(&self.path, self.config.clone())?))
    }

    /// The serial device the arm is opened on.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Which device the path names now, without opening it (opening resets the
    /// board); `None` while it is absent (unplugged).
    pub fn link(&self) -> Option<LinkId> {
        LinkId::of(&self.path)
    }
}

/// What a device path names: the path itself (a `/dev/serial/by-id` link, or the
/// device node, is made anew when the board is plugged in: its inode and change time)
/// and the device it leads to. Two differ when the board was unplugged and plugged in
/// meanwhile, even where the new link reuses the old one's inode and device number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkId {
    path: (u64, u64, i64, i64),
    device: u64,
}

impl LinkId {
    /// What `path` names now; `None` while it is absent.
    pub fn of(path: &Path) -> Option<LinkId> {
        use std::os::unix::fs::MetadataExt;
        let own = std::fs::symlink_metadata(path).ok()?;
        let device = std::fs::metadata(path).ok()?;
        Some(LinkId {
            path: (own.dev(), own.ino(), own.ctime(), own.ctime_nsec()),
            device: device.rdev(),
        })
    }
}

/// The running emulators, kept alive for the daemon's life and reachable for fault
/// injection.
pub struct Emulators {
    pub grbl: std::sync::Mutex<GrblEmulator>,
    pub camera_faults: FaultInjector,
}

/// What the daemon knows of its devices besides the devices themselves.
pub struct Devices {
    pub arm: ArmOpener,
    pub camera: Box<dyn Camera>,
    /// Geometry and white reflectance written to each scan's setup.json, if known.
    pub setup: Option<Setup>,
    /// Where `setup` comes from: `emulated scene` or `configuration [setup]`.
    pub setup_source: &'static str,
    /// Scene truth written to each emulated scan's truth.json.
    pub truth: Option<Value>,
    /// Levels and response written to every capture sidecar.
    pub sidecar: SidecarDefaults,
    /// ISO set for every exposure, where the body has one.
    pub iso: Option<u32>,
    /// What the devices' steps are expected to take.
    pub timing: Timing,
    pub emulators: Option<Arc<Emulators>>,
    /// The sample on the cylinder.
    pub mount: Arc<Mount>,
}

/// What an emulated scan's files say of the scene it images: its setup, its truth and
/// the levels of its captures.
pub struct SceneFacts {
    pub setup: Setup,
    pub truth: Value,
    pub sidecar: SidecarDefaults,
}

impl SceneFacts {
    pub fn of(scene: &Scene) -> anyhow::Result<Self> {
        let setup: Setup =
            serde_json::from_value(scene.setup_json()).context("converting the scene setup")?;
        let levels = gonio_mock_hw::render::file_levels(scene);
        Ok(Self {
            setup,
            truth: scene.truth_json(),
            sidecar: SidecarDefaults {
                black_level: Some(f64::from(levels.black_level)),
                white_level: Some(f64::from(levels.white_level)),
                response: if levels.nonlinear {
                    Response::Nonlinear
                } else {
                    Response::Linear
                },
                significant_bits: Some(levels.significant_bits),
            },
        })
    }
}

/// The driver's expectations: the `[arm]` keys and the θL limits.
fn grbl_arm_config(arm: &ArmConfig, limits: Limits) -> GrblArmConfig {
    GrblArmConfig {
        axis: arm.axis(),
        min_deg: limits.min_deg,
        max_deg: limits.max_deg,
        steps_per_deg: arm.steps_per_deg,
        max_travel_deg: arm.max_travel_deg,
        max_rate_deg_per_min: arm.max_rate_deg_per_min,
        accel_deg_per_s2: arm.accel_deg_per_s2,
        homing: match arm.homing {
            HomingMode::Required => Homing::Required,
            HomingMode::Optional => Homing::Optional,
            HomingMode::Off => Homing::Off,
        },
        apply_settings: arm.apply_settings,
        reply_timeout: arm.reply_timeout(),
        ..GrblArmConfig::default()
    }
}

/// The emulated board: the `board` file if given, else a board set up as the `[arm]`
/// keys expect (homing the arm's axis, and the carousel's with it); at `time_scale`
/// either way.
fn emulated_board(
    arm: &ArmConfig,
    carousel: Option<&CarouselConfig>,
) -> anyhow::Result<GrblConfig> {
    let board = match &arm.board {
        Some(path) => {
            let text = read_input_to_string(path, MAX_SMALL_FILE_BYTES)
                .with_context(|| format!("reading arm.board {}", path.display()))?;
            GrblConfig::from_toml_str(&text)
                .with_context(|| format!("arm.board {}", path.display()))?
        }
        None => {
            let preset = GrblConfig::arm_board();
            let axis = arm.axis();
            let homes = arm.homing != HomingMode::Off;
            let carousel_mask = carousel.map_or(0, |c| 1 << c.axis().index());
            GrblConfig {
                arm_axis: emulated_axis(axis),
                steps_per_deg: arm.steps_per_deg,
                max_travel_deg: arm.max_travel_deg,
                max_rate_deg_per_min: arm
                    .max_rate_deg_per_min
                    .unwrap_or(preset.max_rate_deg_per_min),
                accel_deg_per_s2: arm.accel_deg_per_s2.unwrap_or(preset.accel_deg_per_s2),
                homing_enabled: homes,
                soft_limits: homes,
                homing_cycles: vec![AxisSet {
                    mask: (1 << axis.index()) | carousel_mask,
                }],
                ..preset
            }
        }
    };
    Ok(GrblConfig {
        time_scale: arm.time_scale,
        ..board
    })
}

/// The emulated board's name of `axis`.
fn emulated_axis(axis: ArmAxis) -> Axis {
    match axis {
        ArmAxis::X => Axis::X,
        ArmAxis::Y => Axis::Y,
        ArmAxis::Z => Axis::Z,
    }
}

/// The emulated carousel of `config` before a camera showing `shown`: each slot holds
/// its sample's scene (a sample without one leaves its slot empty).
fn emulated_carousel(
    config: &CarouselConfig,
    scenes: &BTreeMap<String, String>,
    shown: &Scene,
    world: World,
) -> anyhow::Result<Carousel> {
    let mut slots = Vec::new();
    for (sample, slot) in &config.slots {
        if let Some(spec) = scene_of(scenes, sample) {
            let scene = load_scene(spec).with_context(|| format!("scene of sample {sample}"))?;
            slots.push((*slot, scene));
        }
    }
    let empty = shown.without_sample().context("the empty carousel slot")?;
    Ok(Carousel::new(config.axis().index(), slots, empty, world))
}

/// Loads a scene by builtin name or file path.
fn load_scene(name_or_path: &str) -> anyhow::Result<Scene> {
    gonio_mock_hw::scene_spec::load_scene(name_or_path).context("camera.scene")
}

/// Opens the devices of `config`.
pub fn open(config: &Config) -> anyhow::Result<Devices> {
    let world = World::new(0.0);
    let real = Timing::real();
    let (grbl, arm, timing) = match config.arm.kind {
        ArmKind::Emulator => {
            let board = emulated_board(&config.arm, config.carousel.as_ref())?;
            if let Some(carousel) = &config.carousel {
                let travel =
                    gonio_mock_hw::grbl::axis_travel(&board, emulated_axis(carousel.axis()));
                carousel.check_travel(travel)?;
            }
            let timing = Timing::emulated(&board, real.capture);
            let emulator =
                GrblEmulator::start(board, world.clone()).context("starting the GRBL emulator")?;
            let arm = ArmOpener {
                path: emulator.device_path().to_path_buf(),
                config: grbl_arm_config(&config.arm, config.limits),
            };
            (Some(emulator), arm, timing)
        }
        ArmKind::Grbl => (
            None,
            ArmOpener {
                path: config.arm.path.clone().context("arm.path is not set")?,
                config: grbl_arm_config(&config.arm, config.limits),
            },
            real,
        ),
    };
    match &config.camera {
        CameraConfig::Emulator {
            scene: spec,
            sample,
            samples,
            time_scale,
        } => {
            let scene = load_scene(spec)?;
            let capture = CaptureTiming {
                time_scale: *time_scale,
                ..CaptureTiming::default()
            };
            let mut camera = EmulatedCamera::new(scene.clone(), world.clone(), capture);
            let facts = SceneFacts::of(&scene)?;
            let frame = (facts.setup.image_width, facts.setup.image_height);
            let body = scene.camera();
            let mut scenes = samples.clone();
            scenes.insert(sample.clone(), spec.clone());
            if let Some(carousel) = &config.carousel {
                let carousel = emulated_carousel(carousel, &scenes, &scene, world.clone())?;
                camera = camera.with_carousel(carousel);
            }
            let mount =
                Mount::emulated(sample, EmulatedSamples::new(camera.sample_mount(), scenes)?);
            let emulators = grbl.map(|grbl| {
                Arc::new(Emulators {
                    grbl: std::sync::Mutex::new(grbl),
                    camera_faults: camera.fault_injector(),
                })
            });
            Ok(Devices {
                arm,
                camera: Box::new(camera),
                setup: Some(facts.setup),
                setup_source: "emulated scene",
                truth: Some(facts.truth),
                sidecar: facts.sidecar,
                iso: Some(body.iso),
                timing: Timing {
                    capture,
                    rendered: true,
                    ..timing
                }
                .with_frame(frame.0, frame.1),
                emulators,
                mount: Arc::new(mount),
            })
        }
        CameraConfig::Gphoto2 { iso, model, port } => Ok(Devices {
            arm,
            camera: open_gphoto2(model.as_deref(), port.as_deref())?,
            setup: config.setup(),
            setup_source: "configuration [setup]",
            truth: None,
            sidecar: SidecarDefaults::default(),
            iso: Some(*iso),
            timing: match config.setup() {
                Some(setup) => timing.with_frame(setup.image_width, setup.image_height),
                None => timing,
            },
            emulators: None,
            mount: Arc::new(Mount::unknown()),
        }),
    }
}

/// The gphoto2 camera, run in the supervised `gonio-camera-worker` process (built
/// with the `gphoto2` feature) beside this executable.
fn open_gphoto2(model: Option<&str>, port: Option<&str>) -> anyhow::Result<Box<dyn Camera>> {
    let mut args = Vec::new();
    for (flag, value) in [("--model", model), ("--port", port)] {
        if let Some(value) = value {
            args.extend([flag.to_owned(), value.to_owned()]);
        }
    }
    let spec = WorkerSpec::beside_current_exe(args).context("locating gonio-camera-worker")?;
    // The worker starts with the first call, so the daemon starts without the camera
    // and finds it once it is plugged in.
    Ok(Box::new(SupervisedCamera::new(
        spec,
        SupervisorConfig::default(),
    )))
}

/// A fault the test hook injects into an emulator. Each variant is a struct, so that a
/// field it does not take is refused (serde lets a unit variant of a tagged enum ignore
/// them).
#[derive(Debug, Clone, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case", tag = "fault", deny_unknown_fields)]
pub enum InjectedFault {
    /// Pull the emulated serial cable.
    Unplug {},
    /// Plug it back in.
    Reconnect {},
    /// The board resets by itself (as when DTR toggles): it greets again and has lost
    /// its position.
    ArmReset {},
    /// The camera reports busy for the next `count` captures.
    CameraBusy { count: u32 },
    /// The next `count` captures never complete (time out).
    CameraTimeout { count: u32 },
    /// Pull the camera's USB cable: every camera call fails until it is plugged back.
    CameraUnplug {},
    /// Plug the camera back in.
    CameraReplug {},
    /// The next capture aborts the daemon (a crashing camera library).
    CameraAbort {},
}

impl Emulators {
    /// Applies a fault to the emulated devices.
    pub fn inject(&self, fault: &InjectedFault) -> anyhow::Result<()> {
        match fault {
            InjectedFault::Unplug {} => lock(&self.grbl).inject(Fault::Unplug),
            InjectedFault::Reconnect {} => lock(&self.grbl)
                .reconnect()
                .context("reconnecting the GRBL emulator")?,
            InjectedFault::ArmReset {} => lock(&self.grbl).inject(Fault::ResetBanner),
            InjectedFault::CameraBusy { count } => {
                self.camera_faults
                    .inject(CameraFault::Busy { captures: *count });
            }
            InjectedFault::CameraTimeout { count } => {
                for _ in 0..*count {
                    self.camera_faults.inject(CameraFault::Timeout);
                }
            }
            InjectedFault::CameraUnplug {} => self.camera_faults.unplug(),
            InjectedFault::CameraReplug {} => self.camera_faults.replug(),
            InjectedFault::CameraAbort {} => self.camera_faults.inject(CameraFault::Abort),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::InjectedFault;

    #[test]
    fn a_fault_with_a_field_it_does_not_take_is_refused() {
        let parse = |text: &str| serde_json::from_str::<InjectedFault>(text);
        assert!(matches!(
            parse(r#"{"fault": "camera_busy", "count": 2}"#),
            Ok(InjectedFault::CameraBusy { count: 2 })
        ));
        assert!(matches!(
            parse(r#"{"fault": "unplug"}"#),
            Ok(InjectedFault::Unplug {})
        ));
        for text in [
            r#"{"fault": "camera_busy", "count": 2, "times": 3}"#,
            r#"{"fault": "unplug", "count": 1}"#,
            r#"{"fault": "camera_busy"}"#,
        ] {
            let error = parse(text).expect_err(text).to_string();
            assert!(
                error.contains("times") || error.contains("count"),
                "{text}: {error}"
            );
        }
    }
}
