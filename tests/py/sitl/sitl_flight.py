#!/usr/bin/env python3
"""Closed loop with a real ArduCopter SITL: the autopilot's sensors go through the real
mavlink-server to skyfuse over Zenoh, skyfuse's VISION_POSITION_ESTIMATE goes back to
the autopilot (EKF3 ExternalNav is its only horizontal position source), and this
script flies a take-off, a 10 m square and a landing in GUIDED mode, then scores EKF3
and skyfuse against the simulator's truth.

  sitl_flight.py --skyfuse BIN --scenario {gps_flow,no_gps,gps_loss,flow_fail}
                 --link {zenoh_raw,tcpout,udpin} --speedup N --out result.json

    SITL SERIAL0 (tcp 5760+10k) <- mavlink-server tcpclient -> Zenoh (client of skyfuse)
    skyfuse (Zenoh peer, listens on loopback) -> VPE by the chosen link:
      zenoh_raw: mavlink_raw/in -> mavlink-server -> SERIAL0
      tcpout:    tcp 127.0.0.1:5763+10k (SERIAL2)
      udpin:     SITL SERIAL2 is `udpclient:127.0.0.1:P`, skyfuse `udpin:127.0.0.1:P`
                 (SITL has no UDP server mode, so skyfuse cannot `udpout` to it)
    this script: control on SERIAL1 (tcp 5762+10k), skyfuse's pose on Zenoh,
                 GET /api/v1/status every second.

Everything on loopback; every child is stopped at the end (also on error, timeout,
SIGINT/SIGTERM). Peers from $SKYFUSE_PEERS (default ../shared/peers of the repo).
Exit code 0 when the flight completed (armed, took off, flew the square, landed,
disarmed), 1 otherwise, 2 on a harness error; result.json is written in every case.
"""
import argparse
import collections
import glob
import json
import struct
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import urllib.request

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import procs as procs_mod  # noqa: E402
import score  # noqa: E402

ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
DATA = os.path.join(ROOT, "tests", "data", "sitl")
HOME = (-35.363261, 149.16523, 584.0, 353.0)
VEHICLE = "sitl"

SCENARIOS = {
    # gps: GPS on at boot (sets the EKF origin, skyfuse fuses GPS_RAW_INT);
    # fault: (parameter, value) set at the start of the square's second leg;
    # limits: pass thresholds, m: whole-flight horizontal RMSE of EKF3 and of skyfuse
    # against truth, and the truth's largest miss of a corner of the square.
    "gps_flow": {"gps": True, "fault": None, "limits": (1.0, 1.5)},
    "no_gps": {"gps": False, "fault": None, "limits": (2.0, 3.0)},
    "gps_loss": {"gps": True, "fault": ("SIM_GPS_DISABLE", 1), "limits": (2.0, 3.0)},
    "flow_fail": {"gps": True, "fault": ("SIM_FLOW_ENABLE", 0), "limits": (1.0, 1.5)},
}
LINKS = ("zenoh_raw", "tcpout", "udpin")

COPTER_GUIDED, COPTER_LAND = 4, 9
MAV_CMD_DO_SET_MODE, MAV_CMD_ARM, MAV_CMD_TAKEOFF = 176, 400, 22
MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE = 511, 512
POS_ONLY = 0b0000_1101_1111_1000  # SET_POSITION_TARGET_LOCAL_NED: x, y, z only (yaw ignored too)
EKF_POS_HORIZ_ABS = 0x10
LANDED = {0: "undefined", 1: "on_ground", 2: "in_air", 3: "takeoff", 4: "landing"}


class HarnessError(Exception):
    pass


class Tlog:
    """A telemetry log as QGroundControl/MAVProxy write it: per frame an 8-byte big-endian
    Unix time in µs, then the frame. Fed with SERIAL0's frames as mavlink-server puts
    them on mavlink_raw/out (what skyfuse's link sees) and SIM_STATE from SERIAL1."""

    def __init__(self, path):
        self.f = open(path, "wb")
        self.lock = threading.Lock()
        self.frames = 0

    def write(self, frame):
        with self.lock:
            if self.f.closed:
                return
            self.f.write(struct.pack(">Q", int(time.time() * 1e6)) + bytes(frame))
            self.frames += 1

    def close(self):
        with self.lock:
            self.f.close()


TLOG = None


