#!/usr/bin/env python3
"""zenoh-bridge-ros2dds liveliness tokens, with Python eclipse-zenoh.

  ros_tokens.py list --connect EP
      print the publisher tokens alive on the network (liveliness get), as JSON
  ros_tokens.py bridge --connect EP --hold S --drop-after D
      declare tokens exactly as zenoh-bridge-ros2dds does for /gps/fix (NavSatFix),
      /camera/odom/sample (Odometry), /mavros/imu/data (Imu) and an unknown type,
      publish one rosbags-serialized CDR message on the first three, undeclare the
      gps token after D s, and exit after S s
"""
import argparse
import json
import time

from rosbags.typesys import Stores, get_typestore
from zenoh_peer import open_peer

TOPICS = [
    ("gps/fix", "sensor_msgs/msg/NavSatFix"),
    ("camera/odom/sample", "nav_msgs/msg/Odometry"),
    ("mavros/imu/data", "sensor_msgs/msg/Imu"),
    ("weird/thing", "acme_msgs/msg/Gizmo"),
]
QOS = ":1::0,10"


def token(zid, key, typ):
    return f"@/{zid}/@ros2_lv/MP/{key.replace('/', '§')}/{typ.replace('/', '§')}/{QOS}"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["list", "bridge"])
    ap.add_argument("--connect", required=True)
    ap.add_argument("--hold", type=float, default=5.0)
    ap.add_argument("--drop-after", type=float, default=3.0)
    a = ap.parse_args()
    s = open_peer(a.connect)
    time.sleep(0.5)
    if a.mode == "list":
        keys = [str(r.ok.key_expr) for r in s.liveliness().get("@/*/@ros2_lv/MP/**", timeout=2.0) if r.ok]
        print(json.dumps(sorted(keys)))
    else:
        zid = str(s.info.zid())
        toks = {k: s.liveliness().declare_token(token(zid, k, t)) for k, t in TOPICS}
        ts = get_typestore(Stores.ROS2_HUMBLE)
        T = ts.types
        hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1_700_000_000, nanosec=0), frame_id="gps")
        fix = T["sensor_msgs/msg/NavSatFix"](header=hdr, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                                            latitude=47.3977, longitude=8.5456, altitude=488.5,
                                            position_covariance=__import__("numpy").array([1.0, 0, 0, 0, 1.0, 0, 0, 0, 2.0]),
                                            position_covariance_type=2)
        V3 = T["geometry_msgs/msg/Vector3"]
        quat = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=0.5), orientation=quat)
        cov = __import__("numpy").eye(6).flatten() * 0.001
        odom = T["nav_msgs/msg/Odometry"](
            header=hdr, child_frame_id="base",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=V3(x=0.1, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0)),
                covariance=cov))
        zeros = __import__("numpy").zeros(9)
        imu = T["sensor_msgs/msg/Imu"](header=hdr, orientation=quat, orientation_covariance=zeros,
                                       angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=zeros,
                                       linear_acceleration=V3(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=zeros)
        time.sleep(0.5)  # let subscribers see the tokens before the data
        s.put("gps/fix", bytes(ts.serialize_cdr(fix, "sensor_msgs/msg/NavSatFix")))
        s.put("camera/odom/sample", bytes(ts.serialize_cdr(odom, "nav_msgs/msg/Odometry")))
        s.put("mavros/imu/data", bytes(ts.serialize_cdr(imu, "sensor_msgs/msg/Imu")))
        time.sleep(a.drop_after)
        toks.pop("gps/fix").undeclare()
        time.sleep(max(0.0, a.hold - a.drop_after))
        print(json.dumps({"zid": zid, "declared": [token(zid, k, t) for k, t in TOPICS]}))
        for t in toks.values():
            t.undeclare()
    s.close()


if __name__ == "__main__":
    main()
