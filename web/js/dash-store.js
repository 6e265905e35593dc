// The data the page keeps: a columnar ring buffer of the ticks (PROTOCOL.md), the
// position sources seen, and the page state the panels share.
import { CAP, KNOWN, WINDOWS, colorFor, isNum, num } from './dash-util.js';

// ------------------------------------------------------------- ring buffer
// Columnar Float64Arrays, NaN = no value. Columns appear when a new source does.
export const store = {
  cap: CAP, start: 0, len: 0, cols: new Map(), list: [],
  col(name) {
    let c = this.cols.get(name);
    if (!c) { c = new Float64Array(this.cap).fill(NaN); this.cols.set(name, c); this.list.push(c); }
    return c;
  },
  clear() { this.start = 0; this.len = 0; for (const c of this.list) c.fill(NaN); },
  phys(i) { return (this.start + i) % this.cap; },
  lastT() { return this.len ? this.t[this.phys(this.len - 1)] : NaN; },
  firstT() { return this.len ? this.t[this.start] : NaN; },
  // first logical index with t >= v
  lowerBound(v) {
    let lo = 0, hi = this.len;
    while (lo < hi) { const m = (lo + hi) >> 1; if (this.t[this.phys(m)] < v) lo = m + 1; else hi = m; }
    return lo;
  },
  // append one row: `vals` is a list of [column, value]
  push(vals) {
    let p;
    if (this.len < this.cap) { p = this.phys(this.len); this.len++; } else { p = this.start; this.start = (this.start + 1) % this.cap; }
    for (const c of this.list) c[p] = NaN;
    for (const [c, v] of vals) c[p] = v;
  },
};
store.t = store.col('t');
export const C = {
  px: store.col('px'), py: store.col('py'), pz: store.col('pz'), yaw: store.col('yaw'),
  fdx: store.col('d:fused:0'), fdy: store.col('d:fused:1'), fdz: store.col('d:fused:2'),
  rawx: store.col('f:raw:0'), rawy: store.col('f:raw:1'), gyx: store.col('f:gyro:0'),
  gyy: store.col('f:gyro:1'), cmx: store.col('f:comp:0'), cmy: store.col('f:comp:1'),
};

// ------------------------------------------------------------------- state
export const state = {
  frames: 0, ticks: 0, eventCount: 0, dropped: 0, droppedTotal: 0, badFrames: 0,
  win: 60, paused: false, pausedT: NaN,
  sources: [],            // position sources seen, display order
  visible: {},            // series label -> shown (shared by charts and map)
  status: null, events: [], lastFrameAt: 0, tickTimes: [], network: [],
  counts: {},             // chart name -> points drawn
};
const savedWin = Number(localStorage.getItem('skyfuse.window'));
if (WINDOWS.includes(savedWin)) state.win = savedWin;

export function sortSources(list) {
  return list.sort((a, b) => {
    const ia = KNOWN.indexOf(a), ib = KNOWN.indexOf(b);
    if (ia >= 0 || ib >= 0) return (ia < 0 ? 99 : ia) - (ib < 0 ? 99 : ib);
    return a < b ? -1 : a > b ? 1 : 0;
  });
}
export function noteSource(name) {
  if (name === 'fused' || state.sources.includes(name)) return;
  state.sources = sortSources([...state.sources, name]);
  colorFor(name);
  for (let a = 0; a < 3; a++) { store.col(`s:${name}:${a}`); store.col(`d:${name}:${a}`); }
  state.sourcesChanged = true;
}

// ------------------------------------------------------------------ ingest
export function ingestTick(k) {
  if (!k || !isNum(k.t)) return false;
  if (store.len) {
    const last = store.lastT();
    if (k.t <= last) {
      if (k.t < last - 5) store.clear(); // clock went back: a different service run
      else return false;                 // overlap with the snapshot
    }
  }
  if (k.sources) for (const s of Object.keys(k.sources)) noteSource(s);
  if (k.deltas) for (const s of Object.keys(k.deltas)) noteSource(s);
  const vals = [[store.t, k.t]];
  const p = k.pose;
  if (p) {
    vals.push([C.px, num(p.x)], [C.py, num(p.y)], [C.pz, num(p.z)], [C.yaw, num(p.yaw)]);
  }
  if (k.sources) {
    for (const [s, v] of Object.entries(k.sources)) {
      if (Array.isArray(v)) for (let a = 0; a < 3; a++) vals.push([store.col(`s:${s}:${a}`), num(v[a])]);
    }
  }
  if (k.deltas) {
    for (const [s, v] of Object.entries(k.deltas)) {
      if (Array.isArray(v)) for (let a = 0; a < 3; a++) vals.push([store.col(`d:${s}:${a}`), num(v[a])]);
    }
  }
  const f = k.flow;
  if (f) {
    if (f.raw) vals.push([C.rawx, num(f.raw[0])], [C.rawy, num(f.raw[1])]);
    if (f.gyro) vals.push([C.gyx, num(f.gyro[0])], [C.gyy, num(f.gyro[1])]);
    if (f.comp) vals.push([C.cmx, num(f.comp[0])], [C.cmy, num(f.comp[1])]);
  }
  store.push(vals);
  state.lastPose = p || state.lastPose;
  return true;
}
