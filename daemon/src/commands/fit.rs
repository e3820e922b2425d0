//! `gonio fit` (to be written).

/// Arguments of `gonio fit`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio fit is not available in this build yet")
}
