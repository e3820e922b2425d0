//! Captures are decoded in child processes under a memory and a time limit: a file
//! that makes a decoder allocate gigabytes, or a decoder that aborts, fails its step
//! with a one-line error naming the file, and the daemon goes on serving and runs the
//! next scan. Loopback only, emulated hardware; each test bounded in time.

use std::path::Path;
use std::time::Duration;

use gonio_tests::{emulator_config_scaled, temp_dir, Daemon};
use serde_json::{json, Value};

/// A CR3 file (ISO base media) whose Canon metadata box (`CMT1`, in the `moov` box's
/// Canon `uuid` box) claims `claimed` bytes with a 64-bit size: rawler allocates that
/// much before it reads the box. No TIFF directory claims anything, so nothing refuses
/// the file before the decoder meets it.
fn cr3_claiming(claimed: u64) -> Vec<u8> {
    const CANON_UUID: [u8; 16] = [
        0x85, 0xc0, 0xb6, 0x87, 0x82, 0x0f, 0x11, 0xe0, 0x81, 0x11, 0xf4, 0xce, 0x46, 0x2b, 0x6a,
        0x48,
    ];
    let mut b = Vec::new();
    // ftyp: major brand "crx ", minor version 1, compatible brand "crx ".
    b.extend(20u32.to_be_bytes());
    b.extend(b"ftypcrx ");
    b.extend(1u32.to_be_bytes());
    b.extend(b"crx ");
    // moov (48 bytes) holding the uuid box (40 bytes) holding the CMT1 header.
    b.extend(48u32.to_be_bytes());
    b.extend(b"moov");
    b.extend(40u32.to_be_bytes());
    b.extend(b"uuid");
    b.extend(CANON_UUID);
    b.extend(1u32.to_be_bytes());
    b.extend(b"CMT1");
    b.extend(claimed.to_be_bytes());
    b
}

/// Starts a scan at θL −20°, pauses it during its second capture (before its θL's
/// processing steps), lets `plant` write into its `theta_l_-20.0` directory, queues
/// another scan and resumes. Returns the two scans' final records.
fn plant_and_finish(daemon: &Daemon, plant: impl FnOnce(&Path)) -> (Value, Value) {
    let first = daemon.post_gold_scan(&[-20.0], &[0.01, 2.0]);
    daemon.wait_for(
        &format!("/api/scans/{first}/steps"),
        Duration::from_secs(60),
        |steps| {
            steps.as_array().is_some_and(|steps| {
                steps.iter().any(|s| {
                    s["step"]["kind"] == "capture"
                        && s["step"]["index"] == 1
                        && s["state"] == "started"
                })
            })
        },
    );
    let pause = daemon.post(&format!("/api/scans/{first}/pause"), &json!({}));
    assert_eq!(pause.status, 200, "{:?}", pause.json);
    daemon.wait_state(first, &["paused"], Duration::from_secs(30));
    let steps = daemon.get(&format!("/api/scans/{first}/steps")).json;
    let processed = steps.as_array().unwrap().iter().any(|s| {
        matches!(s["step"]["kind"].as_str(), Some("hdr" | "samples")) && s["state"] != "pending"
    });
    assert!(!processed, "paused too late: {steps}");
    plant(&daemon.data.join(format!("scans/{first}/theta_l_-20.0")));
    let second = daemon.post_gold_scan(&[-25.0], &[0.01, 0.02]);
    let resume = daemon.post(&format!("/api/scans/{first}/resume"), &json!({}));
    assert_eq!(resume.status, 200, "{:?}", resume.json);
    let first = daemon.wait_state(first, &["done", "failed"], Duration::from_secs(120));
    let second = daemon.wait_state(second, &["done", "failed"], Duration::from_secs(120));
    (first, second)
}

fn sidecar(theta_l: f64) -> Vec<u8> {
    json!({"shutter_s": 0.01, "iso": 100, "theta_l": theta_l, "camera": "planted",
           "time": "2026-01-01T00:00:00Z"})
    .to_string()
    .into_bytes()
}

