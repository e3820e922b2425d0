//! The shapes of the JSON the HTTP API reads and writes field by field rather than
//! through a Rust type: request bodies (checked in `validate`, which names the field
//! at fault) and the views of a scan and a sweep (built as JSON in `view` and
//! `api`). They exist for the OpenAPI description (`GET /api/openapi.json`), and a
//! client of the API may deserialize the answers into them.

use serde::{Deserialize, Serialize};
use serde_json::Value;
use utoipa::ToSchema;

use crate::store::ScanState;

/// `POST /api/scans`: a scan of one sample at the light angles θL.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ScanRequest {
    /// The sample's name: letters, digits, `.`, `-`, `_`, at most 64.
    #[schema(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,63}$")]
    pub sample: String,
    /// Light angles θL in degrees (1 to 181), inside the soft limits, distinct (to 0.1°,
    /// as their directories are named).
    #[schema(min_items = 1, max_items = 181)]
    pub theta_l: Vec<f64>,
    /// The exposures at each θL (default: the configured bracket).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bracket: Option<Bracket>,
}

/// The exposures at each θL: chosen by metering (`"auto"`) or given.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(untagged)]
pub enum Bracket {
    /// `"auto"`: a metering capture at each θL chooses its shutter times.
    Auto(Metered),
    /// The shutter times given.
    Given(GivenBracket),
}

/// The word `"auto"`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Metered {
    Auto,
}

/// Shutter times given for every θL.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GivenBracket {
    /// Seconds (1 to 32), within the camera's range.
    #[schema(min_items = 1, max_items = 32)]
    pub shutter_s: Vec<f64>,
}

/// `POST /api/sweeps`: samples × θL sets × repeats scans, queued together.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SweepRequest {
    /// The samples, in order.
    #[schema(min_items = 1)]
    pub samples: Vec<String>,
    /// Each set of light angles θL (degrees) every sample is scanned at.
    #[schema(min_items = 1)]
    pub theta_l_sets: Vec<Vec<f64>>,
    /// How often each scan is repeated (default 1; at most 1000, and 1000 scans in all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(minimum = 1, maximum = 1000)]
    pub repeats: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bracket: Option<Bracket>,
    /// No scan of the sweep starts before this time (RFC 3339).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(format = DateTime)]
    pub start_at: Option<String>,
}

/// `POST /api/arm/position`: where the arm is.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ArmPosition {
    /// θL of the arm now, degrees, on the arm's travel [−arm.max_travel_deg, 0] (else
    /// 422).
    pub angle: f64,
}

/// A scan as the API shows it (`GET /api/scans/{id}`, the lists, the events).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[schema(as = Scan)]
pub struct ScanView {
    pub id: i64,
    pub sample: String,
    pub state: ScanState,
    /// Why it failed, was interrupted, stopped or waits.
    pub error: Option<String>,
    /// Set on every waiting or interrupted scan: why (the same text as error). `mount
    /// sample <name>`: the sweep stops for a sample change (the scan's sample is not
    /// known to be on the cylinder); it goes on after POST /api/scans/{id}/confirm.
    /// `disk full: …`: the data directory lacks space; the scan goes on by itself once
    /// there is. Otherwise why the arm or camera cannot serve the scan yet (refused
    /// with each differing setting, homing failed with GRBL's alarm and advice,
    /// position not declared, a device not available); it is queued again when the
    /// arm reconnects, its position is declared, or the scan is resumed. Interrupted:
    /// the device lost; the scan resumes once it is back. A scan waiting on the arm
    /// holds the later scans of its sweep (they stay queued). Paused by an emergency
    /// stop (POST /api/arm/stop): `emergency stop by the operator`; null after the
    /// operator's own pause.
    pub reason: Option<String>,
    pub sweep_id: Option<i64>,
    /// Light angles θL, degrees.
    pub theta_l: Vec<f64>,
    pub bracket: BracketView,
    pub progress: ScanProgress,
    /// The control routes (`POST /api/scans/{id}/<action>`) the scan's state allows:
    /// `pause`, `resume`, `cancel`; only `cancel` and `confirm` while it waits for its
    /// sample to be mounted.
    pub actions: Vec<String>,
    /// The hardware step under way or next, else the processing one; null once the
    /// scan has ended.
    pub current_step: Option<String>,
    /// The processing step under way; null once the scan has ended.
    pub processing_step: Option<String>,
    /// The live fits after each θL, in order (null in lists for queued and finished
    /// scans).
    pub live: Option<Vec<LiveFit>>,
    /// When it was queued (RFC 3339).
    pub created: String,
    pub started: Option<String>,
    pub finished: Option<String>,
    /// A sweep's start time: the scan is not started before it (UTC, RFC 3339).
    pub not_before: Option<String>,
    /// URLs of the scan's routes: `self`, `events`, `steps`, `files`, `thumbnail`,
    /// `plot`.
    pub links: std::collections::BTreeMap<String, String>,
    pub results: ScanResults,
    /// The latest frame's θL and shutter time, from the capture step that took it; null
    /// before the first capture.
    pub frame: Option<FrameView>,
    /// The model the auto fit chose (fit-auto.json); null until that fit is done.
    pub choice: Option<ChoiceView>,
}

