//! `gonio report`: a scan directory's report as one self-contained HTML file.

use std::path::PathBuf;

use anyhow::Context;
use gonio_files::output::write_atomically;
use gonio_report::ScanFacts;

/// Arguments of `gonio report`.
#[derive(clap::Args)]
pub struct Args {
    /// Scan directory: setup.json, plan.json, samples.csv and the fit JSONs.
    pub dir: PathBuf,
    /// Output HTML file.
    #[arg(long)]
    pub out: PathBuf,
    /// Sample name shown, instead of the scene's or the directory's.
    #[arg(long)]
    pub sample: Option<String>,
    /// Notes shown on the report (who sent the sample, its batch, …).
    #[arg(long)]
    pub notes: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !args.dir.is_dir() {
        anyhow::bail!("{}: no such scan directory", args.dir.display());
    }
    let results = super::output::scan_results(&args.dir);
    super::output::refuse_overwriting(&args.out, &results, &[&args.dir])?;
    let facts = ScanFacts {
        sample: args.sample,
        notes: args.notes,
        ..ScanFacts::default()
    };
    let html = gonio_report::render(&args.dir, &facts, env!("CARGO_PKG_VERSION"), &now())?;
    write_atomically(&args.out, html.as_bytes())
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!("report of {} -> {}", args.dir.display(), args.out.display());
    Ok(())
}

/// The time now, RFC 3339 (UTC).
fn now() -> String {
    time::OffsetDateTime::now_utc()
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}
