//! What the web page shows of a scan: a small PNG of a frame, and the measured samples
//! with the fitted models' predictions.

use std::io::Cursor;
use std::path::Path;

use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_processing::capture::{CaptureError, Frame};
use gonio_processing::fit::FitResult;
use image::{ImageBuffer, Rgb};
use serde_json::{json, Value};

use super::plan::FIT_MODELS;

/// Longest side of a thumbnail, pixels.
const THUMBNAIL_SIZE: u32 = 360;

/// Errors of the previews.
#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    #[error("{path}: {error}")]
    Image {
        path: String,
        error: image::ImageError,
    },
    #[error("{0}")]
    Processing(String),
}

/// A PNG thumbnail of a capture (TIFF or camera raw, with its sidecar): downscaled,
/// black level removed, normalised to its 99.5th percentile and gamma-encoded so dark
/// frames stay visible. Only about twice as many rows as the thumbnail has are read
/// (evenly spaced; a striped TIFF decodes only their strips), so the memory it takes is
/// a few rows' worth, not the frame's.
pub fn thumbnail_png(path: &Path) -> Result<Vec<u8>, PreviewError> {
    let image_err = |error| PreviewError::Image {
        path: path.display().to_string(),
        error,
    };
    let mut full = (1usize, 1usize);
    let capture = Frame::read_rows(path, |width, height| {
        full = (width, height);
        let step = (height / (2 * THUMBNAIL_SIZE as usize)).max(1);
        Ok::<_, CaptureError>((0..height).step_by(step).map(|y| y..y + 1).collect())
    })
    .map_err(|e| PreviewError::Processing(e.to_string()))?;
    let black = capture.black_level.clamp(0.0, f64::from(u16::MAX)) as u16;
    let mut counts = capture.data;
    for value in &mut counts {
        *value = value.saturating_sub(black);
    }
    let frame: ImageBuffer<Rgb<u16>, Vec<u16>> =
        ImageBuffer::from_raw(capture.width as u32, capture.height as u32, counts).ok_or_else(
            || PreviewError::Processing(format!("{}: inconsistent frame size", path.display())),
        )?;
    // The frame's own proportions, whichever rows were read.
    let (full_width, full_height) = (full.0.max(1) as u64, full.1 as u64);
    let width = THUMBNAIL_SIZE.min(frame.width()).max(1);
    let height = ((u64::from(width) * full_height) / full_width).clamp(1, u64::from(u32::MAX));
    let small = image::imageops::thumbnail(&frame, width, height as u32);
    let mut values: Vec<u16> = small.as_raw().clone();
    let top = if values.is_empty() {
        1.0
    } else {
        let k = (values.len() - 1) * 995 / 1000;
        f64::from(*values.select_nth_unstable(k).1).max(1.0)
    };
    let out: ImageBuffer<Rgb<u8>, Vec<u8>> =
        ImageBuffer::from_fn(small.width(), small.height(), |x, y| {
            let p = small.get_pixel(x, y);
            Rgb(p.0.map(|v| {
                let linear = (f64::from(v) / top).clamp(0.0, 1.0);
                (255.0 * linear.powf(1.0 / 2.2)).round() as u8
            }))
        });
    let mut png = Vec::new();
    out.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(image_err)?;
    Ok(png)
}

/// The samples of a scan (`samples.csv`) and, per fitted model, its parameters and the
/// β it predicts at each sample's angles.
pub fn plot_data(dir: &Path) -> Result<Value, PreviewError> {
    let samples = gonio_processing::samples::read_csv(&dir.join("samples.csv"))
        .map_err(|e| PreviewError::Processing(e.to_string()))?;
    let mut fits = serde_json::Map::new();
    for (model, name) in FIT_MODELS {
        let path = dir.join(name);
        let Ok(text) = read_input_to_string(&path, MAX_SMALL_FILE_BYTES) else {
            continue;
        };
        let fit: FitResult = serde_json::from_str(&text)
            .map_err(|e| PreviewError::Processing(format!("{name}: {e}")))?;
        let predicted: Vec<[f64; 3]> = samples
            .iter()
            .map(|s| fit.predict(s.theta_i, s.theta_r))
            .collect();
        let params = serde_json::to_value(&fit)
            .map_err(|e| PreviewError::Processing(format!("{name}: {e}")))?;
        fits.insert(
            model.to_owned(),
            json!({ "params": params, "predicted": predicted }),
        );
    }
    Ok(json!({
        "samples": samples.iter().map(|s| json!({
            "theta_l": s.theta_l, "theta_i": s.theta_i, "theta_r": s.theta_r, "rgb": s.rgb,
        })).collect::<Vec<_>>(),
        "fits": fits,
    }))
}