/// The latest frame of a scan.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FrameView {
    /// Light angle, degrees.
    pub theta_l: f64,
    /// Shutter time, s.
    pub shutter_s: f64,
}

/// The model choice of a scan's auto fit.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ChoiceView {
    /// The model chosen (`cook-torrance`, `ward`, `cook-torrance-fresnel`, `table`).
    pub model: String,
    /// Its roughness form (`shared` or `per-channel`), as the fit JSON writes it (null
    /// where a fit JSON has none).
    #[schema(value_type = Option<String>)]
    pub roughness: serde_json::Value,
    /// Whether a colour shift of the highlight is reported.
    pub colour_shift: Option<bool>,
    /// Why this model, in words.
    pub reason: Option<String>,
    /// URL of fit-auto.json.
    pub fit: String,
}

/// The scan's exposures.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct BracketView {
    /// The shutter times given; for an automatic bracket, every one its metering chose
    /// so far (longest first), empty before the first θL is metered.
    pub shutter_s: Vec<f64>,
    pub auto: bool,
    /// Automatic bracket only: each metered θL's own bracket.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub by_theta_l: Option<Vec<MeteredBracket>>,
}

/// The bracket metering chose at one θL.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct MeteredBracket {
    pub theta_l: f64,
    pub shutter_s: Vec<f64>,
}

/// `done`/`total` count the steps planned when the scan was queued (fixed; a metering
/// step counts as done once the bracket it planned is captured).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ScanProgress {
    pub done: u32,
    pub total: u32,
    /// Journal rows (the total grows as metering plans captures).
    pub steps: Progress,
    /// θL whose bracket is captured and processed (null in lists for queued and
    /// finished scans).
    pub theta_l: Option<ThetaProgress>,
    /// Estimated seconds until both lanes are done, from the timing model scaled by
    /// the scan's own measured steps; only while the scan is running (null when
    /// queued, scheduled, paused, waiting, interrupted or ended).
    pub eta_s: Option<f64>,
}

/// Done of total.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Progress {
    pub done: u32,
    pub total: u32,
}

/// θL counted by what is done with them.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ThetaProgress {
    pub captured: u32,
    pub processed: u32,
    pub total: u32,
}

/// The robust fits over every θL captured so far.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct LiveFit {
    pub theta_l: Vec<f64>,
    pub samples: u64,
    /// Per model (`cook-torrance`, `ward`): `kd`, `ks`, `m`, `loss`, `err_p` (eq. 11 on
    /// the points so far), `held_out_err_p` (ΔErr_p at the newest θL of the fit made
    /// before it; null for the first θL), `change_p` (ΔErr_p between the previous and
    /// the new fit's predictions at every point so far; null for the first θL), or
    /// `error`.
    #[schema(value_type = std::collections::BTreeMap<String, Object>)]
    pub fits: Value,
}

