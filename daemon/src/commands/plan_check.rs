//! The offline commands' check of a scan directory against its plan (`plan.json`): a
//! missing θL or frame stops them with one line naming it, unless `--allow-missing`.

use std::path::Path;

use gonio_processing::scan_plan;

use crate::progress;

/// Refuses `dir` when it lacks a planned θL or frame, or holds half a frame (an image
/// without its sidecar, a sidecar without its image); with `allow_missing`, says what is
/// missing on stderr and goes on. A directory without a plan is checked for half frames
/// only ([`say_if_unplanned`]).
pub fn require_whole(dir: &Path, allow_missing: bool) -> anyhow::Result<()> {
    let gaps = scan_plan::gaps(dir)?;
    if gaps.is_empty() {
        return Ok(());
    }
    let what = scan_plan::describe(&gaps);
    if allow_missing {
        progress::say(format_args!(
            "warning: {}: going on without {what}",
            dir.display()
        ));
        return Ok(());
    }
    anyhow::bail!(
        "{}: incomplete scan: {what} (--allow-missing to go on without)",
        dir.display()
    )
}

/// Says on stderr, once a command's work is done, that `dir` has no plan, so that
/// whether it held every θL and frame was not checked.
pub fn say_if_unplanned(dir: &Path) {
    if matches!(scan_plan::ScanPlan::read(dir), Ok(None)) {
        progress::say(format_args!(
            "warning: {}: no {}: whether every θL and frame was here is not checked",
            dir.display(),
            scan_plan::PLAN_FILE
        ));
    }
}

/// For samples of a scan directory (`DIR/samples.csv` beside `DIR/plan.json`): the θL
/// the plan names that `present` lacks, refused unless `allow_missing` as above.
pub fn require_planned_theta_l(
    samples: &Path,
    present: &[f64],
    allow_missing: bool,
) -> anyhow::Result<()> {
    let Some(dir) = samples.parent() else {
        return Ok(());
    };
    let Some(plan) = scan_plan::ScanPlan::read(dir)? else {
        return Ok(());
    };
    let missing: Vec<String> = plan
        .missing_theta_l(present)
        .iter()
        .map(|t| format!("{t:.1}°"))
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    let what = format!(
        "θL {} of {} (its plan.json)",
        missing.join(", "),
        dir.join(scan_plan::PLAN_FILE).display()
    );
    if allow_missing {
        progress::say(format_args!(
            "warning: {}: going on without {what}",
            samples.display()
        ));
        return Ok(());
    }
    anyhow::bail!(
        "{}: samples lack {what} (--allow-missing to go on without)",
        samples.display()
    )
}
