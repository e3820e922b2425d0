//! The timing probe (server/src/daemon.md, "Time left"): what processing costs on this
//! machine, measured once per data directory by running the processing steps
//! themselves on a small synthetic scan (the builtin gold scene binned to a sixteenth
//! of its pixels, three θL, two exposures each; the automatic choice also on half
//! its points), then cached in
//! DATA/processing-costs.json. It runs on a thread of its own at the processing lane's
//! lower priority, beside the lanes, never before them; it gives up past
//! [`BUDGET`] (the stated defaults stay, and the next start measures again).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use gonio_mock_hw::render::render_frame;
use gonio_mock_hw::scene::Scene;
use gonio_processing::capture::{Frame, Sidecar};
use gonio_processing::samples::{read_csv, write_csv, Sample};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::processing::lower_priority;
use crate::devices::SceneFacts;
use crate::files::write_atomic;
use crate::fit_cache::Budgets;
use crate::plan::{exposure_stem, theta_dir_name, ScanPlan, Step, AUTO_FIT, FIT_MODELS};
use crate::process::{self, Prefetched};
use crate::shared::Shared;
use crate::store::now_rfc3339;
use crate::timing::Costs;

/// The cache of the measured costs in the data directory.
const CACHE_FILE: &str = "processing-costs.json";
/// Where the synthetic scan is made, removed after.
const WORK_DIR: &str = ".timing-probe";
/// Version of the cache's contents: a cache of another version is measured again.
const VERSION: u32 = 3;
/// The synthetic scan: the builtin gold scene binned by this factor…
const BINNING: u32 = 4;
/// …at these θL (three, so that the automatic choice holds each out in turn)…
const THETA_L: [f64; 3] = [-20.0, -30.0, -40.0];
/// …with these exposures, seconds.
const BRACKET_S: [f64; 2] = [0.5, 0.02];
/// The most the probe may take, wall-clock; past it the defaults stay.
const BUDGET: Duration = Duration::from_secs(90);

/// What DATA/processing-costs.json holds.
#[derive(Debug, Serialize, Deserialize)]
struct Cache {
    version: u32,
    /// When the costs were measured (RFC 3339).
    measured: String,
    /// Wall seconds the probe took.
    took_s: f64,
    costs: Costs,
}

/// Sets `shared.costs` from the data directory's cache, or starts the probe that
/// measures and caches them unless `[processing] timing_probe` is off (the stated
/// defaults hold until it is done).
pub fn start(shared: Arc<Shared>) -> anyhow::Result<()> {
    let data = shared.config.data_dir.clone();
    if let Some(costs) = read_cache(&data.join(CACHE_FILE)) {
        let _ = shared.costs.set(costs);
        return Ok(());
    }
    if !shared.config.processing.timing_probe {
        return Ok(());
    }
    std::thread::Builder::new()
        .name("timing-probe".to_owned())
        .spawn(move || {
            lower_priority();
            let threads = std::thread::available_parallelism().map_or(2, |n| n.get()) + 1;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .thread_name(|n| format!("timing-probe-{n}"))
                .start_handler(|_| lower_priority())
                .build();
            let measured = match pool {
                Ok(pool) => {
                    let measured = pool.install(|| measure_and_cache(&data));
                    // The decoding children its threads started die with the thread
                    // that started them (and serve other threads meanwhile): the
                    // pool's idle threads stay.
                    std::mem::forget(pool);
                    measured
                }
                Err(err) => Err(anyhow::anyhow!("its thread pool: {err}")),
            };
            match measured {
                Ok(costs) => {
                    let _ = shared.costs.set(costs);
                }
                Err(err) => tracing::warn!(
                    "timing probe: {err:#}; time left uses the stated processing costs"
                ),
            }
        })
        .context("starting the timing probe")?;
    Ok(())
}

/// The costs cached at `path`, if it holds valid ones of this version.
fn read_cache(path: &Path) -> Option<Costs> {
    let text = std::fs::read(path).ok()?;
    let cache: Cache = serde_json::from_slice(&text).ok()?;
    (cache.version == VERSION && cache.costs.is_valid()).then_some(cache.costs)
}

