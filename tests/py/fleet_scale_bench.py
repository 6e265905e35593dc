#!/usr/bin/env python3
"""The fleet view at 100 to 1 000 vehicles through a three-router Zenoh mesh: vehicles on
two routers (A and B), `skyfuse monitor` on the third (GS, running
config/zenohd-fleet.json5, linked to both), the stand-ins from `skyfuse sim --fleet`.

    tests/py/fleet_scale_bench.py --binary ~/.cache/skyfuse-fleet-target/release/skyfuse \
        --zenohd ~/.cache/skyfuse-zenohd-release/bin/zenohd --vehicles 100 300 1000 --markdown

Per fleet size: every vehicle present once (live, none missing, none duplicated); over
--seconds with nobody looking, the monitor's CPU (share of one core, /proc) and resident
memory, the bytes into the monitor (its TCP link to router GS, the kernel's tcp_info via
`ss`), the routers' and stand-ins' CPU; then the fleet page in Debian's headless
Chromium (animation frame rate, canvas redraw time, rows in the DOM, monitor CPU while
it serves the page); then one vehicle killed (time until the monitor shows it gone);
then router A restarted (time until its vehicles are all live again, nothing else
restarted). Prints one JSON line per size, and a Markdown table with --markdown.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import urllib.request

from probe import CHROMIUM_ARGS, cpu_s, free_port, rss_mib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))



def fleet(port):
    # Without tracks: a poll must cost little, or the time-to-gone measures the poll (a
    # full view of 1 000 vehicles a minute into the run took over a second).
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/fleet?tracks=false", timeout=10) as r:
        return json.loads(r.read())


def wait_http(port, timeout=30):
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=2) as r:
                if r.status == 200:
                    return
        except Exception:
            time.sleep(0.2)
    raise RuntimeError(f"no answer on :{port}")


def tcp_bytes_received(pid, peer_port):
    """Bytes `pid` received on its connections to `peer_port` (tcp_info, `ss -ti`)."""
    out = subprocess.run(["ss", "-tinpH", "state", "established", f"( dport = :{peer_port} )"],
                         capture_output=True, text=True).stdout
    total, mine = 0, False
    for line in out.splitlines():
        if not line[:1].isspace():
            mine = f"pid={pid}," in line
            continue
        if mine:
            for w in line.split():
                if w.startswith("bytes_received:"):
                    total += int(w.split(":")[1])
    return total


class Procs:
    def __init__(self):
        self.all = []

    def start(self, args, log=None):
        p = subprocess.Popen(args, env=dict(os.environ, RUST_LOG="warn"), stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=open(log, "w") if log else subprocess.DEVNULL)
        self.all.append(p)
        return p

    def stop(self):
        for p in self.all:
            if p.poll() is None:
                p.kill()
                p.wait(10)


def router(procs, zenohd, port, *extra):
    p = procs.start([zenohd, "-l", f"tcp/127.0.0.1:{port}", "--no-multicast-scouting", *extra])
    start = time.monotonic()
    import socket
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return p
        except OSError:
            if time.monotonic() - start > 20:
                raise RuntimeError(f"zenohd not listening on {port}")
            time.sleep(0.05)


def stand_ins(procs, binary, port, n, first, pose_hz):
    return procs.start([binary, "sim", "--fleet", str(n), "--fleet-first", str(first), "--pose-hz", str(pose_hz),
                        "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}", "--no-multicast"])


def presence(f, name):
    for v in f["vehicles"]:
        if v["name"] == name:
            return v["presence"]
    return None


def one_size(args, n):
    procs = Procs()
    pa, pb, pg, http = free_port(), free_port(), free_port(), free_port()
    try:
        ra = router(procs, args.zenohd, pa)
        rb = router(procs, args.zenohd, pb)
        rg = router(procs, args.zenohd, pg, "-c", os.path.join(REPO, "config/zenohd-fleet.json5"),
                    "-e", f"tcp/127.0.0.1:{pa}", "-e", f"tcp/127.0.0.1:{pb}")
        half = n // 2
        sa = stand_ins(procs, args.binary, pa, half - 1, 0, args.pose_hz)
        lone = stand_ins(procs, args.binary, pa, 1, half - 1, args.pose_hz)
        sb = stand_ins(procs, args.binary, pb, n - half, half, args.pose_hz)
        mon = procs.start([args.binary, "monitor", "--mode", "client", "--connect", f"tcp/127.0.0.1:{pg}",
                           "--no-multicast", "--http", f"127.0.0.1:{http}"])
        wait_http(http)
        start = time.monotonic()
        while True:
            f = fleet(http)
            names = [v["name"] for v in f["vehicles"]]
            live = sum(1 for v in f["vehicles"] if v["presence"] == "live")
            if live == n:
                break
            if time.monotonic() - start > 90:
                raise RuntimeError(f"only {live} of {n} live after 90 s")
            time.sleep(0.5)
        all_present = len(names) == n and len(set(names)) == n and set(names) == {f"v{i:04d}" for i in range(n)}
        time.sleep(5)
        # Nobody looking.
        watched = {"monitor": mon, "router_a": ra, "router_b": rb, "router_gs": rg, "standins_a": sa, "standins_b": sb}
        c0 = {k: cpu_s(f"/proc/{p.pid}/stat") for k, p in watched.items()}
        b0, t0 = tcp_bytes_received(mon.pid, pg), time.monotonic()
        time.sleep(args.seconds)
        dt = time.monotonic() - t0
        ingress = (tcp_bytes_received(mon.pid, pg) - b0) / dt
        cpu = {k: 100.0 * (cpu_s(f"/proc/{p.pid}/stat") - c0[k]) / dt for k, p in watched.items()}
        rss = rss_mib(mon.pid)
        # The page.
        from playwright.sync_api import sync_playwright
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=args.chromium, args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1400, "height": 900})
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://127.0.0.1:{http}/fleet")
            page.wait_for_function(f"document.getElementById('fleet-counts').innerText.startsWith('{n} vehicles')", timeout=30000)
            time.sleep(2)
            s0 = page.evaluate("({...window.fleetStats})")
            a, tp = cpu_s(f"/proc/{mon.pid}/stat"), time.monotonic()
            fps = []
            for _ in range(int(args.seconds)):
                time.sleep(1)
                fps.append(page.evaluate("window.fleetStats.fps"))
            page_cpu = 100.0 * (cpu_s(f"/proc/{mon.pid}/stat") - a) / (time.monotonic() - tp)
            s1 = page.evaluate("({...window.fleetStats})")
            dtp = time.monotonic() - tp
            # Search and sort work at this size: 'gone' finds none yet, a name finds one.
            page.fill("#fleet-search", "v0007")
            time.sleep(0.3)
            found = page.evaluate("document.querySelectorAll('#fleet-rows tr').length")
            page.fill("#fleet-search", "")
            b.close()
        draws = s1["draws"] - s0["draws"]
        # One vehicle killed: time until the monitor shows it gone.
        lone_name = f"v{half - 1:04d}"
        t_kill = time.monotonic()
        lone.kill()
        lone.wait(10)
        while presence(fleet(http), lone_name) != "gone":
            if time.monotonic() - t_kill > 30:
                raise RuntimeError(f"{lone_name} not gone after 30 s")
            time.sleep(0.05)
        to_gone = time.monotonic() - t_kill
        # Router A restarts: its vehicles go and come back by themselves.
        a_names = [f"v{i:04d}" for i in range(half - 1)]
        ra.kill()
        ra.wait(10)
        t_restart = time.monotonic()
        while presence(fleet(http), a_names[0]) == "live":
            if time.monotonic() - t_restart > 30:
                raise RuntimeError("router A's vehicles never left")
            time.sleep(0.05)
        left_after = time.monotonic() - t_restart
        ra = router(procs, args.zenohd, pa)
        t_up = time.monotonic()
        while True:
            f = fleet(http)
            live = {v["name"] for v in f["vehicles"] if v["presence"] == "live"}
            if all(x in live for x in a_names):
                break
            if time.monotonic() - t_up > 120:
                raise RuntimeError(f"after router A's restart only {len(live)} live")
            time.sleep(0.2)
        back_after = time.monotonic() - t_up
        restarts = sum(v["restarts"] for v in f["vehicles"])
        return {
            "vehicles": n, "pose_hz": args.pose_hz, "all_present": all_present,
            "monitor_cpu_pct": round(cpu["monitor"], 1), "monitor_rss_mib": round(rss, 1),
            "monitor_ingress_kb_s": round(ingress / 1000, 1), "ingress_per_vehicle_b_s": round(ingress / n),
            "routers_cpu_pct": {k: round(v, 1) for k, v in cpu.items() if k.startswith("router")},
            "standins_cpu_pct": round(cpu["standins_a"] + cpu["standins_b"], 1),
            "page_fps_median": round(statistics.median(fps), 1), "page_fps_min": round(min(fps), 1),
            "page_draw_ms": round((s1["drawMsTotal"] - s0["drawMsTotal"]) / max(1, draws), 2),
            "page_rows_in_dom": s1["rowsRendered"], "page_clusters": s1["clusters"],
            "page_kb_s": round((s1["bytes"] - s0["bytes"]) / dtp / 1000, 1),
            "monitor_cpu_page_open_pct": round(page_cpu, 1), "search_v0007_rows": found, "page_errors": errors,
            "gone_s": round(to_gone, 2), "router_restart": {"left_s": round(left_after, 2), "all_back_s": round(back_after, 2),
                                                            "restarts_counted": restarts},
        }
    finally:
        procs.stop()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", required=True)
    ap.add_argument("--zenohd", required=True)
    ap.add_argument("--vehicles", type=int, nargs="+", default=[100, 300, 1000])
    ap.add_argument("--seconds", type=float, default=20)
    ap.add_argument("--pose-hz", type=float, default=50)
    ap.add_argument("--chromium", default=os.environ.get("SKYFUSE_CHROMIUM", "/usr/bin/chromium"))
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args()
    rows = []
    for n in args.vehicles:
        r = one_size(args, n)
        print(json.dumps(r), flush=True)
        rows.append(r)
    if args.markdown:
        print("\n| vehicles | all present | monitor CPU | monitor RSS | into monitor | per vehicle | page fps (min) | redraw | gone after | router A restart: back after |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['vehicles']} | {'yes' if r['all_present'] else 'NO'} | {r['monitor_cpu_pct']} % | {r['monitor_rss_mib']} MiB | "
                  f"{r['monitor_ingress_kb_s']} KB/s | {r['ingress_per_vehicle_b_s']} B/s | {r['page_fps_median']} ({r['page_fps_min']}) | "
                  f"{r['page_draw_ms']} ms | {r['gone_s']} s | {r['router_restart']['all_back_s']} s |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
