//! A scan as the API shows it (docs/ARCHITECTURE.md, "HTTP API"), and the publisher
//! thread that sends it to event subscribers whenever it changes: the lanes only say
//! which scan changed, so they never wait for a view to be built.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use serde_json::{json, Value};

use super::plan::{theta_dir_name, FIT_MODELS};
use super::progress::progress;
use super::shared::{ScanEvent, Shared};
use super::store::{ScanRecord, ScanState, Store, StoreError};

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
        .filter_map(|t| file(&format!("hdr/{}.exr", theta_dir_name(*t))))
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
    let journal = if detail || active {
        let now = time::OffsetDateTime::now_utc();
        Some(progress(&store.steps(scan.id)?, &shared.timing, now))
    } else {
        None
    };
    let eta_s = journal
        .as_ref()
        .filter(|_| !scan.state.is_final())
        .map(|p| (p.eta_s * 10.0).round() / 10.0);
    Ok(json!({
        "id": scan.id,
        "sample": scan.plan.sample,
        "state": scan.state,
        "error": scan.error,
        "reason": matches!(scan.state, ScanState::Waiting | ScanState::Interrupted)
            .then_some(&scan.error),
        "sweep_id": scan.sweep_id,
        "theta_l": scan.plan.theta_l,
        "bracket": { "shutter_s": scan.plan.shutter_s, "auto": scan.plan.auto_bracket },
        "progress": {
            "done": scan.done,
            "total": scan.total,
            "steps": { "done": scan.steps_done, "total": scan.steps_total },
            "theta_l": journal.as_ref().map(|p| p.theta_l),
            "eta_s": eta_s,
        },
        "actions": CONTROLS
            .iter()
            .filter(|(_, from)| from.contains(&scan.state))
            .map(|(verb, _)| *verb)
            .collect::<Vec<_>>(),
        "current_step": scan.current_step,
        "processing_step": journal.as_ref().and_then(|p| p.processing_step.clone()),
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
    }))
}

/// Starts the publisher: it builds the view of every scan announced as changed
/// ([`Shared::changed`]) with its own connection to the database at `db_path`, and
/// sends it to event subscribers, in the order the changes happened.
pub fn start_publisher(shared: Arc<Shared>, db_path: &Path) -> anyhow::Result<()> {
    let store = Store::open(db_path)?;
    std::thread::Builder::new()
        .name("publisher".into())
        .spawn(move || loop {
            for id in shared.changed.take(PUBLISHER_POLL) {
                if let Err(err) = publish(&shared, &store, id) {
                    tracing::error!("publishing scan {id}: {err}");
                }
            }
        })?;
    Ok(())
}

fn publish(shared: &Shared, store: &Store, id: i64) -> Result<(), StoreError> {
    let Some(scan) = store.scan(id)? else {
        return Ok(());
    };
    let view = scan_view(shared, store, &scan, true)?;
    // No subscriber is not an error.
    let _ = shared.events.send(ScanEvent {
        id,
        state: scan.state,
        view: view.to_string().into(),
    });
    Ok(())
}
