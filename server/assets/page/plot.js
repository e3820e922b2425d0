// The fit plot of an ended scan: measured β and each model's fitted β against θr, one
// channel (a colour per θL) or all three (a colour per channel), on a log or linear
// β axis, with each fit's parameters and uncertainty budget below it.
//
// Drawn here as SVG by hand rather than through a vendored plotting library (uPlot was
// the candidate): the browser tests read the figure's own elements (the axis lines,
// tick texts, `circle.marker`, `path.fit-<model>` and the legend box, inside the plot
// area, below it on a narrow screen), which a canvas library does not have, and the
// figure needs nothing a library would add but values under the pointer. Those are
// here: moving over (or tapping) the plot rings the nearest measured point and writes
// its θL, θr, measured β and every model's fitted β at that point below the figure.

import { $, get, page } from "./state.js";
import { escapeHtml } from "./text.js";

// Tick values at round numbers (1, 2 or 5 × 10^k apart) covering [lo, hi].
function niceTicks(lo, hi, target) {
  const span = hi - lo;
  if (!(span > 0)) return [lo];
  const raw = span / target, mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((f) => f * mag).find((v) => v >= raw * 0.999);
  const ticks = [];
  for (let k = Math.ceil(lo / step - 1e-9); k * step <= hi + 1e-9 * span; k++) ticks.push(+(k * step).toPrecision(12));
  return ticks;
}

// Plot choices, kept across scans.
const plotChoice = { channel: 1, scale: "log" };
let plotData = null;

// The scan whose plot data is being fetched (the page asks at every poll until drawn).
let fetching = null;

// Fetches scan `id`'s plot data and draws it, unless another scan was selected meanwhile.
export async function plot(id) {
  if (fetching === id) return;
  fetching = id;
  try {
    const res = await get(`/api/scans/${id}/plot`);
    if (!res.ok || page.selected !== id) return;
    plotData = await res.json();
    if (!plotData.samples.length) return;
    drawPlot();
  } finally {
    if (fetching === id) fetching = null;
  }
}

// Distinct colours: per θL (a categorical palette) when one channel is shown, per
// channel (red, green, blue) when all three are.
const THETA_COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"];
const CHANNEL_COLORS = ["#d62728", "#2ca02c", "#1f77b4"];
const CHANNEL_NAMES = ["red", "green", "blue"];
// Models told apart by line style; Cook–Torrance is drawn last and widest, so the
// Fresnel variant (dashed) never hides it.
const MODEL_STYLES = {
  "cook-torrance-fresnel": { dash: "6 3", width: 1.4, name: "Cook–Torrance–Fresnel" },
  "ward": { dash: "2 2", width: 1.4, name: "Ward" },
  "cook-torrance": { dash: "", width: 1.8, name: "Cook–Torrance" },
};

// The plot's width in CSS pixels: that of its box, between 280 and 640.
function drawnWidth() {
  return Math.round(Math.min(640, Math.max(280, $("plot").clientWidth || 600)));
}

// Drawn again when the window's width changes the plot's.
window.addEventListener("resize", () => {
  const svg = $("plot").querySelector("svg");
  if (plotData && svg && svg.viewBox.baseVal.width !== drawnWidth()) drawPlot();
});