/// The scan's error is one line naming the file and `reason`; the daemon still answers
/// and is the same process; the next scan is done.
fn assert_failed_alone(daemon: &Daemon, pid: u32, scans: (Value, Value), file: &str, reason: &str) {
    let (first, second) = scans;
    assert_eq!(first["state"], "failed", "{first}");
    let error = first["error"].as_str().unwrap();
    assert!(
        error.contains(file) && error.contains(reason) && !error.contains('\n'),
        "{error}"
    );
    assert_eq!(second["state"], "done", "{second}");
    assert_eq!(daemon.get("/api/health").status, 200);
    assert_eq!(daemon.pid(), pid);
}

/// A CR3 whose metadata box claims 64 GiB: in the daemon's own process the allocation
/// fails and aborts the daemon; in a decoding child it meets the child's memory limit.
#[test]
fn a_file_that_asks_for_gigabytes_fails_its_step_by_the_memory_limit() {
    let dir = temp_dir("decoders-memory");
    let daemon = Daemon::start(&dir, &emulator_config_scaled(0.05, 1.0));
    let pid = daemon.pid();
    let scans = plant_and_finish(&daemon, |dir| {
        std::fs::write(dir.join("exp_99.cr3"), cr3_claiming(64 << 30)).unwrap();
        std::fs::write(dir.join("exp_99.json"), sidecar(-20.0)).unwrap();
    });
    assert_failed_alone(
        &daemon,
        pid,
        scans,
        "exp_99.cr3",
        "the decoder was killed by its memory limit (",
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A decoder that aborts on a file (the decoding child aborts on the file named in
/// `GONIO_DECODE_WORKER_ABORT_ON`, standing for a decoder bug; no file is known to
/// abort rawler, tiff or exr on its own): the step fails, the daemon stays.
#[test]
fn a_decoder_that_aborts_fails_its_step_and_the_daemon_stays() {
    let dir = temp_dir("decoders-abort");
    let daemon = Daemon::start_with_env(
        &dir,
        &emulator_config_scaled(0.05, 1.0),
        &[("GONIO_DECODE_WORKER_ABORT_ON", "exp_98.tiff")],
    );
    let pid = daemon.pid();
    // A copy of the scan's first frame: decoded in the daemon's own process, it
    // would just be read.
    let scans = plant_and_finish(&daemon, |dir| {
        std::fs::copy(dir.join("exp_00.tiff"), dir.join("exp_98.tiff")).unwrap();
        std::fs::copy(dir.join("exp_00.json"), dir.join("exp_98.json")).unwrap();
    });
    assert_failed_alone(
        &daemon,
        pid,
        scans,
        "exp_98.tiff",
        "the decoder aborted (signal 6)",
    );
    std::fs::remove_dir_all(dir).ok();
}

/// The program's file replaced while the daemon runs (an install or a build over it):
/// decoders are started from the running image, not from the path, so scans go on.
#[test]
fn decoders_start_after_the_program_file_is_replaced() {
    let dir = temp_dir("decoders-replaced");
    let bin = dir.join("gonio");
    if std::fs::hard_link(gonio_tests::gonio_bin(), &bin).is_err() {
        std::fs::copy(gonio_tests::gonio_bin(), &bin).expect("copying gonio");
    }
    let daemon = Daemon::start_from(&bin, &dir, &emulator_config_scaled(0.01, 0.01));
    // Replaced as installers do: a new file renamed over the old name, which leaves
    // the running image without a path (/proc/<pid>/exe says "(deleted)").
    let new = dir.join("gonio.new");
    std::fs::copy(&bin, &new).expect("copying gonio");
    std::fs::rename(&new, &bin).expect("replacing gonio");
    let id = daemon.post_gold_scan(&[-20.0, -30.0, -40.0], &[0.1, 0.01]);
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}
