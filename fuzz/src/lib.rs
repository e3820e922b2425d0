//! Fuzz targets for every reader of untrusted files: one function per reader that
//! feeds it arbitrary bytes and checks what comes back. A reader may refuse its input
//! with an error that says what is wrong; it must never panic, abort, hang, or hand
//! back a value that breaks its own documented invariants (the checks below panic
//! then, so the fuzzer records it).
//!
//! The same targets run in three ways: under AFL++ (`src/main.rs`, see README.md), over
//! the committed seed corpus in `corpus/<target>/`, and over random bytes and mutated
//! seeds with proptest (`tests/`).

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

use gonio_mock_hw::scene::Scene;
use gonio_processing::capture::Frame;
use gonio_processing::hdr::read_exr_rgb;
use gonio_processing::reference::Reference;
use gonio_processing::{color, extract, samples};

/// A fuzz target: a name (also its corpus directory) and its check.
pub struct Target {
    pub name: &'static str,
    run: fn(&Scratch, &[u8]) -> Outcome,
}

/// What a reader made of an input: accepted, or refused with this message.
pub type Outcome = Result<(), String>;

impl Target {
    /// Feeds `data` to the reader and checks the outcome (panics on a broken
    /// invariant, which is a finding).
    pub fn check(&self, scratch: &Scratch, data: &[u8]) -> Outcome {
        (self.run)(scratch, data)
    }
}

/// Every target.
pub const TARGETS: [Target; 7] = [
    Target {
        name: "tiff_sidecar",
        run: tiff_sidecar,
    },
    Target {
        name: "raw",
        run: raw,
    },
    Target {
        name: "exr",
        run: exr,
    },
    Target {
        name: "samples_csv",
        run: samples_csv,
    },
    Target {
        name: "reference_csv",
        run: reference_csv,
    },
    Target {
        name: "scene_toml",
        run: scene_toml,
    },
    Target {
        name: "setup_json",
        run: setup_json,
    },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// The seed corpus directory of a target.
pub fn corpus_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(name)
}

/// A private directory where targets whose readers take paths write their input.
pub struct Scratch {
    dir: tempfile::TempDir,
}

impl Scratch {
    pub fn new() -> io::Result<Self> {
        Ok(Self {
            dir: tempfile::tempdir()?,
        })
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let path = self.dir.path().join(name);
        fs::write(&path, bytes).expect("writing the fuzz input to the scratch directory");
        path
    }
}

/// The sidecar used where the input holds only an image.
const SIDECAR: &[u8] = br#"{"shutter_s":0.01,"iso":100,"theta_l":-20.0,"camera":"fuzz","time":"2024-01-01T00:00:00Z"}"#;

/// Splits a TIFF+sidecar input: a 2-byte little-endian length, that many bytes of
/// sidecar JSON, then the image file.
pub fn split_sidecar(data: &[u8]) -> (&[u8], &[u8]) {
    let Some((len, rest)) = data.split_first_chunk::<2>() else {
        return (&[], data);
    };
    let len = usize::from(u16::from_le_bytes(*len)).min(rest.len());
    rest.split_at(len)
}

/// An error message must say something.
fn refused(error: &dyn std::fmt::Display) -> Outcome {
    let text = error.to_string();
    assert!(!text.trim().is_empty(), "an empty error message");
    Err(text)
}

fn check_frame(result: Result<Frame, gonio_processing::capture::CaptureError>) -> Outcome {
    match result {
        Ok(frame) => {
            assert!(frame.width > 0 && frame.height > 0);
            assert_eq!(frame.data.len(), 3 * frame.width * frame.height);
            assert!(frame.black_level.is_finite() && frame.white_level.is_finite());
            assert!(frame.black_level < frame.white_level);
            for (x, y) in [(0, 0), (frame.width - 1, frame.height - 1)] {
                assert!(frame.signal(x, y, 0).is_finite());
            }
            Ok(())
        }
        Err(err) => refused(&err),
    }
}

fn tiff_sidecar(scratch: &Scratch, data: &[u8]) -> Outcome {
    let (sidecar, image) = split_sidecar(data);
    scratch.write("frame.json", sidecar);
    check_frame(Frame::read(&scratch.write("frame.tiff", image)))
}

fn raw(scratch: &Scratch, data: &[u8]) -> Outcome {
    scratch.write("frame.json", SIDECAR);
    // The extension only picks the raw path: rawler identifies the format itself.
    check_frame(Frame::read(&scratch.write("frame.dng", data)))
}

fn exr(scratch: &Scratch, data: &[u8]) -> Outcome {
    match read_exr_rgb(&scratch.write("map.exr", data)) {
        Ok((width, height, rgb)) => {
            assert_eq!(rgb.len(), 3 * width * height);
            Ok(())
        }
        Err(err) => refused(&err),
    }
}

fn samples_csv(_: &Scratch, data: &[u8]) -> Outcome {
    match samples::read_csv_from(data) {
        Ok(samples) => {
            for s in &samples {
                assert_eq!(s.non_finite_field(), None);
                assert!(s.rgb.iter().all(|v| (v * v).is_finite()));
            }
            Ok(())
        }
        Err(err) => refused(&err),
    }
}

fn reference_csv(_: &Scratch, data: &[u8]) -> Outcome {
    match Reference::from_reader(data, "fuzz", &color::CameraModel::builtin()) {
        Ok(reference) => {
            for p in reference.points() {
                if let Some(rgb) = reference.interpolate(p.theta_i, p.theta_r) {
                    assert!(rgb.iter().all(|v| v.is_finite()), "{rgb:?}");
                }
            }
            Ok(())
        }
        Err(err) => refused(&err),
    }
}

fn scene_toml(_: &Scratch, data: &[u8]) -> Outcome {
    let text = std::str::from_utf8(data).map_err(|e| e.to_string())?;
    match Scene::from_toml_str(text) {
        Ok(scene) => {
            let _ = scene.truth_json();
            let _ = scene.setup_json();
            Ok(())
        }
        Err(err) => refused(&err),
    }
}

fn setup_json(scratch: &Scratch, data: &[u8]) -> Outcome {
    match extract::read_setup(&scratch.write("setup.json", data)) {
        Ok(setup) => {
            assert!(setup.validate().is_ok());
            Ok(())
        }
        Err(err) => refused(&err),
    }
}
