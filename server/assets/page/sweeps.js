// A sweep's panel: its state, the sample changes it will wait for (estimated, local
// time), its controls (pause, resume or cancel the whole sweep in one request; a new
// start time while it is scheduled) and its scans, each row opening that scan.

import { $, page, post, patch } from "./state.js";
import { escapeHtml, localTime } from "./text.js";
import { bar, stateLabel } from "./render.js";

// The sample changes a sweep will wait for, in words: who must mount what, and about
// when (the daemon's estimate, assuming each change is confirmed at once).
export function waitsText(waits) {
  if (!waits || !waits.length) return "";
  return "a person is needed: " + waits.map((w) => w.waiting
    ? `mount ${w.sample} for scan ${w.scan_id}: waiting since ${localTime(w.at)}`
    : `mount ${w.sample} for scan ${w.scan_id} at about ${localTime(w.at)}`).join("; ") + " (local time)";
}

// Draws the panel of the sweep selected, from the polled sweeps.
export function showSweep(sweeps) {
  if (page.sweep === null) return;
  const w = sweeps.find((x) => x.id === page.sweep);
  if (!w) { $("sweepdetail").hidden = true; return; }
  $("sweepdetail").hidden = false;
  $("swtitle").textContent = `Sweep ${w.id}: ${w.request.samples.join(", ")}`;
  $("swstate").innerHTML = `<span class="state-${w.state}">${w.state}</span> ${w.progress.done}/${w.progress.total}` +
    ` ${bar(w.progress.done, w.progress.total)}` +
    `<div class="muted">${escapeHtml(w.start_at ? `start ${localTime(w.start_at)} (local time)` : "start at once")}</div>`;
  const text = waitsText(w.waits);
  $("swwaits").innerHTML = text ? `<p class="note" id="swwaitnote">${escapeHtml(text)}</p>` : "";
  document.querySelectorAll("#sweepdetail button[data-sweep-act]").forEach((btn) => {
    btn.disabled = !w.actions.includes(btn.dataset.sweepAct);
  });
  $("swstart").hidden = !w.actions.includes("reschedule");
  $("swscans").innerHTML = w.scans.map((s) =>
    `<tr data-id="${s.id}" class="${s.id === page.selected ? "sel" : ""}"><td>${s.id}</td><td>${escapeHtml(s.sample)}</td>` +
    `<td class="state-${s.state}">${stateLabel(s)}</td><td>${bar(s.progress.done, s.progress.total)}</td></tr>`).join("");
}

// Wires the sweep rows, the panel's controls and its scan rows; `selectScan` opens a
// scan, `refresh` polls again.
export function initSweeps(selectScan, refresh) {
  $("sweeps").addEventListener("click", (e) => {
    const tr = e.target.closest("tr[data-sweep]");
    if (!tr) return;
    page.sweep = Number(tr.dataset.sweep);
    $("swmsg").textContent = "";
    refresh();
  });
  $("swscans").addEventListener("click", (e) => {
    const tr = e.target.closest("tr[data-id]");
    if (tr) selectScan(Number(tr.dataset.id));
  });
  document.querySelectorAll("#sweepdetail button[data-sweep-act]").forEach((btn) => {
    btn.addEventListener("click", async () => {
      if (page.sweep === null) return;
      try {
        await post(`/api/sweeps/${page.sweep}/${btn.dataset.sweepAct}`);
        $("swmsg").textContent = "";
      } catch (err) { $("swmsg").textContent = err.message; }
      refresh();
    });
  });
  $("swstart").addEventListener("submit", async (e) => {
    e.preventDefault();
    if (page.sweep === null) return;
    try {
      // datetime-local gives the local wall time without a zone: Date reads it as local.
      const at = $("swstartat").value ? new Date($("swstartat").value).toISOString() : null;
      await patch(`/api/sweeps/${page.sweep}`, { start_at: at });
      $("swmsg").textContent = "";
    } catch (err) { $("swmsg").textContent = err.message; }
    refresh();
  });
}
