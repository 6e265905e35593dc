// The time-series charts (uPlot, loaded before the modules as vendor/uPlot.iife.min.js).
import { $, COLORS, FONT, GAP_S, MAX_PTS, colorFor } from './dash-util.js';
import { C, state, store } from './dash-store.js';
import { requestDraw } from './dash-draw.js';
import { renderMapLegend } from './dash-map.js';
import { setPaused } from './dash-controls.js';

// ------------------------------------------------------------------ charts
export const charts = {};   // name -> uPlot
export const chartDefs = {}; // name -> {series: [{label, col}], group}

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

export function buildCharts(names) {
  const spec = seriesSpec();
  for (const n of names) {
    if (charts[n]) { charts[n].destroy(); delete charts[n]; }
    makeChart(n, spec[n]);
  }
}

export const resizeObs = new ResizeObserver((entries) => {
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
export function buildData(cols, i0, i1, shown) {
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
