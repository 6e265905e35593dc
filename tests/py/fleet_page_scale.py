#!/usr/bin/env python3
"""The fleet page with many vehicles, in Debian's headless Chromium (playwright): what the
list puts in the DOM, search, sort by state, map clustering, frame rate.

    python tests/py/fleet_page_scale.py --url http://127.0.0.1:PORT/fleet --vehicles 100 \
        --search v0042 --seconds 3

Waits until the page counts --vehicles vehicles, then prints one JSON line: `rows_in_dom`
(the list's <tr>s: only those in view), `scroll_rows` (names in the DOM sorted by name
and scrolled to the end: the last vehicles of the list), `search_rows` (names shown for --search),
`state_first` (the first row's name and presence sorted by state, worst first),
`clusters` (clusters on the map), `aimed_ids`, `cluster_ids` and `cluster_rows` (the
largest cluster's vehicles as last drawn, the ones a click on it picked, and the rows
listed then), `cluster_note`,
`after_clear_shown` (the list's note once the pick is cleared: empty), `fps` (median over --seconds), `errors` (page
errors and console errors). Exits 1 with {"ok": false, ...} if the page never shows the
fleet.
"""
import argparse
import json
import os
import statistics
import sys
import time

from probe import open_page

ROWS = "() => [...document.querySelectorAll('#fleet-rows tr')].map((tr) => ({name: tr.dataset.name, presence: tr.dataset.presence}))"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", required=True)
    ap.add_argument("--vehicles", type=int, required=True)
    ap.add_argument("--search", default="v0042")
    ap.add_argument("--seconds", type=float, default=3)
    ap.add_argument("--timeout", type=float, default=60)
    ap.add_argument("--chromium", default=os.environ.get("SKYFUSE_CHROMIUM", "/usr/bin/chromium"))
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    errors = []
    with sync_playwright() as p:
        browser, page = open_page(p, args.chromium, errors)
        try:
            page.goto(args.url)
            page.wait_for_function(
                f"document.getElementById('fleet-counts').innerText.startsWith('{args.vehicles} vehicles')",
                timeout=args.timeout * 1000)
            time.sleep(1.2)
            out = {"ok": True, "counts": page.inner_text("#fleet-counts")}
            out["rows_in_dom"] = len(page.evaluate(ROWS))
            out["clusters"] = page.evaluate("window.fleetStats.clusters")
            # Sorted by name and scrolled to the end: the list's last vehicles come into
            # the DOM.
            page.select_option("#fleet-sort", "name")
            time.sleep(0.2)
            page.evaluate("document.getElementById('fleet-list').scrollTop = 1e9")
            time.sleep(0.3)
            out["scroll_rows"] = [r["name"] for r in page.evaluate(ROWS)]
            page.evaluate("document.getElementById('fleet-list').scrollTop = 0")
            # A click on a cluster lists just its vehicles; the ✕ shows all again.
            hits = page.evaluate("window.fleetMap.hits()")
            big = max(hits, key=lambda x: len(x["ids"]))
            box = page.locator("#fleet-map").bounding_box()
            page.mouse.click(box["x"] + big["x"], box["y"] + big["y"])
            time.sleep(0.3)
            # What the click picked: the map redraws as the vehicles move, and the
            # cluster under the pointer may have gained or lost one since `hits`.
            out["aimed_ids"] = sorted(big["ids"])
            out["cluster_ids"] = sorted(page.evaluate("window.fleetMap.picked()") or [])
            out["cluster_rows"] = sorted(r["id"] for r in page.evaluate(
                "() => [...document.querySelectorAll('#fleet-rows tr')].map((tr) => ({id: tr.dataset.id}))"))
            out["cluster_note"] = page.inner_text("#fleet-picked")
            out["cluster_shown"] = page.inner_text("#fleet-shown")
            page.click("#fleet-picked button")
            time.sleep(0.3)
            out["after_clear_shown"] = page.inner_text("#fleet-shown")
            page.fill("#fleet-search", args.search)
            time.sleep(0.3)
            out["search_rows"] = [r["name"] for r in page.evaluate(ROWS)]
            page.fill("#fleet-search", "")
            page.select_option("#fleet-sort", "state")
            time.sleep(0.3)
            rows = page.evaluate(ROWS)
            out["state_first"] = rows[0] if rows else None
            fps = []
            for _ in range(max(1, int(args.seconds))):
                time.sleep(1)
                fps.append(page.evaluate("window.fleetStats.fps"))
            out["fps"] = statistics.median(fps)
            out["errors"] = errors
            print(json.dumps(out), flush=True)
        except Exception as e:
            print(json.dumps({"ok": False, "error": str(e), "errors": errors}), flush=True)
            browser.close()
            return 1
        browser.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
