//! The daemon's files on disk, on emulated hardware: temporaries of writes cut short
//! are removed from every scan, finished ones included; a full disk is a state the
//! scans wait in, not a failure.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gonio_tests::{emulator_config_scaled, temp_dir, Daemon};
use serde_json::json;

/// The id of a process that has ended (free until the system reuses it).
fn ended_process() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

/// Leaves the temporary of a write by `pid`, cut short, in `dir`; returns its path.
fn leftover(dir: &Path, pid: u32) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(format!(".exp_00.tiff.{pid}.0.partial"));
    std::fs::write(&path, b"half a frame").unwrap();
    path
}

fn wait_gone(path: &Path, timeout: Duration) {
    let deadline = Instant::now() + timeout;
    while path.exists() {
        assert!(
            Instant::now() < deadline,
            "{} still there after {timeout:?}",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A temporary left in a scan that ended (cancelled, here) is removed when it ends,
/// and one found in an ended scan at start is removed then (only active scans were
/// cleaned: it stayed forever). A temporary of a writer still running stays.
#[test]
fn temporaries_of_ended_scans_are_removed() {
    let dir = temp_dir("storage-partials");
    // The camera in real time: a 2 s exposure leaves time to cancel.
    let daemon = Daemon::start(&dir, &emulator_config_scaled(0.05, 1.0));
    let id = daemon.post_gold_scan(&[-20.0], &[2.0, 1.0]);
    daemon.wait_state(id, &["running"], Duration::from_secs(30));
    let scan_dir = daemon.data.join(format!("scans/{id}"));
    let frames = scan_dir.join("theta_l_-20.0");
    let cut_short = leftover(&frames, ended_process());
    // This test process stands for a writer still at work (a `gonio` command, say).
    let in_flight = leftover(&scan_dir, std::process::id());
    assert_eq!(
        daemon
            .post(&format!("/api/scans/{id}/cancel"), &json!({}))
            .status,
        200
    );
    daemon.wait_state(id, &["cancelled"], Duration::from_secs(30));
    wait_gone(&cut_short, Duration::from_secs(10));
    assert!(in_flight.exists());

    // A daemon dies with a write of the ended scan cut short; the next one removes it
    // before it runs anything.
    let cut_short = leftover(&frames, ended_process());
    daemon.kill9();
    let daemon = Daemon::restart(&dir);
    assert!(!cut_short.exists(), "left at start");
    assert!(in_flight.exists());
    assert_eq!(
        daemon.get(&format!("/api/scans/{id}")).json["state"],
        "cancelled"
    );
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

/// The emulators' configuration with the data directory's free space read from `free`
/// (the emulator's test hook for a disk that fills up and empties).
fn config_with_free_space(camera_time_scale: f64, free: &Path) -> String {
    let config = emulator_config_scaled(0.05, camera_time_scale);
    let hook = format!(
        "[emulator]\nfault_injection = true\nfree_space_file = {:?}\n",
        free.display().to_string()
    );
    let with_hook = config.replace("[emulator]\nfault_injection = true\n", &hook);
    assert_ne!(with_hook, config, "the emulator section moved");
    with_hook
}

/// The disk fills up while a scan captures (it once failed every queued scan in turn
/// within seconds, the ENOSPC reported as a camera error): the scan waits, "disk full:
/// N GB free, M GB needed", the next scan does not start, health reports the free
/// space; once space is back both go on by themselves and complete.
#[test]
fn a_full_disk_makes_the_scans_wait_until_space_returns() {
    let dir = temp_dir("storage-full");
    let free = dir.join("free-bytes");
    let plenty = 100_000_000_000u64;
    std::fs::write(&free, plenty.to_string()).unwrap();
    // The camera in real time: each 1 s exposure leaves time to fill the disk.
    let daemon = Daemon::start(&dir, &config_with_free_space(1.0, &free));
    assert_eq!(daemon.get("/api/health").json["disk_free_bytes"], plenty);
    let first = daemon.post_gold_scan(&[-20.0, -25.0], &[1.0, 0.5]);
    let second = daemon.post_gold_scan(&[-30.0], &[0.01]);
    daemon.wait_for_a_capture(first, Duration::from_secs(60));
    std::fs::write(&free, "1000").unwrap();
    let waiting = daemon.wait_state(
        first,
        &["waiting", "failed", "done"],
        Duration::from_secs(30),
    );
    assert_eq!(waiting["state"], "waiting", "{waiting}");
    let reason = waiting["reason"].as_str().unwrap();
    assert!(
        reason.starts_with("disk full: 0.00 GB free, ") && reason.ends_with(" GB needed"),
        "{reason}"
    );
    assert_eq!(daemon.get("/api/health").json["disk_free_bytes"], 1000);
    // Nothing else starts meanwhile, and the camera shows no error.
    std::thread::sleep(Duration::from_secs(3));
    let next = daemon.get(&format!("/api/scans/{second}")).json;
    assert!(
        next["state"] == "queued" || next["state"] == "waiting",
        "{next}"
    );
    assert_eq!(
        daemon.get(&format!("/api/scans/{first}")).json["state"],
        "waiting"
    );
    let hardware = daemon.get("/api/hardware").json;
    assert!(hardware["camera"]["error"].is_null(), "{hardware}");

    std::fs::write(&free, plenty.to_string()).unwrap();
    for id in [first, second] {
        let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
        assert_eq!(scan["state"], "done", "{scan}");
    }
    let log = daemon.get("/api/hardware/log").json;
    let waits: Vec<_> = log
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["action"] == "wait")
        .collect();
    assert!(waits.iter().any(|e| e["scan_id"] == first), "{log}");
    drop(daemon);
    std::fs::remove_dir_all(dir).ok();
}

/// A tmpfs mounted at a path for the life of the value, unmounted (lazily: the daemon
/// may still hold files in it) when dropped.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(path: &Path, bytes: u64) -> Option<Tmpfs> {
        std::fs::create_dir_all(path).unwrap();
        let status = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={bytes}"), "tmpfs"])
            .arg(path)
            .status()
            .ok()?;
        status.success().then(|| Tmpfs(path.to_path_buf()))
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount")
            .arg("-l")
            .arg(&self.0)
            .status();
    }
}

/// Bytes free on the filesystem of `path`.
fn free_bytes(path: &Path) -> u64 {
    use std::os::unix::ffi::OsStrExt;
    let c_path = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a zeroed statvfs is valid; statvfs fills it from a NUL-terminated path.
    let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    assert_eq!(unsafe { libc::statvfs(c_path.as_ptr(), &mut stat) }, 0);
    stat.f_bavail * stat.f_frsize
}

/// A tmpfs of `bytes` mounted at `dir`/data, the test's data directory; `None`, with
/// the reason printed, where mounting is not permitted (not root): the caller skips.
fn small_data_disk(dir: &Path, bytes: u64) -> Option<Tmpfs> {
    let data = dir.join("data");
    let tmpfs = Tmpfs::mount(&data, bytes);
    if tmpfs.is_none() {
        eprintln!(
            "skipped: mounting a tmpfs at {} is not permitted here (it needs root)",
            data.display()
        );
    }
    tmpfs
}

/// The same on a real small filesystem: the data directory on a 48 MiB tmpfs that a
/// file fills while the scan captures, then is removed. Mounting needs root: skipped
/// (with a message) where it is not permitted.
#[test]
fn a_full_tmpfs_makes_the_scan_wait_until_space_returns() {
    let dir = temp_dir("storage-tmpfs");
    let data = dir.join("data");
    let Some(_tmpfs) = small_data_disk(&dir, 48 << 20) else {
        return;
    };
    let reserve = 8u64 << 20;
    let config =
        emulator_config_scaled(0.05, 1.0) + &format!("\n[storage]\nreserve_bytes = {reserve}\n");
    let daemon = Daemon::start(&dir, &config);
    let id = daemon.post_gold_scan(&[-20.0, -25.0], &[1.0, 0.5]);
    daemon.wait_for_a_capture(id, Duration::from_secs(60));
    // Leave 4 MiB: less than the reserve.
    let ballast = data.join("ballast");
    let fill = free_bytes(&data).saturating_sub(4 << 20);
    std::fs::write(&ballast, vec![1u8; fill as usize]).unwrap();
    let waiting = daemon.wait_state(id, &["waiting", "failed", "done"], Duration::from_secs(30));
    assert_eq!(waiting["state"], "waiting", "{waiting}");
    let reason = waiting["reason"].as_str().unwrap();
    assert!(
        reason.starts_with("disk full: ") && reason.ends_with(" GB needed"),
        "{reason}"
    );
    let free = daemon.get("/api/health").json["disk_free_bytes"]
        .as_u64()
        .unwrap();
    assert!(free < reserve, "{free}");

    std::fs::remove_file(&ballast).unwrap();
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    drop(daemon);
    drop(_tmpfs);
    std::fs::remove_dir_all(dir).ok();
}

/// Fills the filesystem of `dir` to the last byte with the file `dir`/`name`, as
/// another process would; returns its path.
fn fill(dir: &Path, name: &str) -> PathBuf {
    use std::io::Write;
    let path = dir.join(name);
    let mut file = std::fs::File::create(&path).unwrap();
    let chunk = vec![7u8; 4096];
    loop {
        match file.write(&chunk) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) if e.raw_os_error() == Some(libc::ENOSPC) => break,
            Err(e) => panic!("filling {}: {e}", path.display()),
        }
    }
    let _ = file.sync_all();
    path
}

