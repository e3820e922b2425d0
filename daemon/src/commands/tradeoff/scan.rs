//! The captures of a simulated scan, and their extraction for a chosen subset of the
//! bracket at one θL (timed: HDR merge + extraction is processing time).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use gonio_processing::capture::{read_sidecar, sidecar_path};
use gonio_processing::extract::{extract_scan, theta_groups, ExtractOptions};
use gonio_processing::samples::Sample;

/// One capture: the image file and its shutter time.
#[derive(Debug, Clone, PartialEq)]
pub struct Exposure {
    pub image: PathBuf,
    pub shutter_s: f64,
}

/// The captures at one arm angle, longest exposure first.
#[derive(Debug, Clone, PartialEq)]
pub struct Position {
    pub theta_l: f64,
    pub exposures: Vec<Exposure>,
}

/// The captures under `dir` grouped by their sidecar's θL (as extraction finds them),
/// positions in descending θL (the scan order −20°, −25°, … of the example scenes).
pub fn discover(dir: &Path) -> anyhow::Result<Vec<Position>> {
    let (groups, _) = theta_groups(dir)?;
    let mut positions = groups
        .into_iter()
        .map(|(theta_l, images)| {
            let exposures = images
                .into_iter()
                .map(|image| {
                    let shutter_s = read_sidecar(&image)?.shutter_s;
                    Ok(Exposure { image, shutter_s })
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            Ok(Position { theta_l, exposures })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    positions.sort_by(|a, b| b.theta_l.total_cmp(&a.theta_l));
    for p in &mut positions {
        p.exposures
            .sort_by(|a, b| b.shutter_s.total_cmp(&a.shutter_s));
    }
    Ok(positions)
}

/// Indices of `k` of `n` items spread evenly over the range: both ends for k ≥ 2, the
/// middle (lower middle for even n) for k = 1. `k` is clamped to `1..=n`.
pub fn spread(n: usize, k: usize) -> Vec<usize> {
    let k = k.clamp(1, n.max(1));
    if k == 1 {
        return vec![(n.max(1) - 1) / 2];
    }
    (0..k)
        .map(|i| ((i * (n - 1)) as f64 / (k - 1) as f64).round() as usize)
        .collect()
}

/// The samples of one θL from a subset of its bracket, with the wall time of the HDR
/// merge and extraction.
#[derive(Debug, Clone)]
pub struct Extracted {
    pub samples: Vec<Sample>,
    pub seconds: f64,
}

fn link_or_copy(from: &Path, to: &Path) -> anyhow::Result<()> {
    if std::fs::hard_link(from, to).is_err() {
        std::fs::copy(from, to)
            .with_context(|| format!("copying {} to {}", from.display(), to.display()))?;
    }
    Ok(())
}

/// Extracts `position` using only the exposures at `chosen` (indices into its
/// exposures): a scan directory holding just those captures is assembled under `work`
/// (hard links, or copies across file systems) with the scan's `setup.json`.
pub fn extract_subset(
    scan_dir: &Path,
    work: &Path,
    position: &Position,
    chosen: &[usize],
    options: &ExtractOptions,
) -> anyhow::Result<Extracted> {
    std::fs::create_dir_all(work).with_context(|| format!("creating {}", work.display()))?;
    link_or_copy(&scan_dir.join("setup.json"), &work.join("setup.json"))?;
    for (n, &i) in chosen.iter().enumerate() {
        let exposure = &position.exposures[i];
        let ext = exposure
            .image
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("tiff");
        let image = work.join(format!("exp_{n:02}.{ext}"));
        link_or_copy(&exposure.image, &image)?;
        link_or_copy(&sidecar_path(&exposure.image), &sidecar_path(&image))?;
    }
    let start = Instant::now();
    let extraction = extract_scan(work, options).with_context(|| {
        format!(
            "extracting θL {}° from {}",
            position.theta_l,
            work.display()
        )
    })?;
    Ok(Extracted {
        samples: extraction.samples,
        seconds: start.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::spread;

    #[test]
    fn spread_keeps_ends_and_centre() {
        assert_eq!(spread(4, 1), vec![1]);
        assert_eq!(spread(4, 2), vec![0, 3]);
        assert_eq!(spread(4, 3), vec![0, 2, 3]);
        assert_eq!(spread(4, 4), vec![0, 1, 2, 3]);
        assert_eq!(spread(6, 3), vec![0, 3, 5]);
        assert_eq!(spread(6, 9), (0..6).collect::<Vec<_>>());
    }
}
