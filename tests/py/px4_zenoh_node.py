#!/usr/bin/env python3
"""PX4 on Zenoh, as a plain eclipse-zenoh session: a vehicle's px4_msgs the three ways
they reach Zenoh, serialised by CycloneDDS' Python binding (the serialiser PX4's zenoh
module itself uses), with PX4 1.16's field lists.

    px4_zenoh_node.py --connect tcp/127.0.0.1:7447 --style bridge|rmw_zenoh|px4_zenoh [--seconds 10]
    px4_zenoh_node.py --bag DIR [--seconds 60]

The second form writes the same flight, at once, as a ROS 2 user's `ros2 bag record`
of PX4's `/fmu/out/...` topics would hold it: a rosbag2 bag (MCAP storage) written by
rosbags, the px4_msgs types registered from the field lists below, the stamps in the
agent's clock. It prints {"start": unix time of the circle's t = 0, "counts": ...}.

- `bridge`: uXRCE-DDS through zenoh-bridge-ros2dds: keys `fmu/out/<topic>`, XCDR1, the
  stamps moved to the agent's clock (this host's Unix time), as PX4 does with
  UXRCE_DDS_SYNCT=1.
- `rmw_zenoh`: PX4 >= 1.17's zenoh module: `0/fmu/out/<topic>/px4_msgs::msg::dds_::<T>_/
  RIHS01_<hash>`, XCDR1 with its 24-byte safety margin sent behind the message, the
  33-byte attachment, PX4's boot clock. TimesyncStatus starts 3 s late, so the first
  poses have no PX4 clock to be stamped in.
- `px4_zenoh`: PX4 1.16's zenoh module on user keys `fmu/out/<topic>`: XCDR2 behind
  the header 00 01 00 00, 12 bytes of buffer after it, no attachment, PX4's boot clock.

The vehicle (NED, PX4 booted 100 s before the node started) flies a circle of 4 m
radius at 0.25 rad/s, 2 m up, heading north: SensorCombined 200 Hz, VehicleAttitude
50 Hz, SensorGps (as vehicle_gps_position) 5 Hz, VehicleAirData 20 Hz, DistanceSensor
(downward) 20 Hz, VehicleStatus (armed) 2 Hz, TimesyncStatus 1 Hz.

It subscribes to skyfuse's px4_msgs/VehicleOdometry (`fmu/in/vehicle_visual_odometry`,
and its rmw_zenoh key for that style), decodes it with CycloneDDS, applies
px4-ros2-interface-lib's checks (written here again, independently), and compares the
position with the circle at `timestamp_sample`, read in the clock the style implies.

Prints one JSON object: messages sent per topic, and `odometry` (received, passing the
checks, the failures, position RMSE, timestamp_sample's offset from the expected
clock, attachments well formed).
"""
import argparse
import hashlib
import json
import math
import struct
import time

import zenoh
from cyclonedds.idl import make_idl_struct, types as t
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

