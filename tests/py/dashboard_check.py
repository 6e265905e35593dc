#!/usr/bin/env python3
"""Drive the skyfuse dashboard in a real browser (Debian chromium, headless, via playwright).

    python tests/py/dashboard_check.py --url http://127.0.0.1:PORT/ --token TOKEN \
        --screenshot PATH [--inject-sensor gps --inject-fault stop]

1. GET {url}api/v1/status for the configured sensor ids.
2. Open the page and wait until every chart and the trajectory map report points
   (window.skyfuse.pointCounts()) and a health tile exists for every sensor id
   (window.skyfuse.tiles()).
3. With --inject-*: type the token into the token field, choose the sensor and the
   fault in the fault injector and click "Inject" (real input events), then wait until
   the POST succeeded, an event mentioning the sensor arrived in the event log, and the
   sensor's tile shows a non-ok state or a reason.
4. Save a screenshot; fail if the page logged any console error or threw.

Prints one JSON line (point counts, tiles, events seen, timings); exits 0 when every
check passed, 1 with a message on stderr (and "ok": false in the JSON) otherwise, 2 on
bad usage. Needs the `playwright` Python package (tests/requirements.txt) and a chromium
binary (Debian package `chromium`, /usr/bin/chromium); `playwright install` is never
needed or used.
"""
import argparse
import json
import os
import sys
import time
import urllib.error
import urllib.request

CHARTS = ["flow", "pos_x", "pos_y", "pos_z", "delta_x", "delta_y", "delta_z", "map"]
from probe import CHROMIUM_ARGS  # noqa: E402
FAULTS = ["stop", "nan", "no-fix", "jump", "covariance", "drift", "reset", "dark-floor", "tof-range", "accel-offset", "clear"]


class CheckFailed(Exception):
    pass


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", required=True, help="dashboard URL, e.g. http://127.0.0.1:8080/")
    ap.add_argument("--token", default=None, help="control token (needed with --inject-*)")
    ap.add_argument("--screenshot", required=True, help="PNG path to write")
    ap.add_argument("--inject-sensor", default=None, help="sensor id to inject a fault into")
    ap.add_argument("--inject-fault", default=None, choices=FAULTS, help="fault to inject")
    ap.add_argument("--inject-duration", type=float, default=None, help="fault duration (s); the page's default otherwise")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds for each wait (default 60)")
    ap.add_argument("--viewport", default="1400x900", help="WIDTHxHEIGHT (default 1400x900)")
    ap.add_argument("--allow-empty", action="append", default=[], choices=CHARTS,
                    help="a chart allowed to stay empty (repeatable), e.g. flow without a flow sensor")
    ap.add_argument("--chromium", default=os.environ.get("SKYFUSE_CHROMIUM", "/usr/bin/chromium"),
                    help="chromium binary (default $SKYFUSE_CHROMIUM or /usr/bin/chromium)")
    a = ap.parse_args()
    if bool(a.inject_sensor) != bool(a.inject_fault):
        ap.error("--inject-sensor and --inject-fault go together")
    if a.inject_sensor and not a.token:
        ap.error("--inject-* needs --token")
    if not a.url.endswith("/"):
        a.url += "/"
    try:
        w, h = (int(v) for v in a.viewport.lower().split("x"))
    except ValueError:
        ap.error("--viewport must look like 1400x900")
    a.size = {"width": w, "height": h}
    return a


def status_sensor_ids(url, timeout):
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url + "api/v1/status", timeout=5) as r:
                st = json.load(r)
            return [s["id"] for s in st.get("sensors") or []]
        except (urllib.error.URLError, OSError, ValueError, KeyError, TypeError) as e:
            last = e
            time.sleep(0.5)
    raise CheckFailed(f"GET {url}api/v1/status failed: {last}")


