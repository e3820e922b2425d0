// Rendering the daemon's views into the page: the queue and sweep tables, the
// hardware line, the selected scan's detail (state, reason, times, bracket, controls,
// latest frame, result links, live fit, multi-angle colour), its file listing and a
// calibrated setup.
// Reads the page's state; sends no command (main.js does).

import { $, page, FINAL, get, fetchFile, remember, timeLeft } from "./state.js";
import { escapeHtml, formatShutter, localTime, duration, percent } from "./text.js";
import { plot } from "./plot.js";
import { noteBatches, showColour } from "./colour.js";

// Writes every time-left slot of the page (queue rows and detail) from `timeLeft`.
export function paintTimeLeft() {
  document.querySelectorAll(".left[data-id]").forEach((el) => {
    const text = timeLeft(Number(el.dataset.id));
    el.textContent = text ? " · " + text : "";
  });
}

// Whether a queued scan waits for a start time still ahead.
function scheduled(s) {
  return s.state === "queued" && s.not_before && new Date(s.not_before).getTime() > Date.now();
}

// The state as the operator reads it: a queued scan with a later start is "scheduled".
export function stateLabel(s) {
  return scheduled(s) ? "scheduled" : s.state;
}

function liveTable(live, model) {
  const rows = (live || []).map((e) => {
    const f = e.fits[model];
    if (!f || f.error) return `<tr><td>${e.theta_l.length}</td><td colspan="7" class="muted">${escapeHtml(f ? f.error : "no fit")}</td></tr>`;
    const held = f.held_out_err_p ? f.held_out_err_p[1] : null;
    const change = f.change_p ? f.change_p[1] : null;
    return `<tr><td>${e.theta_l.length} (${e.theta_l[e.theta_l.length - 1]}°)</td><td>${e.samples}</td>` +
      `<td>${f.ks[1].toFixed(2)}</td><td>${f.kd[1].toFixed(2)}</td><td>${f.m.map((v) => v.toFixed(4)).join("/")}</td>` +
      `<td>${percent(f.err_p[1])}</td><td>${percent(held)}</td><td>${percent(change)}</td></tr>`;
  });
  return `<table><thead><tr><th>θL so far</th><th>points</th><th>Ks</th><th>Kd</th><th>m</th><th>ΔErr_p</th>` +
    `<th>at new θL</th><th>fit moved</th></tr></thead><tbody>${rows.join("")}</tbody></table>`;
}

export function bar(done, total) {
  const pct = total ? Math.round(100 * done / total) : 0;
  return `<div class="bar" title="${done}/${total}"><div style="width:${pct}%"></div></div>`;
}

// A calibrated setup as a table: field, value (± its standard uncertainty where it was
// estimated), and where it came from; the uncertainty block one row per key
// (`uncertainty.<key>`, its provenance per key).
export function setupTable(setup, id) {
  const cal = setup.calibration || {}, from = setup.provenance || {};
  const fmt = (v) => typeof v === "number" ? +v.toPrecision(6) : (v === null ? "–" : escapeHtml(JSON.stringify(v)));
  const row = (name, value, source) =>
    `<tr><td>${escapeHtml(name)}</td><td>${value}</td><td class="muted">${escapeHtml(typeof source === "string" ? source : "")}</td></tr>`;
  const rows = Object.entries(setup).filter(([k]) => k !== "calibration" && k !== "provenance").flatMap(([k, v]) => {
    if (k === "uncertainty" && v && typeof v === "object") {
      const fromU = from.uncertainty || {};
      return Object.entries(v).map(([u, x]) => row(`uncertainty.${u}`, fmt(x), typeof fromU === "string" ? fromU : fromU[u]));
    }
    const est = cal[k] && typeof cal[k] === "object" && cal[k].stderr != null ? ` ± ${+cal[k].stderr.toPrecision(2)}` : "";
    return [row(k, `${fmt(v)}${est}`, from[k])];
  });
  const notes = (cal.notes || []).map((n) => `<li>${escapeHtml(n)}</li>`).join("");
  return `<p class="ok">setup calibrated from scan ${id}: later scans use it</p>` +
    `<div class="scroll"><table class="setup"><thead><tr><th>field</th><th>value</th><th>from</th></tr></thead>` +
    `<tbody>${rows.join("")}</tbody></table></div>${notes ? `<ul class="muted">${notes}</ul>` : ""}`;
}

