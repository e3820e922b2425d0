//! `gonio serve`: the measurement daemon (the `gonio-server` crate), logging to stderr
//! and stopped by SIGINT or SIGTERM.

use std::path::PathBuf;

use crate::interrupt::wait_for_signal;

/// Arguments of `gonio serve`.
#[derive(clap::Args)]
pub struct Args {
    /// Configuration file (TOML, every key optional); without one the daemon runs on
    /// emulated hardware with the builtin `gold` scene.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Listen address (default 127.0.0.1:8080; port 0 picks a free port).
    #[arg(long)]
    bind: Option<std::net::SocketAddr>,
    /// Data directory: database, token, scans (default ./gonio-data).
    #[arg(long)]
    data: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        // Colours only for a person at a terminal: plain text in files and journals.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let options = gonio_server::Options {
        config: args.config,
        bind: args.bind,
        data: args.data,
    };
    gonio_server::run(options, wait_for_signal())
}
