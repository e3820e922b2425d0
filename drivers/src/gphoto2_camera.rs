//! A DSLR through libgphoto2 (cargo feature `gphoto2`; needs `libgphoto2-dev`,
//! `libclang-dev` and `pkg-config` to build).
//!
//! [`GphotoCamera`] talks to the camera in-process and has no deadline of its own: a
//! call stuck inside libgphoto2 cannot be cancelled. The daemon therefore runs it in
//! the `gonio-camera-worker` binary under a
//! [`SupervisedCamera`](crate::supervised_camera::SupervisedCamera).
//!
//! On open the camera captures to its internal RAM (`capturetarget`) and in raw
//! quality (`imagequality` on Nikon bodies, `imageformat` on others) where the body
//! has those settings. Busy and I/O errors are retried with exponential backoff.

use std::io;
use std::path::Path;
use std::thread;
use std::time::Duration;

use gphoto2::error::ErrorKind;
use gphoto2::widget::RadioWidget;
use gphoto2::{Camera as GpCamera, Context};

use crate::camera_choice::{
    nearest_iso, nearest_shutter, parse_iso, parse_shutter, shutter_times, ShutterChoice,
};
use crate::{Camera, CameraInfo, Capture, DeviceError, Exposure};
use gonio_files::output::write_atomically;

/// Which camera to open and how patiently to retry.
#[derive(Debug, Clone, PartialEq)]
pub struct GphotoConfig {
    /// Model name as libgphoto2 lists it (`Nikon DSC D750`), or `None` for any.
    pub model: Option<String>,
    /// Port as libgphoto2 lists it (`usb:001,004`), or `None` for any.
    pub port: Option<String>,
    /// Retries of a call that failed with "busy" or an I/O error.
    pub retries: u32,
    /// First retry delay, doubling each retry.
    pub backoff: Duration,
}

impl Default for GphotoConfig {
    fn default() -> Self {
        Self {
            model: None,
            port: None,
            retries: 4,
            backoff: Duration::from_millis(200),
        }
    }
}

/// The device error for a libgphoto2 error.
pub fn map_error(error: &gphoto2::Error) -> DeviceError {
    let message = format!("libgphoto2: {error}");
    match error.kind() {
        ErrorKind::CameraBusy => DeviceError::Busy,
        ErrorKind::Timeout => DeviceError::Io(io::Error::new(io::ErrorKind::TimedOut, message)),
        ErrorKind::Io
        | ErrorKind::IoRead
        | ErrorKind::IoWrite
        | ErrorKind::IoUpdate
        | ErrorKind::IoSerialSpeed
        | ErrorKind::IoUsbClearHalt
        | ErrorKind::IoLock
        | ErrorKind::IoUsbClaim => DeviceError::Io(io::Error::other(message)),
        ErrorKind::ModelNotFound | ErrorKind::UnknownPort | ErrorKind::IoUsbFind => {
            DeviceError::NotFound(message)
        }
        _ => DeviceError::Protocol(message),
    }
}

/// The raw-quality choice among a body's `imagequality`/`imageformat` choices:
/// raw only (not raw + JPEG).
pub fn raw_choice<S: AsRef<str>>(choices: &[S]) -> Option<&str> {
    choices.iter().map(AsRef::as_ref).find(|c| {
        let c = c.to_ascii_lowercase();
        (c.contains("raw") || c.contains("nef")) && !c.contains('+')
    })
}

/// A camera opened through libgphoto2.
pub struct GphotoCamera {
    // Field order matters: the camera must go before its context.
    camera: GpCamera,
    _context: Context,
    info: CameraInfo,
    config: GphotoConfig,
    exposure: Option<Exposure>,
}