def main():
    a = parse_args()
    t_start = time.monotonic()
    timings = {}
    report = {"ok": False, "url": a.url}
    console_errors = []

    def mark(name, since):
        timings[name] = round(time.monotonic() - since, 3)

    try:
        from playwright.sync_api import Error as PlaywrightError
        from playwright.sync_api import TimeoutError as PlaywrightTimeout
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("dashboard_check: the playwright package is missing (pip install -r tests/requirements.txt)",
              file=sys.stderr)
        return 2
    if not os.access(a.chromium, os.X_OK):
        print(f"dashboard_check: no chromium at {a.chromium} (apt-get install chromium, or --chromium PATH)",
              file=sys.stderr)
        return 2

    pw = browser = None
    try:
        sensors = status_sensor_ids(a.url, a.timeout)
        report["expected_sensors"] = sensors
        if a.inject_sensor and a.inject_sensor not in sensors:
            raise CheckFailed(f"--inject-sensor {a.inject_sensor!r} is not among the service's sensors {sensors}")

        t = time.monotonic()
        pw = sync_playwright().start()
        browser = pw.chromium.launch(executable_path=a.chromium, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport=a.size)
        page.on("console", lambda m: m.type == "error" and console_errors.append(m.text))
        page.on("pageerror", lambda e: console_errors.append(f"uncaught: {e}"))
        mark("launch_s", t)

        t = time.monotonic()
        resp = page.goto(a.url, wait_until="load", timeout=a.timeout * 1000)
        if resp is None or not resp.ok:
            raise CheckFailed(f"GET {a.url} answered {resp.status if resp else 'nothing'}")
        try:
            page.wait_for_function("() => window.skyfuse && typeof window.skyfuse.pointCounts === 'function'",
                                   timeout=a.timeout * 1000)
        except PlaywrightTimeout:
            raise CheckFailed(f"window.skyfuse never appeared (page script failed?) console errors: {console_errors}")
        mark("page_s", t)

        # every chart and the map have points, every sensor has a tile
        t = time.monotonic()
        need = [c for c in CHARTS if c not in a.allow_empty]
        try:
            page.wait_for_function(
                """([need, sensors]) => {
                     const pc = window.skyfuse.pointCounts(), tiles = window.skyfuse.tiles();
                     return need.every((c) => pc[c] > 0) && sensors.every((s) => tiles.includes(s));
                   }""",
                arg=[need, sensors], timeout=a.timeout * 1000, polling=250)
        except PlaywrightTimeout:
            pc = page.evaluate("() => window.skyfuse.pointCounts()")
            tiles = page.evaluate("() => window.skyfuse.tiles()")
            empty = [c for c in need if not pc.get(c)]
            missing = [s for s in sensors if s not in tiles]
            raise CheckFailed(f"after {a.timeout:.0f} s: charts without points {empty}, sensors without a tile "
                              f"{missing} (point counts {pc}, tiles {tiles}, frames "
                              f"{page.evaluate('() => window.skyfuse.frames')})")
        mark("data_s", t)

        # The recorder / Foxglove row, when the service runs either.
        with urllib.request.urlopen(a.url + "api/v1/status", timeout=5) as r:
            recorder = json.load(r).get("recorder")
        if recorder:
            want = f"ws://{recorder['foxglove']}" if recorder.get("foxglove") else "messages"
            try:
                page.wait_for_function(
                    "(want) => ((document.querySelector('#recorder') || {}).textContent || '').includes(want)",
                    arg=want, timeout=a.timeout * 1000, polling=250)
            except PlaywrightTimeout:
                raise CheckFailed(f"the recorder row never showed {want!r}")
            report["recorder_row"] = page.evaluate("() => document.querySelector('#recorder').textContent")

        if a.inject_sensor:
            t = time.monotonic()
            report["injected"] = inject(page, a, PlaywrightTimeout)
            mark("inject_s", t)

        page.wait_for_timeout(300)  # one more redraw, so the screenshot shows the latest state
        info = page.evaluate("""() => ({pc: window.skyfuse.pointCounts(), tiles: window.skyfuse.tiles(),
                                        events: window.skyfuse.events(), frames: window.skyfuse.frames})""")
        report.update(point_counts=info["pc"], tiles=info["tiles"], events_seen=info["events"][:30],
                      events_total=len(info["events"]), frames=info["frames"])
        os.makedirs(os.path.dirname(os.path.abspath(a.screenshot)), exist_ok=True)
        page.screenshot(path=a.screenshot)
        report["screenshot"] = os.path.abspath(a.screenshot)
        if console_errors:
            raise CheckFailed(f"the page logged console errors: {console_errors}")
        report["ok"] = True
    except CheckFailed as e:
        report["error"] = str(e)
    except PlaywrightError as e:
        report["error"] = f"browser: {e}"
    finally:
        if console_errors:
            report["console_errors"] = console_errors
        if not report["ok"] and browser is not None and "screenshot" not in report:
            try:  # a picture of the failure helps more than none
                browser.contexts[0].pages[0].screenshot(path=a.screenshot)
                report["screenshot"] = os.path.abspath(a.screenshot)
            except Exception:  # noqa: BLE001 - best effort only
                pass
        for closer in (browser, pw):
            try:
                if closer is browser and browser is not None:
                    browser.close()
                elif closer is pw and pw is not None:
                    pw.stop()
            except Exception:  # noqa: BLE001
                pass
        mark("total_s", t_start)
        report["timings"] = timings
        print(json.dumps(report), flush=True)
    if not report["ok"]:
        print(f"dashboard_check: FAILED: {report['error']}", file=sys.stderr)
        return 1
    return 0


