//! The routes that read a scan's files, against hostile scan folders and crowds of
//! clients, on emulated hardware: odd and long names, links, FIFOs and hard links in
//! the folder, links and FIFOs swapped in while an archive is written, hundreds of
//! clients that never read, a 1 GiB file, hundreds of thumbnail requests. Memory is
//! bounded by reading the daemon's `/proc/PID/status`. Loopback only; each test bounded
//! in count and time.

use std::ffi::OsStr;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use gonio_tests::{allow_open_files, emulator_config, memory_kib, temp_dir, Daemon};
use serde_json::{json, Value};

/// A daemon with one finished scan of one frame: the scan's id and directory.
fn daemon_with_a_scan(dir: &Path, config: &str) -> (Daemon, i64, PathBuf) {
    let daemon = Daemon::start(dir, config);
    let id = daemon.post_gold_scan(&[-20.0], &[0.5]);
    daemon.wait_state(id, &["done", "failed"], Duration::from_secs(120));
    let scan = daemon.data.join(format!("scans/{id}"));
    (daemon, id, scan)
}

fn mkfifo(path: &Path) {
    assert!(Command::new("mkfifo").arg(path).status().unwrap().success());
}

/// Every file under `dir` (extracted from an archive), relative, as bytes, with its
/// contents.
fn files_in(dir: &Path) -> Vec<(Vec<u8>, Vec<u8>)> {
    fn walk(base: &Path, dir: &Path, out: &mut Vec<(Vec<u8>, Vec<u8>)>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if entry.file_type().unwrap().is_dir() {
                walk(base, &path, out);
            } else {
                let rel = path.strip_prefix(base).unwrap().as_os_str().as_bytes();
                out.push((rel.to_vec(), std::fs::read(&path).unwrap()));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// Extracts `archive` with GNU tar into a fresh `dir/name` and returns its files.
fn untar(dir: &Path, name: &str, archive: &[u8]) -> Vec<(Vec<u8>, Vec<u8>)> {
    let out = dir.join(name);
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let tar = dir.join(format!("{name}.tar"));
    std::fs::write(&tar, archive).unwrap();
    let status = Command::new("tar")
        .arg("-xf")
        .arg(&tar)
        .arg("-C")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success(), "tar could not extract the archive");
    files_in(&out)
}

/// Long (255-byte name, 301-byte path), non-UTF-8 and odd (quote, newline) names are
/// archived whole (they once cut the download); hidden files, a hard link to the token,
/// links to /etc and a FIFO are neither listed, served nor archived: the archive holds
/// exactly what the files route serves, plus `log.json` and the names no URL can hold.
#[test]
fn the_archive_holds_exactly_what_the_files_route_serves_with_every_name() {
    let dir = temp_dir("dl-names");
    let (daemon, id, scan) = daemon_with_a_scan(&dir, &emulator_config(0.01));
    let long = "f".repeat(255);
    let deep = format!("{}/{}", "d".repeat(200), "e".repeat(100));
    std::fs::create_dir_all(scan.join("d".repeat(200))).unwrap();
    for name in [long.as_str(), deep.as_str(), "quote\"new\nline.csv"] {
        std::fs::write(scan.join(name), format!("content of {name}")).unwrap();
    }
    let binary = OsStr::from_bytes(b"bytes\xff\xfe.csv");
    std::fs::write(scan.join(binary), "not UTF-8").unwrap();
    std::fs::write(scan.join(".hidden.csv"), "hidden").unwrap();
    std::fs::write(daemon.data.join("token"), "secret-token").unwrap();
    std::fs::hard_link(daemon.data.join("token"), scan.join("token.csv")).unwrap();
    std::os::unix::fs::symlink("/etc", scan.join("etc")).unwrap();
    std::os::unix::fs::symlink("/etc/passwd", scan.join("passwd.csv")).unwrap();
    mkfifo(&scan.join("fifo.csv"));

    for (path, status) in [
        (long.as_str(), 200),
        (deep.as_str(), 200),
        ("token.csv", 404),
        (".hidden.csv", 404),
        ("passwd.csv", 404),
        ("etc/passwd", 404),
        ("fifo.csv", 404),
    ] {
        let answer = daemon.get(&format!("/api/scans/{id}/files/{path}"));
        assert_eq!(answer.status, status, "{path}");
    }
    let listing: Vec<String> = daemon
        .get(&format!("/api/scans/{id}/files"))
        .json
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_owned())
        .collect();
    for name in [&long, &deep] {
        assert!(listing.contains(name), "{name} not listed");
    }
    for hidden in ["token.csv", ".hidden.csv", "passwd.csv", "fifo.csv"] {
        assert!(!listing.iter().any(|n| n == hidden), "{hidden} listed");
    }
    assert!(!listing.iter().any(|n| n.starts_with("etc")));

    let archive = daemon.get(&format!("/api/scans/{id}/archive"));
    assert_eq!(archive.status, 200);
    let files = untar(&dir, "names", &archive.bytes);
    let top = format!("{id}-gold/");
    let mut expected: Vec<Vec<u8>> = listing
        .iter()
        .map(|n| format!("{top}{n}").into_bytes())
        .collect();
    expected.push([top.as_bytes(), binary.as_bytes()].concat());
    expected.push(format!("{top}log.json").into_bytes());
    expected.sort();
    let names: Vec<Vec<u8>> = files.iter().map(|(name, _)| name.clone()).collect();
    assert_eq!(
        names
            .iter()
            .map(|n| String::from_utf8_lossy(n))
            .collect::<Vec<_>>(),
        expected
            .iter()
            .map(|n| String::from_utf8_lossy(n))
            .collect::<Vec<_>>()
    );
    for (name, data) in &files {
        let rel = OsStr::from_bytes(&name[top.len()..]);
        if rel != "log.json" {
            assert_eq!(data, &std::fs::read(scan.join(rel)).unwrap(), "{rel:?}");
        }
    }

    // A scan not started yet (its start ahead) has no directory: its archive is a
    // whole tar of its log alone, as its files are an empty list.
    let ahead = daemon.post(
        "/api/sweeps",
        &json!({"samples": ["gold"], "theta_l_sets": [[-20]], "bracket": {"shutter_s": [0.1]},
                "start_at": "2999-01-01T00:00:00Z"}),
    );
    assert_eq!(ahead.status, 201, "{:?}", ahead.json);
    let later = gonio_tests::sweep_scans(&ahead.json)[0];
    assert_eq!(
        daemon.get(&format!("/api/scans/{later}/files")).json,
        json!([])
    );
    let archive = daemon.get(&format!("/api/scans/{later}/archive"));
    assert_eq!(archive.status, 200);
    let files = untar(&dir, "not-started", &archive.bytes);
    let names: Vec<String> = files
        .iter()
        .map(|(name, _)| String::from_utf8_lossy(name).into_owned())
        .collect();
    assert_eq!(names, [format!("{later}-gold/log.json")]);
    std::fs::remove_dir_all(dir).ok();
}

/// A directory swapped for a link to a secret folder outside, and a file swapped for a
/// FIFO, again and again while archives are written: no archive holds the secret (7 of
/// 76 once held /etc/passwd), none hangs (a FIFO once blocked requests for 20 s), each
/// is whole.
#[test]
fn links_and_fifos_swapped_in_while_archiving_are_never_followed() {
    let dir = temp_dir("dl-toctou");
    let (daemon, id, scan) = daemon_with_a_scan(&dir, &emulator_config(0.01));
    let secret = dir.join("secret");
    std::fs::create_dir_all(&secret).unwrap();
    std::fs::write(secret.join("passwd"), "root:secret-outside").unwrap();
    std::fs::create_dir_all(scan.join("sub")).unwrap();
    std::fs::write(scan.join("sub/passwd"), "inside").unwrap();
    std::os::unix::fs::symlink(&secret, scan.join("link")).unwrap();
    std::fs::write(scan.join("data.csv"), "plain").unwrap();
    mkfifo(&scan.join("pipe"));
    let stop = AtomicBool::new(false);
    std::thread::scope(|threads| {
        threads.spawn(|| {
            let at = |name: &str| scan.join(name);
            while !stop.load(Ordering::Relaxed) {
                let _ = std::fs::rename(at("sub"), at("spare"));
                let _ = std::fs::rename(at("link"), at("sub"));
                let _ = std::fs::rename(at("spare"), at("link"));
                let _ = std::fs::rename(at("data.csv"), at("spare.csv"));
                let _ = std::fs::rename(at("pipe"), at("data.csv"));
                let _ = std::fs::rename(at("spare.csv"), at("pipe"));
            }
        });
        // The swapper stops whatever the rounds do, so that a failed round fails the
        // test instead of leaving the scope waiting on it.
        let rounds = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut slowest = Duration::ZERO;
            for round in 0..60 {
                let asked = Instant::now();
                let archive = daemon.get(&format!("/api/scans/{id}/archive"));
                slowest = slowest.max(asked.elapsed());
                assert_eq!(archive.status, 200, "round {round}");
                let text = String::from_utf8_lossy(&archive.bytes);
                assert!(
                    !text.contains("secret-outside"),
                    "round {round}: a secret archived"
                );
                untar(&dir, "toctou", &archive.bytes);
            }
            slowest
        }));
        stop.store(true, Ordering::Relaxed);
        let slowest = rounds.unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        assert!(
            slowest < Duration::from_secs(10),
            "an archive took {slowest:?}"
        );
    });
    std::fs::remove_dir_all(dir).ok();
}

