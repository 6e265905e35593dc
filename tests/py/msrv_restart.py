#!/usr/bin/env python3
"""mavlink-server killed and restarted under a running skyfuse.

An autopilot stand-in (pymavlink frames on a TCP server: HEARTBEAT 1 Hz and
LOCAL_POSITION_NED 30 Hz, its clock running on) feeds the real mavlink-server
(`tcpclient://`), which publishes to skyfuse over Zenoh as a client of skyfuse's
endpoint. skyfuse's `autopilot` input (LOCAL_POSITION_NED) must be healthy, go stale
when mavlink-server is killed (SIGKILL), and be healthy again soon after it restarts;
the other inputs, the estimate and the VPE must not notice. The change shows in
skyfuse's status and on its Zenoh events key. Prints a JSON report.

  msrv_restart.py --mavlink-server BIN --zenoh tcp/127.0.0.1:7447 --http 8080 --vehicle demo
"""
import argparse
import json
import math
import os
import shutil
import socket
import subprocess
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
import sys  # noqa: E402

sys.path.insert(0, HERE)
from pymavlink.dialects.v20 import common as mavlink2  # noqa: E402
from probe import free_port, status  # noqa: E402
from zenoh_peer import open_peer  # noqa: E402


def sensor(st, sid):
    return next(s for s in st["sensors"] if s["id"] == sid)


class Autopilot(threading.Thread):
    """A TCP server that streams to whoever connects, and takes the next connection
    when one goes away (as an autopilot's TCP port does)."""

    def __init__(self):
        super().__init__(daemon=True)
        self.srv = socket.socket()
        self.srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.srv.bind(("127.0.0.1", 0))
        self.srv.listen(1)
        self.port = self.srv.getsockname()[1]
        self.t0 = time.monotonic()
        self.connections = 0
        self.stop = threading.Event()

    def run(self):
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        while not self.stop.is_set():
            self.srv.settimeout(0.5)
            try:
                conn, _ = self.srv.accept()
            except socket.timeout:
                continue
            self.connections += 1
            last_hb = 0.0
            try:
                while not self.stop.is_set():
                    now = time.monotonic() - self.t0
                    frames = []
                    if now - last_hb >= 1.0:
                        last_hb = now
                        frames.append(mav.heartbeat_encode(2, 3, 0, 0, 4))
                    a = 0.3 * now
                    frames.append(mav.local_position_ned_encode(
                        int(now * 1000), 2 * math.cos(a), 2 * math.sin(a), -1.5,
                        -0.6 * math.sin(a), 0.6 * math.cos(a), 0.0))
                    conn.sendall(b"".join(f.pack(mav) for f in frames))
                    time.sleep(1 / 30)
            except OSError:
                pass
            finally:
                conn.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mavlink-server", required=True)
    ap.add_argument("--zenoh", required=True, help="skyfuse's Zenoh endpoint")
    ap.add_argument("--http", type=int, required=True)
    ap.add_argument("--vehicle", default="demo")
    ap.add_argument("--down-s", type=float, default=3.0)
    a = ap.parse_args()
    work = tempfile.mkdtemp(prefix="skyfuse-msrv-")
    autopilot = Autopilot()
    autopilot.start()
    conf = os.path.join(work, "zenoh.json5")
    with open(conf, "w") as f:
        json.dump({"mode": "client", "connect": {"endpoints": [a.zenoh]},
                   "scouting": {"multicast": {"enabled": False}}}, f)
    host, port = a.zenoh.split("/", 1)[1].rsplit(":", 1)
    argv = [a.mavlink_server, f"tcpclient://127.0.0.1:{autopilot.port}", f"zenoh://{host}:{port}",
            "--zenoh-config-file", conf, "--web-server", f"127.0.0.1:{free_port()}",
            "--log-path", os.path.join(work, "logs")]
    log = open(os.path.join(work, "mavlink-server.log"), "w")

    events = []
    session = open_peer(a.zenoh)
    session.declare_subscriber(f"skyfuse/{a.vehicle}/events",
                               lambda s: events.append(json.loads(s.payload.to_bytes())))
    report = {"autopilot_port": autopilot.port}

    def wait(cond, timeout):
        start = time.monotonic()
        while time.monotonic() - start < timeout:
            st = status(a.http)
            if cond(st):
                return time.monotonic() - start, st
            time.sleep(0.1)
        return None, status(a.http)

    def others(st):
        return {s["id"]: (s["health"], s["dropped"]) for s in st["sensors"]
                if s["enabled"] and s["id"] != "autopilot"}

    msrv = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
    try:
        took, st = wait(lambda st: sensor(st, "autopilot")["health"] == "ok", 30)
        report["first_ok_s"] = took
        if took is None:
            report["error"] = f"autopilot input never ok: {sensor(st, 'autopilot')}"
            return report
        time.sleep(2)
        before = status(a.http)
        report["before"] = {"others": others(before), "received": sensor(before, "autopilot")["received"],
                            "vpe_sent": before["outputs"][0]["sent"]}
        msrv.kill()
        msrv.wait()
        killed = time.monotonic()
        took, st = wait(lambda st: sensor(st, "autopilot")["health"] == "stale", 10)
        report["stale_after_s"] = took
        report["while_down"] = {"others": others(st), "valid": st["estimator"]["valid"],
                                "reasons": sensor(st, "autopilot")["reasons"]}
        time.sleep(max(0.0, a.down_s - (time.monotonic() - killed)))
        msrv = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
        restarted = time.monotonic()
        took, st = wait(lambda st: sensor(st, "autopilot")["health"] == "ok"
                        and sensor(st, "autopilot")["age_ms"] is not None
                        and sensor(st, "autopilot")["age_ms"] < 200, 30)
        report["ok_again_after_restart_s"] = took
        time.sleep(1)
        after = status(a.http)
        report["after"] = {"others": others(after), "valid": after["estimator"]["valid"],
                           "received": sensor(after, "autopilot")["received"],
                           "rejected": sensor(after, "autopilot")["rejected"],
                           "clock_restarts": sensor(after, "autopilot")["clock_restarts"],
                           "vpe_sent": after["outputs"][0]["sent"],
                           "seconds": time.monotonic() - restarted}
        report["autopilot_connections"] = autopilot.connections
        report["events"] = [e.get("message") for e in events if e.get("source") == "autopilot"]
        return report
    finally:
        msrv.kill()
        msrv.wait()
        autopilot.stop.set()
        session.close()
        log.close()
        # The mavlink-server log is kept only when something went wrong.
        if sys.exc_info()[1] is None:
            shutil.rmtree(work, ignore_errors=True)
        else:
            print(f"mavlink-server log kept in {work}", file=sys.stderr)


if __name__ == "__main__":
    print(json.dumps(main()))
