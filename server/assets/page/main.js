// The page's controls and its start: the scan and sweep forms (the sweep's own
// bracket; the sample changes it will wait for), STOP ARM, Home, the arm's declared
// position, a scan's actions and calibration, downloads carrying the token, selecting
// a scan or a sweep, and the polling (every 1.5 s) with the time-left countdown.

import { $, page, hasToken, post, overview, fetchFile, watch } from "./state.js";
import { escapeHtml, localTime } from "./text.js";
import { show, showOverview, clearFrame, setupTable, paintTimeLeft } from "./render.js";
import { showSweep, initSweeps, waitsText } from "./sweeps.js";
import { clearColour } from "./colour.js";

// Numbers written comma separated.
function numbers(text) {
  return text.split(",").map((s) => s.trim()).filter((s) => s !== "").map(Number);
}

// Shutter times as written in the Bracket field: seconds ("0.5") or fractions ("1/30"),
// comma separated; anything else is refused naming the entry.
function shutterTimes(text) {
  return text.split(",").map((s) => s.trim()).filter((s) => s !== "").map((s) => {
    const f = /^(\d+(?:\.\d+)?)\s*\/\s*(\d+(?:\.\d+)?)$/.exec(s);
    const t = f ? Number(f[1]) / Number(f[2]) : (/^\d*\.?\d+(?:e-?\d+)?$/i.test(s) ? Number(s) : NaN);
    if (!(t > 0 && Number.isFinite(t))) throw new Error(`bracket: "${s}" is not a shutter time (seconds, e.g. 0.5 or 1/30)`);
    return t;
  });
}

// A bracket field (the scan form's or the sweep form's) as the API takes it: "auto"
// or the shutter times.
function bracketBody(field) {
  const b = $(field).value.trim();
  return b === "auto" || b === "" ? "auto" : { shutter_s: shutterTimes(b) };
}

// Where a form sends what it creates: its own `action` (the API route).
const target = (form) => $(form).getAttribute("action");

$("scanform").addEventListener("submit", async (e) => {
  e.preventDefault();
  try {
    const body = { sample: $("sample").value.trim(), theta_l: numbers($("theta").value), bracket: bracketBody("bracket") };
    const r = await post(target("scanform"), body);
    $("scanmsg").innerHTML = `<span class="ok">scan ${r.id} queued</span>`;
    select(r.id);
    refresh();
  } catch (err) { $("scanmsg").textContent = err.message; }
});

$("sweepform").addEventListener("submit", async (e) => {
  e.preventDefault();
  try {
    const body = {
      samples: $("samples").value.split(",").map((s) => s.trim()).filter((s) => s),
      theta_l_sets: $("sets").value.split(";").map(numbers),
      repeats: Number($("repeats").value || 1),
      bracket: bracketBody("sweepbracket"),
    };
    // datetime-local gives the local wall time without a zone: Date reads it as local.
    if ($("startat").value) body.start_at = new Date($("startat").value).toISOString();
    const r = await post(target("sweepform"), body);
    const when = body.start_at ? `, starting ${localTime(body.start_at)}` : "";
    const waits = waitsText(r.waits);
    $("sweepmsg").innerHTML = `<span class="ok">sweep ${r.id} queued: ${r.scans.length} scan${r.scans.length === 1 ? "" : "s"}${escapeHtml(when)}</span>` +
      (waits ? `<br><span class="note" id="sweepwaits">${escapeHtml(waits)}</span>` : "");
    page.sweep = r.id;
    refresh();
  } catch (err) { $("sweepmsg").textContent = err.message; }
});

$("livemodel").addEventListener("change", () => { if (page.lastScan) show(page.lastScan); });

// A note in the header: plain for news, red for a failure.
function say(el, text, failed) {
  el.textContent = text;
  el.className = failed ? "msg" : "note";
}

$("stop").addEventListener("click", async () => {
  try {
    const r = await post("/api/arm/stop");
    say($("stopmsg"), "arm stopped" + (r.paused.length ? "; paused scan " + r.paused.join(", ") : ""), false);
  } catch (err) { say($("stopmsg"), err.message, true); }
  refresh();
});

$("home").addEventListener("click", async () => {
  try {
    await post("/api/arm/home");
    // The arm line (the hardware's state) tells the homing and its end.
    say($("stopmsg"), "", false);
  } catch (err) { say($("stopmsg"), err.message, true); }
  refresh();
});

$("armpos").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  try {
    const r = await post("/api/arm/position", { angle: Number($("armangle").value) });
    $("armposmsg").textContent = `declared θL ${r.angle}°`;
  } catch (err) { $("armposmsg").textContent = err.message; }
});

