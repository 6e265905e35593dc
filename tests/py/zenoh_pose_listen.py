#!/usr/bin/env python3
"""Subscribe with eclipse-zenoh to skyfuse's pose: the JSON on <prefix>/pose and the
ROS 2 CDR geometry_msgs/PoseStamped on data_fusion/pose_msg (decoded with rosbags, as
a ROS 2 node behind zenoh-bridge-ros2dds would see it), and the debug series
(data_fusion/<series>, PointStamped): how many of each, over how much of their own time.
Prints a JSON summary.

  zenoh_pose_listen.py --connect EP --seconds S [--prefix skyfuse/demo]
"""
import argparse
import json
import time

from rosbags.typesys import Stores, get_typestore
from zenoh_peer import open_peer


# The seed's debug series skyfuse publishes (README, "Outputs").
DEBUG_SERIES = ["compensated_OF", "OF_sum", "oriUAV_t265", "oriUAV_gps", "origin_dOF",
                "origin_dt265", "origin_dgps", "fusion_displace"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--seconds", type=float, required=True)
    ap.add_argument("--prefix", default="skyfuse/*")
    ap.add_argument("--pose-key", default="data_fusion/pose_msg")
    ap.add_argument("--debug-prefix", default="data_fusion")
    a = ap.parse_args()
    ts = get_typestore(Stores.ROS2_HUMBLE)
    s = open_peer(a.connect)
    js, cdr, health, events, errors = [], [], 0, 0, []

    def on_json(sample):
        try:
            js.append(json.loads(bytes(sample.payload.to_bytes()).decode()))
        except Exception as e:  # noqa: BLE001
            errors.append(f"json: {e}")

    def on_cdr(sample):
        try:
            m = ts.deserialize_cdr(bytes(sample.payload.to_bytes()), "geometry_msgs/msg/PoseStamped")
            cdr.append({"stamp_us": m.header.stamp.sec * 1_000_000 + m.header.stamp.nanosec // 1000,
                        "frame_id": m.header.frame_id,
                        "p": [m.pose.position.x, m.pose.position.y, m.pose.position.z],
                        "q": [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w]})
        except Exception as e:  # noqa: BLE001
            errors.append(f"cdr: {e}")

    debug = {}

    def on_debug(sample):
        key = str(sample.key_expr)
        try:
            m = ts.deserialize_cdr(bytes(sample.payload.to_bytes()), "geometry_msgs/msg/PointStamped")
            debug.setdefault(key.rsplit("/", 1)[-1], []).append(
                m.header.stamp.sec * 1_000_000 + m.header.stamp.nanosec // 1000)
        except Exception as e:  # noqa: BLE001
            errors.append(f"debug {key}: {e}")

    def on_health(_sample):
        nonlocal health
        health += 1

    subs = [s.declare_subscriber(f"{a.prefix}/pose", on_json),
            s.declare_subscriber(a.pose_key, on_cdr),
            s.declare_subscriber(f"{a.prefix}/health", on_health),
            *[s.declare_subscriber(f"{a.debug_prefix}/{name}", on_debug) for name in DEBUG_SERIES]]
    time.sleep(a.seconds)
    for x in subs:
        x.undeclare()
    s.close()
    by_time = {p["time_us"]: p for p in js}
    matched = [(c, by_time[c["stamp_us"]]) for c in cdr if c["stamp_us"] in by_time]
    max_diff = max((max(abs(c["p"][i] - j["position"][i]) for i in range(3)) for c, j in matched), default=None)
    def rate(stamps_us):
        """Messages per second of their own time (the publisher's rate, not the link's)."""
        span = (max(stamps_us) - min(stamps_us)) / 1e6 if len(stamps_us) > 1 else 0
        return (len(stamps_us) - 1) / span if span > 0 else None
    print(json.dumps({"json": len(js), "cdr": len(cdr), "health": health, "matched": len(matched),
                      "json_rate_hz": rate([p["time_us"] for p in js]),
                      "debug_rate_hz": {k: rate(v) for k, v in sorted(debug.items())},
                      "max_position_diff": max_diff, "errors": errors[:5],
                      "last_json": js[-1] if js else None, "last_cdr": cdr[-1] if cdr else None}))


if __name__ == "__main__":
    main()