/// 600 clients ask for an archive of 64 MiB and never read: two are written (the cap),
/// the others get 503 with Retry-After at once; listing scans, a scan's view, health
/// and queuing a scan still answer; once the stalled downloads time out, an archive
/// is served again. (530 such clients once stalled every route, 529 threads.)
#[test]
fn six_hundred_stalled_archive_readers_are_capped_and_time_out() {
    let dir = temp_dir("dl-crowd");
    let config = format!(
        "{}\n[downloads]\nmax_archives = 2\nstall_timeout_s = 3\n",
        emulator_config(0.01)
    );
    let (daemon, id, scan) = daemon_with_a_scan(&dir, &config);
    std::fs::File::create(scan.join("big.bin"))
        .unwrap()
        .set_len(64 << 20)
        .unwrap();
    allow_open_files(4096);
    let request = format!(
        "GET /api/scans/{id}/archive HTTP/1.1\r\nHost: {}\r\n\r\n",
        daemon.addr()
    );
    let mut stalled: Vec<TcpStream> = (0..600)
        .map(|_| {
            let mut stream = TcpStream::connect(daemon.addr()).unwrap();
            stream.write_all(request.as_bytes()).unwrap();
            stream
        })
        .collect();
    std::thread::sleep(Duration::from_millis(500));
    let mut slowest = Duration::ZERO;
    for path in [
        "/api/scans".to_owned(),
        format!("/api/scans/{id}"),
        "/api/health".to_owned(),
    ] {
        let asked = Instant::now();
        assert_eq!(daemon.get(&path).status, 200, "{path}");
        slowest = slowest.max(asked.elapsed());
    }
    let asked = Instant::now();
    daemon.post_gold_scan(&[-20.0], &[0.5]);
    slowest = slowest.max(asked.elapsed());
    eprintln!("slowest other route with 600 stalled archive readers: {slowest:?}");
    assert!(slowest < Duration::from_secs(10), "{slowest:?}");
    let mut refused = 0;
    for stream in &mut stalled {
        stream
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let mut head = [0u8; 512];
        let n = stream.read(&mut head).unwrap_or(0);
        let head = String::from_utf8_lossy(&head[..n]).to_ascii_lowercase();
        if head.starts_with("http/1.1 503") {
            assert!(head.contains("retry-after: "), "{head}");
            refused += 1;
        }
    }
    assert_eq!(refused, 598, "all but max_archives refused");
    // The two written stall, time out (3 s) and free their slots.
    std::thread::sleep(Duration::from_secs(6));
    let archive = daemon.get(&format!("/api/scans/{id}/archive"));
    assert_eq!(archive.status, 200);
    assert!(archive.bytes.len() > 64 << 20);
    drop(stalled);
    std::fs::remove_dir_all(dir).ok();
}

