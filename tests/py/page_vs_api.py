#!/usr/bin/env python3
"""The dashboard says what the API says (issue 35): read the rendered page in a real
browser (Debian chromium, headless, via playwright) and compare every status word with
GET /api/v1/status taken at the same moment.

    python tests/py/page_vs_api.py --url http://127.0.0.1:PORT/ --expect flying|silent

Checks, whatever the state:
  - each sensor card's badge is the API's health; a card without data names, on the
    card itself, the key its input waits for (the API's `key`); no value on a card is
    cut (a text wider than its box);
  - each output row says "sending" exactly when the API does; a row not sending shows
    the API's reason; "last sent never" only when the API has no last send, and a rate
    of 0 when the API's is 0;
  - the recorder row says recording only when the API does, and what its message count
    is (recorded, or streamed to Foxglove);
  - the connection badge is green "live" only while poses arrive;
  - the event list is in time order.
--expect flying (`skyfuse demo`): the estimate is valid, the GPS (10 Hz under 20 Hz
  ticks) is drawn as one line in the position plots (no gap cut by uPlot), the Network
  panel lists the simulator's keys.
--expect silent (`skyfuse run`, nothing published): every card waits for its key, no
  output is sending, the badge is not live.

Prints one JSON line; exits 0 when every check passed, 1 otherwise (message on stderr).
"""
import argparse
import json
import os
import sys
import time
import urllib.request

from probe import CHROMIUM_ARGS  # noqa: E402


def api(url, path):
    with urllib.request.urlopen(url + path, timeout=5) as r:
        return json.load(r)


PAGE = """() => {
  const tiles = [...document.querySelectorAll('#tiles .tile')].map((t) => ({
    id: t.dataset.sensor, state: t.dataset.state,
    badge: t.querySelector('.badge').textContent,
    waiting: t.querySelector('.waiting') ? t.querySelector('.waiting').textContent : '',
    cut: [...t.querySelectorAll('.tile-grid .v')].filter((v) => v.scrollWidth > v.clientWidth + 1)
      .map((v) => v.textContent),
  }));
  const outputs = [...document.querySelectorAll('#outputs .out')].map((o) => ({
    name: o.querySelector('.oname') ? o.querySelector('.oname').textContent : '',
    badge: o.querySelector('.badge') ? o.querySelector('.badge').textContent : '',
    stats: o.querySelector('.out-stats') ? o.querySelector('.out-stats').textContent : '',
    why: o.querySelector('.out-why') ? o.querySelector('.out-why').textContent : '',
  }));
  const rec = document.querySelector('#recorder');
  const evs = [...document.querySelectorAll('#events .ev-t')].map((e) => parseFloat(e.textContent));
  return {
    tiles, outputs,
    recorder: rec ? { badge: rec.querySelector('.badge').textContent, stats: rec.querySelector('.out-stats').textContent } : null,
    conn: { state: document.querySelector('#conn').dataset.state, text: document.querySelector('#conn-text').textContent },
    events_t: evs,
    network: window.skyfuse.network(),
    gps_gaps: { pos_x: window.skyfuse.gaps('pos_x', 'gps'), pos_y: window.skyfuse.gaps('pos_y', 'gps') },
    points: window.skyfuse.pointCounts(),
    dropped: window.skyfuse.dropped,
  };
}"""


