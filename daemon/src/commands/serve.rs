//! `gonio serve` (to be written).

/// Arguments of `gonio serve`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio serve is not available in this build yet")
}
