//! `gonio extract` (to be written).

/// Arguments of `gonio extract`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio extract is not available in this build yet")
}
