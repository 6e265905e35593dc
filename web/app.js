// skyfuse dashboard. Plain script, no bundler: uPlot comes from vendor/uPlot.iife.min.js.
// Data: one websocket (`ws`, relative to the page) carrying the frames in PROTOCOL.md.
'use strict';
(() => {
  // ---------------------------------------------------------------- constants
  const WINDOWS = [10, 30, 60, 300];
  const CAP = 6400;          // ring capacity: 5 min at 20 Hz plus slack
  const MAX_PTS = 1500;      // points per series handed to a chart (bucketed beyond)
  const GAP_S = 1.5;         // a source silent for longer than this breaks its line
  const MAX_EVENTS = 200;    // events kept and shown
  const TOKEN_KEY = 'skyfuse.token';
  const KNOWN = ['gps', 't265', 'flow'];
  const COLORS = { gps: '#1c7ed6', t265: '#e8590c', flow: '#2f9e44', imu: '#7048e8', fused: '#111111' };
  const EXTRA = ['#c2255c', '#0c8599', '#f08c00', '#5c940d', '#862e9c', '#364fc7', '#a61e4d'];
  const FONT = '11px system-ui, -apple-system, "Segoe UI", Roboto, sans-serif';

  const $ = (sel, root = document) => root.querySelector(sel);
  const h = (tag, cls, text) => {
    const e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text != null) e.textContent = text;
    return e;
  };
  const isNum = (v) => typeof v === 'number' && Number.isFinite(v);
  const num = (v) => (isNum(v) ? v : NaN);
  const fmt = (v, d = 2) => (isNum(v) ? v.toFixed(d) : '—');
  const fmtMs = (v) => (!isNum(v) ? '—' : v < 1000 ? `${v.toFixed(0)} ms` : v < 60000 ? `${(v / 1000).toFixed(1)} s` : `${(v / 60000).toFixed(1)} min`);
  const fmtDur = (s) => (!isNum(s) ? '—' : s < 60 ? `${s.toFixed(0)} s` : s < 3600 ? `${Math.floor(s / 60)} min ${Math.floor(s % 60)} s` : `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`);

  let extraIdx = 0;
  function colorFor(name) {
    if (!COLORS[name]) COLORS[name] = EXTRA[extraIdx++ % EXTRA.length];
    return COLORS[name];
  }

  // ------------------------------------------------------------- ring buffer
  // Columnar Float64Arrays, NaN = no value. Columns appear when a new source does.
  const store = {
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
  const C = {
    px: store.col('px'), py: store.col('py'), pz: store.col('pz'), yaw: store.col('yaw'),
    fdx: store.col('d:fused:0'), fdy: store.col('d:fused:1'), fdz: store.col('d:fused:2'),
    rawx: store.col('f:raw:0'), rawy: store.col('f:raw:1'), gyx: store.col('f:gyro:0'),
    gyy: store.col('f:gyro:1'), cmx: store.col('f:comp:0'), cmy: store.col('f:comp:1'),
  };

  // ------------------------------------------------------------------- state
  const state = {
    frames: 0, ticks: 0, eventCount: 0, dropped: 0, droppedTotal: 0, badFrames: 0,
    win: 60, paused: false, pausedT: NaN,
    sources: [],            // position sources seen, display order
    visible: {},            // series label -> shown (shared by charts and map)
    status: null, events: [], lastFrameAt: 0, tickTimes: [], network: [],
    counts: {},             // chart name -> points drawn
  };
  const savedWin = Number(localStorage.getItem('skyfuse.window'));
  if (WINDOWS.includes(savedWin)) state.win = savedWin;

  function sortSources(list) {
    return list.sort((a, b) => {
      const ia = KNOWN.indexOf(a), ib = KNOWN.indexOf(b);
      if (ia >= 0 || ib >= 0) return (ia < 0 ? 99 : ia) - (ib < 0 ? 99 : ib);
      return a < b ? -1 : a > b ? 1 : 0;
    });
  }
  function noteSource(name) {
    if (name === 'fused' || state.sources.includes(name)) return;
    state.sources = sortSources([...state.sources, name]);
    colorFor(name);
    for (let a = 0; a < 3; a++) { store.col(`s:${name}:${a}`); store.col(`d:${name}:${a}`); }
    sourcesChanged = true;
  }
  let sourcesChanged = false;

  // ------------------------------------------------------------------ ingest
  function ingestTick(k) {
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
    lastPose = p || lastPose;
    return true;
  }
  let lastPose = null;

  function onFrame(m) {
    state.frames++;
    state.lastFrameAt = performance.now();
    switch (m.type) {
      case 'snapshot': {
        backoff = 500;
        if (m.protocol != null && m.protocol !== 1) setResult(`server speaks protocol ${m.protocol}, page expects 1`, 'bad');
        store.clear();
        lastPose = null;
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

  // ------------------------------------------------------------------ charts
  const charts = {};   // name -> uPlot
  const chartDefs = {}; // name -> {series: [{label, col}], group}

  const axisBase = {
    stroke: '#495057', font: FONT, labelFont: FONT, labelSize: 14, labelGap: 0,
    grid: { stroke: '#eceef1', width: 1 }, ticks: { stroke: '#dee2e6', width: 1, size: 3 },
  };
  const valFmt = (d) => (u, v) => (v == null ? '—' : v.toFixed(d));

  function seriesSpec() {
    const out = {};
    const srcSeries = (prefix, axis) => [
      ...state.sources.map((s) => ({ label: s, col: store.col(`${prefix}:${s}:${axis}`), stroke: colorFor(s), width: 1.25 })),
      { label: 'fused', col: prefix === 's' ? [C.px, C.py, C.pz][axis] : [C.fdx, C.fdy, C.fdz][axis], stroke: COLORS.fused, width: 2.25 },
    ];
    ['x', 'y', 'z'].forEach((ax, a) => {
      out[`pos_${ax}`] = { group: 'src', unit: `${ax} (m)`, digits: 2, series: srcSeries('s', a) };
      out[`delta_${ax}`] = { group: 'src', unit: `d${ax} (m)`, digits: 3, series: srcSeries('d', a) };
    });
    const fl = colorFor('flow'), im = colorFor('imu');
    out.flow = {
      group: 'flow', unit: 'rate (rad/s)', digits: 3, series: [
        { label: 'raw x', col: C.rawx, stroke: fl, width: 1.25 },
        { label: 'raw y', col: C.rawy, stroke: fl, width: 1.25, dash: [5, 3] },
        { label: 'gyro x', col: C.gyx, stroke: im, width: 1.25 },
        { label: 'gyro y', col: C.gyy, stroke: im, width: 1.25, dash: [5, 3] },
        { label: 'comp x', col: C.cmx, stroke: COLORS.fused, width: 2 },
        { label: 'comp y', col: C.cmy, stroke: COLORS.fused, width: 2, dash: [5, 3] },
      ],
    };
    return out;
  }

  function makeChart(name, def) {
    const card = document.querySelector(`[data-chart="${name}"]`);
    const plotEl = $('.plot', card), legendHost = $('.legend-host', card);
    plotEl.replaceChildren();
    legendHost.replaceChildren();
    const height = Number(plotEl.dataset.h) || 150;
    const opts = {
      width: Math.max(120, plotEl.clientWidth), height,
      pxAlign: false,
      cursor: { sync: { key: 'skyfuse-t' }, drag: { x: true, y: false }, focus: { prox: 16 } },
      focus: { alpha: 0.3 },
      legend: { live: true, mount: (u, el) => legendHost.appendChild(el) },
      scales: { x: { time: false, auto: false } },
      axes: [
        { ...axisBase, size: 22, values: (u, vals) => vals.map((v) => (v == null ? '' : `${+v.toFixed(3)} s`)) },
        { ...axisBase, label: def.unit, size: 46 },
      ],
      series: [
        { label: 't', value: (u, v) => (v == null ? '—' : `${v.toFixed(2)} s`) },
        ...def.series.map((s) => ({
          label: s.label, stroke: s.stroke, width: s.width, dash: s.dash, spanGaps: false,
          show: state.visible[s.label] !== false, value: valFmt(def.digits),
          points: { size: 4 },
        })),
      ],
      hooks: {
        setSeries: [(u, i, o) => onSeriesToggle(name, u, i, o)],
        // a drag-zoom pauses the live view so the zoom stays; Resume returns to the window
        setSelect: [(u) => { if (u.select.width > 4) { u._skyfuseZoomed = true; if (!state.paused) setPaused(true, false); } }],
      },
    };
    const u = new uPlot(opts, [[], ...def.series.map(() => [])], plotEl);
    u._skyfuseHover = false;
    u.over.addEventListener('mouseenter', () => { u._skyfuseHover = true; });
    u.over.addEventListener('mouseleave', () => { u._skyfuseHover = false; requestDraw(true); });
    charts[name] = u;
    chartDefs[name] = def;
    return u;
  }

  function onSeriesToggle(name, u, i, o) {
    if (o.show == null || i == null) return;
    const label = u.series[i].label;
    state.visible[label] = o.show;
    if (chartDefs[name].group === 'src') {
      for (const [n, c] of Object.entries(charts)) {
        if (c === u || chartDefs[n].group !== 'src') continue;
        const j = c.series.findIndex((s, k) => k > 0 && s.label === label);
        if (j > 0 && c.series[j].show !== o.show) c.setSeries(j, { show: o.show }, false);
      }
      renderMapLegend();
    }
    requestDraw(true);
  }

  function buildCharts(names) {
    const spec = seriesSpec();
    for (const n of names) {
      if (charts[n]) { charts[n].destroy(); delete charts[n]; }
      makeChart(n, spec[n]);
    }
  }

  const resizeObs = new ResizeObserver((entries) => {
    for (const e of entries) {
      const name = e.target.closest('[data-chart]')?.dataset.chart;
      const u = name && charts[name];
      const w = Math.floor(e.contentRect.width);
      if (u && w > 0 && Math.abs(u.width - w) > 1) u.setSize({ width: w, height: u.height });
    }
    if (entries.some((e) => e.target.id === 'map-wrap-el')) requestDraw(true);
  });

  // Build the uPlot data for the rows [i0, i1) of the ring: bucketed to MAX_PTS,
  // `undefined` (spanned) while a source is briefly absent, `null` (a gap) after GAP_S.
  function buildData(cols, i0, i1, shown) {
    const n = i1 - i0;
    const stride = Math.max(1, Math.ceil(n / MAX_PTS));
    const m = Math.ceil(n / stride);
    const xs = new Array(m);
    const ys = cols.map(() => new Array(m));
    const lastSeen = cols.map(() => -Infinity);
    const lastIdx = cols.map(() => null);
    let count = 0;
    const t = store.t;
    for (let j = 0, i = i0; j < m; j++, i += stride) {
      const e = Math.min(i + stride, i1);
      const pe = store.phys(e - 1);
      const x = t[pe];
      xs[j] = x;
      for (let s = 0; s < cols.length; s++) {
        const c = cols[s];
        let v = NaN;
        for (let k = e - 1; k >= i; k--) { const q = c[store.phys(k)]; if (q === q) { v = q; break; } }
        if (v === v) {
          ys[s][j] = v; lastSeen[s] = x; lastIdx[s] = j;
          if (shown[s]) count++;
        } else {
          ys[s][j] = x - lastSeen[s] <= GAP_S ? undefined : null;
        }
      }
    }
    return { data: [xs, ...ys], count, lastIdx };
  }

  // -------------------------------------------------------------- map canvas
  const mapCanvas = $('#map');
  const mapWrap = $('.map-wrap');
  mapWrap.id = 'map-wrap-el';
  const mapCtx = mapCanvas.getContext('2d');

  function niceStep(raw) {
    const p = Math.pow(10, Math.floor(Math.log10(raw)));
    const f = raw / p;
    return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * p;
  }

  function mapSeries() {
    return [
      ...state.sources.map((s) => ({ label: s, cx: store.col(`s:${s}:0`), cy: store.col(`s:${s}:1`), color: colorFor(s), width: 1.4 })),
      { label: 'fused', cx: C.px, cy: C.py, color: COLORS.fused, width: 2.4 },
    ];
  }

  function drawMap(i0, i1) {
    const dpr = window.devicePixelRatio || 1;
    const W = Math.max(100, Math.floor(mapWrap.clientWidth));
    const H = Math.max(100, Math.floor(mapWrap.clientHeight));
    if (mapCanvas.width !== W * dpr || mapCanvas.height !== H * dpr) {
      mapCanvas.width = W * dpr; mapCanvas.height = H * dpr;
      mapCanvas.style.width = `${W}px`; mapCanvas.style.height = `${H}px`;
    }
    const g = mapCtx;
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, W, H);
    g.font = FONT;

    // collect tracks
    const n = i1 - i0;
    const stride = Math.max(1, Math.ceil(n / MAX_PTS));
    const tracks = [];
    let minX = Infinity, maxX = -Infinity, minY = Infinity, maxY = -Infinity, count = 0;
    for (const s of mapSeries()) {
      if (state.visible[s.label] === false) continue;
      const pts = []; // flat x, y; NaN pair = break
      let lastT = -Infinity;
      for (let i = i0; i < i1; i += stride) {
        const p = store.phys(Math.min(i + stride, i1) - 1);
        let x = s.cx[p], y = s.cy[p];
        if (x !== x || y !== y) {
          // find the latest value in the bucket
          for (let k = Math.min(i + stride, i1) - 2; k >= i; k--) {
            const q = store.phys(k);
            if (s.cx[q] === s.cx[q] && s.cy[q] === s.cy[q]) { x = s.cx[q]; y = s.cy[q]; break; }
          }
        }
        if (x === x && y === y) {
          if (store.t[p] - lastT > GAP_S && pts.length) pts.push(NaN, NaN);
          pts.push(x, y); lastT = store.t[p]; count++;
          if (x < minX) minX = x; if (x > maxX) maxX = x; if (y < minY) minY = y; if (y > maxY) maxY = y;
        }
      }
      tracks.push({ ...s, pts });
    }
    state.counts.map = count;

    const padL = 40, padR = 12, padT = 10, padB = 28;
    const pw = W - padL - padR, ph = H - padT - padB;
    if (!count) {
      g.fillStyle = '#868e96'; g.textAlign = 'center'; g.textBaseline = 'middle';
      g.fillText('waiting for positions…', W / 2, H / 2);
      return;
    }
    // equal aspect around the data, at least 4 m across
    // (a 28 px margin keeps the heading arrow and end markers inside the frame)
    const spanX = Math.max(maxX - minX, 4), spanY = Math.max(maxY - minY, 4);
    const cx = (minX + maxX) / 2, cy = (minY + maxY) / 2;
    const scale = Math.min(Math.max(20, pw - 56) / spanX, Math.max(20, ph - 56) / spanY);
    const X = (x) => padL + pw / 2 + (x - cx) * scale;
    const Y = (y) => padT + ph / 2 - (y - cy) * scale;
    const x0 = cx - pw / 2 / scale, x1 = cx + pw / 2 / scale, y0 = cy - ph / 2 / scale, y1 = cy + ph / 2 / scale;

    // grid + labels
    const step = niceStep(60 / scale);
    const dec = step < 1 ? Math.min(3, Math.ceil(-Math.log10(step))) : 0;
    g.lineWidth = 1; g.strokeStyle = '#eceef1'; g.fillStyle = '#495057';
    g.textAlign = 'center'; g.textBaseline = 'top';
    for (let v = Math.ceil(x0 / step) * step; v <= x1; v += step) {
      const px = Math.round(X(v)) + 0.5;
      g.beginPath(); g.moveTo(px, padT); g.lineTo(px, padT + ph); g.stroke();
      g.fillText(v.toFixed(dec), px, padT + ph + 3);
    }
    g.textAlign = 'right'; g.textBaseline = 'middle';
    for (let v = Math.ceil(y0 / step) * step; v <= y1; v += step) {
      const py = Math.round(Y(v)) + 0.5;
      g.beginPath(); g.moveTo(padL, py); g.lineTo(padL + pw, py); g.stroke();
      g.fillText(v.toFixed(dec), padL - 4, py);
    }
    g.strokeStyle = '#ced4da'; g.strokeRect(padL + 0.5, padT + 0.5, pw - 1, ph - 1);
    g.fillStyle = '#495057'; g.textAlign = 'center'; g.textBaseline = 'bottom';
    g.fillText('x east (m)', padL + pw / 2, H - 1);
    g.save(); g.translate(10, padT + ph / 2); g.rotate(-Math.PI / 2); g.textBaseline = 'middle';
    g.fillText('y north (m)', 0, 0); g.restore();

    g.save();
    g.beginPath(); g.rect(padL, padT, pw, ph); g.clip();
    // origin
    if (0 >= x0 && 0 <= x1 && 0 >= y0 && 0 <= y1) {
      g.strokeStyle = '#adb5bd'; g.lineWidth = 1;
      g.beginPath(); g.moveTo(X(0) - 6, Y(0)); g.lineTo(X(0) + 6, Y(0)); g.moveTo(X(0), Y(0) - 6); g.lineTo(X(0), Y(0) + 6); g.stroke();
    }
    // tracks: sources under, fused on top
    g.lineJoin = 'round'; g.lineCap = 'round';
    for (const tr of tracks) {
      const p = tr.pts;
      g.strokeStyle = tr.color; g.lineWidth = tr.width; g.globalAlpha = tr.label === 'fused' ? 1 : 0.8;
      g.beginPath();
      let pen = false;
      for (let i = 0; i < p.length; i += 2) {
        if (p[i] !== p[i]) { pen = false; continue; }
        if (pen) g.lineTo(X(p[i]), Y(p[i + 1])); else { g.moveTo(X(p[i]), Y(p[i + 1])); pen = true; }
      }
      g.stroke();
      g.globalAlpha = 1;
      // current position marker
      let k = p.length - 2;
      while (k >= 0 && p[k] !== p[k]) k -= 2;
      if (k >= 0 && tr.label !== 'fused') {
        g.fillStyle = tr.color; g.strokeStyle = '#fff'; g.lineWidth = 1.5;
        g.beginPath(); g.arc(X(p[k]), Y(p[k + 1]), 3.5, 0, 2 * Math.PI); g.fill(); g.stroke();
      }
    }
    // heading arrow at the fused position (ENU yaw: 0 = east, counter-clockwise)
    const fused = tracks.find((t) => t.label === 'fused');
    const lp = i1 > 0 ? store.phys(i1 - 1) : -1;
    let fx = NaN, fy = NaN, yaw = NaN;
    if (fused) {
      for (let i = i1 - 1; i >= i0; i--) {
        const q = store.phys(i);
        if (C.px[q] === C.px[q] && C.py[q] === C.py[q]) { fx = C.px[q]; fy = C.py[q]; yaw = C.yaw[q]; break; }
      }
    }
    if (fx === fx) {
      const sx = X(fx), sy = Y(fy);
      if (yaw === yaw) {
        const L = 22, dx = Math.cos(yaw), dy = -Math.sin(yaw);
        g.save(); g.translate(sx, sy); g.rotate(Math.atan2(dy, dx));
        g.fillStyle = COLORS.fused; g.strokeStyle = '#fff'; g.lineWidth = 1.5;
        g.beginPath(); g.moveTo(L, 0); g.lineTo(-7, -8); g.lineTo(-2, 0); g.lineTo(-7, 8); g.closePath();
        g.stroke(); g.fill(); g.restore();
      } else {
        g.fillStyle = COLORS.fused; g.beginPath(); g.arc(sx, sy, 4.5, 0, 2 * Math.PI); g.fill();
      }
    }
    g.restore();
    // north arrow + scale bar
    g.fillStyle = '#495057'; g.strokeStyle = '#495057'; g.lineWidth = 1.5;
    const nx = padL + pw - 14, ny = padT + 8;
    g.beginPath(); g.moveTo(nx, ny); g.lineTo(nx - 5, ny + 12); g.lineTo(nx + 5, ny + 12); g.closePath(); g.fill();
    g.textAlign = 'center'; g.textBaseline = 'top'; g.fillText('N', nx, ny + 13);
    const barPx = step * scale;
    const bx = padL + 8, by = padT + ph - 8;
    g.beginPath(); g.moveTo(bx, by - 4); g.lineTo(bx, by); g.lineTo(bx + barPx, by); g.lineTo(bx + barPx, by - 4); g.stroke();
    g.textAlign = 'left'; g.textBaseline = 'bottom'; g.fillText(`${step.toFixed(dec)} m`, bx + barPx + 4, by + 2);

    // info line
    const pose = lastPose;
    $('#map-info').textContent = lp >= 0 && fx === fx
      ? `x ${fmt(fx)}  y ${fmt(fy)}  z ${fmt(C.pz[lp] === C.pz[lp] ? C.pz[lp] : pose && pose.z)} m · yaw ${isNum(yaw) ? (yaw * 180 / Math.PI).toFixed(0) : '—'}°` +
        (pose && isNum(pose.vx) && W > 330 ? ` · ${fmt(Math.hypot(pose.vx, pose.vy, pose.vz || 0), 1)} m/s` : '')
      : '';
  }

  function renderMapLegend() {
    const host = $('#map-legend');
    const items = [...state.sources, 'fused'];
    if (host.dataset.items !== items.join(',')) {
      host.dataset.items = items.join(',');
      host.replaceChildren(...items.map((s) => {
        const b = h('button', 'lg-item');
        b.type = 'button';
        b.dataset.series = s;
        const sw = h('span', 'sw'); sw.style.background = colorFor(s);
        if (s === 'fused') sw.classList.add('thick');
        b.append(sw, document.createTextNode(s));
        b.addEventListener('click', () => toggleSource(s));
        return b;
      }));
    }
    for (const b of host.children) b.classList.toggle('off', state.visible[b.dataset.series] === false);
  }

  function toggleSource(label) {
    const show = state.visible[label] === false;
    state.visible[label] = show;
    for (const [n, c] of Object.entries(charts)) {
      if (chartDefs[n].group !== 'src') continue;
      const j = c.series.findIndex((s, k) => k > 0 && s.label === label);
      if (j > 0) c.setSeries(j, { show }, false);
    }
    renderMapLegend();
    requestDraw(true);
  }

  // ------------------------------------------------------------------ redraw
  let scheduled = false, lastDraw = 0, dirty = false;
  const minInterval = () => (state.win >= 300 ? 250 : 100);
  function requestDraw(force) {
    if (state.paused && !force) return;
    dirty = true;
    if (scheduled) return;
    scheduled = true;
    const wait = force ? 0 : Math.max(0, lastDraw + minInterval() - performance.now());
    setTimeout(() => requestAnimationFrame(drawFrame), wait);
  }
  function drawFrame() {
    scheduled = false;
    if (!dirty) return;
    dirty = false;
    lastDraw = performance.now();
    draw();
    // uPlot renders in a microtask queued by setData/setScale; this one runs after it
    const t0 = lastDraw;
    queueMicrotask(() => { state.drawMs = performance.now() - t0; });
  }

  function draw() {
    if (sourcesChanged) {
      sourcesChanged = false;
      buildCharts(['pos_x', 'pos_y', 'pos_z', 'delta_x', 'delta_y', 'delta_z']);
      renderMapLegend();
      for (const n of Object.keys(charts)) resizeObs.observe($(`[data-chart="${n}"] .plot`));
    }
    const tEnd = state.paused && isNum(state.pausedT) ? state.pausedT : store.lastT();
    const t0 = isNum(tEnd) ? tEnd - state.win : 0;
    const i0 = store.len ? store.lowerBound(t0) : 0;
    const i1 = store.len ? (state.paused ? store.lowerBound(tEnd + 1e-9) : store.len) : 0;
    for (const [name, u] of Object.entries(charts)) {
      const def = chartDefs[name];
      const shown = def.series.map((s, k) => u.series[k + 1].show);
      const { data, count, lastIdx } = buildData(def.series.map((s) => s.col), i0, i1, shown);
      state.counts[name] = count;
      u.setData(data, false);
      if (isNum(tEnd) && !u._skyfuseZoomed) u.setScale('x', { min: t0, max: tEnd });
      if (!u._skyfuseHover) u.setLegend({ idxs: [data[0].length ? data[0].length - 1 : null, ...lastIdx] });
    }
    drawMap(i0, i1);
  }

  // ------------------------------------------------------------- status side
  const HEALTH_ORDER = { failed: 0, stale: 1, no_data: 2, degraded: 3, ok: 4, disabled: 5 };
  function sensorView(s, est) {
    const hl = s.health;
    const stateName = typeof hl === 'string' ? hl : (hl && hl.state) || 'no_data';
    const reasons = s.reasons || (hl && hl.reasons) || [];
    const src = est && est.sources ? est.sources[s.id] : null;
    const testRatio = s.test_ratio !== undefined ? s.test_ratio : src ? src.test_ratio : null;
    let used = s.used;
    if (used === undefined) used = est && Array.isArray(est.sources_used) ? est.sources_used.includes(s.id) : null;
    return { ...s, state: stateName, reasons, testRatio, used };
  }

  // An input with nothing (or nothing lately) says on its card which key it waits
  // for, and what is published that looks meant for it (from /api/v1/discovered).
  function renderWaiting(el, s) {
    const waiting = s.state === 'no_data' || s.state === 'stale';
    const near = waiting ? state.network.filter((k) => k.near && k.near.input === s.id) : [];
    const sig = waiting ? `${s.key}\u0000${near.map((k) => k.key).join('\u0000')}` : '';
    if (el.dataset.v === sig) return;
    el.dataset.v = sig;
    el.replaceChildren();
    if (!waiting) return;
    el.append(document.createTextNode(s.state === 'stale' ? 'nothing lately on ' : 'waiting for '), h('code', null, s.key || '?'));
    for (const k of near) {
      const line = h('div', 'near');
      line.append(document.createTextNode('published: '), h('code', null, k.key),
        document.createTextNode(` ${fmt(k.rate_hz, 1)} Hz: ${k.near.why}`));
      el.append(line);
    }
  }

  const tileEls = new Map();
  function renderTiles(sensors, est) {
    const host = $('#tiles');
    const ids = sensors.map((s) => s.id);
    if (host.dataset.ids !== ids.join('\u0000')) {
      host.dataset.ids = ids.join('\u0000');
      tileEls.clear();
      host.replaceChildren();
      if (!sensors.length) host.append(h('div', 'empty muted', 'no sensors configured'));
      for (const s of sensors) {
        const t = h('div', 'tile');
        t.dataset.sensor = s.id;
        t.innerHTML = '<div class="tile-head"><span class="sw"></span><span class="tid"></span><span class="tkind muted"></span><span class="badge"></span></div>' +
          '<div class="tile-grid">' +
          '<span class="k">rate</span><span class="v f-rate"></span><span class="k">age</span><span class="v f-age"></span>' +
          '<span class="k">qual.</span><span class="v f-q"></span><span class="k">test</span><span class="v f-tr"></span>' +
          '<span class="k">fused</span><span class="v f-used"></span><span class="k">rx/rej</span><span class="v f-rx"></span>' +
          '</div><div class="waiting"></div><ul class="reasons"></ul>';
        host.append(t);
        tileEls.set(s.id, t);
      }
    }
    const counts = {};
    for (const raw of sensors) {
      const s = sensorView(raw, est);
      const t = tileEls.get(s.id);
      if (!t) continue;
      counts[s.state] = (counts[s.state] || 0) + 1;
      t.dataset.state = s.state;
      $('.sw', t).style.background = COLORS[s.id] || COLORS[s.kind] || '#adb5bd';
      $('.tid', t).textContent = s.id;
      $('.tkind', t).textContent = s.kind && s.kind !== s.id ? s.kind : '';
      t.title = [s.key && `key ${s.key}`, s.format && `format ${s.format}`, s.last_error && `last error: ${s.last_error}`].filter(Boolean).join('\n');
      const b = $('.badge', t);
      b.textContent = s.state.replace('_', ' ');
      b.className = `badge st-${s.state}`;
      const rate = $('.f-rate', t);
      rate.textContent = `${fmt(s.rate_hz, isNum(s.rate_hz) && s.rate_hz >= 100 ? 0 : 1)}/${fmt(s.expected_rate_hz, 0)} Hz`;
      rate.classList.toggle('warn', isNum(s.rate_hz) && isNum(s.expected_rate_hz) && s.expected_rate_hz > 0 && s.rate_hz < 0.8 * s.expected_rate_hz);
      const age = $('.f-age', t);
      age.textContent = fmtMs(s.age_ms);
      age.classList.toggle('warn', isNum(s.age_ms) && isNum(s.expected_rate_hz) && s.expected_rate_hz > 0 && s.age_ms > 3000 / s.expected_rate_hz);
      $('.f-q', t).textContent = isNum(s.quality) ? String(Math.round(s.quality)) : '—';
      const tr = $('.f-tr', t);
      tr.textContent = isNum(s.testRatio) ? s.testRatio.toFixed(2) : '—';
      tr.className = `v f-tr${isNum(s.testRatio) ? (s.testRatio > 1 ? ' bad' : s.testRatio > 0.5 ? ' warn' : '') : ''}`;
      const used = $('.f-used', t);
      used.textContent = s.used === true ? 'yes' : s.used === false ? 'no' : '—';
      used.className = `v f-used${s.used === true ? ' good' : ''}`;
      $('.f-rx', t).textContent = `${s.received ?? s.accepted ?? '—'}/${s.rejected ?? '—'}`;
      renderWaiting($('.waiting', t), s);
      const ul = $('.reasons', t);
      const rs = s.reasons.map((r) => (typeof r === 'string' ? r : r.text || r.code || ''));
      if (ul.dataset.v !== rs.join('\n')) {
        ul.dataset.v = rs.join('\n');
        ul.replaceChildren(...s.reasons.map((r) => {
          const li = h('li');
          if (r && r.code) li.append(h('code', null, r.code), document.createTextNode(' '));
          li.append(document.createTextNode(typeof r === 'string' ? r : r.text || ''));
          return li;
        }));
      }
    }
    $('#sensors-summary').textContent = Object.entries(counts)
      .sort((a, b) => (HEALTH_ORDER[a[0]] ?? 9) - (HEALTH_ORDER[b[0]] ?? 9))
      .map(([k, v]) => `${v} ${k.replace('_', ' ')}`).join(' · ');
    // fault injector sensor list
    const sel = $('#fault-sensor');
    if (sel.dataset.ids !== ids.join('\u0000')) {
      const cur = sel.value;
      sel.dataset.ids = ids.join('\u0000');
      sel.replaceChildren(...ids.map((id) => { const o = h('option', null, id); o.value = id; return o; }));
      if (ids.includes(cur)) sel.value = cur;
    }
  }

  function renderEstimator(st) {
    const e = st.estimator;
    const dl = $('#est');
    const badge = $('#est-badge');
    const pill = $('#est-pill');
    const rows = [];
    if (!e) {
      badge.textContent = 'not started'; badge.className = 'badge st-no_data';
      pill.textContent = 'estimator not started'; pill.className = 'pill st-no_data';
      rows.push(['state', 'not running yet']);
    } else {
      const ok = !!e.valid;
      const cls = ok ? 'st-ok' : e.initialised ? 'st-failed' : 'st-no_data';
      badge.textContent = ok ? 'valid' : e.initialised ? 'invalid' : 'initialising';
      badge.className = `badge ${cls}`;
      pill.textContent = `${e.mode || '?'} · ${badge.textContent}`;
      pill.className = `pill ${cls}`;
      pill.title = e.invalid_reason || '';
      if (!ok) rows.push(['why invalid', e.invalid_reason || (e.initialised ? 'unknown' : 'not initialised'), 'full bad']);
      rows.push(['mode', e.mode ?? '—']);
      rows.push(['reset counter', String(e.reset_counter ?? '—')]);
      const sd = e.position_std;
      rows.push(['position σ', Array.isArray(sd) ? `${sd.map((v) => fmt(v, 2)).join(' / ')} m` : '—', 'full']);
      const pr = e.integrity && e.integrity.protection;
      if (pr) {
        const over = pr.horizontal_m > pr.horizontal_alert_m || pr.vertical_m > pr.vertical_alert_m;
        rows.push(['protection', `H ${fmt(pr.horizontal_m, 1)} / V ${fmt(pr.vertical_m, 1)} m (limits ${fmt(pr.horizontal_alert_m, 0)} / ${fmt(pr.vertical_alert_m, 0)})`, over ? 'full bad' : 'full']);
      }
      const excluded = e.integrity && Array.isArray(e.integrity.excluded) ? e.integrity.excluded : [];
      if (excluded.length) rows.push(['excluded', excluded.join(', '), 'full bad']);
      rows.push(['sources used', Array.isArray(e.sources_used) && e.sources_used.length ? e.sources_used.join(', ') : 'none', 'full']);
      if (e.calibration && e.calibration.state) {
        const c = e.calibration;
        rows.push(['flow calib.', `${c.state}${c.result ? ` → ${c.result.map((v) => fmt(v, 3)).join(', ')}` : ''}`]);
      }
    }
    const svc = st.service || {};
    const z = svc.zenoh || {};
    if (z.mode) {
      // A client without its router receives nothing: say so here, not only as stale tiles.
      const lost = z.mode === 'client' && z.routers === 0;
      const links = `${z.routers ?? '?'} router${z.routers === 1 ? '' : 's'}, ${z.peers ?? '?'} peer${z.peers === 1 ? '' : 's'}`;
      rows.push(['Zenoh', `${z.mode} · ${lost ? 'no router, reconnecting' : links}`, lost ? 'full bad' : null]);
    }
    // The estimator's clock: a simulator faster than real time runs it at its rate.
    const clock = (st.ingest || {}).clock;
    if (clock && clock.base === 'vehicle') {
      rows.push(['clock', `vehicle · ${fmt(clock.rate, 2)}× real time (${clock.reference})`, 'full warn']);
    }
    rows.push(['uptime', fmtDur(svc.uptime_s)]);
    const cells = [];
    for (const [k, v, cls] of rows) cells.push(h('dt', null, k), h('dd', cls || null, v));
    dl.replaceChildren(...cells);
    $('#vehicle').textContent = svc.vehicle || '';
    $('#version').textContent = svc.version ? `v${svc.version}` : '';
  }

  // The autopilot's clock (MAVLink TIMESYNC): poses carry its time once converged.
  function timesyncText(t) {
    if (!t.converged) return t.used || t.answered ? 'timesync: converging' : 'timesync: no answer yet';
    const rate = isNum(t.rate) && t.rate !== 1 ? ` · autopilot clock ×${fmt(t.rate, 2)}` : '';
    return `timesync rtt ${fmt(t.rtt_ms, 1)} ms${rate}`;
  }

  function renderOutputs(outputs) {
    const host = $('#outputs');
    if (!Array.isArray(outputs) || !outputs.length) {
      const msg = Array.isArray(outputs) ? 'no outputs configured' : 'no output status';
      if (host.textContent !== msg) host.replaceChildren(h('div', 'empty muted', msg));
      return;
    }
    host.replaceChildren(...outputs.map((o) => {
      const row = h('div', `out ${o.sending ? 'sending' : 'stopped'}`);
      const head = h('div', 'out-head');
      head.append(h('span', `badge ${o.sending ? 'st-ok' : 'st-failed'}`, o.sending ? 'sending' : 'not sending'),
        h('span', 'oname', o.name || '?'), h('span', 'okind muted', o.kind || ''), h('span', 'oend muted mono', o.endpoint || ''));
      const stats = h('div', 'out-stats mono');
      stats.textContent = [`${fmt(o.rate_hz, 1)} Hz`, `last sent ${isNum(o.last_sent_age_ms) ? `${fmtMs(o.last_sent_age_ms)} ago` : 'never'}`,
        `reset ${o.reset_counter ?? '—'}`, `sent ${o.sent ?? '—'}`, o.dropped ? `dropped ${o.dropped}` : '', o.errors ? `errors ${o.errors}` : '',
        o.timesync ? timesyncText(o.timesync) : '']
        .filter(Boolean).join(' · ');
      row.append(head, stats);
      if (!o.sending && o.not_sending_reason) row.append(h('div', 'out-why', o.not_sending_reason));
      if (o.last_error) row.append(h('div', 'out-err muted small', `last error: ${o.last_error}`));
      return row;
    }));
  }

  // The flight recorder and the Foxglove live view, as one more row under the outputs.
  function renderRecorder(r) {
    let host = $('#recorder');
    if (!r) { if (host) host.remove(); return; }
    if (!host) { host = h('div', 'out'); host.id = 'recorder'; $('#outputs-card').append(host); }
    const ok = !r.error;
    const head = h('div', 'out-head');
    head.append(h('span', `badge ${r.recording ? (ok ? 'st-ok' : 'st-failed') : 'st-disabled'}`,
      r.recording ? (ok ? 'recording' : 'stopped') : 'not recording'),
    h('span', 'oname', 'recorder'), h('span', 'okind muted', 'mcap'), h('span', 'oend muted mono', r.file || ''));
    const stats = h('div', 'out-stats mono');
    // `messages` counts what the recorder thread logged: to the MCAP file when
    // recording, else only to the Foxglove live view.
    const what = r.recording ? 'recorded' : r.foxglove ? 'streamed to Foxglove' : 'logged';
    stats.textContent = [r.recording ? `${fmt((r.bytes || 0) / 1048576, 1)} MiB in ${r.files ?? 0} file${r.files === 1 ? '' : 's'}` : '',
      `${r.messages ?? 0} messages ${what}`, r.dropped ? `dropped ${r.dropped}` : 'none dropped',
      r.foxglove ? `Foxglove ws://${r.foxglove} (${r.foxglove_clients ?? 0} client${r.foxglove_clients === 1 ? '' : 's'})` : '']
      .filter(Boolean).join(' · ');
    host.replaceChildren(head, stats);
    if (r.error) host.append(h('div', 'out-why', r.error));
  }

  function onStatus(st) {
    state.status = st;
    const est = st.estimator || null;
    renderEstimator(st);
    renderTiles(Array.isArray(st.sensors) ? st.sensors : [], est);
    renderOutputs(st.outputs);
    renderRecorder(st.recorder);
    if (st.websocket && isNum(st.websocket.dropped_total)) state.serverDroppedTotal = st.websocket.dropped_total;
    state.wsClients = st.websocket ? st.websocket.clients : undefined;
    renderWsStats();
  }

  // ------------------------------------------------------------------ events
  // Event kinds (web/PROTOCOL.md) → [label, colour class]; an unknown kind shows as info.
  const KINDS = {
    health: ['health', 'health'], source_usable: ['usable', 'health'], clock_restart: ['clock', 'health'], time_base: ['clock', 'health'],
    source_switch: ['switch', 'source_switch'], segment: ['segment', 'source_switch'],
    reset: ['reset', 'reset'], terrain_reset: ['terrain', 'reset'], origin_set: ['origin', 'reset'],
    monitor_reset: ['monitor', 'monitor'], handled: ['handled', 'monitor'], constraint: ['constraint', 'monitor'],
    calibration_started: ['calib.', 'calibration'], calibration_result: ['calib.', 'calibration'],
    fault_injected: ['fault', 'fault_injected'], fault_cleared: ['fault', 'fault_injected'],
    zenoh_link: ['zenoh', 'control'], initialised: ['init', 'info'], sample_rejected: ['rejected', 'info'],
    gate_reject: ['gate', 'info'], late_drop: ['late', 'info'], info: ['info', 'info'],
  };
  function eventEl(ev) {
    const [label, cls] = KINDS[ev.kind] || KINDS.info;
    const li = h('li', `ev k-${cls}`);
    const k = h('span', 'ev-kind', label);
    k.title = ev.kind || 'info';
    li.append(h('span', 'ev-t mono', isNum(ev.t) ? ev.t.toFixed(1) : ''), k,
      h('span', 'ev-msg', ev.message || (ev.source ? `${ev.source}` : '')));
    const extra = [ev.source && `source: ${ev.source}`, ev.data && typeof ev.data === 'object' && Object.keys(ev.data).length ? JSON.stringify(ev.data) : '']
      .filter(Boolean).join('\n');
    if (extra) li.title = extra;
    return li;
  }
  // Kept in time order: an estimator event carries its sample's time and can arrive
  // after a later service event. state.events is oldest first, the list newest first.
  function addEvent(ev, live) {
    state.eventCount++;
    const t = isNum(ev.t) ? ev.t : Infinity;
    let i = state.events.length;
    while (i > 0 && isNum(state.events[i - 1].t) && state.events[i - 1].t > t) i--;
    state.events.splice(i, 0, ev);
    const ol = $('#events');
    const el = eventEl(ev);
    ol.insertBefore(el, ol.children[state.events.length - 1 - i] || null);
    if (state.events.length > MAX_EVENTS) { state.events.shift(); ol.lastChild.remove(); }
    if (live) el.classList.add('fresh');
    $('#events-count').textContent = `${state.events.length} shown`;
  }
  function renderEventsAll(list) {
    const ol = $('#events');
    ol.replaceChildren();
    state.events = [];
    for (const ev of list.slice(-MAX_EVENTS)) addEvent(ev, false);
    if (!list.length) $('#events-count').textContent = 'none yet';
  }

  // -------------------------------------------------------------- connection
  let ws = null, backoff = 500, reconnectAt = 0, reconnectTimer = null;
  const wantRate = () => ((navigator.connection && navigator.connection.saveData) || window.matchMedia('(max-width: 700px)').matches ? 5 : 20);
  function wsUrl() {
    const u = new URL('ws', window.location.href);
    u.protocol = u.protocol === 'https:' ? 'wss:' : 'ws:';
    u.hash = '';
    return u.href;
  }
  function setConn(s, text) {
    const c = $('#conn');
    c.dataset.state = s;
    document.body.classList.toggle('offline', s === 'down' || s === 'stale');
    $('#conn-text').textContent = text || { live: 'live', connecting: 'connecting…', open: 'connected, waiting for snapshot' }[s] || s;
  }
  function connect() {
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
  function renderWsStats() {
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

  // ---------------------------------------------------------------- controls
  const tokenEl = $('#token');
  try { tokenEl.value = sessionStorage.getItem(TOKEN_KEY) || ''; } catch (e) { /* storage blocked */ }
  tokenEl.addEventListener('input', () => {
    try {
      if (tokenEl.value) sessionStorage.setItem(TOKEN_KEY, tokenEl.value);
      else sessionStorage.removeItem(TOKEN_KEY);
    } catch (e) { /* storage blocked */ }
  });
  $('#controls').addEventListener('submit', (e) => e.preventDefault());

  function setResult(text, cls) {
    const r = $('#ctl-result');
    r.textContent = text;
    r.className = `ctl-result small ${cls || ''}`;
  }
  async function control(path, body, label, btn) {
    const token = tokenEl.value.trim();
    if (!token) { setResult(`${label}: enter the token first`, 'bad'); tokenEl.focus(); return; }
    btn.disabled = true;
    setResult(`${label}: sending…`, '');
    try {
      const res = await fetch(`api/v1/control/${path}`, {
        method: 'POST',
        headers: { Authorization: `Bearer ${token}`, 'Content-Type': 'application/json' },
        body: JSON.stringify(body || {}),
        cache: 'no-store',
      });
      let detail = '';
      try {
        const text = (await res.text()).trim();
        detail = text;
        try {
          const j = JSON.parse(text);
          if (j && typeof j === 'object') {
            detail = j.error || j.message || (Array.isArray(j.events) && j.events.join('; ')) || '';
          }
        } catch (e) { /* plain text */ }
      } catch (e) { /* no body */ }
      if (detail.length > 200) detail = `${detail.slice(0, 200)}…`;
      const tail = detail ? ` — ${detail}` : '';
      if (res.status === 401) setResult(`${label}: token refused (401)${tail}`, 'bad');
      else if (res.ok) setResult(`${label}: done (${res.status})${tail}`, 'good');
      else setResult(`${label}: HTTP ${res.status}${tail}`, 'bad');
    } catch (e) {
      setResult(`${label}: network error (${e.message || e})`, 'bad');
    } finally {
      btn.disabled = false;
    }
  }
  $('#btn-reset-origin').addEventListener('click', (e) => control('reset-origin', {}, 'reset origin', e.currentTarget));
  $('#btn-flow-cal').addEventListener('click', (e) => control('flow-calibration', {}, 'flow calibration', e.currentTarget));
  $('#btn-fault').addEventListener('click', (e) => {
    const sensor = $('#fault-sensor').value;
    const fault = $('#fault-kind').value;
    if (!sensor) { setResult('fault: no sensor to choose yet', 'bad'); return; }
    const body = { sensor, fault };
    const d = Number($('#fault-duration').value);
    if (fault !== 'clear' && isNum(d) && d > 0) body.duration_s = d;
    control('fault', body, `fault ${fault} → ${sensor}`, e.currentTarget);
  });

  // ------------------------------------------------------- window and pause
  function setWin(w) {
    state.win = w;
    for (const u of Object.values(charts)) u._skyfuseZoomed = false;
    try { localStorage.setItem('skyfuse.window', String(w)); } catch (e) { /* ignore */ }
    for (const b of document.querySelectorAll('#win-seg button')) b.setAttribute('aria-pressed', String(Number(b.dataset.win) === w));
    requestDraw(true);
  }
  function setPaused(p, redraw = true) {
    state.paused = p;
    state.pausedT = p ? store.lastT() : NaN;
    if (!p) for (const u of Object.values(charts)) u._skyfuseZoomed = false;
    const b = $('#pause');
    b.setAttribute('aria-pressed', String(p));
    b.textContent = p ? 'Resume' : 'Pause';
    document.body.classList.toggle('paused', p);
    if (!p || redraw) requestDraw(true);
  }
  for (const b of document.querySelectorAll('#win-seg button')) b.addEventListener('click', () => setWin(Number(b.dataset.win)));
  $('#pause').addEventListener('click', () => setPaused(!state.paused));
  document.addEventListener('keydown', (e) => {
    if (e.ctrlKey || e.metaKey || e.altKey || e.target.closest('input, select, textarea')) return;
    if (e.key === 'p' || (e.key === ' ' && !e.target.closest('button'))) { e.preventDefault(); setPaused(!state.paused); }
  });

  // -------------------------------------------------------------------- init
  buildCharts(['flow', 'pos_x', 'pos_y', 'pos_z', 'delta_x', 'delta_y', 'delta_z']);
  for (const n of Object.keys(charts)) resizeObs.observe($(`[data-chart="${n}"] .plot`));
  resizeObs.observe(mapWrap);
  renderMapLegend();
  setWin(state.win);
  connect();

  // ------------------------------------------- Network: every key on Zenoh
  // /api/v1/discovered: what each key is, who reads it, what an unread one looks meant
  // for. Refreshed every 3 s; the sensor cards use it for their "published:" hints.
  function keyWhat(k) {
    const what = k.ros_type ? `${k.ros_type}${k.type_from === 'announced' ? ' (bridge)' : ''}`
      : k.message ? `MAVLink ${k.message}` : k.candidates && k.candidates.length ? `CDR: one of ${k.candidates.join(', ')}`
        : k.format || 'not read by skyfuse';
    return k.kinds && k.kinds.length ? `${what} · ${k.kinds.join('+')}` : what;
  }
  function keyInput(k) {
    if (k.own_output) return 'this service';
    if (k.read_by && k.read_by.length) return k.read_by.join(', ');
    if (k.near) return `unused · meant for ${k.near.input}? ${k.near.why}`;
    return 'unused';
  }
  async function refreshNetwork() {
    try {
      const r = await fetch('api/v1/discovered', { cache: 'no-store' });
      const body = document.querySelector('#net-keys tbody');
      if (r.status === 404) {
        state.network = [];
        body.replaceChildren();
        $('#net-summary').textContent = 'discovery off ([discovery] enabled = false)';
        return;
      }
      if (!r.ok) return;
      const j = await r.json();
      const keys = (j.keys || []).slice().sort((a, b) => (a.own_output - b.own_output) || a.key.localeCompare(b.key));
      state.network = keys;
      body.replaceChildren(...keys.map((k) => {
        const tr = document.createElement('tr');
        tr.className = k.own_output ? 'own' : k.near ? 'near' : k.rate_hz > 0 ? '' : 'quiet';
        tr.dataset.key = k.key;
        const cells = [['key', k.key], ['rate', k.last_age_ms == null ? 'announced' : `${fmt(k.rate_hz, 1)} Hz`],
          ['what', keyWhat(k)], ['input', keyInput(k)]];
        for (const [cls, c] of cells) { const td = document.createElement('td'); td.className = cls; td.textContent = c; tr.appendChild(td); }
        return tr;
      }));
      const unused = keys.filter((k) => !k.own_output && !(k.read_by && k.read_by.length)).length;
      $('#net-summary').textContent = keys.length
        ? `${keys.length} key${keys.length === 1 ? '' : 's'} · ${unused} unused${j.overflow ? ` · ${j.overflow} messages on keys not listed` : ''}`
        : 'nothing published';
      if (state.status) renderTiles(Array.isArray(state.status.sensors) ? state.status.sensors : [], state.status.estimator || null);
    } catch (e) { /* the service is restarting: the websocket shows it */ }
  }
  refreshNetwork();
  setInterval(refreshNetwork, 3000);

  // test hook: cheap accessors only
  window.skyfuse = {
    charts,
    pointCounts() {
      const out = {};
      for (const n of Object.keys(charts)) out[n] = state.counts[n] || 0;
      out.map = state.counts.map || 0;
      return out;
    },
    tiles: () => [...tileEls.keys()],
    // What a series of a chart draws: how many gaps uPlot cut in its line.
    gaps(chart, label) {
      const u = charts[chart];
      if (!u) return null;
      const i = u.series.findIndex((x) => x.label === label);
      if (i < 1) return null;
      const p = u.series[i]._paths;
      return p && p.gaps ? p.gaps.length : 0;
    },
    network: () => state.network.map((k) => k.key),
    events: () => state.events.map((e) => e.message || '').reverse(),
    get frames() { return state.frames; },
    // Frames the server dropped for this page (a slow page loses frames by design, and says so).
    get dropped() { return Math.max(state.dropped, state.droppedTotal); },
    get drawMs() { return state.drawMs; }, // duration of the last redraw (ms)
    get eventCount() { return state.eventCount; }, // events received since load (snapshot ones included)
    get paused() { return state.paused; },
    get window() { return state.win; },
  };
})();
