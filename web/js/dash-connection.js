// The websocket: connect, reconnect with back-off, the frames of PROTOCOL.md.
import { $, isNum } from './dash-util.js';
import { ingestTick, state, store } from './dash-store.js';
import { requestDraw } from './dash-draw.js';
import { onStatus } from './dash-status.js';
import { addEvent, renderEventsAll } from './dash-events.js';
import { setResult } from './dash-controls.js';

// -------------------------------------------------------------- connection
let ws = null, backoff = 500, reconnectAt = 0, reconnectTimer = null;
const wantRate = () => ((navigator.connection && navigator.connection.saveData) || window.matchMedia('(max-width: 700px)').matches ? 5 : 20);
function wsUrl() {
  const u = new URL('ws', window.location.href);
  u.protocol = u.protocol === 'https:' ? 'wss:' : 'ws:';
  u.hash = '';
  return u.href;
}
export function setConn(s, text) {
  const c = $('#conn');
  c.dataset.state = s;
  document.body.classList.toggle('offline', s === 'down' || s === 'stale');
  $('#conn-text').textContent = text || { live: 'live', connecting: 'connecting…', open: 'connected, waiting for snapshot' }[s] || s;
}
export function connect() {
  clearTimeout(reconnectTimer);
  reconnectTimer = null;
  setConn('connecting');
  let sock;
  try { sock = new WebSocket(wsUrl()); } catch (e) { scheduleReconnect(); return; }
  ws = sock;
  sock.onopen = () => {
    state.lastFrameAt = performance.now();
    state.subRate = wantRate();
    sock.send(JSON.stringify({ type: 'subscribe', max_rate_hz: state.subRate }));
    setConn('open');
  };
  sock.onmessage = (e) => {
    let m;
    try { m = JSON.parse(e.data); } catch (err) { state.badFrames++; return; }
    if (m && typeof m === 'object') onFrame(m);
  };
  sock.onerror = () => {};
  sock.onclose = () => { if (ws === sock) { ws = null; scheduleReconnect(); } };
}
function scheduleReconnect() {
  const delay = backoff * (0.8 + 0.4 * Math.random());
  backoff = Math.min(backoff * 2, 10000);
  reconnectAt = performance.now() + delay;
  reconnectTimer = setTimeout(connect, delay);
  updateConnCountdown();
}
function updateConnCountdown() {
  if (!reconnectTimer) return;
  const s = Math.max(0, (reconnectAt - performance.now()) / 1000);
  setConn('down', `disconnected, retry in ${s.toFixed(0)} s`);
}
export function renderWsStats() {
  const parts = [`${state.frames} frames`];
  if (state.subRate) parts.push(`${state.subRate} Hz max`);
  if (state.dropped > 0 || state.droppedTotal > 0) parts.push(`<span class="warn">dropped ${Math.max(state.dropped, state.droppedTotal)}</span>`);
  if (isNum(state.wsClients)) parts.push(`${state.wsClients} client${state.wsClients === 1 ? '' : 's'}`);
  $('#ws-stats').innerHTML = parts.join(' · ');
}

// housekeeping, 1 Hz: tick rate, silent-link detection, countdown
setInterval(() => {
  const now = performance.now();
  state.tickTimes = state.tickTimes.filter((t) => now - t < 2000);
  if (reconnectTimer) { updateConnCountdown(); return; }
  if (ws && ws.readyState === WebSocket.OPEN) {
    const silent = now - state.lastFrameAt;
    if (silent > 10000) { try { ws.close(); } catch (e) { /* ignore */ } ws = null; scheduleReconnect(); return; }
    const c = $('#conn').dataset.state;
    if (c === 'live' || c === 'stale' || c === 'idle' || (c === 'open' && state.tickTimes.length)) {
      if (silent > 3000) setConn('stale', `no data for ${(silent / 1000).toFixed(0)} s`);
      else if (!state.tickTimes.length) setConn('idle', 'connected · no pose from the estimator');
      else setConn('live', `live · ${(state.tickTimes.length / 2).toFixed(0)} Hz`);
    }
  }
  renderWsStats();
}, 1000);

function onFrame(m) {
  state.frames++;
  state.lastFrameAt = performance.now();
  switch (m.type) {
    case 'snapshot': {
      backoff = 500;
      if (m.protocol != null && m.protocol !== 1) setResult(`server speaks protocol ${m.protocol}, page expects 1`, 'bad');
      store.clear();
      state.lastPose = null;
      for (const k of m.ticks || []) ingestTick(k);
      state.events = [];
      renderEventsAll(m.events || []);
      if (m.status) onStatus(m.status);
      setConn('live');
      requestDraw(true);
      break;
    }
    case 'tick':
      state.ticks++;
      state.tickTimes.push(state.lastFrameAt);
      if (ingestTick(m) && !state.paused) requestDraw();
      break;
    case 'status':
      if (m.status) onStatus(m.status);
      break;
    case 'event':
      if (m.event) addEvent(m.event, true);
      break;
    case 'dropped':
      state.dropped += m.dropped || 0;
      if (isNum(m.total)) state.droppedTotal = m.total;
      renderWsStats();
      break;
    default:
      break;
  }
}
