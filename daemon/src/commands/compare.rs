//! `gonio compare STANDARD BATCH`: per aspecular angle ΔL*, ΔC*, ΔH*, ΔE00 and the flop
//! index's difference with their uncertainties, and pass / fail / undecided against
//! tolerances per angle (a TOML file, `daemon/assets/tolerances.example.toml`); see
//! `gonio_processing::multi_angle::compare` and docs/ARCHITECTURE.md, "Multi-angle colour".

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use gonio_files::input::{read_input_to_string, MAX_SMALL_FILE_BYTES};
use gonio_files::output::write_atomically;
use gonio_processing::multi_angle::compare::{compare, Comparison, Mounting, Tolerances};

use super::colour::{inputs_of, report, Options};

/// Arguments of `gonio compare`.
#[derive(clap::Args)]
pub struct Args {
    /// The standard: a colour.json, a fit JSON or a scan directory.
    standard: PathBuf,
    /// The batch, likewise.
    batch: PathBuf,
    /// Tolerances per angle (TOML); without it ΔE00 ≤ 1 at every angle.
    #[arg(long)]
    tolerances: Option<PathBuf>,
    #[command(flatten)]
    options: Options,
    /// Also write the comparison as JSON here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Both scans are of one mounting, not moved between them: the errors of the setup's
    /// geometry cancel too (without it, only the white's and the colour transform's do).
    #[arg(long)]
    same_mount: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(out) = &args.out {
        let mut inputs = inputs_of(&args.standard, &args.options);
        inputs.extend(inputs_of(&args.batch, &args.options));
        inputs.extend(args.tolerances.clone());
        super::output::refuse_overwriting(out, &inputs, &[])?;
    }
    let tolerances = match &args.tolerances {
        Some(path) => {
            let text = read_input_to_string(path, MAX_SMALL_FILE_BYTES)
                .with_context(|| format!("reading {}", path.display()))?;
            let t: Tolerances = toml::from_str(&text).map_err(|e| {
                anyhow::anyhow!(
                    "{}: {}",
                    path.display(),
                    gonio_mock_hw::toml_error::one_line(&text, &e)
                )
            })?;
            t.check().with_context(|| path.display().to_string())?;
            t
        }
        None => Tolerances::default(),
    };
    let standard = report(&args.standard, &args.options)
        .with_context(|| format!("standard {}", args.standard.display()))?;
    let batch = report(&args.batch, &args.options)
        .with_context(|| format!("batch {}", args.batch.display()))?;
    let mounting = if args.same_mount {
        Mounting::Same
    } else {
        Mounting::Separate
    };
    let comparison = compare(&standard, &batch, &tolerances, mounting)?;
    if let Some(path) = &args.out {
        let text = serde_json::to_string_pretty(&comparison)? + "\n";
        write_atomically(path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    print!("{}", summary(&comparison));
    Ok(())
}

/// What `gonio compare` prints.
fn summary(c: &Comparison) -> String {
    let mut out = format!(
        "batch − standard, {}, values ± U (k = {})\n  as°   ΔL*             ΔC*             ΔH*             ΔE00            tol   verdict\n",
        c.conditions.name(),
        c.coverage_factor
    );
    for a in &c.angles {
        let _ = write!(out, "{:>5}", a.aspecular);
        for d in [a.delta_l, a.delta_c, a.delta_h, a.delta_e00] {
            let _ = write!(out, " {:>7.2} ± {:<5.2}", d.value, d.expanded);
        }
        let _ = writeln!(out, " {:>5.2} {}", a.tolerance, a.verdict.name());
    }
    if let Some(f) = &c.flop_index {
        let _ = write!(
            out,
            "flop index: standard {:.2}, batch {:.2}, ΔFI {:.2} ± {:.2}",
            f.standard, f.batch, f.delta.value, f.delta.expanded
        );
        match (f.tolerance, f.verdict) {
            (Some(t), Some(v)) => {
                let _ = writeln!(out, " (tolerance {t}: {})", v.name());
            }
            _ => out.push('\n'),
        }
    }
    let _ = writeln!(out, "overall: {}", c.overall.name());
    out
}
