//! Time left as a new user meets it: `gonio serve` as README starts it (no
//! configuration: emulated devices, the builtin full-size gold scene, time scale 0.1)
//! on a new data directory, README's 6-θL scan with its automatic bracket, and every
//! estimate of `GET /api/scans/{id}` (`progress.eta_s`, polled each second) compared
//! with the time the scan actually had left at that poll (to its end as the daemon
//! journalled it, `finished`).
//!
//! The daemon measures what processing costs on this machine when it first starts
//! (the timing probe, cached in DATA/processing-costs.json); the scan is posted once
//! that is cached, as a user does after reading the token.
//!
//! Targets: within 35 % of the time actually left from the first second, within 15 %
//! once the first θL is processed. The error at a poll is |estimate − actual| over the
//! actual time left, counted no smaller than [`FLOOR_S`]: in the last seconds a
//! relative error says nothing. How long the steps take depends on what else the
//! machine runs, which no estimate made at the first second can know (the probe itself
//! measures the machine as it is when the daemon starts), and on a shared machine the
//! emulated camera's and the processing's speed drift within one scan even when no other
//! process runs. So one run asserts no target: it prints both, and asserts, when the
//! machine was quiet (the processes other than the daemon and the children it starts
//! used at most [`QUIET_SHARE`] of the cores' time from the daemon's start, the probe
//! included, to the scan's end; read from /proc), every estimate within [`RATIO`] times
//! of the time actually left either way (the model it replaced said 6.6 s at the first
//! second of a 92 s scan: 14×). The server's unit test
//! `recorded_first_scans_are_estimated_within_the_targets` replays the journals of 14
//! such scans recorded on a quiet machine with the release build a user runs
//! (`GONIO_BIN=target/release/gonio GONIO_KEEP_TEST_DIRS=1`, which keeps this run's data
//! directory in the temporary directory) and asserts that each target is met by at
//! least three quarters of them. On a machine that was not quiet the figures are
//! printed with that share and the load, and the test says it did not assert the bound
//! (so too when the probe gave up past its budget on a busy machine: on a quiet one that
//! fails). Asserted whatever the load: an estimate at every poll and never "finishing"
//! with seconds of work left.
//!
//! A test binary of its own (not a module of `end_to_end`): tests running beside it in one
//! process would leave the machine never quiet.

use std::time::{Duration, Instant};

use gonio_tests::{temp_dir, Daemon};
use serde_json::json;
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

/// The time left below which an error is counted against this many seconds.
const FLOOR_S: f64 = 10.0;
/// The targets: from the first second, and once the first θL is processed.
const FROM_FIRST_SECOND: f64 = 0.35;
const AFTER_FIRST_THETA: f64 = 0.15;
/// The largest ratio, either way, of an estimate to the time actually left (both
/// counted no smaller than [`FLOOR_S`]) on any machine.
const RATIO: f64 = 3.0;

/// The most of the cores' time other processes may use for the machine to count as
/// quiet (the bound of [`RATIO`] asserted).
const QUIET_SHARE: f64 = 0.2;

/// One poll: seconds since the scan was posted, when it was answered, its estimate, θL
/// processed.
struct Poll {
    at_s: f64,
    answered: OffsetDateTime,
    eta_s: Option<f64>,
    processed: u64,
}

/// The 1-minute load average over the cores of this machine.
fn load_per_core() -> f64 {
    let text = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let load: f64 = text
        .split_whitespace()
        .next()
        .and_then(|l| l.parse().ok())
        .unwrap_or(f64::INFINITY);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    load / cores as f64
}

/// Clock ticks of CPU time: the whole machine's busy and total (every core, from
/// /proc/stat), and those of process `pid` and its children, living and reaped.
#[derive(Clone, Copy)]
struct CpuTicks {
    busy: u64,
    total: u64,
    daemon: u64,
}

/// The fields of a /proc/PID/stat line after the command's closing parenthesis.
fn stat_fields(path: &std::path::Path) -> Option<Vec<u64>> {
    let text = std::fs::read_to_string(path).ok()?;
    let rest = &text[text.rfind(')')? + 1..];
    // State is the first field after the command; numbers from the parent's pid on.
    Some(
        rest.split_whitespace()
            .skip(1)
            .map(|f| f.parse().unwrap_or(0))
            .collect(),
    )
}

