#!/usr/bin/env python3
"""Write tests/data/ros_vectors.json: ROS messages serialised by rosbags, the reference
implementation of both ROS wire formats outside ROS itself.

For each message type skyfuse reads or writes: the field values, the ROS 2 CDR bytes
(little-endian as DDS sends them, and big-endian), the ROS 1 bytes, and the ROS 1 md5sum
and full message definition rosbags computes (genmsg's algorithm; zenoh-plugin-ros1 puts
the md5 in its keys). ROS 2 bytes come from the humble type store (the distro of the
captured bridge traffic), ROS 1 bytes from noetic (its std_msgs/Header has `seq`). One
extra vector is Jazzy's sensor_msgs/Range, which added a trailing `float32 variance`.

The Rust tests in src/codec/ros/tests.rs decode every vector exactly, encode the same
values back byte for byte, and compare RosType::ros1_md5() with the md5 here.

Usage: python tests/py/gen_ros_vectors.py   (rosbags 0.11.9, numpy)
"""
import json
import os
from importlib.metadata import version

import numpy as np
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
OUT = os.path.join(ROOT, "tests", "data", "ros_vectors.json")
FLOWTOF_MSG = os.path.join(ROOT, "msg", "FlowTof.msg")
FLOWTOF = "skyfuse_msgs/msg/FlowTof"


def store(which):
    ts = get_typestore(which)
    with open(FLOWTOF_MSG, encoding="utf-8") as f:
        ts.register(get_types_from_msg(f.read(), FLOWTOF))
    return ts


ROS2 = store(Stores.ROS2_HUMBLE)
ROS1 = store(Stores.ROS1_NOETIC)
JAZZY = store(Stores.ROS2_JAZZY)


def build(ts, typename, values, seq):
    """A rosbags message of `typename` from a plain dict (nested dicts, lists)."""
    _consts, fields = ts.fielddefs[typename]
    kwargs = {}
    for name, (kind, detail) in fields:
        if typename == "std_msgs/msg/Header" and name == "seq":
            kwargs[name] = seq
            continue
        v = values[name]
        if kind.name == "NAME":
            kwargs[name] = build(ts, detail, v, seq)
        elif kind.name == "ARRAY":
            (_sub_kind, (elem, _)), _n = detail
            dtype = {"float64": np.float64, "float32": np.float32, "uint8": np.uint8}[elem]
            kwargs[name] = np.array(v, dtype=dtype)
        else:
            kwargs[name] = v
    return ts.types[typename](**kwargs)


def f32(x):
    """Keep float32 fields exact so both sides compare equal."""
    assert float(np.float32(x)) == x, x
    return x


HEADER = {"stamp": {"sec": 1700000123, "nanosec": 456789012}}


def header(frame_id):
    return {**HEADER, "frame_id": frame_id}


def quat(x, y, z, w):
    return {"x": x, "y": y, "z": z, "w": w}


def vec(x, y, z):
    return {"x": x, "y": y, "z": z}


def diag(n, *d):
    m = [0.0] * (n * n)
    for i, v in enumerate(d):
        m[i * n + i] = v
    return m


