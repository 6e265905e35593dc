#!/usr/bin/env python3
"""A serial MAVLink link that is unplugged and plugged back, on a pseudo-terminal.

skyfuse is started with `--mavlink serial:LINK:57600` where LINK does not exist yet.
This script creates a pty pair and points LINK (a symlink, like /dev/serial/by-id/...)
at its slave end: "plugged". It reads what arrives on the master end with pymavlink's
parser for --seconds, then closes the pair and removes LINK ("unplugged") for --gap
seconds, then plugs a new pair in at the same LINK and reads again. Prints JSON: per
phase the VISION_POSITION_ESTIMATE and HEARTBEAT counts and undecodable bytes.

  pty_serial.py --link /tmp/x/ttyFC --seconds 4 --gap 3
"""
import argparse
import json
import os
import select
import time
import tty

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402


def plug(link):
    master, slave = os.openpty()
    tty.setraw(master)
    if os.path.lexists(link):
        os.unlink(link)
    os.symlink(os.ttyname(slave), link)
    return master, slave


def read_phase(master, seconds):
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    counts = {"vpe": 0, "heartbeat": 0, "bad": 0, "bytes": 0}
    end = time.time() + seconds
    while time.time() < end:
        r, _, _ = select.select([master], [], [], 0.2)
        if not r:
            continue
        try:
            data = os.read(master, 4096)
        except OSError:
            break
        counts["bytes"] += len(data)
        for m in parser.parse_buffer(data) or []:
            t = m.get_type()
            if t == "VISION_POSITION_ESTIMATE":
                counts["vpe"] += 1
            elif t == "HEARTBEAT":
                counts["heartbeat"] += 1
            elif t == "BAD_DATA":
                counts["bad"] += 1
    return counts


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--link", required=True)
    ap.add_argument("--seconds", type=float, default=4)
    ap.add_argument("--gap", type=float, default=3)
    a = ap.parse_args()
    master, slave = plug(a.link)
    first = read_phase(master, a.seconds)
    os.close(master)
    os.close(slave)
    os.unlink(a.link)
    time.sleep(a.gap)
    master, slave = plug(a.link)
    plugged_at = time.time()
    second = read_phase(master, a.seconds)
    os.close(master)
    os.close(slave)
    os.unlink(a.link)
    print(json.dumps({"before": first, "after": second, "replugged_at": plugged_at}))


if __name__ == "__main__":
    main()
