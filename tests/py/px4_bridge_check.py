#!/usr/bin/env python3
"""px4_msgs through the real zenoh-bridge-ros2dds, both ways (issue 37).

A ROS 2 node emulated on DDS (the peers' `ros2/ros2_dds.py`, Python cyclonedds)
publishes PX4's topics as a uXRCE-DDS agent puts them on DDS: `rt/fmu/out/...` with
types `px4_msgs::msg::dds_::<T>_` (PX4 1.16 fields, XCDR1, stamps in the agent's clock),
and subscribes to `rt/fmu/in/vehicle_visual_odometry` as PX4's reader does. skyfuse,
connected to the bridge, takes every input's type from the bridge's announcement
(`type = "auto"`), fuses, and sends px4_msgs/VehicleOdometry, which comes back through
the bridge to the DDS reader. The node checks each message as px4-ros2-interface-lib
would and compares it with the circle flown.

    px4_bridge_check.py --skyfuse target/debug/skyfuse --bridge BRIDGE --peers PEERS

Prints one JSON object; exits non-zero on failure. The plain MicroXRCEAgent is not a
ROS node: the bridge routes only topics of nodes announced on `ros_discovery_info`,
which this emulated node does (so the test shows what skyfuse does with what the
bridge delivers, not whether a given agent is routed).
"""
import argparse
import json
import math
import os
import sys
import tempfile
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import px4_zenoh_node as px4  # noqa: E402
from ros2_bridge_check import (  # noqa: E402
    Fail, Procs, dds_world, free_tcp_port, http_json, log, start_bridge, wait_for)

INPUTS = [  # id, kind, topic
    ("imu", "imu", "sensor_combined"),
    ("attitude", "attitude", "vehicle_attitude"),
    ("gps", "gnss", "vehicle_gps_position"),
    ("baro", "baro", "vehicle_air_data"),
    ("range", "range", "distance_sensor"),
    ("status", "vehicle_state", "vehicle_status"),
]


def config_text():
    text = "[output]\npx4_odometry = true\npx4_clock = \"agent\"\n\n"
    for id_, kind, topic in INPUTS:
        hz = next(hz for t, _, hz in px4.TOPICS.values() if t == f"fmu/out/{topic}")
        text += (f"[[inputs]]\nid = \"{id_}\"\nkind = \"{kind}\"\nkey = \"fmu/out/{topic}\"\n"
                 f"format = \"ros2\"\ntype = \"auto\"\nrate_hz = {hz}\n\n")
    return text


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--skyfuse", required=True)
    ap.add_argument("--bridge")
    ap.add_argument("--peers", required=True)
    ap.add_argument("--seconds", type=float, default=14.0)
    a = ap.parse_args()
    a.config = os.path.join(tempfile.mkdtemp(prefix="skyfuse-px4-bridge-cfg-"), "px4.toml")
    with open(a.config, "w") as f:
        f.write(config_text())
    tmp, domain, env, bridge_bin, peers = dds_world(a, "skyfuse-px4-bridge-")
    from ros2_dds import RosNodeEmulator, ros_default_qos
    procs = Procs()
    out = {"domain_id": domain, "tmp": tmp}
    ok = False
    try:
        bport, _ = start_bridge(procs, bridge_bin, domain, env, tmp, out)
        http_port = free_tcp_port()
        sky_log = os.path.join(tmp, "skyfuse.log")
        sky = procs.start("skyfuse", [a.skyfuse, "run", "-c", a.config, "--connect", f"tcp/127.0.0.1:{bport}",
                                      "--listen", f"tcp/127.0.0.1:{free_tcp_port()}", "--no-multicast",
                                      "--http", f"127.0.0.1:{http_port}"], env, sky_log)

        def healthy():
            if sky.poll() is not None:
                raise Fail(f"skyfuse exited ({sky.returncode}):\n{open(sky_log, errors='replace').read()[-3000:]}")
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/healthz", timeout=1) as r:
                    return r.status == 200
            except Exception:  # noqa: BLE001 - not up yet
                return False
        wait_for("skyfuse /healthz", 20, healthy)

        node = RosNodeEmulator("px4_uxrce", domain_id=domain)
        structs = {name: px4.struct_of(name) for name in px4.FIELDS}
        writers = {n: node.publisher("/" + topic, structs[name], ros_default_qos(reliable=False))
                   for n, (topic, name, _) in px4.TOPICS.items()}
        reader = node.subscription("/fmu/in/vehicle_visual_odometry", structs["VehicleOdometry"])
        start = time.time()
        boot = start - 100.0
        sent = {n: 0 for n in px4.TOPICS}
        due = {n: start for n in px4.TOPICS}
        odo = {"received": 0, "passed": 0, "failures": [], "errors": []}

        def take():
            for o in reader.take(N=100):
                odo["received"] += 1
                why = px4.check(o)
                if why:
                    odo["failures"].append(why)
                    continue
                odo["passed"] += 1
                p, _, _ = px4.truth(o.timestamp_sample * 1e-6 - start)
                odo["errors"].append([float(x) - y for x, y in zip(o.position, p)])
        log(f"publishing {a.seconds} s of PX4 topics on DDS domain {domain}")
        while time.time() - start < a.seconds:
            now = time.time()
            for n, (topic, name, hz) in px4.TOPICS.items():
                if now < due[n]:
                    continue
                due[n] += 1.0 / hz
                now_us = int(now * 1e6)
                m = px4.message(name, now_us, now - start, int((now - boot) * 1e6) - now_us, now_us)
                writers[n].write(structs[name](**m))
                sent[n] += 1
            take()
            time.sleep(0.001)
        time.sleep(0.5)
        take()
        status = http_json(http_port, "/api/v1/status")
        sensors = {s["id"]: s for s in status["sensors"]}
        out["inputs"] = {i: {k: sensors[i].get(k) for k in ("accepted", "rejected", "resolved_type", "last_error")}
                         for i, _, _ in INPUTS}
        out["sent"] = sent
        out["estimator_valid"] = status["estimator"].get("valid")
        out["sources_used"] = status["estimator"].get("sources_used")
        tail = odo["errors"][len(odo["errors"]) // 2:]
        mean = [sum(e[i] for e in tail) / len(tail) for i in range(3)] if tail else None
        out["odometry"] = {
            "received": odo["received"], "passed": odo["passed"], "failures": odo["failures"][:5],
            "offset_m": mean,
            "rmse_m": (math.sqrt(sum(sum((e[i] - mean[i]) ** 2 for i in range(3)) for e in tail) / len(tail))
                       if tail else None),
        }
        for i, _, topic in INPUTS:
            s = out["inputs"][i]
            if not s["accepted"] or s["rejected"]:
                raise Fail(f"{i}: {s}")
            if s["resolved_type"] is None or not s["resolved_type"].startswith("px4_msgs/msg/"):
                raise Fail(f"{i}: type not from the bridge: {s}")
        if not out["estimator_valid"]:
            raise Fail(f"estimate not valid: {status['estimator']}")
        if odo["received"] < 50 or odo["passed"] != odo["received"]:
            raise Fail(f"VehicleOdometry back through the bridge: {out['odometry']}")
        ok = True
    finally:
        out["ok"] = ok
        procs.stop_all()
        print(json.dumps(out), flush=True)
    if not ok:
        sys.exit(1)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        print(f"FAIL: {e}", file=sys.stderr)
        sys.exit(1)