/// URLs of the scan's results, once they exist.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ScanResults {
    pub samples: Option<String>,
    /// URL of each fit JSON by model: cook-torrance, ward, cook-torrance-fresnel (with
    /// stderr, ci95 and the Ks–m correlation).
    pub fits: std::collections::BTreeMap<String, String>,
    /// URLs of the HDR maps.
    pub hdr: Vec<String>,
    /// The latest frame as PNG, once a capture exists.
    pub thumbnail: Option<String>,
}

/// A sweep: its scans and their summed progress.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[schema(as = Sweep)]
pub struct SweepView {
    pub id: i64,
    pub created: String,
    /// No scan starts before it (RFC 3339).
    pub start_at: Option<String>,
    pub request: SweepRequest,
    /// `done` once every scan is done; `finished` once every scan has ended, some not
    /// done; `running` while one runs; `paused` when every scan not ended is paused;
    /// `scheduled` while its start time is ahead and no scan has started; else
    /// `waiting` (queued behind other scans, or a scan waits for a device, a sample or
    /// disk space).
    #[schema(pattern = "^(scheduled|waiting|paused|running|done|finished)$")]
    pub state: String,
    pub progress: Progress,
    /// How many of its scans are in each state (every state named).
    pub scans_by_state: std::collections::BTreeMap<String, u32>,
    /// What the operator can do with the whole sweep now: `pause`, `resume`, `cancel`
    /// (`POST /api/sweeps/{id}/<action>`), `reschedule` (`PATCH /api/sweeps/{id}`
    /// while scheduled).
    pub actions: Vec<String>,
    /// The sample changes its scans will wait for, with when each wait is expected to
    /// begin.
    pub waits: Vec<PlannedWaitView>,
    pub scans: Vec<ScanView>,
}

/// A wait for the operator to mount a sample, planned from the queue and the time-left
/// model: the queue played forward from now, each scan lasting its estimated time,
/// the operator confirming at once.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PlannedWaitView {
    /// The scan that will wait.
    pub scan_id: i64,
    /// The sample to mount.
    pub sample: String,
    /// When the wait is expected to begin (UTC, RFC 3339); for a scan already waiting,
    /// when it began.
    #[schema(format = DateTime)]
    pub at: String,
    /// The scan waits already (since `at`).
    pub waiting: bool,
}

/// `PATCH /api/sweeps/{id}`: the sweep's new start time.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SweepSchedule {
    /// RFC 3339; null: start now.
    #[schema(format = DateTime, required = true)]
    pub start_at: Option<String>,
}

/// What a sweep's control verb (pause, resume, cancel) answers.
#[derive(utoipa::IntoResponses)]
// Only described, never built: the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
pub enum SweepControlAnswers {
    /// The sweep, its scans moved
    #[response(status = 200)]
    Done(SweepView),
    /// No such sweep
    #[response(status = 404)]
    NotFound(crate::answers::ErrorBody),
    /// No scan of the sweep is in a state the verb applies to (a scan waiting for its sample is only confirmed or cancelled)
    #[response(status = 409)]
    NotAllowed(crate::answers::ErrorBody),
    /// The disk is full and the journal cannot be written; nothing changed. Try again once space is freed
    #[response(status = 503)]
    DiskFull(crate::answers::ErrorBody),
}

/// What a control verb (pause, resume, cancel) answers.
#[derive(utoipa::IntoResponses)]
// Only described, never built: the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
pub enum ControlAnswers {
    /// Scan
    #[response(status = 200)]
    Done(ScanView),
    /// No such scan
    #[response(status = 404)]
    NotFound(crate::answers::ErrorBody),
    /// The scan's state does not allow it (a scan waiting for its sample to be mounted is only confirmed or cancelled)
    #[response(status = 409)]
    NotAllowed(crate::answers::ErrorBody),
    /// The disk is full and the journal cannot be written; nothing changed. Try again once space is freed
    #[response(status = 503)]
    DiskFull(crate::answers::ErrorBody),
}
