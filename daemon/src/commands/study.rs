//! `gonio study` (to be written).

/// Arguments of `gonio study`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio study is not available in this build yet")
}
