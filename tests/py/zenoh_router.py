#!/usr/bin/env python3
"""A Zenoh router (eclipse-zenoh in router mode) that also publishes an IMU, for the
test of skyfuse as a client: waiting for its router at start, reconnecting after the
router restarts. Publishes sensor_msgs/Imu CDR (rosbags) on KEY at RATE Hz for SECONDS,
then closes; prints JSON {"published": n}.

  zenoh_router.py --listen tcp/127.0.0.1:P --seconds S [--key mavros/imu/data] [--rate 50]
"""
import argparse
import json
import time

import zenoh
from publish_inputs import ros_message, typestore


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--listen", required=True)
    ap.add_argument("--seconds", type=float, required=True)
    ap.add_argument("--key", default="mavros/imu/data")
    ap.add_argument("--rate", type=float, default=50.0)
    a = ap.parse_args()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([a.listen]))
    s = zenoh.open(conf)
    ts = typestore()
    pub = s.declare_publisher(a.key)
    start, n = time.time(), 0
    while time.time() - start < a.seconds:
        # Stamped now, as a bridge would: a restarted router does not restart time.
        now = time.time()
        t = ts.types
        msg = ros_message(ts, "sensor_msgs/msg/Imu", n)
        msg.header = t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=int(now), nanosec=int(now % 1 * 1e9)), frame_id="imu")
        pub.put(bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/Imu")))
        n += 1
        time.sleep(max(0.0, start + n / a.rate - time.time()))
    pub.undeclare()
    s.close()
    print(json.dumps({"published": n}))


if __name__ == "__main__":
    main()