/// Measures the costs in `data`'s work directory (removed after) and caches them.
fn measure_and_cache(data: &Path) -> anyhow::Result<Costs> {
    let dir = data.join(WORK_DIR);
    let _ = std::fs::remove_dir_all(&dir);
    let started = Instant::now();
    let measured = measure(&dir, started);
    let _ = std::fs::remove_dir_all(&dir);
    let costs = measured?;
    let took_s = started.elapsed().as_secs_f64();
    let cache = Cache {
        version: VERSION,
        measured: now_rfc3339(),
        took_s,
        costs,
    };
    write_atomic(&data.join(CACHE_FILE), &serde_json::to_vec_pretty(&cache)?)
        .context(CACHE_FILE)?;
    tracing::info!("timing probe: processing costs measured in {took_s:.1} s: {costs:?}");
    Ok(costs)
}

/// Seconds `work` takes; an error past the probe's budget (counted from `started`).
fn timed<T>(
    started: Instant,
    what: &str,
    work: impl FnOnce() -> anyhow::Result<T>,
) -> anyhow::Result<(f64, T)> {
    if started.elapsed() > BUDGET {
        anyhow::bail!("over its budget of {BUDGET:?} before {what}");
    }
    let at = Instant::now();
    let value = work().with_context(|| what.to_owned())?;
    Ok((at.elapsed().as_secs_f64(), value))
}

/// Makes the synthetic scan in `dir` and times each processing step on it.
fn measure(dir: &Path, started: Instant) -> anyhow::Result<Costs> {
    let mut scene = Scene::builtin("gold")
        .context("the builtin gold scene")?
        .binned(BINNING)?;
    scene.set_theta_l_deg(THETA_L.to_vec())?;
    let facts = SceneFacts::of(&scene)?;
    let (width, height) = (facts.setup.image_width, facts.setup.image_height);
    let mpx = f64::from(width) * f64::from(height) / 1e6;
    write_atomic(&dir.join("setup.json"), &serde_json::to_vec(&facts.setup)?)?;
    let mut frame_s = 0.0;
    for theta_l in THETA_L {
        for (index, shutter_s) in BRACKET_S.into_iter().enumerate() {
            let stem = dir.join(theta_dir_name(theta_l)).join(exposure_stem(index));
            let (took, ()) = timed(started, "rendering a frame", || {
                write_frame(&scene, &facts, &stem, theta_l, shutter_s)
            })?;
            frame_s += took;
        }
    }
    let plan = ScanPlan {
        sample: "probe".to_owned(),
        theta_l: THETA_L.to_vec(),
        shutter_s: BRACKET_S.to_vec(),
        auto_bracket: false,
    };
    // Reading a frame whole, as the metering step does.
    let first = dir
        .join(theta_dir_name(THETA_L[0]))
        .join(format!("{}.tiff", exposure_stem(0)));
    let (read_s, _) = timed(started, "reading a frame", || {
        Frame::read(&first).map_err(anyhow::Error::from)
    })?;
    let mut prefetched = Prefetched::default();
    // The fits share their budgets as the lane's do.
    let budgets = Budgets::default();
    let mut run = |step: Step| {
        timed(started, &step.describe(), || {
            process::run(&step, dir, &plan, &mut prefetched, &budgets)
        })
    };
    // Per θL: the samples step's extraction (as it reports it) and live fits (the
    // rest of its seconds, over the points fitted so far), the merges.
    let (mut extraction_s, mut live_s, mut fitted, mut hdr_s, mut points) =
        (0.0, 0.0, 0.0, 0.0, 0.0);
    for theta_l in THETA_L {
        let (took, result) = run(Step::Samples { theta_l })?;
        points += result.get("samples").and_then(Value::as_f64).unwrap_or(0.0);
        let extract_s = result
            .get("extract_s")
            .and_then(Value::as_f64)
            .unwrap_or(took)
            .clamp(0.0, took);
        extraction_s += extract_s;
        live_s += took - extract_s;
        fitted += points;
        hdr_s += run(Step::Hdr { theta_l })?.0;
    }
    let extract_s = run(Step::Extract)?.0;
    let mut fit_s = [0.0; 3];
    for (slot, (model, _)) in fit_s.iter_mut().zip(FIT_MODELS) {
        *slot = run(Step::Fit {
            model: model.to_owned(),
        })?
        .0;
    }
    let auto = Step::Fit {
        model: AUTO_FIT.0.to_owned(),
    };
    let auto_s = run(auto.clone())?.0;
    // The automatic choice again on every other point: what it costs per point and
    // what it costs whatever the points.
    let all = dir.join("samples.csv");
    let every_other: Vec<Sample> = read_csv(&all)?.into_iter().step_by(2).collect();
    write_csv(&all, &every_other)?;
    let half_s = run(auto)?.0;
    anyhow::ensure!(points > 0.0, "the synthetic scan gave no samples");
    let thetas = THETA_L.len() as f64;
    let bracket_mpx = mpx * BRACKET_S.len() as f64;
    // A samples step = extraction (∝ the bracket's columns: it reads the strip rows)
    // + live fits (∝ the points so far).
    let live = if fitted > 0.0 { live_s / fitted } else { 0.0 };
    let extraction = extraction_s / thetas;
    let half = every_other.len() as f64;
    let auto_per_point = ((auto_s - half_s) / (points - half)).max(0.0);
    let auto_per_point = if auto_per_point.is_finite() {
        auto_per_point
    } else {
        auto_s / points
    };
    let costs = Costs {
        frame_s_per_mpx: frame_s / (thetas * BRACKET_S.len() as f64 * mpx),
        read_s_per_mpx: read_s / mpx,
        hdr_s_per_mpx_frame: hdr_s / (thetas * bracket_mpx),
        extraction_s_per_column_frame: extraction / (BRACKET_S.len() as f64 * f64::from(width)),
        live_fit_s_per_point: live,
        points_per_column: points / (thetas * f64::from(width)),
        extract_s_per_point: extract_s / points,
        fit_s_per_point: fit_s.map(|s| s / points),
        auto_s_per_point: auto_per_point,
        auto_s: (auto_s - auto_per_point * points).max(0.0),
    };
    anyhow::ensure!(costs.is_valid(), "costs out of range: {costs:?}");
    Ok(costs)
}