def compare(page, st, expect):
    """Every disagreement between the page and the API, as text."""
    bad = []
    sensors = {s["id"]: s for s in st.get("sensors", [])}
    for t in page["tiles"]:
        s = sensors.get(t["id"])
        if s is None:
            bad.append(f"tile {t['id']}: no such sensor in the API")
            continue
        health = s["health"] if isinstance(s["health"], str) else s["health"].get("state")
        if t["state"] != health:
            bad.append(f"tile {t['id']}: page {t['state']!r}, API {health!r}")
        if health in ("no_data", "stale") and s.get("key") and s["key"] not in t["waiting"]:
            bad.append(f"tile {t['id']} ({health}) does not name its key {s['key']!r}: {t['waiting']!r}")
        if t["cut"]:
            bad.append(f"tile {t['id']}: values cut {t['cut']}")
    outputs = {o["name"]: o for o in st.get("outputs", [])}
    for o in page["outputs"]:
        if o["name"] == "recorder":
            continue
        a = outputs.get(o["name"])
        if a is None:
            bad.append(f"output row {o['name']!r} not in the API")
            continue
        says_sending = o["badge"] == "sending"
        if says_sending != bool(a["sending"]):
            bad.append(f"output {o['name']}: page {o['badge']!r}, API sending={a['sending']}")
        if not a["sending"] and a.get("not_sending_reason") and a["not_sending_reason"] not in o["why"]:
            bad.append(f"output {o['name']}: reason {a['not_sending_reason']!r} not shown ({o['why']!r})")
        if ("last sent never" in o["stats"]) != (a.get("last_sent_age_ms") is None):
            bad.append(f"output {o['name']}: {o['stats']!r} vs last_sent_age_ms {a.get('last_sent_age_ms')}")
        if a.get("rate_hz") == 0 and not o["stats"].startswith("0.0 Hz"):
            bad.append(f"output {o['name']}: API rate 0, page {o['stats']!r}")
        if "— Hz" in o["stats"]:
            bad.append(f"output {o['name']}: no rate on the page {o['stats']!r}")
    rec = st.get("recorder")
    if rec and page["recorder"]:
        shown = page["recorder"]["badge"]
        if (shown == "recording") != bool(rec["recording"]):
            bad.append(f"recorder: page {shown!r}, API recording={rec['recording']}")
        if not rec["recording"] and "recorded" in page["recorder"]["stats"]:
            bad.append(f"recorder not recording but the page says recorded: {page['recorder']['stats']!r}")
    if page["conn"]["state"] == "live" and expect == "silent":
        bad.append(f"connection badge live with no pose: {page['conn']}")
    ts = [t for t in page["events_t"] if t == t]
    if any(a < b for a, b in zip(ts, ts[1:])):
        bad.append(f"events not newest first: {ts[:20]}")
    return bad


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", required=True)
    ap.add_argument("--expect", choices=["flying", "silent"], required=True)
    ap.add_argument("--timeout", type=float, default=45.0)
    ap.add_argument("--chromium", default=os.environ.get("SKYFUSE_CHROMIUM", "/usr/bin/chromium"))
    a = ap.parse_args()
    url = a.url if a.url.endswith("/") else a.url + "/"
    from playwright.sync_api import sync_playwright

    report = {"ok": False}
    problems = []
    errors = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=a.chromium, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(url)
            page.wait_for_function("() => window.skyfuse && window.skyfuse.tiles().length > 0", timeout=a.timeout * 1e3)
            end = time.time() + a.timeout
            # Settle: the state the page and API are compared in must be steady.
            while True:
                time.sleep(1.0)
                st = api(url, "api/v1/status")
                shown = page.evaluate(PAGE)
                st2 = api(url, "api/v1/status")
                problems = compare(shown, st, a.expect)
                # A status that changed while the page was read is read again.
                same = [s.get("health") for s in st["sensors"]] == [s.get("health") for s in st2["sensors"]] and \
                    [o["sending"] for o in st["outputs"]] == [o["sending"] for o in st2["outputs"]]
                if a.expect == "flying":
                    if not st["estimator"].get("valid"):
                        problems.append("estimate not valid yet")
                    if shown["points"].get("pos_x", 0) < 100:
                        problems.append(f"few points drawn yet: {shown['points']}")
                    # A gap is a fault unless the server dropped frames for this page
                    # (its queue drops oldest when the page falls behind, by design,
                    # and the page shows the count): then the line is cut where the
                    # frames were lost, and saying so is what the page must do.
                    for c, n in shown["gps_gaps"].items():
                        if n != 0 and not shown.get("dropped"):
                            problems.append(f"the GPS line in {c} has {n} gaps (the 10 Hz GPS drawn in fragments) "
                                            f"with no frame dropped")
                    if not any(k == "gps/fix" for k in shown["network"]):
                        problems.append(f"Network panel lacks gps/fix: {shown['network']}")
                    live = shown["conn"]["state"] == "live"
                    if not live:
                        problems.append(f"connection badge not live while flying: {shown['conn']}")
                else:
                    if any(o["sending"] for o in st["outputs"]):
                        problems.append(f"an output sends with nothing published: {st['outputs']}")
                    if shown["conn"]["state"] == "live":
                        problems.append(f"badge live: {shown['conn']}")
                    empty = [t for t in shown["tiles"] if t["state"] in ("no_data", "stale")]
                    if not empty:
                        problems.append(f"no card without data: {shown['tiles']}")
                    if not all(t["waiting"] for t in empty):
                        problems.append("a card without data does not say what it waits for")
                if same and not problems:
                    break
                if time.time() > end:
                    break
            report.update(page=shown, status_outputs=st["outputs"], recorder=st.get("recorder"))
        finally:
            browser.close()
    if errors:
        problems.append(f"page errors: {errors}")
    report["problems"] = problems
    report["ok"] = not problems
    print(json.dumps(report), flush=True)
    if problems:
        print("FAIL: " + "; ".join(problems), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
