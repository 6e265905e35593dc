#!/usr/bin/env python3
"""A ROS 2 node on rmw_zenoh, as a plain eclipse-zenoh session: what `RMW_IMPLEMENTATION=
rmw_zenoh_cpp` puts on Zenoh (ros2/rmw_zenoh docs/design.md; Jazzy 0.2.10 / Kilted 0.6.7
sources), with the messages serialised by rosbags' Kilted type store.

    rmw_zenoh_node.py --connect tcp/127.0.0.1:7447 --seconds 8 [--domain 0]

A vehicle standing still at the PX4 SITL home: sensor_msgs/Imu on /imu/data (100 Hz),
sensor_msgs/NavSatFix on /gps/fix (5 Hz), nav_msgs/Odometry on /camera/odom/sample
(30 Hz), each on `<domain>/<topic>/<pkg>::msg::dds_::<Type>_/<RIHS01 hash>` with the
33-byte attachment (sequence number from 1, source time in ns, the publisher's GID),
and the liveliness tokens of the node and its publishers. Also 5 IMU samples with no
attachment (rmw_zenoh's subscribers drop those) and 5 with a cut one.

It also subscribes, as an rmw_zenoh node would, to skyfuse's pose
(`/data_fusion/pose_msg`, geometry_msgs/PoseStamped with the Jazzy+ type hash), checks
each sample's attachment and CDR, and at the end asks the graph (`@ros2_lv/<domain>/**`,
as `ros2 topic list -t` does on rmw_zenoh) what nodes and publishers there are.

Prints one JSON object: per topic the samples sent with a good attachment, and the bad;
`skyfuse_pose` (samples, attachments well formed, sequence numbers consecutive, CDR
decoded by rosbags) and `graph` (every token's node/kind/topic/type).
"""
import argparse
import hashlib
import json
import struct
import time

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

# RIHS01 type hashes of the Jazzy/Kilted/Rolling definitions (rosidl's type description
# hash; the same in the three distributions).
HASHES = {
    "sensor_msgs/msg/Imu": "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "sensor_msgs/msg/NavSatFix": "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
}
TOPICS = {
    "imu": ("/imu/data", "sensor_msgs/msg/Imu", 100.0),
    "gps": ("/gps/fix", "sensor_msgs/msg/NavSatFix", 5.0),
    "odom": ("/camera/odom/sample", "nav_msgs/msg/Odometry", 30.0),
}
HOME = (47.397742, 8.545594, 488.0)


def dds_type(ros2):
    pkg, kind, name = ros2.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def data_key(domain, topic, ros2):
    return f"{domain}/{topic.strip('/')}/{dds_type(ros2)}/{HASHES[ros2]}"


def mangle(name):
    return name.replace("/", "%")


def token(domain, zid, nid, eid, kind, topic=None, ros2=None, qos=None):
    """rmw_zenoh's liveliness token (liveliness_utils.cpp): node `NN`, publisher `MP`."""
    parts = ["@ros2_lv", str(domain), zid, str(nid), str(eid), kind, "%", "%", "sensors"]
    if topic is not None:
        parts += [mangle(topic), dds_type(ros2), HASHES[ros2], qos]
    return "/".join(parts)


