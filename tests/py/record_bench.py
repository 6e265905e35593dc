#!/usr/bin/env python3
"""What the flight recorder costs: `skyfuse run` fed by `skyfuse sim` (a separate
process, the demo's sensors and rates over Zenoh on loopback), measured without the
recorder, with it, and with it plus the Foxglove server; then `skyfuse replay` of the
recording. Configurations alternate over --rounds and medians are reported:

- service CPU (% of one core, the whole `skyfuse run` process) and the recorder
  thread's own CPU (`skyfuse-record`, from /proc/<pid>/task), messages logged per
  second and the thread's CPU per message;
- file size per minute (zstd chunks);
- replay of the recording: wall time, messages and samples per second.

  record_bench.py --binary ~/.cache/skyfuse-target/release/skyfuse --seconds 60 --rounds 3
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from probe import cpu_s, free_port, run_with_sim, status  # noqa: E402


def recorder_thread(pid):
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                if f.read().strip() == "skyfuse-record":
                    return f"/proc/{pid}/task/{tid}/stat"
        except OSError:
            pass
    return None


def run_once(binary, seconds, extra, workdir):
    log = open(os.path.join(workdir, "run.log"), "a")
    svc, sim, hport = run_with_sim(binary, extra, out=log)
    try:
        time.sleep(3)  # warm-up
        thread = recorder_thread(svc.pid)
        st0, t0 = status(hport), time.time()
        c0 = cpu_s(f"/proc/{svc.pid}/stat")
        r0 = cpu_s(thread) if thread else 0.0
        time.sleep(seconds)
        st1, t1 = status(hport), time.time()
        c1 = cpu_s(f"/proc/{svc.pid}/stat")
        r1 = cpu_s(thread) if thread else 0.0
        dt = t1 - t0
        rec0, rec1 = st0.get("recorder") or {}, st1.get("recorder") or {}
        msgs = (rec1.get("messages", 0) - rec0.get("messages", 0)) / dt
        row = {
            "cpu_pct": 100 * (c1 - c0) / dt,
            "recorder_thread_pct": 100 * (r1 - r0) / dt,
            "messages_per_s": msgs,
            "us_per_message": 1e6 * (r1 - r0) / max(msgs * dt, 1),
            "bytes_per_min": 60 * (rec1.get("bytes", 0) - rec0.get("bytes", 0)) / dt,
            "dropped": rec1.get("dropped", 0),
            "consumed_per_s": (st1["ingest"]["consumed"] - st0["ingest"]["consumed"]) / dt,
        }
    finally:
        sim.terminate()
        svc.terminate()
        sim.wait(10)
        svc.wait(10)
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binary", required=True)
    ap.add_argument("--seconds", type=float, default=60)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    work = tempfile.mkdtemp(prefix="skyfuse-record-bench-")
    configs = {
        "off": [],
        "record": ["--record", os.path.join(work, "rec")],
        "record+foxglove": ["--record", os.path.join(work, "rec"), "--foxglove", f"127.0.0.1:{free_port()}"],
    }
    rows = {k: [] for k in configs}
    for r in range(a.rounds):
        for name, extra in configs.items():
            row = run_once(a.binary, a.seconds, extra, work)
            rows[name].append(row)
            print(json.dumps({"round": r, "config": name, **{k: round(v, 3) for k, v in row.items()}}), flush=True)
    med = {name: {k: round(statistics.median(r[k] for r in rs), 3) for k in rs[0]} for name, rs in rows.items()}
    # Replay the largest recording.
    files = sorted((os.path.join(work, "rec", f) for f in os.listdir(os.path.join(work, "rec"))),
                   key=os.path.getsize)
    biggest = files[-1]
    times = []
    out = ""
    for _ in range(3):
        t = time.perf_counter()
        out = subprocess.run([a.binary, "replay", biggest, "--out", os.path.join(work, "replay")],
                             capture_output=True, text=True, check=True).stdout
        times.append(time.perf_counter() - t)
    samples = next(int(l.split()[1]) for l in out.splitlines() if l.startswith("replayed "))
    from mcap.reader import make_reader
    with open(biggest, "rb") as f:
        messages = make_reader(f).get_summary().statistics.message_count
    summary = {
        "seconds": a.seconds,
        "rounds": a.rounds,
        "median": med,
        "replay": {
            "file_mb": round(os.path.getsize(biggest) / 2**20, 2),
            "messages": messages,
            "wall_s": round(statistics.median(times), 3),
            "messages_per_s": round(messages / statistics.median(times)),
            "samples_per_s": round(samples / statistics.median(times)),
        },
    }
    print(json.dumps(summary, indent=1))
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