impl GphotoCamera {
    /// Detect the camera (the first one matching `config.model`/`config.port`), set its
    /// capture target to internal RAM and its quality to raw where it has them.
    pub fn open(config: GphotoConfig) -> Result<GphotoCamera, DeviceError> {
        let context = Context::new().map_err(|e| map_error(&e))?;
        let detected: Vec<_> = retry(&config, || context.list_cameras().wait())?.collect();
        let wanted = |model: &str, port: &str| {
            config
                .model
                .as_deref()
                .is_none_or(|m| m.eq_ignore_ascii_case(model))
                && config.port.as_deref().is_none_or(|p| p == port)
        };
        let descriptor = detected
            .iter()
            .find(|d| wanted(&d.model, &d.port))
            .ok_or_else(|| {
                let found: Vec<String> = detected
                    .iter()
                    .map(|d| format!("{} on {}", d.model, d.port))
                    .collect();
                DeviceError::NotFound(format!(
                    "no camera{}{} detected (found: {})",
                    config
                        .model
                        .as_deref()
                        .map(|m| format!(" model {m:?}"))
                        .unwrap_or_default(),
                    config
                        .port
                        .as_deref()
                        .map(|p| format!(" on port {p:?}"))
                        .unwrap_or_default(),
                    if found.is_empty() {
                        "none".to_owned()
                    } else {
                        found.join(", ")
                    }
                ))
            })?
            .clone();
        let camera = retry(&config, || context.get_camera(&descriptor).wait())?;
        let this = GphotoCamera {
            camera,
            _context: context,
            info: CameraInfo {
                model: descriptor.model,
                port: descriptor.port,
            },
            config,
            exposure: None,
        };
        if let Some(target) = this.radio("capturetarget")? {
            let ram = choices(&target).into_iter().find(|c| {
                let c = c.to_ascii_lowercase();
                c.contains("internal ram") || c.contains("sdram")
            });
            if let Some(ram) = ram {
                this.set_radio(&target, &ram)?;
            }
        }
        for key in ["imagequality", "imageformat"] {
            if let Some(quality) = this.radio(key)? {
                if let Some(raw) = raw_choice(&choices(&quality)) {
                    this.set_radio(&quality, raw)?;
                }
                break;
            }
        }
        Ok(this)
    }

    fn retry<T>(&self, op: impl FnMut() -> gphoto2::Result<T>) -> Result<T, DeviceError> {
        retry(&self.config, op)
    }

    /// A radio/menu setting, or `None` when the body has no such key.
    fn radio(&self, key: &str) -> Result<Option<RadioWidget>, DeviceError> {
        match self.retry(|| self.camera.config_key::<RadioWidget>(key).wait()) {
            Ok(widget) => Ok(Some(widget)),
            Err(DeviceError::Protocol(_)) => Ok(None),
            Err(e) => Err(e),
        }
    }

    fn set_radio(&self, widget: &RadioWidget, choice: &str) -> Result<(), DeviceError> {
        widget.set_choice(choice).map_err(|e| map_error(&e))?;
        self.retry(|| self.camera.set_config(widget).wait())
    }

    fn shutter_widget(&self) -> Result<RadioWidget, DeviceError> {
        self.radio("shutterspeed")?.ok_or_else(|| {
            DeviceError::Protocol(format!("{} has no shutterspeed setting", self.info.model))
        })
    }

    /// The exposure the body is set to now.
    fn read_exposure(&self) -> Result<Exposure, DeviceError> {
        let shutter = self.shutter_widget()?.choice();
        let shutter_s = match parse_shutter(&shutter) {
            Some(ShutterChoice::Seconds(t)) => t,
            _ => {
                return Err(DeviceError::Protocol(format!(
                    "camera reports shutter {shutter:?}, not a fixed time"
                )))
            }
        };
        let iso = self.radio("iso")?.and_then(|w| parse_iso(&w.choice()));
        Ok(Exposure { shutter_s, iso })
    }
}

fn choices(widget: &RadioWidget) -> Vec<String> {
    widget.choices_iter().collect()
}

/// Run `op`, retrying busy and I/O errors with exponential backoff.
fn retry<T>(
    config: &GphotoConfig,
    mut op: impl FnMut() -> gphoto2::Result<T>,
) -> Result<T, DeviceError> {
    let mut delay = config.backoff;
    let mut attempt = 0;
    loop {
        match op() {
            Ok(value) => return Ok(value),
            Err(e) => {
                let error = map_error(&e);
                let transient = matches!(error, DeviceError::Busy | DeviceError::Io(_));
                if !transient || attempt >= config.retries {
                    return Err(error);
                }
                attempt += 1;
                thread::sleep(delay);
                delay *= 2;
            }
        }
    }
}

impl Camera for GphotoCamera {
    fn identify(&mut self) -> Result<CameraInfo, DeviceError> {
        Ok(self.info.clone())
    }

    fn shutter_speeds(&mut self) -> Result<Vec<f64>, DeviceError> {
        Ok(shutter_times(&choices(&self.shutter_widget()?)))
    }