function drawPlot() {
  const data = plotData, pts = data.samples;
  const order = Object.keys(MODEL_STYLES);
  const fits = Object.entries(data.fits).sort(([a], [b]) => order.indexOf(a) - order.indexOf(b));
  const channels = plotChoice.channel === "all" ? [0, 1, 2] : [plotChoice.channel];
  const log = plotChoice.scale === "log";
  const thetas = [...new Set(pts.map((p) => p.theta_l))].sort((a, b) => b - a);
  const colour = (theta, c) => channels.length > 1 ? CHANNEL_COLORS[c] : THETA_COLORS[thetas.indexOf(theta) % THETA_COLORS.length];
  // Drawn at the width it is shown at (at most 640 px), so that its text keeps its
  // CSS size on a narrow screen instead of being scaled down with the figure.
  const W = drawnWidth(), L = 62, R = 10, T = 10, B = 300;
  const xs = pts.map((p) => p.theta_r);
  const xmin = Math.min(...xs), xmax = Math.max(...xs);
  const values = channels.flatMap((c) => [...pts.map((p) => p.rgb[c]), ...fits.flatMap(([, f]) => f.predicted.map((q) => q[c]))]);
  const X = (x) => L + (x - xmin) / (xmax - xmin || 1) * (W - L - R);
  let Y, yTicks, hidden = 0, label;
  if (log) {
    // Log β: the diffuse level and the peak both readable; β ≤ 0 cannot be drawn.
    const positive = values.filter((v) => v > 0);
    const lo = Math.floor(Math.log10(Math.min(...positive))), hi = Math.ceil(Math.log10(Math.max(...positive)));
    const top = Math.max(hi, lo + 1);
    Y = (v) => B - (Math.log10(v) - lo) / (top - lo) * (B - T);
    yTicks = [];
    for (let k = lo; k <= top; k++) yTicks.push([10 ** k, k >= 0 && k < 6 ? String(10 ** k) : `1e${k}`]);
    hidden = channels.reduce((n, c) => n + pts.filter((p) => !(p.rgb[c] > 0)).length, 0);
  } else {
    const top = Math.max(...values);
    const ticks = niceTicks(0, top, 4);
    const yStep = ticks.length > 1 ? ticks[1] - ticks[0] : (top || 1);
    const ymax = Math.max(yStep, Math.ceil(top / yStep - 1e-9) * yStep);
    if (ticks[ticks.length - 1] < ymax) ticks.push(+ymax.toPrecision(12));
    Y = (v) => B - v / ymax * (B - T);
    yTicks = ticks.map((t) => [t, String(t)]);
  }
  label = `β ${log ? "(log scale)" : ""} — % of a perfect white's green`;
  // The legend: colours, then line styles; inside the plot area, in the top corner
  // (right, else left) that hides fewer of the drawn values, or below the figure on a
  // narrow screen, where it would cover much of it.
  const entries = (channels.length > 1
    ? channels.map((c) => ({ swatch: "marker", col: CHANNEL_COLORS[c], text: CHANNEL_NAMES[c] }))
    : thetas.map((t) => ({ swatch: "marker", col: colour(t, channels[0]), text: `θL ${t}°` })))
    .concat([{ swatch: "marker", col: "#444", text: "measured" }])
    .concat(fits.map(([m]) => ({ swatch: "line", col: "#444", dash: (MODEL_STYLES[m] || {}).dash || "", text: (MODEL_STYLES[m] || { name: m }).name })));
  const below = W < 480;
  const lw = 170, lh = 14 * entries.length + 8, ly = below ? B + 44 : T + 4;
  const H = below ? ly + lh + 4 : B + 40;
  const drawn = channels.flatMap((c) => pts.flatMap((p, i) => [[p.theta_r, p.rgb[c]], ...fits.map(([, f]) => [p.theta_r, f.predicted[i][c]])]))
    .filter(([, v]) => !log || v > 0).map(([x, v]) => [X(x), Y(v)]);
  const under = (lx) => drawn.filter(([x, y]) => x >= lx && x <= lx + lw && y >= ly && y <= ly + lh).length;
  const right = W - R - lw - 4, left = L + 4;
  const lx = below ? L : under(left) < under(right) ? left : right;
  let svg = `<svg viewBox="0 0 ${W} ${H}" role="img" aria-label="measured and fitted β against θr">`;
  svg += `<line x1="${L}" y1="${B}" x2="${W - R}" y2="${B}" stroke="#888"/><line x1="${L}" y1="${T}" x2="${L}" y2="${B}" stroke="#888"/>`;
  for (const [v, text] of yTicks) {
    svg += `<line x1="${L - 3}" y1="${Y(v)}" x2="${L}" y2="${Y(v)}" stroke="#888"/>`;
    svg += `<text x="${L - 5}" y="${Y(v) + 4}" text-anchor="end">${text}</text>`;
  }
  for (const x of niceTicks(xmin, xmax, Math.max(3, Math.min(6, Math.floor((W - L - R) / 80))))) {
    svg += `<line x1="${X(x)}" y1="${B}" x2="${X(x)}" y2="${B + 3}" stroke="#888"/>`;
    svg += `<text x="${X(x)}" y="${B + 15}" text-anchor="middle">${x}°</text>`;
  }
  svg += `<text class="xlabel" x="${(W + L) / 2}" y="${B + 32}" text-anchor="middle">θr, viewing angle (degrees)</text>`;
  svg += `<text class="ylabel" transform="translate(14 ${(T + B) / 2}) rotate(-90)" text-anchor="middle">${escapeHtml(label)}</text>`;
  const byTheta = {};
  pts.forEach((p, i) => { (byTheta[p.theta_l] ||= []).push(i); });
  const clip = `<clipPath id="plotarea"><rect x="${L}" y="${T}" width="${W - L - R}" height="${B - T}"/></clipPath>`;
  // Lines by model, drawn in MODEL_STYLES order (Cook–Torrance over the others).
  const lines = Object.fromEntries(fits.map(([m]) => [m, ""]));
  let markers = "";
  for (const [theta, idx] of Object.entries(byTheta)) {
    idx.sort((a, b) => pts[a].theta_r - pts[b].theta_r);
    const step = Math.max(1, Math.floor(idx.length / 40));
    for (const c of channels) {
      const col = colour(Number(theta), c);
      for (let k = 0; k < idx.length; k += step) {
        const p = pts[idx[k]];
        if (log && !(p.rgb[c] > 0)) continue;
        markers += `<circle class="marker" cx="${X(p.theta_r).toFixed(1)}" cy="${Y(p.rgb[c]).toFixed(1)}" r="2.6" fill="none" stroke="${col}" stroke-width="1"/>`;
      }
      for (const [model, fit] of fits) {
        const st = MODEL_STYLES[model] || { dash: "", width: 1 };
        const seg = idx.filter((i) => !log || fit.predicted[i][c] > 0);
        const d = seg.map((i, k) => `${k ? "L" : "M"}${X(pts[i].theta_r).toFixed(1)},${Y(fit.predicted[i][c]).toFixed(1)}`).join("");
        lines[model] += `<path class="fit fit-${model}" d="${d}" fill="none" stroke="${col}" stroke-width="${st.width}" stroke-dasharray="${st.dash}"/>`;
      }
    }
  }
  svg += `<defs>${clip}</defs><g clip-path="url(#plotarea)">${markers}${fits.map(([m]) => lines[m]).join("")}</g>`;
  svg += `<g class="legend-box"><rect x="${lx}" y="${ly}" width="${lw}" height="${lh}" fill="#fff" fill-opacity="0.85" stroke="#ccc"/>`;
  entries.forEach((e, i) => {
    const y = ly + 14 + 14 * i;
    svg += e.swatch === "line"
      ? `<line x1="${lx + 6}" y1="${y - 4}" x2="${lx + 26}" y2="${y - 4}" stroke="${e.col}" stroke-width="1.6" stroke-dasharray="${e.dash}"/>`
      : `<circle cx="${lx + 16}" cy="${y - 4}" r="2.6" fill="none" stroke="${e.col}"/>`;
    svg += `<text class="legend" x="${lx + 32}" y="${y}">${escapeHtml(e.text)}</text>`;
  });
  svg += "</g>";
  svg += `<circle class="hover" r="4.5" fill="none" stroke="#000" stroke-width="1.5" visibility="hidden"/></svg>`;
  const rgb = (v, digits) => v.map((x) => x.toFixed(digits)).join("/");
  const params = fits.map(([model, fit]) => {
    const p = fit.params;
    // ρd: the diffuse albedo on one scale for both models (Ward's Kd is π times
    // Cook–Torrance's for the same surface).
    const albedo = p.rho_d ? `, ρd ${rgb(p.rho_d, 3)}` : "";
    // A Nelder–Mead fit that ended above the global minimum is not the optimum.
    const above = p.global_minimum && !p.global_minimum.reached
      ? ` — not the optimum: Nelder–Mead ended at ${(p.loss / p.global_minimum.loss).toFixed(2)}× the robust fit's loss` : "";
    return `<p class="fitparams">${escapeHtml((MODEL_STYLES[model] || { name: model }).name)} (${model}): ` +
      `Kd ${rgb(p.kd, 2)}, Ks ${rgb(p.ks, 2)}${p.ks_90 ? ` (90°: ${rgb(p.ks_90, 2)})` : ""}, ` +
      `m ${p.m.map((v, k) => v.toFixed(3) + (p.ci95 ? ` [${p.ci95.m[k].map((b) => b.toFixed(3)).join("–")}]` : "")).join("/")}${albedo}${escapeHtml(above)}</p>` +
      budgetTable(p.budget);
  }).join("");
  const opt = (value, text, current) => `<option value="${value}"${String(current) === String(value) ? " selected" : ""}>${text}</option>`;
  const controls = `<p class="controls muted"><label>channel <select id="plotchannel">` +
    [0, 1, 2].map((c) => opt(c, CHANNEL_NAMES[c] + " (colour per θL)", plotChoice.channel)).join("") + opt("all", "all three (colour per channel)", plotChoice.channel) +
    `</select></label><label>β axis <select id="plotscale">${opt("log", "log", plotChoice.scale)}${opt("linear", "linear", plotChoice.scale)}</select></label></p>`;
  const note = hidden ? `<p class="muted">${hidden} measured β ≤ 0 not drawn on the log axis</p>` : "";
  const readout = `<p class="readout muted" id="plotreadout">${HOVER_HINT}</p>`;
  $("plot").innerHTML = controls + svg + readout + note + params;
  followPointer({ pts, fits, channels, log, X, Y, box: { L, R, T, B, W }, colour });
  $("plotchannel").addEventListener("change", (e) => { plotChoice.channel = e.target.value === "all" ? "all" : Number(e.target.value); drawPlot(); });
  $("plotscale").addEventListener("change", (e) => { plotChoice.scale = e.target.value; drawPlot(); });
}