/// Resets the peak resident size the kernel keeps for `pid` (`VmHWM`).
fn reset_peak(pid: u32) {
    let _ = std::fs::write(format!("/proc/{pid}/clear_refs"), "5");
}

/// A 1 GiB file is streamed (the daemon's peak resident size grows by at most 64 MiB;
/// it once read the file into memory, +1 GB) with `Accept-Ranges: bytes`; one range
/// gets 206 with `Content-Range`, a range beyond the end 416.
#[test]
fn a_gibibyte_file_streams_in_bounded_memory_with_byte_ranges() {
    let dir = temp_dir("dl-big");
    let (daemon, id, scan) = daemon_with_a_scan(&dir, &emulator_config(0.01));
    let len: u64 = 1 << 30;
    {
        let mut file = std::fs::File::create(scan.join("big.bin")).unwrap();
        file.write_all(b"head").unwrap();
        file.set_len(len).unwrap();
        use std::io::{Seek, SeekFrom};
        file.seek(SeekFrom::Start(len - 4)).unwrap();
        file.write_all(b"tail").unwrap();
    }
    let url = format!("{}/api/scans/{id}/files/big.bin", daemon.url);
    reset_peak(daemon.pid());
    let before = memory_kib(daemon.pid(), "VmHWM");
    let response = ureq::get(&url)
        .timeout(Duration::from_secs(300))
        .call()
        .unwrap();
    assert_eq!(response.status(), 200);
    assert_eq!(response.header("Accept-Ranges"), Some("bytes"));
    assert_eq!(
        response.header("Content-Length"),
        Some(len.to_string().as_str())
    );
    let read = std::io::copy(&mut response.into_reader(), &mut std::io::sink()).unwrap();
    assert_eq!(read, len);
    let grown = memory_kib(daemon.pid(), "VmHWM").saturating_sub(before);
    eprintln!("daemon peak resident size grew by {grown} KiB serving 1 GiB");
    assert!(grown <= 64 << 10, "peak resident size grew by {grown} KiB");

    for (range, body, content_range) in [
        ("bytes=0-3", "head", format!("bytes 0-3/{len}")),
        (
            "bytes=-4",
            "tail",
            format!("bytes {}-{}/{len}", len - 4, len - 1),
        ),
    ] {
        let response = ureq::get(&url).set("Range", range).call().unwrap();
        assert_eq!(response.status(), 206, "{range}");
        assert_eq!(
            response.header("Content-Range"),
            Some(content_range.as_str())
        );
        assert_eq!(response.into_string().unwrap(), body, "{range}");
    }
    match ureq::get(&url)
        .set("Range", &format!("bytes={len}-"))
        .call()
    {
        Err(ureq::Error::Status(416, response)) => {
            let expected = format!("bytes */{len}");
            assert_eq!(response.header("Content-Range"), Some(expected.as_str()));
            let json: Value = serde_json::from_str(&response.into_string().unwrap()).unwrap();
            assert!(json["error"].is_string());
        }
        other => panic!("a range beyond the end: {other:?}"),
    }
    std::fs::remove_dir_all(dir).ok();
}

