// The top-down map: every position source's track and the fused one, with heading.
import { $, COLORS, FONT, GAP_S, MAX_PTS, colorFor, fmt, h, isNum } from './dash-util.js';
import { C, state, store } from './dash-store.js';
import { chartDefs, charts } from './dash-charts.js';
import { requestDraw } from './dash-draw.js';

// -------------------------------------------------------------- map canvas
const mapCanvas = $('#map');
export const mapWrap = $('.map-wrap');
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

export function drawMap(i0, i1) {
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
  const pose = state.lastPose;
  $('#map-info').textContent = lp >= 0 && fx === fx
    ? `x ${fmt(fx)}  y ${fmt(fy)}  z ${fmt(C.pz[lp] === C.pz[lp] ? C.pz[lp] : pose && pose.z)} m · yaw ${isNum(yaw) ? (yaw * 180 / Math.PI).toFixed(0) : '—'}°` +
      (pose && isNum(pose.vx) && W > 330 ? ` · ${fmt(Math.hypot(pose.vx, pose.vy, pose.vz || 0), 1)} m/s` : '')
    : '';
}

export function renderMapLegend() {
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
