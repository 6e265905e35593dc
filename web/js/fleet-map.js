// The fleet map: every vehicle's track and heading, top-down in metres, north up. With
// many vehicles, markers that would overlap on screen are drawn as one cluster (a disc
// with their count); a click on a cluster lists just its vehicles, a click on a marker
// shows its row.
import { GONE, colour, state, stats } from "./fleet-common.js";

// Below this many placed vehicles every marker is drawn with its name (overlaps are
// still readable); from it on, clustering.
export const CLUSTER_FROM = 40;
const CELL_PX = 34;               // cluster grid cell
const TRACK_POINTS_DRAWN = 60000; // points of all tracks drawn per redraw, at most

const canvas = document.getElementById("fleet-map");
const ctx = canvas.getContext("2d");
// What the last draw put where, for clicks: clusters and single markers, screen px.
let hits = [];
let onReveal = () => {};
export function onMarkerClick(fn) { onReveal = fn; }
// For tests: where the last draw put its clusters and markers (CSS px on the canvas),
// and the ids a click on a cluster picked (null: none). The map redraws as vehicles
// move, so the cluster a click lands on may not be the one a test aimed at.
window.fleetMap = {
  hits: () => hits.map((x) => ({ x: x.x, y: x.y, r: x.r, ids: x.ids })),
  picked: () => (state.picked ? [...state.picked] : null),
};

function niceStep(span) {
  const raw = span / 6, p = Math.pow(10, Math.floor(Math.log10(raw))), m = raw / p;
  return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * p;
}

export function draw() {
  const t0 = performance.now();
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  const vs = [...state.vehicles.values()];
  // With many vehicles each track is drawn shortened (its newest points), so a redraw
  // costs the same at 50 vehicles as at 1 000.
  const perTrack = Math.max(20, Math.floor(TRACK_POINTS_DRAWN / Math.max(1, vs.length)));
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  const grow = (p) => { if (p[0] < x0) x0 = p[0]; if (p[0] > x1) x1 = p[0]; if (p[1] < y0) y0 = p[1]; if (p[1] > y1) y1 = p[1]; };
  for (const v of vs) {
    const t = v.track;
    for (let i = Math.max(0, t.length - perTrack); i < t.length; i++) grow(t[i]);
    if (v.xy) grow(v.xy);
  }
  if (!isFinite(x0)) { x0 = -10; x1 = 10; y0 = -10; y1 = 10; }
  const span = Math.max(x1 - x0, y1 - y0, 10) * 1.15;
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2, pad = 24;
  const scale = Math.min(w - 2 * pad, h - 2 * pad) / span;
  const X = (x) => w / 2 + (x - cx) * scale, Y = (y) => h / 2 - (y - cy) * scale;
  // Grid, metres.
  const step = niceStep(span);
  ctx.strokeStyle = "#e8ebef"; ctx.lineWidth = 1; ctx.fillStyle = "#8c959f"; ctx.font = "10px system-ui";
  ctx.beginPath();
  for (let gx = Math.ceil((cx - span) / step) * step; gx <= cx + span; gx += step) { ctx.moveTo(X(gx), 0); ctx.lineTo(X(gx), h); }
  for (let gy = Math.ceil((cy - span) / step) * step; gy <= cy + span; gy += step) { ctx.moveTo(0, Y(gy)); ctx.lineTo(w, Y(gy)); }
  ctx.stroke();
  ctx.fillText(`grid ${step} m`, 6, h - 6);
  // Tracks under markers; the gone ones first (grey, under the rest).
  vs.sort((a, b) => (a.presence === "gone") - (b.presence === "gone") || a.slot - b.slot).reverse();
  ctx.lineWidth = vs.length > CLUSTER_FROM ? 1 : 1.5;
  for (const v of vs) {
    const t = v.track;
    if (t.length < 2) continue;
    ctx.strokeStyle = colour(v); ctx.globalAlpha = v.presence === "gone" ? 0.5 : 0.8;
    ctx.setLineDash(v.frame === "local" ? [4, 3] : []);
    ctx.beginPath();
    const i0 = Math.max(0, t.length - perTrack);
    ctx.moveTo(X(t[i0][0]), Y(t[i0][1]));
    for (let i = i0 + 1; i < t.length; i++) ctx.lineTo(X(t[i][0]), Y(t[i][1]));
    ctx.stroke();
  }
  ctx.setLineDash([]); ctx.globalAlpha = 1;
  const placed = vs.filter((v) => v.xy);
  hits = [];
  if (placed.length < CLUSTER_FROM) {
    for (const v of placed) marker(v, X(v.xy[0]), Y(v.xy[1]), true);
    stats.clusters = 0;
  } else {
    // One grid cell, one cluster: O(n), stable while vehicles stay in their cells.
    const cells = new Map();
    for (const v of placed) {
      const px = X(v.xy[0]), py = Y(v.xy[1]);
      const key = `${Math.floor(px / CELL_PX)},${Math.floor(py / CELL_PX)}`;
      let c = cells.get(key);
      if (!c) cells.set(key, (c = { vs: [], sx: 0, sy: 0 }));
      c.vs.push(v); c.sx += px; c.sy += py;
    }
    let clusters = 0;
    for (const c of cells.values()) {
      if (c.vs.length === 1) { const v = c.vs[0]; marker(v, X(v.xy[0]), Y(v.xy[1]), false); continue; }
      clusters++;
      cluster(c.vs, c.sx / c.vs.length, c.sy / c.vs.length);
    }
    stats.clusters = clusters;
  }
  const ms = performance.now() - t0;
  stats.draws += 1; stats.lastDrawMs = ms; stats.drawMsTotal += ms;
}

