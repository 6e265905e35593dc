// Shared by the fleet page's modules: the vehicles' colours, HTML escaping, and the
// counters tests and benchmarks read (window.fleetStats).

export const PALETTE = ["#1c7ed6", "#e8590c", "#2f9e44", "#ae3ec9", "#f08c00", "#0c8599",
  "#c2255c", "#5c940d", "#6741d9", "#862e9c", "#d9480f", "#1098ad"];
export const GONE = "#9aa4ae";

export function colour(v) { return v.presence === "gone" ? GONE : PALETTE[v.slot % PALETTE.length]; }

export const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));

// Frames received, canvas redraws and their time, animation frame rate, bytes received,
// table rows in the DOM (only the visible ones are).
export const stats = window.fleetStats = { frames: 0, draws: 0, lastDrawMs: 0, drawMsTotal: 0, fps: 0, bytes: 0, rowsRendered: 0, clusters: 0 };

// The page's state: vehicles by id (the newest view of each, with the track this page
// keeps), the map's GNSS reference, and what the list shows.
export const state = {
  vehicles: new Map(), reference: null, dirty: true, lastFrameMs: 0,
  // Ids picked by a click on a map cluster (null: no such filter).
  picked: null,
};
