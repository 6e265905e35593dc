// The control bar: the token, reset origin, flow calibration, fault injection; the
// time window and pause.
import { $, TOKEN_KEY, isNum } from './dash-util.js';
import { state, store } from './dash-store.js';
import { charts } from './dash-charts.js';
import { requestDraw } from './dash-draw.js';

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

export function setResult(text, cls) {
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
export function setWin(w) {
  state.win = w;
  for (const u of Object.values(charts)) u._skyfuseZoomed = false;
  try { localStorage.setItem('skyfuse.window', String(w)); } catch (e) { /* ignore */ }
  for (const b of document.querySelectorAll('#win-seg button')) b.setAttribute('aria-pressed', String(Number(b.dataset.win) === w));
  requestDraw(true);
}
export function setPaused(p, redraw = true) {
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
