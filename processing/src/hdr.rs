//! HDR radiance maps from a bracket of exposures.
//!
//! Two methods, one merge of a value's readings: the weighted mean of reading/exposure
//! over the frames that hold it, each weighted by its inverse variance H²/σ² (H the
//! frame's exposure). Which frames hold it and the variance σ² of each are decided by
//! the reading an estimate predicts for the frame (estimate × H), not by the frame's own
//! noisy reading: a reading that noise lifts over the black threshold would otherwise be
//! kept more often than one it lowers (a bias of up to 1 % at low signal in the linear
//! case, and several-fold for dark 8-bit values), and noisy readings would set their own
//! weights. The first estimate is the longest exposure's usable reading alone; the mean
//! is taken from it, then again from the merged value. A frame whose own reading is
//! clipped never counts; a black reading in a frame that should hold the value counts as
//! the signal it reads.
//! - **linear** (raw counts): the reading is the normalised signal, usable between
//!   `min_signal` and `max_signal`; σ² is shot plus read noise of the noise model.
//! - **Debevec–Malik (1997)** for non-linear frames: counts quantised to 256 levels,
//!   the log response g(z) recovered per channel by least squares from sampled pixels
//!   with hat weights, a second-difference smoothness term λ and g(128) = 0, made
//!   monotone (see `response`). The reading of level z is the exposure e^g(z) (0 at level
//!   0), usable where the prediction reads between levels 1 and 254; σ² is shot, read
//!   and quantisation noise of a model fitted to the bracket.
//!
//! Radiance is relative: for the linear method, normalised signal (0 black, 1 clipping)
//! per second of exposure at ISO 100; for Debevec–Malik the scale fixed by g(128) = 0.
//! Ratios of radiances (which is what extraction uses) are independent of that scale.
//!
//! A channel with no usable frame is flagged in [`HdrImage::mask`] and given a finite
//! value: if any frame clipped, the lower bound from the shortest clipped exposure
//! ([`SATURATED`]); otherwise (black in every frame) 0 ([`UNDEREXPOSED`]).
#![doc = include_str!("hdr.md")]

mod debevec_malik;
mod error;
mod exr;
mod image;
mod linear;
mod options;
mod response;
mod weighting;

use crate::capture::{Frame, Response};
use debevec_malik::merge_debevec_malik;
use linear::merge_linear;
use options::check_options;

pub use error::HdrError;
pub use exr::read_exr_rgb;
pub use image::{channel_mask, HdrImage, HdrInfo, SATURATED, UNDEREXPOSED};
pub use options::{MergeMethod, MergeOptions, NoiseModel};

/// Merges a bracket of frames of one θL (any order; repeated exposures are fine).
pub fn merge(frames: &[Frame], options: &MergeOptions) -> Result<HdrImage, HdrError> {
    let first = frames.first().ok_or(HdrError::NoFrames)?;
    check_options(options)?;
    for frame in frames {
        if (frame.width, frame.height) != (first.width, first.height) {
            return Err(HdrError::SizeMismatch {
                path: frame.path.clone(),
                width: first.width,
                height: first.height,
                found_w: frame.width,
                found_h: frame.height,
            });
        }
        if (frame.sidecar.theta_l - first.sidecar.theta_l).abs() > 1e-6 {
            return Err(HdrError::ThetaMismatch {
                path: frame.path.clone(),
                expected: first.sidecar.theta_l,
                found: frame.sidecar.theta_l,
            });
        }
        if frame.sidecar.response != first.sidecar.response {
            return Err(HdrError::MixedResponse {
                path: frame.path.clone(),
                expected: first.sidecar.response,
                found: frame.sidecar.response,
            });
        }
    }
    let method = match (options.method, first.sidecar.response) {
        (MergeMethod::Auto, Response::Linear) | (MergeMethod::Linear, _) => MergeMethod::Linear,
        _ => MergeMethod::DebevecMalik,
    };
    let (rgb, mask, name) = match method {
        MergeMethod::DebevecMalik => {
            let (rgb, mask) = merge_debevec_malik(frames, options)?;
            (rgb, mask, "debevec-malik")
        }
        _ => {
            let (rgb, mask) = merge_linear(frames, options);
            (rgb, mask, "linear")
        }
    };
    Ok(HdrImage {
        width: first.width,
        height: first.height,
        rgb,
        mask,
        info: HdrInfo {
            method: name,
            shutter_s: frames.iter().map(|f| f.sidecar.shutter_s).collect(),
            iso: frames
                .iter()
                .map(|f| f.sidecar.iso.unwrap_or(100.0))
                .collect(),
            theta_l: first.sidecar.theta_l,
            camera: first.sidecar.camera.clone(),
            time: first.sidecar.time.clone(),
        },
    })
}