def inject(page, a, PlaywrightTimeout):
    sensor, fault = a.inject_sensor, a.inject_fault
    timeout_ms = a.timeout * 1000
    token = page.locator("#token")
    token.click()
    token.press("Control+a")
    token.press("Backspace")
    token.press_sequentially(a.token, delay=5)
    if page.evaluate("() => document.querySelector('#token').type") != "password":
        raise CheckFailed("the token field is not a password field")
    try:
        page.wait_for_function(
            "(s) => [...document.querySelectorAll('#fault-sensor option')].some((o) => o.value === s)",
            arg=sensor, timeout=timeout_ms)
    except PlaywrightTimeout:
        raise CheckFailed(f"the fault injector never offered sensor {sensor!r}")
    page.locator("#fault-sensor").select_option(sensor)
    page.locator("#fault-kind").select_option(fault)
    if a.inject_duration is not None:
        dur = page.locator("#fault-duration")
        dur.click()
        dur.press("Control+a")
        dur.press_sequentially(f"{a.inject_duration:g}")
    before = page.evaluate("() => window.skyfuse.eventCount")
    page.locator("#btn-fault").click()

    # the HTTP result the page shows
    try:
        page.wait_for_function(
            "() => { const r = document.querySelector('#ctl-result'); return r && /\\b(good|bad)\\b/.test(r.className); }",
            timeout=timeout_ms)
    except PlaywrightTimeout:
        raise CheckFailed(f"no result shown after clicking Inject: {page.locator('#ctl-result').inner_text()!r}")
    result = page.locator("#ctl-result").inner_text()
    if "bad" in page.locator("#ctl-result").get_attribute("class"):
        raise CheckFailed(f"fault injection refused: {result!r}")

    # an event about the sensor, and the sensor's tile off "ok" or with a reason
    try:
        handle = page.wait_for_function(
            """([sensor, before]) => {
                 const sk = window.skyfuse, fresh = sk.events().slice(0, Math.max(0, sk.eventCount - before));
                 const s = sensor.toLowerCase();
                 const ev = fresh.find((m) => m.toLowerCase().includes(s));
                 if (!ev) return null;
                 const shown = [...document.querySelectorAll('#events .ev-msg')].some((e) => e.textContent === ev);
                 const tile = document.querySelector(`#tiles .tile[data-sensor="${CSS.escape(sensor)}"]`);
                 if (!shown || !tile) return null;
                 const reasons = [...tile.querySelectorAll('.reasons li')].map((li) => li.textContent);
                 const state = tile.dataset.state;
                 if (state === 'ok' && !reasons.length) return null;
                 return {event: ev, tile_state: state, tile_reasons: reasons,
                         new_events: fresh.filter((m) => m.toLowerCase().includes(s))};
               }""",
            arg=[sensor, before], timeout=timeout_ms, polling=250)
    except PlaywrightTimeout:
        state = page.evaluate(
            "(s) => { const t = document.querySelector(`#tiles .tile[data-sensor=\"${CSS.escape(s)}\"]`);"
            " return t ? t.dataset.state : null; }", sensor)
        fresh = page.evaluate(
            "(b) => window.skyfuse.events().slice(0, Math.max(0, window.skyfuse.eventCount - b))", before)
        raise CheckFailed(f"after injecting {fault} into {sensor} ({result!r}): within {a.timeout:.0f} s no event "
                          f"about {sensor} with its tile off ok / with a reason; new events {fresh}, "
                          f"tile state {state}")
    out = handle.json_value()
    out.update(sensor=sensor, fault=fault, http_result=result)
    return out


if __name__ == "__main__":
    sys.exit(main())