    /// Snap to the nearest allowed shutter (and ISO, where the body has it), write it,
    /// and return what the body reads back.
    fn set_exposure(&mut self, exposure: Exposure) -> Result<Exposure, DeviceError> {
        if !(exposure.shutter_s.is_finite() && exposure.shutter_s > 0.0) {
            return Err(DeviceError::OutOfRange {
                what: "shutter time (s)".into(),
                value: exposure.shutter_s,
                min: 0.0,
                max: f64::INFINITY,
            });
        }
        let shutter = self.shutter_widget()?;
        let all = choices(&shutter);
        let (choice, _) = nearest_shutter(&all, exposure.shutter_s)
            .ok_or_else(|| DeviceError::Protocol(format!("no fixed shutter time among {all:?}")))?;
        let choice = choice.to_owned();
        self.set_radio(&shutter, &choice)?;
        if let (Some(target), Some(iso)) = (exposure.iso, self.radio("iso")?) {
            let all = choices(&iso);
            if let Some((choice, _)) = nearest_iso(&all, target) {
                let choice = choice.to_owned();
                self.set_radio(&iso, &choice)?;
            }
        }
        let actual = self.read_exposure()?;
        self.exposure = Some(actual);
        Ok(actual)
    }

    fn capture_to(&mut self, path: &Path) -> Result<Capture, DeviceError> {
        let exposure = match self.exposure {
            Some(e) => e,
            None => self.read_exposure()?,
        };
        let file = self.retry(|| self.camera.capture_image().wait())?;
        let (folder, name) = (file.folder().into_owned(), file.name().into_owned());
        let data = self.retry(|| {
            let fs = self.camera.fs();
            let camera_file = fs.download(&folder, &name).wait()?;
            camera_file.get_data(&self.camera).wait()
        })?;
        let target = match Path::new(&name).extension() {
            Some(ext) => path.with_extension(ext.to_ascii_lowercase()),
            None => path.to_owned(),
        };
        write_atomically(&target, &data)?;
        // Free the camera's RAM; the frame is safe on disk, so a failure here is harmless.
        let _ = self.camera.fs().delete_file(&folder, &name).wait();
        Ok(Capture {
            path: target,
            exposure,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gphoto2::libgphoto2_sys as sys;

    #[test]
    fn maps_libgphoto2_errors() {
        let map = |code| map_error(&gphoto2::Error::new(code, None));
        assert!(matches!(map(sys::GP_ERROR_CAMERA_BUSY), DeviceError::Busy));
        assert!(matches!(map(sys::GP_ERROR_IO_READ), DeviceError::Io(_)));
        assert!(matches!(
            map(sys::GP_ERROR_IO_USB_CLAIM),
            DeviceError::Io(_)
        ));
        assert!(matches!(
            map(sys::GP_ERROR_MODEL_NOT_FOUND),
            DeviceError::NotFound(_)
        ));
        assert!(matches!(
            map(sys::GP_ERROR_IO_USB_FIND),
            DeviceError::NotFound(_)
        ));
        assert!(matches!(
            map(sys::GP_ERROR_NOT_SUPPORTED),
            DeviceError::Protocol(_)
        ));
        let DeviceError::Io(timeout) = map(sys::GP_ERROR_TIMEOUT) else {
            panic!("timeout not an I/O error")
        };
        assert_eq!(timeout.kind(), io::ErrorKind::TimedOut);
        assert!(map(sys::GP_ERROR_CAMERA_BUSY).is_transient());
    }

    #[test]
    fn retries_only_transient_errors_and_gives_up() {
        let config = GphotoConfig {
            retries: 2,
            backoff: Duration::from_millis(1),
            ..GphotoConfig::default()
        };
        let mut calls = 0;
        let result: Result<(), _> = retry(&config, || {
            calls += 1;
            Err(gphoto2::Error::new(sys::GP_ERROR_CAMERA_BUSY, None))
        });
        assert!(matches!(result, Err(DeviceError::Busy)));
        assert_eq!(calls, 3);
        calls = 0;
        let result = retry(&config, || {
            calls += 1;
            if calls < 2 {
                Err(gphoto2::Error::new(sys::GP_ERROR_IO, None))
            } else {
                Ok(calls)
            }
        });
        assert_eq!(result.unwrap(), 2);
        calls = 0;
        let result: Result<(), _> = retry(&config, || {
            calls += 1;
            Err(gphoto2::Error::new(sys::GP_ERROR_BAD_PARAMETERS, None))
        });
        assert!(matches!(result, Err(DeviceError::Protocol(_))));
        assert_eq!(calls, 1);
    }

    #[test]
    fn picks_raw_only_quality() {
        let nikon = ["JPEG Basic", "JPEG Fine", "NEF (Raw)", "NEF+Basic"];
        assert_eq!(raw_choice(&nikon), Some("NEF (Raw)"));
        let canon = ["Large Fine JPEG", "RAW + Large Fine JPEG", "RAW"];
        assert_eq!(raw_choice(&canon), Some("RAW"));
        assert_eq!(raw_choice(&["JPEG"]), None);
    }
}
