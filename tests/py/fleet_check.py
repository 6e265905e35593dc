#!/usr/bin/env python3
"""Watch the skyfuse fleet page in a real browser (Debian chromium, headless, playwright)
through the steps a test drives from outside.

    python tests/py/fleet_check.py --url http://127.0.0.1:PORT/fleet \
        --step live:drone1,drone2,drone3 --step gone:drone3 --step live:drone4 ...

Each --step waits (up to --timeout s) until the table shows every named vehicle in
that presence (`live`, `stale` or `gone`, from the row's data-presence; `live` ones
also drawn on the map, more than DRAWN_PX pixels of their colour), then prints one
JSON line describing the page (rows: name, id, presence, slot colour, estimate and VPE
cells; the map: pixels of each row's colour on the canvas; window.fleetStats; seconds
the step took) and, unless it is the last step, reads one line from stdin before the
next step: the driving test stops or starts vehicles in between.

--click NAME then clicks that vehicle's row and prints the URL of the tab it opens;
--screenshot PATH writes the page after the last step. Exits 0 when every step held, 1
with {"ok": false, "error": ...} otherwise. Needs `playwright` (tests/requirements.txt)
and /usr/bin/chromium; `playwright install` is never used.
"""
import argparse
import json
import os
import sys
import time

from probe import open_page  # noqa: E402

# Rows as the page shows them, and how many canvas pixels carry each row's colour.
PAGE_STATE = """() => {
  const rows = [...document.querySelectorAll('#fleet-rows tr')].map((tr) => {
    const sw = tr.querySelector('.swatch');
    const cells = [...tr.children].map((td) => td.innerText.trim());
    return { name: tr.dataset.name, id: tr.dataset.id, presence: tr.dataset.presence,
             colour: sw ? getComputedStyle(sw).backgroundColor : null, cells };
  });
  const c = document.getElementById('fleet-map');
  const img = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  const pixels = {};
  for (const r of rows) {
    const m = (r.colour || '').match(/\\d+/g);
    if (!m) continue;
    const [R, G, B] = m.map(Number);
    let n = 0;
    for (let i = 0; i < img.length; i += 4) {
      if (img[i + 3] > 200 && Math.abs(img[i] - R) < 12 && Math.abs(img[i + 1] - G) < 12 && Math.abs(img[i + 2] - B) < 12) n++;
    }
    pixels[r.name] = n;
  }
  return { rows, pixels, stats: window.fleetStats, counts: document.getElementById('fleet-counts').innerText,
           conn: document.getElementById('conn').dataset.state };
}"""


# Pixels of a vehicle's colour on the map that mean it is drawn (a marker is ~60).
DRAWN_PX = 12


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", required=True)
    ap.add_argument("--step", action="append", required=True, help="PRESENCE:NAME[,NAME...]")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--screenshot", default=None)
    ap.add_argument("--click", default=None, help="after the last step, click this vehicle's row and report the tab it opens")
    ap.add_argument("--chromium", default=os.environ.get("SKYFUSE_CHROMIUM", "/usr/bin/chromium"))
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    errors = []
    with sync_playwright() as p:
        browser, page = open_page(p, args.chromium, errors)
        page.goto(args.url)
        try:
            for i, step in enumerate(args.step):
                presence, names = step.split(":", 1)
                names = names.split(",")
                start = time.monotonic()
                while True:
                    st = page.evaluate(PAGE_STATE)
                    by_name = {r["name"]: r for r in st["rows"]}
                    # A live vehicle must also be drawn (a marker's worth of its colour
                    # on the map): its position comes with its once-a-second summary, a
                    # moment after its token says it is there.
                    if all(n in by_name and by_name[n]["presence"] == presence
                           and (presence != "live" or st["pixels"].get(n, 0) > DRAWN_PX) for n in names):
                        break
                    if time.monotonic() - start > args.timeout:
                        raise RuntimeError(f"step {step}: after {args.timeout} s the rows are {st['rows']}")
                    time.sleep(0.2)
                # One more frame so the map has drawn what the table shows.
                time.sleep(0.6)
                st = page.evaluate(PAGE_STATE)
                st.update(ok=True, step=step, seconds=round(time.monotonic() - start, 2), errors=errors)
                print(json.dumps(st), flush=True)
                if i + 1 < len(args.step):
                    if not sys.stdin.readline():
                        raise RuntimeError("stdin closed before the next step")
            if args.click:
                # A click on a row opens that vehicle's dashboard (a new tab).
                with page.expect_popup(timeout=10000) as popup:
                    page.click(f'#fleet-rows tr[data-name="{args.click}"]')
                tab = popup.value
                tab.wait_for_load_state()
                print(json.dumps({"ok": True, "errors": errors, "clicked": args.click, "opened": tab.url,
                                  "opened_title": tab.title()}), flush=True)
            if args.screenshot:
                page.screenshot(path=args.screenshot)
        except Exception as e:  # report, with what the page showed
            print(json.dumps({"ok": False, "error": str(e), "errors": errors}), flush=True)
            browser.close()
            return 1
        browser.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
