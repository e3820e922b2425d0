//! `gonio tradeoff` (to be written).

/// Arguments of `gonio tradeoff`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio tradeoff is not available in this build yet")
}
