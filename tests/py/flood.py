#!/usr/bin/env python3
"""Flood one ROS 2 input of skyfuse with valid sensor_msgs/NavSatFix messages (rosbags
CDR) as fast as Python can put them on Zenoh, each saying "no fix" (so whatever gets
through changes no estimate). Prints JSON: how many were put, over how long.

  flood.py --connect tcp/127.0.0.1:7447 --key gps/fix --seconds 5
  flood.py ... --clock-jump -86400   # stamped on a clock a day behind, advancing with
                                     # time: a consistent series beside the real one
"""
import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import numpy as np  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402
from zenoh_peer import open_peer  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--key", required=True)
    ap.add_argument("--seconds", type=float, default=5)
    ap.add_argument("--clock-jump", type=float, default=None,
                    help="stamp each message now + this many seconds (default: one fixed stamp)")
    a = ap.parse_args()
    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    now = time.time()
    msg = t["sensor_msgs/msg/NavSatFix"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=int(now), nanosec=0), frame_id="flood"),
        status=t["sensor_msgs/msg/NavSatStatus"](status=-1, service=1),
        latitude=47.0, longitude=8.0, altitude=500.0,
        position_covariance=np.eye(3).flatten(), position_covariance_type=2)
    payload = bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/NavSatFix"))
    session = open_peer(a.connect)
    time.sleep(1.0)
    pub = session.declare_publisher(a.key)
    n, start = 0, time.time()
    while time.time() - start < a.seconds:
        if a.clock_jump is not None:
            t_msg = time.time() + a.clock_jump
            msg.header.stamp.sec = int(t_msg)
            msg.header.stamp.nanosec = int((t_msg % 1) * 1e9)
            payload = bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/NavSatFix"))
        pub.put(payload)
        n += 1
    elapsed = time.time() - start
    session.close()
    print(json.dumps({"put": n, "seconds": elapsed, "rate_hz": n / elapsed}))


if __name__ == "__main__":
    main()
