// The text the page writes: HTML escaping, shutter times, local times, durations and
// percentages. Pure functions: no page element, no request.

export function escapeHtml(s) {
  return String(s ?? "").replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" }[c]));
}

// Shutter times as photographers write them (same rule as the daemon's step names):
// fractions below 0.3 s, one decimal below 10 s, whole seconds above.
export function formatShutter(t) {
  if (!(t > 0)) return `${t} s`;
  if (t < 0.3) return `1/${Math.round(1 / t)} s`;
  return `${t < 10 ? +t.toFixed(1) : Math.round(t)} s`;
}

// A time the daemon gives (RFC 3339, UTC) in the browser's local time zone.
export function localTime(iso) {
  if (!iso) return "";
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return String(iso);
  const two = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${two(d.getMonth() + 1)}-${two(d.getDate())} ` +
    `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}

// A duration in seconds as "42 s", "3 min 05 s" or "2 h 10 min".
export function duration(seconds) {
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return `${s} s`;
  const m = Math.floor(s / 60);
  if (m < 60) return `${m} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
}

// A fraction as a percentage with one decimal; "–" when absent.
export function percent(v) {
  return v == null ? "–" : (100 * v).toFixed(1) + " %";
}
