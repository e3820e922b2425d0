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
    /// Fit a reflection model to a samples CSV, with its uncertainty budget.
    ///
    /// Samples with uncertainty columns (what `gonio extract` writes unless
    /// `--no-uncertainty`) get the fit's uncertainty budget (GUM law of propagation):
    /// each parameter's standard uncertainty by source (noise, misfit, the setup's
    /// standard uncertainties), combined and expanded (k = 2), printed as a table and
    /// kept in the fit JSON under `budget`; `--monte-carlo N` adds the JCGM 101
    /// propagation.
    Fit(commands::fit::Args),
    /// Fit every combination of the θL present and compare against a reference.
    Study(commands::study::Args),
    /// Measure what accuracy costs in acquisition and processing time for a scene.
    Tradeoff(commands::tradeoff::Args),
    /// Serve the GRBL 1.1h emulator alone on a pseudo-terminal, until interrupted.
    EmulateArm(commands::emulate_arm::Args),
    /// Write a fit for a renderer (Mitsuba 3 BSDF) or as a BRDF table.
    Export(commands::export::Args),
    /// Write a scan's report: one self-contained, printable HTML file.
    Report(commands::report::Args),
    /// CIELAB at the standard aspecular angles (45° illumination), with uncertainties.
    Colour(commands::colour::Args),
    /// Judge a batch against its standard: ΔL*, ΔC*, ΔH*, ΔE00, flop index per angle.
    ///
    /// The verdict is printed (`overall: pass` or `fail`) and written with `--out`; the
    /// exit status is 0 whatever it is (non-zero only when the comparison cannot be made).
    Compare(commands::compare::Args),
    /// Decode captures asked for on stdin (a child of the other commands).
    #[command(hide = true)]
    DecodeWorker(commands::decode_worker::Args),
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
        // A child: its parent handles an interrupt.
        Some("decode-worker") => {}
        Some(name) => interrupt::install(name.to_owned()),
    }
    if matches.subcommand_name() != Some("decode-worker") {
        // Captures are decoded in child processes that may die of a file.
        gonio_server::decode_workers::install();
    }
    let outcome = guard::catch(|| match cli.command {
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
        Command::Report(args) => commands::report::run(args),
        Command::Colour(args) => commands::colour::run(args),
        Command::Compare(args) => commands::compare::run(args),
        Command::DecodeWorker(args) => commands::decode_worker::run(args),
    });
    let result = match outcome {
        Ok(result) => result,
        // `println!` panics when its write fails.
        Err(panic) if panic.starts_with("failed printing to stdout") && stdout_closed() => {
            std::process::exit(EXIT_STDOUT_CLOSED)
        }
        Err(panic) => Err(anyhow::anyhow!(
            "internal error (a bug; please report): {panic}"
        )),
    };
    if let Err(err) = result {
        interrupt::yield_to_signal();
        if is_broken_pipe(&err) && stdout_closed() {
            std::process::exit(EXIT_STDOUT_CLOSED);
        }
        // One line, whatever a cause's message holds.
        progress::say(format_args!(
            "error: {}",
            guard::one_line(&with_causes(&err))
        ));
        std::process::exit(1);
    }
}

/// Exit status of a command whose stdout its reader closed (`gonio fit … | head -1`):
/// what a shell reports for a process ended by SIGPIPE (128 + 13). The command stops
/// there, quietly; outputs it wrote before are whole (each is written atomically).
const EXIT_STDOUT_CLOSED: i32 = 141;

/// `err` and its causes, joined by `: `, a cause left out where the text before it says
/// it already (an error whose message includes its source's).
fn with_causes(err: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in err.chain() {
        let said = cause.to_string();
        if text.contains(&said) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&said);
    }
    text
}

/// Whether `err` is, or was caused by, a write to a pipe with no reader.
fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// Whether stdout is a pipe or socket whose reader has gone: `poll` reports an error
/// (or hang-up) condition on it. A terminal, a file or an open pipe report none.
fn stdout_closed() -> bool {
    let mut fd = libc::pollfd {
        fd: libc::STDOUT_FILENO,
        events: 0,
        revents: 0,
    };
    // SAFETY: `fd` is one valid pollfd for the duration of the call; no wait.
    let ready = unsafe { libc::poll(&mut fd, 1, 0) };
    ready == 1 && fd.revents & (libc::POLLERR | libc::POLLHUP) != 0
}