// A fit's uncertainty budget (docs/ARCHITECTURE.md, "Uncertainty budget"): per
// parameter its value, each source's standard uncertainty, u_c, U = k·u_c and the
// interval; the summary names each parameter's largest source.
function budgetTable(b) {
  if (!b) return "";
  const names = [];
  const rows = [];
  const P = b.parameters;
  for (const [key, set] of [["Kd", P.kd], ["Ks", P.ks], ["Ks_90", P.ks_90]]) {
    if (set) set.forEach((x, c) => { names.push(`${key} ${CHANNEL_NAMES[c]}`); rows.push(x); });
  }
  P.m.forEach((x, c) => { names.push(P.m.length === 1 ? "m" : `m ${CHANNEL_NAMES[c]}`); rows.push(x); });
  const sources = rows[0].contributions.map((c) => c.source.replace(/_/g, " "));
  // Minus signs as U+2212, at which no line breaks (`1.7e-3` never splits as `1.7e-`).
  const minus = (t) => t.replace(/-/g, "\u2212");
  const num = (v) => minus(v === 0 ? "0" : Math.abs(v) >= 0.01 && Math.abs(v) < 1e4 ? v.toPrecision(3) : v.toExponential(1));
  // Uncertainties to two significant digits (GUM 7.2.6).
  const unc = (v) => minus(v === 0 ? "0" : Math.abs(v) >= 0.01 && Math.abs(v) < 1e4 ? v.toPrecision(2) : v.toExponential(1));
  const largest = (x) => x.contributions.reduce((a, c) => (c.u > a.u ? c : a)).source.replace(/_/g, " ");
  const head = `<tr><th></th><th>value</th>${sources.map((s) => `<th>${escapeHtml(s)}</th>`).join("")}<th>u<sub>c</sub></th><th>U (k = ${b.coverage_factor})</th><th>interval</th></tr>`;
  const body = rows.map((x, i) => `<tr><th>${escapeHtml(names[i])}</th><td>${num(x.value)}</td>` +
    x.contributions.map((c) => `<td>${unc(c.u)}</td>`).join("") +
    `<td>${unc(x.combined)}</td><td>${unc(x.expanded)}</td><td>[${num(x.interval[0])},<wbr> ${num(x.interval[1])}]</td></tr>`).join("");
  const summary = `uncertainty budget: ` + rows.map((x, i) => `${escapeHtml(names[i])} ± ${num(x.expanded)}`).join(", ") +
    ` (k = ${b.coverage_factor}); largest source of Ks ${CHANNEL_NAMES[1]}: ${escapeHtml(largest(P.ks[1]))}; residuals ${b.residual_to_noise.toFixed(2)}× the noise`;
  return `<details class="budget"><summary>${summary}</summary><div class="scroll"><table><thead>${head}</thead><tbody>${body}</tbody></table></div></details>`;
}

