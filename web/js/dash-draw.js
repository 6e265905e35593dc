// Redraws, at most every 100 ms (250 ms on the 5 min window), of the charts and the map.
import { $, isNum } from './dash-util.js';
import { state, store } from './dash-store.js';
import { buildCharts, buildData, chartDefs, charts, resizeObs } from './dash-charts.js';
import { drawMap, renderMapLegend } from './dash-map.js';

// ------------------------------------------------------------------ redraw
let scheduled = false, lastDraw = 0, dirty = false;
const minInterval = () => (state.win >= 300 ? 250 : 100);
export function requestDraw(force) {
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
  if (state.sourcesChanged) {
    state.sourcesChanged = false;
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