// What the queue row says beside the bar: the reason of a waiting scan, the error of a
// failed or interrupted one, the start of a scheduled one, the step of a running one.
function rowNote(s) {
  if (s.state === "waiting") return s.reason || s.error || "";
  if (s.error) return s.error;
  if (scheduled(s)) return `starts ${localTime(s.not_before)}`;
  if (s.state === "running") return s.current_step || "";
  return "";
}

// A queue row's note kept to a line: its first clause, up to 80 characters (the whole
// note is the cell's title and the detail's).
function brief(note) {
  const clause = note.split(" (")[0];
  return clause.length > 80 ? clause.slice(0, 79) + "…" : clause;
}

// The arm's line: its state in words, its angle while known, and its fault without
// what the state already says (after a stop the fault "arm position unknown: the
// controller reset or reconnected: home the arm" adds only its cause).
function armLine(a) {
  const unknown = ["alarm", "homing", "needs_homing", "needs_position", "disconnected"].includes(a.state);
  const state = {
    alarm: "alarm, position unknown, home it",
    needs_homing: "position unknown, home it",
    needs_position: "position unknown, declare it",
  }[a.state] || a.state;
  const fault = (a.error || "").replace(/^(arm )?position unknown:\s*/i, "")
    .replace(/[:,]?\s*(position unknown,?\s*)?home (before moving|the arm)$/i, "").trim();
  return `arm: ${state}` + (a.angle_deg != null && !unknown ? ` at ${a.angle_deg.toFixed(1)}°` : "") +
    (fault ? ` (${fault})` : "");
}

// The queue, the sweeps and the header's hardware line from what the page polls.
export function showOverview(scans, sweeps, hw) {
  scans.forEach(remember);
  noteBatches(scans);
  $("scans").innerHTML = scans.slice().reverse().map((s) =>
    `<tr data-id="${s.id}" class="${s.id === page.selected ? "sel" : ""}"><td>${s.id}</td><td>${escapeHtml(s.sample)}</td>` +
    `<td class="state-${s.state}">${stateLabel(s)}</td><td>${bar(s.progress.done, s.progress.total)}</td>` +
    `<td class="muted" title="${escapeHtml(rowNote(s))}">${escapeHtml(brief(rowNote(s)))}<span class="left" data-id="${s.id}"></span></td></tr>`).join("");
  // A sweep is coloured as waiting only while a scan of it waits for a person (else
  // its scans are merely queued behind another's); its start is "now" only while it
  // has not begun.
  $("sweeps").innerHTML = sweeps.slice().reverse().map((w) => {
    const person = (w.waits || []).some((x) => x.waiting);
    const start = w.start_at ? localTime(w.start_at) : w.progress.done ? "" : "now";
    return `<tr data-sweep="${w.id}" class="${w.id === page.sweep ? "sel" : ""}" title="open its scans"><td>${w.id}</td>` +
      `<td class="${w.state !== "waiting" || person ? "state-" + w.state : ""}">${w.state}</td><td>${bar(w.progress.done, w.progress.total)}</td>` +
      `<td class="muted">${escapeHtml(start)}</td></tr>`;
  }).join("");
  const a = hw.arm;
  $("arm").textContent = armLine(a);
  // After STOP ARM nothing runs until the operator homes the arm or resumes a scan:
  // the stop's note says so on every page that polls, and goes once the hold ends.
  const held = "nothing runs until the arm is homed or a scan resumed";
  const note = $("stopmsg");
  // A control's failure (red) stays as it is.
  if (hw.halted && !note.textContent.includes(held) && note.className !== "msg") {
    note.textContent = (note.textContent || "arm stopped") + "; " + held;
    note.className = "note";
  } else if (!hw.halted && note.textContent.includes(held)) {
    note.textContent = "";
  }
  $("armpos").hidden = a.state !== "needs_position";
  // Home is offered wherever it is needed: a lost position, and an emergency stop's
  // hold, which homing ends (also when the arm is at rest with its position known).
  const holdEnds = hw.halted && a.homes && ["idle", "hold"].includes(a.state);
  $("home").hidden = !(["needs_homing", "alarm", "hold"].includes(a.state) || holdEnds);
  const c = hw.camera;
  // A capture outlives the scan's pause or end by the exposure under way.
  const state = c.state === "capturing" && !scans.some((s) => s.state === "running") ? "finishing the exposure under way" : c.state;
  $("camera").textContent = `camera: ${c.model || "?"} ${state}` + (c.error ? ` (${c.error})` : "") + (hw.emulated ? " · emulated" : "");
  paintTimeLeft();
}

