// The Network panel: every key on Zenoh, from /api/v1/discovered.
import { $, fmt } from './dash-util.js';
import { state } from './dash-store.js';
import { renderTiles } from './dash-status.js';

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
export async function refreshNetwork() {
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
