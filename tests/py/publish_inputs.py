#!/usr/bin/env python3
"""Publish every input format skyfuse reads, made by the real producers, on Zenoh.

- ROS 2 CDR and ROS 1 bytes from `rosbags` (serialize_cdr / serialize_ros1), on the
  keys zenoh-bridge-ros2dds and zenoh-plugin-ros1 use;
- mavlink-server JSON made by ../shared/tools/mavlink_server_json.py's Codec (read
  from there, $SKYFUSE_SHARED/tools, never copied; its inputs are left out, saying so,
  when it is absent) from pymavlink messages, on mavlink/<sys>/<comp>/<MSG> plus the
  per-field keys mavlink-server also publishes;
- raw MAVLink 2 frames from pymavlink;
- skyfuse's own JSON.

Also sends malformed payloads on some keys. Two modes:
  --print-config      print the [[inputs]] TOML the service needs for these keys
  --connect EP        publish, then print JSON {input_id: {"good","bad","ignored"}}
"""
import argparse
import json
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SHARED = os.environ.get("SKYFUSE_SHARED") or os.path.join(ROOT, "..", "shared")
SHARED_CODEC = os.path.join(SHARED, "tools", "mavlink_server_json.py")
sys.path.insert(0, os.path.dirname(SHARED_CODEC))
os.environ.setdefault("MAVLINK20", "1")


def reference_codec():
    """The shared reference mavlink-server Codec, or None (and the skip said) when absent."""
    if not os.path.isfile(SHARED_CODEC):
        why = f"publish_inputs.py: mavlink-server JSON inputs left out: {SHARED_CODEC} is absent"
        print("SKIPPED " + why, file=sys.stderr)
        log = os.environ.get("SKYFUSE_SKIP_LOG")
        if log:
            with open(log, "a") as f:
                f.write(why + "\n")
        return None
    import mavlink_server_json as msj
    return msj

import numpy as np  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

ROS_TYPES = {
    "gps": ("sensor_msgs/msg/NavSatFix", "gnss"),
    "imu": ("sensor_msgs/msg/Imu", "imu"),
    "odom": ("nav_msgs/msg/Odometry", "odometry"),
    "range": ("sensor_msgs/msg/Range", "range"),
    "pose": ("geometry_msgs/msg/PoseStamped", "odometry"),
    "posecov": ("geometry_msgs/msg/PoseWithCovarianceStamped", "odometry"),
    "flow": ("skyfuse_msgs/msg/FlowTof", "flow"),
    "baro": ("sensor_msgs/msg/FluidPressure", "baro"),
}

MAV_INPUTS = {
    # input id: (message, kind)
    "mj_highres": ("HIGHRES_IMU", "imu"),
    # The same messages' abs_pressure, as a barometer.
    "mj_hrbaro": ("HIGHRES_IMU", "baro"),
    "mj_scaled": ("SCALED_IMU", "imu"),
    "mj_rawimu": ("RAW_IMU", "imu"),
    "mj_att": ("ATTITUDE", "attitude"),
    "mj_attq": ("ATTITUDE_QUATERNION", "attitude"),
    "mj_flow": ("OPTICAL_FLOW", "flow"),
    "mj_flowrad": ("OPTICAL_FLOW_RAD", "flow"),
    "mj_dist": ("DISTANCE_SENSOR", "range"),
    "mj_gps": ("GPS_RAW_INT", "gnss"),
    "mj_gpi": ("GLOBAL_POSITION_INT", "autopilot_estimate"),
    "mj_odom": ("ODOMETRY", "odometry"),
    "mj_lpn": ("LOCAL_POSITION_NED", "autopilot_estimate"),
}

GOOD = 5  # good messages per input


def typestore(store=Stores.ROS2_HUMBLE):
    ts = get_typestore(store)
    with open(os.path.join(ROOT, "msg", "FlowTof.msg")) as f:
        ts.register(get_types_from_msg(f.read(), "skyfuse_msgs/msg/FlowTof"))
    return ts