const HOVER_HINT = "move over or tap the plot for the values at a point";

// Rings the measured point nearest the pointer (any sample, also those between the
// drawn markers) and writes its values below the figure: θL, θr, the measured β of
// each channel shown and each model's fitted β there. A mouse leaving the plot area
// clears it; a tap keeps it.
function followPointer({ pts, fits, channels, log, X, Y, box, colour }) {
  const svg = $("plot").querySelector("svg"), ring = svg.querySelector("circle.hover"), out = $("plotreadout");
  const clear = () => { ring.setAttribute("visibility", "hidden"); out.textContent = HOVER_HINT; };
  const value = (v) => (Math.abs(v) >= 0.01 && Math.abs(v) < 1e4) || v === 0 ? +v.toPrecision(3) : v.toExponential(2);
  const name = (m) => (MODEL_STYLES[m] || { name: m }).name;
  const onMove = (e) => {
    const ctm = svg.getScreenCTM();
    if (!ctm) return;
    const q = new DOMPoint(e.clientX, e.clientY).matrixTransform(ctm.inverse());
    const edge = 5; // markers on the plot area's edge stay within reach
    if (q.x < box.L - edge || q.x > box.W - box.R + edge || q.y < box.T - edge || q.y > box.B + edge) {
      if (e.pointerType === "mouse") clear();
      return;
    }
    let best = null;
    pts.forEach((p, i) => {
      for (const c of channels) {
        if (log && !(p.rgb[c] > 0)) continue;
        const d = (X(p.theta_r) - q.x) ** 2 + (Y(p.rgb[c]) - q.y) ** 2;
        if (!best || d < best.d) best = { d, i, c };
      }
    });
    if (!best) return clear();
    const p = pts[best.i];
    ring.setAttribute("cx", X(p.theta_r).toFixed(1));
    ring.setAttribute("cy", Y(p.rgb[best.c]).toFixed(1));
    ring.setAttribute("stroke", colour(p.theta_l, best.c));
    ring.setAttribute("visibility", "visible");
    const at = (rgb) => channels.map((c) => value(rgb[c])).join("/");
    const which = channels.length > 1 ? "β red/green/blue" : `β ${CHANNEL_NAMES[channels[0]]}`;
    out.textContent = `θL ${p.theta_l}°, θr ${+p.theta_r.toFixed(2)}°: ${which} measured ${at(p.rgb)}` +
      fits.map(([m, f]) => `; ${name(m)} ${at(f.predicted[best.i])}`).join("");
  };
  svg.addEventListener("pointermove", onMove);
  svg.addEventListener("pointerdown", onMove);
  svg.addEventListener("pointerleave", (e) => { if (e.pointerType === "mouse") clear(); });
}