fn cpu_ticks(pid: u32) -> CpuTicks {
    let stat = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let cpu: Vec<u64> = stat
        .lines()
        .next()
        .unwrap_or_default()
        .split_whitespace()
        .skip(1)
        .map(|f| f.parse().unwrap_or(0))
        .collect();
    // user nice system idle iowait irq softirq steal
    let total: u64 = cpu.iter().take(8).sum();
    let idle = cpu.get(3).copied().unwrap_or(0) + cpu.get(4).copied().unwrap_or(0);
    // After the state: ppid is index 0, utime 10, stime 11, cutime 12, cstime 13.
    let own = stat_fields(
        &std::path::Path::new("/proc")
            .join(pid.to_string())
            .join("stat"),
    )
    .map_or(0, |f| f[10..14].iter().sum::<u64>());
    let children: u64 = std::fs::read_dir("/proc")
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| stat_fields(&e.path().join("stat")))
        .filter(|f| f.first() == Some(&u64::from(pid)))
        .map(|f| f[10] + f[11])
        .sum();
    CpuTicks {
        busy: total - idle,
        total,
        daemon: own + children,
    }
}

/// The share of the cores' time processes other than the daemon used between `from`
/// and `to`.
fn others_share(from: CpuTicks, to: CpuTicks) -> f64 {
    let others = (to.busy - from.busy).saturating_sub(to.daemon.saturating_sub(from.daemon));
    others as f64 / (to.total - from.total).max(1) as f64
}