def ros_message(ts, name, i):
    """A valid message of type `name` with values depending on i."""
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=1_700_000_000 + i, nanosec=1000 * i)
    if "seq" in t["std_msgs/msg/Header"].__dataclass_fields__:  # ROS 1 header
        hdr = t["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="e2e")
    else:
        hdr = t["std_msgs/msg/Header"](stamp=stamp, frame_id="e2e")
    V3, Q = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Quaternion"]
    P, Pose = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Pose"]
    quat = Q(x=0.0, y=0.0, z=0.0, w=1.0)
    pose = Pose(position=P(x=1.0 + i, y=2.0, z=3.0), orientation=quat)
    cov36 = np.eye(6, dtype=np.float64).flatten() * 0.01
    if name == "sensor_msgs/msg/NavSatFix":
        return t[name](header=hdr, status=t["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                       latitude=47.3977 + i * 1e-6, longitude=8.5456, altitude=488.5,
                       position_covariance=np.array([1.5, 0, 0, 0, 1.5, 0, 0, 0, 4.0]),
                       position_covariance_type=2)
    if name == "sensor_msgs/msg/Imu":
        return t[name](header=hdr, orientation=quat, orientation_covariance=np.zeros(9),
                       angular_velocity=V3(x=0.01 * i, y=0.0, z=0.0), angular_velocity_covariance=np.zeros(9),
                       linear_acceleration=V3(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))
    if name == "nav_msgs/msg/Odometry":
        tw = t["geometry_msgs/msg/Twist"](linear=V3(x=0.5, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0))
        return t[name](header=hdr, child_frame_id="base",
                       pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov36),
                       twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=tw, covariance=cov36))
    if name == "sensor_msgs/msg/Range":
        return t[name](header=hdr, radiation_type=1, field_of_view=0.05, min_range=0.1, max_range=8.0,
                       range=1.0 + 0.1 * i)
    if name == "geometry_msgs/msg/PoseStamped":
        return t[name](header=hdr, pose=pose)
    if name == "geometry_msgs/msg/PoseWithCovarianceStamped":
        return t[name](header=hdr, pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov36))
    if name == "skyfuse_msgs/msg/FlowTof":
        return t[name](header=hdr, distance=1.5, strength=200, precision=3, tof_status=0,
                       flow_vel_x=0.1, flow_vel_y=-0.2, flow_quality=180, flow_status=1)
    if name == "sensor_msgs/msg/FluidPressure":
        return t[name](header=hdr, fluid_pressure=97000.0 + i, variance=4.0)
    raise ValueError(name)


def ros1_name(name):
    return name.replace("/msg/", "/")


def config():
    out = []

    def inp(id_, kind, key, fmt, rate, typ=None):
        out.append("[[inputs]]")
        out.append(f'id = "{id_}"\nkind = "{kind}"\nkey = "{key}"\nformat = "{fmt}"\nrate_hz = {rate}')
        if typ:
            out.append(f'type = "{typ}"')
        out.append("")

    for short, (name, kind) in ROS_TYPES.items():
        inp(f"r2_{short}", kind, f"e2e/{short}", "ros2", 10.0, name)
        inp(f"r1_{short}", kind, f"e2e1/{short}", "ros1", 10.0, ros1_name(name))
    if os.path.isfile(SHARED_CODEC):
        for id_, (msg, kind) in MAV_INPUTS.items():
            inp(id_, kind, f"mavlink/*/*/{msg}", "mavlink-json", 10.0)
    inp("raw_imu", "imu", "e2e_raw/out", "mavlink-raw", 10.0)
    inp("js_range", "range", "e2e/json/range", "json", 10.0)
    return "\n".join(out)


