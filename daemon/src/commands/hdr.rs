//! `gonio hdr` (to be written).

/// Arguments of `gonio hdr`.
#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("gonio hdr is not available in this build yet")
}
