#!/usr/bin/env python3
"""Closed loop with PX4 SITL and its SIH quadcopter: EKF2 flies on skyfuse's pose.

    px4_flight.py --skyfuse target/debug/skyfuse [--messages vpe|odometry] [--speed 1]
                  [--instance 0] --out result.json [--keep]

PX4 (v1.16, airframe sihsim_quadx, no Gazebo) with EKF2_GPS_CTRL 0 (it never uses its
GPS) and EKF2_EV_CTRL 1 (horizontal position from vision), height from its barometer.
skyfuse takes every sensor from PX4's own MAVLink: the offboard link bridged to Zenoh by
the real mavlink-server (HIGHRES_IMU with its pressure, ATTITUDE_QUATERNION,
DISTANCE_SENSOR, GPS_RAW_INT, HEARTBEAT, EXTENDED_SYS_STATE) and sends its pose
(VISION_POSITION_ESTIMATE or ODOMETRY) straight to PX4's payload link over UDP, where
TIMESYNC runs both ways. SIH has no optical flow: skyfuse's horizontal position comes
from the GPS that EKF2 is told to ignore.

This script is the ground station on PX4's GCS link (it binds 14550): OFFBOARD with
position setpoints, arm, climb to 3 m, a 10 m square, descend, land, disarm. Truth is
SIH's HIL_STATE_QUATERNION on its display link (19410+N), stamped on arrival (v1.16.0
leaves time_usec 0). EKF2's LOCAL_POSITION_NED and skyfuse's pose (its Zenoh output)
are scored against it, the error at arming removed (the local frames' origins differ).

Peers from $SKYFUSE_PEERS (default ../shared/peers): px4/bin/px4 and px4/etc (PX4's
build), bin/mavlink-server. Exit code 0 pass, 1 flight or accuracy failure, 2 harness
error. result.json is written in every case.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

os.environ.setdefault("MAVLINK20", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
sys.path.insert(0, HERE)
import procs as procs_mod  # noqa: E402
import score  # noqa: E402

SQUARE = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0), (0.0, 0.0)]  # north, east
ALT = 3.0
LIMITS = {"rmse_h": 1.5, "corner_miss": 2.5}


class HarnessError(Exception):
    pass


def log(*a):
    print(f"[{time.strftime('%H:%M:%S')}]", *a, file=sys.stderr, flush=True)


def get_json(url, timeout=2.0):
    with urllib.request.urlopen(url, timeout=timeout) as r:
        return json.loads(r.read())


class Gcs:
    """pymavlink on PX4's GCS link; a reader thread records with host time."""

    def __init__(self, port, truth_port):
        from pymavlink import mavutil
        self.mavutil = mavutil
        self.m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255,
                                            source_component=190)
        self.truth_link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{truth_port}")
        self.t0 = time.monotonic()
        self.lock = threading.Lock()
        self.lpos, self.truth, self.statustext, self.acks = [], [], [], []
        self.armed = None
        self.nav_state = None
        self.stop = threading.Event()
        for target in (self._read, self._read_truth):
            threading.Thread(target=target, daemon=True).start()

    def now(self):
        return time.monotonic() - self.t0

    def _read(self):
        while not self.stop.is_set():
            m = self.m.recv_match(blocking=True, timeout=0.2)
            if m is None:
                continue
            t, ty = self.now(), m.get_type()
            with self.lock:
                if ty == "LOCAL_POSITION_NED":
                    self.lpos.append((t, m.x, m.y, m.z))
                elif ty == "HEARTBEAT" and m.get_srcComponent() == 1:
                    self.armed = bool(m.base_mode & 128)
                    self.nav_state = m.custom_mode
                elif ty == "STATUSTEXT":
                    self.statustext.append((round(t, 2), m.text))
                    log("PX4:", m.text)
                elif ty == "COMMAND_ACK":
                    self.acks.append((round(t, 2), m.command, m.result))

    def _read_truth(self):
        while not self.stop.is_set():
            m = self.truth_link.recv_match(type="HIL_STATE_QUATERNION", blocking=True, timeout=0.2)
            if m is not None:
                with self.lock:
                    self.truth.append((self.now(), m.lat / 1e7, m.lon / 1e7, m.alt / 1e3))

    def command(self, cmd, *params):
        p = list(params) + [0] * (7 - len(params))
        self.m.mav.command_long_send(1, 1, cmd, 0, *p)

    def setpoint(self, n, e, d):
        # Position only (type_mask: ignore velocity, acceleration, yaw rate).
        self.m.mav.set_position_target_local_ned_send(
            0, 1, 1, self.mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0b0000_1011_1111_1000,
            n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)

    def position(self):
        with self.lock:
            return self.lpos[-1][1:] if self.lpos else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--skyfuse", required=True)
    ap.add_argument("--messages", choices=("vpe", "odometry"), default="vpe")
    ap.add_argument("--speed", type=float, default=1.0, help="PX4_SIM_SPEED_FACTOR")
    ap.add_argument("--instance", type=int, default=0)
    ap.add_argument("--config", default=None, help="skyfuse config (default tests/data/sitl/skyfuse-px4.toml)")
    ap.add_argument("--imu-hz", type=int, default=200, help="HIGHRES_IMU rate asked of PX4")
    ap.add_argument("--out", required=True)
    ap.add_argument("--keep", action="store_true")
    a = ap.parse_args()
    result = {"messages": a.messages, "speed": a.speed, "pass": False, "fails": []}
    work = tempfile.mkdtemp(prefix="px4-sih-")
    result["workdir"] = work
    procs = procs_mod.Procs(work)
    gcs = None
    code = 2
    try:
        peers = os.environ.get("SKYFUSE_PEERS", os.path.join(ROOT, "..", "shared", "peers"))
        px4 = os.path.join(peers, "px4", "bin", "px4")
        etc = os.path.join(peers, "px4", "etc")
        msrv = os.path.join(peers, "bin", "mavlink-server")
        for f in (px4, etc, msrv, a.skyfuse):
            if not os.path.exists(f):
                raise HarnessError(f"missing: {f}")
        n = a.instance
        zport, hport, wport = procs_mod.free_port(), procs_mod.free_port(), procs_mod.free_port()
        offboard_us = 14540 + n  # PX4 sends its offboard link here (it listens on 14580+n)
        payload_px4 = 14280 + n
        gcs_us, truth_us = 14550, 19410 + n

        # PX4 first: its clock starts at boot; EKF2 without GPS, horizontal position from
        # vision, height from the barometer, vision's own covariance.
        env = dict(os.environ, PX4_SYS_AUTOSTART="10040", PX4_SIMULATOR="sihsim",
                   PX4_SIM_MODEL="sihsim_quadx", PX4_SIM_SPEED_FACTOR=str(a.speed),
                   PX4_PARAM_EKF2_GPS_CTRL="0", PX4_PARAM_EKF2_EV_CTRL="1",
                   PX4_PARAM_EKF2_HGT_REF="0", PX4_PARAM_EKF2_EV_NOISE_MD="0",
                   PX4_PARAM_EKF2_EV_DELAY="20", PX4_PARAM_COM_ARM_WO_GPS="1",
                   PX4_PARAM_COM_OF_LOSS_T="2")
        procs.start("px4", [px4, "-d", "-i", str(n), "-w", os.path.join(work, "px4"), etc],
                    cwd=work, env=env)
        gcs = Gcs(gcs_us, truth_us)
        # PX4's offboard link streams HIGHRES_IMU at 50 Hz: ask for an IMU's rate (as
        # MAVROS users do), through PX4's own shell once it runs.
        wait_boot = time.monotonic() + 30
        while subprocess.run([px4 + "-mavlink", "--instance", str(n), "stream", "-u",
                              str(14580 + n), "-s", "HIGHRES_IMU", "-r", str(a.imu_hz)],
                             capture_output=True, timeout=10).returncode != 0:
            if time.monotonic() > wait_boot:
                raise HarnessError("PX4 shell does not answer (px4-mavlink stream)")
            time.sleep(0.5)
        # mavlink-server on the offboard link, a Zenoh client of skyfuse.
        zconf = os.path.join(work, "mavlink-server-zenoh.json5")
        with open(zconf, "w") as f:
            json.dump({"mode": "client", "connect": {"endpoints": [f"tcp/127.0.0.1:{zport}"]},
                       "scouting": {"multicast": {"enabled": False}}}, f)
        cfg = a.config or os.path.join(ROOT, "tests", "data", "sitl", "skyfuse-px4.toml")
        endpoint = f"udpout:127.0.0.1:{payload_px4}?messages={a.messages}"
        argv = [a.skyfuse, "run", "-c", cfg, "--listen", f"tcp/127.0.0.1:{zport}",
                "--no-multicast", "--http", f"127.0.0.1:{hport}", "--mavlink", endpoint]
        result["skyfuse_cmd"] = " ".join(argv)
        procs.start("skyfuse", argv, cwd=work,
                    env=dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "info,zenoh=warn")))
        http = f"http://127.0.0.1:{hport}"
        deadline = time.monotonic() + 20
        while True:
            try:
                with urllib.request.urlopen(f"{http}/healthz", timeout=2) as r:
                    r.read()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise HarnessError("skyfuse /healthz does not answer")
                time.sleep(0.3)
        procs.start("mavlink-server", [msrv, f"udpserver://127.0.0.1:{offboard_us}",
                                       f"zenoh://127.0.0.1:{zport}", "--zenoh-config-file", zconf,
                                       "--web-server", f"127.0.0.1:{wport}"], cwd=work)

        # skyfuse's pose (its Zenoh output) for scoring, and its status over time.
        import zenoh
        zc = zenoh.Config()
        zc.insert_json5("mode", '"client"')
        zc.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zport}"]))
        zc.insert_json5("scouting/multicast/enabled", "false")
        session = zenoh.open(zc)
        sky = []

        def on_pose(sample):
            try:
                p = json.loads(sample.payload.to_bytes())
                if p.get("valid"):
                    pos = p["position"]
                    sky.append((gcs.now(), pos[1], pos[0], -pos[2]))  # ENU -> NED
            except (ValueError, KeyError, TypeError, IndexError):
                pass
        session.declare_subscriber("skyfuse/px4-sih/pose", on_pose)

        def status():
            try:
                return get_json(f"{http}/api/v1/status")
            except OSError:
                return {}

        def wait(pred, secs, what):
            end = time.monotonic() + secs / a.speed
            while time.monotonic() < end:
                if procs.dead():
                    raise HarnessError(f"process died: {procs.dead()} (waiting for {what})")
                if pred():
                    return True
                time.sleep(0.1)
            raise FlightFailed(f"timed out: {what}")

        # skyfuse's status once a second: validity, why not, sensor health.
        timeline = []
        result["status_timeline"] = timeline

        def poll():
            while not gcs.stop.is_set():
                st = status()
                e = st.get("estimator") or {}
                timeline.append({
                    "t": round(gcs.now(), 1), "valid": e.get("valid"), "why": e.get("invalid_reason"),
                    "used": e.get("sources_used"), "armed_px4": gcs.armed,
                    "gps_innovation": ((e.get("sources") or {}).get("gps") or {}).get("innovation"),
                    "gps_ratio": ((e.get("sources") or {}).get("gps") or {}).get("test_ratio"),
                    "velocity": e.get("velocity"), "position": e.get("position"),
                    "sensors": {x["id"]: [x.get("health"), x.get("rate_hz") and round(x["rate_hz"], 1),
                                          x.get("rejected"), x.get("last_error")]
                                for x in st.get("sensors", [])},
                })
                time.sleep(1.0)
        threading.Thread(target=poll, daemon=True).start()

        # TIMESYNC with PX4 on the payload link, from skyfuse's first frame.
        t_boot = gcs.now()
        wait(lambda: status().get("outputs", [{}])[0].get("timesync", {}).get("converged"), 30,
             "TIMESYNC converged")
        ts = status()["outputs"][0]["timesync"]
        result["timesync"] = dict(ts, converged_after_s=round(gcs.now() - t_boot, 1))
        log("TIMESYNC:", result["timesync"])
        wait(lambda: status().get("estimator", {}).get("valid"), 60, "skyfuse valid")
        wait(lambda: gcs.position() is not None, 60, "EKF2 local position")
        time.sleep(3.0 / a.speed)

        # OFFBOARD needs setpoints flowing first; hold them at 20 Hz throughout.
        target = [0.0, 0.0, 0.0]
        stop_sp = threading.Event()
        lpos0 = gcs.position()
        target[:] = [lpos0[0], lpos0[1], lpos0[2]]

        def stream():
            while not stop_sp.is_set():
                gcs.setpoint(*target)
                time.sleep(0.05 / a.speed)
        threading.Thread(target=stream, daemon=True).start()
        time.sleep(1.0)
        base_n, base_e, base_d = lpos0
        # DO_SET_MODE: base mode CUSTOM_MODE_ENABLED, PX4 main mode 6 = OFFBOARD.
        gcs.command(176, 1, 6, 0)
        gcs.command(400, 1)  # arm
        wait(lambda: gcs.armed, 15, "armed")
        t_arm = gcs.now()
        result["armed_at_s"] = round(t_arm, 1)
        target[:] = [base_n, base_e, base_d - ALT]
        wait(lambda: gcs.position()[2] < base_d - ALT + 0.4, 30, "climbed")
        corners = []
        for (cn, ce) in SQUARE[1:]:
            target[:] = [base_n + cn, base_e + ce, base_d - ALT]
            ok = True
            try:
                wait(lambda: math.hypot(gcs.position()[0] - target[0], gcs.position()[1] - target[1]) < 0.5,
                     25, f"corner {cn},{ce}")
            except FlightFailed:
                ok = False
            time.sleep(1.5 / a.speed)
            corners.append({"corner_ne": [cn, ce], "reached_by_ekf2": ok, "t": round(gcs.now(), 1)})
        result["square"] = corners
        target[:] = [base_n, base_e, base_d + 0.5]
        time.sleep(6.0 / a.speed)
        gcs.command(21)  # NAV_LAND
        wait(lambda: gcs.armed is False, 40, "landed and disarmed")
        t_end = gcs.now()
        stop_sp.set()
        result["flight_s"] = round(t_end - t_arm, 1)

        # Score against truth (NED about the truth at arming), the error at arming removed.
        import numpy as np
        with gcs.lock:
            truth = list(gcs.truth)
            lpos = list(gcs.lpos)
        sky_t = list(sky)
        origin = next(x for x in truth if x[0] >= t_arm)[1:]
        tt = np.array([x[0] for x in truth])
        tn = np.array([score.ned(x[1], x[2], x[3], origin) for x in truth])

        def err(series):
            t = np.array([x[0] for x in series if t_arm <= x[0] <= t_end])
            p = np.array([x[1:] for x in series if t_arm <= x[0] <= t_end])
            ref = score.interp(t, tt, tn, 0.5)
            d = p - ref
            ok = ~np.isnan(d).any(axis=1)
            d = d[ok]
            d -= d[0]
            h = np.hypot(d[:, 0], d[:, 1])
            return {"n": int(len(h)), "rmse_h": round(float(np.sqrt(np.mean(h ** 2))), 3),
                    "max_h": round(float(h.max()), 3),
                    "rmse_v": round(float(np.sqrt(np.mean(d[:, 2] ** 2))), 3)}
        if a.keep:
            with open(os.path.join(work, "tracks.json"), "w") as f:
                json.dump({"truth_t": tt.tolist(), "truth_ned": tn.tolist(), "ekf2": lpos,
                           "skyfuse": sky_t, "t_arm": t_arm, "t_end": t_end}, f)
        result["ekf2_vs_truth"] = err(lpos)
        result["skyfuse_vs_truth"] = err(sky_t)
        # The corners by truth.
        misses = []
        for c in corners:
            cn, ce = c["corner_ne"]
            d = np.hypot(tn[:, 0] - cn, tn[:, 1] - ce)
            misses.append(round(float(d[(tt >= t_arm) & (tt <= t_end)].min()), 2))
        result["truth_corner_miss_m"] = misses
        st = status()
        mav = st.get("outputs", [{}])[0]
        result["skyfuse_mavlink"] = {k: mav.get(k) for k in ("sent", "withheld", "rate_hz", "timesync")}
        result["skyfuse_mavlink"]["links"] = mav.get("links")
        result["statustext"] = gcs.statustext[-30:]
        fails = []
        if result["ekf2_vs_truth"]["rmse_h"] > LIMITS["rmse_h"]:
            fails.append(f"EKF2 RMSE {result['ekf2_vs_truth']['rmse_h']} m")
        if max(misses) > LIMITS["corner_miss"]:
            fails.append(f"corner miss {max(misses)} m")
        if not all(c["reached_by_ekf2"] for c in corners):
            fails.append("a corner not reached")
        result["fails"] = fails
        result["pass"] = not fails
        code = 0 if not fails else 1
    except FlightFailed as e:
        result["fails"].append(str(e))
        code = 1
    except HarnessError as e:
        result["fails"].append(f"harness: {e}")
        code = 2
    finally:
        if gcs is not None:
            gcs.stop.set()
        procs.stop_all()
        with open(a.out, "w") as f:
            json.dump(result, f, indent=1)
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    print(json.dumps({k: result.get(k) for k in ("pass", "fails", "timesync", "ekf2_vs_truth",
                                                  "skyfuse_vs_truth", "truth_corner_miss_m")}))
    sys.exit(code)


class FlightFailed(Exception):
    pass


if __name__ == "__main__":
    main()
