// The fleet list: search, sort, and only the rows in view in the DOM (a thousand
// vehicles are a thousand rows of data but some twenty <tr>s), each a fixed height so
// the scroll position says which rows are in view without measuring any.
import { colour, esc, state, stats } from "./fleet-common.js";

const ROW_H = 46;        // px, as in fleet.html's CSS (#fleet-rows tr)
const OVERSCAN = 6;      // rows drawn beyond the view on each side: no blank flash on scroll

const listEl = document.getElementById("fleet-list");
const sizer = document.getElementById("fleet-sizer");
const table = document.getElementById("fleet-table");
const body = document.getElementById("fleet-rows");
const search = document.getElementById("fleet-search");
const sortSel = document.getElementById("fleet-sort");
const pickedEl = document.getElementById("fleet-picked");

// Worst first: what an operator must look at tops the list when sorted by state.
const PRESENCE_RANK = { gone: 3, stale: 2, live: 0 };
const HEALTH_RANK = { failed: 4, stale: 3, no_data: 2, degraded: 1, ok: 0 };
function severity(v) {
  return (PRESENCE_RANK[v.presence] ?? 0) * 100 + (v.valid === false ? 20 : 0) +
    (HEALTH_RANK[v.worst_health] ?? 0) * 3 + (v.vpe === "withheld" ? 1 : 0);
}
const SORTS = {
  slot: (a, b) => a.slot - b.slot,
  state: (a, b) => severity(b) - severity(a) || a.name.localeCompare(b.name),
  name: (a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }) || a.slot - b.slot,
  heard: (a, b) => b.heard_s_ago - a.heard_s_ago || a.slot - b.slot,
};

const tag = (cls, text, title) => `<span class="tag ${cls}"${title ? ` title="${esc(title)}"` : ""}>${esc(text)}</span>`;

function rowHtml(v) {
  const presence = { live: tag("t-ok", "live"), stale: tag("t-warn", "stale"), gone: tag("t-grey", "gone") }[v.presence];
  const heard = v.heard_s_ago < 1.5 ? "" : ` <span class="muted small">${v.heard_s_ago.toFixed(0)} s ago</span>`;
  const link = v.zenoh ? `<span class="muted small">${v.zenoh.routers} routers · ${v.zenoh.peers} peers</span>` : "";
  let est = "—";
  if (v.valid === true) est = tag("t-ok", "valid") + (v.position_std_m != null ? ` <span class="muted small nw">σ ${v.position_std_m.toFixed(2)} m</span>` : "");
  else if (v.valid === false) est = tag("t-bad", "invalid", v.invalid_reason) + ` <span class="small">${esc(v.invalid_reason)}</span>`;
  const worst = v.worst_health;
  const wcls = worst === "ok" ? "t-ok" : worst === "degraded" ? "t-warn" : worst ? "t-bad" : "t-grey";
  const sensors = worst ? tag(wcls, worst) + (v.unhealthy.length ? ` <span class="small">${esc(v.unhealthy.join(", "))}</span>` : "") : "—";
  const vpe = v.vpe === "sending" ? tag("t-ok", "sending") : v.vpe === "withheld" ? tag("t-bad", "withheld", v.vpe_reason) : v.vpe === "off" ? tag("t-grey", "off", "no MAVLink endpoint") : "—";
  const ev = v.last_event ? `<span class="small ev" title="${esc(v.last_event.message)}">${esc(v.last_event.message)}</span>` : "—";
  const restarts = v.restarts ? ` <span class="muted small" title="restarts seen">↻${v.restarts}</span>` : "";
  const frame = v.frame === "local" ? ` <span class="muted small" title="no GNSS origin: drawn in its own frame">local</span>` : "";
  return `<td><span class="swatch" style="background:${colour(v)}"></span><b>${esc(v.name)}</b>${restarts}${frame}<span class="id">${esc(v.id)}</span></td>` +
    `<td>${presence}${heard}<br>${link}</td><td>${est}</td><td class="small">${esc((v.sources || []).join(", ")) || "—"}</td>` +
    `<td>${sensors}</td><td>${vpe}</td><td>${ev}</td>`;
}

// What the search box matches: name, id, presence, estimate and sensor states.
function haystack(v) {
  return `${v.name} ${v.id} ${v.presence} ${v.valid === false ? "invalid " + (v.invalid_reason || "") : v.valid ? "valid" : ""} ${v.worst_health || ""} ${v.unhealthy.join(" ")} ${v.vpe || ""}`.toLowerCase();
}