def attachment(seq, t_ns, gid):
    return struct.pack("<qq", seq, t_ns) + bytes([16]) + gid


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--domain", type=int, default=0)
    a = ap.parse_args()
    ts = get_typestore(Stores.ROS2_KILTED)
    T = ts.types
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    s = zenoh.open(conf)
    zid = str(s.zid())
    tokens = [s.liveliness().declare_token(token(a.domain, zid, 0, 0, "NN"))]
    pubs, gids, seqs = {}, {}, {}
    for i, (name, (topic, ros2, _)) in enumerate(TOPICS.items(), start=1):
        # Reliable, depth 10 (rclcpp's default profile): `::,10:,:,:,,`.
        tok = token(a.domain, zid, 0, i, "MP", topic, ros2, "::,10:,:,:,,")
        tokens.append(s.liveliness().declare_token(tok))
        # rmw_zenoh's GID: a hash of the entity's token (XXH3-128 there; any 16 bytes
        # that are the publisher's own do here).
        gids[name] = hashlib.sha256(tok.encode()).digest()[:16]
        pubs[name] = s.declare_publisher(data_key(a.domain, topic, ros2))
        seqs[name] = 1
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Quat, Vec3 = T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]

    def header(t, frame):
        return Header(stamp=Time(sec=int(t), nanosec=int((t % 1) * 1e9)), frame_id=frame)

    def make(name, t):
        if name == "imu":
            return T["sensor_msgs/msg/Imu"](
                header=header(t, "imu"), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.array([-1.0] + [0.0] * 8),
                angular_velocity=Vec3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=Vec3(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))
        if name == "gps":
            return T["sensor_msgs/msg/NavSatFix"](
                header=header(t, "gps"),
                status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                latitude=HOME[0], longitude=HOME[1], altitude=HOME[2],
                position_covariance=np.array([0.25, 0, 0, 0, 0.25, 0, 0, 0, 1.0]), position_covariance_type=2)
        P = T["geometry_msgs/msg/Point"]
        cov = np.zeros(36)
        cov[::7] = 0.0004
        return T["nav_msgs/msg/Odometry"](
            header=header(t, "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=P(x=0.0, y=0.0, z=0.0),
                                                  orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)),
                covariance=cov),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=Vec3(x=0.0, y=0.0, z=0.0),
                                                    angular=Vec3(x=0.0, y=0.0, z=0.0)),
                covariance=cov))

    out = {name: {"good": 0, "bad": 0} for name in TOPICS}
    pose = {"samples": 0, "attachment_ok": 0, "consecutive": 0, "decoded": 0, "frame_ids": []}
    last_seq = [None]
    pose_hash = "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"

    def on_pose(sample):
        pose["samples"] += 1
        att = sample.attachment.to_bytes() if sample.attachment is not None else b""
        if len(att) == 33 and att[16] == 16:
            seq, t_ns = struct.unpack("<qq", att[:16])
            if abs(t_ns - time.time_ns()) < 5e9:
                pose["attachment_ok"] += 1
            if last_seq[0] is not None and seq == last_seq[0] + 1:
                pose["consecutive"] += 1
            last_seq[0] = seq
        try:
            m = ts.deserialize_cdr(sample.payload.to_bytes(), "geometry_msgs/msg/PoseStamped")
            pose["decoded"] += 1
            if m.header.frame_id not in pose["frame_ids"]:
                pose["frame_ids"].append(m.header.frame_id)
        except Exception as e:  # noqa: BLE001 - report, do not stop
            pose.setdefault("errors", []).append(str(e)[:100])
    sub = s.declare_subscriber(
        f"{a.domain}/data_fusion/pose_msg/geometry_msgs::msg::dds_::PoseStamped_/{pose_hash}", on_pose)
    start = time.time()
    due = {name: start for name in TOPICS}
    bad_left = 10
    while time.time() - start < a.seconds:
        now = time.time()
        for name, (topic, ros2, hz) in TOPICS.items():
            if now < due[name]:
                continue
            due[name] += 1.0 / hz
            cdr = bytes(ts.serialize_cdr(make(name, now), ros2))
            if name == "imu" and bad_left > 0 and now - start > 2.0:
                # rmw_zenoh drops these: none, then a cut one.
                att = None if bad_left > 5 else attachment(seqs[name], time.time_ns(), gids[name])[:20]
                pubs[name].put(cdr, attachment=att)
                bad_left -= 1
                out[name]["bad"] += 1
                continue
            pubs[name].put(cdr, attachment=attachment(seqs[name], time.time_ns(), gids[name]))
            seqs[name] += 1
            out[name]["good"] += 1
        time.sleep(0.002)
    graph = []
    for reply in s.liveliness().get(f"@ros2_lv/{a.domain}/**", timeout=3.0):
        try:
            parts = str(reply.ok.key_expr).split("/")
        except Exception:  # noqa: BLE001 - an error reply
            continue
        if parts[2] == zid:
            continue
        entry = {"kind": parts[5], "namespace": parts[7], "node": parts[8]}
        if len(parts) >= 13:
            entry.update(topic=parts[9].replace("%", "/"), type=parts[10], hash=parts[11], qos=parts[12])
        graph.append(entry)
    sub.undeclare()
    for t in tokens:
        t.undeclare()
    s.close()
    out["skyfuse_pose"] = pose
    out["graph"] = graph
    print(json.dumps(out))


if __name__ == "__main__":
    main()
