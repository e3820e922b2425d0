//! The daemon's two lanes (docs/ARCHITECTURE.md, "Daemon"): the hardware lane owns the
//! arm and the camera and only moves and captures; the processing lane turns captured
//! brackets into results meanwhile. Both work from the journal of steps in the store,
//! each with its own connection; a scan is done when both are.

mod arm_watch;
mod backoff;
mod hardware;
mod processing;
mod step;
mod timing_probe;

use std::path::Path;
use std::sync::Arc;

use anyhow::Context;

use super::devices::Devices;
use super::files::{remove_partials, Writers};
use super::plan::Lane;
use super::shared::Shared;
use super::step_guard;
use super::store::Store;
use hardware::HardwareLane;
use processing::ProcessingLane;

/// Removes the temporary files that writers no longer running left anywhere in the data
/// directory (every scan's, whatever its state, the metering frames, the calibrated
/// setup), then starts both lanes on `devices`, with connections to the database at
/// `db_path`.
pub fn start(shared: Arc<Shared>, devices: Devices, db_path: &Path) -> anyhow::Result<()> {
    let data = &shared.config.data_dir;
    let removed = remove_partials(data, Writers::RunningOthers)
        .with_context(|| format!("cleaning {}", data.display()))?;
    if removed > 0 {
        tracing::info!("{}: removed {removed} partial file(s)", data.display());
    }
    arm_watch::spawn(shared.clone(), devices.arm.path().to_path_buf())?;
    let hardware_store = Store::open(db_path)?;
    let hardware = HardwareLane::new(shared.clone(), hardware_store, devices);
    let probe = shared.clone();
    let processing = ProcessingLane::new(shared, Store::open(db_path)?);
    spawn_watched(Lane::Hardware, move || hardware.run())?;
    spawn_watched(Lane::Processing, move || processing.run())?;
    timing_probe::start(probe)
}

/// Runs `run` on a thread named for `lane`, marked as that lane's. A lane only ends by
/// panicking: then the fault is recorded against it and the process ends too, so that
/// a supervisor restarts it and the journal resumes the scans, rather than serve
/// without it.
fn spawn_watched(lane: Lane, run: impl FnOnce() + Send + 'static) -> anyhow::Result<()> {
    let name = lane.name();
    let thread = std::thread::Builder::new()
        .name(name.to_owned())
        .spawn(move || {
            step_guard::mark_lane(lane);
            run()
        })
        .with_context(|| format!("starting the {name} lane"))?;
    std::thread::Builder::new()
        .name(format!("{name}-watch"))
        .spawn(move || {
            let _ = thread.join();
            step_guard::record_lane_death(lane);
            tracing::error!("the {name} lane stopped; exiting");
            std::process::exit(2);
        })
        .context("starting a lane watch thread")?;
    Ok(())
}