// One control's request at a time: a second click while one is under way (a
// double-click) sends nothing, so it cannot be refused for the first one's effect.
let acting = false;
document.querySelectorAll("#detail button[data-act]").forEach((btn) => {
  btn.addEventListener("click", async () => {
    if (page.selected === null || acting) return;
    const id = page.selected, act = btn.dataset.act;
    acting = true;
    try {
      const s = await post(`/api/scans/${id}/${act}`);
      // Said at once: a retried step may fail again before the next poll shows it ran.
      if (page.selected === id) say($("actmsg"), `scan ${id}: ${act} sent, now ${s.state}`, false);
      refresh();
    } catch (err) {
      if (page.selected === id) say($("actmsg"), err.message, true);
    } finally { acting = false; }
  });
});

// Calibrating takes seconds: the button says how long it has been at it, then the
// setup it stored is shown with where each value came from.
$("calibrate").addEventListener("click", async () => {
  if (page.selected === null) return;
  const id = page.selected, btn = $("calibrate"), box = $("calbox"), t0 = Date.now();
  btn.disabled = true;
  page.calibrating = true;
  box.hidden = false;
  const tick = () => { box.innerHTML = `<p class="muted" id="calprogress">calibrating from scan ${id}… ${Math.round((Date.now() - t0) / 1000)} s</p>`; };
  tick();
  const timer = setInterval(tick, 500);
  try {
    const setup = await post(`/api/scans/${id}/calibrate`);
    clearInterval(timer);
    if (page.selected === id) box.innerHTML = setupTable(setup, id);
  } catch (err) {
    clearInterval(timer);
    if (page.selected === id) box.innerHTML = `<p class="msg">${escapeHtml(err.message)}</p>`;
  }
  page.calibrating = false;
  btn.disabled = false;
});

// Polls the scans, the sweeps, the hardware and the selected scan, and draws the
// header, the queue and the detail from that one answer; selects the newest scan when
// none is. A poll asked for while one is under way runs once it has ended.
let polling = null, again = false;
async function refresh() {
  if (polling) { again = true; return; }
  polling = (async () => { do { again = false; await poll(); } while (again); })();
  await polling;
  polling = null;
}

async function poll() {
  try {
    const id = page.selected;
    const { scans, sweeps, hw, detail } = await overview(id);
    // Another scan selected meanwhile: its own poll draws the page.
    if (page.selected !== id) return;
    // The scan shown is gone (the daemon started on another data directory): the
    // newest is shown instead.
    if (id !== null && !scans.some((s) => s.id === id)) deselect();
    showOverview(scans, sweeps, hw);
    showSweep(sweeps);
    if (detail) show(detail);
    if (page.selected === null && scans.length) select(scans[scans.length - 1].id);
  } catch (err) {
    // The daemon may be restarting; a 401 means reads need the token.
    if (err.message.startsWith("401")) $("arm").textContent = "reads need the token: " + err.message;
  }
}

// Empties the detail panel: nothing of a scan shown before stays, nor what a control
// said of it.
function deselect() {
  page.selected = null;
  page.lastDone = -1;
  page.lastScan = null;
  $("detail").hidden = true;
  say($("actmsg"), "", false);
}

// Shows scan `id` in the detail panel, emptied until its first view arrives.
function select(id) {
  if (page.selected === id) return;
  deselect();
  page.selected = id;
  $("detail").hidden = false;
  // Nothing of the scan shown before stays while the new one loads.
  $("dtitle").textContent = `Scan ${id}`;
  clearColour();
  $("plot").innerHTML = "";
  $("files").hidden = true;
  $("calbox").hidden = true;
  $("results").innerHTML = "";
  $("dstate").innerHTML = "";
  $("dtimes").textContent = "";
  $("choice").innerHTML = "";
  clearFrame();
  watch(id, refresh);
  refresh();
}

// A queue row selects its scan.
$("scans").addEventListener("click", (e) => {
  const tr = e.target.closest("tr[data-id]");
  if (tr) select(Number(tr.dataset.id));
});

initSweeps(select, refresh);

// Links to results and files download through fetch when a token is entered, under
// the name the daemon gives them (Content-Disposition); a link meant for a new tab (the
// report) opens there, its tab opened at the click so that no popup blocker stops it.
for (const box of ["results", "files"]) {
  $(box).addEventListener("click", async (e) => {
    const a = e.target.closest("a");
    if (!a || !a.getAttribute("href").startsWith("/api/") || !hasToken()) return;
    e.preventDefault();
    const tab = a.target === "_blank" ? window.open("", "_blank") : null;
    try {
      const file = await fetchFile(a.getAttribute("href"));
      if (tab) {
        tab.location = file.url;
      } else {
        const link = document.createElement("a");
        link.href = file.url;
        link.download = file.name;
        link.click();
      }
      setTimeout(() => URL.revokeObjectURL(file.url), 60000);
    } catch (err) {
      if (tab) tab.close();
      say($("actmsg"), err.message, true);
    }
  });
}

refresh();
setInterval(refresh, 1500);
setInterval(paintTimeLeft, 1000);
