//! gonio-processing: the science of image-based BRDF measurement, pure and synchronous.
//!
//! Conventions (the one place for all of them is `docs/ARCHITECTURE.md`; in short):
//! - Angles are degrees in public types, files and the CLI; radians inside computations.
//! - In-plane, signed "anormal" angles from the surface normal, with the specular
//!   direction at θr = θi. The half vector makes α = (θi − θr)/2 with the normal,
//!   n·l = cos θi, n·v = cos θr, v·h = cos((θi + θr)/2).
//! - β is the radiance factor in the camera-RGB domain (a perfect white gives 100 in G
//!   after [`color`] conversion; raw extraction gives β = L_sample / L_white).

mod decimal;
mod simd;

pub use decimal::Brief;

pub mod brdf;
pub mod fit;
pub mod geometry;
pub mod metrics;
pub mod multi_angle;
pub mod samples;
pub mod setup_uncertainty;
pub mod white_angular;

pub mod calibrate;
pub mod capture;
pub mod color;
pub mod extract;
pub mod guard;
pub mod hdr;
pub mod reference;
pub mod scan_plan;

pub mod export;
pub mod study;
pub mod truth;
