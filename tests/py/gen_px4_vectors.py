#!/usr/bin/env python3
"""Write tests/data/px4_vectors.json: px4_msgs messages serialised by real tooling, from
PX4's own `.msg` definitions of v1.14.0, v1.15.0 and v1.16.0.

PX4's definitions are read from a PX4-Autopilot git checkout given on the command line
(nothing of PX4 is kept in this repository: only the values chosen here and the bytes
the tools made of them):

- XCDR1, as uXRCE-DDS → zenoh-bridge-ros2dds, rmw_zenoh and PX4 ≥ 1.17's zenoh module
  put it on Zenoh: rosbags' CDR serialiser with the definitions registered
  (`get_types_from_msg`), cross-checked against CycloneDDS' Python binding.
- XCDR2 as PX4 1.16's zenoh module sends it: the body CycloneDDS serialises with
  `use_version_2=True` (PX4's module serialises with CycloneDDS' `dds_stream_write` at
  XCDR2), behind PX4's fixed header `00 01 00 00`, followed by 12 bytes standing for
  the rest of the module's buffer (`CDR_SAFETY_MARGIN`: it sends the whole buffer).
- The RIHS01 type hash rosbags computes for each definition (rmw_zenoh keys carry it).

The Rust tests (crates/skyfuse-core/src/codec/ros/px4_tests.rs) decode every vector,
compare each field, and compare the hashes with the decoder's table.

Usage: python tests/py/gen_px4_vectors.py PX4_GIT_DIR   (rosbags 0.11.9, cyclonedds 11.0.1)
"""
import json
import math
import os
import subprocess
import sys
from importlib.metadata import version as pkg_version

import numpy as np
from cyclonedds.idl import make_idl_struct, types as idl
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
OUT = os.path.join(ROOT, "tests", "data", "px4_vectors.json")

TAGS = ["v1.14.0", "v1.15.0", "v1.16.0"]
TYPES = [
    "SensorCombined",
    "VehicleAttitude",
    "VehicleAngularVelocity",
    "VehicleOdometry",
    "SensorGps",
    "VehicleAirData",
    "DistanceSensor",
    "VehicleOpticalFlow",
    "SensorOpticalFlow",
    "VehicleLandDetected",
    "VehicleStatus",
    "TimesyncStatus",
]

# A vehicle hovering 2 m over the PX4 SITL home, yawed 30° (NED/FRD as PX4 has it), at
# 120.5 s after boot. Fields not named here get a deterministic filler.
T = 120_500_000
YAW = math.radians(30.0)
Q = [math.cos(YAW / 2), 0.0, 0.0, math.sin(YAW / 2)]
MEANINGFUL = {
    "SensorCombined": {
        "timestamp": T,
        "gyro_rad": [0.01, -0.02, 0.03],
        "gyro_integral_dt": 4000,
        "accelerometer_timestamp_relative": 0,
        "accelerometer_m_s2": [0.1, -0.2, -9.81],
        "accelerometer_integral_dt": 4000,
    },
    "VehicleAttitude": {"timestamp": T, "timestamp_sample": T - 500, "q": Q},
    "VehicleAngularVelocity": {
        "timestamp": T,
        "timestamp_sample": T - 300,
        "xyz": [0.01, -0.02, 0.3],
    },
    "VehicleOdometry": {
        "timestamp": T,
        "timestamp_sample": T - 22_000,
        "pose_frame": 1,
        "position": [1.5, -2.25, -2.0],
        "q": Q,
        "velocity_frame": 1,
        "velocity": [0.5, 0.25, -0.125],
        "angular_velocity": [0.0, 0.0, 0.1],
        "position_variance": [0.01, 0.01, 0.04],
        "orientation_variance": [0.001, 0.001, 0.002],
        "velocity_variance": [0.0025, 0.0025, 0.01],
        "reset_counter": 3,
        "quality": 80,
    },
    "SensorGps": {
        "timestamp": T,
        "timestamp_sample": T - 100_000,
        "lat": 473977420,
        "lon": 85455940,
        "alt": 490000,
        "latitude_deg": 47.397742,
        "longitude_deg": 8.545594,
        "altitude_msl_m": 490.0,
        "fix_type": 3,
        "eph": 0.8,
        "epv": 1.2,
        "hdop": 0.7,
        "vdop": 1.1,
        "vel_n_m_s": 0.5,
        "vel_e_m_s": 0.25,
        "vel_d_m_s": -0.125,
        "vel_ned_valid": True,
        "satellites_used": 12,
        "heading": float("nan"),
    },
    "VehicleAirData": {
        "timestamp": T,
        "timestamp_sample": T - 1000,
        "baro_alt_meter": 490.0,
        "baro_temp_celcius": 21.5,
        "ambient_temperature": 21.5,
        "baro_pressure_pa": 95578.0,
        "rho": 1.13,
        "eas2tas": 1.02,
    },
    "DistanceSensor": {
        "timestamp": T,
        "min_distance": 0.1,
        "max_distance": 8.0,
        "current_distance": 2.05,
        "variance": 0.0004,
        "signal_quality": 90,
        "type": 0,
        "q": [1.0, 0.0, 0.0, 0.0],
        "orientation": 25,
        "mode": 1,
    },
    "VehicleOpticalFlow": {
        "timestamp": T,
        "timestamp_sample": T - 2000,
        "pixel_flow": [0.002, -0.001],
        "delta_angle": [0.0005, 0.0002, -0.0001],
        "distance_m": 2.05,
        "integration_timespan_us": 20000,
        "quality": 200,
        "max_flow_rate": 8.0,
        "min_ground_distance": 0.08,
        "max_ground_distance": 30.0,
    },
    "SensorOpticalFlow": {
        "timestamp": T,
        "timestamp_sample": T - 2000,
        "pixel_flow": [0.002, -0.001],
        "delta_angle": [0.0005, 0.0002, -0.0001],
        "delta_angle_available": True,
        "distance_m": 2.05,
        "distance_available": False,
        "integration_timespan_us": 20000,
        "quality": 200,
        "max_flow_rate": 8.0,
    },
    "VehicleLandDetected": {"timestamp": T, "landed": False, "ground_contact": False},
    "VehicleStatus": {"timestamp": T, "arming_state": 2, "nav_state": 14},
    "TimesyncStatus": {
        "timestamp": T,
        "source_protocol": 2,
        "remote_timestamp": 1_790_000_000_000_000,
        "observed_offset": -1_789_999_879_500_123,
        "estimated_offset": -1_789_999_879_500_000,
        "round_trip_time": 850,
    },
}