let shown = [];   // the filtered, sorted vehicles

// Recompute the filtered and sorted list (on new data, a search or a sort change).
export function refreshList() {
  const q = search.value.trim().toLowerCase();
  const terms = q ? q.split(/\s+/) : [];
  const all = [...state.vehicles.values()];
  shown = all.filter((v) => (!state.picked || state.picked.has(v.id)) && terms.every((t) => haystack(v).includes(t)));
  shown.sort(SORTS[sortSel.value] || SORTS.slot);
  let live = 0, stale = 0, gone = 0, local = 0;
  for (const v of all) {
    if (v.presence === "live") live++; else if (v.presence === "stale") stale++; else gone++;
    if (v.frame === "local") local++;
  }
  document.getElementById("fleet-empty").style.display = all.length ? "none" : "";
  document.getElementById("fleet-counts").textContent = `${all.length} vehicles · ${live} live · ${stale} stale · ${gone} gone`;
  document.getElementById("fleet-shown").textContent = shown.length === all.length ? "" : `${shown.length} of ${all.length} shown`;
  pickedEl.hidden = !state.picked;
  if (state.picked) pickedEl.querySelector("span").textContent = `${state.picked.size} picked on the map`;
  document.getElementById("map-note").textContent = state.reference
    ? `origin ${state.reference.lat.toFixed(6)}, ${state.reference.lon.toFixed(6)}` + (local ? ` · ${local} without GNSS drawn in their own frame` : "")
    : (all.length ? "no GNSS origin yet: each vehicle in its own frame" : "");
  renderRows();
}

// Put the rows in view into the DOM, reusing the <tr> of a vehicle already there.
function renderRows() {
  sizer.style.height = `${shown.length * ROW_H}px`;
  const first = Math.max(0, Math.floor(listEl.scrollTop / ROW_H) - OVERSCAN);
  const last = Math.min(shown.length, Math.ceil((listEl.scrollTop + listEl.clientHeight) / ROW_H) + OVERSCAN);
  table.style.top = `${first * ROW_H}px`;
  const existing = new Map([...body.children].map((tr) => [tr.dataset.id, tr]));
  for (let i = first; i < last; i++) {
    const v = shown[i];
    let tr = existing.get(v.id);
    if (!tr) { tr = document.createElement("tr"); tr.dataset.id = v.id; }
    existing.delete(v.id);
    tr.dataset.presence = v.presence;
    tr.dataset.name = v.name;
    tr.title = v.dashboard ? `open ${v.dashboard}` : "no dashboard announced";
    const html = rowHtml(v);
    if (tr._html !== html) { tr.innerHTML = html; tr._html = html; }
    const at = i - first;
    if (body.children[at] !== tr) body.insertBefore(tr, body.children[at] || null);
  }
  for (const tr of existing.values()) tr.remove();
  stats.rowsRendered = body.children.length;
}

// Scrolling only moves the window over the same list.
let scrollQueued = false;
listEl.addEventListener("scroll", () => {
  if (scrollQueued) return;
  scrollQueued = true;
  requestAnimationFrame(() => { scrollQueued = false; renderRows(); });
});
window.addEventListener("resize", renderRows);
search.addEventListener("input", () => { listEl.scrollTop = 0; refreshList(); });
sortSel.addEventListener("change", () => { listEl.scrollTop = 0; refreshList(); });
pickedEl.querySelector("button").addEventListener("click", () => { state.picked = null; state.dirty = true; refreshList(); });

// A click on a row opens that vehicle's own dashboard (one listener for every row).
body.addEventListener("click", (e) => {
  const tr = e.target.closest("tr");
  const cur = tr && state.vehicles.get(tr.dataset.id);
  if (cur && cur.dashboard) window.open(cur.dashboard, "_blank", "noopener");
});

// Show one vehicle's row (a click on its marker).
export function reveal(id) {
  const i = shown.findIndex((v) => v.id === id);
  if (i < 0) return;
  listEl.scrollTop = Math.max(0, i * ROW_H - listEl.clientHeight / 2);
  renderRows();
  const tr = body.querySelector(`tr[data-id="${CSS.escape(id)}"]`);
  if (tr) { tr.classList.add("flash"); setTimeout(() => tr.classList.remove("flash"), 1200); }
}
