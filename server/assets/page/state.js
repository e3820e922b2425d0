// The page's state and its talk with the daemon: the token (kept in localStorage, sent
// in a header), the API calls, the scan selected, the latest view of each scan (for
// the time left), and a scan's event stream. Writes no HTML.

import { duration } from "./text.js";

export const $ = (id) => document.getElementById(id);

const tokenInput = $("token");
tokenInput.value = localStorage.getItem("gonio-token") || "";
tokenInput.addEventListener("change", () => localStorage.setItem("gonio-token", tokenInput.value.trim()));

// Whether a token is entered.
export const hasToken = () => tokenInput.value.trim() !== "";

// What the page is showing: the scan selected, the steps done when its frame was last
// fetched, its latest view, whether a calibration from it is under way, and the sweep
// whose panel is open.
export const page = { selected: null, lastDone: -1, lastScan: null, calibrating: false, sweep: null };

export const FINAL = ["done", "failed", "cancelled"];

// The token goes in a header on every request once entered (reads need it when the
// daemon is open beyond loopback), never in a URL, which would end up in logs.
const auth = () => (hasToken() ? { "Authorization": "Bearer " + tokenInput.value.trim() } : {});
export const get = (path, options) => fetch(path, { ...options, headers: auth() });

// The JSON of an answer; an error "status: message" when it is not a success.
async function answer(res) {
  let json = {};
  try { json = await res.json(); } catch (e) { /* no body */ }
  if (!res.ok) throw new Error(res.status + ": " + (json.error || res.statusText));
  return json;
}

export async function getJson(path) {
  return answer(await get(path));
}

// A JSON body sent with `method` and the token.
async function send(method, path, body) {
  return answer(await fetch(path, {
    method,
    headers: { "Content-Type": "application/json", ...auth() },
    body: JSON.stringify(body || {}),
  }));
}

export const post = (path, body) => send("POST", path, body);
export const patch = (path, body) => send("PATCH", path, body);

// What the page polls, all at once: the scans, the sweeps, the hardware and the
// selected scan's own view (with what its journal tells), which also stands for it in
// the list, so that one answer draws the header, the queue and the detail alike.
export async function overview(selected) {
  const [scans, sweeps, hw, detail] = await Promise.all([
    getJson("/api/scans"), getJson("/api/sweeps"), getJson("/api/hardware"),
    selected === null ? null : getJson(`/api/scans/${selected}`).catch(() => null),
  ]);
  const at = detail ? scans.findIndex((s) => s.id === detail.id) : -1;
  if (at >= 0) scans[at] = detail;
  return { scans, sweeps, hw, detail };
}

// A file fetched with the token, as an object URL, and the name the daemon gives it.
export async function fetchFile(path) {
  const res = await get(path);
  if (!res.ok) throw new Error(res.status + ": " + res.statusText);
  const disposition = res.headers.get("Content-Disposition") || "";
  const name = (/filename="([^"]+)"/.exec(disposition) || [])[1] || path.split("/").pop();
  return { url: URL.createObjectURL(await res.blob()), name };
}

// The latest view of each scan and when it arrived (from the list or the event stream):
// the queue row and the detail panel read the time left from the same one.
const latest = new Map();

// Keeps `s` as the latest view of its scan.
export function remember(s) {
  latest.set(s.id, { view: s, at: Date.now() });
}

// The time left of scan `id`, counted down from its latest view: only while it runs
// (a queued, scheduled, paused, waiting, interrupted or ended scan has none).
export function timeLeft(id) {
  const seen = latest.get(id);
  if (!seen || seen.view.state !== "running" || seen.view.progress.eta_s == null) return "";
  const left = seen.view.progress.eta_s - (Date.now() - seen.at) / 1000;
  return left >= 1 ? `about ${duration(left)} left` : "finishing";
}

let events = null;

// Follows scan `id`'s event stream, calling `changed` whenever the scan changes (the
// page then polls, so that the whole page shows the new state at once), and stops
// following the one before.
export function watch(id, changed) {
  if (events) events.abort();
  events = new AbortController();
  follow(id, events.signal, changed);
}

// Reads the scan's event stream with fetch, so that it carries the token (EventSource
// cannot send headers); reconnects while the scan is not final, as EventSource would.
async function follow(id, signal, changed) {
  while (!signal.aborted) {
    try {
      const res = await get(`/api/scans/${id}/events`, { signal });
      if (!res.ok) throw new Error(res.status);
      const reader = res.body.pipeThrough(new TextDecoderStream()).getReader();
      let buffer = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buffer += value;
        let end;
        while ((end = buffer.indexOf("\n\n")) >= 0) {
          const lines = buffer.slice(0, end).split("\n");
          buffer = buffer.slice(end + 2);
          const data = lines.filter((l) => l.startsWith("data:")).map((l) => l.slice(5).trim()).join("\n");
          if (!lines.some((l) => /^event: ?progress$/.test(l)) || !data) continue;
          const s = JSON.parse(data);
          if (signal.aborted || s.id !== page.selected) return;
          changed(s);
          if (FINAL.includes(s.state)) return;
        }
      }
    } catch (err) { /* the daemon may be restarting */ }
    if (!signal.aborted) await new Promise((r) => setTimeout(r, 2000));
  }
}
