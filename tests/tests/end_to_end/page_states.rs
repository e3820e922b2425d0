//! The web page in a real browser (`gonio_tests::browser`'s headless Chromium), scan
//! by scan: one test walks scans through every state (scheduled, queued, running,
//! paused, interrupted, cancelled, waiting for a device or for a sample change and
//! confirmed, done) and checks what the page shows in each, then the downloads, the
//! calibration, STOP ARM and Home, and the page at 390 px width. Another shows a scan
//! waiting for the arm's position (a controller that does not home) until it is
//! declared.

use std::time::Duration;

use gonio_tests::browser::Browser;
use gonio_tests::page::{
    fits_the_screen, no_time_left, open_page, select_and_wait, shown_waiting, wait_shown,
};
use gonio_tests::{
    emulator_config, emulator_config_scaled, temp_dir, with_small_red_sample, Daemon, TOKEN,
};
use serde_json::{json, Value};

/// Unix seconds of an RFC 3339 time, as the browser's local wall time in a zone
/// `offset_minutes` east of UTC (one without daylight saving time).
fn local_wall_time(rfc3339: &str, offset_minutes: i64) -> String {
    let format = time::format_description::well_known::Rfc3339;
    let t = time::OffsetDateTime::parse(rfc3339, &format).unwrap()
        + time::Duration::minutes(offset_minutes);
    format!(
        "{:04}-{:02}-{:02} {:02}:{:02}:{:02}",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second()
    )
}

/// The entry names of a tar archive (ustar: name and prefix fields).
fn tar_names(archive: &[u8]) -> Vec<String> {
    let field = |b: &[u8]| {
        let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        String::from_utf8_lossy(&b[..end]).into_owned()
    };
    let mut names = Vec::new();
    let mut at = 0;
    while at + 512 <= archive.len() && archive[at..at + 512].iter().any(|&b| b != 0) {
        let header = &archive[at..at + 512];
        let size = usize::from_str_radix(field(&header[124..135]).trim(), 8).unwrap();
        let (prefix, name) = (field(&header[345..500]), field(&header[..100]));
        names.push(if prefix.is_empty() {
            name
        } else {
            format!("{prefix}/{name}")
        });
        at += 512 + size.div_ceil(512) * 512;
    }
    names
}

/// The zone the browser is put in: India, 5 h 30 min east of UTC all year round.
const ZONE: &str = "Asia/Kolkata";
const ZONE_OFFSET_MIN: i64 = 330;

