// The selected scan's multi-angle colour (CIELAB at the standard aspecular angles,
// values ± U, a swatch per angle) and a batch judged against it, as `gonio colour` and
// `gonio compare` state them: fetched once a scan has ended with a fit. Writes #colour
// only.

import { $, page, getJson } from "./state.js";
import { escapeHtml } from "./text.js";

// The scan and end time #colour shows, and the ended scans with a fit (id → sample).
const shown = { key: null };
let batches = new Map();

// `value ± U`, or a dash where the value is not finite.
const pm = (q, digits = 1) => (q && Number.isFinite(q.value) && Number.isFinite(q.expanded)
  ? `${q.value.toFixed(digits)} ± ${q.expanded.toFixed(digits)}` : "–");

function colourTable(c) {
  const rows = c.angles.map((a) => `<tr><td>${a.aspecular}°</td><td>${escapeHtml(a.origin)}` +
    (a.beyond_data ? ` <span class="warn" title="brighter than the measured columns support at this geometry">beyond the data: not a reading</span>` : "") + "</td>" +
    ["L", "a", "b", "C", "h"].map((k) => `<td>${pm(a[k])}</td>`).join("") +
    `<td><span class="swatch" style="background:${a.swatch.hex}" title="${a.swatch.hex}"></span>` +
    (a.swatch.in_gamut ? "" : ` <span class="warn">out of gamut</span>`) + "</td></tr>").join("");
  const flop = c.flop_index ? `<p class="fitparams" id="flop">flop index ${pm(c.flop_index, 2)}</p>` : "";
  return `<h3>Multi-angle colour</h3>` +
    `<p class="muted">${escapeHtml(c.conditions)}, 45° illumination, values ± U (k = ${c.coverage_factor}) from the ` +
    `${escapeHtml(c.model)} model; “data” where the geometry lies inside the measured range, “model” outside it. ` +
    `The camera RGB → XYZ transform's own error is in the uncertainties (ΔE00 median ` +
    `${c.transform.delta_e00_median.toFixed(2)} over its test spectra). A swatch is a display colour, not a measurement.</p>` +
    `<div class="scroll"><table id="colourtable" class="params"><thead><tr><th>aspecular</th><th>from</th>` +
    `<th>L*</th><th>a*</th><th>b*</th><th>C*</th><th>h °</th><th>sRGB</th></tr></thead><tbody>${rows}</tbody></table></div>` +
    flop +
    `<label for="batch">Judge a batch against this scan as its standard</label>` +
    `<select id="batch"></select><div id="comparison"></div>`;
}

function comparisonTable(k) {
  const rows = k.angles.map((a) => `<tr><td>${a.aspecular}°</td>` +
    ["delta_L", "delta_C", "delta_H", "delta_e00"].map((q) => `<td>${pm(a[q], 2)}</td>`).join("") +
    `<td>${a.tolerance}</td><td class="verdict-${a.verdict}">${escapeHtml(a.verdict)}</td></tr>`).join("");
  const flop = k.flop_index ? `<p class="fitparams">flop index ${k.flop_index.standard.toFixed(2)} → ` +
    `${k.flop_index.batch.toFixed(2)}: Δ ${pm(k.flop_index.delta, 2)}</p>` : "";
  return `<p id="overall"><b>scan ${k.batch} against scan ${k.standard}: <span class="verdict-${k.overall}">${escapeHtml(k.overall)}</span></b>` +
    (k.angles.some((a) => a.verdict === "undecided")
      ? ` <span class="muted">(an angle undecided: its interval straddles the tolerance)</span>` : "") +
    ` <span class="muted">(lines both scans share cancel)</span></p>` +
    `<div class="scroll"><table id="comparetable" class="params"><thead><tr><th>aspecular</th><th>ΔL*</th><th>ΔC*</th>` +
    `<th>ΔH*</th><th>ΔE00</th><th>tolerance</th><th>verdict</th></tr></thead><tbody>${rows}</tbody></table></div>` + flop;
}

// The choices of the batch list: every other ended scan with a fit.
function fillBatches(id) {
  const select = $("batch");
  if (!select) return;
  const chosen = select.value;
  select.innerHTML = `<option value="">choose a scan</option>` + [...batches].filter(([b]) => b !== id)
    .map(([b, sample]) => `<option value="${b}">scan ${b}: ${escapeHtml(sample)}</option>`).join("");
  select.value = [...select.options].some((o) => o.value === chosen) ? chosen : "";
}

// Notes the ended scans with a fit from the queue the page polls.
export function noteBatches(scans) {
  batches = new Map(scans.filter((s) => s.state === "done" && Object.keys(s.results.fits).length)
    .map((s) => [s.id, s.sample]));
  if (page.selected != null) fillBatches(page.selected);
}

async function judge(id) {
  const batch = $("batch").value;
  const box = $("comparison");
  if (!batch) { box.innerHTML = ""; return; }
  box.innerHTML = `<p class="muted">comparing…</p>`;
  try {
    const k = await getJson(`/api/scans/${id}/compare/${batch}`);
    if (page.selected === id && $("batch").value === batch) box.innerHTML = comparisonTable(k);
  } catch (e) {
    box.innerHTML = `<p class="msg">${escapeHtml(e.message)}</p>`;
  }
}

// Shows no scan's colour (another scan was selected): the next view fetches its own.
export function clearColour() {
  shown.key = null;
  $("colour").innerHTML = "";
}

// Shows scan view `s`'s colour once it has ended with a fit (fetched once per scan end).
export async function showColour(s) {
  const box = $("colour");
  const key = s.state === "done" && Object.keys(s.results.fits).length ? `${s.id}@${s.finished}` : null;
  if (key === shown.key) return;
  shown.key = key;
  box.innerHTML = "";
  if (!key) return;
  try {
    const c = await getJson(`/api/scans/${s.id}/colour`);
    if (shown.key !== key) return;
    box.innerHTML = colourTable(c);
    fillBatches(s.id);
    $("batch").addEventListener("change", () => judge(s.id));
  } catch (e) {
    if (shown.key === key) box.innerHTML = `<p class="muted">no multi-angle colour: ${escapeHtml(e.message)}</p>`;
  }
}