# Distinctive values: frame ids of different lengths so CDR padding before the first
# float64 differs (0..7 bytes), no two fields alike, float32 fields exact in float32.
S = 0.5 ** 0.5
MESSAGES = [
    ("sensor_msgs/msg/NavSatFix", {
        "header": header("gps"),
        "status": {"status": 2, "service": 9},
        "latitude": 47.3977421,
        "longitude": -122.0840575,
        "altitude": 488.125,
        "position_covariance": [1.5, 0.1, 0.2, 0.1, 1.75, 0.3, 0.2, 0.3, 4.0],
        "position_covariance_type": 3,
    }),
    ("sensor_msgs/msg/Imu", {
        "header": header("imu_link"),
        "orientation": quat(0.1, -0.2, 0.3, (1 - 0.14) ** 0.5),
        "orientation_covariance": diag(3, 0.0025, 0.0026, 0.0027),
        "angular_velocity": vec(0.011, -0.022, 0.033),
        "angular_velocity_covariance": diag(3, 1e-4, 2e-4, 3e-4),
        "linear_acceleration": vec(0.125, -0.25, 9.80665),
        "linear_acceleration_covariance": diag(3, 0.01, 0.02, 0.03),
    }),
    ("sensor_msgs/msg/Range", {
        "header": header("range_down"),
        "radiation_type": 1,
        "field_of_view": f32(0.046875),
        "min_range": f32(0.0625),
        "max_range": f32(12.0),
        "range": f32(3.375),
    }),
    ("nav_msgs/msg/Odometry", {
        "header": header("camera_odom_frame"),
        "child_frame_id": "camera_pose_frame",
        "pose": {
            "pose": {"position": vec(1.25, -2.5, 0.75), "orientation": quat(0.0, 0.0, S, S)},
            "covariance": [float(i) / 100.0 for i in range(36)],
        },
        "twist": {
            "twist": {"linear": vec(0.5, -0.125, 0.0625), "angular": vec(0.01, 0.02, -0.3)},
            "covariance": diag(6, 0.02, 0.021, 0.022, 0.002, 0.0021, 0.0022),
        },
    }),
    ("geometry_msgs/msg/PoseStamped", {
        "header": header("map"),
        "pose": {"position": vec(10.5, -3.25, 1.125), "orientation": quat(0.0, 0.0, -S, S)},
    }),
    ("geometry_msgs/msg/PoseWithCovarianceStamped", {
        "header": header("odom"),
        "pose": {
            "pose": {"position": vec(-4.5, 6.75, -0.5), "orientation": quat(0.5, 0.5, 0.5, 0.5)},
            "covariance": diag(6, 0.04, 0.05, 0.06, 0.007, 0.008, 0.009),
        },
    }),
    (FLOWTOF, {
        "header": header("flow"),
        "distance": f32(1.3125),
        "strength": 201,
        "precision": 17,
        "tof_status": 1,
        "flow_vel_x": f32(-0.21875),
        "flow_vel_y": f32(0.4375),
        "flow_quality": 187,
        "flow_status": 3,
    }),
    ("sensor_msgs/msg/FluidPressure", {
        "header": header("barometer"),
        "fluid_pressure": 97123.5,
        "variance": 36.0,
    }),
    ("geometry_msgs/msg/PointStamped", {
        "header": header("base_link_fused"),
        "point": vec(0.1, -0.2, 0.3),
    }),
]

SEQ = 4242


def main():
    vectors = []
    for typename, values in MESSAGES:
        m2 = build(ROS2, typename, values, SEQ)
        m1 = build(ROS1, typename, values, SEQ)
        msgdef1, md5_1 = ROS1.generate_msgdef(typename)
        ros1_name = typename.replace("/msg/", "/")
        vectors.append({
            "type": typename,
            "ros1_type": ros1_name,
            "store": "ros2_humble",
            "values": values,
            "ros1_seq": SEQ,
            "cdr_le": bytes(ROS2.serialize_cdr(m2, typename)).hex(),
            "cdr_be": bytes(ROS2.serialize_cdr(m2, typename, little_endian=False)).hex(),
            "ros1": bytes(ROS1.serialize_ros1(m1, typename)).hex(),
            "ros1_md5": md5_1,
            "ros1_msgdef": msgdef1,
        })
    # Jazzy's Range: the same fields plus a trailing variance (CDR only).
    jazzy_range = dict(MESSAGES[2][1], variance=f32(0.015625))
    m = build(JAZZY, "sensor_msgs/msg/Range", jazzy_range, SEQ)
    vectors.append({
        "type": "sensor_msgs/msg/Range",
        "store": "ros2_jazzy",
        "values": jazzy_range,
        "cdr_le": bytes(JAZZY.serialize_cdr(m, "sensor_msgs/msg/Range")).hex(),
        "cdr_be": bytes(JAZZY.serialize_cdr(m, "sensor_msgs/msg/Range",
                                             little_endian=False)).hex(),
    })
    doc = {
        "generator": "tests/py/gen_ros_vectors.py",
        "rosbags": version("rosbags"),
        "vectors": vectors,
    }
    with open(OUT, "w", encoding="utf-8") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    print(f"wrote {len(vectors)} vectors to {OUT}")


if __name__ == "__main__":
    main()
