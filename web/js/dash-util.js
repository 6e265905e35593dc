// The dashboard's constants and small helpers (DOM, number formatting, series colours).

// ---------------------------------------------------------------- constants
export const WINDOWS = [10, 30, 60, 300];
export const CAP = 6400;          // ring capacity: 5 min at 20 Hz plus slack
export const MAX_PTS = 1500;      // points per series handed to a chart (bucketed beyond)
export const GAP_S = 1.5;         // a source silent for longer than this breaks its line
export const MAX_EVENTS = 200;    // events kept and shown
export const TOKEN_KEY = 'skyfuse.token';
export const KNOWN = ['gps', 't265', 'flow'];
export const COLORS = { gps: '#1c7ed6', t265: '#e8590c', flow: '#2f9e44', imu: '#7048e8', fused: '#111111' };
export const EXTRA = ['#c2255c', '#0c8599', '#f08c00', '#5c940d', '#862e9c', '#364fc7', '#a61e4d'];
export const FONT = '11px system-ui, -apple-system, "Segoe UI", Roboto, sans-serif';

export const $ = (sel, root = document) => root.querySelector(sel);
export const h = (tag, cls, text) => {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text != null) e.textContent = text;
  return e;
};
export const isNum = (v) => typeof v === 'number' && Number.isFinite(v);
export const num = (v) => (isNum(v) ? v : NaN);
export const fmt = (v, d = 2) => (isNum(v) ? v.toFixed(d) : '—');
export const fmtMs = (v) => (!isNum(v) ? '—' : v < 1000 ? `${v.toFixed(0)} ms` : v < 60000 ? `${(v / 1000).toFixed(1)} s` : `${(v / 60000).toFixed(1)} min`);
export const fmtDur = (s) => (!isNum(s) ? '—' : s < 60 ? `${s.toFixed(0)} s` : s < 3600 ? `${Math.floor(s / 60)} min ${Math.floor(s % 60)} s` : `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`);

let extraIdx = 0;
export function colorFor(name) {
  if (!COLORS[name]) COLORS[name] = EXTRA[extraIdx++ % EXTRA.length];
  return COLORS[name];
}
