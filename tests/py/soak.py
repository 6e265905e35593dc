#!/usr/bin/env python3
"""Soak: `skyfuse demo` for a long run with many websocket clients, half of which never
read, sampled every minute: resident memory, CPU, samples consumed and dropped, late
drops, websocket drops, VPE sent, validity, and with --record the flight recorder
(files rotated every --rotate-s; afterwards every file is opened with the MCAP
project's reader and its messages counted against what the recorder logged). Writes
soak.csv and soak.svg (memory and CPU over time) to --out and prints a JSON summary;
exits non-zero when memory grows more than 5 % after warm-up, a sample is dropped, or
the recorder dropped or lost anything.

  soak.py --binary target/release/skyfuse --minutes 60 --clients 20 --record --out out/soak
"""
import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from probe import cpu_s, free_port, status  # noqa: E402
from ws_clients import connect, recv_frame, send_text  # noqa: E402


def proc(pid):
    cpu = cpu_s(f"/proc/{pid}/stat")
    with open(f"/proc/{pid}/status") as f:
        rss_kib = next(int(l.split()[1]) for l in f if l.startswith("VmRSS:"))
    return cpu, rss_kib


def reader(port, counts, i, stop):
    s = connect(port)
    s.settimeout(5.0)
    while not stop.is_set():
        try:
            op, _ = recv_frame(s)
        except (socket.timeout, EOFError, OSError):
            break
        if op == 1:
            counts[i] += 1
    s.close()