/// Lines of the daemon's log at `log` that say the disk or the database is full.
fn full_disk_lines(log: &Path) -> Vec<String> {
    std::fs::read_to_string(log)
        .unwrap_or_default()
        .lines()
        .filter(|l| l.contains("database or disk is full"))
        .map(str::to_owned)
        .collect()
}

/// Another process fills the data directory's disk (a 24 MiB tmpfs) to the last byte
/// while a scan captures, past the reserve the steps keep: SQLite itself finds the disk
/// full ("database or disk is full"). The journal writes in the space it held
/// (`DATA/journal.reserve`, deleted for it): the scan waits, "disk full", neither failed
/// nor left `running`; the controls answer, 503 with an error saying the disk is full
/// when the journal cannot write, never 500; the lanes do not log the full disk every
/// second. Once the file is removed, the scan completes by itself with every frame and
/// map, and the journal's reserve is made again. Skipped where mounting is not
/// permitted.
#[test]
fn a_disk_filled_by_another_process_leaves_the_journal_writing() {
    let dir = temp_dir("storage-filled");
    let data = dir.join("data");
    let Some(_tmpfs) = small_data_disk(&dir, 24 << 20) else {
        return;
    };
    let journal_reserve = 2u64 << 20;
    let config = emulator_config_scaled(0.05, 1.0)
        + &format!(
            "\n[storage]\nreserve_bytes = {}\njournal_reserve_bytes = {journal_reserve}\n",
            4u64 << 20
        );
    let daemon = Daemon::start(&dir, &config);
    let reserve = data.join("journal.reserve");
    assert_eq!(std::fs::metadata(&reserve).unwrap().len(), journal_reserve);
    let theta_l = [-20.0, -25.0];
    let id = daemon.post_gold_scan(&theta_l, &[1.0, 0.5]);
    daemon.wait_for_a_capture(id, Duration::from_secs(60));
    let ballast = fill(&data, "ballast");
    let waiting = daemon.wait_state(id, &["waiting", "failed", "done"], Duration::from_secs(30));
    assert_eq!(waiting["state"], "waiting", "{waiting}");
    let reason = waiting["reason"].as_str().unwrap_or("");
    assert!(reason.starts_with("disk full: "), "{waiting}");
    // The journal wrote in the reserve's space.
    assert!(!reserve.exists(), "the journal's reserve was not used");
    // Nothing changes by itself while the disk stays full, and the log stays quiet.
    std::thread::sleep(Duration::from_secs(3));
    let scan = daemon.get(&format!("/api/scans/{id}")).json;
    assert_eq!(scan["state"], "waiting", "{scan}");
    let lines = full_disk_lines(&daemon.log);
    assert!(lines.len() <= 4, "{lines:#?}");
    // Fill what the reserve freed too: the journal cannot write at all.
    let more = fill(&data, "ballast-2");
    for verb in ["pause", "resume"] {
        let answer = daemon.post(&format!("/api/scans/{id}/{verb}"), &json!({}));
        match answer.status {
            200 => {}
            503 => {
                let error = answer.json["error"].as_str().unwrap();
                assert!(error.starts_with("the disk is full"), "{error}");
            }
            other => panic!("{verb}: {other} {:?}", answer.json),
        }
    }
    assert_eq!(daemon.get("/api/health").status, 200);
    std::thread::sleep(Duration::from_secs(2));
    let lines = full_disk_lines(&daemon.log);
    assert!(lines.len() <= 4, "{lines:#?}");

    std::fs::remove_file(&ballast).unwrap();
    std::fs::remove_file(&more).unwrap();
    // Resumed if the pause went through.
    if daemon.get(&format!("/api/scans/{id}")).json["state"] == "paused" {
        let answer = daemon.post(&format!("/api/scans/{id}/resume"), &json!({}));
        assert_eq!(answer.status, 200, "{:?}", answer.json);
    }
    let scan = daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    assert_eq!(scan["state"], "done", "{scan}");
    let scan_dir = data.join(format!("scans/{id}"));
    let files = gonio_tests::files_under(&scan_dir);
    for theta in theta_l {
        for file in ["exp_00.tiff", "exp_01.tiff"] {
            let frame = format!("theta_l_{theta:.1}/{file}");
            assert!(files.contains(&frame), "{frame} missing: {files:?}");
        }
        let map = format!("hdr/theta_l_{theta:.1}.exr");
        assert!(files.contains(&map), "{map} missing: {files:?}");
    }
    assert!(files.iter().all(|f| !f.contains(".partial")), "{files:?}");
    let deadline = Instant::now() + Duration::from_secs(10);
    while std::fs::metadata(&reserve).map_or(0, |m| m.len()) != journal_reserve {
        assert!(
            Instant::now() < deadline,
            "the journal's reserve not made again"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    drop(daemon);
    drop(_tmpfs);
    std::fs::remove_dir_all(dir).ok();
}
