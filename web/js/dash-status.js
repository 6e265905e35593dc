// The status side: sensor tiles, the estimator, the outputs and the recorder.
import { $, COLORS, fmt, fmtDur, fmtMs, h, isNum } from './dash-util.js';
import { state } from './dash-store.js';
import { renderWsStats } from './dash-connection.js';

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

export const tileEls = new Map();
export function renderTiles(sensors, est) {
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
      // Relative navigation: the horizontal bound is from the last anchor, not take-off.
      if (pr.anchored_us != null && e.time_us != null) {
        rows.push(['anchored', `${fmt((e.time_us - pr.anchored_us) / 1e6, 0)} s ago (H relative to it)`, 'full']);
      }
    }
    const excluded = e.integrity && Array.isArray(e.integrity.excluded) ? e.integrity.excluded : [];
    if (excluded.length) rows.push(['excluded', excluded.join(', '), 'full bad']);
    const aside = e.integrity && e.integrity.set_aside;
    if (aside && Array.isArray(aside.separation)) {
      // The exclusion's other answer: were the source right, the estimate is this far off.
      const d = Math.hypot(aside.separation[0], aside.separation[1]);
      rows.push(['were it right', `${aside.source}: ${fmt(d, 1)} m H / ${fmt(Math.abs(aside.separation[2]), 1)} m V (in the bound)`, 'full']);
    }
    const held = e.integrity && Array.isArray(e.integrity.tests) ? e.integrity.tests.filter((t) => t.lone_receiver_held) : [];
    // The only receiver and the dead reckoning disagree: kept, and the bound holds both.
    for (const t of held) {
      const d = Math.hypot(t.separation[0], t.separation[1]);
      rows.push(['disagrees', `${t.source} (the only receiver) and the rest: ${fmt(d, 1)} m H (kept; in the bound)`, 'full']);
    }
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

export function onStatus(st) {
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
