// skyfuse fleet view: every vehicle's fused track and heading on one map, and the list
// of their state. Data: /ws/fleet (the view with tracks first, then a thinned view every
// 0.5 s without tracks; this page extends each track itself). ES modules, no bundler:
// fleet-common (state, colours), fleet-list (search, sort, visible rows only), fleet-map
// (canvas, clustering).
import { state, stats } from "./fleet-common.js";
import { refreshList, reveal } from "./fleet-list.js";
import { draw, onMarkerClick } from "./fleet-map.js";

const TRACK_MAX = 600;          // points kept per vehicle
const TRACK_MIN_STEP_M = 0.3;   // a new point only after this much movement

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
  if (state.picked) for (const id of [...state.picked]) if (!seen.has(id)) state.picked.delete(id);
  state.reference = view.reference;
  // Served by `skyfuse monitor`: no vehicle dashboard beside this page.
  document.getElementById("home-link").hidden = !!view.monitor;
  state.dirty = true;
  refreshList();
}

onMarkerClick((id) => { if (id) reveal(id); else refreshList(); state.dirty = true; });

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
