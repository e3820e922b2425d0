//! `gonio serve` stopped with Ctrl-C while a page listens to a running scan's event
//! stream: it says so in its log and ends within its grace period instead of waiting
//! for the stream; its log in a file has no terminal colour codes.

use std::io::Read;
use std::time::Duration;

use gonio_tests::{emulator_config, temp_dir, Daemon};
use serde_json::json;

#[test]
fn sigint_stops_the_daemon_with_an_open_event_stream() {
    let dir = temp_dir("signals");
    // Slow hardware: the scan is still running when the signal comes.
    let daemon = Daemon::start(&dir, &emulator_config(0.5));
    let created = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": [-20, -30, -40]}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let id = created.json["id"].as_i64().unwrap();
    daemon.wait_state(id, &["running"], Duration::from_secs(30));

    // A page's EventSource: a request that never ends by itself.
    let events = format!("{}/api/scans/{id}/events", daemon.url);
    let (opened_tx, opened) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let response = ureq::get(&events).call().expect("event stream");
        let mut reader = response.into_reader();
        let mut first = [0u8; 16];
        let _ = reader.read(&mut first);
        let _ = opened_tx.send(());
        let mut rest = Vec::new();
        let _ = reader.read_to_end(&mut rest);
    });
    opened
        .recv_timeout(Duration::from_secs(30))
        .expect("the event stream sends its first event");

    let log = daemon.log.clone();
    let status = daemon.interrupt(Duration::from_secs(15));
    assert!(status.success(), "{status:?}");
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        text.contains("Ctrl-C (SIGINT): stopping; a scan in progress resumes"),
        "{text}"
    );
    assert!(
        !text.contains('\u{1b}'),
        "ANSI codes in the log file:\n{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
