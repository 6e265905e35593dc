#!/usr/bin/env python3
"""Where the service's CPU goes at the demo's nominal rates: `skyfuse run` fed by
`skyfuse sim` (a separate process, the demo's sensors and rates over Zenoh on loopback:
IMU 200 Hz, T265 200 Hz, flow 50 Hz, attitude 50 Hz, range 25 Hz, GPS 10 Hz), with one
dashboard client reading /ws at its default rate (the dashboard open).

    cargo build --release
    tests/py/service_cpu.py --binary ~/.cache/skyfuse-target/release/skyfuse --seconds 30 --rounds 3 [--perf]

Per round: the whole process's CPU (% of one core, /proc) and each thread group's
(tokio workers, Zenoh's threads by name, the rest); medians over the rounds. With
--perf, one more run under `perf record -e cpu-clock` (Debian's linux-perf; software
clock sampling, as this VM has no hardware counters) and the top symbols.
"""
import argparse
import base64
import collections
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from probe import cpu_s, run_with_sim, status  # noqa: E402


def threads(pid):
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                name = f.read().strip()
            out[tid] = (name, cpu_s(f"/proc/{pid}/task/{tid}/stat"))
        except OSError:
            pass
    return out


def group(name):
    # Thread names: tokio's workers, zenoh's runtimes (rx/tx/acc/net...), ours.
    name = re.sub(r"[-_ ]?\d+$", "", name)
    return name


def dashboard_client(port, stop):
    """A browser's worth of /ws: subscribe at the page's default rate and read all."""
    s = socket.create_connection(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    s.settimeout(0.5)
    while not stop.is_set():
        try:
            if not s.recv(65536):
                break
        except socket.timeout:
            pass
    s.close()


def run_once(binary, seconds, perf=None):
    svc, sim, hport = run_with_sim(binary)
    stop = threading.Event()
    try:
        client = threading.Thread(target=dashboard_client, args=(hport, stop), daemon=True)
        client.start()
        time.sleep(3)
        consumed0 = status(hport)["ingest"]["consumed"]
        p = None
        if perf:
            p = subprocess.Popen(["perf", "record", "-e", "cpu-clock", "-F", "2000", "-g", "-p", str(svc.pid),
                                  "-o", perf, "--", "sleep", str(seconds)], stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
        t0, a, th0 = time.monotonic(), cpu_s(f"/proc/{svc.pid}/stat"), threads(svc.pid)
        time.sleep(seconds)
        dt = time.monotonic() - t0
        total = 100 * (cpu_s(f"/proc/{svc.pid}/stat") - a) / dt
        th1 = threads(svc.pid)
        groups = collections.Counter()
        for tid, (name, c) in th1.items():
            groups[group(name)] += 100 * (c - th0.get(tid, (name, 0.0))[1]) / dt
        consumed = (status(hport)["ingest"]["consumed"] - consumed0) / dt
        if p:
            p.wait()
        return {"cpu_pct": round(total, 2), "samples_per_s": round(consumed),
                "threads": {k: round(v, 2) for k, v in groups.most_common()}}
    finally:
        stop.set()
        sim.terminate()
        svc.terminate()
        sim.wait(10)
        svc.wait(10)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", required=True)
    ap.add_argument("--seconds", type=float, default=30)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--perf", action="store_true")
    args = ap.parse_args()
    rounds = [run_once(args.binary, args.seconds) for _ in range(args.rounds)]
    names = sorted({k for r in rounds for k in r["threads"]})
    summary = {
        "cpu_pct_median": statistics.median(r["cpu_pct"] for r in rounds),
        "samples_per_s": statistics.median(r["samples_per_s"] for r in rounds),
        "threads_median": {n: statistics.median(r["threads"].get(n, 0.0) for r in rounds) for n in names},
        "rounds": rounds,
    }
    if args.perf:
        data = "/tmp/skyfuse-service.perf"
        run_once(args.binary, args.seconds, perf=data)
        rep = subprocess.run(["perf", "report", "-i", data, "--no-children", "--sort", "dso,symbol",
                              "--stdio", "-g", "none", "--percent-limit", "0.7"],
                             capture_output=True, text=True).stdout
        summary["perf_top"] = [l.strip() for l in rep.splitlines() if l.strip() and not l.startswith("#")][:40]
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
