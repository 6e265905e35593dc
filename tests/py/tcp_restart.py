#!/usr/bin/env python3
"""A MAVLink TCP server (what skyfuse's `tcpout:` connects to, like a GCS or an
autopilot's TCP port) that goes away and comes back on the same port: accept, read
with pymavlink's parser for --seconds, close everything for --gap seconds (connections
are refused meanwhile), listen again, read again. Prints JSON per phase: VPE and
HEARTBEAT counts, undecodable messages, and how long skyfuse took to reconnect.

  tcp_restart.py --port P --seconds 4 --gap 2
"""
import argparse
import json
import os
import socket
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402


NAMES = {"VISION_POSITION_ESTIMATE": "vpe", "HEARTBEAT": "heartbeat", "BAD_DATA": "bad"}


def serve_phase(port, seconds):
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", port))
    srv.listen(1)
    srv.settimeout(15)
    listening = time.time()
    conn, _ = srv.accept()
    accepted_after = time.time() - listening
    conn.settimeout(0.5)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    counts = {"vpe": 0, "heartbeat": 0, "bad": 0, "accepted_after_s": round(accepted_after, 3)}
    end = time.time() + seconds
    while time.time() < end:
        try:
            data = conn.recv(4096)
        except socket.timeout:
            continue
        if not data:
            break
        for m in parser.parse_buffer(data) or []:
            key = NAMES.get(m.get_type(), "other")
            counts[key] = counts.get(key, 0) + 1
    conn.close()
    srv.close()
    return counts


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--seconds", type=float, default=4)
    ap.add_argument("--gap", type=float, default=2)
    a = ap.parse_args()
    first = serve_phase(a.port, a.seconds)
    time.sleep(a.gap)
    second = serve_phase(a.port, a.seconds)
    print(json.dumps({"before": first, "after": second}))


if __name__ == "__main__":
    main()