NP = {
    "float32": np.float32,
    "float64": np.float64,
    "uint8": np.uint8,
    "int8": np.int8,
    "uint16": np.uint16,
    "uint32": np.uint32,
    "int32": np.int32,
    "uint64": np.uint64,
    "int64": np.int64,
}
IDL = {
    "bool": bool,
    "float32": idl.float32,
    "float64": idl.float64,
    "uint8": idl.uint8,
    "int8": idl.int8,
    "uint16": idl.uint16,
    "uint32": idl.uint32,
    "int32": idl.int32,
    "uint64": idl.uint64,
    "int64": idl.int64,
}


def msg_text(px4, tag, name):
    for path in (f"msg/{name}.msg", f"msg/versioned/{name}.msg"):
        r = subprocess.run(
            ["git", "-C", px4, "show", f"{tag}:{path}"], capture_output=True, text=True
        )
        if r.returncode == 0:
            return r.stdout
    raise SystemExit(f"{name}.msg not in {tag}")


def filler(prim, i):
    """A value that fits `prim`, different for each field index."""
    if prim == "bool":
        return i % 2 == 1
    if prim.startswith("float"):
        return float(np.float32(0.125 * (i + 1)))
    if prim.startswith("int"):
        return -(i + 1)
    return i + 1


def main():
    px4 = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("PX4_GIT", "")
    if not px4 or not os.path.isdir(px4):
        raise SystemExit("usage: gen_px4_vectors.py PX4_GIT_DIR (a PX4-Autopilot clone with tags)")
    vectors = []
    for tag in TAGS:
        ts = get_typestore(Stores.ROS2_JAZZY)
        for name in TYPES:
            full = f"px4_msgs/msg/{name}"
            ts.register(get_types_from_msg(msg_text(px4, tag, name), full))
        for name in TYPES:
            full = f"px4_msgs/msg/{name}"
            _consts, fdefs = ts.fielddefs[full]
            values, kwargs, idl_fields, idl_values = {}, {}, {}, {}
            for i, (fname, (kind, detail)) in enumerate(fdefs):
                if kind.name == "BASE":
                    prim = detail[0]
                    v = MEANINGFUL[name].get(fname, filler(prim, i))
                    kwargs[fname] = v
                    values[fname] = v
                    idl_fields[fname] = IDL[prim]
                    idl_values[fname] = v
                elif kind.name == "ARRAY":
                    (_k, (prim, _)), n = detail
                    v = MEANINGFUL[name].get(fname, [filler(prim, i + j) for j in range(n)])
                    kwargs[fname] = np.array(v, dtype=NP[prim])
                    values[fname] = [float(x) if prim.startswith("float") else int(x) for x in kwargs[fname]]
                    idl_fields[fname] = idl.array[IDL[prim], n]
                    idl_values[fname] = list(v)
                else:
                    raise SystemExit(f"{full}.{fname}: unexpected field kind {kind}")
            msg = ts.types[full](**kwargs)
            xcdr1 = bytes(ts.serialize_cdr(msg, full))
            S = make_idl_struct(name, f"px4_msgs::msg::dds_::{name}_", idl_fields)
            s = S(**idl_values)
            cdds1 = s.serialize(use_version_2=False)
            if cdds1 != xcdr1:
                raise SystemExit(f"{tag} {name}: CycloneDDS XCDR1 differs from rosbags")
            body2 = s.serialize(use_version_2=True)[4:]
            px4_zenoh = bytes([0, 1, 0, 0]) + body2 + bytes([0xA5] * 12)

            def plain(v):
                if isinstance(v, float) and math.isnan(v):
                    return "NaN"
                if isinstance(v, (bool, np.bool_)):
                    return int(v)
                return v

            vectors.append(
                {
                    "type": full,
                    "version": tag.lstrip("v").rsplit(".", 1)[0],
                    "order": list(values),
                    "fields": {k: [plain(x) for x in v] if isinstance(v, list) else plain(v) for k, v in values.items()},
                    "xcdr1": xcdr1.hex(),
                    "px4_zenoh_1_16": px4_zenoh.hex() if tag == "v1.16.0" else None,
                    "rihs01": ts.hash_rihs01(full),
                }
            )
    out = {
        "generator": "tests/py/gen_px4_vectors.py",
        "tools": {"rosbags": pkg_version("rosbags"), "cyclonedds": pkg_version("cyclonedds")},
        "px4_tags": TAGS,
        "vectors": vectors,
    }
    with open(OUT, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
        f.write("\n")
    print(f"{OUT}: {len(vectors)} vectors")


if __name__ == "__main__":
    main()
