#!/usr/bin/env python3
"""Light stand-ins for many skyfuse vehicles on Zenoh, for the fleet view's tests and
benchmark: each holds the liveliness token `<ns>/skyfuse/<name>/alive` and publishes
`<ns>/skyfuse/<name>/pose` (the JSON skyfuse publishes, flying a circle of its own near
a shared GNSS origin) at --rate Hz, and `/health` (service, VPE, Zenoh, sensors) and
`/summary` (the newest pose with the health's verdict, what the fleet view reads) once a
second, as skyfuse does. (`skyfuse sim --fleet N` is the cheap stand-in for hundreds.)

    python tests/py/fleet_load.py --connect tcp/127.0.0.1:7447 --vehicles 50 --seconds 60

--bad N also puts N malformed payloads (not JSON, wrong shapes, non-finite text) on
the health, events and pose keys of an extra vehicle `bad`. Prints one JSON line at the
end: vehicles, messages and bytes published per key kind, the achieved pose rate.
"""
import argparse
import json
import math
import sys
import time

from zenoh_peer import open_peer

ORIGIN = (47.397742, 8.545594, 488.0)


def pose(t, i, rate_ok=True):
    r = 5.0 + (i % 7)
    w = 0.3 + 0.01 * (i % 5)
    cx, cy = 25.0 * (i % 10), 25.0 * (i // 10)
    x, y = cx + r * math.cos(w * t), cy + r * math.sin(w * t)
    yaw = w * t + math.pi / 2
    return {
        "time_us": int(t * 1e6), "frame": "map",
        "position": [x, y, 3.0], "orientation": [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)],
        "velocity": [-r * w * math.sin(w * t), r * w * math.cos(w * t), 0.0],
        "position_covariance": [0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.02],
        "velocity_covariance": [0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.01],
        "orientation_covariance": [0.001, 0, 0, 0, 0.001, 0, 0, 0, 0.002],
        "sources": ["gps", "imu", "t265"], "reset_counter": 0, "valid": rate_ok,
        "invalid_reason": None if rate_ok else "position uncertainty above 5 m",
        "origin": {"lat": ORIGIN[0], "lon": ORIGIN[1], "alt": ORIGIN[2]},
    }


def health(name, started_us):
    return {
        "time_us": int(time.time() * 1e6),
        "service": {"vehicle": name, "version": "load", "started_us": started_us, "dashboard": None},
        "vpe": {"endpoints": 1, "sending": True, "sent": 0, "withheld": 0, "reason": None},
        "zenoh": {"routers": 1, "peers": 0},
        "sensors": [{"id": s, "health": "ok"} for s in ("gps", "imu", "t265")],
        "estimator": {"valid": True},
    }


def summary(p, h):
    """The fleet view's once-a-second message, as skyfuse's fleet::summary_json makes it."""
    return {
        "time_us": h["time_us"], "pose": p, "service": h["service"],
        "vpe": {k: h["vpe"][k] for k in ("endpoints", "sending", "reason")},
        "zenoh": h["zenoh"], "sensors": [{"id": s["id"], "health": s["health"]} for s in h["sensors"]],
    }


BAD = [b"", b"\xff\xfe\x00garbage", b"{", b"[1, 2, 3]", b'{"position": "here"}',
       b'{"position": [NaN, 0, 0]}', b'{"service": 7}', b'{"message": 5}', b"null"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", required=True)
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--rate", type=float, default=50.0, help="pose rate per vehicle, Hz (skyfuse's default pose_rate_hz)")
    ap.add_argument("--namespace", default="load")
    ap.add_argument("--bad", type=int, default=0)
    args = ap.parse_args()

    s = open_peer(args.connect)
    names = [f"v{i:02d}" for i in range(args.vehicles)]
    prefix = {n: f"{args.namespace}/skyfuse/{n}" for n in names}
    tokens = [s.liveliness().declare_token(f"{prefix[n]}/alive") for n in names]
    pubs = {n: (s.declare_publisher(f"{prefix[n]}/pose"), s.declare_publisher(f"{prefix[n]}/health"),
                s.declare_publisher(f"{prefix[n]}/summary")) for n in names}
    started = int(time.time() * 1e6)
    sent = {"pose": [0, 0], "health": [0, 0], "summary": [0, 0], "bad": [0, 0]}
    for i in range(args.bad):
        key = f"{args.namespace}/skyfuse/bad/" + ("health", "events", "summary")[i % 3]
        payload = BAD[i % len(BAD)]
        s.put(key, payload)
        sent["bad"][0] += 1
        sent["bad"][1] += len(payload)
    t0 = time.monotonic()
    next_pose, next_health, tick = t0, t0, 1.0 / args.rate
    while (now := time.monotonic()) - t0 < args.seconds:
        if now >= next_health:
            for i, n in enumerate(names):
                h = health(n, started)
                b = json.dumps(h).encode()
                pubs[n][1].put(b)
                sent["health"][0] += 1
                sent["health"][1] += len(b)
                b = json.dumps(summary(pose(now - t0, i), h)).encode()
                pubs[n][2].put(b)
                sent["summary"][0] += 1
                sent["summary"][1] += len(b)
            next_health += 1.0
        for i, n in enumerate(names):
            b = json.dumps(pose(now - t0, i)).encode()
            pubs[n][0].put(b)
            sent["pose"][0] += 1
            sent["pose"][1] += len(b)
        next_pose += tick
        delay = next_pose - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    elapsed = time.monotonic() - t0
    for t in tokens:
        t.undeclare()
    s.close()
    print(json.dumps({
        "vehicles": args.vehicles, "seconds": round(elapsed, 2),
        "messages": {k: v[0] for k, v in sent.items()}, "bytes": {k: v[1] for k, v in sent.items()},
        "pose_rate_per_vehicle": round(sent["pose"][0] / max(1, args.vehicles) / elapsed, 1),
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
