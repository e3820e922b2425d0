//! gonio-mock-hw: hardware emulators that behave like the real devices.
//!
//! - [`grbl`]: a GRBL 1.1 controller on a pseudo-terminal, opened by device path.
//! - [`scene`], [`render`], [`camera`]: a camera that renders the cylinder scene with
//!   its own vector-form reflection code, simulating only the effects a scene names.
//! - [`world`]: the one emulated world both share: the light sits where the arm is.
//! - [`toml_error`]: TOML errors (of scenes and emulator configurations) on one line.

pub mod toml_error;
pub mod world;

pub mod grbl;

pub mod camera;
pub mod render;
pub mod scan_timing;
pub mod scene;
pub mod scene_spec;