#[test]
fn page_tells_the_truth_in_every_state() {
    let dir = temp_dir("browser-states");
    // Slow enough devices that a running scan can be watched, paused and unplugged.
    // `red`: the small scene with another material, as a second sample.
    let config = with_small_red_sample(&emulator_config_scaled(0.3, 0.3), &dir);
    let daemon = Daemon::start(&dir, &config);
    let browser = Browser::launch(&dir.join("profile"));
    let mut page = browser.page();
    page.call("Emulation.setTimezoneOverride", json!({"timezoneId": ZONE}));
    open_page(&mut page, &daemon.url);
    page.eval(&format!(
        r#"(() => {{ const t = document.getElementById("token"); t.value = {};
            t.dispatchEvent(new Event("change")); }})()"#,
        json!(TOKEN)
    ));

    // Scheduled: a sweep entered for 23:30 local time starts at 23:30 local, which is
    // 18:00 UTC in India; the page says so in local time and counts no time down. The
    // sweep takes its own bracket, not the scan form's; queueing it says when it will
    // wait for the red sample to be mounted.
    page.eval(
        r##"(() => {
            document.getElementById("samples").value = "gold, red";
            document.getElementById("sets").value = "-20";
            document.getElementById("bracket").value = "1/2";
            document.getElementById("sweepbracket").value = "1/10, 1/40";
            document.getElementById("startat").value = "2099-12-02T23:30";
            document.querySelector("#sweepform button[type=submit]").click();
        })()"##,
    );
    let note = page.wait_for(
        "the sweep to be queued",
        "document.getElementById('sweepmsg').textContent.includes('queued') && document.getElementById('sweepmsg').textContent",
        Duration::from_secs(30),
    );
    let sweeps = daemon.get("/api/sweeps").json;
    assert_eq!(sweeps[0]["start_at"], "2099-12-02T18:00:00Z", "{sweeps}");
    assert_eq!(
        sweeps[0]["request"]["bracket"],
        json!({"shutter_s": [0.1, 0.025]}),
        "{sweeps}"
    );
    let sweep_id = sweeps[0]["id"].as_i64().unwrap();
    let scheduled_id = sweeps[0]["scans"][0]["id"].as_i64().unwrap();
    let red_wait = &sweeps[0]["waits"][0];
    assert_eq!(red_wait["sample"], "red", "{sweeps}");
    let wait_local = local_wall_time(red_wait["at"].as_str().unwrap(), ZONE_OFFSET_MIN);
    let note = note.as_str().unwrap();
    assert!(
        note.contains(&format!(
            "mount red for scan {} at about {wait_local}",
            red_wait["scan_id"]
        )),
        "{note}"
    );
    page.wait_for(
        "the sweep's local start time",
        "document.getElementById('sweeps').textContent.includes('2099-12-02 23:30:00')",
        Duration::from_secs(30),
    );
    // Its row says what its scans say, and opens them with the sweep's own controls.
    page.eval(&format!(
        "document.querySelector('#sweeps tr[data-sweep=\"{sweep_id}\"]').click()"
    ));
    let panel = page.wait_for(
        "the sweep's panel",
        &format!(
            "!document.getElementById('sweepdetail').hidden && document.querySelectorAll('#swscans tr').length === 2 && ({{
                row: document.querySelector('#sweeps tr[data-sweep=\"{sweep_id}\"]').children[1].textContent,
                scans: [...document.querySelectorAll('#swscans tr')].map((r) => r.children[2].textContent),
                enabled: [...document.querySelectorAll('#sweepdetail button[data-sweep-act]')].filter((b) => !b.disabled).map((b) => b.dataset.sweepAct),
                reschedule: !document.getElementById('swstart').hidden,
                waits: document.getElementById('swwaits').textContent,
            }})"
        ),
        Duration::from_secs(30),
    );
    assert_eq!(panel["row"], "scheduled", "{panel}");
    assert_eq!(panel["scans"], json!(["scheduled", "scheduled"]), "{panel}");
    assert_eq!(panel["enabled"], json!(["pause", "cancel"]), "{panel}");
    assert_eq!(panel["reschedule"], json!(true), "{panel}");
    assert!(
        panel["waits"].as_str().unwrap().contains("mount red"),
        "{panel}"
    );
    // A new start time from the panel: 01:00 local the next night.
    page.eval(
        r##"(() => {
            document.getElementById("swstartat").value = "2099-12-03T01:00";
            document.querySelector("#swstart button[type=submit]").click();
        })()"##,
    );
    page.wait_for(
        "the new start time",
        "document.getElementById('sweeps').textContent.includes('2099-12-03 01:00:00')",
        Duration::from_secs(30),
    );
    let sweep = daemon.get(&format!("/api/sweeps/{sweep_id}")).json;
    assert_eq!(sweep["start_at"], "2099-12-02T19:30:00Z", "{sweep}");
    // Paused and resumed as a whole from the panel.
    for (button, state) in [("pause", "paused"), ("resume", "scheduled")] {
        page.eval(&format!(
            "document.querySelector('#sweepdetail button[data-sweep-act={button}]').click()"
        ));
        page.wait_for(
            &format!("the sweep {state}"),
            &format!(
                "document.querySelector('#sweeps tr[data-sweep=\"{sweep_id}\"]').children[1].textContent === '{state}'"
            ),
            Duration::from_secs(30),
        );
    }
    // A scan row of the panel opens that scan.
    page.eval(&format!(
        "document.querySelector('#swscans tr[data-id=\"{scheduled_id}\"]').click()"
    ));
    let shown = wait_shown(
        &mut page,
        scheduled_id,
        "scheduled",
        |s| {
            s["times"]
                .as_str()
                .unwrap()
                .contains("starts 2099-12-03 01:00:00")
        },
        Duration::from_secs(30),
    );
    assert!(no_time_left(&shown), "{shown}");
    assert!(
        shown["rowNote"]
            .as_str()
            .unwrap()
            .contains("starts 2099-12-03 01:00:00"),
        "{shown}"
    );
    assert_eq!(shown["frame"], Value::Null, "{shown}");
    assert_eq!(shown["noFrame"], json!(true), "{shown}");
    fits_the_screen(&mut page, "scheduled");

    // Running: a scan from the form, its bracket written as shutters are written.
    page.eval(
        r##"(() => {
            document.getElementById("theta").value = "-20,-25,-30,-35,-40,-45";
            document.getElementById("bracket").value = "1/2, 1/8, 1/30, 1/100";
            document.getElementById("scanmsg").textContent = "";
            document.querySelector("#scanform button[type=submit]").click();
        })()"##,
    );
    let message = page.wait_for(
        "the scan to be queued",
        "document.getElementById('scanmsg').textContent.includes('queued') && document.getElementById('scanmsg').textContent",
        Duration::from_secs(30),
    );
    let running_id = scheduled_id + 2;
    assert!(
        message
            .as_str()
            .unwrap()
            .contains(&format!("scan {running_id} queued")),
        "{message}"
    );
    // Queued behind it: an automatic bracket, not metered yet.
    let created = daemon.post(
        "/api/scans",
        &json!({"sample": "gold", "theta_l": [-20, -30, -45], "bracket": "auto"}),
    );
    assert_eq!(created.status, 201, "{:?}", created.json);
    let queued_id = created.json["id"].as_i64().unwrap();
    daemon.wait_state(running_id, &["running"], Duration::from_secs(30));
    let shown = select_and_wait(
        &mut page,
        queued_id,
        "queued",
        |s| s["bracket"] == "auto (not metered yet)",
        Duration::from_secs(30),
    );
    assert!(no_time_left(&shown), "{shown}");
    assert_eq!(shown["frame"], Value::Null, "{shown}");
    assert_eq!(shown["noFrame"], json!(true), "{shown}");
    assert_eq!(shown["work"], "", "{shown}");
    fits_the_screen(&mut page, "queued");

    // The running scan: its own frame, its time left the same in the queue and the
    // detail, its bracket as given.
    let shown = select_and_wait(
        &mut page,
        running_id,
        "running",
        |s| {
            let lefts = s["lefts"].as_array().unwrap();
            s["frame"] == json!(running_id)
                && lefts.len() == 2
                && lefts[0] == lefts[1]
                && lefts[0].as_str().unwrap().contains("left")
        },
        Duration::from_secs(60),
    );
    assert_eq!(shown["bracket"], "0.5 s, 1/8 s, 1/30 s, 1/100 s", "{shown}");
    let started = daemon.get(&format!("/api/scans/{running_id}")).json["started"]
        .as_str()
        .unwrap()
        .to_owned();
    let local = local_wall_time(&started, ZONE_OFFSET_MIN);
    assert!(
        shown["times"]
            .as_str()
            .unwrap()
            .contains(&format!("started {local}")),
        "{shown} vs {started}"
    );
    fits_the_screen(&mut page, "running");

    // Paused from the page: no time left, no step under way on the arm.
    page.eval("document.querySelector('#detail button[data-act=pause]').click()");
    let shown = wait_shown(
        &mut page,
        running_id,
        "paused",
        no_time_left,
        Duration::from_secs(30),
    );
    assert!(
        !shown["work"].as_str().unwrap().contains("capture"),
        "{shown}"
    );
    assert_eq!(shown["frame"], json!(running_id), "{shown}");
    fits_the_screen(&mut page, "paused");
    // The camera line from the same poll: capturing only while the queue shows a scan
    // running (the paused one's exposure under way is told as finishing).
    let camera = page.eval(
        "({ line: document.getElementById('camera').textContent, \
            running: document.querySelectorAll('#scans td.state-running').length })",
    );
    assert!(
        !camera["line"].as_str().unwrap().contains("capturing") || camera["running"] != 0,
        "{camera}"
    );
    page.eval("document.querySelector('#detail button[data-act=resume]').click()");
    wait_shown(
        &mut page,
        running_id,
        "running",
        |s| s["lefts"][0].as_str().unwrap().contains("left"),
        Duration::from_secs(30),
    );

    // Interrupted: the camera's cable pulled; the reason shown, no time left.
    let unplug = daemon.post("/api/emulator/fault", &json!({"fault": "camera_unplug"}));
    assert_eq!(unplug.status, 200, "{:?}", unplug.json);
    let shown = wait_shown(
        &mut page,
        running_id,
        "interrupted",
        no_time_left,
        Duration::from_secs(60),
    );
    assert!(!shown["why"].as_str().unwrap().is_empty(), "{shown}");
    fits_the_screen(&mut page, "interrupted");
    let replug = daemon.post("/api/emulator/fault", &json!({"fault": "camera_replug"}));
    assert_eq!(replug.status, 200, "{:?}", replug.json);
    wait_shown(
        &mut page,
        running_id,
        "running",
        |_| true,
        Duration::from_secs(60),
    );

    // Cancelled mid-scan: nothing shown as under way after the end, no time left.
    page.eval("document.querySelector('#detail button[data-act=cancel]').click()");
    let shown = wait_shown(
        &mut page,
        running_id,
        "cancelled",
        no_time_left,
        Duration::from_secs(30),
    );
    assert_eq!(shown["work"], "", "{shown}");
    assert_eq!(shown["enabled"], json!([]), "{shown}");
    let view = daemon.get(&format!("/api/scans/{running_id}")).json;
    assert_eq!(view["processing_step"], Value::Null, "{view}");
    assert_eq!(view["current_step"], Value::Null, "{view}");
    assert_eq!(view["progress"]["eta_s"], Value::Null, "{view}");
    fits_the_screen(&mut page, "cancelled");

    // Done: the queued scan ran with the bracket its metering chose, shown as used.
    let shown = select_and_wait(
        &mut page,
        queued_id,
        "done",
        |s| s["frame"] == json!(queued_id),
        Duration::from_secs(180),
    );
    assert!(no_time_left(&shown), "{shown}");
    assert_eq!(shown["work"], "", "{shown}");
    let view = daemon.get(&format!("/api/scans/{queued_id}")).json;
    let used: Vec<f64> = serde_json::from_value(view["bracket"]["shutter_s"].clone()).unwrap();
    assert!(!used.is_empty(), "{view}");
    assert_eq!(
        view["bracket"]["by_theta_l"].as_array().unwrap().len(),
        3,
        "{view}"
    );
    let bracket = shown["bracket"].as_str().unwrap();
    assert!(
        bracket.starts_with("auto: ") && bracket.matches(" s").count() == used.len(),
        "{bracket} vs {used:?}"
    );
    let times = shown["times"].as_str().unwrap();
    let finished = local_wall_time(view["finished"].as_str().unwrap(), ZONE_OFFSET_MIN);
    assert!(
        times.contains(&format!("ended {finished}")) && times.contains("took "),
        "{times}"
    );
    page.wait_for(
        "the fit plot",
        "document.querySelector('#plot svg path') !== null",
        Duration::from_secs(60),
    );
    fits_the_screen(&mut page, "done");
    // The latest frame's caption and the model the `auto` fit chose, as the view
    // gives them.
    let view = daemon.get(&format!("/api/scans/{queued_id}")).json;
    let caption = page.wait_for(
        "the frame's caption",
        "!document.getElementById('framecap').hidden && document.getElementById('framecap').textContent",
        Duration::from_secs(30),
    );
    let theta = view["frame"]["theta_l"].as_f64().unwrap();
    let caption = caption.as_str().unwrap();
    assert!(
        caption.starts_with(&format!("θL {theta}° · exposure ")) && caption.ends_with(" s"),
        "{caption} vs {view}"
    );
    let choice = page.eval("document.getElementById('choice').textContent");
    let model = view["choice"]["model"].as_str().unwrap();
    assert!(
        choice
            .as_str()
            .unwrap()
            .contains(&format!("model chosen: {model}"))
            && choice.as_str().unwrap().contains("colour shift"),
        "{choice} vs {view}"
    );

    // Downloads named after what they are, and the whole scan as one archive.
    let base = format!("{}/api/scans/{queued_id}", daemon.url);
    let csv = ureq::get(&format!("{base}/files/samples.csv"))
        .call()
        .unwrap();
    assert_eq!(
        csv.header("Content-Disposition"),
        Some(format!("attachment; filename=\"{queued_id}-gold-samples.csv\"").as_str())
    );
    let archive = ureq::get(&format!("{base}/archive")).call().unwrap();
    assert_eq!(
        archive.header("Content-Disposition"),
        Some(format!("attachment; filename=\"{queued_id}-gold.tar\"").as_str())
    );
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut archive.into_reader(), &mut bytes).unwrap();
    let names = tar_names(&bytes);
    let top = format!("{queued_id}-gold/");
    for wanted in [
        "setup.json",
        "samples.csv",
        "fit-cook-torrance.json",
        "fit-ward.json",
        "log.json",
    ] {
        assert!(
            names.contains(&format!("{top}{wanted}")),
            "{wanted}: {names:?}"
        );
    }
    assert!(
        names
            .iter()
            .any(|n| n.starts_with(&format!("{top}theta_l_")) && n.ends_with(".tiff")),
        "{names:?}"
    );
    assert!(
        names.iter().any(|n| n.starts_with(&format!("{top}hdr/"))),
        "{names:?}"
    );

    // Calibrating from the done scan: progress while it works, then the setup it
    // stored and where each value came from.
    page.eval("document.getElementById('calibrate').click()");
    page.wait_for(
        "the calibration's progress",
        "document.getElementById('calprogress') !== null",
        Duration::from_secs(10),
    );
    let table = page.wait_for(
        "the calibrated setup (or an error)",
        "(document.querySelector('#calbox table.setup') || document.querySelector('#calbox .msg')) && document.getElementById('calbox').textContent",
        Duration::from_secs(180),
    );
    let table = table.as_str().unwrap();
    assert!(
        table.contains(&format!("calibrated from scan {queued_id}"))
            && table.contains("emulated scene")
            && table.contains("sample_row")
            // The estimates' standard uncertainties, one row per key.
            && table.contains("uncertainty.camera_offset_mm")
            && !table.contains("[object Object]"),
        "{table}"
    );

    // Waiting: the camera gone (a scan interrupted by it), the next scan waits for it;
    // its reason shown, no Confirm for it.
    let unplug = daemon.post("/api/emulator/fault", &json!({"fault": "camera_unplug"}));
    assert_eq!(unplug.status, 200, "{:?}", unplug.json);
    let one_frame = json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": [0.1]}});
    let interrupted_id = daemon.post("/api/scans", &one_frame).json["id"]
        .as_i64()
        .unwrap();
    daemon.wait_state(interrupted_id, &["interrupted"], Duration::from_secs(60));
    let waiting_id = daemon.post("/api/scans", &one_frame).json["id"]
        .as_i64()
        .unwrap();
    shown_waiting(&mut page, waiting_id, "camera not available", false);
    fits_the_screen(&mut page, "waiting for the camera");
    for id in [interrupted_id, waiting_id] {
        let cancelled = daemon.post(&format!("/api/scans/{id}/cancel"), &json!({}));
        assert_eq!(cancelled.status, 200, "{:?}", cancelled.json);
    }
    daemon.post("/api/emulator/fault", &json!({"fault": "camera_replug"}));

    // Waiting for a sample change: a scan of another sample than the one mounted waits
    // with its reason and a Confirm button; confirming lets it run to the end.
    let red = json!({"sample": "red", "theta_l": [-20], "bracket": {"shutter_s": [0.1]}});
    let red_id = daemon.post("/api/scans", &red).json["id"].as_i64().unwrap();
    shown_waiting(&mut page, red_id, "mount sample red", true);
    // Waiting for a person: only Confirm and Cancel.
    let shown = wait_shown(
        &mut page,
        red_id,
        "waiting",
        |_| true,
        Duration::from_secs(10),
    );
    assert_eq!(shown["enabled"], json!(["cancel", "confirm"]), "{shown}");
    fits_the_screen(&mut page, "waiting for a sample");
    page.eval("document.querySelector('#detail button[data-act=confirm]').click()");
    let shown = wait_shown(
        &mut page,
        red_id,
        "done",
        |_| true,
        Duration::from_secs(120),
    );
    assert_eq!(shown["confirmHidden"], json!(true), "{shown}");
    assert!(no_time_left(&shown), "{shown}");
    fits_the_screen(&mut page, "done after a sample change");

    // At 390 px (a phone): nothing wider than the screen, with the plot and the file
    // list on show.
    select_and_wait(
        &mut page,
        queued_id,
        "done",
        |_| true,
        Duration::from_secs(30),
    );
    page.wait_for(
        "the fit plot",
        "document.querySelector('#plot svg path') !== null",
        Duration::from_secs(60),
    );
    page.eval("document.getElementById('allfiles').click()");
    page.call(
        "Emulation.setDeviceMetricsOverride",
        json!({"width": 390, "height": 844, "deviceScaleFactor": 1, "mobile": true}),
    );
    let width = page.wait_for(
        "the layout at 390 px",
        "window.innerWidth === 390 && document.querySelectorAll('#files a').length > 0 && document.documentElement.scrollWidth",
        Duration::from_secs(30),
    );
    assert!(
        width.as_u64().unwrap() <= 390,
        "page {width} px wide at 390 px"
    );

    // STOP ARM: a note, not an error; no angle while the position is unknown; Home
    // brings it back.
    page.eval("document.getElementById('stop').click()");
    let stopped = page.wait_for(
        "the stop note",
        "document.getElementById('stopmsg').textContent.includes('arm stopped') && document.getElementById('stopmsg').className",
        Duration::from_secs(30),
    );
    assert_eq!(stopped, "note");
    // The instrument holds, and the note says until when.
    let held = page.wait_for(
        "the hold's note",
        "document.getElementById('stopmsg').textContent.includes('nothing runs until the arm is homed') && document.getElementById('stopmsg').textContent",
        Duration::from_secs(30),
    );
    assert!(held.as_str().unwrap().starts_with("arm stopped"), "{held}");
    // Home is offered (the hold ends once the arm is homed), and the arm's line says
    // its position was lost.
    let arm = page.wait_for(
        "the arm's unknown position",
        "!document.getElementById('home').hidden && document.getElementById('arm').textContent.includes('position unknown') && document.getElementById('arm').textContent",
        Duration::from_secs(30),
    );
    let arm = arm.as_str().unwrap();
    assert!(
        arm.contains("position unknown") && !arm.contains('°'),
        "{arm}"
    );
    // The line says it once, with the cause.
    assert_eq!(arm.matches("position unknown").count(), 1, "{arm}");
    assert_eq!(arm.matches("home").count(), 1, "{arm}");
    assert!(arm.contains("(the controller reset"), "{arm}");
    assert_eq!(
        daemon.get("/api/hardware").json["arm"]["angle_deg"],
        Value::Null
    );
    page.eval("document.getElementById('home').click()");
    let arm = page.wait_for(
        "the arm homed",
        "document.getElementById('home').hidden && document.getElementById('arm').textContent.includes('°') && document.getElementById('arm').textContent",
        Duration::from_secs(60),
    );
    assert!(arm.as_str().unwrap().starts_with("arm: idle at"), "{arm}");
    // Homing ended the hold: its note is gone.
    let note = page.wait_for(
        "the hold's end",
        "!document.getElementById('stopmsg').textContent.includes('nothing runs') && 'gone'",
        Duration::from_secs(30),
    );
    assert_eq!(note, "gone");
    // Nothing says the arm is homing once it is idle.
    let note = page.eval("document.querySelector('header').textContent");
    assert!(!note.as_str().unwrap().contains("homing"), "{note}");
    assert_eq!(
        page.eval("document.getElementById('stopmsg').className"),
        "note"
    );

    assert_eq!(page.errors(), Vec::<String>::new(), "console errors");
    drop(browser);
    drop(daemon);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Waiting for the arm's position (a controller that does not home): the page gives the