# PX4 1.16 fields (msg/ and msg/versioned/), in declaration order.
FIELDS = {
    "SensorCombined": [
        ("timestamp", "uint64"), ("gyro_rad", "float32", 3), ("gyro_integral_dt", "uint32"),
        ("accelerometer_timestamp_relative", "int32"), ("accelerometer_m_s2", "float32", 3),
        ("accelerometer_integral_dt", "uint32"), ("accelerometer_clipping", "uint8"),
        ("gyro_clipping", "uint8"), ("accel_calibration_count", "uint8"),
        ("gyro_calibration_count", "uint8")],
    "VehicleAttitude": [
        ("timestamp", "uint64"), ("timestamp_sample", "uint64"), ("q", "float32", 4),
        ("delta_q_reset", "float32", 4), ("quat_reset_counter", "uint8")],
    "SensorGps": [
        ("timestamp", "uint64"), ("timestamp_sample", "uint64"), ("device_id", "uint32"),
        ("latitude_deg", "float64"), ("longitude_deg", "float64"), ("altitude_msl_m", "float64"),
        ("altitude_ellipsoid_m", "float64"), ("s_variance_m_s", "float32"),
        ("c_variance_rad", "float32"), ("fix_type", "uint8"), ("eph", "float32"), ("epv", "float32"),
        ("hdop", "float32"), ("vdop", "float32"), ("noise_per_ms", "int32"),
        ("automatic_gain_control", "uint16"), ("jamming_state", "uint8"),
        ("jamming_indicator", "int32"), ("spoofing_state", "uint8"), ("vel_m_s", "float32"),
        ("vel_n_m_s", "float32"), ("vel_e_m_s", "float32"), ("vel_d_m_s", "float32"),
        ("cog_rad", "float32"), ("vel_ned_valid", "bool"), ("timestamp_time_relative", "int32"),
        ("time_utc_usec", "uint64"), ("satellites_used", "uint8"), ("heading", "float32"),
        ("heading_offset", "float32"), ("heading_accuracy", "float32"),
        ("rtcm_injection_rate", "float32"), ("selected_rtcm_instance", "uint8"),
        ("rtcm_crc_failed", "bool"), ("rtcm_msg_used", "uint8")],
    "VehicleAirData": [
        ("timestamp", "uint64"), ("timestamp_sample", "uint64"), ("baro_device_id", "uint32"),
        ("baro_alt_meter", "float32"), ("baro_pressure_pa", "float32"),
        ("ambient_temperature", "float32"), ("temperature_source", "uint8"), ("rho", "float32"),
        ("calibration_count", "uint8")],
    "DistanceSensor": [
        ("timestamp", "uint64"), ("device_id", "uint32"), ("min_distance", "float32"),
        ("max_distance", "float32"), ("current_distance", "float32"), ("variance", "float32"),
        ("signal_quality", "int8"), ("type", "uint8"), ("h_fov", "float32"), ("v_fov", "float32"),
        ("q", "float32", 4), ("orientation", "uint8"), ("mode", "uint8")],
    "VehicleStatus": [
        ("timestamp", "uint64"), ("armed_time", "uint64"), ("takeoff_time", "uint64"),
        ("arming_state", "uint8"), ("latest_arming_reason", "uint8"),
        ("latest_disarming_reason", "uint8"), ("nav_state_timestamp", "uint64"),
        ("nav_state_user_intention", "uint8"), ("nav_state", "uint8"),
        ("executor_in_charge", "uint8"), ("valid_nav_states_mask", "uint32"),
        ("can_set_nav_states_mask", "uint32"), ("failure_detector_status", "uint16"),
        ("hil_state", "uint8"), ("vehicle_type", "uint8"), ("failsafe", "bool"),
        ("failsafe_and_user_took_over", "bool"), ("failsafe_defer_state", "uint8"),
        ("gcs_connection_lost", "bool"), ("gcs_connection_lost_counter", "uint8"),
        ("high_latency_data_link_lost", "bool"), ("is_vtol", "bool"),
        ("is_vtol_tailsitter", "bool"), ("in_transition_mode", "bool"),
        ("in_transition_to_fw", "bool"), ("system_type", "uint8"), ("system_id", "uint8"),
        ("component_id", "uint8"), ("safety_button_available", "bool"), ("safety_off", "bool"),
        ("power_input_valid", "bool"), ("usb_connected", "bool"),
        ("open_drone_id_system_present", "bool"), ("open_drone_id_system_healthy", "bool"),
        ("parachute_system_present", "bool"), ("parachute_system_healthy", "bool"),
        ("rc_calibration_in_progress", "bool"), ("calibration_enabled", "bool"),
        ("pre_flight_checks_pass", "bool")],
    "TimesyncStatus": [
        ("timestamp", "uint64"), ("source_protocol", "uint8"), ("remote_timestamp", "uint64"),
        ("observed_offset", "int64"), ("estimated_offset", "int64"), ("round_trip_time", "uint32")],
    "VehicleOdometry": [
        ("timestamp", "uint64"), ("timestamp_sample", "uint64"), ("pose_frame", "uint8"),
        ("position", "float32", 3), ("q", "float32", 4), ("velocity_frame", "uint8"),
        ("velocity", "float32", 3), ("angular_velocity", "float32", 3),
        ("position_variance", "float32", 3), ("orientation_variance", "float32", 3),
        ("velocity_variance", "float32", 3), ("reset_counter", "uint8"), ("quality", "int8")],
}
IDL = {"bool": bool, "uint8": t.uint8, "int8": t.int8, "uint16": t.uint16, "uint32": t.uint32,
       "int32": t.int32, "uint64": t.uint64, "int64": t.int64, "float32": t.float32,
       "float64": t.float64}
