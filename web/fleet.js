// skyfuse fleet view: every vehicle's fused track and heading on one map, and a table
// of their state. Data: /ws/fleet (the view with tracks first, then a thinned view
// every 0.5 s without tracks; this page extends each track itself). No dependencies.
"use strict";

const PALETTE = ["#1c7ed6", "#e8590c", "#2f9e44", "#ae3ec9", "#f08c00", "#0c8599",
  "#c2255c", "#5c940d", "#6741d9", "#862e9c", "#d9480f", "#1098ad"];
const GONE = "#9aa4ae";
const TRACK_MAX = 600;          // points kept per vehicle
const TRACK_MIN_STEP_M = 0.3;   // a new point only after this much movement

const state = { vehicles: new Map(), reference: null, dirty: true, lastFrameMs: 0 };
// Read by tests and benchmarks: frames received, canvas redraws, animation frame rate.
const stats = window.fleetStats = { frames: 0, draws: 0, lastDrawMs: 0, drawMsTotal: 0, fps: 0, bytes: 0 };

function colour(v) { return v.presence === "gone" ? GONE : PALETTE[v.slot % PALETTE.length]; }

function apply(view) {
  const seen = new Set();
  for (const v of view.vehicles) {
    seen.add(v.id);
    const old = state.vehicles.get(v.id);
    // A track lives in one frame: a vehicle that gains a GNSS origin starts a new one.
    let track = old && old.frame === v.frame ? old.track : [];
    if (v.track) track = v.track.slice(-TRACK_MAX);
    else if (v.xy) {
      const last = track[track.length - 1];
      if (!last || Math.hypot(v.xy[0] - last[0], v.xy[1] - last[1]) >= TRACK_MIN_STEP_M) {
        track.push(v.xy);
        if (track.length > TRACK_MAX) track.splice(0, track.length - TRACK_MAX);
      }
    }
    v.track = track;
    state.vehicles.set(v.id, v);
  }
  for (const id of [...state.vehicles.keys()]) if (!seen.has(id)) state.vehicles.delete(id);
  state.reference = view.reference;
  // Served by `skyfuse monitor`: no vehicle dashboard beside this page.
  document.getElementById("home-link").hidden = !!view.monitor;
  state.dirty = true;
  renderTable();
}

// ------------------------------------------------------------------ table
const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
const tag = (cls, text, title) => `<span class="tag ${cls}"${title ? ` title="${esc(title)}"` : ""}>${esc(text)}</span>`;

function rowHtml(v) {
  const presence = { live: tag("t-ok", "live"), stale: tag("t-warn", "stale"), gone: tag("t-grey", "gone") }[v.presence];
  const heard = v.heard_s_ago < 1.5 ? "" : ` <span class="muted small">${v.heard_s_ago.toFixed(0)} s ago</span>`;
  const link = v.zenoh ? `<span class="muted small">${v.zenoh.routers} routers · ${v.zenoh.peers} peers</span>` : "";
  let est = "—";
  if (v.valid === true) est = tag("t-ok", "valid") + (v.position_std_m != null ? ` <span class="muted small nw">σ ${v.position_std_m.toFixed(2)} m</span>` : "");
  else if (v.valid === false) est = tag("t-bad", "invalid", v.invalid_reason) + ` <span class="small">${esc(v.invalid_reason)}</span>`;
  const worst = v.worst_health;
  const wcls = worst === "ok" ? "t-ok" : worst === "degraded" ? "t-warn" : worst ? "t-bad" : "t-grey";
  const sensors = worst ? tag(wcls, worst) + (v.unhealthy.length ? ` <span class="small">${esc(v.unhealthy.join(", "))}</span>` : "") : "—";
  const vpe = v.vpe === "sending" ? tag("t-ok", "sending") : v.vpe === "withheld" ? tag("t-bad", "withheld", v.vpe_reason) : v.vpe === "off" ? tag("t-grey", "off", "no MAVLink endpoint") : "—";
  const ev = v.last_event ? `<span class="small ev" title="${esc(v.last_event.message)}">${esc(v.last_event.message)}</span>` : "—";
  const restarts = v.restarts ? ` <span class="muted small" title="restarts seen">↻${v.restarts}</span>` : "";
  const frame = v.frame === "local" ? ` <span class="muted small" title="no GNSS origin: drawn in its own frame">local</span>` : "";
  return `<td><span class="swatch" style="background:${colour(v)}"></span><b>${esc(v.name)}</b>${restarts}${frame}<span class="id">${esc(v.id)}</span></td>` +
    `<td>${presence}${heard}<br>${link}</td><td>${est}</td><td class="small">${esc((v.sources || []).join(", ")) || "—"}</td>` +
    `<td>${sensors}</td><td>${vpe}</td><td>${ev}</td>`;
}