/// reason, no time left, no frame and no Confirm; once the position is declared the scan
/// runs to the end.
#[test]
fn page_shows_a_scan_waiting_for_the_arm_position() {
    let dir = temp_dir("browser-position");
    let config = emulator_config(0.01).replace(
        "[arm]\nkind = \"emulator\"",
        "[arm]\nkind = \"emulator\"\nhoming = \"off\"",
    );
    assert!(config.contains("homing = \"off\""), "{config}");
    let daemon = Daemon::start(&dir, &config);
    let browser = Browser::launch(&dir.join("profile"));
    let mut page = browser.page();
    open_page(&mut page, &daemon.url);
    let scan = json!({"sample": "gold", "theta_l": [-20], "bracket": {"shutter_s": [0.1]}});
    let id = daemon.post("/api/scans", &scan).json["id"]
        .as_i64()
        .unwrap();
    shown_waiting(&mut page, id, "declare where the arm is", false);
    fits_the_screen(&mut page, "waiting for the arm's position");
    assert_eq!(
        daemon.get("/api/hardware").json["arm"]["angle_deg"],
        Value::Null
    );
    let declared = daemon.post("/api/arm/position", &json!({"angle": 0.0}));
    assert_eq!(declared.status, 200, "{:?}", declared.json);
    let shown = wait_shown(&mut page, id, "done", |_| true, Duration::from_secs(120));
    assert!(no_time_left(&shown), "{shown}");
    assert_eq!(shown["frame"], json!(id), "{shown}");
    assert_eq!(page.errors(), Vec::<String>::new(), "console errors");
    drop(browser);
    drop(daemon);
    let _ = std::fs::remove_dir_all(&dir);
}