#[test]
fn time_left_holds_from_the_first_second_of_a_new_data_directory_s_first_scan() {
    let dir = temp_dir("time-left");
    // An empty configuration is README's `gonio serve`: every key at its default.
    let daemon = Daemon::start(&dir, "");
    // From the start: the probe measures the machine as it is, and a machine busy while
    // it measures is not quiet for the scan's estimates either.
    let ticks_before = cpu_ticks(daemon.pid());
    let costs = daemon.data.join("processing-costs.json");
    let probe_deadline = Instant::now() + Duration::from_secs(300);
    // The probe gives up past its budget (the stated costs stay): on a busy machine,
    // where the targets are then not asserted; on a quiet one that is a fault.
    let mut probe_gave_up = None;
    while !costs.exists() {
        assert!(
            Instant::now() < probe_deadline,
            "the timing probe did not finish; see {}",
            daemon.log.display()
        );
        let log = std::fs::read_to_string(&daemon.log).unwrap_or_default();
        if let Some(line) = log.lines().find(|l| l.contains("timing probe:")) {
            let others = others_share(ticks_before, cpu_ticks(daemon.pid()));
            assert!(
                others > QUIET_SHARE,
                "on a quiet machine (other processes at {:.0} % of the cores): {line}",
                100.0 * others
            );
            probe_gave_up = Some(format!(
                "the timing probe gave up with other processes at {:.0} % of the cores",
                100.0 * others
            ));
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let load_before = load_per_core();

    let posted = Instant::now();
    let created = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": [-20, -25, -30, -35, -40, -45]}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let id = created.json["id"].as_i64().unwrap();
    let mut polls = Vec::new();
    // When the scan ended, as the daemon journalled it (a poll sees it up to a second
    // late).
    let (ended, ended_s) = loop {
        std::thread::sleep(Duration::from_secs(1));
        let at_s = posted.elapsed().as_secs_f64();
        let asked = OffsetDateTime::now_utc();
        let scan = daemon.get(&format!("/api/scans/{id}")).json;
        let took: time::Duration = OffsetDateTime::now_utc() - asked;
        let answered = asked + took * 0.5;
        match scan["state"].as_str() {
            Some("done") => {
                let finished: OffsetDateTime = scan["finished"]
                    .as_str()
                    .and_then(|f| OffsetDateTime::parse(f, &Rfc3339).ok())
                    .unwrap_or_else(|| panic!("a done scan without its end: {scan}"));
                let late: time::Duration = answered - finished;
                break (finished, at_s - late.as_seconds_f64());
            }
            Some("running") => polls.push(Poll {
                at_s,
                answered,
                eta_s: scan["progress"]["eta_s"].as_f64(),
                processed: scan["progress"]["theta_l"]["processed"]
                    .as_u64()
                    .unwrap_or(0),
            }),
            _ => {}
        }
        assert!(
            state_is_live(&scan),
            "the scan ended {}: {scan}",
            scan["state"]
        );
        assert!(at_s < 900.0, "the scan still runs after 900 s: {scan}");
    };
    let load_after = load_per_core();
    let others = others_share(ticks_before, cpu_ticks(daemon.pid()));

    // Every estimate against the time the scan actually had left.
    let mut worst = [0.0_f64; 2];
    // The first estimate more than RATIO times off either way.
    let mut off_by: Option<String> = None;
    eprintln!(
        "scan took {ended_s:.1} s; load per core {load_before:.2} before, {load_after:.2} \
         after; other processes used {:.0} % of the cores meanwhile",
        100.0 * others
    );
    eprintln!("   t (s)  estimate  actual   error  θL processed");
    for poll in &polls {
        let eta = poll
            .eta_s
            .unwrap_or_else(|| panic!("no estimate at {:.1} s", poll.at_s));
        let left: time::Duration = ended - poll.answered;
        let left = left.as_seconds_f64();
        let error = (eta - left).abs() / left.max(FLOOR_S);
        eprintln!(
            "{:8.1} {eta:9.1} {left:7.1} {:6.0} % {}",
            poll.at_s,
            100.0 * error,
            poll.processed
        );
        let ratio = eta.max(FLOOR_S) / left.max(FLOOR_S);
        if !(1.0 / RATIO..=RATIO).contains(&ratio) && off_by.is_none() {
            off_by = Some(format!(
                "{eta:.1} s estimated at {:.1} s with {left:.1} s left",
                poll.at_s
            ));
        }
        let after_first = usize::from(poll.processed >= 1);
        worst[after_first] = worst[after_first].max(error);
        // Never "finishing" (under a second) while seconds of work remain.
        assert!(
            eta >= 1.0 || left < 5.0,
            "{eta} s estimated at {:.1} s with {left:.1} s left",
            poll.at_s
        );
    }
    let after_first_theta = polls.iter().filter(|p| p.processed >= 1).count();
    assert!(
        polls.len() >= 10 && after_first_theta >= 5,
        "too few polls to judge: {} ({after_first_theta} after the first θL)",
        polls.len()
    );
    eprintln!(
        "worst error: {:.0} % before the first θL is processed, {:.0} % after",
        100.0 * worst[0],
        100.0 * worst[1]
    );
    let met = |error: f64, target: f64| if error <= target { "met" } else { "not met" };
    eprintln!(
        "targets with other processes at {:.0} % of the cores: from the first second {} \
         (≤ {:.0} %), after the first θL {} (≤ {:.0} %)",
        100.0 * others,
        met(worst[0].max(worst[1]), FROM_FIRST_SECOND),
        100.0 * FROM_FIRST_SECOND,
        met(worst[1], AFTER_FIRST_THETA),
        100.0 * AFTER_FIRST_THETA
    );
    if others > QUIET_SHARE || probe_gave_up.is_some() {
        eprintln!(
            "the bound of {RATIO}× not asserted: other processes used {:.0} % of the cores \
             (quiet: ≤ {:.0} %){}{}",
            100.0 * others,
            100.0 * QUIET_SHARE,
            probe_gave_up.map_or(String::new(), |p| format!("; {p}")),
            off_by.map_or(String::new(), |o| format!("; {o}"))
        );
        return;
    }
    assert!(
        off_by.is_none(),
        "on a quiet machine: {}",
        off_by.unwrap_or_default()
    );
}

/// Whether a scan is queued, running or done (not failed, cancelled or stuck).
fn state_is_live(scan: &serde_json::Value) -> bool {
    matches!(scan["state"].as_str(), Some("queued" | "running" | "done"))
}
