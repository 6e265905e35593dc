// skyfuse dashboard: the entry module. No bundler: each panel is an ES module under
// js/ (served from the binary, src/http/assets.rs), loaded by the browser's own import;
// uPlot comes from vendor/uPlot.iife.min.js, a classic script loaded before this one.
// Data: one websocket (`ws`, relative to the page) carrying the frames in PROTOCOL.md.
import { $ } from './js/dash-util.js';
import { state } from './js/dash-store.js';
import { buildCharts, charts, resizeObs } from './js/dash-charts.js';
import { mapWrap, renderMapLegend } from './js/dash-map.js';
import { tileEls } from './js/dash-status.js';
import { connect } from './js/dash-connection.js';
import { setWin } from './js/dash-controls.js';
import { refreshNetwork } from './js/dash-network.js';

// -------------------------------------------------------------------- init
buildCharts(['flow', 'pos_x', 'pos_y', 'pos_z', 'delta_x', 'delta_y', 'delta_z']);
for (const n of Object.keys(charts)) resizeObs.observe($(`[data-chart="${n}"] .plot`));
resizeObs.observe(mapWrap);
renderMapLegend();
setWin(state.win);
connect();

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
