//! A scan as the API shows it (docs/ARCHITECTURE.md, "HTTP API"), and the publisher
//! thread that sends it to event subscribers whenever it changes: the lanes only say
//! which scan changed, so they never wait for a view to be built. A scan that reached
//! a final state is cleared of leftover temporary files as it is published, and what
//! calls for a person is noticed (`notices`).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use serde_json::{json, Value};

use super::files::{remove_partials, Writers};
use super::notices::Notices;
use super::notify::Notifier;
use super::plan::{theta_dir_name, theta_map_path, Step, AUTO_FIT, FIT_MODELS};
use super::progress::{metered_bracket, progress};
use super::shared::{ScanEvent, Shared};
use super::store::{ScanRecord, ScanState, StepRecord, StepState, Store, StoreError};

/// How long the publisher sleeps when nothing changes (it then looks again).
const PUBLISHER_POLL: Duration = Duration::from_secs(5);

/// Unix seconds as RFC 3339.
pub fn rfc3339(unix: i64) -> Option<String> {
    time::OffsetDateTime::from_unix_timestamp(unix)
        .ok()?
        .format(&time::format_description::well_known::Rfc3339)
        .ok()
}

/// The states each control verb applies to; a scan's JSON lists the verbs its state
/// allows (`actions`), so that the page offers only those.
pub const CONTROLS: [(&str, &[ScanState]); 3] = [
    (
        "pause",
        &[
            ScanState::Queued,
            ScanState::Running,
            ScanState::Interrupted,
            ScanState::Waiting,
        ],
    ),
    // Re-queues a paused or waiting scan, or retries a failed one from its first step
    // not done.
    (
        "resume",
        &[ScanState::Paused, ScanState::Failed, ScanState::Waiting],
    ),
    (
        "cancel",
        &[
            ScanState::Queued,
            ScanState::Running,
            ScanState::Paused,
            ScanState::Interrupted,
            ScanState::Waiting,
        ],
    ),
];

/// The control routes a scan's state allows; while it waits for its sample to be
/// mounted only `cancel` and `confirm` (pausing or resuming would not end the wait).
fn actions(scan: &ScanRecord) -> Vec<&'static str> {
    let waits_for_sample = scan.waits_for_sample();
    let mut verbs: Vec<&str> = CONTROLS
        .iter()
        .filter(|(verb, from)| {
            from.contains(&scan.state) && (!waits_for_sample || *verb == "cancel")
        })
        .map(|(verb, _)| *verb)
        .collect();
    if waits_for_sample {
        verbs.push("confirm");
    }
    verbs
}

/// The states control `verb` applies to (none for an unknown verb).
pub fn applies_to(verb: &str) -> &'static [ScanState] {
    CONTROLS
        .iter()
        .find(|(name, _)| *name == verb)
        .map_or(&[], |(_, from)| from)
}

