//! `gonio emulate-arm`: the GRBL 1.1h emulator alone, on a pseudo-terminal whose stable
//! path is `--link`, until interrupted, so an operator can try any GRBL sender or their
//! own scripts against it (115200 8N1, like the real board).

use std::path::{Path, PathBuf};

use anyhow::Context;
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_mock_hw::grbl::{GrblConfig, GrblEmulator};
use gonio_mock_hw::world::World;

use crate::{interrupt, progress};

/// Where the emulated arm starts: 10° below its home switch (θ = 0).
const START_DEG: f64 = -10.0;

/// Arguments of `gonio emulate-arm`.
#[derive(clap::Args)]
pub struct Args {
    /// Path of the device link to create (a symlink to the pseudo-terminal), e.g.
    /// /tmp/ttyGRBL; its directory must exist.
    #[arg(long)]
    link: PathBuf,
    /// Emulator configuration (TOML, every key optional): the board's settings, its
    /// speed (`time_scale`), its homing cycles and scheduled faults. Without it: a stock
    /// GRBL 1.1h board in real time. The arm starts 10° below its home switch.
    #[arg(long)]
    config: Option<PathBuf>,
}

/// Reads and checks an emulator configuration file.
fn load_config(path: &Path) -> anyhow::Result<GrblConfig> {
    let text = read_input_to_string(path, MAX_SMALL_FILE_BYTES)
        .with_context(|| format!("reading emulator config {}", path.display()))?;
    GrblConfig::from_toml_str(&text).with_context(|| format!("emulator config {}", path.display()))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => load_config(path)?,
        None => GrblConfig::default(),
    };
    let time_scale = config.time_scale;
    let emulator = GrblEmulator::start_at(config, World::new(START_DEG), &args.link)
        .with_context(|| format!("starting the emulator at {}", args.link.display()))?;
    let pty = std::fs::read_link(emulator.device_path())
        .map(|p| p.display().to_string())
        .unwrap_or_default();
    println!(
        "GRBL 1.1h emulator on {} ({pty}), 115200 8N1, time scale {time_scale}; Ctrl-C to stop",
        args.link.display()
    );
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()
        .context("starting the signal handler")?;
    let signal = runtime.block_on(interrupt::wait_for_signal());
    drop(emulator);
    progress::say(format_args!(
        "gonio emulate-arm: stopped by {signal}; {} removed",
        args.link.display()
    ));
    Ok(())
}