function renderTable() {
  const body = document.getElementById("fleet-rows");
  const rows = [...state.vehicles.values()].sort((a, b) => a.slot - b.slot);
  const existing = new Map([...body.children].map((tr) => [tr.dataset.id, tr]));
  rows.forEach((v, i) => {
    let tr = existing.get(v.id);
    if (!tr) {
      tr = document.createElement("tr");
      tr.dataset.id = v.id;
      tr.addEventListener("click", () => {
        const cur = state.vehicles.get(tr.dataset.id);
        if (cur && cur.dashboard) window.open(cur.dashboard, "_blank", "noopener");
      });
    }
    existing.delete(v.id);
    tr.dataset.presence = v.presence;
    tr.dataset.name = v.name;
    tr.title = v.dashboard ? `open ${v.dashboard}` : "no dashboard announced";
    const html = rowHtml(v);
    if (tr._html !== html) { tr.innerHTML = html; tr._html = html; }
    if (body.children[i] !== tr) body.insertBefore(tr, body.children[i] || null);
  });
  for (const tr of existing.values()) tr.remove();
  document.getElementById("fleet-empty").style.display = rows.length ? "none" : "";
  const n = (p) => rows.filter((v) => v.presence === p).length;
  document.getElementById("fleet-counts").textContent =
    `${rows.length} vehicles · ${n("live")} live · ${n("stale")} stale · ${n("gone")} gone`;
  const local = rows.filter((v) => v.frame === "local").length;
  document.getElementById("map-note").textContent = state.reference
    ? `origin ${state.reference.lat.toFixed(6)}, ${state.reference.lon.toFixed(6)}` + (local ? ` · ${local} without GNSS drawn in their own frame` : "")
    : (rows.length ? "no GNSS origin yet: each vehicle in its own frame" : "");
}

// ------------------------------------------------------------------ map
const canvas = document.getElementById("fleet-map");
const ctx = canvas.getContext("2d");

function niceStep(span) {
  const raw = span / 6, p = Math.pow(10, Math.floor(Math.log10(raw))), m = raw / p;
  return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * p;
}

