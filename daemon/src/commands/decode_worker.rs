//! `gonio decode-worker`: a child that decodes captures asked for on stdin, under the
//! limits its parent gives (`gonio_server::decode_workers`).

use gonio_server::decode_workers::{self, Limits};

/// Arguments of `gonio decode-worker` (started by the daemon and the commands, not
/// by a user).
#[derive(clap::Args)]
pub struct Args {
    /// Address space limit, bytes.
    #[arg(long)]
    memory_bytes: u64,
    /// Processor time each decode may use, seconds.
    #[arg(long)]
    cpu_seconds: u64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    decode_workers::serve(Limits {
        memory_bytes: args.memory_bytes,
        cpu_seconds: args.cpu_seconds,
    })
}