def mav_messages(mav, i):
    """One pymavlink message per MAV_INPUTS entry (values depend on i)."""
    nan = float("nan")
    q = [1.0, 0.0, 0.0, 0.0]
    return {
        "HIGHRES_IMU": mav.highres_imu_encode(1000 * i, 0.5, -0.25, -9.8125, 0.0625, -0.03125, 0.015625,
                                              0.25, 0.125, -0.5, 1013.25, 0.5, 488.5, 35.5, 0x1FFF, 0),
        "SCALED_IMU": mav.scaled_imu_encode(10 * i, 100, -50, -1000, 10, -20, 30, 0, 0, 0),
        "RAW_IMU": mav.raw_imu_encode(1000 * i, 100, -50, -1000, 10, -20, 30, 0, 0, 0),
        "ATTITUDE": mav.attitude_encode(10 * i, 0.125, -0.25, 1.5, 0.0078125, -0.015625, 0.03125),
        "ATTITUDE_QUATERNION": mav.attitude_quaternion_encode(10 * i, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        "OPTICAL_FLOW": mav.optical_flow_encode(1000 * i, 0, 0, 0, -0.125, 0.25, 200, 1.5, 0.0625, -0.0625),
        "OPTICAL_FLOW_RAD": mav.optical_flow_rad_encode(1000 * i, 0, 20000, 0.01, -0.02, 0.001, 0.002, 0.003,
                                                        25, 180, 1000, 1.25),
        "DISTANCE_SENSOR": mav.distance_sensor_encode(10 * i, 20, 1200, 150 + i, 0, 0, 25, 0),
        "GPS_RAW_INT": mav.gps_raw_int_encode(1000 * i, 3, 473977420, 85455940, 488500, 80, 120, 150, 9000,
                                              14),
        "GLOBAL_POSITION_INT": mav.global_position_int_encode(10 * i, 473977420, 85455940, 488500, 2000,
                                                              100, -50, 10, 9000),
        "ODOMETRY": mav.odometry_encode(1000 * i, 1, 8, 1.0, 2.0, -3.0, q, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0,
                                        [nan] + [0.0] * 20, [nan] + [0.0] * 20),
        "LOCAL_POSITION_NED": mav.local_position_ned_encode(10 * i, 1.0, 2.0, -3.0, 0.1, 0.2, -0.3),
    }


def publish_mavlink_json(msj, put, expected):
    """MAVLink as mavlink-server publishes it, with the reference Codec."""
    xml = msj.default_xml()
    dialect = msj.load_dialect(xml)
    codec = msj.Codec(xml, dialect)
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    for i in range(GOOD):
        for name, msg in mav_messages(mav, i + 1).items():
            msg.pack(mav)
            name_, text, fields = codec.encode(msg)
            topic = f"mavlink/1/1/{name_}"
            put("mavlink/out", text)
            put(topic, text)
            for field, ftext in codec.field_texts(fields).items():
                put(topic + "/" + field, ftext)
    for id_ in MAV_INPUTS:
        expected[id_] = {"good": GOOD, "bad": 0, "ignored": 0}
    # Malformed JSON, a required field missing, and our own VPE coming back (ignored).
    put("mavlink/1/1/HIGHRES_IMU", '{"header":{"system_id":1,')
    put("mavlink/1/1/HIGHRES_IMU", '{"header":{"system_id":1,"component_id":1,"sequence":1,"message_id":105},'
                                   '"message":{"type":"HIGHRES_IMU","time_usec":1}}')
    put("mavlink/1/1/HIGHRES_IMU", b"\xff\xfe\x00 not utf-8")
    expected["mj_highres"]["bad"] = 3
    expected["mj_hrbaro"]["bad"] = 3
    own = dialect.MAVLink(None, srcSystem=1, srcComponent=197)
    own_msg = own.attitude_encode(99999, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    own_msg.pack(own)
    put("mavlink/1/197/ATTITUDE", codec.encode(own_msg)[1])
    expected["mj_att"]["ignored"] = 1


def publish(connect):
    from pymavlink.dialects.v20 import common as dialect
    from zenoh_peer import open_peer

    msj = reference_codec()

    session = open_peer(connect)
    time.sleep(1.0)  # let the subscriptions propagate
    expected = {}

    def put(key, payload):
        session.put(key, payload)
        time.sleep(0.002)

    ts = typestore()
    ts1 = typestore(Stores.ROS1_NOETIC)
    # ROS 2 and ROS 1: GOOD valid messages each, plus malformed ones on gps and imu.
    for short, (name, _) in ROS_TYPES.items():
        md5 = ts1.generate_msgdef(name, ros_version=1)[1]
        r1_key = f"{ros1_name(name).encode().hex()}/{md5}/e2e1/{short}"
        # Since 2025 zenoh-plugin-ros1 adds a namespace chunk; send half the ROS 1
        # messages in that form.
        r1_key_ns = f"{ros1_name(name).encode().hex()}/{md5}/robot/e2e1/{short}"
        for i in range(GOOD):
            msg = ros_message(ts, name, i + 1)
            put(f"e2e/{short}", bytes(ts.serialize_cdr(msg, name)))
            msg1 = ros_message(ts1, name, i + 1)
            put(r1_key if i % 2 == 0 else r1_key_ns, bytes(ts1.serialize_ros1(msg1, name)))
        expected[f"r2_{short}"] = {"good": GOOD, "bad": 0, "ignored": 0}
        expected[f"r1_{short}"] = {"good": GOOD, "bad": 0, "ignored": 0}
    good_fix = bytes(ts.serialize_cdr(ros_message(ts, "sensor_msgs/msg/NavSatFix", 9), "sensor_msgs/msg/NavSatFix"))
    put("e2e/gps", good_fix[:40])  # truncated
    put("e2e/gps", b"\x00\x01")  # only half a header
    nan_fix = ros_message(ts, "sensor_msgs/msg/NavSatFix", 10)
    nan_fix.latitude = math.nan
    put("e2e/gps", bytes(ts.serialize_cdr(nan_fix, "sensor_msgs/msg/NavSatFix")))
    expected["r2_gps"]["bad"] = 3
    # A ROS 1 payload announced as another type on the imu topic.
    imu_md5 = ts1.generate_msgdef("sensor_msgs/msg/Imu", ros_version=1)[1]
    put(f"{'sensor_msgs/Range'.encode().hex()}/{imu_md5}/e2e1/imu", b"\x00" * 32)
    expected["r1_imu"]["bad"] = 1

    if msj is not None:
        publish_mavlink_json(msj, put, expected)
    own = dialect.MAVLink(None, srcSystem=1, srcComponent=197)

    # Raw MAVLink 2 frames: good IMU frames, a heartbeat (another kind: ignored), our
    # own component (ignored), and a frame with a broken CRC (rejected).
    raw = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    for i in range(GOOD):
        m = mav_messages(raw, i + 1)["HIGHRES_IMU"]
        put("e2e_raw/out", bytes(m.pack(raw)))
    hb = raw.heartbeat_encode(2, 3, 0, 0, 4)
    put("e2e_raw/out", bytes(hb.pack(raw)))
    own_imu = mav_messages(own, 7)["HIGHRES_IMU"]
    put("e2e_raw/out", bytes(own_imu.pack(own)))
    bad = bytearray(mav_messages(raw, 8)["HIGHRES_IMU"].pack(raw))
    bad[-1] ^= 0xFF
    put("e2e_raw/out", bytes(bad))
    expected["raw_imu"] = {"good": GOOD, "bad": 1, "ignored": 2}

    # skyfuse JSON.
    for i in range(GOOD):
        put("e2e/json/range", json.dumps({"kind": "range", "stamp_us": 1000 * (i + 1), "distance_m": 1.0 + i}))
    put("e2e/json/range", '{"kind":"range","distance_m":-3}')
    put("e2e/json/range", '{"kind":"range","distance":1}')
    expected["js_range"] = {"good": GOOD, "bad": 2, "ignored": 0}

    time.sleep(0.5)
    session.close()
    print(json.dumps(expected))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--print-config", action="store_true")
    p.add_argument("--connect")
    a = p.parse_args()
    if a.print_config:
        print(config())
    elif a.connect:
        publish(a.connect)
    else:
        p.error("--print-config or --connect EP")


if __name__ == "__main__":
    main()