function draw() {
  const t0 = performance.now();
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  const vs = [...state.vehicles.values()];
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const v of vs) for (const p of v.track.concat(v.xy ? [v.xy] : [])) {
    x0 = Math.min(x0, p[0]); x1 = Math.max(x1, p[0]); y0 = Math.min(y0, p[1]); y1 = Math.max(y1, p[1]);
  }
  if (!isFinite(x0)) { x0 = -10; x1 = 10; y0 = -10; y1 = 10; }
  const span = Math.max(x1 - x0, y1 - y0, 10) * 1.15;
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2, pad = 24;
  const scale = Math.min(w - 2 * pad, h - 2 * pad) / span;
  const X = (x) => w / 2 + (x - cx) * scale, Y = (y) => h / 2 - (y - cy) * scale;
  // Grid, metres.
  const step = niceStep(span);
  ctx.strokeStyle = "#e8ebef"; ctx.lineWidth = 1; ctx.fillStyle = "#8c959f"; ctx.font = "10px system-ui";
  for (let gx = Math.ceil((cx - span) / step) * step; gx <= cx + span; gx += step) {
    ctx.beginPath(); ctx.moveTo(X(gx), 0); ctx.lineTo(X(gx), h); ctx.stroke();
  }
  for (let gy = Math.ceil((cy - span) / step) * step; gy <= cy + span; gy += step) {
    ctx.beginPath(); ctx.moveTo(0, Y(gy)); ctx.lineTo(w, Y(gy)); ctx.stroke();
  }
  ctx.fillText(`grid ${step} m`, 6, h - 6);
  // Tracks under markers; the gone ones first (grey, under the rest).
  vs.sort((a, b) => (a.presence === "gone") - (b.presence === "gone") || a.slot - b.slot).reverse();
  for (const v of vs) {
    if (v.track.length < 2) continue;
    ctx.strokeStyle = colour(v); ctx.globalAlpha = v.presence === "gone" ? 0.5 : 0.8; ctx.lineWidth = 1.5;
    ctx.setLineDash(v.frame === "local" ? [4, 3] : []);
    ctx.beginPath();
    v.track.forEach((p, i) => (i ? ctx.lineTo(X(p[0]), Y(p[1])) : ctx.moveTo(X(p[0]), Y(p[1]))));
    ctx.stroke();
  }
  ctx.setLineDash([]); ctx.globalAlpha = 1;
  for (const v of vs) {
    if (!v.xy) continue;
    const px = X(v.xy[0]), py = Y(v.xy[1]);
    const hd = ((v.heading_deg ?? 0) * Math.PI) / 180; // from north, clockwise
    ctx.save(); ctx.translate(px, py); ctx.rotate(hd);
    ctx.fillStyle = colour(v); ctx.strokeStyle = "#fff"; ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.moveTo(0, -10); ctx.lineTo(6.5, 7); ctx.lineTo(0, 3.5); ctx.lineTo(-6.5, 7); ctx.closePath();
    ctx.fill(); ctx.stroke(); ctx.restore();
    ctx.fillStyle = v.presence === "gone" ? GONE : "#1f2328"; ctx.font = "600 11px system-ui";
    ctx.fillText(v.name, px + 9, py - 8);
  }
  const ms = performance.now() - t0;
  stats.draws += 1; stats.lastDrawMs = ms; stats.drawMsTotal += ms;
}

// Redraw only when something changed; count animation frames for the frame rate.
let fpsCount = 0, fpsStart = performance.now();
function frame(now) {
  fpsCount += 1;
  if (now - fpsStart >= 1000) { stats.fps = (fpsCount * 1000) / (now - fpsStart); fpsCount = 0; fpsStart = now; }
  if (state.dirty) { state.dirty = false; draw(); }
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);
window.addEventListener("resize", () => { state.dirty = true; });

// ------------------------------------------------------------------ connection
const conn = document.getElementById("conn"), connText = document.getElementById("conn-text");
function setConn(s, text) { conn.dataset.state = s; connText.textContent = text; }
let backoff = 500;
function connect() {
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${location.pathname.replace(/fleet$/, "")}ws/fleet`;
  const ws = new WebSocket(url);
  ws.onopen = () => { backoff = 500; setConn("open", "connected"); };
  ws.onmessage = (m) => {
    stats.frames += 1; stats.bytes += m.data.length;
    state.lastFrameMs = performance.now();
    try { apply(JSON.parse(m.data)); setConn("live", "live"); } catch (e) { console.error("fleet frame", e); }
  };
  ws.onclose = () => {
    setConn("down", "reconnecting…");
    setTimeout(connect, backoff); backoff = Math.min(backoff * 2, 5000);
  };
}
setInterval(() => { if (conn.dataset.state === "live" && performance.now() - state.lastFrameMs > 3000) setConn("stale", "no data"); }, 1000);
connect();