/// The JSON of a scan: record, progress, links to its results that exist. With
/// `detail`, or while the scan is active (not queued, not final), also what its
/// journal tells: θL captured and processed, the processing step, the time left and
/// the live fits.
pub fn scan_view(
    shared: &Shared,
    store: &Store,
    scan: &ScanRecord,
    detail: bool,
) -> Result<Value, StoreError> {
    let base = format!("/api/scans/{}", scan.id);
    let dir = shared.scan_dir(scan.id);
    let file = |rel: &str| {
        dir.join(rel)
            .is_file()
            .then(|| format!("{base}/files/{rel}"))
    };
    let fits: serde_json::Map<String, Value> = FIT_MODELS
        .iter()
        .filter_map(|(model, name)| file(name).map(|url| ((*model).to_owned(), json!(url))))
        .collect();
    let hdr: Vec<String> = scan
        .plan
        .theta_l
        .iter()
        .filter_map(|t| file(&theta_map_path(*t)))
        .collect();
    // A frame to preview once a capture has landed in a θL directory.
    let has_frame = scan.plan.theta_l.iter().any(|t| {
        std::fs::read_dir(dir.join(theta_dir_name(*t))).is_ok_and(|entries| {
            entries
                .flatten()
                .any(|e| !e.file_name().to_string_lossy().starts_with('.'))
        })
    });
    let active = !(scan.state == ScanState::Queued || scan.state.is_final());
    // The journal: an automatic bracket as its metering steps chose it, the latest
    // frame and the model chosen (in the list as in the scan's own view, ended or
    // not), and what a scan under way is doing.
    let steps = store.steps(scan.id)?;
    // The time left of a running scan also learns from the previous scan that ended
    // done (the kinds of step this one has not measured yet).
    let earlier = match scan.state {
        ScanState::Running => match store.last_done_before(scan.id)? {
            Some(done) => store.steps(done.id)?,
            None => Vec::new(),
        },
        _ => Vec::new(),
    };
    let journal = (detail || active).then(|| {
        let now = time::OffsetDateTime::now_utc();
        progress(&steps, &earlier, &shared.timing_now(), now)
    });
    // Time left only while the scan runs: a queued, paused, waiting or interrupted
    // scan has no end to count down to.
    let eta_s = journal
        .as_ref()
        .filter(|_| scan.state == ScanState::Running)
        .map(|p| (p.eta_s * 10.0).round() / 10.0);
    let bracket = if scan.plan.auto_bracket {
        auto_bracket_view(&steps)
    } else {
        json!({ "shutter_s": scan.plan.shutter_s, "auto": false })
    };
    // Nothing is under way once the scan has ended.
    let ended = scan.state.is_final();
    // The latest frame's θL and exposure, and the model the `auto` fit chose, as the
    // journal's steps that made them recorded them.
    let frame = latest_frame(&steps).map(|(step, _)| match step.step {
        Step::Capture {
            theta_l, shutter_s, ..
        } => json!({ "theta_l": theta_l, "shutter_s": shutter_s }),
        _ => Value::Null,
    });
    let choice = Some(steps.as_slice())
        .filter(|_| dir.join(AUTO_FIT.1).is_file())
        .and_then(model_choice)
        .map(|mut choice| {
            choice["fit"] = json!(format!("{base}/files/{}", AUTO_FIT.1));
            choice
        });
    Ok(json!({
        "id": scan.id,
        "sample": scan.plan.sample,
        "state": scan.state,
        "error": scan.error,
        "reason": matches!(
            scan.state,
            ScanState::Waiting | ScanState::Interrupted | ScanState::Paused
        )
        .then_some(&scan.error),
        "sweep_id": scan.sweep_id,
        "theta_l": scan.plan.theta_l,
        "bracket": bracket,
        "progress": {
            "done": scan.done,
            "total": scan.total,
            "steps": { "done": scan.steps_done, "total": scan.steps_total },
            "theta_l": journal.as_ref().map(|p| p.theta_l),
            "eta_s": eta_s,
        },
        "actions": actions(scan),
        "current_step": scan.current_step.as_ref().filter(|_| !ended),
        "processing_step": journal
            .as_ref()
            .filter(|_| !ended)
            .and_then(|p| p.processing_step.clone()),
        "live": journal.map(|p| p.live),
        "created": scan.created,
        "started": scan.started,
        "finished": scan.finished,
        "not_before": scan.not_before.and_then(rfc3339),
        "links": {
            "self": base,
            "events": format!("{base}/events"),
            "steps": format!("{base}/steps"),
            "files": format!("{base}/files"),
            "thumbnail": format!("{base}/thumbnail.png"),
            "plot": format!("{base}/plot"),
        },
        "results": {
            "samples": file("samples.csv"),
            "fits": fits,
            "hdr": hdr,
            "thumbnail": has_frame.then(|| format!("{base}/thumbnail.png")),
        },
        "frame": frame,
        "choice": choice,
    }))
}