def log(*a):
    print(f"[{time.strftime('%H:%M:%S')}]", *a, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- control link
class Control:
    """pymavlink on SERIAL1: a reader thread records everything with host time."""

    def __init__(self, url, speedup, deadline):
        from pymavlink import mavutil
        self.mavutil = mavutil
        self.speedup = speedup
        last = None
        while True:
            try:
                self.m = mavutil.mavlink_connection(url, source_system=255, source_component=190,
                                                    autoreconnect=False)
                break
            except OSError as e:
                last = e
                if time.monotonic() > deadline:
                    raise HarnessError(f"control link {url}: {last}")
                time.sleep(0.2)
        self.send_lock = threading.Lock()
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.t0 = time.monotonic()
        self.counts = collections.Counter()
        self.first, self.last_t = {}, {}
        self.lpos, self.truth = [], []          # (t, x, y, z), (t, lat, lon, alt)
        self.truth_vel = []
        self.gps = []                           # (t, lat, lon, alt) with a 3D fix
        self.statustext = []                   # (t, severity, text)
        self.acks = []                         # (t, command, result)
        self.events = []                       # (t, what, value)
        self.params = {}
        self.armed = None
        self.mode = None
        self.landed = None
        self.ekf_flags = None
        self.origin = None
        self.home = None
        self.boot = None                       # (host t, time_boot_ms)
        self.vpe_routed = []                   # host times of VPE from 1/197 seen here
        self.error = None
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    # -- receiving
    def _run(self):
        while not self.stop.is_set():
            try:
                msg = self.m.recv_match(blocking=True, timeout=0.2)
            except Exception as e:  # noqa: BLE001
                self.error = repr(e)
                time.sleep(0.1)
                continue
            if msg is None:
                continue
            try:
                self._on(msg, time.monotonic())
            except Exception as e:  # noqa: BLE001
                self.error = f"{msg.get_type()}: {e!r}"

    def _on(self, msg, t):
        typ = msg.get_type()
        if typ == "BAD_DATA":
            self.counts["BAD_DATA"] += 1
            return
        sysid, comp = msg.get_srcSystem(), msg.get_srcComponent()
        if TLOG is not None and typ == "SIM_STATE":
            TLOG.write(msg.get_msgbuf())
        key = typ if comp == 1 else f"{typ}@{sysid}/{comp}"
        self.counts[key] += 1
        self.first.setdefault(key, t)
        self.last_t[key] = t
        if comp == 197:
            if typ == "VISION_POSITION_ESTIMATE":
                self.vpe_routed.append((t, msg.usec, msg.x, msg.y, msg.z, msg.reset_counter))
            return
        if comp != 1:
            return
        if typ == "HEARTBEAT":
            if msg.type == 6:  # a GCS
                return
            armed = bool(msg.base_mode & 128)
            if armed != self.armed:
                self.events.append((t, "armed", armed))
                self.armed = armed
            if msg.custom_mode != self.mode:
                self.events.append((t, "mode", msg.custom_mode))
                self.mode = msg.custom_mode
        elif typ == "LOCAL_POSITION_NED":
            self.lpos.append((t, msg.x, msg.y, msg.z))
            self.boot = (t, msg.time_boot_ms)
        elif typ == "SIM_STATE":
            if getattr(msg, "lat_int", 0):
                lat, lon = msg.lat_int * 1e-7, msg.lon_int * 1e-7
            else:  # ArduPilot fills the float fields with degE7 as well
                lat, lon = msg.lat * 1e-7, msg.lon * 1e-7
            self.truth.append((t, lat, lon, msg.alt))
            self.truth_vel.append((msg.vn, msg.ve, msg.vd))
        elif typ == "GPS_RAW_INT":
            if msg.fix_type >= 3:
                self.gps.append((t, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3))
        elif typ == "SYSTEM_TIME":
            self.boot = (t, msg.time_boot_ms)
        elif typ == "STATUSTEXT":
            self.statustext.append((t, msg.severity, msg.text))
        elif typ == "COMMAND_ACK":
            self.acks.append((t, msg.command, msg.result))
        elif typ == "EXTENDED_SYS_STATE":
            if msg.landed_state != self.landed:
                self.events.append((t, "landed_state", LANDED.get(msg.landed_state, msg.landed_state)))
                self.landed = msg.landed_state
        elif typ == "EKF_STATUS_REPORT":
            if msg.flags != self.ekf_flags:
                self.events.append((t, "ekf_flags", msg.flags))
                self.ekf_flags = msg.flags
        elif typ == "GPS_GLOBAL_ORIGIN":
            o = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
            if o != self.origin:
                self.events.append((t, "gps_global_origin", o))
            self.origin = o
        elif typ == "HOME_POSITION":
            self.home = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
        elif typ == "PARAM_VALUE":
            self.params[msg.param_id] = (t, msg.param_value)

    # -- helpers
    def sim_now(self):
        """Autopilot time since boot, s (from the last time_boot_ms seen)."""
        if self.boot is None:
            return None
        t, ms = self.boot
        return ms / 1000.0 + (time.monotonic() - t) * self.speedup

    def texts_since(self, t0):
        return [x for x in self.statustext if x[0] >= t0]

    def saw_text(self, fragment, t0=0.0):
        return any(fragment in x[2] for x in self.statustext if x[0] >= t0)

    # -- sending
    def _send(self, fn, *args):
        with self.send_lock:
            fn(*args)

    def command(self, cmd, *p):
        p = list(p) + [0] * (7 - len(p))
        self._send(self.m.mav.command_long_send, 1, 1, cmd, 0, *p)

    def heartbeat(self):
        self._send(self.m.mav.heartbeat_send, 6, 8, 0, 0, 4)  # GCS, invalid autopilot, active

    def interval(self, msg_id, hz):
        self.command(MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)

    def request(self, msg_id):
        self.command(MAV_CMD_REQUEST_MESSAGE, msg_id)

    def set_mode(self, custom):
        self.command(MAV_CMD_DO_SET_MODE, 1, custom)

    def set_param(self, name, value):
        self._send(self.m.mav.param_set_send, 1, 1, name.encode(), float(value),
                   self.mavutil.mavlink.MAV_PARAM_TYPE_REAL32)

    def target(self, x, y, z):
        ms = int(self.sim_now() * 1000) & 0xFFFFFFFF if self.boot else 0
        self._send(self.m.mav.set_position_target_local_ned_send, ms, 1, 1, 1, POS_ONLY,
                   x, y, z, 0, 0, 0, 0, 0, 0, 0, 0)

    def set_origin(self, lat, lon, alt):
        li, lo, al = int(lat * 1e7), int(lon * 1e7), int(alt * 1000)
        self._send(self.m.mav.set_gps_global_origin_send, 1, li, lo, al, 0)
        self._send(self.m.mav.set_home_position_send, 1, li, lo, al, 0, 0, 0,
                   [1, 0, 0, 0], 0, 0, 0, 0)

    def close(self):
        self.stop.set()
        self.th.join(timeout=2)
        try:
            self.m.close()
        except Exception:  # noqa: BLE001
            pass


# --------------------------------------------------------------------------- Zenoh watcher
class ZenohWatch:
    """skyfuse's pose and events, and what mavlink-server publishes (counted by message)."""

    def __init__(self, endpoint):
        import zenoh
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("listen/endpoints", "[]")
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        self.s = zenoh.open(conf)
        self.lock = threading.Lock()
        self.pose = []          # (t, valid, [x, y, z] ENU)
        self.pose_last = None
        self.origin = None
        self.resets = []        # (t, reset_counter)
        self.sources = []       # (t, sources)
        self.invalid = []       # (t, reason) changes
        self.events = []
        self.mav = {}           # key -> [count, first t, last t]
        self.raw_in = 0
        self.errors = []
        self.last_payload = {}
        p = f"skyfuse/{VEHICLE}"
        self.subs = [self.s.declare_subscriber(f"{p}/pose", self._pose),
                     self.s.declare_subscriber(f"{p}/events", self._event),
                     self.s.declare_subscriber("mavlink/*/*/*", self._mav),
                     self.s.declare_subscriber("mavlink_raw/in", self._raw_in)]
        if TLOG is not None:
            self.subs.append(self.s.declare_subscriber(
                "mavlink_raw/out", lambda smp: TLOG.write(smp.payload.to_bytes())))

    def _pose(self, sample):
        t = time.monotonic()
        try:
            p = json.loads(bytes(sample.payload.to_bytes()))
        except Exception as e:  # noqa: BLE001
            self.errors.append(f"pose: {e}")
            return
        with self.lock:
            self.pose.append((t, bool(p.get("valid")), p.get("position")))
            self.pose_last = p
            if p.get("origin"):
                self.origin = p["origin"]
            rc = p.get("reset_counter")
            if not self.resets or self.resets[-1][1] != rc:
                self.resets.append((t, rc))
            src = sorted(p.get("sources") or [])
            if not self.sources or self.sources[-1][1] != src:
                self.sources.append((t, src))
            why = p.get("invalid_reason")
            if not self.invalid or self.invalid[-1][1] != why:
                self.invalid.append((t, why))

    def _event(self, sample):
        try:
            e = json.loads(bytes(sample.payload.to_bytes()))
        except Exception as e2:  # noqa: BLE001
            e = {"undecodable": str(e2)}
        with self.lock:
            self.events.append((time.monotonic(), e))

    def _mav(self, sample):
        t = time.monotonic()
        k = str(sample.key_expr)
        self.last_payload[k] = sample.payload
        c = self.mav.get(k)
        if c is None:
            self.mav[k] = [1, t, t]
        else:
            c[0] += 1
            c[2] = t

    def snapshot(self, names=("OPTICAL_FLOW", "DISTANCE_SENSOR", "HIGHRES_IMU", "GPS_RAW_INT",
                              "ATTITUDE_QUATERNION")):
        """The last payload of each of these messages, as mavlink-server sent it."""
        out = {}
        for k, p in list(self.last_payload.items()):
            if k.rsplit("/", 1)[-1] in names and k.startswith("mavlink/1/1/"):
                try:
                    out[k] = bytes(p.to_bytes()).decode()
                except Exception as e:  # noqa: BLE001
                    out[k] = f"undecodable: {e}"
        with self.lock:
            out["skyfuse_pose"] = self.pose_last
        return out

    def _raw_in(self, _sample):
        self.raw_in += 1

    def close(self):
        for s in self.subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self.s.close()


# --------------------------------------------------------------------------- status poller
class StatusPoll:
    def __init__(self, url, period=1.0):
        self.url, self.period = url, period
        self.snaps = []      # reduced
        self.first_valid = None
        self.last = None
        self.errors = 0
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def get(self):
        with urllib.request.urlopen(self.url, timeout=1.5) as r:
            return json.loads(r.read())

    def _run(self):
        while not self.stop.wait(self.period):
            try:
                s = self.get()
            except Exception:  # noqa: BLE001
                self.errors += 1
                continue
            t = time.monotonic()
            self.last = (t, s)
            red = reduce_status(s)
            red["t"] = t
            self.snaps.append(red)
            if self.first_valid is None and red["estimator"].get("valid"):
                self.first_valid = (t, s)

    def close(self):
        self.stop.set()
        self.th.join(timeout=3)


ESTIMATOR_KEYS = ("valid", "invalid_reason", "mode", "reset_counter", "sources", "position_std_m",
                  "pos_std_m", "std", "origin")


def reduce_status(s):
    est = s.get("estimator") or {}
    outs = s.get("outputs") or []
    if isinstance(outs, dict):
        outs = [dict(v, name=k) for k, v in outs.items()]
    mav = next((o for o in outs if o.get("name") == "mavlink"), {})
    sensors = {}
    for x in s.get("sensors") or []:
        sensors[x.get("id")] = {k: x.get(k) for k in ("health", "rate_hz", "accepted", "rejected",
                                                        "dropped", "last_error", "used", "usable",
                                                        "test_ratio")}
        sensors[x.get("id")]["reasons"] = [r.get("code") if isinstance(r, dict) else r
                                           for r in x.get("reasons") or []]
    return {"estimator": {k: est.get(k) for k in ESTIMATOR_KEYS if k in est},
            "mavlink": {k: mav.get(k) for k in ("sent", "withheld", "dropped", "errors", "rate_hz",
                                               "sending", "not_sending_reason", "last_error",
                                               "timesync")},
            "clock": (s.get("ingest") or {}).get("clock"),
            "sensors": sensors}


# --------------------------------------------------------------------------- the run
class Run:
    def __init__(self, a):
        self.a = a
        self.sc = SCENARIOS[a.scenario]
        self.result = {"scenario": a.scenario, "link": a.link, "speedup": a.speedup,
                       "ok": False, "stage": "setup", "problems": []}
        self.procs = None
        self.ctl = None
        self.z = None
        self.poll = None
        self.phase_marks = []  # (name, host t)
        self.flying = False
        self.t_start = time.monotonic()

    def mark(self, name):
        t = time.monotonic()
        self.phase_marks.append((name, t))
        log(f"{name} (wall {t - self.t_start:.1f} s, sim {self.ctl.sim_now() if self.ctl else None})")
        self.result["stage"] = name
        return t

    def problem(self, text):
        log("PROBLEM:", text)
        self.result["problems"].append(text)

    def truth_d(self, at=None):
        """Truth height (NED d about the first SIM_STATE), now or at host time `at`."""
        tr = self.ctl.truth
        if not tr:
            return None
        if at is None:
            row = tr[-1]
        else:
            row = min(tr, key=lambda r: abs(r[0] - at))
        return float(score.ned([row[1]], [row[2]], [row[3]], tr[0][1:4])[0][2])

    def check_alive(self):
        dead = self.procs.dead() if self.procs else []
        if dead:
            raise HarnessError(f"child ended: {dead}")

    def wait(self, pred, sim_s, poll=0.05, slack=1.0):
        """Wait for pred() at most sim_s simulated seconds (wall: / speedup, + slack s).
        While flying, a disarm ends the flight (FlightFailed)."""
        end = time.monotonic() + sim_s / self.a.speedup + slack
        while time.monotonic() < end:
            if pred():
                return True
            self.check_alive()
            if self.flying and self.ctl.armed is False:
                texts = [x[2] for x in self.ctl.statustext[-6:]]
                raise FlightFailed(f"disarmed in flight (last STATUSTEXTs: {texts})")
            time.sleep(poll)
        return bool(pred())

    # -- setup
    def setup(self):
        a = self.a
        peers = os.environ.get("SKYFUSE_PEERS", os.path.join(ROOT, "..", "shared", "peers"))
        arducopter = os.path.join(peers, "bin", "arducopter")
        msrv = os.path.join(peers, "bin", "mavlink-server")
        copter_parm = os.path.join(peers, "ardupilot", "copter.parm")
        for f in (arducopter, msrv, copter_parm, a.skyfuse):
            if not os.path.exists(f):
                raise HarnessError(f"missing: {f}")
        self.work = tempfile.mkdtemp(prefix=f"sitl-{a.scenario}-")
        self.result["workdir"] = self.work
        self.procs = procs_mod.Procs(self.work)
        # skyfuse: a private copy (the original may be rebuilt under us).
        sky = os.path.join(self.work, "skyfuse")
        stable_copy(a.skyfuse, sky)
        self.result["skyfuse_version"] = subprocess.run([sky, "--version"], capture_output=True,
                                                        text=True, timeout=20).stdout.strip()
        inst = procs_mod.free_sitl_instance(first=a.instance or 1)
        s0, s1, s2 = 5760 + 10 * inst, 5762 + 10 * inst, 5763 + 10 * inst
        zport, hport, wport = procs_mod.free_port(), procs_mod.free_port(), procs_mod.free_port()
        uport = procs_mod.free_port(procs_mod.socket.SOCK_DGRAM)
        self.ports = {"instance": inst, "serial0": s0, "serial1": s1, "serial2": s2,
                      "zenoh": zport, "http": hport, "mavlink_server_web": wport}
        self.http = f"http://127.0.0.1:{hport}"

        # skyfuse config, env and command line
        cfg = a.config or os.path.join(DATA, "skyfuse-gps.toml" if self.sc["gps"] else "skyfuse-nogps.toml")
        self.result["skyfuse_config"] = cfg
        env = dict(os.environ)
        env.setdefault("RUST_LOG", "info,zenoh=warn")
        argv = [sky, "run", "-c", cfg, "--listen", f"tcp/127.0.0.1:{zport}", "--no-multicast",
                "--http", f"127.0.0.1:{hport}"]
        if a.link == "zenoh_raw":
            env["SKYFUSE__MAVLINK__ZENOH_RAW"] = "true"
        elif a.link == "tcpout":
            argv += ["--mavlink", f"tcpout:127.0.0.1:{s2}"]
        else:
            argv += ["--mavlink", f"udpin:127.0.0.1:{uport}"]
            self.ports["udp"] = uport
        origin_by = a.origin
        if a.origin == "auto" and self.sc["gps"] and not a.fast_arm:
            origin_by = "gps"  # GPS on at boot sets the EKF origin (after ~20 s)
        if origin_by == "none":
            origin_by = "gps" if self.sc["gps"] else "none"
        elif origin_by != "gps":
            if origin_by in ("auto", "skyfuse"):
                env2 = dict(env, SKYFUSE__MAVLINK__EKF_ORIGIN=json.dumps(list(HOME[:3])))
                chk = subprocess.run([sky, "check-config", cfg], env=env2, capture_output=True,
                                     text=True, timeout=20)
                if chk.returncode == 0:
                    env, origin_by = env2, "skyfuse"
                elif origin_by == "skyfuse":
                    raise HarnessError(f"skyfuse rejects ekf_origin: {chk.stderr.strip()[-300:]}")
                else:
                    origin_by = "harness"
                    self.result["ekf_origin_note"] = ("skyfuse has no [mavlink] ekf_origin yet: "
                                                      + (chk.stderr or chk.stdout).strip()[-200:]
                                                      + "; the harness sends SET_GPS_GLOBAL_ORIGIN"
                                                      " + SET_HOME_POSITION on SERIAL1")
        self.origin_by = origin_by
        self.result["ekf_origin_by"] = origin_by
        chk = subprocess.run([sky, "check-config", cfg], env=env, capture_output=True, text=True,
                             timeout=20)
        if chk.returncode != 0:
            raise HarnessError(f"check-config {cfg}: {chk.stderr.strip()[-500:]}")
        self.result["skyfuse_cmd"] = " ".join(argv)
        if "SKYFUSE__MAVLINK__EKF_ORIGIN" in env:
            self.result["skyfuse_env"] = {"SKYFUSE__MAVLINK__EKF_ORIGIN": env["SKYFUSE__MAVLINK__EKF_ORIGIN"]}
        self.procs.start("skyfuse", argv, cwd=self.work, env=env)
        if not wait_http(f"{self.http}/healthz", 20):
            raise HarnessError("skyfuse /healthz does not answer")

        # SITL
        shutil.copy(os.path.join(DATA, "message-intervals-chan0.txt"), self.work)
        parms = [copter_parm, os.path.join(DATA, "common.parm"),
                 os.path.join(DATA, "gps.parm" if self.sc["gps"] else "nogps.parm")]
        if a.fast_arm:
            # ARMING_CHECK bits (AP_Arming): 0 all, 3 GPS, 4 INS, 12 GPS config; 1..20 exist.
            bits = set(range(1, 21)) - {3, 4, 12}
            extra = os.path.join(self.work, "fastarm-checks.parm")
            with open(extra, "w") as f:
                f.write(f"ARMING_CHECK {sum(1 << b for b in bits)}\n")
            parms += [os.path.join(DATA, "fastarm.parm"), extra]
        sargv = [arducopter, "--model", "quad", "--speedup", str(a.speedup), "-I", str(inst), "-w",
                 "--home", ",".join(str(x) for x in (HOME[0], HOME[1], int(HOME[2]), int(HOME[3]))),
                 "--defaults", ",".join(parms)]
        if a.link == "udpin":
            sargv += ["--serial2", f"udpclient:127.0.0.1:{uport}"]
        self.result["sitl_cmd"] = " ".join(sargv)
        self.procs.start("arducopter", sargv, cwd=self.work)
        if not wait_port(s0, 10):
            raise HarnessError(f"SITL SERIAL0 {s0} not listening")

        # mavlink-server: a Zenoh client of skyfuse
        zconf = os.path.join(self.work, "mavlink-server-zenoh.json5")
        with open(zconf, "w") as f:
            json.dump({"mode": "client", "connect": {"endpoints": [f"tcp/127.0.0.1:{zport}"]},
                       "scouting": {"multicast": {"enabled": False}}}, f, indent=1)
        margv = [msrv, f"tcpclient://127.0.0.1:{s0}", f"zenoh://127.0.0.1:{zport}",
                 f"zenohraw://127.0.0.1:{zport}", "--zenoh-config-file", zconf,
                 "--web-server", f"127.0.0.1:{wport}", "--log-path", os.path.join(self.work, "msrv-logs")]
        self.result["mavlink_server_cmd"] = " ".join(margv)
        self.procs.start("mavlink-server", margv, cwd=self.work)

        self.z = ZenohWatch(f"tcp/127.0.0.1:{zport}")
        self.poll = StatusPoll(f"{self.http}/api/v1/status", 1.0)
        self.ctl = Control(f"tcp:127.0.0.1:{s1}", a.speedup, time.monotonic() + 30)
        self.result["ports"] = self.ports

    # -- flight
    def fly(self):
        a, ctl, sp = self.a, self.ctl, self.a.speedup
        self.mark("boot")
        if not self.wait(lambda: ctl.armed is not None, 20 * sp):
            raise HarnessError("no HEARTBEAT from the autopilot on SERIAL1")
        # SIM_STATE, LOCAL_POSITION_NED, EXTENDED_SYS_STATE, SYSTEM_TIME, EKF_STATUS_REPORT,
        # GLOBAL_POSITION_INT, GPS_RAW_INT
        for mid, hz in ((108, 25), (32, 25), (245, 5), (2, 5), (193, 2), (33, 5), (24, 5)):
            ctl.interval(mid, hz)
        ctl.heartbeat()
        t_boot = time.monotonic()
        last_hb = 0.0
        last_origin = -1e9

        def tick():
            nonlocal last_hb, last_origin
            now = time.monotonic()
            if now - last_hb >= 1.0:
                ctl.heartbeat()
                last_hb = now
            if self.origin_by == "harness" and ctl.origin is None and now - last_origin >= 2.0 / sp:
                ctl.set_origin(*HOME[:3])
                ctl.request(49)  # GPS_GLOBAL_ORIGIN
                last_origin = now
            return False

        # Wait for EKF3 to use ExternalNav (it needs the origin and skyfuse's VPE).
        extnav = self.wait(lambda: tick() or ctl.saw_text("is using external nav data"),
                           a.extnav_timeout)
        self.result["extnav_used"] = extnav
        self.result["extnav_wait_sim_s"] = round((time.monotonic() - t_boot) * sp, 1)
        if not extnav:
            self.problem("EKF3 never reported 'is using external nav data'")
        ctl.request(49)
        ctl.request(242)  # HOME_POSITION

        # With GPS, skyfuse's frame is anchored at its first good fix: arm after that.
        if self.sc["gps"]:
            got = self.wait(lambda: tick() or bool(self.z and self.z.origin), 40)
            self.result["skyfuse_origin_wait_sim_s"] = round((time.monotonic() - t_boot) * sp, 1)
            if not got:
                self.problem("skyfuse set no origin from GPS before arming")

        # GUIDED, then arm (retrying: the estimate may need a moment).
        self.mark("arming")
        armed = False
        end = time.monotonic() + a.arm_timeout / sp + 1
        while time.monotonic() < end and not armed:
            tick()
            if ctl.mode != COPTER_GUIDED:
                ctl.set_mode(COPTER_GUIDED)
            else:
                ctl.command(MAV_CMD_ARM, 1)
            armed = self.wait(lambda: tick() or bool(ctl.armed), 1.0, 0.05)
        self.result["armed"] = armed
        if not armed:
            raise FlightFailed("did not arm")
        t_arm = self.mark("takeoff")
        self.flying = True
        x0, y0, z0 = ctl.lpos[-1][1:] if ctl.lpos else (0.0, 0.0, 0.0)
        self.result["takeoff_point_ekf"] = [round(x0, 3), round(y0, 3), round(z0, 3)]
        ctl.command(MAV_CMD_TAKEOFF, 0, 0, 0, 0, 0, 0, a.alt)
        up = self.wait(lambda: tick() or (ctl.lpos and ctl.lpos[-1][3] <= z0 - 0.9 * a.alt), 25)
        self.result["took_off"] = bool(up)
        if not up:
            raise FlightFailed("did not reach the take-off height")

        # The square: corners relative to the take-off point, in EKF3's frame.
        self.mark("square")
        s = a.side
        corners = [(s, 0), (s, s), (0, s), (0, 0)]
        zt = z0 - a.alt
        legs = []
        for i, (cx, cy) in enumerate(corners):
            if i == 1 and self.sc["fault"]:
                name, value = self.sc["fault"]
                ctl.set_param(name, value)
                ok = self.wait(lambda: tick() or (name in ctl.params and ctl.params[name][1] == value), 5)
                self.result["fault"] = {"param": name, "value": value, "acknowledged": ok}
                self.mark("square_after_fault")
            tx, ty = x0 + cx, y0 + cy
            t_leg = time.monotonic()
            last_send = [0.0]

            def reached():
                tick()
                now = time.monotonic()
                if now - last_send[0] > 0.5 / sp:
                    ctl.target(tx, ty, zt)
                    last_send[0] = now
                if not ctl.lpos:
                    return False
                _, x, y, z = ctl.lpos[-1]
                return math.hypot(x - tx, y - ty) < 0.5 and abs(z - zt) < 0.5

            if i == 1:
                self.wait(lambda: reached() and False, 1.5, slack=0)  # moving at speed by now
                snap = self.z.snapshot()
                if ctl.truth:
                    snap["truth_sim_state"] = ctl.truth[-1]
                    snap["truth_velocity_ned"] = ctl.truth_vel[-1] if ctl.truth_vel else None
                self.result["payloads_mid_leg2"] = snap
            ok = self.wait(reached, a.leg_timeout)
            legs.append({"corner": [cx, cy], "target_ekf": [round(tx, 3), round(ty, 3), round(zt, 3)],
                         "t0": t_leg, "t1": time.monotonic(), "reached_by_ekf": ok,
                         "sim_s": round((time.monotonic() - t_leg) * sp, 1)})
            if not ok:
                self.problem(f"corner {i + 1} ({cx}, {cy}) not reached by EKF3 within {a.leg_timeout} sim s")
            self.wait(lambda: tick() or False, 1.0, slack=0)  # a moment at the corner
        self.legs = legs
        self.result["square_done"] = all(leg["reached_by_ekf"] for leg in legs)

        # Land and wait for the disarm.
        self.mark("land")
        self.flying = False
        ctl.set_mode(COPTER_LAND)
        ground_d = self.truth_d(t_arm)
        rest = {"since": None}

        def down():
            tick()
            if ctl.armed is False:
                return True
            d = self.truth_d()
            now = time.monotonic()
            if ground_d is not None and d is not None and abs(d - ground_d) < 0.15:
                rest["since"] = rest["since"] or now
                if (now - rest["since"]) * sp > a.ground_wait:
                    return True
            else:
                rest["since"] = None
            return False

        self.wait(down, a.land_timeout)
        disarmed = ctl.armed is False
        self.result["disarmed"] = disarmed
        self.result["landed"] = ctl.landed == 1
        self.result["on_ground_by_truth"] = rest["since"] is not None or (
            ground_d is not None and self.truth_d() is not None and abs(self.truth_d() - ground_d) < 0.15)
        if not disarmed:
            self.result["autopilot_landed_state_at_end"] = LANDED.get(ctl.landed, ctl.landed)
            ctl.command(MAV_CMD_ARM, 0, 21196)  # force disarm, so the run ends cleanly
            self.wait(lambda: ctl.armed is False, 3)
            self.result["force_disarmed"] = ctl.armed is False
        self.mark("end")
        if not disarmed:
            raise FlightFailed("did not disarm after LAND")
        if not (self.result["square_done"] and self.result["landed"]):
            raise FlightFailed("square not completed" if not self.result["square_done"]
                               else "not on the ground at the end")

    # -- scoring and report
    def report(self):
        r, ctl, z = self.result, self.ctl, self.z
        sp = self.a.speedup
        marks = dict(self.phase_marks)
        t_end = time.monotonic()
        r["wall_s"] = round(t_end - self.t_start, 1)
        if ctl is None:
            return
        r["sim_s"] = round(ctl.sim_now(), 1) if ctl.sim_now() else None
        # phases
        order = [n for n, _ in self.phase_marks] + ["_"]
        times = [t for _, t in self.phase_marks] + [t_end]
        phases = {order[i]: (times[i], times[i + 1]) for i in range(len(order) - 1)}
        if "takeoff" in marks:
            phases["flight"] = (marks["takeoff"], marks.get("end", t_end))
        r["phases_wall_s"] = {k: round((v[1] - v[0]), 1) for k, v in phases.items()}
        t_arm = marks.get("takeoff")
        flight_events = [(t, w, v) for (t, w, v) in ctl.events]
        r["armed_s_sim"] = armed_time(flight_events, t_end, sp)
        # truth
        with ctl.lock:
            truth = np.array(ctl.truth, float).reshape(-1, 4)
            lpos = np.array(ctl.lpos, float).reshape(-1, 4)
        r["samples"] = {"SIM_STATE": len(truth), "LOCAL_POSITION_NED": len(lpos),
                        "skyfuse_pose": len(z.pose) if z else 0}
        if len(truth) < 2:
            self.problem("no SIM_STATE truth on SERIAL1")
            return
        ekf_origin = ctl.origin
        ref = ekf_origin or (truth[0, 1], truth[0, 2], truth[0, 3])
        r["ekf_origin"] = ekf_origin
        r["home"] = ctl.home
        tn = score.ned(truth[:, 1], truth[:, 2], truth[:, 3], ref)
        if len(lpos):
            r["ekf3_vs_truth"] = score.errors(lpos[:, 0], lpos[:, 1:4], truth[:, 0], tn, phases, t_arm)
            if "flight" in phases:
                r["ekf3_vs_truth"]["lag"] = score.best_lag(lpos[:, 0], lpos[:, 1:4], truth[:, 0], tn,
                                                            *phases["flight"])
        # the simulated GPS itself (what skyfuse fuses), for reference
        with ctl.lock:
            gps = np.array(ctl.gps, float).reshape(-1, 4)
        if len(gps) > 10:
            gn = score.ned(gps[:, 1], gps[:, 2], gps[:, 3], ref)
            r["gps_vs_truth"] = {k: v for k, v in score.errors(gps[:, 0], gn, truth[:, 0], tn, phases, t_arm).items()
                                 if k in ("flight", "offset_at_arming")}
            if "flight" in phases:
                r["gps_vs_truth"]["lag"] = score.best_lag(gps[:, 0], gn, truth[:, 0], tn, *phases["flight"])
        # skyfuse's pose (ENU about its own origin, or about its start pose without one)
        if z and z.pose:
            with z.lock:
                pose = [(t, p) for t, v, p in z.pose if v and p]
                sky_origin = z.origin
            r["skyfuse_origin"] = sky_origin
            if pose:
                pt = np.array([t for t, _ in pose])
                enu = np.array([p for _, p in pose], float)
                pn = np.stack([enu[:, 1], enu[:, 0], -enu[:, 2]], axis=1)
                if sky_origin:
                    sref = (sky_origin["lat"], sky_origin["lon"], sky_origin["alt"])
                else:
                    sref = (truth[0, 1], truth[0, 2], truth[0, 3])
                    r["skyfuse_frame_note"] = "no origin in the pose: truth about the first SIM_STATE"
                sn = score.ned(truth[:, 1], truth[:, 2], truth[:, 3], sref)
                r["skyfuse_vs_truth"] = score.errors(pt, pn, truth[:, 0], sn, phases, t_arm)
                if "flight" in phases:
                    r["skyfuse_vs_truth"]["lag"] = score.best_lag(pt, pn, truth[:, 0], sn, *phases["flight"])
            r["skyfuse_pose_valid_fraction"] = round(sum(1 for _, v, _ in z.pose if v) / len(z.pose), 3)
        if self.a.tracks:
            self.write_tracks(truth, tn, lpos)
        # the square against truth (truth in EKF3's frame: about the EKF origin)
        if getattr(self, "legs", None):
            worst = 0.0
            for leg in self.legs:
                m = (truth[:, 0] >= leg["t0"]) & (truth[:, 0] <= leg["t1"] + 1.0 / sp)
                if m.any():
                    d = np.hypot(tn[m, 0] - leg["target_ekf"][0], tn[m, 1] - leg["target_ekf"][1])
                    leg["truth_closest_m"] = round(float(d.min()), 3)
                    worst = max(worst, leg["truth_closest_m"])
                m2 = (lpos[:, 0] >= leg["t0"]) & (lpos[:, 0] <= leg["t1"] + 1.0 / sp)
                if m2.any():
                    d = np.hypot(lpos[m2, 1] - leg["target_ekf"][0], lpos[m2, 2] - leg["target_ekf"][1])
                    leg["ekf_closest_m"] = round(float(d.min()), 3)
                leg.pop("t0")
                leg.pop("t1")
            r["square"] = {"legs": self.legs, "max_truth_distance_from_corner_m": round(worst, 3)}

    def write_tracks(self, truth, tn, lpos):
        """CSV of every track in EKF3's NED frame (truth about the EKF origin), host time
        since start: truth, ekf3 (LOCAL_POSITION_NED), vpe (what the autopilot got, as it
        forwards it to SERIAL1), skyfuse (its Zenoh pose, ENU -> NED, own frame)."""
        t0 = self.t_start
        with open(self.a.tracks, "w") as f:
            f.write("t,track,valid,n,e,d\n")
            for (t, *_), p in zip(truth, tn):
                f.write(f"{t - t0:.3f},truth,1,{p[0]:.3f},{p[1]:.3f},{p[2]:.3f}\n")
            for t, x, y, z in lpos:
                f.write(f"{t - t0:.3f},ekf3,1,{x:.3f},{y:.3f},{z:.3f}\n")
            for t, _, x, y, z, _ in self.ctl.vpe_routed:
                f.write(f"{t - t0:.3f},vpe,1,{x:.3f},{y:.3f},{z:.3f}\n")
            if self.z:
                for t, v, p in self.z.pose:
                    if p:
                        f.write(f"{t - t0:.3f},skyfuse,{int(v)},{p[1]:.3f},{p[0]:.3f},{-p[2]:.3f}\n")
        self.result["tracks"] = self.a.tracks

    def verdict(self):
        """pass = the flight completed and the figures are within the scenario's limits."""
        r = self.result
        rmse_lim, corner_lim = self.sc["limits"]
        if self.a.max_rmse is not None:
            rmse_lim = self.a.max_rmse
        if self.a.max_corner is not None:
            corner_lim = self.a.max_corner
        fails = [] if r.get("ok") else [f"flight not completed (stage {r.get('stage')})"]
        for who in ("ekf3_vs_truth", "skyfuse_vs_truth"):
            try:
                v = r[who]["flight"]["raw"]["rmse_h"]
            except (KeyError, TypeError):
                fails.append(f"{who}: no figure")
                continue
            if v > rmse_lim:
                fails.append(f"{who} flight rmse_h {v} > {rmse_lim} m")
        c = (r.get("square") or {}).get("max_truth_distance_from_corner_m")
        if c is None or c > corner_lim:
            fails.append(f"square corner miss {c} > {corner_lim} m")
        r["limits"] = {"rmse_h_m": rmse_lim, "corner_m": corner_lim}
        r["pass"] = not fails
        r["fails"] = fails
        return r["pass"]

    def collect(self):
        r, ctl, z, poll = self.result, self.ctl, self.z, self.poll
        t0 = self.t_start
        sp = self.a.speedup
        if ctl:
            texts = []
            for t, sev, text in ctl.statustext:
                if texts and texts[-1]["text"] == text:
                    texts[-1]["n"] += 1
                    continue
                texts.append({"t_wall": round(t - t0, 2), "sev": sev, "text": text, "n": 1})
            r["statustext"] = texts[:300]
            r["autopilot_events"] = [{"t_wall": round(t - t0, 2), "what": w, "value": v}
                                     for t, w, v in ctl.events][:300]
            r["acks"] = collections.Counter(f"{c}:{res}" for _, c, res in ctl.acks)
            r["control_link_counts"] = dict(ctl.counts)
            r["vpe_routed_to_serial1"] = len(ctl.vpe_routed)
            r["vpe_clock"] = vpe_clock(ctl.vpe_routed, sp)
            if ctl.error:
                r["control_link_error"] = ctl.error
        if z:
            win = {}
            for k, (n, f, la) in sorted(z.mav.items()):
                if n > 2 and la > f:
                    win[k] = {"n": n, "hz_wall": round((n - 1) / (la - f), 1),
                              "hz_sim": round((n - 1) / (la - f) / sp, 1)}
                else:
                    win[k] = {"n": n}
            r["serial0_via_mavlink_server"] = win
            r["zenoh_mavlink_raw_in_frames"] = z.raw_in
            r["skyfuse_resets"] = [{"t_wall": round(t - t0, 2), "reset_counter": c} for t, c in z.resets]
            r["skyfuse_sources"] = [{"t_wall": round(t - t0, 2), "sources": s} for t, s in z.sources][:100]
            r["skyfuse_invalid_reasons"] = [{"t_wall": round(t - t0, 2), "reason": w}
                                            for t, w in z.invalid][:100]
            r["skyfuse_events"] = [dict(e, t_wall=round(t - t0, 2)) if isinstance(e, dict) else e
                                   for t, e in z.events][:200]
            r["zenoh_errors"] = z.errors[:10]
        if poll:
            r["status_timeline"] = [timeline_entry(s, t0) for s in poll.snaps]
            if poll.last:
                r["status_last"] = reduce_status(poll.last[1])
                with open(os.path.join(self.work, "status_last.json"), "w") as f:
                    json.dump(poll.last[1], f, indent=1)
            if poll.first_valid:
                r["skyfuse_first_valid_wall_s"] = round(poll.first_valid[0] - t0, 1)
            mav = r.get("status_last", {}).get("mavlink", {})
            r["vpe_sent_by_skyfuse"] = mav.get("sent")
        bins = sorted(glob.glob(os.path.join(self.work, "logs", "*.BIN")))
        if bins and self.a.parse_bin:
            r["dataflash"] = dataflash_counts(bins[-1])

    def stop(self):
        for x in (self.poll, self.z, self.ctl):
            if x:
                try:
                    x.close()
                except Exception as e:  # noqa: BLE001
                    log("close:", e)
        if self.procs:
            self.result["cpu_s"] = self.procs.cpu_times()
            ru = resource.getrusage(resource.RUSAGE_SELF)
            self.result["cpu_s"]["harness"] = round(ru.ru_utime + ru.ru_stime, 1)
            codes = self.procs.stop_all()
            self.result["exit_codes"] = codes


class FlightFailed(Exception):
    pass


def timeline_entry(s, t0):
    """One status poll, small: validity, output, and per source/sensor the verdicts."""
    est = s["estimator"]
    src = est.get("sources") or {}
    return {"t": round(s["t"] - t0, 1), "valid": est.get("valid"), "invalid_reason": est.get("invalid_reason"),
            "reset_counter": est.get("reset_counter"),
            "vpe_sent": s["mavlink"].get("sent"), "not_sending_reason": s["mavlink"].get("not_sending_reason"),
            "sources": {k: [v.get("usable"), round(v.get("test_ratio") or 0, 2), v.get("accepted"),
                            v.get("rejected"), v.get("last_reject_reason")]
                        for k, v in src.items() if isinstance(v, dict)},
            "health": {k: [v.get("health"), v.get("reasons"), round(v.get("rate_hz") or 0, 1)]
                       for k, v in s["sensors"].items()}}


def vpe_clock(vpe, speedup):
    """How skyfuse's VISION_POSITION_ESTIMATE.usec advances against the host clock
    (1.0: wall clock) and the autopilot's (wall rate / speedup), and the largest gap."""
    if len(vpe) < 10:
        return None
    t = np.array([v[0] for v in vpe])
    us = np.array([v[1] for v in vpe], float) * 1e-6
    slope = float(np.polyfit(t - t[0], us - us[0], 1)[0])
    gaps = np.diff(t)
    return {"usec_first": int(vpe[0][1]), "rate_vs_wall": round(slope, 3),
            "rate_vs_autopilot_clock": round(slope / speedup, 3),
            "max_gap_wall_s": round(float(gaps.max()), 2),
            "gaps_over_0.25s_sim": int(np.sum(gaps * speedup > 0.25)),
            "reset_counters": sorted({int(v[5]) for v in vpe})}


def armed_time(events, t_end, speedup):
    total, t_on = 0.0, None
    for t, w, v in events:
        if w != "armed":
            continue
        if v and t_on is None:
            t_on = t
        elif not v and t_on is not None:
            total += t - t_on
            t_on = None
    if t_on is not None:
        total += t_end - t_on
    return round(total * speedup, 1)


def dataflash_counts(path):
    """VISP (each VISION_POSITION_ESTIMATE the autopilot took) in its dataflash log."""
    from pymavlink import DFReader
    out = {"file": os.path.basename(path), "size": os.path.getsize(path)}
    try:
        d = DFReader.DFReader_binary(path)
        n, first, last = 0, None, None
        while True:
            m = d.recv_match(type=["VISP"])
            if m is None:
                break
            n += 1
            first = first if first is not None else m.TimeUS
            last = m.TimeUS
        out["VISP"] = n
        if n > 1:
            out["VISP_hz_sim"] = round((n - 1) / ((last - first) * 1e-6), 1)
    except Exception as e:  # noqa: BLE001
        out["error"] = repr(e)
    return out


def stable_copy(src, dst, settle=1.0, tries=60):
    """Copy a binary that may be being rewritten: wait until size and mtime hold still."""
    for _ in range(tries):
        st1 = os.stat(src)
        time.sleep(settle)
        st2 = os.stat(src)
        if (st1.st_size, st1.st_mtime_ns) == (st2.st_size, st2.st_mtime_ns) and st2.st_size > 0:
            shutil.copy2(src, dst)
            st3 = os.stat(src)
            if (st3.st_size, st3.st_mtime_ns) == (st2.st_size, st2.st_mtime_ns):
                return
    raise HarnessError(f"{src} keeps changing")


def wait_http(url, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            with urllib.request.urlopen(url, timeout=1) as r:
                if r.status == 200:
                    return True
        except Exception:  # noqa: BLE001
            time.sleep(0.2)
    return False


def wait_port(port, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not procs_mod.port_free(port):
            return True
        time.sleep(0.1)
    return False


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--skyfuse", required=True, help="skyfuse binary (copied before use)")
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), default="gps_flow")
    ap.add_argument("--link", choices=LINKS + ("udpout",), default="zenoh_raw",
                    help="how VPE reaches the autopilot (udpout: same as udpin, see above)")
    ap.add_argument("--speedup", type=float, default=1.0)
    ap.add_argument("--out", default="result.json")
    ap.add_argument("--instance", type=int, default=None, help="SITL -I (default: a free one)")
    ap.add_argument("--origin", choices=("auto", "skyfuse", "harness", "none"), default="auto",
                    help="no_gps: who sets the EKF origin (auto: skyfuse if it knows ekf_origin)")
    ap.add_argument("--config", default=None,
                    help="skyfuse TOML (default tests/data/sitl/skyfuse-{gps,nogps}.toml)")
    ap.add_argument("--alt", type=float, default=3.0)
    ap.add_argument("--side", type=float, default=10.0)
    ap.add_argument("--extnav-timeout", type=float, default=60.0, help="sim s")
    ap.add_argument("--arm-timeout", type=float, default=40.0, help="sim s")
    ap.add_argument("--leg-timeout", type=float, default=25.0, help="sim s")
    ap.add_argument("--land-timeout", type=float, default=40.0, help="sim s")
    ap.add_argument("--ground-wait", type=float, default=10.0,
                    help="sim s on the ground (by truth) without a disarm before giving up")
    ap.add_argument("--fast-arm", action="store_true",
                    help="no INS arming check, EK3_GPS_CHECK 0 (tests/data/sitl/fastarm.parm)")
    ap.add_argument("--timeout", type=float, default=None, help="wall s for the whole run")
    ap.add_argument("--max-rmse", type=float, default=None,
                    help="pass limit on the flight's horizontal RMSE, m (default per scenario)")
    ap.add_argument("--max-corner", type=float, default=None,
                    help="pass limit on the truth's miss of a square corner, m (default per scenario)")
    ap.add_argument("--no-parse-bin", dest="parse_bin", action="store_false",
                    help="do not count VISP in the autopilot's dataflash log")
    ap.add_argument("--keep", action="store_true", help="keep the work directory")
    ap.add_argument("--tracks", default=None, help="write every track as CSV here")
    ap.add_argument("--tlog", default=None,
                    help="write a telemetry log (.tlog) of SERIAL0 as mavlink-server relays it, plus SIM_STATE")
    a = ap.parse_args()
    if a.link == "udpout":
        a.link = "udpin"
    if a.timeout is None:
        a.timeout = 60 + 260 / a.speedup
    global TLOG
    if a.tlog:
        TLOG = Tlog(a.tlog)
    run = Run(a)

    def on_signal(signum, _frame):
        raise KeyboardInterrupt(f"signal {signum}")

    def on_alarm(_signum, _frame):
        raise TimeoutError(f"whole-run timeout {a.timeout:.0f} s")

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(int(a.timeout))
    code = 2
    try:
        run.setup()
        run.fly()
        run.result["ok"] = True
        code = 1
    except FlightFailed as e:
        run.problem(f"flight: {e}")
        code = 1
    except (HarnessError, TimeoutError, KeyboardInterrupt) as e:
        run.problem(f"harness: {e}")
    except Exception as e:  # noqa: BLE001
        run.problem(f"harness: {e!r}\n{traceback.format_exc()}")
    finally:
        signal.alarm(0)
        if TLOG is not None:
            TLOG.close()
            run.result["tlog_frames"] = TLOG.frames
        try:
            run.report()
        except Exception as e:  # noqa: BLE001
            run.problem(f"report: {e!r} {traceback.format_exc()}")
        try:
            run.collect()
        except Exception as e:  # noqa: BLE001
            run.problem(f"collect: {e!r}")
        run.stop()
        try:
            if code != 2 and run.verdict():
                code = 0
        except Exception as e:  # noqa: BLE001
            run.problem(f"verdict: {e!r}")
        run.result["wall_s_total"] = round(time.monotonic() - run.t_start, 1)
        if run.procs:
            for name in ("skyfuse", "arducopter", "mavlink-server"):
                p = os.path.join(run.work, f"{name}.log")
                if os.path.exists(p):
                    run.result.setdefault("log_tail", {})[name] = tail(p, 15)
        with open(a.out, "w") as f:
            json.dump(run.result, f, indent=1, default=str)
        if not a.keep and getattr(run, "work", None):
            shutil.rmtree(run.work, ignore_errors=True)
        log(f"result: {a.out} flight_ok={run.result['ok']} pass={run.result.get('pass')} "
            f"{run.result.get('fails', '')} wall={run.result['wall_s_total']} s")
    return code


def tail(path, n):
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            size = f.tell()
            f.seek(max(0, size - 8000))
            lines = f.read().decode(errors="replace").splitlines()
        return lines[-n:]
    except OSError:
        return []


if __name__ == "__main__":
    sys.exit(main())
