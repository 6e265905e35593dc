#!/usr/bin/env python3
"""What one skyfuse's outputs cost on the link: the payload bytes a Zenoh subscriber
receives per key for --seconds (Zenoh's framing not counted), for every key under its
output prefix (JSON pose, health, summary, events) and its ROS 2 outputs (pose_msg and
the debug series, CDR). The subscriber takes everything on the network; keys that are
not outputs (the sensors a demo's simulator publishes) are listed apart and not counted.

  vehicle_bandwidth.py --connect EP --seconds S [--namespace NS] [--vehicle demo]

Prints JSON: per output key its messages/s, bytes/s and mean bytes a message; the JSON
and ROS 2 groups; the total; and the other keys seen.
"""
import argparse
import json
import threading
import time

from zenoh_peer import open_peer

# The seed's debug series skyfuse publishes (README, "Outputs").
DEBUG_SERIES = ["compensated_OF", "OF_sum", "oriUAV_t265", "oriUAV_gps", "origin_dOF",
                "origin_dt265", "origin_dgps", "fusion_displace"]


def measure(connect, seconds, namespace="", vehicle="demo", pose_key="data_fusion/pose_msg",
            debug_prefix="data_fusion"):
    ns = f"{namespace}/" if namespace else ""
    json_prefix = f"{ns}skyfuse/{vehicle}/"
    ros2_keys = {f"{ns}{pose_key}"} | {f"{ns}{debug_prefix}/{s}" for s in DEBUG_SERIES}
    counts, lock = {}, threading.Lock()

    def on(sample):
        key = str(sample.key_expr)
        size = len(sample.payload.to_bytes())
        with lock:
            c = counts.setdefault(key, [0, 0])
            c[0] += 1
            c[1] += size

    s = open_peer(connect)
    sub = s.declare_subscriber("**", on)
    t0 = time.monotonic()
    time.sleep(seconds)
    dt = time.monotonic() - t0
    sub.undeclare()
    s.close()

    def rates(n, size):
        return {"msgs_per_s": round(n / dt, 1), "bytes_per_s": round(size / dt),
                "bytes_per_msg": round(size / n) if n else None}

    keys, groups, other = {}, {"json": [0, 0], "ros2": [0, 0]}, {}
    with lock:
        for k, (n, size) in sorted(counts.items()):
            group = "json" if k.startswith(json_prefix) else "ros2" if k in ros2_keys else None
            if group is None:
                other[k] = rates(n, size)
                continue
            keys[k] = rates(n, size)
            groups[group][0] += n
            groups[group][1] += size
    return {"seconds": round(dt, 2), "keys": keys,
            "groups": {g: rates(n, size) for g, (n, size) in groups.items()},
            "total_bytes_per_s": round(sum(size for _, size in groups.values()) / dt),
            "not_outputs": other}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", required=True)
    ap.add_argument("--seconds", type=float, required=True)
    ap.add_argument("--namespace", default="")
    ap.add_argument("--vehicle", default="demo")
    a = ap.parse_args()
    print(json.dumps(measure(a.connect, a.seconds, a.namespace, a.vehicle)))


if __name__ == "__main__":
    main()