TOPICS = {  # name: (topic, type, Hz)
    "imu": ("fmu/out/sensor_combined", "SensorCombined", 200.0),
    "attitude": ("fmu/out/vehicle_attitude", "VehicleAttitude", 50.0),
    "gps": ("fmu/out/vehicle_gps_position", "SensorGps", 5.0),
    "baro": ("fmu/out/vehicle_air_data", "VehicleAirData", 20.0),
    "range": ("fmu/out/distance_sensor", "DistanceSensor", 20.0),
    "status": ("fmu/out/vehicle_status", "VehicleStatus", 2.0),
    "timesync": ("fmu/out/timesync_status", "TimesyncStatus", 1.0),
}
HOME = (47.397742, 8.545594, 488.0)
RADIUS, OMEGA, HEIGHT = 4.0, 0.25, 2.0
G = 9.80665


def struct_of(name):
    fields = {}
    for f in FIELDS[name]:
        fields[f[0]] = t.array[IDL[f[1]], f[2]] if len(f) == 3 else IDL[f[1]]
    return make_idl_struct(name, f"px4_msgs::msg::dds_::{name}_", fields)


def rihs01(name):
    """rosbags' REP 2011 hash of the definition written from FIELDS."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    text = "".join(f"{f[1]}[{f[2]}] {f[0]}\n" if len(f) == 3 else f"{f[1]} {f[0]}\n" for f in FIELDS[name])
    full = f"px4_msgs/msg/{name}"
    ts.register(get_types_from_msg(text, full))
    return ts.hash_rihs01(full)


def truth(t_rel):
    """NED position, velocity, acceleration of the circle at `t_rel` s."""
    a = OMEGA * t_rel
    p = (RADIUS * math.cos(a), RADIUS * math.sin(a), -HEIGHT)
    v = (-RADIUS * OMEGA * math.sin(a), RADIUS * OMEGA * math.cos(a), 0.0)
    acc = (-RADIUS * OMEGA ** 2 * math.cos(a), -RADIUS * OMEGA ** 2 * math.sin(a), 0.0)
    return p, v, acc


def geodetic(p):
    lat = HOME[0] + math.degrees(p[0] / 6378137.0)
    lon = HOME[1] + math.degrees(p[1] / (6378137.0 * math.cos(math.radians(HOME[0]))))
    return lat, lon, HOME[2] - p[2]


def zeros(name):
    out = {}
    for f in FIELDS[name]:
        zero = False if f[1] == "bool" else (0.0 if f[1].startswith("float") else 0)
        out[f[0]] = [zero] * f[2] if len(f) == 3 else zero
    return out


def message(name, stamp_us, t_rel, px4_minus_agent_us, now_us):
    p, v, acc = truth(t_rel)
    m = zeros(name)
    m["timestamp"] = stamp_us
    if "timestamp_sample" in m:
        m["timestamp_sample"] = stamp_us
    if name == "SensorCombined":
        m["accelerometer_m_s2"] = [acc[0], acc[1], -G]
        m["gyro_integral_dt"] = m["accelerometer_integral_dt"] = 5000
    elif name == "VehicleAttitude":
        m["q"] = [1.0, 0.0, 0.0, 0.0]
    elif name == "SensorGps":
        lat, lon, alt = geodetic(p)
        m.update(latitude_deg=lat, longitude_deg=lon, altitude_msl_m=alt, fix_type=3, eph=0.5,
                 epv=0.8, hdop=0.6, vdop=0.9, vel_n_m_s=v[0], vel_e_m_s=v[1], vel_d_m_s=v[2],
                 vel_m_s=math.hypot(v[0], v[1]), vel_ned_valid=True, satellites_used=14,
                 heading=float("nan"), s_variance_m_s=0.2)
    elif name == "VehicleAirData":
        alt = HOME[2] + HEIGHT
        m.update(baro_alt_meter=alt, baro_pressure_pa=101325.0 * (1 - 2.25577e-5 * alt) ** 5.25588,
                 ambient_temperature=15.0, rho=1.17)
    elif name == "DistanceSensor":
        m.update(min_distance=0.1, max_distance=12.0, current_distance=HEIGHT, variance=0.0004,
                 signal_quality=100, q=[1.0, 0.0, 0.0, 0.0], orientation=25, mode=1)
    elif name == "VehicleStatus":
        m.update(arming_state=2, nav_state=14, vehicle_type=1, system_id=1, component_id=1)
    elif name == "TimesyncStatus":
        m.update(source_protocol=2, remote_timestamp=now_us, observed_offset=px4_minus_agent_us,
                 estimated_offset=px4_minus_agent_us, round_trip_time=900)
    return m


def check(o):
    """px4-ros2-interface-lib's LocalPositionMeasurementInterface::update checks, and
    EKF2's on the quaternion; the first failure, or None."""
    def is_set(v):
        return not any(math.isnan(x) for x in v)
    pos, vel, q = list(o.position), list(o.velocity), list(o.q)
    if not (is_set(pos) or is_set(vel) or is_set(q)):
        return "all empty"
    for s, var, what in ((pos, o.position_variance, "position"), (vel, o.velocity_variance, "velocity"),
                         (q, o.orientation_variance, "orientation")):
        if is_set(s) and any(not (x > 0) for x in var):
            return f"{what} variance {list(var)}"
    if is_set(pos) and o.pose_frame not in (1, 2):
        return f"pose_frame {o.pose_frame}"
    if is_set(vel) and o.velocity_frame not in (1, 2, 3):
        return f"velocity_frame {o.velocity_frame}"
    for v in (pos, vel, q):
        if any(math.isnan(x) for x in v) and not all(math.isnan(x) for x in v):
            return f"partly NaN {v}"
    if o.timestamp_sample == 0:
        return "timestamp_sample 0"
    if is_set(q):
        n = math.sqrt(sum(x * x for x in q))
        if abs(n - 1) > 1e-5 or any(abs(x) > 1 + 1e-5 for x in q):
            return f"q norm {n}"
    return None


