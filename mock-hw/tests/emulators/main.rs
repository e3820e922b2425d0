//! The emulated camera and stepper controller, one binary (one link).

mod grbl_support;

mod camera;
mod grbl_faults;
mod grbl_firmware_bytes;
mod grbl_session;
mod misalignment;
mod render;
mod rgl_bsdf;
mod scene;
mod tiff_file;
