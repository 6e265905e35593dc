#!/usr/bin/env python3
"""PX4 1.16's own zenoh module feeding skyfuse, no bridge (issue 37).

    px4_zenoh_sitl.py --skyfuse target/debug/skyfuse [--seconds 25] [--instance 7]

PX4 v1.16.0 SITL built with its zenoh module (`px4_sitl_zenoh`; from
$SKYFUSE_PEERS/px4-zenoh, built by you: its run-sih-quad-zenoh.sh writes the module's
net.txt and pub.csv and starts the SIH quadcopter on the ground). The module, a
zenoh-pico client, connects straight to skyfuse's Zenoh listener and publishes uORB
topics as px4_msgs on `fmu/out/<topic>` (XCDR2, its buffer's tail behind each).
skyfuse reads them with `transport = "px4_zenoh"`. A Python eclipse-zenoh session on
the same listener also takes PX4's own `fmu/out/vehicle_odometry` (EKF2) and skyfuse's
pose, to compare their headings.

Prints one JSON object: per input accepted / rejected / rate / last error, the
estimate's validity and sources, skyfuse's horizontal spread while standing, and the
heading difference to EKF2's. Exit 0 when every input decoded without a rejection and
the estimate was valid; 1 otherwise; 2 when the peers are missing.
"""
import argparse
import json
import math
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
INPUTS = [  # id, kind, uORB topic, px4_msgs type, Hz
    ("imu", "imu", "sensor_combined", "SensorCombined", 250),
    ("attitude", "attitude", "vehicle_attitude", "VehicleAttitude", 250),
    ("gps", "gnss", "sensor_gps", "SensorGps", 8),
    ("baro", "baro", "vehicle_air_data", "VehicleAirData", 10),
    ("range", "range", "distance_sensor", "DistanceSensor", 50),
    ("status", "vehicle_state", "vehicle_status", "VehicleStatus", 2),
    ("land", "vehicle_state", "vehicle_land_detected", "VehicleLandDetected", 1),
]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def status(port):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/status", timeout=2) as r:
        return json.load(r)


def yaw_of_wxyz(w, x, y, z):
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--skyfuse", required=True)
    ap.add_argument("--peers", default=os.environ.get("SKYFUSE_PEERS") or os.path.join(ROOT, "..", "shared", "peers"))
    ap.add_argument("--seconds", type=float, default=25.0)
    ap.add_argument("--instance", type=int, default=7)
    a = ap.parse_args()
    px4_dir = os.path.join(a.peers, "px4-zenoh")
    run_px4 = os.path.join(px4_dir, "run-sih-quad-zenoh.sh")
    if not os.path.isfile(run_px4):
        print(f"no {run_px4} (PX4 v1.16 px4_sitl_zenoh, built by you)", file=sys.stderr)
        sys.exit(2)
    import zenoh

    tmp = tempfile.mkdtemp(prefix="skyfuse-px4-zenoh-")
    cfg = os.path.join(tmp, "px4-zenoh.toml")
    with open(cfg, "w") as f:
        for id_, kind, topic, ty, hz in INPUTS:
            f.write(f'[[inputs]]\nid = "{id_}"\nkind = "{kind}"\nkey = "fmu/out/{topic}"\nformat = "ros2"\n'
                    f'type = "px4_msgs/msg/{ty}"\ntransport = "px4_zenoh"\nrate_hz = {hz}.0\n\n')
    zport, hport = free_port(), free_port()
    procs = []
    out = {"tmp": tmp}
    ok = False
    try:
        sky = subprocess.Popen([a.skyfuse, "run", "-c", cfg, "--listen", f"tcp/127.0.0.1:{zport}", "--no-multicast",
                                "--http", f"127.0.0.1:{hport}"], stdout=open(os.path.join(tmp, "skyfuse.log"), "wb"),
                               stderr=subprocess.STDOUT)
        procs.append(sky)
        for _ in range(100):
            try:
                status(hport)
                break
            except Exception:  # noqa: BLE001 - not up yet
                time.sleep(0.1)
        # The module opens its session once, at boot: skyfuse listens first.
        topics = " ".join([t for _, _, t, _, _ in INPUTS] + ["vehicle_odometry"])
        env = dict(os.environ, ZENOH_LOCATOR=f"tcp/127.0.0.1:{zport}", ZENOH_PUB_TOPICS=topics)
        work = os.path.join(tmp, "px4")
        px4 = subprocess.Popen([run_px4, work, str(a.instance)], env=env,
                               stdout=open(os.path.join(tmp, "px4.log"), "wb"), stderr=subprocess.STDOUT,
                               start_new_session=True)
        procs.append(px4)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zport}"]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        s = zenoh.open(conf)
        ekf2, ours = [], []

        def on_ekf2(x):
            b = x.payload.to_bytes()
            # VehicleOdometry: the same layout in XCDR1 and XCDR2; q (w, x, y, z) at 32.
            if len(b) >= 4 + 48:
                ekf2.append((time.time(), struct.unpack_from("<4f", b, 4 + 32)))

        def on_pose(x):
            p = json.loads(x.payload.to_bytes())
            if p.get("valid"):
                ours.append((time.time(), p["position"], p["orientation"]))
        subs = [s.declare_subscriber("fmu/out/vehicle_odometry", on_ekf2),
                s.declare_subscriber("skyfuse/*/pose", on_pose)]
        time.sleep(a.seconds)
        st = status(hport)
        for sub in subs:
            sub.undeclare()
        s.close()
        sensors = {x["id"]: x for x in st["sensors"]}
        out["inputs"] = {i: {k: sensors[i].get(k) for k in ("accepted", "rejected", "rate_hz", "health", "last_error")}
                         for i, *_ in INPUTS}
        est = st["estimator"]
        out["estimator_valid"] = est.get("valid")
        out["sources_used"] = est.get("sources_used")
        out["ekf2_odometry"] = len(ekf2)
        out["skyfuse_poses"] = len(ours)
        tail = [p for p in ours if p[0] > ours[-1][0] - 10] if ours else []
        if tail:
            xs = [p[1][0] for p in tail]
            ys = [p[1][1] for p in tail]
            out["skyfuse_horizontal_spread_m"] = round(math.hypot(max(xs) - min(xs), max(ys) - min(ys)), 3)
        if tail and ekf2:
            # skyfuse: body FLU → ENU (x, y, z, w); EKF2: body FRD → NED (w, x, y, z).
            ox, oy, oz, ow = tail[-1][2]
            ours_enu = yaw_of_wxyz(ow, ox, oy, oz)
            ekf2_ned = yaw_of_wxyz(*ekf2[-1][1])
            diff = (math.pi / 2 - ekf2_ned) - ours_enu
            out["heading_vs_ekf2_deg"] = round(math.degrees(math.atan2(math.sin(diff), math.cos(diff))), 3)
        ok = (out["estimator_valid"] is True
              and all(v["accepted"] and not v["rejected"] for v in out["inputs"].values()))
    finally:
        subprocess.run([os.path.join(px4_dir, "bin", "px4-shutdown"), "--instance", str(a.instance)],
                       capture_output=True, timeout=15)
        for p in procs:
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        out["ok"] = ok
        print(json.dumps(out), flush=True)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
