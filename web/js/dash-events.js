// The event log, newest first, in the time order of the events.
import { $, MAX_EVENTS, h, isNum } from './dash-util.js';
import { state } from './dash-store.js';

// ------------------------------------------------------------------ events
// Event kinds (web/PROTOCOL.md) → [label, colour class]; an unknown kind shows as info.
const KINDS = {
  health: ['health', 'health'], source_usable: ['usable', 'health'], clock_restart: ['clock', 'health'], time_base: ['clock', 'health'],
  source_switch: ['switch', 'source_switch'], segment: ['segment', 'source_switch'],
  reset: ['reset', 'reset'], terrain_reset: ['terrain', 'reset'], origin_set: ['origin', 'reset'],
  monitor_reset: ['monitor', 'monitor'], handled: ['handled', 'monitor'], constraint: ['constraint', 'monitor'],
  integrity_exclusion: ['excluded', 'reset'], integrity_readmit: ['readmitted', 'source_switch'],
  dead_reckoning_doubted: ['IMU doubted', 'reset'], calibration_ran_away: ['IMU doubted', 'reset'],
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
export function addEvent(ev, live) {
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
export function renderEventsAll(list) {
  const ol = $('#events');
  ol.replaceChildren();
  state.events = [];
  for (const ev of list.slice(-MAX_EVENTS)) addEvent(ev, false);
  if (!list.length) $('#events-count').textContent = 'none yet';
}
