//! `gonio simulate` (to be written).

/// Arguments of `gonio simulate`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio simulate is not available in this build yet")
}