def svg(rows, path):
    """Memory (MiB) and CPU (% of a core) against minutes, two polylines."""
    w, h, pad = 720, 300, 40
    t = [r["minute"] for r in rows]
    series = [("rss_mib", "#1c7ed6", "RSS MiB"), ("cpu_pct", "#e8590c", "CPU % of a core")]
    tmax = max(t) or 1
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">',
           f'<rect width="{w}" height="{h}" fill="white"/>']
    for k, (key, color, label) in enumerate(series):
        vals = [r[key] for r in rows]
        vmax = max(vals) * 1.2 or 1
        pts = " ".join(f"{pad + (w - 2 * pad) * ti / tmax:.1f},{h - pad - (h - 2 * pad) * v / vmax:.1f}"
                       for ti, v in zip(t, vals))
        out.append(f'<polyline fill="none" stroke="{color}" stroke-width="2" points="{pts}"/>')
        out.append(f'<text x="{pad + 10 + 200 * k}" y="20" fill="{color}">{label} (max {max(vals):.1f}, axis 0–{vmax:.1f})</text>')
    out.append(f'<text x="{w // 2}" y="{h - 8}" text-anchor="middle">minutes (0–{tmax})</text>')
    out.append(f'<line x1="{pad}" y1="{h - pad}" x2="{w - pad}" y2="{h - pad}" stroke="#888"/>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binary", required=True)
    ap.add_argument("--minutes", type=float, default=60)
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--warmup", type=float, default=5, help="minutes before memory is compared")
    ap.add_argument("--every", type=float, default=60, help="seconds between samples")
    ap.add_argument("--out", required=True)
    ap.add_argument("--record", action="store_true", help="run the flight recorder too")
    ap.add_argument("--rotate-s", type=float, default=600, help="recorder file rotation, s")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    port = free_port()
    log = open(os.path.join(a.out, "skyfuse.log"), "w")
    record_dir = os.path.join(a.out, "recording")
    extra = ["--record", record_dir] if a.record else []
    env = {**os.environ, "SKYFUSE__RECORD__MAX_FILE_S": str(a.rotate_s)}
    svc = subprocess.Popen([a.binary, "demo", "--no-browser", "--no-multicast", "--http", f"127.0.0.1:{port}",
                            "--listen", f"tcp/127.0.0.1:{free_port()}", *extra], stdout=log,
                           stderr=subprocess.STDOUT, env=env)
    try:
        for _ in range(100):
            try:
                if status(port)["estimator"]["valid"]:
                    break
            except Exception:
                pass
            time.sleep(0.3)
        stop = threading.Event()
        readers = a.clients // 2
        counts = [0] * readers
        threads = [threading.Thread(target=reader, args=(port, counts, i, stop), daemon=True) for i in range(readers)]
        for th in threads:
            th.start()
        stalled = []
        for _ in range(a.clients - readers):
            s = connect(port, rcvbuf=2048)
            send_text(s, json.dumps({"type": "subscribe", "max_rate_hz": 50}))
            stalled.append(s)
        rows = []
        start = time.time()
        last_cpu, last_t = proc(svc.pid)[0], start
        while True:
            time.sleep(a.every)
            now = time.time()
            cpu, rss = proc(svc.pid)
            st = status(port)
            rows.append({
                "minute": round((now - start) / 60, 2),
                "rss_mib": round(rss / 1024, 2),
                "cpu_pct": round(100 * (cpu - last_cpu) / (now - last_t), 2),
                "consumed": st["ingest"]["consumed"],
                "queue_len": st["ingest"]["queue_len"],
                "input_dropped": sum(s["dropped"] for s in st["sensors"]),
                "late_dropped": (st["estimator"] or {}).get("late_dropped", 0),
                "ws_clients": st["websocket"]["clients"],
                "ws_dropped": st["websocket"]["dropped_total"],
                "vpe_sent": st["outputs"][0]["sent"],
                "valid": (st["estimator"] or {}).get("valid", False),
                "frames_read": sum(counts),
                "recorder_messages": (st.get("recorder") or {}).get("messages", 0),
                "recorder_dropped": (st.get("recorder") or {}).get("dropped", 0),
                "recorder_files": (st.get("recorder") or {}).get("files", 0),
                "recorder_mib": round((st.get("recorder") or {}).get("bytes", 0) / 2**20, 1),
            })
            last_cpu, last_t = cpu, now
            print(json.dumps(rows[-1]), flush=True)
            if now - start >= a.minutes * 60:
                break
        stop.set()
        for s in stalled:
            s.close()
        final = status(port)
    finally:
        svc.terminate()
        svc.wait(timeout=10)
    with open(os.path.join(a.out, "soak.csv"), "w") as f:
        keys = list(rows[0])
        f.write(",".join(keys) + "\n")
        for r in rows:
            f.write(",".join(str(r[k]) for k in keys) + "\n")
    svg(rows, os.path.join(a.out, "soak.svg"))
    warm = [r for r in rows if r["minute"] >= a.warmup] or rows
    growth = (warm[-1]["rss_mib"] - warm[0]["rss_mib"]) / warm[0]["rss_mib"]
    cpus = sorted(r["cpu_pct"] for r in warm)
    summary = {
        "minutes": rows[-1]["minute"],
        "clients": a.clients,
        "rss_after_warmup_mib": warm[0]["rss_mib"],
        "rss_end_mib": warm[-1]["rss_mib"],
        "rss_growth_pct": round(100 * growth, 2),
        "cpu_pct_median": cpus[len(cpus) // 2],
        "cpu_pct_min_max": [cpus[0], cpus[-1]],
        "input_dropped": rows[-1]["input_dropped"],
        "late_dropped": rows[-1]["late_dropped"],
        "ws_dropped": rows[-1]["ws_dropped"],
        "vpe_sent": rows[-1]["vpe_sent"],
        "valid_every_sample": all(r["valid"] for r in rows),
    }
    if a.record:
        from mcap.reader import make_reader
        files = sorted(os.listdir(record_dir))
        in_files = 0
        for name in files:
            with open(os.path.join(record_dir, name), "rb") as f:
                in_files += make_reader(f).get_summary().statistics.message_count
        logged = final["recorder"]["messages"]
        summary["recorder"] = {
            "files": len(files),
            "mib": round(sum(os.path.getsize(os.path.join(record_dir, n)) for n in files) / 2**20, 1),
            "dropped": final["recorder"]["dropped"],
            "logged_at_last_status": logged,
            "messages_in_files": in_files,
        }
    print(json.dumps(summary))
    bad = []
    if growth > 0.05:
        bad.append(f"memory grew {100 * growth:.1f} % after warm-up")
    if rows[-1]["input_dropped"] or rows[-1]["late_dropped"]:
        bad.append("samples dropped")
    if a.record:
        r = summary["recorder"]
        # Read a moment before the stop: the files hold that and what came after.
        if r["dropped"] or r["messages_in_files"] < r["logged_at_last_status"]:
            bad.append(f"recorder: {r}")
    if bad:
        sys.exit("; ".join(bad))


if __name__ == "__main__":
    main()