// Shows no frame: a scan without one never shows another scan's.
export function clearFrame() {
  const img = $("thumb");
  if (img.src.startsWith("blob:")) URL.revokeObjectURL(img.src);
  img.removeAttribute("src");
  delete img.dataset.scan;
  img.hidden = true;
  $("framecap").hidden = true;
  $("noframe").hidden = false;
}

// The frame's caption: its θL and exposure.
function frameCaption(f) {
  return f ? `θL ${f.theta_l}° · exposure ${formatShutter(f.shutter_s)}` : "";
}

// The model the scan's `auto` fit chose, why, and whether a colour shift is reported.
function choiceText(c) {
  if (!c) return "";
  return `<p id="dchoice"><b>model chosen: ${escapeHtml(c.model)}</b>` +
    (c.roughness ? ` <span class="muted">(roughness ${escapeHtml(c.roughness)})</span>` : "") +
    ` · colour shift ${c.colour_shift ? "reported" : "not reported"}` +
    `<br><span class="muted">${escapeHtml(c.reason)}</span></p>`;
}

// The bracket as used: the shutter times given, or those the metering chose (per θL
// in the tooltip), or that it is not metered yet.
function bracketText(b) {
  const list = (b.shutter_s || []).map(formatShutter).join(", ");
  if (!b.auto) return list;
  return list ? `auto: ${list}` : "auto (not metered yet)";
}

