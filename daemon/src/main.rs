//! `gonio`: the measurement daemon (`serve`) and the offline processing commands.

mod commands;
mod interrupt;
mod progress;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use gonio_processing::guard;

/// Image-based BRDF measurement: acquire, process, emulate.
#[derive(Parser)]
#[command(name = "gonio", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the measurement daemon (HTTP API and web page).
    Serve(commands::serve::Args),
    /// Render the captures a scan of a scene would produce, plus truth and reference.
    Simulate(commands::simulate::Args),
    /// Merge a bracket of exposures into an HDR radiance map (OpenEXR).
    Hdr(commands::hdr::Args),
    /// Turn the captures of a scan into a samples CSV.
    Extract(commands::extract::Args),
    /// Estimate a scan's setup (strip rows, camera offset, cylinder tilt, arm zero) from its captures.
    Calibrate(commands::calibrate::Args),
    /// Fit a reflection model to a samples CSV.
    Fit(commands::fit::Args),
    /// Fit every combination of the θL present and compare against a reference.
    Study(commands::study::Args),
    /// Measure what accuracy costs in acquisition and processing time for a scene.
    Tradeoff(commands::tradeoff::Args),
    /// Serve the GRBL 1.1h emulator alone on a pseudo-terminal, until interrupted.
    EmulateArm(commands::emulate_arm::Args),
    /// Write a fit for a renderer (Mitsuba 3 BSDF) or as a BRDF table.
    Export(commands::export::Args),
}

fn main() {
    // A panic that a decoder catches itself, or that the guard below turns into an
    // error, prints nothing: the one-line error says it.
    guard::install_quiet_panic_hook();
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|err| err.exit());
    match matches.subcommand_name() {
        // Servers: an interrupt is how they end; they handle it themselves.
        Some("serve" | "emulate-arm") | None => {}
        Some(name) => interrupt::install(name.to_owned()),
    }
    let result = guard::catch(|| match cli.command {
        Command::Serve(args) => commands::serve::run(args),
        Command::Simulate(args) => commands::simulate::run(args),
        Command::Hdr(args) => commands::hdr::run(args),
        Command::Extract(args) => commands::extract::run(args),
        Command::Calibrate(args) => commands::calibrate::run(args),
        Command::Fit(args) => commands::fit::run(args),
        Command::Study(args) => commands::study::run(args),
        Command::Tradeoff(args) => commands::tradeoff::run(args),
        Command::EmulateArm(args) => commands::emulate_arm::run(args),
        Command::Export(args) => commands::export::run(args),
    })
    .unwrap_or_else(|panic| {
        Err(anyhow::anyhow!(
            "internal error (a bug; please report): {panic}"
        ))
    });
    if let Err(err) = result {
        // One line, whatever a cause's message holds.
        eprintln!("error: {}", guard::one_line(&format!("{err:#}")));
        std::process::exit(1);
    }
}