def write_bag(bag, seconds):
    """The flight as a rosbag2 bag (MCAP), written by rosbags, on a simulated clock."""
    from pathlib import Path

    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = get_typestore(Stores.ROS2_JAZZY)
    for name in FIELDS:
        text = "".join(f"{f[1]}[{f[2]}] {f[0]}\n" if len(f) == 3 else f"{f[1]} {f[0]}\n"
                       for f in FIELDS[name])
        store.register(get_types_from_msg(text, f"px4_msgs/msg/{name}"))
    start = 1_790_000_000.0
    boot = start - 100.0
    events = []
    for n, (topic, name, hz) in TOPICS.items():
        k = 0
        while k / hz < seconds:
            events.append((start + k / hz, n))
            k += 1
    events.sort()
    counts = {}
    with Writer(Path(bag), version=8, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for now, n in events:
            topic, name, _ = TOPICS[n]
            now_us = int(now * 1e6)
            m = message(name, now_us, now - start, int((now - boot) * 1e6) - now_us, now_us)
            kwargs = {}
            for f in FIELDS[name]:
                v = m[f[0]]
                if len(f) == 3:
                    v = np.array(v, dtype={"float32": np.float32, "float64": np.float64,
                                           "uint8": np.uint8}[f[1]])
                kwargs[f[0]] = v
            full = f"px4_msgs/msg/{name}"
            cdr = bytes(store.serialize_cdr(store.types[full](**kwargs), full))
            if topic not in conns:
                conns[topic] = w.add_connection("/" + topic, full, typestore=store)
            w.write(conns[topic], int(now * 1e9), cdr)
            counts["/" + topic] = counts.get("/" + topic, 0) + 1
    print(json.dumps({"start": start, "counts": counts}))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect")
    ap.add_argument("--style", choices=["bridge", "rmw_zenoh", "px4_zenoh"])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--bag")
    a = ap.parse_args()
    if a.bag:
        write_bag(a.bag, a.seconds)
        return
    if not (a.connect and a.style):
        ap.error("--connect and --style (or --bag)")
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    s = zenoh.open(conf)
    structs = {name: struct_of(name) for name in FIELDS}
    hashes = {name: rihs01(name) for name in FIELDS}
    start = time.time()
    boot = start - 100.0  # PX4 booted 100 s ago

    def key(topic, name):
        if a.style == "rmw_zenoh":
            return f"0/{topic}/px4_msgs::msg::dds_::{name}_/{hashes[name]}"
        return topic

    def payload(name, m):
        obj = structs[name](**m)
        if a.style == "px4_zenoh":
            return bytes([0, 1, 0, 0]) + obj.serialize(use_version_2=True)[4:] + bytes([0xA5] * 12)
        raw = obj.serialize(use_version_2=False)
        return raw + bytes([0x5A] * 24) if a.style == "rmw_zenoh" else raw

    pubs = {n: s.declare_publisher(key(topic, name)) for n, (topic, name, _) in TOPICS.items()}
    gid = hashlib.sha256(b"px4_zenoh_node").digest()[:16]
    seq = {n: 1 for n in TOPICS}
    sent = {n: 0 for n in TOPICS}

    odo = {"received": 0, "passed": 0, "failures": [], "errors": [], "clock_err_ms": [],
           "attachment_ok": 0, "rmw_received": 0, "frames": set()}
    Odometry = structs["VehicleOdometry"]

    def on_odometry(sample, rmw=False):
        now = time.time()
        try:
            o = Odometry.deserialize(sample.payload.to_bytes())
        except Exception as e:  # noqa: BLE001 - report, do not stop
            odo["failures"].append(f"decode: {e}"[:120])
            return
        if rmw:
            odo["rmw_received"] += 1
            att = sample.attachment.to_bytes() if sample.attachment is not None else b""
            if len(att) == 33 and att[16] == 16:
                odo["attachment_ok"] += 1
            return
        odo["received"] += 1
        why = check(o)
        if why:
            odo["failures"].append(why)
            return
        odo["passed"] += 1
        odo["frames"].add((o.pose_frame, o.velocity_frame))
        # timestamp_sample in the clock the style implies: the agent's (Unix) over the
        # bridge, PX4's boot clock over its zenoh module.
        ts = o.timestamp_sample * 1e-6
        unix = ts if a.style == "bridge" else ts + boot
        odo["clock_err_ms"].append((unix - now) * 1e3)
        p, _, _ = truth(unix - start)
        # skyfuse's local origin is where its first GPS fix was, not the circle's
        # centre: errors are kept per axis and their mean (that offset) removed below.
        odo["errors"].append([float(x) - y for x, y in zip(o.position, p)])

    subs = [s.declare_subscriber("fmu/in/vehicle_visual_odometry", on_odometry)]
    if a.style == "rmw_zenoh":
        subs.append(s.declare_subscriber(
            f"0/fmu/in/vehicle_visual_odometry/px4_msgs::msg::dds_::VehicleOdometry_/{hashes['VehicleOdometry']}",
            lambda smp: on_odometry(smp, rmw=True)))
    due = {n: start for n in TOPICS}
    while time.time() - start < a.seconds:
        now = time.time()
        for n, (topic, name, hz) in TOPICS.items():
            if now < due[n]:
                continue
            due[n] += 1.0 / hz
            if n == "timesync" and a.style == "rmw_zenoh" and now - start < 3.0:
                continue
            now_us = int(now * 1e6)
            px4_us = int((now - boot) * 1e6)
            stamp = now_us if a.style == "bridge" else px4_us
            m = message(name, stamp, now - start, px4_us - now_us, now_us)
            att = None
            if a.style == "rmw_zenoh":
                # PX4's RmwAttachment: sequence, hrt time (µs), GID.
                att = struct.pack("<qq", seq[n], px4_us) + bytes([16]) + gid
                seq[n] += 1
            pubs[n].put(payload(name, m), attachment=att)
            sent[n] += 1
        time.sleep(0.001)
    time.sleep(0.3)
    for sub in subs:
        sub.undeclare()
    s.close()
    errs = sorted(odo["clock_err_ms"])
    # Over the second half: the filter has converged and its origin is set.
    tail = odo["errors"][len(odo["errors"]) // 2:]
    mean = [sum(e[i] for e in tail) / len(tail) for i in range(3)] if tail else None
    rmse = (math.sqrt(sum(sum((e[i] - mean[i]) ** 2 for i in range(3)) for e in tail) / len(tail))
            if tail else None)
    out = {
        "sent": sent,
        "hashes": hashes,
        "odometry": {
            "received": odo["received"],
            "passed": odo["passed"],
            "failures": odo["failures"][:5],
            "failed": len(odo["failures"]),
            "offset_m": mean,
            "rmse_m": rmse,
            "clock_err_ms_median": errs[len(errs) // 2] if errs else None,
            "clock_err_ms_max": max((abs(e) for e in errs), default=None),
            "frames": sorted(odo["frames"]),
            "rmw_received": odo["rmw_received"],
            "attachment_ok": odo["attachment_ok"],
        },
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