/// The latest capture done of a scan's journal (the frame its thumbnail shows) and the
/// path of its file in the scan directory.
pub fn latest_frame(steps: &[StepRecord]) -> Option<(&StepRecord, &str)> {
    steps
        .iter()
        .rev()
        .filter(|s| s.state == StepState::Done && matches!(s.step, Step::Capture { .. }))
        .find_map(|s| Some((s, s.result.as_ref()?.get("path")?.as_str()?)))
}

/// The model the `auto` fit chose, from its step's record: the model, its roughness
/// parameterisation, whether a colour shift is reported and the reason in words.
fn model_choice(steps: &[StepRecord]) -> Option<Value> {
    let record = steps
        .iter()
        .rev()
        .filter(|s| s.state == StepState::Done)
        .find(|s| matches!(&s.step, Step::Fit { model } if model == AUTO_FIT.0))?
        .result
        .as_ref()?;
    let model = record.get("model")?;
    Some(json!({
        "model": model,
        "roughness": record.get("roughness"),
        "colour_shift": record.get("colour_shift"),
        "reason": record.get("reason"),
    }))
}

/// The bracket of an automatic scan as its metering steps chose it: every shutter time
/// planned so far (longest first) and each metered θL's own bracket.
fn auto_bracket_view(steps: &[StepRecord]) -> Value {
    let metered: Vec<(f64, Vec<f64>)> = steps
        .iter()
        .filter(|s| s.state == StepState::Done)
        .filter_map(|s| match s.step {
            Step::Meter { theta_l } => Some((theta_l, metered_bracket(s)?)),
            _ => None,
        })
        .collect();
    let mut all: Vec<f64> = metered
        .iter()
        .flat_map(|(_, b)| b.iter().copied())
        .collect();
    all.sort_by(|a, b| b.total_cmp(a));
    all.dedup();
    json!({
        "shutter_s": all,
        "auto": true,
        "by_theta_l": metered
            .iter()
            .map(|(theta_l, bracket)| json!({ "theta_l": theta_l, "shutter_s": bracket }))
            .collect::<Vec<_>>(),
    })
}

/// Starts the publisher: it builds the view of every scan announced as changed
/// ([`Shared::changed`]) with its own connection to the database at `db_path`, and
/// sends it to event subscribers, in the order the changes happened.
/// Each change is also shown to `Notices`, which runs the `[notify]` command on what
/// calls for a person.
pub fn start_publisher(shared: Arc<Shared>, db_path: &Path) -> anyhow::Result<()> {
    let store = Store::open(db_path)?;
    let mut notices = Notices::new(&store, Notifier::start(shared.config.notify.clone())?)?;
    std::thread::Builder::new()
        .name("publisher".into())
        .spawn(move || loop {
            for id in shared.changed.take(PUBLISHER_POLL) {
                if let Err(err) = publish(&shared, &store, &mut notices, id) {
                    tracing::error!("publishing scan {id}: {err}");
                }
            }
        })?;
    Ok(())
}

fn publish(
    shared: &Shared,
    store: &Store,
    notices: &mut Notices,
    id: i64,
) -> Result<(), StoreError> {
    let Some(scan) = store.scan(id)? else {
        return Ok(());
    };
    notices.changed(store, &scan)?;
    if scan.state.is_final() {
        // A scan that ended keeps no temporary of a writer no longer running (a write
        // still in flight, ours included, renames or removes its own).
        let dir = shared.scan_dir(id);
        match remove_partials(&dir, Writers::Running) {
            Ok(0) => {}
            Ok(n) => tracing::info!("scan {id}: removed {n} partial file(s)"),
            Err(err) => tracing::warn!("scan {id}: cleaning {}: {err}", dir.display()),
        }
    }
    let view = scan_view(shared, store, &scan, true)?;
    // No subscriber is not an error.
    let _ = shared.events.send(ScanEvent {
        id,
        state: scan.state,
        view: view.to_string().into(),
    });
    Ok(())
}