function marker(v, px, py, label) {
  const hd = ((v.heading_deg ?? 0) * Math.PI) / 180; // from north, clockwise
  ctx.save(); ctx.translate(px, py); ctx.rotate(hd);
  ctx.fillStyle = colour(v); ctx.strokeStyle = "#fff"; ctx.lineWidth = 1.5;
  ctx.beginPath(); ctx.moveTo(0, -10); ctx.lineTo(6.5, 7); ctx.lineTo(0, 3.5); ctx.lineTo(-6.5, 7); ctx.closePath();
  ctx.fill(); ctx.stroke(); ctx.restore();
  if (label) {
    ctx.fillStyle = v.presence === "gone" ? GONE : "#1f2328"; ctx.font = "600 11px system-ui";
    ctx.fillText(v.name, px + 9, py - 8);
  }
  hits.push({ x: px, y: py, r: 10, ids: [v.id] });
}

// A cluster: a disc sized by its count, ringed in the colour of its worst member's state
// (red: one is gone or invalid; amber: stale; blue: all live and valid).
function cluster(vs, px, py) {
  const n = vs.length;
  // At most CELL_PX across: neighbouring cells' clusters touch but do not cover each other.
  const r = Math.min(CELL_PX / 2 - 1, 8 + 2.5 * Math.log2(n));
  const worst = vs.some((v) => v.presence === "gone" || v.valid === false) ? "#e03131"
    : vs.some((v) => v.presence === "stale") ? "#f08c00" : "#1c7ed6";
  ctx.beginPath(); ctx.arc(px, py, r, 0, 2 * Math.PI);
  ctx.fillStyle = "rgba(255,255,255,0.92)"; ctx.fill();
  ctx.lineWidth = 3; ctx.strokeStyle = worst; ctx.stroke();
  ctx.fillStyle = "#1f2328"; ctx.font = "600 11px system-ui"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
  ctx.fillText(String(n), px, py);
  ctx.textAlign = "start"; ctx.textBaseline = "alphabetic";
  hits.push({ x: px, y: py, r, ids: vs.map((v) => v.id) });
}

canvas.addEventListener("click", (e) => {
  const rect = canvas.getBoundingClientRect();
  const x = e.clientX - rect.left, y = e.clientY - rect.top;
  let best = null, bestD = Infinity;
  for (const hit of hits) {
    const d = Math.hypot(hit.x - x, hit.y - y);
    if (d <= hit.r + 4 && d < bestD) { best = hit; bestD = d; }
  }
  if (!best) return;
  if (best.ids.length > 1) { state.picked = new Set(best.ids); onReveal(null); }
  else onReveal(best.ids[0]);
});