// Shows scan view `s` in the detail panel (and fetches its plot once it has ended).
export function show(s) {
  page.lastScan = s;
  remember(s);
  const p = s.progress;
  const ended = FINAL.includes(s.state);
  // Under the bar (a block of its own): no separator before it.
  const angles = p.theta_l ? `θL ${p.theta_l.captured}/${p.theta_l.total} captured, ${p.theta_l.processed} processed` : "";
  $("dtitle").textContent = `Scan ${s.id}: ${s.sample}`;
  const perTheta = (s.bracket.by_theta_l || []).map((m) => `θL ${m.theta_l}°: ${m.shutter_s.map(formatShutter).join(", ")}`).join("\n");
  // Work under way: the hardware step only while running, the processing step until
  // the scan has ended.
  const current = s.state === "running" && s.current_step ? s.current_step : "";
  const work = [
    current,
    // Once the hardware is done the current step is the processing's: said once.
    !ended && s.processing_step && s.processing_step !== current ? "processing: " + s.processing_step : "",
  ].filter((w) => w).join(" · ");
  const why = s.state === "waiting" ? s.reason || s.error : s.error;
  $("dstate").innerHTML = `<span class="state-${s.state}">${stateLabel(s)}</span> ${p.done}/${p.total}` +
    ` ${bar(p.done, p.total)}${angles}<span class="left" data-id="${s.id}"></span>` +
    `<div class="muted" id="dwork">${escapeHtml(work)}</div>` +
    `<div class="muted">θL ${s.theta_l.map((t) => t + "°").join(", ")} · bracket <span id="dbracket" title="${escapeHtml(perTheta)}">${escapeHtml(bracketText(s.bracket))}</span></div>` +
    (why ? `<div class="msg" id="dwhy">${s.state === "waiting" ? "waiting: " : ""}${escapeHtml(why)}</div>` : "");
  const times = [`created ${localTime(s.created)}`];
  if (scheduled(s)) times.push(`starts ${localTime(s.not_before)}`);
  if (s.started) times.push(`started ${localTime(s.started)}`);
  if (s.finished) times.push(`ended ${localTime(s.finished)}`);
  if (s.started && s.finished) times.push(`took ${duration((new Date(s.finished) - new Date(s.started)) / 1000)}`);
  $("dtimes").textContent = times.join(" · ") + " (local time)";
  paintTimeLeft();
  // Only the controls the scan's state allows (the daemon lists them).
  document.querySelectorAll("#detail button[data-act]").forEach((btn) => {
    const allowed = (s.actions || []).includes(btn.dataset.act);
    btn.disabled = !allowed;
    if (btn.dataset.act === "confirm") btn.hidden = !allowed;
  });
  if (!page.calibrating) $("calibrate").disabled = !(ended && s.results.thumbnail);
  $("livebox").hidden = !(s.live && s.live.length);
  $("live").innerHTML = liveTable(s.live, $("livemodel").value);
  // A frame is fetched once the journal records the capture that made it (its file may
  // land a moment before).
  if (!s.results.thumbnail) clearFrame();
  else if (s.frame && p.steps.done !== page.lastDone) {
    page.lastDone = p.steps.done;
    const caption = frameCaption(s.frame);
    fetchFile(`${s.results.thumbnail}?t=${Date.now()}`).then(({ url }) => {
      if (page.selected !== s.id) { URL.revokeObjectURL(url); return; }
      const img = $("thumb");
      if (img.src.startsWith("blob:")) URL.revokeObjectURL(img.src);
      img.src = url;
      img.dataset.scan = s.id;
      img.hidden = false;
      $("framecap").textContent = caption;
      $("framecap").hidden = !caption;
      $("noframe").hidden = true;
    }, () => { /* no frame yet */ });
  }
  $("choice").innerHTML = choiceText(s.choice);
  showColour(s);
  const links = [];
  if (s.results.samples) links.push(`<a href="${s.results.samples}" download>samples.csv</a>`);
  for (const [m, url] of Object.entries(s.results.fits)) links.push(`<a href="${url}" download>fit ${m}</a>`);
  for (const url of s.results.hdr) links.push(`<a href="${url}" download>${url.split("/").pop()}</a>`);
  if (s.state !== "queued") links.push(`<a href="${s.links.self}/archive" download id="archive">whole scan (.tar)</a>`);
  if (s.results.samples) links.push(`<a href="${s.links.self}/report" target="_blank" id="report">report (HTML)</a>`);
  $("results").innerHTML = `<p>${links.join(" · ")}${links.length ? " · " : ""}<a href="#" id="allfiles">all files</a></p>`;
  $("allfiles").addEventListener("click", (e) => { e.preventDefault(); listFiles(s); });
  if (ended && Object.keys(s.results.fits).length && !$("plot").innerHTML) plot(s.id);
}

// The scan's files as links, grouped by directory (the API gives a flat JSON list).
async function listFiles(s) {
  const box = $("files");
  if (!box.hidden) { box.hidden = true; return; }
  const res = await get(s.links.files);
  const files = res.ok ? await res.json() : [];
  const groups = {};
  for (const f of files) {
    const cut = f.lastIndexOf("/");
    (groups[cut < 0 ? "" : f.slice(0, cut)] ||= []).push(f);
  }
  box.innerHTML = files.length ? Object.entries(groups).map(([dir, list]) =>
    `<h3>${escapeHtml(dir || "scan directory")} <span class="muted">(${list.length})</span></h3><ul>` +
    list.map((f) => `<li><a download href="${s.links.files}/${f.split("/").map(encodeURIComponent).join("/")}">` +
      `${escapeHtml(f.slice(f.lastIndexOf("/") + 1))}</a></li>`).join("") + "</ul>").join("")
    : `<p class="muted">no files yet</p>`;
  box.hidden = false;
}

