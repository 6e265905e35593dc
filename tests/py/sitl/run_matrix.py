#!/usr/bin/env python3
"""Run sitl_flight.py over scenarios × links × speedups, one after another, and print a
table of the figures (and write it as summary.json in --outdir).

  run_matrix.py --skyfuse BIN [--scenarios gps_flow,no_gps,gps_loss,flow_fail]
                [--links zenoh_raw] [--speedups 1] --outdir DIR
"""
import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def fig(r, who, phase="flight", kind="raw"):
    try:
        s = r[who][phase][kind]
        return f"{s['rmse_h']:.2f}/{s['max_h']:.2f}"
    except (KeyError, TypeError):
        return "-"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--skyfuse", required=True)
    ap.add_argument("--scenarios", default="gps_flow,no_gps,gps_loss,flow_fail")
    ap.add_argument("--links", default="zenoh_raw")
    ap.add_argument("--speedups", default="1")
    ap.add_argument("--outdir", required=True)
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (each its own SITL instance)")
    ap.add_argument("extra", nargs="*", help="more sitl_flight.py arguments (after --)")
    a = ap.parse_args()
    os.makedirs(a.outdir, exist_ok=True)
    todo = [(sp, sc, link) for sp in a.speedups.split(",") for sc in a.scenarios.split(",")
            for link in a.links.split(",")]
    rows, running = [], []
    t_all = time.monotonic()

    def finish(job):
        (sp, sc, link), p, out, t0, logf = job
        code = p.wait()
        logf.close()
        wall = time.monotonic() - t0
        try:
            r = json.load(open(out))
        except (OSError, ValueError):
            r = {}
        sq = (r.get("square") or {}).get("max_truth_distance_from_corner_m")
        rows.append({"scenario": sc, "link": link, "speedup": float(sp), "exit": code,
                     "ok": r.get("ok"), "pass": r.get("pass"), "wall_s": round(wall, 1), "sim_s": r.get("sim_s"),
                     "ekf3_flight": fig(r, "ekf3_vs_truth"),
                     "skyfuse_flight": fig(r, "skyfuse_vs_truth"),
                     "square_max_m": sq, "vpe_sent": r.get("vpe_sent_by_skyfuse"),
                     "valid_frac": r.get("skyfuse_pose_valid_fraction"),
                     "cpu_s": r.get("cpu_s"), "problems": r.get("problems", [])[:3]})
        print(json.dumps(rows[-1]), flush=True)

    for i, (sp, sc, link) in enumerate(todo):
        while len(running) >= a.jobs:
            for job in list(running):
                if job[1].poll() is not None:
                    running.remove(job)
                    finish(job)
            time.sleep(0.2)
        out = os.path.join(a.outdir, f"{sc}-{link}-x{sp}.json")
        logf = open(out[:-5] + ".log", "w")
        argv = [sys.executable, os.path.join(HERE, "sitl_flight.py"), "--skyfuse", a.skyfuse,
                "--scenario", sc, "--link", link, "--speedup", sp, "--out", out]
        if a.jobs > 1:
            argv += ["--instance", str(1 + (10 * i) % 50)]
        running.append(((sp, sc, link), subprocess.Popen(argv + a.extra, stdout=logf, stderr=logf),
                        out, time.monotonic(), logf))
    for job in running:
        finish(job)
    print(f"total wall {time.monotonic() - t_all:.1f} s", flush=True)
    with open(os.path.join(a.outdir, "summary.json"), "w") as f:
        json.dump(rows, f, indent=1)
    print(f"\n{'scenario':10} {'link':9} {'x':>3} {'ok':5} {'wall':>6} {'EKF3 rmse/max':>14} "
          f"{'skyfuse':>12} {'square':>7} {'valid':>6} pass")
    for r in rows:
        print(f"{r['scenario']:10} {r['link']:9} {r['speedup']:3g} {str(r['ok']):5} {r['wall_s']:6.1f} "
              f"{r['ekf3_flight']:>14} {r['skyfuse_flight']:>12} {str(r['square_max_m']):>7} "
              f"{str(r['valid_frac']):>6} {r['pass']}")
    return 0 if all(r["pass"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
