#!/usr/bin/env python3
"""Receive what skyfuse sends over MAVLink with pymavlink (MAVLink 2, common dialect)
and print one JSON summary: every VISION_POSITION_ESTIMATE and ODOMETRY (arrival time,
fields), HEARTBEATs (sender and type), and any message pymavlink could not decode.

  mavlink_listen.py --port P --seconds S [--host 0.0.0.0]
"""
import argparse
import json
import math
import os
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--seconds", type=float, required=True)
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: from containers)")
    a = ap.parse_args()
    conn = mavutil.mavlink_connection(f"udpin:{a.host}:{a.port}", dialect="common")
    start = time.time()
    vpe, odo, hb, other, bad = [], [], [], {}, 0
    while time.time() - start < a.seconds:
        m = conn.recv_match(blocking=True, timeout=0.2)
        if m is None:
            continue
        t = m.get_type()
        if t == "BAD_DATA":
            bad += 1
        elif t == "VISION_POSITION_ESTIMATE":
            vpe.append({
                "rx": time.time() - start, "usec": m.usec, "x": m.x, "y": m.y, "z": m.z,
                "roll": m.roll, "pitch": m.pitch, "yaw": m.yaw,
                "covariance": list(m.covariance), "reset_counter": m.reset_counter,
                "sys": m.get_srcSystem(), "comp": m.get_srcComponent(),
                "finite": all(math.isfinite(v) for v in [m.x, m.y, m.z, m.roll, m.pitch, m.yaw, *m.covariance]),
                "mavlink2": m.get_msgbuf()[0] == 0xFD,
            })
        elif t == "ODOMETRY":
            odo.append({
                "rx": time.time() - start, "time_usec": m.time_usec, "x": m.x, "y": m.y, "z": m.z,
                "q": list(m.q), "v": [m.vx, m.vy, m.vz], "frame_id": m.frame_id,
                "child_frame_id": m.child_frame_id, "quality": m.quality,
                "reset_counter": m.reset_counter, "estimator_type": m.estimator_type,
                "pose_covariance": list(m.pose_covariance), "velocity_covariance": list(m.velocity_covariance),
                "finite": all(math.isfinite(v) for v in [m.x, m.y, m.z, *m.q, m.vx, m.vy, m.vz,
                                                         *m.pose_covariance, *m.velocity_covariance]),
            })
        elif t == "HEARTBEAT":
            hb.append({"rx": time.time() - start, "sys": m.get_srcSystem(), "comp": m.get_srcComponent(),
                       "type": m.type, "autopilot": m.autopilot, "system_status": m.system_status})
        else:
            other[t] = other.get(t, 0) + 1
    print(json.dumps({"vpe": vpe, "odometry": odo, "heartbeat": hb, "other": other, "bad_data": bad}))


if __name__ == "__main__":
    main()
