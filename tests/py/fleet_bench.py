#!/usr/bin/env python3
"""The fleet view at scale: `skyfuse monitor` watching N light stand-in vehicles
(tests/py/fleet_load.py: each a liveliness token, its pose at 50 Hz and its health at
1 Hz, as skyfuse publishes them), and the cost of one real vehicle's outputs.

    cargo build --release
    tests/py/fleet_bench.py --binary ~/.cache/skyfuse-target/release/skyfuse \
        --vehicles 50 --seconds 30 --rounds 3

Per round: (a) the monitor's CPU (share of one core, from /proc) and resident memory
while it watches N vehicles with nobody looking, (b) the same with the fleet page open
in Debian's headless Chromium, and the page's animation frame rate, canvas draw time and
bytes received per second (window.fleetStats); medians over the rounds. Then (c) one
`skyfuse demo` in a namespace of its own, and a Zenoh subscriber counting the payload
bytes of each of its outputs (tests/py/vehicle_bandwidth.py: JSON pose, health, summary,
events; ROS 2 pose and debug series) for --seconds; --outputs-only runs only that.
Prints a JSON summary (and a Markdown table with --markdown).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time

from probe import CHROMIUM_ARGS, cpu_s, free_port, rss_mib

HERE = os.path.dirname(os.path.abspath(__file__))



def wait_http(port, path="/healthz", timeout=30):
    import urllib.request
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
                if r.status == 200:
                    return json.loads(r.read()) if path.startswith("/api") else True
        except Exception:
            time.sleep(0.2)
    raise RuntimeError(f"no answer on :{port}{path}")


def cpu_share(pid, seconds):
    a, t0 = cpu_s(f"/proc/{pid}/stat"), time.monotonic()
    time.sleep(seconds)
    return 100.0 * (cpu_s(f"/proc/{pid}/stat") - a) / (time.monotonic() - t0)


def one_round(args):
    http, zport = free_port(), free_port()
    env = dict(os.environ, RUST_LOG="warn")
    mon = subprocess.Popen([args.binary, "monitor", "--listen", f"tcp/127.0.0.1:{zport}", "--no-multicast",
                            "--http", f"127.0.0.1:{http}"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    load = None
    try:
        wait_http(http)
        load = subprocess.Popen([sys.executable, os.path.join(HERE, "fleet_load.py"), "--connect", f"tcp/127.0.0.1:{zport}",
                                 "--vehicles", str(args.vehicles), "--seconds", str(2 * args.seconds + 20)],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        start = time.monotonic()
        while True:
            f = wait_http(http, "/api/v1/fleet")
            live = sum(1 for v in f["vehicles"] if v["presence"] == "live")
            if live >= args.vehicles:
                break
            if time.monotonic() - start > 30:
                raise RuntimeError(f"only {live} of {args.vehicles} vehicles live")
            time.sleep(0.5)
        time.sleep(3)
        idle_cpu = cpu_share(mon.pid, args.seconds)
        idle_rss = rss_mib(mon.pid)
        from playwright.sync_api import sync_playwright
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=args.chromium, args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1400, "height": 900})
            page.goto(f"http://127.0.0.1:{http}/fleet")
            page.wait_for_function(f"document.querySelectorAll('#fleet-rows tr').length >= {args.vehicles}", timeout=30000)
            time.sleep(2)
            s0 = page.evaluate("({...window.fleetStats})")
            fps = []
            result = {}
            a, t0 = cpu_s(f"/proc/{mon.pid}/stat"), time.monotonic()
            for _ in range(int(args.seconds)):
                time.sleep(1)
                fps.append(page.evaluate("window.fleetStats.fps"))
            page_cpu = 100.0 * (cpu_s(f"/proc/{mon.pid}/stat") - a) / (time.monotonic() - t0)
            s1 = page.evaluate("({...window.fleetStats})")
            dt = time.monotonic() - t0
            rows = page.evaluate("document.querySelectorAll('#fleet-rows tr').length")
            b.close()
        draws = s1["draws"] - s0["draws"]
        result.update(
            idle_cpu_pct=round(idle_cpu, 2), idle_rss_mib=round(idle_rss, 1),
            page_cpu_pct=round(page_cpu, 2), rss_mib=round(rss_mib(mon.pid), 1),
            fps_median=round(statistics.median(fps), 1), fps_min=round(min(fps), 1),
            frames_per_s=round((s1["frames"] - s0["frames"]) / dt, 2),
            draw_ms_mean=round((s1["drawMsTotal"] - s0["drawMsTotal"]) / max(1, draws), 2),
            page_bytes_per_s=round((s1["bytes"] - s0["bytes"]) / dt), rows=rows,
        )
        return result
    finally:
        if load:
            load.kill()
        mon.terminate()
        mon.wait(10)


def vehicle_bandwidth(args):
    """Payload bytes per second of one demo vehicle's outputs, seen over Zenoh."""
    from vehicle_bandwidth import measure
    http, zport = free_port(), free_port()
    demo = subprocess.Popen([args.binary, "demo", "--no-browser", "--namespace", "bw", "--vehicle", "bw",
                             "--listen", f"tcp/127.0.0.1:{zport}", "--no-multicast", "--http", f"127.0.0.1:{http}"],
                            env=dict(os.environ, RUST_LOG="warn"), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_http(http)
        time.sleep(8)
        return measure(f"tcp/127.0.0.1:{zport}", args.seconds, namespace="bw", vehicle="bw")
    finally:
        demo.terminate()
        demo.wait(10)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", required=True)
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=30)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--chromium", default=os.environ.get("SKYFUSE_CHROMIUM", "/usr/bin/chromium"))
    ap.add_argument("--markdown", action="store_true")
    ap.add_argument("--outputs-only", action="store_true", help="only (c): one demo vehicle's outputs")
    args = ap.parse_args()
    if args.outputs_only:
        bw = vehicle_bandwidth(args)
        print(json.dumps({"seconds": args.seconds, "one_vehicle_outputs": bw}))
        if args.markdown:
            print("\n| key | messages/s | bytes/s | bytes a message |\n|---|---|---|---|")
            for k, v in list(bw["keys"].items()) + [(f"{g} (all)", v) for g, v in bw["groups"].items()]:
                print(f"| `{k}` | {v['msgs_per_s']} | {v['bytes_per_s']} | {v['bytes_per_msg']} |")
            print(f"| total | | **{bw['total_bytes_per_s']}** | |")
        return 0
    rounds = [one_round(args) for _ in range(args.rounds)]
    med = {k: statistics.median(r[k] for r in rounds) for k in rounds[0]}
    bw = vehicle_bandwidth(args)
    summary = {"vehicles": args.vehicles, "seconds": args.seconds, "rounds": rounds, "median": med, "one_vehicle_outputs": bw}
    print(json.dumps(summary))
    if args.markdown:
        print(f"\n| {args.vehicles} vehicles | median of {args.rounds} |\n|---|---|")
        for k, v in med.items():
            print(f"| {k} | {v} |")
        for k, v in bw["groups"].items():
            print(f"| {k} outputs | {v} |")
        print(f"| total_bytes_per_s | {bw['total_bytes_per_s']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