/// The latest frame of a scan replaced by a 12 MP one; 300 clients ask for its
/// thumbnail at once: each gets the PNG or 503 with Retry-After, the daemon stays under
/// 1 GiB resident (64 full decodes once took 6 GB) and health answers meanwhile.
#[test]
fn three_hundred_thumbnail_requests_keep_the_daemon_small_and_answering() {
    use gonio_processing::capture::{read_sidecar, write_tiff_capture};
    let dir = temp_dir("dl-thumbs");
    let (daemon, id, scan) = daemon_with_a_scan(&dir, &emulator_config(0.01));
    let steps = daemon.get(&format!("/api/scans/{id}/steps")).json;
    let frame = steps
        .as_array()
        .unwrap()
        .iter()
        .rev()
        .filter(|s| s["step"]["kind"] == "capture" && s["state"] == "done")
        .find_map(|s| s["result"]["path"].as_str())
        .expect("a captured frame")
        .to_owned();
    let frame = scan.join(frame);
    let mut sidecar = read_sidecar(&frame).unwrap();
    let (width, height) = (4000u32, 3000u32);
    sidecar.width = None;
    sidecar.height = None;
    let counts: Vec<u16> = (0..width as usize * height as usize * 3)
        .map(|i| (i % 4000) as u16)
        .collect();
    write_tiff_capture(&frame, width, height, &counts, &sidecar).unwrap();
    drop(counts);
    allow_open_files(4096);
    reset_peak(daemon.pid());
    let url = format!("{}/api/scans/{id}/thumbnail.png", daemon.url);
    let (pngs, busy) = std::thread::scope(|threads| {
        let asked: Vec<_> = (0..300)
            .map(|_| {
                threads.spawn(
                    || match ureq::get(&url).timeout(Duration::from_secs(120)).call() {
                        Ok(response) => {
                            let mut png = Vec::new();
                            response.into_reader().read_to_end(&mut png).unwrap();
                            assert!(png.starts_with(b"\x89PNG"));
                            (1, 0)
                        }
                        Err(ureq::Error::Status(503, response)) => {
                            assert!(response.header("Retry-After").is_some());
                            (0, 1)
                        }
                        Err(err) => panic!("thumbnail: {err}"),
                    },
                )
            })
            .collect();
        let asked_health = Instant::now();
        assert_eq!(daemon.get("/api/health").status, 200);
        eprintln!(
            "health answered in {:?} amid 300 thumbnail requests",
            asked_health.elapsed()
        );
        asked
            .into_iter()
            .map(|t| t.join().unwrap())
            .fold((0, 0), |(a, b), (c, d)| (a + c, b + d))
    });
    let peak = memory_kib(daemon.pid(), "VmHWM");
    eprintln!("{pngs} thumbnails, {busy} busy; daemon peak resident {peak} KiB");
    assert!(pngs >= 1);
    assert!(peak < 1 << 20, "daemon peak resident {peak} KiB");
    std::fs::remove_dir_all(dir).ok();
}