/// Renders exposure `shutter_s` of `scene` at θL and writes it as `stem`.tiff with its
/// sidecar, as the emulated camera's captures are written.
fn write_frame(
    scene: &Scene,
    facts: &SceneFacts,
    stem: &Path,
    theta_l: f64,
    shutter_s: f64,
) -> anyhow::Result<()> {
    let image = PathBuf::from(format!("{}.tiff", stem.display()));
    if let Some(parent) = image.parent() {
        std::fs::create_dir_all(parent)?;
    }
    render_frame(scene, theta_l, shutter_s).write_tiff(&image)?;
    let sidecar = Sidecar {
        shutter_s,
        iso: Some(f64::from(scene.camera().iso)),
        theta_l,
        camera: scene.camera().model.clone(),
        time: now_rfc3339(),
        black_level: facts.sidecar.black_level,
        white_level: facts.sidecar.white_level,
        response: facts.sidecar.response,
        significant_bits: facts.sidecar.significant_bits,
        aperture: None,
        width: None,
        height: None,
    };
    write_atomic(
        &stem.with_extension("json"),
        &serde_json::to_vec_pretty(&sidecar)?,
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_probe_measures_every_cost_and_cleans_up() {
        let data = std::env::temp_dir().join(format!("gonio-probe-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&data);
        std::fs::create_dir_all(&data).unwrap();
        let costs = measure_and_cache(&data).unwrap();
        assert!(costs.is_valid(), "{costs:?}");
        assert!(costs.hdr_s_per_mpx_frame > 0.0 && costs.fit_s_per_point[0] > 0.0);
        assert!(costs.read_s_per_mpx > 0.0 && costs.extraction_s_per_column_frame > 0.0);
        assert!(costs.points_per_column > 0.0 && costs.points_per_column < 2.0);
        assert_eq!(read_cache(&data.join(CACHE_FILE)), Some(costs));
        assert!(!data.join(WORK_DIR).exists());
        // A cache that does not parse, or holds a cost out of range, is not taken.
        std::fs::write(data.join(CACHE_FILE), "{").unwrap();
        assert_eq!(read_cache(&data.join(CACHE_FILE)), None);
        let _ = std::fs::remove_dir_all(&data);
    }
}
